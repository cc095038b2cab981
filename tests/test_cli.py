"""The command line (SPEC §5): outputs and their JSON sidecar, methods and their flags, errors.

The CLI runs in-process through ``caustica.cli.main`` (fast: kernels compile once per
session); a few tests run ``python -m caustica`` in a subprocess for the real exit code
and real signals.  Renders are tiny: 16x16 (or 8x8) pixels, 1 spp, a few thousand photons.
"""
from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from caustica import __version__, imageio, memory, methods

BUILTINS = ("cornell-diacaustic", "cornell-catacaustic", "cornell-pyramid", "cornell-bunny", "cornell-diacaustic-fog")
SCENE = "cornell-diacaustic"
TINY = ("--res", "16", "--spp", "1", "-q")
#: Small photon counts for each method; an empty tuple for the path tracer.
SMALL = {
    "pt": (),
    "pm": ("--photons", "2000"),
    "spm": ("--streams", "500", "--assoc", "3"),
}
COMMON_FLAGS = ("--method", "--spp", "--res", "--seed", "--threads", "-D", "--output", "--exposure", "--quiet")
PHOTON_TIMINGS = ("photon_trace_s", "map_build_s")

MINIMAL_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
    <emitter type="point"><point name="position" value="0, 0, 3"/><rgb name="intensity" value="10"/></emitter>
</scene>
"""


#: A sensor for scenes written to carry one problem only (the loader reports every problem of a scene;
#: a scene without a sensor has that second one).
SENSOR_XML = MINIMAL_XML.split("\n", 1)[1].split("    <shape")[0]


def _files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob("*") if p.is_file()) if directory.exists() else []


def _one_line_error(err: str) -> str:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("caustica: error: "), err
    return lines[0]


def _render(cli, out: Path, *args, scene=SCENE):
    code, stdout, err = cli("render", scene, *TINY, "-o", out, *args)
    assert code == 0, err
    assert "Traceback" not in err
    return json.loads(out.with_suffix(".json").read_text())


# ----------------------------------------------------------------------------- outputs and JSON


@pytest.mark.parametrize("method", ["pt", "pm", "spm"])
def test_render_writes_exr_png_and_json_side_by_side(cli, tmp_path, method):
    out = tmp_path / "x.exr"
    stats = _render(cli, out, "--method", method, "--res", "16x12", *SMALL[method])
    assert _files(tmp_path) == ["x.exr", "x.json", "x.png"]
    img = imageio.read_exr(out)
    assert img.shape == (12, 16, 3) and np.isfinite(img).all() and img.max() > 0
    from PIL import Image
    with Image.open(tmp_path / "x.png") as png:
        assert png.size == (16, 12) and png.mode == "RGB"

    assert stats["method"] == method
    assert stats["scene"] == SCENE
    assert stats["seed"] == 0 and stats["spp"] == 1
    assert stats["version"] == __version__
    assert (stats["width"], stats["height"]) == (16, 12)
    assert stats["outputs"] == {"exr": "x.exr", "png": "x.png", "json": "x.json"}
    # every parameter of the method, and nothing else
    assert set(stats["parameters"]) == {p.name for p in methods.get(method).params}
    t = stats["timings"]
    phases = ("scene_load_s", "compile_s", "camera_pass_s", "total_s")
    phases += PHOTON_TIMINGS if method != "pt" else ()
    for phase in phases:
        assert isinstance(t[phase], float) and t[phase] >= 0.0, phase
    assert stats["peak_memory_bytes"] > 1_000_000
    if method != "pt":
        assert stats["photons_emitted"] > 0 and 0 < stats["photons_stored"]
        assert stats["map_bytes"] > 0
        assert stats["map_mb"] == pytest.approx(stats["map_bytes"] / 1e6)
    if method == "spm":
        assert stats["streams_emitted"] == 500
        assert stats["stream_records_stored"] > 0
        assert stats["photons_emitted"] == 500 * (3 + 1)


def test_pt_json_reports_zero_photons_and_map_memory(cli, tmp_path):
    stats = _render(cli, tmp_path / "x.exr")
    assert stats["photons_emitted"] == 0 and stats["photons_stored"] == 0
    assert stats["map_bytes"] == 0 and stats["map_mb"] == 0.0


def test_total_time_covers_every_phase(cli, tmp_path, monkeypatch):
    import time

    from caustica import api
    compile_scene = api.compile_scene

    def slow_compile_scene(desc):  # a scene that takes a measurable time to load
        time.sleep(0.2)
        return compile_scene(desc)

    monkeypatch.setattr(api, "compile_scene", slow_compile_scene)
    stats = _render(cli, tmp_path / "x.exr", "--method", "pm", *SMALL["pm"])
    t = stats["timings"]
    phases = sum(v for k, v in t.items() if k != "total_s")
    assert t["total_s"] >= phases - 1e-3


def test_default_output_name_is_out_scene_method(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "box.xml").write_text(MINIMAL_XML)
    assert cli("render", SCENE, *TINY)[0] == 0
    assert cli("render", "box.xml", *TINY)[0] == 0
    assert _files(tmp_path / "out") == sorted(
        f"{stem}_pt.{ext}" for stem in (SCENE, "box") for ext in ("exr", "png", "json"))


def test_output_path_without_suffix_or_png(cli, tmp_path):
    assert cli("render", SCENE, *TINY, "-o", tmp_path / "a" / "plain")[0] == 0
    assert cli("render", SCENE, *TINY, "-o", tmp_path / "b" / "pic.png")[0] == 0
    assert _files(tmp_path / "a") == ["plain.exr", "plain.json", "plain.png"]
    assert _files(tmp_path / "b") == ["pic.exr", "pic.json", "pic.png"]


def test_summary_line_unless_quiet(cli, tmp_path):
    code, out, err = cli("render", SCENE, "--res", "8", "--spp", "1", "-o", tmp_path / "x.exr")
    assert code == 0 and "Traceback" not in err
    assert "8x8" in out and "x.exr" in out
    code, out, _ = cli("render", SCENE, *TINY, "-o", tmp_path / "y.exr")
    assert code == 0 and out == ""


# ----------------------------------------------------------------------------- methods and their flags


def _non_default_value(p):
    """A valid value other than the default: (CLI text, value expected in the JSON)."""
    override = {"photons": 2000, "caustic_photons": 500, "streams": 300, "assoc": 2, "light_samples": 2,
                "max_bounces": 2, "k": 7, "caustic_k": 5, "max_depth": 3}
    if p.name in override:
        v = override[p.name]
    elif p.choices:
        v = next(c for c in p.choices if c != p.default)
    elif p.type is bool:
        v = not p.default
        return ("true" if v else "false"), v
    elif p.type is int:
        v = 7 if p.default is None else p.default + 1
    elif p.type is float:
        v = 1.5 if p.default is None else p.default * 0.5 + 0.25
    else:
        raise AssertionError(f"no test value for parameter {p.name} of type {p.type}")
    return str(v), v


@pytest.mark.parametrize("method", ["pt", "pm", "spm"])
def test_every_method_parameter_flag_is_passed_through(cli, tmp_path, method):
    args, expected = [], {}
    for p in methods.get(method).params:
        text, value = _non_default_value(p)
        args += [p.flag, text]
        expected[p.name] = value
    stats = _render(cli, tmp_path / "x.exr", "--method", method, *args)
    assert stats["parameters"] == expected


def test_k_flag_shows_up_in_json(cli, tmp_path):
    stats = _render(cli, tmp_path / "x.exr", "--method", "spm", *SMALL["spm"], "--k", "7")
    assert stats["parameters"]["k"] == 7


def test_pm_with_caustic_photons_builds_a_caustic_map(cli, tmp_path):
    plain = _render(cli, tmp_path / "a.exr", "--method", "pm", "--photons", "2000")
    pmc = _render(cli, tmp_path / "b.exr", "--method", "pm", "--photons", "2000", "--caustic-photons", "1000")
    assert plain["parameters"]["caustic_photons"] == 0
    assert pmc["parameters"]["caustic_photons"] == 1000
    assert plain["photons_emitted"] == 2000
    assert pmc["photons_emitted"] == 3000
    assert pmc["timings"]["photon_trace_s"] >= 0 and pmc["timings"]["map_build_s"] >= 0
    assert pmc["map_bytes"] > 0


@pytest.mark.parametrize("method, flag, value", [
    ("pm", "--streams", "10"),
    ("pm", "--stream-radius", "1"),
    ("spm", "--photons", "10"),
    ("spm", "--caustic-photons", "10"),
    ("pt", "--k", "7"),
    ("spm", "--rr-depth", "3"),
])
def test_flag_of_another_method_is_an_error(cli, tmp_path, method, flag, value):
    out = tmp_path / "o" / "x.exr"
    code, _, err = cli("render", SCENE, *TINY, "--method", method, flag, value, "-o", out)
    assert code == 2
    line = _one_line_error(err)
    assert flag.lstrip("-").replace("-", "_") in line and method in line
    assert _files(tmp_path) == []


@pytest.mark.parametrize("args, names", [
    (("--method", "pm", "--k", "0"), "--k"),
    (("--method", "spm", "--assoc", "-1"), "--assoc"),
    (("--method", "pm", "--radius", "0"), "--radius"),
    (("--method", "pm", "--filter", "box"), "--filter"),
])
def test_method_parameter_out_of_range_is_an_error(cli, tmp_path, args, names):
    code, _, err = cli("render", SCENE, *TINY, *args, "-o", tmp_path / "x.exr")
    assert code == 2 and "Traceback" not in err
    assert names in err.strip().splitlines()[-1]
    assert _files(tmp_path) == []


def test_bad_bool_value_is_an_error(cli, tmp_path):
    code, _, err = cli("render", SCENE, *TINY, "--method", "pm", *SMALL["pm"], "--fixed-light-grid", "maybe",
                       "-o", tmp_path / "x.exr")
    assert code == 2
    assert "--fixed-light-grid" in _one_line_error(err)
    assert _files(tmp_path) == []


# ----------------------------------------------------------------------------- bad input


def _write_scene(tmp_path: Path, xml: str) -> Path:
    (tmp_path / "s.xml").write_text(xml)
    return tmp_path / "s.xml"


def _write_mesh_scene(tmp_path: Path, mesh_name: str, kind: str = "obj") -> Path:
    xml = tmp_path / "meshy.xml"
    xml.write_text(f'<scene version="3.0.0">\n'
                   f'    <shape type="{kind}"><string name="filename" value="{mesh_name}"/></shape>\n'
                   f'{SENSOR_XML}</scene>\n')
    return xml


def _bad_input_cases():
    """(id, setup(tmp_path) -> extra CLI args, words the error line must contain)."""
    def scene_args(scene, *rest):
        return lambda tmp: (scene, *rest)

    def malformed(tmp):
        (tmp / "bad.xml").write_text('<scene version="3.0.0">\n  <shape type="sphere">\n</scene>\n')
        return (tmp / "bad.xml",)

    def unknown_element(tmp):
        (tmp / "unk.xml").write_text(f'<scene version="3.0.0">\n  <teapot/>\n{SENSOR_XML}</scene>\n')
        return (tmp / "unk.xml",)

    def garbage_obj(tmp):
        (tmp / "garbage.obj").write_bytes(b"\x00\x01 not an obj file \xff")
        return (_write_mesh_scene(tmp, "garbage.obj"),)

    def malformed_ply(tmp):
        (tmp / "broken.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                        "end_header\n1 2\n")
        return (_write_mesh_scene(tmp, "broken.ply", "ply"),)

    def missing_mesh(tmp):
        return (_write_mesh_scene(tmp, "nowhere.obj"),)

    return [
        ("missing-scene-file", scene_args("no/such/scene.xml"), ["scene.xml"]),
        ("unknown-builtin", scene_args("cornell-teapot"), ["cornell-teapot", "cornell-diacaustic"]),
        ("malformed-xml", malformed, ["bad.xml", "malformed"]),
        ("unknown-element", unknown_element, ["unk.xml:2", "teapot", "supported"]),
        ("negative-spp", scene_args(SCENE, "--spp", "-3"), ["--spp"]),
        ("zero-spp", scene_args(SCENE, "--spp", "0"), ["--spp"]),
        ("res-abc", scene_args(SCENE, "--res", "abc"), ["--res", "abc"]),
        ("res-negative", scene_args(SCENE, "--res", "-4"), ["--res"]),
        ("define-without-equals", scene_args(SCENE, "-D", "res"), ["-D", "res"]),
        ("bad-output-suffix", lambda tmp: (SCENE, "-o", tmp / "o" / "x.jpg"), [".jpg"]),
        ("unreadable-mesh-garbage-obj", garbage_obj, ["garbage.obj"]),
        ("unreadable-mesh-malformed-ply", malformed_ply, ["broken.ply"]),
        ("missing-mesh", missing_mesh, ["nowhere.obj"]),
        ("threads-zero", scene_args(SCENE, "--threads", "0"), ["--threads"]),
        ("seed-negative", scene_args(SCENE, "--seed", "-1"), ["--seed"]),
        # integers beyond what the kernels can honour (issue 8): refused with the allowed range
        ("spp-2^63", scene_args(SCENE, "--spp", str(2**63)), ["--spp", "<= 1,048,576"]),
        ("seed-huge", scene_args(SCENE, "--seed", "9" * 23), ["--seed", "<= 4,294,967,295"]),
        ("threads-huge", scene_args(SCENE, "--threads", "5000"), ["--threads", "<= 1,024"]),
        ("res-beyond-int32-pixels", scene_args(SCENE, "--res", "50000x50000"), ["50000x50000", "int32"]),
        ("light-samples-2^32", scene_args(SCENE, "-m", "pm", "--light-samples", str(2**32)),
         ["--light-samples", "<= 64"]),
        ("max-specular-depth-huge", scene_args(SCENE, "-m", "pm", "--max-specular-depth", "9" * 23),
         ["--max-specular-depth", "<= 1,024"]),
        ("k-1e11", scene_args(SCENE, "-m", "spm", "--k", "100000000000"), ["--k", "<= 2,147,483,647"]),
        ("max-depth-huge", scene_args(SCENE, "--max-depth", "99999"), ["--max-depth", "<= 1,024"]),
        ("sampler-beyond-spp-bound", lambda tmp: (_write_scene(tmp, MINIMAL_XML.replace(
            "</sensor>", f'<sampler type="independent"><integer name="sample_count" value="{2**20 + 1}"/>'
                         f'</sampler></sensor>')),), ["s.xml:6", "sample_count", "1,048,576"]),
    ]


@pytest.mark.parametrize("case", _bad_input_cases(), ids=lambda c: c[0])
def test_bad_input_is_one_line_error_exit_2_and_no_output(cli, tmp_path, case):
    _, setup, words = case
    args = list(setup(tmp_path))
    inputs = _files(tmp_path)
    if "-o" not in args:
        args += ["-o", tmp_path / "o" / "x.exr"]
    for flag, value in (("--res", "8"), ("--spp", "1")):
        if flag not in args:
            args += [flag, value]
    code, _, err = cli("render", *args, "-q")
    assert code == 2, err
    line = _one_line_error(err)
    for word in words:
        assert word in line, (word, line)
    assert _files(tmp_path) == inputs  # nothing written, no temporary left behind


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads files whatever their mode")
def test_mesh_without_read_permission_is_an_error(cli, tmp_path):
    mesh = tmp_path / "locked.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    mesh.chmod(0)
    code, _, err = cli("render", _write_mesh_scene(tmp_path, "locked.obj"), *TINY, "-o", tmp_path / "o" / "x.exr")
    assert code == 2
    assert "locked.obj" in _one_line_error(err)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (("--res", "40000"), ("40000x40000", "GB", "--res")),
    (("-m", "pm", "--photons", "2000000000"), ("photons", "GB", "--photons")),
    (("-m", "spm", "--streams", "100000000", "--assoc", "100"), ("streams", "GB", "--assoc")),
    # the k-nearest search's scratch: 16 bytes per neighbour on each thread (a MemoryError before)
    (("-m", "spm", "--k", "2000000000", "--threads", "64"), ("--k 2,000,000,000 on 64 threads", "GB")),
    (("-m", "pm", "--caustic-k", "2000000000", "--threads", "64"), ("--caustic-k", "GB")),
])
def test_parameters_that_would_exhaust_memory_are_refused(cli, tmp_path, monkeypatch, args, words):
    """Refused before allocating, with the estimate in the message; nothing written (on a 16 GiB machine)."""
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 16 * 2**30)
    code, _, err = cli("render", SCENE, "--spp", "1", "-q", *args, "-o", tmp_path / "o" / "x.exr")
    assert code == 2
    line = _one_line_error(err)
    for word in words:
        assert word in line, (word, line)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("res", ["0", "0x8", "8x0"])
def test_res_zero_is_an_error(cli, tmp_path, res):
    code, _, err = cli("render", SCENE, "-D", "res=8", "--spp", "1", "-q", "--res", res,
                       "-o", tmp_path / "x.exr")
    assert code == 2
    assert "--res" in _one_line_error(err)
    assert _files(tmp_path) == []


def test_unwritable_output_path_is_an_error(cli, tmp_path):
    (tmp_path / "afile").write_text("not a folder")
    code, _, err = cli("render", SCENE, *TINY, "-o", tmp_path / "afile" / "x.exr")
    assert code == 2
    assert "afile" in _one_line_error(err)


@pytest.mark.parametrize("args", [("--spp", "abc"), ("--method", "nope"), ("--bogus-flag",)],
                         ids=["spp-abc", "unknown-method", "unknown-flag"])
def test_usage_errors_exit_2_without_traceback_or_output(cli, tmp_path, args):
    code, _, err = cli("render", SCENE, *TINY, *args, "-o", tmp_path / "x.exr")
    assert code == 2
    assert "Traceback" not in err and "error" in err.strip().splitlines()[-1]
    assert _files(tmp_path) == []


def test_usage_errors_are_one_caustica_error_line(cli, tmp_path):
    code, _, err = cli("render", SCENE, *TINY, "--spp", "abc", "-o", tmp_path / "x.exr")
    assert code == 2
    assert "--spp" in _one_line_error(err)


def test_python_m_caustica_real_exit_code_and_no_traceback(tmp_path):
    env = dict(os.environ, COLUMNS="200")
    proc = subprocess.run([sys.executable, "-m", "caustica", "render", str(tmp_path / "missing.xml"),
                           "-o", str(tmp_path / "x.exr"), "-q"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert "Traceback" not in proc.stderr
    assert proc.stderr.startswith("caustica: error: ") and proc.stderr.count("\n") == 1
    assert "missing.xml" in proc.stderr
    assert _files(tmp_path) == []


# ----------------------------------------------------------------------------- listings and help


def test_scenes_lists_the_builtins(cli):
    code, out, err = cli("scenes")
    assert code == 0 and err == ""
    lines = out.strip().splitlines()
    assert [line.split()[0].rstrip(':') for line in lines] == list(BUILTINS)


def test_scenes_names_each_scene_once_per_line(cli):
    _, out, _ = cli("scenes")
    for name, line in zip(BUILTINS, out.strip().splitlines()):
        assert line.count(name) == 1, line


def test_methods_lists_every_method_with_its_parameters(cli):
    code, out, err = cli("methods")
    assert code == 0 and err == ""
    lines = out.splitlines()
    for name in ("pt", "pm", "spm"):
        start = next(i for i, line in enumerate(lines) if line.startswith(f"{name}:"))
        block = []
        for line in lines[start + 1:]:
            if not line.startswith(" "):
                break
            block.append(line.split()[0])
        assert block == [p.flag for p in methods.get(name).params], name


def test_listings_claim_only_what_is_shown(cli, tmp_path):
    """issue 19: 'caustica scenes' called the fog box "pt only" though every method renders it, and
    'caustica methods' called sppm and pspm "consistent", which no test measures (the error falling
    with the passes at the expected rate)."""
    _, scenes, _ = cli("scenes")
    fog = next(line for line in scenes.splitlines() if line.startswith("cornell-diacaustic-fog:"))
    assert "pt only" not in fog and "every method" in fog
    for method in sorted(methods.available()):
        code, _, err = cli("render", "cornell-diacaustic-fog", "--method", method, "--res", "8", "-q",
                           "-o", tmp_path / f"{method}.exr")
        assert code == 0, (method, err)
    _, listing, _ = cli("methods")
    assert "consistent" not in listing


def test_top_level_help_and_version(cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    code, out, _ = cli("--help")
    assert code == 0
    for word in ("render", "scenes", "methods", "--version", "--help"):
        assert word in out
    code, out, _ = cli("--version")
    assert code == 0 and __version__ in out
    code, out, _ = cli()  # no command: help, usage exit status
    assert code == 2 and "render" in out


def test_render_help_mentions_every_option(cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    code, out, _ = cli("render", "--help")
    assert code == 0
    flags = set(COMMON_FLAGS)
    for cls in methods.available().values():
        flags |= {p.flag for p in cls.params}
    missing = [f for f in sorted(flags) if f not in out]
    assert missing == []
    for name in ("pt", "pm", "spm"):
        assert name in out


# ----------------------------------------------------------------------------- -D, seeds, determinism


def test_define_res_changes_the_output_size(cli, tmp_path):
    _render_plain = ("render", SCENE, "--spp", "1", "-q")
    assert cli(*_render_plain, "-D", "res=8", "-o", tmp_path / "a.exr")[0] == 0
    assert imageio.read_exr(tmp_path / "a.exr").shape == (8, 8, 3)
    assert cli(*_render_plain, "-D", "res=12", "-o", tmp_path / "b.exr")[0] == 0
    assert imageio.read_exr(tmp_path / "b.exr").shape == (12, 12, 3)
    # --res wins over the scene's film, whatever -D says
    assert cli(*_render_plain, "-D", "res=8", "--res", "10x6", "-o", tmp_path / "c.exr")[0] == 0
    assert imageio.read_exr(tmp_path / "c.exr").shape == (6, 10, 3)
    # -D spp=2 reaches the sampler
    assert cli("render", SCENE, "-q", "-D", "res=8", "-D", "spp=2", "-o", tmp_path / "d.exr")[0] == 0
    assert json.loads((tmp_path / "d.json").read_text())["spp"] == 2


@pytest.mark.parametrize("method", ["pt", "spm"])
def test_seed_changes_the_image_and_same_seed_same_bytes(cli, tmp_path, method):
    def exr_bytes(name, *args):
        _render(cli, tmp_path / f"{name}.exr", "--method", method, *SMALL[method], *args)
        return (tmp_path / f"{name}.exr").read_bytes()

    a = exr_bytes("a", "--seed", "1")
    b = exr_bytes("b", "--seed", "1")
    c = exr_bytes("c", "--seed", "2")
    one_thread = exr_bytes("d", "--seed", "1", "--threads", "1")
    assert a == b
    assert a == one_thread  # the thread count does not change the image
    assert not np.array_equal(imageio.read_exr(tmp_path / "a.exr"), imageio.read_exr(tmp_path / "c.exr"))
    assert json.loads((tmp_path / "c.json").read_text())["seed"] == 2


# ----------------------------------------------------------------------------- failed / interrupted renders


def _leftovers(directory: Path) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.endswith((".tmp", ".old"))]  # temporaries, backups


def test_render_interrupted_before_saving_writes_nothing(cli, tmp_path, monkeypatch):
    cls = methods.get("pt")

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(cls, "run_pass", staticmethod(interrupted))
    code, _, err = cli("render", SCENE, *TINY, "-o", tmp_path / "x.exr")
    assert code == 130
    assert "interrupted" in err and "Traceback" not in err
    assert _files(tmp_path) == []


def _interrupt_png_write(monkeypatch, exc):
    """Make the PNG writer fail half-way through writing its temporary file."""
    def failing_png_writer(image, exposure_stops=0.0):
        def writer(tmp):
            tmp.write_bytes(b"\x89PNG half a file")
            raise exc
        return writer
    monkeypatch.setattr(imageio, "png_writer", failing_png_writer)


def test_interrupted_save_keeps_previous_files_whole(cli, tmp_path, monkeypatch):
    """The EXR, PNG and JSON are replaced as a set: an interrupt while one is written changes none."""
    out = tmp_path / "x.exr"
    _render(cli, out, "--seed", "1")
    before = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}
    _interrupt_png_write(monkeypatch, KeyboardInterrupt())
    code, _, err = cli("render", SCENE, *TINY, "--seed", "2", "-o", out)
    assert code == 130 and "interrupted" in err and "Traceback" not in err
    assert _leftovers(tmp_path) == []
    after = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}
    assert after == before


def test_failed_exr_write_leaves_previous_file_and_no_temporary(cli, tmp_path, monkeypatch):
    out = tmp_path / "x.exr"
    _render(cli, out, "--seed", "1")
    before = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}

    def failing_exr_writer(image):
        def writer(tmp):
            tmp.write_bytes(b"v/1\x01 half an EXR")
            raise OSError(28, "No space left on device")
        return writer

    monkeypatch.setattr(imageio, "exr_writer", failing_exr_writer)
    code, _, err = cli("render", SCENE, *TINY, "--seed", "2", "-o", out)
    assert code == 2 and "No space left on device" in _one_line_error(err)
    assert _leftovers(tmp_path) == []
    after = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}
    assert after == before


# ----------------------------------------------------------------------------- outputs: inputs, folders, devices


def _no_render(monkeypatch):
    """Make rendering fail loudly, to show that a refusal came before it."""
    def must_not_render(*a, **k):
        raise AssertionError("rendered although the output was refused")
    from caustica import driver, photon_view
    monkeypatch.setattr(driver, "run", must_not_render)  # every method's passes run here
    monkeypatch.setattr(photon_view, "photon_picture", must_not_render)


def test_render_refuses_to_write_over_its_scene_file(cli, tmp_path, monkeypatch):
    """A scene file named s.exr and -o s.exr: the scene used to be destroyed."""
    scene = tmp_path / "s.exr"
    scene.write_text(MINIMAL_XML)
    _no_render(monkeypatch)
    for out in (scene, tmp_path / "s.png", tmp_path / "s"):  # every name of the set is the scene's
        code, _, err = cli("render", scene, *TINY, "-o", out)
        assert code == 2
        assert "input" in _one_line_error(err) and "s.exr" in err
    (tmp_path / "link.exr").symlink_to(scene)
    code, _, err = cli("render", scene, *TINY, "-o", tmp_path / "link.exr")
    assert code == 2 and "input" in _one_line_error(err)
    assert scene.read_text() == MINIMAL_XML
    assert _files(tmp_path) == ["link.exr", "s.exr"]


def test_render_refuses_to_write_over_a_mesh_the_scene_loads(cli, tmp_path, monkeypatch):
    (tmp_path / "tri.png").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # an OBJ, oddly named
    xml = tmp_path / "m.xml"
    xml.write_text(MINIMAL_XML.replace('<shape type="rectangle">',
                                       '<shape type="obj"><string name="filename" value="tri.png"/>'))
    _no_render(monkeypatch)
    code, _, err = cli("render", xml, *TINY, "-o", tmp_path / "tri.exr")
    assert code == 2 and "tri.png" in _one_line_error(err)
    assert (tmp_path / "tri.png").read_text().startswith("v 0 0 0")
    code, _, err = cli("photons", xml, *TINY, "--method", "pm", *SMALL["pm"], "-o", tmp_path / "tri.png")
    assert code == 2 and "input" in _one_line_error(err)
    assert _files(tmp_path) == ["m.xml", "tri.png"]


def test_output_into_a_folder_uses_the_default_name_and_says_so(cli, tmp_path):
    folder = tmp_path / "existing"
    folder.mkdir()
    code, out, err = cli("render", SCENE, "--res", "8", "--spp", "1", "-o", folder)
    assert code == 0 and "Traceback" not in err
    assert "is a folder" in err and f"{SCENE}_pt.exr" in err
    assert _files(folder) == [f"{SCENE}_pt.{ext}" for ext in ("exr", "json", "png")]
    code, _, err = cli("render", SCENE, *TINY, "-o", f"{tmp_path / 'new'}{os.sep}")
    assert code == 0, err
    assert _files(tmp_path / "new") == [f"{SCENE}_pt.{ext}" for ext in ("exr", "json", "png")]
    assert not (tmp_path / "new.exr").exists() and not (tmp_path / "existing.exr").exists()


def test_photons_into_a_folder_uses_the_default_name(cli, tmp_path):
    code, _, err = cli("photons", SCENE, *TINY, "--method", "pm", *SMALL["pm"], "-o", tmp_path)
    assert code == 0, err
    assert _files(tmp_path) == [f"{SCENE}_pm_photons.png"]


@pytest.mark.parametrize("command", ["render", "photons"])
def test_output_onto_a_device_is_refused_before_rendering(cli, tmp_path, monkeypatch, command):
    _no_render(monkeypatch)
    code, _, err = cli(command, SCENE, *TINY, "-o", "/dev/null")
    assert code == 2 and "/dev/null" in _one_line_error(err)
    assert not Path("/dev/null.exr").exists() and not Path("/dev/null.png").exists()


def test_a_json_target_that_is_a_folder_is_refused_before_rendering(cli, tmp_path, monkeypatch):
    out = tmp_path / "x.exr"
    _render(cli, out, "--seed", "1")
    before = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png")}
    (tmp_path / "x.json").unlink()
    (tmp_path / "x.json").mkdir()
    _no_render(monkeypatch)
    code, _, err = cli("render", SCENE, *TINY, "--seed", "2", "-o", out)
    assert code == 2 and "x.json" in _one_line_error(err) and "folder" in err
    assert {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png")} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.json", "x.png"]


def test_a_failed_json_rename_keeps_the_previous_set_whole(cli, tmp_path, monkeypatch):
    """The last rename of the set fails: the EXR and PNG already renamed are put back."""
    out = tmp_path / "x.exr"
    _render(cli, out, "--seed", "1")
    before = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}
    real_replace = imageio.os.replace

    def replace(src, dst):
        if Path(dst).name == "x.json":
            raise PermissionError(13, "Permission denied")
        real_replace(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    code, _, err = cli("render", SCENE, *TINY, "--seed", "2", "-o", out)
    assert code == 2 and "x.json" in _one_line_error(err) and "Permission denied" in err
    assert {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.json", "x.png"]


def test_photons_write_failure_is_one_line(cli, tmp_path, monkeypatch):
    def full(tmp):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(imageio, "png_writer", lambda image, exposure_stops=0.0: full)
    code, _, err = cli("photons", SCENE, *TINY, "--method", "pm", *SMALL["pm"], "-o", tmp_path / "p.png")
    assert code == 2 and "No space left on device" in _one_line_error(err)
    assert _files(tmp_path) == []


@pytest.mark.parametrize("exc", [RuntimeError('Failed to write pixel data to image file "{tmp}". '
                                              'No space left on device.'), OSError(28, "No space left on device")],
                         ids=["openexr-runtime-error", "oserror"])
def test_full_disk_is_one_line_and_keeps_the_previous_set(cli, tmp_path, monkeypatch, full_disk_exr, exc):
    """OpenEXR reports a full disk as RuntimeError (only OSError used to be caught: a traceback)."""
    out = tmp_path / "x.exr"
    _render(cli, out, "--seed", "1")
    before = {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")}
    full_disk_exr(lambda name: type(exc)(*[str(a).replace("{tmp}", name) for a in exc.args])
                  if isinstance(exc, RuntimeError) else exc)
    code, _, err = cli("render", SCENE, *TINY, "--seed", "2", "-o", out)
    monkeypatch.undo()
    assert code == 2 and "No space left on device" in _one_line_error(err)
    assert ".tmp" not in err  # the message names the output, not a temporary
    assert {name: (tmp_path / name).read_bytes() for name in ("x.exr", "x.png", "x.json")} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.json", "x.png"]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e6", "-151"])
def test_bad_exposure_is_refused_before_rendering(cli, tmp_path, monkeypatch, value):
    """--exposure nan wrote a black PNG and null in the JSON; 1e6 raised OverflowError."""
    _no_render(monkeypatch)
    code, _, err = cli("render", SCENE, *TINY, f"--exposure={value}", "-o", tmp_path / "x.exr")
    assert code == 2
    line = _one_line_error(err)
    assert "--exposure" in line and "-150" in line and "150" in line
    assert _files(tmp_path) == []


def test_exposure_at_the_limit_is_accepted(cli, tmp_path):
    stats = _render(cli, tmp_path / "x.exr", "--exposure", "150")
    assert stats["preview_exposure_stops"] == 150.0
    from PIL import Image
    with Image.open(tmp_path / "x.png") as im:
        assert np.asarray(im).max() == 255


# ----------------------------------------------------------------------------- compare


def _exr(path: Path, image) -> Path:
    imageio.write_exr(path, np.asarray(image, np.float32))
    return path


def test_compare_refuses_images_with_non_finite_pixels(cli, tmp_path):
    """An all-NaN image used to be scored exactly like an all-black one."""
    ref = _exr(tmp_path / "ref.exr", np.full((8, 8, 3), 0.5))
    nan = _exr(tmp_path / "nan.exr", np.full((8, 8, 3), np.nan))
    one_inf = np.full((8, 8, 3), 0.5)
    one_inf[2, 5, 1] = np.inf
    inf = _exr(tmp_path / "inf.exr", one_inf)
    code, out, err = cli("compare", nan, ref, "--no-flip")
    assert code == 2 and out == ""
    assert "nan.exr" in _one_line_error(err) and "64 of 64" in err and "not finite" in err
    code, _, err = cli("compare", ref, inf, "--no-flip")
    assert code == 2 and "inf.exr" in _one_line_error(err) and "x=5, y=2" in err


def test_compare_explains_a_zero_reference(cli, tmp_path):
    zero = _exr(tmp_path / "zero.exr", np.zeros((8, 8, 3)))
    test = _exr(tmp_path / "t.exr", np.full((8, 8, 3), 0.5))
    code, out, err = cli("compare", test, zero, "--no-flip")
    assert code == 0 and err == ""
    notes = [line for line in out.splitlines() if line.startswith("note:")]
    assert len(notes) == 2 and "block err" in notes[0] and "mean err" in notes[1]   # the two relative errors
    assert all("reference is zero" in note for note in notes)
    code, out, _ = cli("compare", zero, zero, "--no-flip")
    assert code == 0 and "note:" not in out  # equal images: every error is 0, even against zero
    assert out.splitlines()[1].split()[1:3] == ["0", "0"]


def test_compare_flip_against_a_black_reference_is_explained_not_fatal(tmp_path):
    """FLIP ends the whole process (exit 255) on a black reference; run it in a subprocess to see."""
    zero = _exr(tmp_path / "zero.exr", np.zeros((8, 8, 3)))
    test = _exr(tmp_path / "t.exr", np.full((8, 8, 3), 0.5))
    proc = subprocess.run([sys.executable, "-m", "caustica", "compare", str(test), str(zero)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "note: FLIP over the whole image is nan" in proc.stdout and "exposure" in proc.stdout


def test_compare_unreadable_files_are_one_line(cli, tmp_path):
    good = _exr(tmp_path / "a.exr", np.random.default_rng(6).random((8, 8, 3)))
    data = good.read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[: len(data) // 2])
    (tmp_path / "mask.png").write_text("this is not a PNG")
    for args, word in (((tmp_path / "cut.exr", good), "cut.exr"), ((good, tmp_path / "cut.exr"), "cut.exr"),
                       ((good, good, "--mask", tmp_path / "mask.png"), "mask.png")):
        code, out, err = cli("compare", *args, "--no-flip")
        assert code == 2 and out == ""
        assert word in _one_line_error(err)


def _read_available(fd: int, seconds: float) -> bytes:
    """What a pseudo-terminal's master has to read within ``seconds`` (b"" once the other end is closed)."""
    r, _, _ = select.select([fd], [], [], seconds)
    if not r:
        return b""
    try:
        return os.read(fd, 65536)
    except OSError:   # EIO: every process holding the terminal has exited
        return b""


@pytest.mark.skipif(os.name != "posix", reason="needs a pseudo-terminal and POSIX signals")
@pytest.mark.parametrize("threads", ["1", "2"])
def test_ctrl_c_stops_a_render_within_seconds_and_keeps_the_outputs(tmp_path, threads):
    """SIGINT to a real ``caustica render`` while its camera pass runs: exit 130 at once, old outputs intact.

    The render (32x32, 8192 spp) would take far longer than the allowance.  The test waits
    for the progress bar, drawn on a pseudo-terminal, to count at least two pixels done:
    then the kernels are compiled and the worker threads are busy.
    """
    import fcntl
    import pty
    import struct
    import termios

    out = tmp_path / "x.exr"
    before = {name: f"the previous {name}".encode() for name in ("x.exr", "x.png", "x.json")}
    for name, data in before.items():
        (tmp_path / name).write_bytes(data)
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))   # tqdm needs a width
    proc = subprocess.Popen([sys.executable, "-m", "caustica", "render", SCENE, "--res", "32", "--spp", "8192",
                             "--threads", threads, "-o", str(out)],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave,
                            # a suite started in the background has SIGINT ignored, and a child inherits
                            # that; a terminal's Ctrl-C reaches a render with the default disposition
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    os.close(slave)
    try:
        seen = b""
        deadline = time.monotonic() + 600   # a cold kernel cache compiles first
        while time.monotonic() < deadline and proc.poll() is None:
            seen += _read_available(master, 0.5)
            done = re.findall(rb"camera pass.*?\| *(\d+)/1024 \[", seen)
            if done and int(done[-1]) >= 2:
                break
        assert proc.poll() is None, seen.decode(errors="replace")
        assert done and int(done[-1]) >= 2, seen.decode(errors="replace")
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=120)
        stopped_s = time.monotonic() - t0
        while chunk := _read_available(master, 0.2):
            seen += chunk
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    err = seen.decode(errors="replace")
    assert code == 130, err
    assert stopped_s < 5.0, f"took {stopped_s:.1f} s to stop"
    assert "interrupted" in err and "Traceback" not in err
    assert proc.stdout.read() == b""
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(before)   # no temporary left either
    assert {name: (tmp_path / name).read_bytes() for name in before} == before



# ----------------------------------------------------------------------------- experiment: nothing before checks


@pytest.mark.parametrize("args, words", [
    (("--res", "100000"), ("--res", "<= 46,340")),
    (("--res", "40000"), ("40000x40000", "GB")),
    (("--threads", "0"), ("--threads", ">= 1")),
    (("--seed", str(2**40)), ("--seed",)),
    (("--repeat", "1000"), ("--repeat", "<= 100")),
    (("--seeds", "1000"), ("--seeds", "<= 100")),
    (("--reference-spp", str(2**30)), ("--reference-spp",)),
    (("--light-samples", "65"), ("--light-samples", "<= 64")),
    # fits at the paper's budget, but the budget sweep doubles it (x2 with --quick)
    (("--photons", "2000000000"), ("table2 would render PM x2", "--photons")),
    (("--k", "2000000000", "--threads", "64"), ("--k", "GB")),
    (("--max-bounces", "1025"), ("--max-bounces", "<= 1,024")),
])
def test_experiment_refuses_bad_settings_before_creating_anything(cli, tmp_path, monkeypatch, args, words):
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 16 * 2**30)   # the same verdicts anywhere
    out = tmp_path / "exp"
    code, _, err = cli("experiment", "table2", "--quick", "-q", "-o", out, "--cache-dir", tmp_path / "cache", *args)
    assert code == 2
    line = _one_line_error(err)
    for word in words:
        assert word in line, (word, line)
    assert _files(tmp_path) == [] and not out.exists() and not (tmp_path / "cache").exists()


@pytest.mark.parametrize("name", ["table2", "merge-ablation", "convergence"])
def test_experiment_with_an_unwritable_cache_dir_renders_nothing(cli, tmp_path, name):
    (tmp_path / "afile").write_text("not a folder")
    out = tmp_path / "exp"
    code, _, err = cli("experiment", name, "--quick", "-q", "-o", out, "--threads", "1", "--res", "40",
                       "--cache-dir", tmp_path / "afile" / "cache")
    assert code == 2
    line = _one_line_error(err)
    assert "reference cache" in line and "afile" in line
    assert not out.exists()
    assert _files(tmp_path) == ["afile"]


def test_experiment_with_a_reference_of_the_wrong_size_renders_nothing(cli, tmp_path):
    imageio.write_exr(tmp_path / "ref.exr", np.ones((16, 16, 3), np.float32))
    out = tmp_path / "exp"
    code, _, err = cli("experiment", "table2", "--quick", "-q", "-o", out,
                       "--reference", f"cornell-diacaustic={tmp_path / 'ref.exr'}")
    assert code == 2
    assert "--res 16" in _one_line_error(err)
    assert not out.exists()
