"""Checkpoints of progressive renders: the state after a number of passes, resumable bit for bit.

A checkpoint is one ``.npz`` file (written atomically; see :mod:`caustica.driver` for when) holding the
method's state arrays and a JSON header: the method, the scene's fingerprint (with one hash per
part — geometry, materials, lights, media, camera — and one per file read, so that a refusal can
say what changed), every setting that changes the image (seed, size, spp, the method's
parameters), the passes done and a SHA-256 of all of it (the header and every array's name,
dtype, shape and bytes).  Resuming with different settings is refused with the first difference
named, so a checkpoint can never be continued into a mixed image.  Threads, --time and --passes may
change between runs: they do not change the bits.

A checkpoint is input from disk, so :func:`load` trusts nothing in it: a file that is empty, cut
short, not an ``.npz``, holds pickled objects (which are never loaded), has a damaged header, does
not match its own hash, or whose arrays have other dtypes or shapes than the method writes, or
values it never writes (NaN, infinities, negative counts, radii out of range), is refused in one
line.  A write is never cut in half by Ctrl-C or SIGTERM (:func:`caustica.interrupts.held`).

:func:`locked` holds an exclusive lock on ``.NAME.lock`` beside the checkpoint while a render
uses it, so a second render given the same checkpoint is refused instead of overwriting the first
one's state; the operating system releases the lock when the process ends, however it ends.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import socket
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from . import interrupts
from .errors import ParameterError, shorten
from .version import __version__
from .jit import source_hash

#: Settings that may differ between the run that wrote a checkpoint and the one resuming it.
FREE_SETTINGS = ("threads",)
#: 2: the header holds a content hash, the scene's parts and files, and the auto settings' values.
FORMAT = 2
#: What every header holds, and the JSON type of each entry.
HEADER_TYPES = {"format": int, "caustica_version": str, "source": str, "method": str, "scene": str,
                "scene_fingerprint": str, "scene_parts": dict, "scene_files": dict, "settings": dict,
                "auto_settings": dict, "passes": int, "content_hash": str}
#: The dtypes a checkpoint's arrays may have: what the methods' ``to_arrays`` write.
ARRAY_DTYPES = (np.dtype(np.float64), np.dtype(np.int64))


def _scene_parts(scene) -> dict:
    """One hash per part of what the renderer sees of the scene: geometry, materials, lights, media, camera."""
    parts = {"geometry": scene.geometry, "materials": scene.materials, "lights": scene.lights}
    if scene.has_media:
        parts["media"] = scene.media
    out = {}
    for name, table in parts.items():
        h = hashlib.sha1()
        for a in table:
            a = np.ascontiguousarray(a)
            h.update(str(a.dtype).encode())
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
        out[name] = h.hexdigest()[:12]
    out["camera"] = hashlib.sha1(repr(scene.camera()).encode()).hexdigest()[:12]
    return out


def scene_fingerprint(scene) -> str:
    """A hash of what the renderer sees of the scene: geometry, materials, lights, media (if any), camera."""
    return hashlib.sha1(json.dumps(_scene_parts(scene), sort_keys=True).encode()).hexdigest()[:20]


def _scene_files(scene) -> dict:
    """The files the scene was read from (the XML, its meshes), each with a hash of its content ("missing" if gone)."""
    out = {}
    for f in scene.description.files:
        try:
            out[str(f)] = hashlib.sha1(Path(f).read_bytes()).hexdigest()[:12]
        except OSError:
            out[str(f)] = "missing"
    return out


def _header(method_cls, scene, settings, passes):
    fixed = {k: v for k, v in sorted(settings.items()) if k not in FREE_SETTINGS}
    auto = getattr(method_cls, "auto_settings", lambda scene, settings: {})(scene, settings)
    parts = _scene_parts(scene)
    return {"format": FORMAT, "caustica_version": __version__, "source": source_hash(), "method": method_cls.name,
            "scene": scene.name, "scene_fingerprint": scene_fingerprint(scene), "scene_parts": parts,
            "scene_files": _scene_files(scene), "settings": fixed,
            "auto_settings": {k: v for k, v in auto.items() if fixed.get(k) is None},
            "passes": int(passes)}


def content_hash(header: dict, arrays: dict) -> str:
    """SHA-256 of the header (without its own hash) and of every array's name, dtype, shape and bytes."""
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in header.items() if k != "content_hash"}, sort_keys=True).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def save(path, method_cls, scene, settings, state) -> None:
    """Write ``state`` (after ``state.passes`` passes) to ``path`` atomically.

    Ctrl-C or SIGTERM during the write is held until the file is in place, then raised as
    InterruptedAfterSaving: an interrupt never costs the passes being saved.
    """
    from .imageio import atomic_write
    with interrupts.held() as interrupted:
        header = _header(method_cls, scene, settings, state.passes)
        arrays = state.to_arrays()
        header["content_hash"] = content_hash(header, arrays)
        blob = np.frombuffer(json.dumps(header).encode(), np.uint8)

        def writer(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, _header=blob, **arrays)
        try:
            atomic_write(path, writer)
        except OSError as exc:
            raise ParameterError(f"--checkpoint {path}: cannot write the checkpoint: {exc.strerror or exc}") \
                from None
    interrupts.raise_held(interrupted, f"the checkpoint {path}")


def _refuse(path, why: str) -> ParameterError:
    return ParameterError(f"--checkpoint {path}: {why}; use a new checkpoint file (or delete this one)")


def _read(path):
    """(header, arrays) of the file at ``path``, or a one-line ParameterError saying why it is not a checkpoint."""
    p = Path(path)
    if p.is_dir():
        raise ParameterError(f"--checkpoint {path}: is a folder, not a checkpoint file")
    if p.is_symlink() and not p.exists():
        raise ParameterError(f"--checkpoint {path}: is a symbolic link to {os.readlink(p)}, which does not exist; "
                             f"remove the link or give the file it should point to")
    try:
        size = p.stat().st_size
    except OSError as exc:
        raise ParameterError(f"--checkpoint {path}: cannot be read ({exc.strerror or exc})") from None
    if size == 0:
        raise _refuse(path, "is empty (0 bytes), not a caustica checkpoint")
    try:
        with open(p, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ParameterError(f"--checkpoint {path}: cannot be read ({exc.strerror or exc})") from None
    if magic != b"PK\x03\x04":   # np.load would take anything else for a .npy array or a pickle
        raise _refuse(path, "is not a caustica checkpoint (not an .npz archive)")
    try:
        with np.load(p, allow_pickle=False) as data:
            names = list(data.files)
            if "_header" not in names:
                raise _refuse(path, "is an .npz file without a caustica header, not a caustica checkpoint")
            arrays = {k: data[k] for k in names}
    except ParameterError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc):   # numpy's advice to allow pickles is not ours to give: a pickle runs code
            raise _refuse(path, "holds an array of Python objects (a pickle), which caustica never writes and "
                                "never loads (loading a pickle can run any code)") from None
        raise _refuse(path, f"is not a caustica checkpoint ({shorten(exc, 80)})") from None
    except (EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, OSError, KeyError, RuntimeError,
            NotImplementedError) as exc:
        what = "cut short" if isinstance(exc, EOFError) else shorten(exc, 80) or type(exc).__name__
        raise _refuse(path, f"is not a readable caustica checkpoint ({what})") from None
    raw = arrays.pop("_header")
    try:
        if raw.dtype != np.uint8 or raw.ndim != 1:
            raise ValueError
        header = json.loads(raw.tobytes().decode("utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise _refuse(path, "its header is damaged (not JSON text)") from None
    return header, arrays


_JSON_NAMES = {int: "an integer", float: "a number", str: "a string", dict: "an object", list: "a list",
               bool: "a boolean", type(None): "null"}


def _check_header(path, header) -> None:
    """Refuse a header of another format or with entries missing or of the wrong type."""
    if not isinstance(header, dict):
        raise _refuse(path, "its header is damaged (not a JSON object)")
    fmt = header.get("format")
    if fmt != FORMAT:
        raise _refuse(path, f"format {shorten(fmt, 20)}, this caustica reads and writes format {FORMAT}")
    for key, kind in HEADER_TYPES.items():
        value = header.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            got = "missing" if key not in header else _JSON_NAMES.get(type(value), type(value).__name__)
            raise _refuse(path, f"its header is damaged ({key} is {got}, not {_JSON_NAMES[kind]})")
    if header["passes"] < 0:
        raise _refuse(path, f"its header is damaged (passes = {header['passes']})")


def _check_arrays(path, arrays) -> None:
    """Refuse arrays of a dtype no method writes, and floats that are not finite (the methods check the rest)."""
    for name, a in sorted(arrays.items()):
        if a.dtype not in ARRAY_DTYPES:
            raise _refuse(path, f"its array {shorten(name, 30)} is {a.dtype}, a checkpoint holds only float64 "
                                f"and int64 arrays")
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            bad = int(a.size - np.count_nonzero(np.isfinite(a)))
            raise _refuse(path, f"its array {shorten(name, 30)} holds {bad:,} NaN or infinite value(s), which no "
                                f"render writes")


def _flag(method_cls, key: str) -> str:
    """How the command line names setting ``key`` (--radius, --res width, ...)."""
    from .methods.params import COMMON_PARAMS
    for p in tuple(method_cls.params) + COMMON_PARAMS:
        if p.name == key:
            return p.flag
    return key


def _value(settings: Mapping, auto: dict, key: str) -> str:
    if key not in settings:
        return "no value recorded"
    v = settings[key]
    if v is None:
        return f"auto ({auto[key]:g})" if isinstance(auto.get(key), (int, float)) else "auto"
    return shorten(v if not isinstance(v, float) else f"{v:g}")


def _scene_difference(header, want) -> str:
    """What differs between the scene a checkpoint was written for and this render's: parts, then files."""
    parts = [k for k in sorted(set(header["scene_parts"]) | set(want["scene_parts"]))
             if header["scene_parts"].get(k) != want["scene_parts"].get(k)]
    files = []
    for f in sorted(set(header["scene_files"]) | set(want["scene_files"])):
        old, new = header["scene_files"].get(f), want["scene_files"].get(f)
        if old != new:
            how = ("not read by that render" if old is None else "not read by this one" if new is None
                   else "missing now" if new == "missing" else "changed since")
            files.append(f"{f} {how}")
    what = f"its {', '.join(parts) or 'description'} {'differs' if len(parts) == 1 else 'differ'}"
    where = (f" ({'; '.join(files)})" if files
             else " (no scene file changed: a -D value or caustica's built-in scene did)")
    return f"written for scene {shorten(header['scene'], 60)}, but {what} from this render's{where}"


def load(path, method_cls, scene, settings):
    """The state saved in ``path`` (None when the file does not exist yet), every part of it checked."""
    p = Path(path)
    if not os.path.lexists(p):
        return None
    header, arrays = _read(path)
    _check_header(path, header)
    if content_hash(header, arrays) != header["content_hash"]:
        raise _refuse(path, "damaged or edited since it was written (its content does not match the hash it was "
                            "written with)")
    _check_arrays(path, arrays)
    want = _header(method_cls, scene, settings, header["passes"])
    if header["source"] != want["source"]:
        raise ParameterError(f"--checkpoint {path}: written by another build of caustica (version "
                             f"{shorten(header['caustica_version'], 20)}, source {shorten(header['source'], 20)}; "
                             f"this one {want['caustica_version']}, source {want['source']}): its passes would not "
                             f"continue bit for bit; use a new checkpoint file")
    if header["method"] != want["method"]:
        raise ParameterError(f"--checkpoint {path}: written by method {shorten(header['method'], 20)}, this render "
                             f"is {want['method']}; use --method {shorten(header['method'], 20)} or a new "
                             f"checkpoint file")
    if header["scene_fingerprint"] != want["scene_fingerprint"]:
        raise ParameterError(f"--checkpoint {path}: {_scene_difference(header, want)}; render that scene or use "
                             f"a new checkpoint file")
    saved = header["settings"]
    for k in sorted(set(saved) | set(want["settings"])):
        if saved.get(k, ...) != want["settings"].get(k, ...):
            raise ParameterError(f"--checkpoint {path}: written with {_flag(method_cls, k)} "
                                 f"{_value(saved, header['auto_settings'], k)}, this render has "
                                 f"{_value(want['settings'], want['auto_settings'], k)}; use the same settings or "
                                 f"a new checkpoint file")
    try:
        state = method_cls.state_from_arrays(scene, settings, arrays)
    except ParameterError as exc:
        if not str(exc).startswith("checkpoint: "):
            raise   # about this render's settings (its memory, say), not the file
        raise _refuse(path, str(exc).removeprefix("checkpoint: ")) from None
    if state.passes != header["passes"]:
        raise _refuse(path, f"damaged (its header says {header['passes']} passes, its state {state.passes})")
    return state


def check_path(path, outputs=(), inputs=()) -> None:
    """Refuse, before any work, a checkpoint path that is one of the render's ``outputs`` or ``inputs`` (the scene
    file, its meshes), a folder, a device, in a folder that cannot be written, or a name too long to save."""
    from .imageio import check_outputs
    check_outputs([path], inputs, label=f"--checkpoint {shorten(path, 60)}")
    p = Path(path)
    for other in list(outputs) + list(inputs):
        if os.path.abspath(p) == os.path.abspath(other) or (p.exists() and Path(other).exists()
                                                            and os.path.samefile(p, other)):
            raise ParameterError(f"--checkpoint {path}: is also {'an output' if other in outputs else 'an input'} "
                                 f"of this render; give it a file of its own (e.g. {Path(other).stem}.npz)")


@contextlib.contextmanager
def locked(path):
    """Hold an exclusive lock on ``.NAME.lock`` beside checkpoint ``path`` while the block runs (None: no lock).

    A second render (in this process or another, on this machine or, on file systems that
    support locks, another) is refused with a one-line error naming the process that holds it.  The
    lock file stays (removing it would race with a render just opening it); it holds no state.
    """
    if path is None or os.name != "posix":
        yield
        return
    import fcntl
    p = Path(path)
    lock = p.with_name(f".{p.name}.lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise ParameterError(f"--checkpoint {path}: cannot create its lock file {lock} "
                             f"({exc.strerror or exc})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip()
                who = f" ({holder})" if holder else ""
                raise ParameterError(f"--checkpoint {path}: another render is using it{who}; wait for it to end "
                                     f"or give this one another checkpoint file") from None
            raise ParameterError(f"--checkpoint {path}: cannot lock {lock} ({exc.strerror or exc}); put the "
                                 f"checkpoint on a file system that supports locks") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"process {os.getpid()} on {socket.gethostname()}".encode(), 0)
        yield
    finally:
        os.close(fd)   # releases the lock
