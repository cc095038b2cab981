"""Output layer: EXR/PNG/JSON writers, atomicity, output names and RenderResult."""
from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

from caustica import __version__, imageio
from caustica.errors import ParameterError
from caustica.result import RenderResult, peak_memory_bytes

REFS = Path(__file__).resolve().parents[2] / "shared" / "refs"


def _srgb_formula(c: float) -> int:
    v = 12.92 * c if c <= 0.0031308 else 1.055 * c ** (1 / 2.4) - 0.055
    return int(np.floor(v * 255 + 0.5))


def _leftovers(directory: Path) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.endswith((".tmp", ".old"))]  # temporaries, backups


# ----------------------------------------------------------------------------- EXR


def test_exr_round_trip_is_bit_exact(tmp_path):
    rng = np.random.default_rng(1)
    img = (rng.standard_normal((17, 23, 3)) * 1e3).astype(np.float32)
    img[0, 0] = [0.0, 1e-40, 3.4e38]  # denormal and near-max survive float channels
    path = imageio.write_exr(tmp_path / "sub" / "dir" / "a.exr", img)
    assert path == tmp_path / "sub" / "dir" / "a.exr"
    back = imageio.read_exr(path)
    assert back.dtype == np.float32 and back.shape == img.shape
    assert np.array_equal(back.view(np.uint32), img.view(np.uint32))
    assert _leftovers(path.parent) == []


def test_exr_channels_are_float_rgb(tmp_path):
    import OpenEXR

    imageio.write_exr(tmp_path / "a.exr", np.ones((4, 5, 3)))
    with OpenEXR.File(str(tmp_path / "a.exr"), separate_channels=True) as f:
        chans = f.channels()
        assert sorted(chans) == ["B", "G", "R"]
        assert all(ch.pixels.dtype == np.float32 and ch.pixels.shape == (4, 5) for ch in chans.values())


def test_read_exr_missing_file_is_a_user_error(tmp_path):
    from caustica.errors import CausticaError

    with pytest.raises(CausticaError, match="nope.exr"):
        imageio.read_exr(tmp_path / "nope.exr")


@pytest.mark.skipif(not REFS.is_dir(), reason="shared reference renders absent (fresh clone)")
def test_reads_mitsuba_reference_exr():
    img = imageio.read_exr(REFS / "cornell-diacaustic_256.exr")
    assert img.shape == (256, 256, 3) and img.dtype == np.float32
    assert np.isfinite(img).all() and img.min() >= 0 and img.mean() > 0


@pytest.mark.skipif(not REFS.is_dir(), reason="shared reference renders absent (fresh clone)")
def test_reads_reference_caustic_mask():
    masks = sorted(REFS.glob("*_caustic_mask.png"))
    assert masks
    m = imageio.read_png_mask(masks[0])
    assert m.dtype == bool and m.shape == (256, 256)
    assert 0 < m.sum() < m.size


def test_read_png_mask_nonzero_is_inside(tmp_path):
    from PIL import Image

    arr = np.zeros((3, 4), np.uint8)
    arr[1, 2] = 1
    arr[2, 0] = 255
    Image.fromarray(arr).save(tmp_path / "m.png")
    assert np.array_equal(imageio.read_png_mask(tmp_path / "m.png"), arr != 0)
    rgba = np.zeros((3, 4, 4), np.uint8)
    rgba[..., 3] = 255  # opaque alpha alone does not make a pixel inside
    rgba[0, 1, 2] = 7
    Image.fromarray(rgba).save(tmp_path / "c.png")
    expected = np.zeros((3, 4), bool)
    expected[0, 1] = True
    assert np.array_equal(imageio.read_png_mask(tmp_path / "c.png"), expected)


# ----------------------------------------------------------------------------- sRGB


@pytest.mark.parametrize(
    "linear, code",
    [(0.0, 0), (1.0, 255), (0.5, 188), (0.0031308, 10), (2.0, 255), (-1.0, 0), (0.18, 118)],
)
def test_srgb_transfer_values(linear, code):
    assert _srgb_formula(min(max(linear, 0.0), 1.0)) == code  # the table agrees with the formula
    out = imageio.to_srgb8(np.full((1, 1, 3), linear, np.float32))
    assert out.dtype == np.uint8 and out.shape == (1, 1, 3)
    assert (out == code).all()


def test_srgb_is_continuous_at_the_knee():
    knee = 0.0031308
    lo = 12.92 * knee
    hi = 1.055 * knee ** (1 / 2.4) - 0.055
    assert abs(lo - hi) < 1e-6
    vals = np.array([knee * (1 - 1e-6), knee, knee * (1 + 1e-6)], np.float64)
    out = imageio.to_srgb8(np.repeat(vals[None, :, None], 3, axis=2))
    assert (out == 10).all()


def test_srgb_matches_formula_everywhere_and_exposure():
    xs = np.linspace(0, 1, 1001)
    img = np.repeat(xs[None, :, None], 3, axis=2)
    out = imageio.to_srgb8(img)[0, :, 0]
    assert np.array_equal(out, [_srgb_formula(x) for x in xs])
    assert np.all(np.diff(out.astype(int)) >= 0)
    # one stop up doubles linear values before encoding
    assert np.array_equal(imageio.to_srgb8(img / 2, exposure_stops=1.0), imageio.to_srgb8(img))


def test_srgb_nan_and_inf():
    img = np.array([[[np.nan, np.inf, -np.inf]]])
    assert imageio.to_srgb8(img).tolist() == [[[0, 255, 0]]]


def test_write_png_reads_back(tmp_path):
    from PIL import Image

    img = np.random.default_rng(2).random((6, 9, 3)).astype(np.float32)
    imageio.write_png(tmp_path / "p.png", img, exposure_stops=0.5)
    with Image.open(tmp_path / "p.png") as im:
        assert im.mode == "RGB" and im.size == (9, 6)
        assert np.array_equal(np.asarray(im), imageio.to_srgb8(img, 0.5))


# ----------------------------------------------------------------------------- atomicity


class Boom(Exception):
    pass


@pytest.mark.parametrize("exc", [Boom("disk on fire"), KeyboardInterrupt()])
def test_failed_writer_leaves_old_file_and_no_temp(tmp_path, exc):
    dest = tmp_path / "out.json"
    imageio.write_json(dest, {"good": 1})
    before = dest.read_bytes()

    def writer(tmp: Path) -> None:
        tmp.write_bytes(b'{"half": ')  # half-written
        raise exc

    with pytest.raises(type(exc)):
        imageio.atomic_write(dest, writer)
    assert dest.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_failed_writer_with_no_previous_file_leaves_nothing(tmp_path):
    def writer(tmp: Path) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        imageio.atomic_write(tmp_path / "new.exr", writer)
    assert list(tmp_path.iterdir()) == []


def test_interrupted_exr_write_keeps_previous_exr(tmp_path, monkeypatch):
    dest = tmp_path / "img.exr"
    old = np.full((4, 4, 3), 0.25, np.float32)
    imageio.write_exr(dest, old)
    real_replace = imageio.os.replace

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(imageio.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        imageio.write_exr(dest, np.ones((8, 8, 3)))
    monkeypatch.setattr(imageio.os, "replace", real_replace)
    assert np.array_equal(imageio.read_exr(dest), old)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.exr"]


def test_atomic_write_replaces_and_uses_normal_permissions(tmp_path):
    dest = tmp_path / "a.txt"
    imageio.atomic_write(dest, lambda t: t.write_text("one"))
    imageio.atomic_write(dest, lambda t: t.write_text("two"))
    assert dest.read_text() == "two"
    mode = dest.stat().st_mode & 0o777
    assert mode == 0o666 & ~imageio._current_umask(), oct(mode)  # not mkstemp's private 0600


# ----------------------------------------------------------------------------- JSON


def test_write_json_converts_numpy(tmp_path):
    data = {
        "f": np.float32(1.5),
        "i": np.int64(7),
        "b": np.bool_(True),
        "a": np.arange(3, dtype=np.uint16),
        "t": (1, 2.0),
        "nested": {"x": np.array([[1.0, 2.0]])},
        "path": tmp_path / "x.exr",
        "nan": float("nan"),
    }
    imageio.write_json(tmp_path / "d.json", data)
    text = (tmp_path / "d.json").read_text()
    assert "\n  " in text and text.endswith("\n")  # pretty-printed
    back = json.loads(text)
    assert back == {
        "f": 1.5, "i": 7, "b": True, "a": [0, 1, 2], "t": [1, 2.0],
        "nested": {"x": [[1.0, 2.0]]}, "path": str(tmp_path / "x.exr"), "nan": None,
    }


# ----------------------------------------------------------------------------- output names


@pytest.mark.parametrize("given", ["out/name.exr", "out/name.png", "out/name", "out/name.EXR"])
def test_output_paths(given):
    exr, png, js = imageio.output_paths(given)
    assert (exr, png, js) == (Path("out/name.exr"), Path("out/name.png"), Path("out/name.json"))


def test_output_paths_keeps_inner_dots():
    assert imageio.output_paths("r/cornell.v2.exr")[2] == Path("r/cornell.v2.json")


@pytest.mark.parametrize("bad", ["out/name.jpg", "name.json", "a/b.tiff"])
def test_output_paths_rejects_other_suffixes(bad):
    with pytest.raises(ParameterError) as info:
        imageio.output_paths(bad)
    msg = str(info.value)
    assert ".exr" in msg and ".png" in msg and "none" in msg


# ----------------------------------------------------------------------------- RenderResult


def _result() -> RenderResult:
    img = np.random.default_rng(3).random((5, 8, 3)).astype(np.float32)
    stats = {
        "method": "spm",
        "parameters": {"photons": 1000, "radius": np.float64(0.01)},
        "seed": 42,
        "timings": {"scene_load": 0.1, "photon_tracing": np.float64(1.25)},
        "photons_emitted": np.int64(1000),
        "map_memory_bytes": 4096,
        "peak_memory_bytes": peak_memory_bytes(),
    }
    return RenderResult(img, stats)


def test_render_result_fills_version_and_size():
    r = _result()
    assert r.stats["version"] == __version__
    assert (r.stats["width"], r.stats["height"]) == (8, 5)
    with pytest.raises(ValueError):
        RenderResult(np.zeros((4, 4)))


def test_render_result_save_writes_three_files(tmp_path):
    r = _result()
    exr, png, js = r.save(tmp_path / "renders" / "scene.exr", exposure_stops=1.0)
    assert (exr.name, png.name, js.name) == ("scene.exr", "scene.png", "scene.json")
    assert all(p.is_file() for p in (exr, png, js))
    assert np.array_equal(imageio.read_exr(exr), r.image)
    data = json.loads(js.read_text())
    for key in ("method", "seed", "version", "width", "height"):
        assert data[key] == r.stats[key]
    assert data["parameters"] == {"photons": 1000, "radius": 0.01}
    assert data["timings"]["photon_tracing"] == 1.25
    assert data["outputs"] == {"exr": "scene.exr", "png": "scene.png", "json": "scene.json"}
    assert data["preview_exposure_stops"] == 1.0
    assert _leftovers(exr.parent) == []


def test_render_result_save_rejects_bad_suffix_before_writing(tmp_path):
    with pytest.raises(ParameterError):
        _result().save(tmp_path / "x.jpg")
    assert list(tmp_path.iterdir()) == []


def test_repr_png_is_a_valid_png():
    from PIL import Image

    r = _result()
    data = r._repr_png_()
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    with Image.open(io.BytesIO(data)) as im:
        im.load()
        assert im.size == (8, 5)
        assert np.array_equal(np.asarray(im), r.to_srgb8())
    assert "data:image/png;base64," in r._repr_html_()


def test_peak_memory_is_plausible():
    assert 10 * 2**20 < peak_memory_bytes() < 2**44


def test_atomic_write_all_replaces_nothing_when_any_writer_fails(tmp_path):
    paths = [tmp_path / name for name in ("a.bin", "b.bin", "c.bin")]
    for p in paths:
        p.write_bytes(b"old " + p.name.encode())

    def ok(data):
        return lambda tmp: tmp.write_bytes(data)

    def failing(tmp):
        tmp.write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        imageio.atomic_write_all([(paths[0], ok(b"new a")), (paths[1], ok(b"new b")), (paths[2], failing)])
    assert [p.read_bytes() for p in paths] == [b"old a.bin", b"old b.bin", b"old c.bin"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "b.bin", "c.bin"]  # no temporaries

    imageio.atomic_write_all([(p, ok(b"new " + p.name.encode())) for p in paths])
    assert [p.read_bytes() for p in paths] == [b"new a.bin", b"new b.bin", b"new c.bin"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "b.bin", "c.bin"]


# ----------------------------------------------------------------------------- a set, whole or not at all


def _old_set(tmp_path: Path) -> tuple[list[Path], dict[str, bytes]]:
    paths = [tmp_path / name for name in ("r.exr", "r.png", "r.json")]
    for p in paths:
        p.write_bytes(b"old " + p.name.encode())
    return paths, {p.name: p.read_bytes() for p in paths}


def _new(data: bytes):
    return lambda tmp: tmp.write_bytes(data)


@pytest.mark.parametrize("failing", ["r.exr", "r.png", "r.json"])
def test_a_failed_rename_puts_the_whole_previous_set_back(tmp_path, monkeypatch, failing):
    """The JSON (or any) rename fails after the others were done: those are undone, nothing is left."""
    from caustica.errors import OutputError

    paths, before = _old_set(tmp_path)
    real_replace = imageio.os.replace

    def replace(src, dst):
        if Path(dst).name == failing:
            raise PermissionError(13, "Permission denied")
        real_replace(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    with pytest.raises(OutputError, match=f"{failing}.*Permission denied"):
        imageio.atomic_write_all([(p, _new(b"new")) for p in paths])
    assert {p.name: p.read_bytes() for p in paths} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.exr", "r.json", "r.png"]  # no temporary, no backup


def test_a_failed_rename_of_a_new_set_leaves_no_file(tmp_path, monkeypatch):
    from caustica.errors import OutputError

    real_replace = imageio.os.replace

    def replace(src, dst):
        if Path(dst).suffix == ".json":
            raise OSError(5, "Input/output error")
        real_replace(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    with pytest.raises(OutputError):
        imageio.atomic_write_all([(tmp_path / n, _new(b"new")) for n in ("r.exr", "r.png", "r.json")])
    assert list(tmp_path.iterdir()) == []


def test_a_target_that_is_a_folder_is_refused_before_anything_is_written(tmp_path):
    from caustica.errors import OutputError

    paths, before = _old_set(tmp_path)
    paths[2].unlink()
    paths[2].mkdir()  # r.json is a folder
    written = []
    with pytest.raises(OutputError, match="r.json.*folder"):
        imageio.atomic_write_all([(p, lambda tmp: written.append(tmp)) for p in paths])
    assert written == []
    assert [p.read_bytes() for p in paths[:2]] == [before["r.exr"], before["r.png"]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.exr", "r.json", "r.png"]


@pytest.mark.parametrize("how", ["same path", "hard link", "symlink"])
def test_an_output_that_is_an_input_is_refused(tmp_path, how):
    from caustica.errors import OutputError

    scene = tmp_path / "scene.exr"
    scene.write_text("<scene/>")
    target = {"same path": scene, "hard link": tmp_path / "h.exr", "symlink": tmp_path / "l.exr"}[how]
    if how == "hard link":
        os.link(scene, target)
    elif how == "symlink":
        target.symlink_to(scene)
    with pytest.raises(OutputError, match="input"):
        imageio.atomic_write(target, _new(b"image"), inputs=[scene])
    assert scene.read_text() == "<scene/>"
    with pytest.raises(OutputError, match="input"):
        _result().save(tmp_path / "other" / ".." / "scene.exr", inputs=[scene])
    assert scene.read_text() == "<scene/>"
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("given", ["{d}", "{d}/", "{d}/new/", "/dev/null", ""])
def test_output_paths_refuses_folders_and_devices(tmp_path, given):
    """'dir/' would have written dir.exr beside the folder, /dev/null /dev/null.exr."""
    path = given.format(d=tmp_path)
    with pytest.raises(ParameterError, match="folder|no file name|not a regular file"):
        imageio.output_paths(path)
    assert list(tmp_path.iterdir()) == []


def test_save_into_a_device_is_refused(tmp_path):
    from caustica.errors import OutputError

    with pytest.raises(OutputError, match="not a regular file"):
        imageio.atomic_write("/dev/null", _new(b"x"))


def _dead_pid() -> int:
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_temporaries_of_dead_processes_are_removed_on_the_next_save(tmp_path):
    host = imageio._host_tag()
    dead, alive = _dead_pid(), os.getppid()
    stale = [f".r.exr.caustica-{host}-{dead}-abc123.tmp", f".r.exr.caustica-{host}-{dead}-abc123.old"]
    kept = [f".r.exr.caustica-{host}-{alive}-zzz.tmp",        # a save in progress elsewhere
            f".r.exr.caustica-otherhost-{dead}-q.tmp",         # another machine's (a shared folder)
            f".r.png.caustica-{host}-{dead}-abc.tmp",          # another output's
            ".r.exr.x1y2.tmp", "notes.txt"]                    # not ours
    for name in stale + kept:
        (tmp_path / name).write_text("junk")
    imageio.atomic_write(tmp_path / "r.exr", _new(b"new"))
    assert (tmp_path / "r.exr").read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(kept + ["r.exr"])


def test_temporary_of_a_killed_process_is_removed_by_the_next_save(tmp_path):
    """A process SIGKILLed while writing leaves its temporary; the next save of that output removes it."""
    import subprocess
    import sys

    code = ("import os, signal, sys\n"
            "from caustica import imageio\n"
            "def writer(tmp):\n"
            "    tmp.write_bytes(b'half')\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n"
            "imageio.atomic_write(sys.argv[1], writer)\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "r.exr")], env=env, timeout=120)
    assert proc.returncode == -9
    left = [p.name for p in tmp_path.iterdir()]
    assert len(left) == 1 and left[0].startswith(".r.exr.caustica-") and left[0].endswith(".tmp")
    imageio.write_exr(tmp_path / "r.exr", np.ones((2, 2, 3)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.exr"]


def test_ctrl_c_during_the_renames_is_held_until_the_set_is_complete(tmp_path, monkeypatch):
    import signal

    from caustica.errors import InterruptedAfterSaving

    paths, _ = _old_set(tmp_path)
    real_replace = imageio.os.replace

    def replace(src, dst):
        if Path(dst).name == "r.exr":
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C right after the first rename begins
        real_replace(src, dst)

    monkeypatch.setattr(imageio.os, "replace", replace)
    # Python's own Ctrl-C handler, also when the suite runs in the background (SIGINT ignored there)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(InterruptedAfterSaving):
            imageio.atomic_write_all([(p, _new(b"new " + p.name.encode())) for p in paths])
        assert [p.read_bytes() for p in paths] == [b"new r.exr", b"new r.png", b"new r.json"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["r.exr", "r.json", "r.png"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler   # the save put it back
    finally:
        signal.signal(signal.SIGINT, previous)


def test_openexr_runtime_error_becomes_one_output_error_and_keeps_the_old_file(tmp_path, monkeypatch,
                                                                                full_disk_exr):
    """OpenEXR reports a full disk as RuntimeError, not OSError."""
    from caustica.errors import OutputError

    dest = tmp_path / "img.exr"
    old = np.full((2, 2, 3), 0.5, np.float32)
    imageio.write_exr(dest, old)
    full_disk_exr(lambda name: RuntimeError(f'Failed to write pixel data to image file "{name}". '
                                            'No space left on device.'))
    with pytest.raises(OutputError) as info:
        imageio.write_exr(dest, np.ones((4, 4, 3)))
    msg = str(info.value)
    assert "No space left on device" in msg and str(dest) in msg and ".tmp" not in msg
    assert isinstance(info.value, OSError)
    monkeypatch.undo()
    assert np.array_equal(imageio.read_exr(dest), old)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.exr"]


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped elsewhere): a real full disk."""
    import subprocess

    mount = tmp_path / "tiny"
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                                           capture_output=True).returncode != 0:
        pytest.skip("needs root and tmpfs to make a full disk")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


def test_a_real_full_disk_keeps_the_previous_set(tiny_disk):
    from caustica.errors import OutputError

    small = RenderResult(np.full((4, 4, 3), 0.25, np.float32), {"method": "pt"})
    exr, png, js = small.save(tiny_disk / "r.exr")
    before = [p.read_bytes() for p in (exr, png, js)]
    big = RenderResult(np.random.default_rng(4).random((128, 128, 3)).astype(np.float32), {"method": "pt"})
    with pytest.raises(OutputError, match="No space left on device"):
        big.save(tiny_disk / "r.exr")
    assert [p.read_bytes() for p in (exr, png, js)] == before
    assert sorted(p.name for p in tiny_disk.iterdir()) == ["r.exr", "r.json", "r.png"]


# ----------------------------------------------------------------------------- exposure, unreadable inputs


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), 1e6, 150.5, "abc", None, True])
def test_exposure_must_be_finite_and_in_range(tmp_path, bad):
    with pytest.raises(ParameterError, match="--exposure"):
        imageio.to_srgb8(np.ones((1, 1, 3)), bad)
    with pytest.raises(ParameterError, match="--exposure"):
        _result().save(tmp_path / "r.exr", exposure_stops=bad)
    assert list(tmp_path.iterdir()) == []


def test_exposure_limits_are_where_nothing_changes_any_more():
    tiny, huge = np.float32(2.0 ** -149), np.finfo(np.float32).max
    img = np.array([[[tiny, huge, 1.0]]], np.float32)
    assert imageio.to_srgb8(img, 150).tolist() == [[[255, 255, 255]]]
    assert imageio.to_srgb8(img, -150).tolist() == [[[0, 0, 0]]]


def test_truncated_exr_is_one_error_and_prints_nothing(tmp_path, capfd):
    from caustica.errors import CausticaError

    imageio.write_exr(tmp_path / "a.exr", np.random.default_rng(5).random((16, 16, 3)))
    data = (tmp_path / "a.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) // 2])
    capfd.readouterr()
    with pytest.raises(CausticaError, match="t.exr") as info:
        imageio.read_exr(tmp_path / "t.exr")
    assert "\n" not in str(info.value)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # OpenEXR's own lines are caught, not printed around the error


@pytest.mark.parametrize("content", [b"not an image at all", b"\x89PNG\r\n\x1a\n truncated"])
def test_a_mask_that_is_not_an_image_is_one_error(tmp_path, content):
    from caustica.errors import CausticaError

    (tmp_path / "m.png").write_bytes(content)
    with pytest.raises(CausticaError, match="m.png"):
        imageio.read_png_mask(tmp_path / "m.png")
