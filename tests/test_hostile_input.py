"""Hostile input of issue 19 beyond checkpoints: radii, alpha, NaN images, memory, names, API types, imports.

Every case is one line ``caustica: error: ...`` naming what is wrong and what is allowed, exit
status 2, nothing written; from Python, a ParameterError (or RenderError).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

import caustica
from caustica import memory
from caustica.photons import records as records_module
from caustica.errors import OutputError, ParameterError, RenderError
from caustica.scene import builtin_scene_path

SCENE = "cornell-diacaustic"


@pytest.fixture(scope="module")
def diacaustic():
    return caustica.load_scene(builtin_scene_path(SCENE))


def _one_line(err: str) -> str:
    assert "Traceback" not in err and "Warning" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("caustica: error: "), err
    return lines[0]


def _cli_refuses(cli, tmp_path, *args, words=()):
    out = tmp_path / "out"
    code, _, err = cli("render", SCENE, "--res", "8", "-q", "-o", out / "x.exr", *[str(a) for a in args])
    line = _one_line(err)
    assert code == 2, err
    for word in words:
        assert word in line, (word, line)
    assert not out.exists()
    return line


# --------------------------------------------------------------------------- A4: radii whose square or cube underflow

@pytest.mark.parametrize("args", [
    ("--method", "sppm", "--passes", "2", "--radius", "1e-200"),
    ("--method", "sppm", "--passes", "2", "--radius", "1e300"),
    ("--method", "sppm", "--passes", "2", "--caustic-radius", "1e-120"),
    ("--method", "pspm", "--passes", "2", "--volume-radius", "1e-155"),
    ("--method", "pm", "--radius", "1e-200"),
    ("--method", "pm", "--caustic-radius", "1e101"),
    ("--method", "spm", "--stream-radius", "1e-200"),
    ("--method", "spm", "--volume-radius", "1e-155"),
])
def test_radii_beyond_float64_s_squares_and_cubes_are_refused_with_the_range(cli, tmp_path, args):
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # --radius 1e300 printed numpy's overflow RuntimeWarning
        _cli_refuses(cli, tmp_path, *args, words=(args[-2], "between 1e-100 and 1e+100"))


def test_radii_at_the_range_s_ends_render_finite_images(diacaustic):
    for r in (1e-100, 1e100):
        img = caustica.render(diacaustic, "sppm", res=8, passes=2, radius=r, volume_radius=r).image
        assert np.isfinite(img).all()
    assert np.isfinite(caustica.render(diacaustic, "spm", res=8, streams=200, stream_radius=0.0).image).all()


# --------------------------------------------------------------------------- A4: no NaN or inf image is a success

@pytest.mark.parametrize("method, kw", [("sppm", dict(passes=2)), ("pt", dict(passes=2)), ("pm", dict(photons=500)),
                                        ("sppm", dict(passes=2, schedule="global"))])
def test_an_image_with_nan_or_inf_pixels_is_an_error_not_a_result(diacaustic, monkeypatch, method, kw):
    cls = caustica.methods.get(method)
    real = cls.image   # bound (a classmethod) or plain (a staticmethod): called the same way

    def image(scene, settings, state):
        img = real(scene, settings, state).copy()
        img[0, 0, 1] = np.nan
        img[3, 2, 0] = np.inf
        return img

    monkeypatch.setattr(cls, "image", staticmethod(image))
    with pytest.raises(RenderError) as info:
        caustica.render(diacaustic, method, res=8, **kw)
    msg = str(info.value)
    assert msg.startswith(f"{method}: the image") and "2 of 64 pixels" in msg and "1 NaN, 1 infinite" in msg, msg
    assert ("after 2 passes" in msg) == ("passes" in kw)


def test_cli_nan_image_is_one_line_exit_2_and_keeps_the_previous_outputs(cli, tmp_path, monkeypatch):
    out = tmp_path / "x.exr"
    assert cli("render", SCENE, "--method", "sppm", "--res", "8", "--passes", "1", "-q", "-o", out)[0] == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    cls = caustica.methods.get("sppm")
    monkeypatch.setattr(cls, "radiance", staticmethod(lambda state: np.full((64, 3), np.nan)))
    code, _, err = cli("render", SCENE, "--method", "sppm", "--res", "8", "--passes", "2", "-q", "-o", out)
    assert code == 2 and "64 of 64 pixels that are not finite" in _one_line(err)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


# --------------------------------------------------------------------------- B2: alpha and a pass's bound

@pytest.mark.parametrize("alpha", ["1e-6", "0.009", "0", "1"])
def test_alpha_below_its_bound_is_refused(cli, tmp_path, alpha):
    _cli_refuses(cli, tmp_path, "--method", "sppm", "--passes", "2", "--alpha", alpha,
                 words=("--alpha", "at least 0.01 and below 1"))


def test_the_smallest_alpha_keeps_passes_short(diacaustic):
    """alpha = 1e-6 made the second pass of a 64x64 render never end; the least alpha allowed does not."""
    caustica.render(diacaustic, "sppm", res=32, passes=1, alpha=0.01)   # compiled
    r = caustica.render(diacaustic, "sppm", res=32, passes=12, alpha=0.01, seed=1)
    assert max(r.stats["pass_seconds"]) < 20 * max(min(r.stats["pass_seconds"]), 0.05)
    assert np.isfinite(r.image).all()


# --------------------------------------------------------------------------- C4: memory before allocating

@pytest.mark.parametrize("method, kw", [("sppm", dict(caustic_photons=2**31 - 1)),
                                        ("pspm", dict(caustic_photons=2**31 - 1)),
                                        ("sppm", dict(photons=2**31 - 1, caustic_photons=0)),
                                        ("pspm", dict(streams=2**31 - 1))])
def test_a_pass_s_memory_is_checked_before_anything_is_allocated(diacaustic, monkeypatch, method, kw):
    from caustica.photons import records, trace

    def refuse(*a, **k):
        raise AssertionError("allocated before the memory check")

    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 16 * 2**30)
    monkeypatch.setattr(trace, "allocate_buffers", refuse)
    monkeypatch.setattr(records, "allocate_buffers", refuse)
    monkeypatch.setattr(caustica.methods.get(method), "run_pass", refuse)
    with pytest.raises(ParameterError, match=f"one {method} pass of .* GB, more than"):
        caustica.render(diacaustic, method, res=8, passes=2, **kw)


def test_the_records_past_each_photons_fixed_slots_are_checked_before_they_are_allocated(diacaustic, monkeypatch):
    """Under roulette a pass is planned with each photon's fixed slots only; the records its longer paths make past
    them are counted while tracing and checked before the buffer that holds them all is allocated."""
    from caustica.photons import trace
    n = 20_000
    planned = n * trace.fixed_slots(1024) * records_module.SLOT_BYTES
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: int(1.05 * planned / memory.BUDGET_FRACTION))
    allocated = []

    def first_buffer_only(*a):   # the fixed slots' buffer; the one for every record must not come
        if allocated:
            raise AssertionError("allocated before the memory check")
        allocated.append(a)
        return records_module.allocate_buffers(*a)

    monkeypatch.setattr(trace, "allocate_buffers", first_buffer_only)
    with pytest.raises(ParameterError, match=r"20,000 photons' [\d,]+ records \(the paths past their first 8\) "
                                             r"and their copy would need about .* GB, more than"):
        caustica.render(diacaustic, "pm", res=8, spp=1, photons=n, caustic_photons=0, termination="roulette",
                        max_bounces=1024)


# --------------------------------------------------------------------------- C5, C7: names that are not names

@pytest.mark.parametrize("aov", ["../../etc", "radius,../x", "/tmp/x", "count/"])
def test_an_aov_is_a_name_not_a_path(cli, tmp_path, aov):
    _cli_refuses(cli, tmp_path, "--method", "sppm", "--passes", "2", "--aov", aov,
                 words=("--aov", "it makes: radius, count"))


@pytest.mark.parametrize("which", ["-o", "--checkpoint", "-o folder"])
def test_a_name_longer_than_the_file_system_allows_is_one_line(cli, tmp_path, which):
    long = "n" * 300
    out, args = tmp_path / "out" / "x.exr", []
    if which == "-o":
        out = tmp_path / "out" / f"{long}.exr"
    elif which == "-o folder":
        out = tmp_path / "out" / long / "x.exr"
    else:
        args = ["--checkpoint", tmp_path / "out" / f"{long}.npz"]
    code, _, err = cli("render", SCENE, "--method", "sppm", "--res", "8", "--passes", "2", "-q", "-o", out, *args)
    line = _one_line(err)
    assert code == 2 and "bytes long; this file system allows" in line and len(line) < 400, line
    assert not (tmp_path / "out").exists()


def test_a_name_that_only_its_temporary_makes_too_long_is_refused_before_rendering(tmp_path):
    from caustica import imageio
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    with pytest.raises(OutputError, match="the temporary written beside it first adds"):
        imageio.check_outputs([tmp_path / ("n" * (limit - 10) + ".exr")])
    imageio.check_outputs([tmp_path / ("n" * (limit - 80) + ".exr")])


# --------------------------------------------------------------------------- C10: the Python API's types

@pytest.mark.parametrize("kw, words", [
    (dict(res=(16, "a")), "--res"), (dict(res=True), "--res"), (dict(res=16.5), "--res"),
    (dict(res=(8, 8, 8)), "--res"),
    (dict(seed=True), "--seed"), (dict(threads=True), "--threads"), (dict(spp=np.True_), "--spp"),
    (dict(passes=True), "--passes"), (dict(time_s=True), "--time"), (dict(time_s="soon"), "--time"),
    (dict(radius=True, passes=2), "--radius"), (dict(photons=True, passes=2), "--photons"),
    (dict(fixed_light_grid=5, passes=2), "--fixed-light-grid"),
    (dict(aov=5, passes=2), "--aov"), (dict(aov=["radius", 5], passes=2), "--aov"),
    (dict(checkpoint=123, passes=2), "--checkpoint: a file name"),
    (dict(checkpoint=b"x.npz", passes=2), "--checkpoint"),
    (dict(checkpoint="", passes=2), "--checkpoint: the file name is empty"),
])
def test_the_api_refuses_wrong_types_in_one_line(diacaustic, tmp_path, monkeypatch, kw, words):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ParameterError) as info:
        caustica.render(diacaustic, "sppm", **{"res": 8, **kw})
    assert words in str(info.value) and "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []     # no file named 123 (or anything else)


def test_the_api_refuses_scene_and_output_names_of_the_wrong_type(tmp_path):
    with pytest.raises(ParameterError, match="load_scene: '123' is not a scene file name"):
        caustica.load_scene(123)
    result = caustica.RenderResult(np.zeros((2, 2, 3)))
    with pytest.raises(ParameterError, match="output path '123': a file name"):
        result.save(123)


# --------------------------------------------------------------------------- Ctrl-C while the package imports

def test_ctrl_c_while_the_package_imports_is_one_line_exit_130(tmp_path):
    """The console script imports caustica.cli and calls main(); Ctrl-C during NumPy's import (the first heavy
    one) must meet the CLI's handler, not the interpreter's traceback."""
    code = ("import builtins, os, signal, sys\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "real = builtins.__import__\n"
            "def imp(name, *a, **k):\n"
            "    if name == 'numpy' and 'numpy' not in sys.modules:\n"
            "        os.kill(os.getpid(), signal.SIGINT)\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = imp\n"
            "from caustica.cli import main\n"      # what the console script does
            "sys.exit(main(['methods']))\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == "caustica: interrupted (SIGINT); no output file was replaced", proc.stderr


def test_importing_the_cli_loads_no_numpy():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", "import sys, caustica.cli; print('numpy' in sys.modules)"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.stdout.strip() == "False", proc.stderr
    proc = subprocess.run([sys.executable, "-c", "import caustica; print(caustica.render.__module__, "
                                                 "caustica.methods.get('pt').name)"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.stdout.split() == ["caustica.api", "pt"], proc.stderr


def test_cli_json_records_the_interrupt_signal_only_when_interrupted(cli, tmp_path):
    out = tmp_path / "x.exr"
    assert cli("render", SCENE, "--method", "sppm", "--res", "8", "--passes", "2", "-q", "-o", out)[0] == 0
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["interrupted"] is False and "interrupted_by" not in meta


def test_an_aov_named_twice_is_written_once(diacaustic):
    r = caustica.render(diacaustic, "sppm", res=8, passes=1, aov="radius, radius,count")
    assert list(r.aovs) == ["radius", "count"]
