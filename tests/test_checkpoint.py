"""Checkpoints as input from disk, their lock, and interrupts (Ctrl-C, SIGTERM) around saves (issue 19).

A checkpoint is read back by a later run, so everything in it is checked: a file that is empty,
cut short, not an .npz, holds pickles, has a damaged header, does not match its own hash, or
whose arrays have other dtypes, shapes or values than a render writes, is refused in one line
(exit 2) and left as it was.  Two renders given the same checkpoint at once: the second is
refused, and a crashed render leaves no lock behind.  Ctrl-C or SIGTERM while a checkpoint is
being written is held until it is complete; SIGTERM is handled as Ctrl-C, with exit status 143.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import caustica
from caustica import checkpoint, driver, interrupts
from caustica.errors import CausticaError, InterruptedAfterSaving, ParameterError
from caustica.scene import builtin_scene_path

SCENE = "cornell-diacaustic"
KW = dict(res=8, seed=2)
SCENE_XML = """<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
    <emitter type="point"><point name="position" value="0, 0, 3"/><rgb name="intensity" value="INTENSITY"/></emitter>
</scene>
"""


@pytest.fixture(scope="module")
def diacaustic():
    return caustica.load_scene(builtin_scene_path(SCENE))


@pytest.fixture(scope="module")
def saved(diacaustic, tmp_path_factory):
    """Checkpoints of 3 passes: sppm's pixel statistics and pt's film."""
    folder = tmp_path_factory.mktemp("saved")
    out = {}
    for method in ("sppm", "pt"):
        out[method] = folder / f"{method}.npz"
        caustica.render(diacaustic, method, passes=3, checkpoint=out[method], **KW)
    return out


def _cli_one_line(cli, *args):
    code, out, err = cli(*[str(a) for a in args])
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return code, lines[0]


def _rewrite(src: Path, dst: Path, *, header=None, arrays=None, rehash=False) -> None:
    """Copy checkpoint ``src`` to ``dst`` with its header and arrays changed by the functions given."""
    with np.load(src) as data:
        d = {k: data[k] for k in data.files}
    head = json.loads(bytes(d.pop("_header")).decode())
    if header is not None:
        head = header(head)
    if arrays is not None:
        arrays(d)
    if rehash:   # a forged checkpoint: the hash recomputed over the edited content
        head["content_hash"] = checkpoint.content_hash(head, d)
    text = head if isinstance(head, str) else json.dumps(head)
    np.savez(dst, _header=np.frombuffer(text.encode(), np.uint8), **d)


def _set(name, index, value, dtype=None):
    def edit(d):
        a = d[name].astype(dtype or d[name].dtype)
        a.reshape(-1)[index] = value
        d[name] = a
    return edit


# --------------------------------------------------------------------------- damaged and tampered checkpoints

DAMAGED = {
    "empty": (lambda src, dst: dst.write_bytes(b""), "is empty (0 bytes)"),
    "cut short": (lambda src, dst: dst.write_bytes(src.read_bytes()[:len(src.read_bytes()) // 2]),
                  "not a readable caustica checkpoint"),
    "text": (lambda src, dst: dst.write_bytes(b"not a checkpoint"), "not an .npz archive"),
    "npy": (lambda src, dst: np.save(open(dst, "wb"), np.zeros(3)), "not an .npz archive"),
    "foreign npz": (lambda src, dst: np.savez(dst, a=np.zeros(3)), "without a caustica header"),
    "pickle": (lambda src, dst: np.savez(dst, _header=np.zeros(1, np.uint8), tau=np.array([{}], dtype=object)),
               "never loads"),
    "value edited": (lambda src, dst: _rewrite(src, dst, arrays=_set("tau", 0, np.nan)), "content does not match"),
    "dtype edited": (lambda src, dst: _rewrite(src, dst, arrays=lambda d: d.update(radius=d["radius"].astype(
        np.float32))), "content does not match"),
    "header not json": (lambda src, dst: _rewrite(src, dst, header=lambda h: "{not json"), "header is damaged"),
    "settings a list": (lambda src, dst: _rewrite(src, dst, header=lambda h: dict(h, settings=[1, 2])),
                        "settings is a list, not an object"),
    "passes a string": (lambda src, dst: _rewrite(src, dst, header=lambda h: dict(h, passes="3")),
                        "passes is a string, not an integer"),
    "no hash": (lambda src, dst: _rewrite(src, dst, header=lambda h: {k: v for k, v in h.items()
                                                                         if k != "content_hash"}),
                "content_hash is missing"),
    "format 1": (lambda src, dst: _rewrite(src, dst, header=lambda h: dict(h, format=1)), "format 1"),
    "forged NaN": (lambda src, dst: _rewrite(src, dst, arrays=_set("tau", 0, np.nan), rehash=True),
                   "NaN or infinite"),
    "forged radius 0": (lambda src, dst: _rewrite(src, dst, arrays=_set("radius", 5, 0.0), rehash=True),
                        "radius has values out of range"),
    "forged negative count": (lambda src, dst: _rewrite(src, dst, arrays=_set("gathered", 1, -4.0), rehash=True),
                              "gathered has values out of range"),
    "forged float32": (lambda src, dst: _rewrite(src, dst, arrays=lambda d: d.update(
        radius=d["radius"].astype(np.float32)), rehash=True), "float32, a checkpoint holds only float64"),
    "forged int tau": (lambda src, dst: _rewrite(src, dst, arrays=lambda d: d.update(
        tau=d["tau"].astype(np.int64)), rehash=True), "tau is int64"),
    "forged shape": (lambda src, dst: _rewrite(src, dst, arrays=lambda d: d.update(radius=d["radius"][:-1]),
                                              rehash=True), "radius is float64 of shape (63,)"),
    "forged passes": (lambda src, dst: _rewrite(src, dst, header=lambda h: dict(h, passes=4), rehash=True),
                      "header says 4 passes"),
}


@pytest.mark.parametrize("case", sorted(DAMAGED))
def test_a_damaged_or_tampered_checkpoint_is_refused_in_one_line(diacaustic, saved, tmp_path, case):
    make, words = DAMAGED[case]
    ck = tmp_path / "state.npz"
    make(saved["sppm"], ck)
    before = ck.read_bytes()
    with pytest.raises(ParameterError) as info:
        caustica.render(diacaustic, "sppm", passes=5, checkpoint=ck, **KW)
    msg = str(info.value)
    assert words in msg and "\n" not in msg and "allow_pickle" not in msg, msg
    assert ck.read_bytes() == before     # left as it was


@pytest.mark.parametrize("case, make, words", [
    ("block float32", lambda d: d.update(film_block_0=d["film_block_0"].astype(np.float32)), "float32"),
    ("block shape", lambda d: d.update(film_block_0=d["film_block_0"][:4]), "film_block_0 is float64 of shape"),
    ("range negative", _set("film_range", 0, -1), "film_range has values out of range"),
    ("block NaN", _set("film_block_0", 7, np.inf), "NaN or infinite"),
])
def test_a_forged_film_checkpoint_is_refused(diacaustic, saved, tmp_path, case, make, words):
    ck = tmp_path / "state.npz"
    _rewrite(saved["pt"], ck, arrays=make, rehash=True)
    with pytest.raises(ParameterError, match=words):
        caustica.render(diacaustic, "pt", passes=5, checkpoint=ck, **KW)


def test_cli_zero_byte_and_tampered_checkpoints_are_one_line_exit_2_nothing_written(cli, saved, tmp_path):
    for case in ("empty", "settings a list", "value edited"):
        ck = tmp_path / f"{case}.npz"
        DAMAGED[case][0](saved["sppm"], ck)
        code, line = _cli_one_line(cli, "render", SCENE, "--method", "sppm", "--res", "8", "--seed", "2",
                                   "--passes", "5", "--checkpoint", ck, "-o", tmp_path / "out" / "x.exr", "-q")
        assert code == 2 and line.startswith(f"caustica: error: --checkpoint {ck}: "), line
    assert not (tmp_path / "out").exists()


def test_a_checkpoint_of_another_method_or_setting_names_the_real_values(diacaustic, saved, tmp_path):
    ck = tmp_path / "state.npz"
    ck.write_bytes(saved["sppm"].read_bytes())
    with pytest.raises(ParameterError, match="written by method sppm, this render is pspm"):
        caustica.render(diacaustic, "pspm", passes=5, checkpoint=ck, **KW)
    # an automatic setting is shown with the value it took, never as "None"
    with pytest.raises(ParameterError) as info:
        caustica.render(diacaustic, "sppm", passes=5, checkpoint=ck, radius=0.5, **KW)
    msg = str(info.value)
    assert "None" not in msg and "--radius auto (0.34641)" in msg and "this render has 0.5" in msg, msg
    with pytest.raises(ParameterError, match="written with --seed 2, this render has 3"):
        caustica.render(diacaustic, "sppm", passes=5, checkpoint=ck, res=8, seed=3)


def test_a_changed_scene_is_named_with_what_changed(tmp_path):
    xml = tmp_path / "box.xml"
    xml.write_text(SCENE_XML.replace("INTENSITY", "10"))
    ck = tmp_path / "state.npz"
    caustica.render(str(xml), "pt", passes=2, checkpoint=ck, res=8)
    xml.write_text(SCENE_XML.replace("INTENSITY", "20"))
    with pytest.raises(ParameterError) as info:
        caustica.render(str(xml), "pt", passes=3, checkpoint=ck, res=8)
    msg = str(info.value)
    assert "its lights differ" in msg and "geometry" not in msg and f"{xml} changed since" in msg, msg
    # the same file, another -D value: no file changed, and the message says so
    xml.write_text(SCENE_XML.replace("INTENSITY", "$i"))
    ck.unlink()
    caustica.render(caustica.load_scene(str(xml), i=10), "pt", passes=2, checkpoint=ck, res=8)
    with pytest.raises(ParameterError, match="its lights differ.*no scene file changed"):
        caustica.render(caustica.load_scene(str(xml), i=30), "pt", passes=3, checkpoint=ck, res=8)


# --------------------------------------------------------------------------- the lock

def test_a_second_render_with_the_same_checkpoint_is_refused(diacaustic, tmp_path):
    ck = tmp_path / "state.npz"
    with checkpoint.locked(ck):   # a render that is using it
        with pytest.raises(ParameterError, match="another render is using it .process"):
            caustica.render(diacaustic, "sppm", passes=2, checkpoint=ck, **KW)
        assert not ck.exists()
    r = caustica.render(diacaustic, "sppm", passes=2, checkpoint=ck, **KW)   # free again
    assert r.stats["passes"] == 2 and ck.is_file()


@pytest.mark.skipif(os.name != "posix", reason="POSIX file locks and signals")
def test_a_killed_render_leaves_no_lock_behind(diacaustic, tmp_path):
    ck = tmp_path / "state.npz"
    code = ("import sys, time; from caustica import checkpoint\n"
            "with checkpoint.locked(sys.argv[1]):\n    print('locked', flush=True); time.sleep(600)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen([sys.executable, "-c", code, str(ck)], stdout=subprocess.PIPE, env=env)
    try:
        assert proc.stdout.readline() == b"locked\n"
        with pytest.raises(ParameterError, match=f"process {proc.pid} on"):
            caustica.render(diacaustic, "sppm", passes=2, checkpoint=ck, **KW)
    finally:
        proc.kill()
        proc.wait()
    assert caustica.render(diacaustic, "sppm", passes=2, checkpoint=ck, **KW).stats["passes"] == 2


# --------------------------------------------------------------------------- interrupts during saves

@pytest.fixture
def python_handles_ctrl_c():
    """Python's own Ctrl-C handler, also when the suite runs in the background (SIGINT ignored there)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _signal_during_save(monkeypatch, signum, when):
    """Send ``signum`` to this process while the checkpoint holding ``when(passes)`` passes is being written."""
    real = np.savez

    def savez(fh, **arrays):
        if when(int(arrays["passes"]) if "passes" in arrays else int(arrays["film_range"][1])):
            os.kill(os.getpid(), signum)
        return real(fh, **arrays)
    monkeypatch.setattr(checkpoint.np, "savez", savez)


def test_ctrl_c_while_the_final_checkpoint_is_written_keeps_every_pass(cli, diacaustic, tmp_path, monkeypatch,
                                                                       python_handles_ctrl_c):
    ck = tmp_path / "state.npz"
    _signal_during_save(monkeypatch, signal.SIGINT, lambda passes: passes == 4)
    code, out, err = cli("render", SCENE, "--method", "sppm", "--res", "8", "--seed", "2", "--passes", "4",
                         "--checkpoint", ck, "-o", tmp_path / "x.exr", "-q")
    assert code == 130 and "4 passes" in err and "Traceback" not in err, err
    assert json.loads((tmp_path / "x.json").read_text())["passes"] == 4     # the outputs were written too
    monkeypatch.undo()
    whole = caustica.render(diacaustic, "sppm", passes=4, **KW)
    assert caustica.render(diacaustic, "sppm", passes=4, checkpoint=ck, **KW).stats["resumed_from_pass"] == 4
    assert (tmp_path / "x.exr").is_file()
    assert np.array_equal(caustica.imageio.read_exr(tmp_path / "x.exr"), whole.image)


def test_an_interrupt_during_a_periodic_save_stops_after_it_without_saving_twice(diacaustic, tmp_path, monkeypatch,
                                                                                 python_handles_ctrl_c):
    ck = tmp_path / "state.npz"
    saves = []
    real = checkpoint.save
    monkeypatch.setattr(driver, "CHECKPOINT_INTERVAL_S", 0.0)    # a save after every pass
    monkeypatch.setattr(checkpoint, "save", lambda *a: saves.append(a[-1].passes) or real(*a))
    _signal_during_save(monkeypatch, signal.SIGINT, lambda passes: passes == 2)
    r = caustica.render(diacaustic, "sppm", passes=9, checkpoint=ck, **KW)
    assert r.stats["interrupted"] and r.stats["passes"] == 2 and saves == [1, 2]
    assert r.stats["interrupted_by"] == "SIGINT"


def test_no_checkpoint_is_written_until_a_pass_is_merged(diacaustic, tmp_path, monkeypatch):
    """A cluster's first task back can be pass 1 while pass 0 is still out: nothing is merged yet, and no
    checkpoint is written (one of none was written, and Ctrl-C just after it rightly kept no image, which the
    cluster's Ctrl-C test read as a hang or a lost pass; 2026-12-03).  An executor that gives back nothing merged
    first, then the pass, stands in for the cluster."""
    scene, cls, settings = caustica.api.resolve_settings(diacaustic, "sppm", multi_pass=True, **KW)
    plan = driver.check_plan(cls, passes=1, checkpoint=tmp_path / "state.npz")
    monkeypatch.setattr(driver, "CHECKPOINT_INTERVAL_S", 0.0)    # a save whenever one is due
    saves = []
    real = checkpoint.save
    monkeypatch.setattr(checkpoint, "save", lambda *a: saves.append(a[-1].passes) or real(*a))

    class PassOneFirst(driver.LocalPasses):
        held_back = True

        def collect(self, state, late_after):
            if self.sent and self.held_back:   # a later pass came back: nothing to merge yet
                self.held_back = False
                return state, [], 0.0
            return super().collect(state, late_after)

    state, log = driver.run(cls, scene, settings, plan, driver.QuietBar,
                            PassOneFirst(cls, scene, settings, driver.QuietBar))
    assert state.passes == 1 and saves == [1] and log.checkpoint_passes == 1


def test_sigterm_is_handled_as_ctrl_c_with_exit_143(cli, tmp_path, interrupt_at_pass):
    interrupt_at_pass("sppm", 2, interrupts.Terminated)   # what the CLI's SIGTERM handler raises
    ck = tmp_path / "state.npz"
    code, _, err = cli("render", SCENE, "--method", "sppm", "--res", "8", "--passes", "9", "--checkpoint", ck,
                       "-o", tmp_path / "x.exr", "-q")
    assert code == 143 and "SIGTERM" in err and "2 passes" in err, err
    meta = json.loads((tmp_path / "x.json").read_text())
    assert meta["interrupted"] and meta["interrupted_by"] == "SIGTERM" and meta["passes"] == 2
    with np.load(ck) as data:
        assert int(data["passes"]) == 2


def test_the_cli_installs_its_sigterm_handler_only_while_it_runs(cli):
    before = signal.getsignal(signal.SIGTERM)
    assert cli("methods")[0] == 0
    assert signal.getsignal(signal.SIGTERM) is before


def test_sigterm_held_during_a_save_ends_with_143_after_it(cli, tmp_path, monkeypatch):
    """SIGTERM while the outputs are renamed into place: the set is completed, then exit 143."""
    import caustica.imageio as imageio
    real = imageio.os.replace
    sent = []

    def replace(src, dst):
        if not sent:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGTERM)
        real(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    code, _, err = cli("render", SCENE, "--method", "pt", "--res", "8", "--spp", "1", "-o", tmp_path / "x.exr", "-q")
    assert code == 143 and "SIGTERM" in err and "the outputs had been written in full" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.json", "x.png"]


@pytest.mark.skipif(os.name != "posix", reason="POSIX signals")
def test_a_real_sigterm_writes_the_checkpoint_and_outputs_and_exits_143(tmp_path):
    """SIGTERM (Slurm, Kubernetes) to a real ``caustica render``: the passes finished are kept, exit 143."""
    ck, out = tmp_path / "state.npz", tmp_path / "x.exr"
    proc = subprocess.Popen([sys.executable, "-m", "caustica", "render", SCENE, "--method", "sppm", "--res", "16",
                             "--passes", "1000000", "--checkpoint", str(ck), "-o", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 600   # a cold kernel cache compiles first
        while not ck.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)
        assert ck.exists(), proc.stderr.read().decode() if proc.poll() is not None else "no checkpoint"
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read().decode()
    assert code == 143 and "SIGTERM" in err and "Traceback" not in err, err
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["interrupted_by"] == "SIGTERM"
    with np.load(ck) as data:
        assert int(data["passes"]) == meta["passes"] > 0


def test_interrupts_held_hands_on_what_arrived(python_handles_ctrl_c):
    with interrupts.held() as pending:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.01)
    assert pending == [signal.SIGINT]
    with pytest.raises(InterruptedAfterSaving) as info:
        interrupts.raise_held(pending, "the checkpoint x")
    assert info.value.signum == signal.SIGINT and info.value.saved == "the checkpoint x"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# --------------------------------------------------------------------------- further hostile paths

@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_checkpoint_that_is_a_fifo_or_a_device_is_refused_before_anything_opens_it(diacaustic, tmp_path):
    """From Python a FIFO used to reach np.load, which blocked forever waiting for a writer."""
    fifo = tmp_path / "state.npz"
    os.mkfifo(fifo)
    with pytest.raises(CausticaError, match="not a regular file"):
        caustica.render(diacaustic, "sppm", passes=2, checkpoint=fifo, **KW)
    (tmp_path / "null.npz").symlink_to(os.devnull)
    with pytest.raises(CausticaError, match="not a regular file"):
        caustica.render(diacaustic, "sppm", passes=2, checkpoint=tmp_path / "null.npz", **KW)


def test_a_checkpoint_that_is_a_dangling_link_says_so(diacaustic, tmp_path):
    (tmp_path / "state.npz").symlink_to(tmp_path / "gone" / "state.npz")
    with pytest.raises(ParameterError, match="symbolic link to .*gone.*which does not exist"):
        caustica.render(diacaustic, "sppm", passes=2, checkpoint=tmp_path / "state.npz", **KW)


def test_a_lock_file_that_cannot_be_opened_is_one_line(diacaustic, tmp_path):
    (tmp_path / ".state.npz.lock").mkdir()
    with pytest.raises(ParameterError, match="cannot create its lock file"):
        caustica.render(diacaustic, "sppm", passes=2, checkpoint=tmp_path / "state.npz", **KW)


def test_a_checkpoint_that_is_also_an_aov_output_is_refused(cli, tmp_path):
    code, line = _cli_one_line(cli, "render", SCENE, "--method", "sppm", "--res", "8", "--passes", "2", "--aov",
                               "radius", "-o", tmp_path / "x.exr", "--checkpoint", tmp_path / "x.radius.exr", "-q")
    assert code == 2 and "is also an output of this render" in line
    assert list(tmp_path.iterdir()) == []


def test_resuming_a_complete_checkpoint_does_not_rewrite_it(diacaustic, saved, tmp_path):
    ck = tmp_path / "state.npz"
    ck.write_bytes(saved["sppm"].read_bytes())
    os.utime(ck, (0, 0))
    r = caustica.render(diacaustic, "sppm", passes=3, checkpoint=ck, **KW)
    assert r.stats["passes_this_run"] == 0 and ck.stat().st_mtime == 0
