"""Generic fixtures shared by the test modules: where the shared scenes, reference images and data live.

Nothing here changes global state.  The shared folder (``../../shared`` from this file, the
project's sibling) is not part of a fresh clone, so fixtures that need it skip cleanly when it
is missing.  Environment variables override the locations:

* ``CAUSTICA_SHARED`` — the shared folder (holding ``scenes/``, ``refs/``, ``data/``);
* ``CAUSTICA_REFS``   — the reference images folder itself.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

TESTS_DIR = Path(__file__).resolve().parent


def _shared_dir() -> Path:
    env = os.environ.get("CAUSTICA_SHARED")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared"


def _existing_dir_or_skip(path: Path, what: str) -> Path:
    if not path.is_dir():
        pytest.skip(f"{what} not found at {path}")
    return path


@pytest.fixture(scope="session")
def test_scenes_dir() -> Path:
    """tests/scenes: small XML scenes written for the tests."""
    return TESTS_DIR / "scenes"


@pytest.fixture(scope="session")
def shared_scenes_dir() -> Path:
    """The shared copies of the paper's scenes (skip when missing)."""
    return _existing_dir_or_skip(_shared_dir() / "scenes", "shared scenes folder")


@pytest.fixture(scope="session")
def refs_dir() -> Path:
    """The Mitsuba reference renders ``*_256.exr`` (+ JSON, caustic masks); skip when missing."""
    env = os.environ.get("CAUSTICA_REFS")
    return _existing_dir_or_skip(Path(env) if env else _shared_dir() / "refs", "reference images folder")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """Shared data files such as bunny.ply (skip when missing)."""
    return _existing_dir_or_skip(_shared_dir() / "data", "shared data folder")


@pytest.fixture
def cli(capsys):
    """Run the CLI in-process: returns (exit code, stdout, stderr)."""
    from caustica.cli import main

    def run(*args):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse: --help, --version, usage errors
            code = exc.code
        out, err = capsys.readouterr()
        return code, out, err
    return run


@pytest.fixture
def full_disk_exr(monkeypatch):
    """``full_disk_exr(error)``: OpenEXR's writer starts a file, then raises ``error(path)``, as on a full disk.

    Returns a function that installs the fake; ``monkeypatch.undo()`` (or the test's end) removes it.
    """
    import OpenEXR

    def install(error):
        class FullDisk:
            def __init__(self, *a, **k):
                pass

            def __enter__(self):
                return self

            def __exit__(self, *a):
                return False

            def write(self, name):
                Path(name).write_bytes(b"v/1\x01 half")
                raise error(name)

        monkeypatch.setattr(OpenEXR, "File", FullDisk)
    return install


@pytest.fixture
def interrupt_at_pass(monkeypatch):
    """``interrupt_at_pass(method, passes, exc=KeyboardInterrupt)``: the method's pass number ``passes`` raises
    ``exc`` (an interrupt arriving then) instead of running; the passes before it run as usual."""
    import caustica

    def install(method, passes, exc=KeyboardInterrupt):
        cls = caustica.methods.get(method)
        real = cls.run_pass.__func__

        def run_pass(klass, scene, settings, state, progress):
            if state.passes == passes:
                raise exc()
            return real(klass, scene, settings, state, progress)

        monkeypatch.setattr(cls, "run_pass", classmethod(run_pass))
    return install


@pytest.fixture(scope="session")
def mi():
    """Mitsuba 3 in its scalar_rgb variant, the independent renderer the tests compare with (skipped without it)."""
    mitsuba = pytest.importorskip("mitsuba")
    try:
        mitsuba.set_variant("scalar_rgb")
    except Exception as exc:  # the variant may not be compiled into this build
        pytest.skip(f"mitsuba scalar_rgb unavailable: {exc}")
    return mitsuba
