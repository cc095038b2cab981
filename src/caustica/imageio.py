"""Reading and writing caustica's outputs: OpenEXR images, sRGB PNG previews and JSON sidecars.

Every writer goes through `atomic_write_all`, so a failed or interrupted render never leaves a
broken or half-written file where a good one was, never replaces part of a set (EXR + PNG +
JSON) and never writes over one of its inputs (SPEC §5).
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import shutil
import socket
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Callable

import numpy as np

from caustica import interrupts
from caustica.errors import CausticaError, OutputError, ParameterError, quoted

__all__ = [
    "atomic_write",
    "atomic_write_all",
    "check_outputs",
    "remove_stale_temporaries",
    "check_exposure",
    "write_exr",
    "read_exr",
    "read_radiance_image",
    "to_srgb8",
    "encode_png",
    "write_png",
    "read_png_mask",
    "write_json",
    "to_jsonable",
    "output_paths",
    "OUTPUT_SUFFIXES",
]

#: Suffixes `output_paths` accepts ("" = no suffix).
OUTPUT_SUFFIXES = (".exr", ".png", "")


def _current_umask() -> int:
    """The process umask, so atomically written files get the usual permissions, not mkstemp's 0600."""
    try:  # Linux: read it without changing it (os.umask is a process-wide set-and-get).
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    """Make the rename itself durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _host_tag() -> str:
    """This machine's name, letters and digits only, so that temporaries on a shared folder say whose they are."""
    return "".join(c for c in socket.gethostname() if c.isascii() and c.isalnum())[:32] or "host"


#: A temporary of ours: ``.NAME.caustica-HOST-PID-RANDOM.tmp`` (the new file) or ``...old`` (a backup).
_TEMP_RE = re.compile(r"([A-Za-z0-9]*)-([0-9]+)-\w+\.(?:tmp|old)")  # after ".NAME.caustica-"


def _temp_prefix(dest: Path) -> str:
    return f".{dest.name}.caustica-{_host_tag()}-{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    """Whether process `pid` exists on this machine (True when unsure: then nothing is removed)."""
    if os.name != "posix":
        return True  # os.kill(pid, 0) is not a harmless probe on Windows
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # e.g. EPERM: it exists but belongs to someone else
    return True


def remove_stale_temporaries(path: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries that a killed caustica process left beside `path`; return them.

    Only files named like ours for this very output (``.NAME.caustica-HOST-PID-*.tmp`` or
    ``.old``), made on this machine by a process that no longer exists, are removed; a save in
    progress elsewhere, or in this process, is left alone.
    """
    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    prefix, host, removed = f".{dest.name}.caustica-", _host_tag(), []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        if not name.startswith(prefix):
            continue
        m = _TEMP_RE.fullmatch(name[len(prefix):])
        if m is None or m.group(1) != host:
            continue
        pid = int(m.group(2))
        if pid == os.getpid() or _pid_alive(pid):
            continue
        try:
            os.unlink(parent / name)
            removed.append(parent / name)
        except OSError:
            pass
    return removed


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        try:
            return a.resolve() == b.resolve()
        except (OSError, RuntimeError):
            return False


def _nearest_folder(folder: Path) -> Path:
    """``folder``, or the nearest of its parents that exists (where missing folders would be created)."""
    folder = Path(os.path.abspath(folder if str(folder) else "."))
    while not os.path.isdir(folder) and folder != folder.parent:
        folder = folder.parent
    return folder


def _limit(folder: Path, name: str, default: int) -> int:
    try:
        return int(os.pathconf(_nearest_folder(folder), name))
    except (OSError, ValueError, AttributeError):
        return default


def check_name_length(path: str | os.PathLike[str], label: str | None = None) -> None:
    """Refuse an output whose name the file system cannot hold, counting the temporary written beside it first
    (``.NAME.caustica-HOST-PID-XXXXXXXX.tmp``, the longest name a save creates), and whose folders or whole
    path are too long: one OutputError saying how long each may be, before any work."""
    head = f"{label}: " if label else ""
    p = Path(path)
    name_max = _limit(p.parent, "PC_NAME_MAX", 255)
    for part in p.parent.parts:
        if len(os.fsencode(part)) > name_max:
            raise OutputError(f"{head}the folder name {quoted(part)} is {len(os.fsencode(part))} bytes long; this "
                              f"file system allows {name_max}")
    n = len(os.fsencode(p.name))
    extra = len(os.fsencode(_temp_prefix(p))) - n + 8 + len(".tmp")
    if n + extra > name_max:
        raise OutputError(f"{head}the file name {quoted(p.name)} is {n} bytes long; this file system allows "
                          f"{name_max} and the temporary written beside it first adds {extra}, so at most "
                          f"{name_max - extra}")
    path_max = _limit(p.parent, "PC_PATH_MAX", 4096)
    whole = len(os.fsencode(os.path.abspath(p))) + extra
    if whole >= path_max:
        raise OutputError(f"{head}the path {quoted(os.path.abspath(p))} is {whole - extra} bytes long; this file "
                          f"system allows {path_max - 1} and the temporary written beside it first adds {extra}")


def check_outputs(paths, inputs=(), label: str | None = None) -> None:
    """Refuse, before anything is rendered or written, outputs that could not be written whole.

    Each path must not be a folder or anything but a regular file (a device, a FIFO), must not
    be (or link to) one of `inputs` (the scene file, its meshes: never write over an input),
    and its folder (or the nearest folder that exists, since missing ones are created) must be
    a writable folder. Raises OutputError naming the path, prefixed by `label` (e.g. "-o out.exr").
    """
    head = f"{label}: " if label else ""
    inputs = [Path(p) for p in inputs]
    for given in (Path(p) for p in paths):
        check_name_length(given, label)
        # where the entry really is: "new/../x" is "x" once "new" is created, and a symlinked
        # folder is its target (the last component is kept: a symlink there is replaced, not followed)
        path = Path(os.path.realpath(given.parent if str(given.parent) else ".")) / given.name
        if path.is_dir():
            raise OutputError(f"{head}cannot write '{given}': it is a folder")
        if path.exists() and not path.is_file():
            raise OutputError(f"{head}cannot write '{given}': it exists and is not a regular file")
        if path.exists():
            for inp in inputs:
                if _same_file(path, inp):
                    raise OutputError(f"{head}'{given}' would write over '{inp}', an input of this render "
                                      "(the scene file or a mesh it loads); choose another output name")
        folder = Path(os.path.abspath(path.parent if str(path.parent) else "."))
        existing = folder
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        if not existing.is_dir():
            raise OutputError(f"{head}cannot create the folder {folder}: {existing} is a file")
        if not os.access(existing, os.W_OK | os.X_OK):
            raise OutputError(f"{head}the folder {existing} is not writable")


def _backup(dest: Path, tmp: Path) -> Path | None:
    """A second name for the current `dest` (a hard link, or a copy where links are not allowed),
    so that it can be put back if a later rename of the set fails. None if `dest` does not exist."""
    if not os.path.lexists(dest):
        return None
    backup = tmp.with_name(tmp.name[: -len(".tmp")] + ".old")
    try:
        os.link(dest, backup, follow_symlinks=False)
    except (OSError, NotImplementedError):
        if dest.is_symlink():
            os.symlink(os.readlink(dest), backup)
        else:
            shutil.copy2(dest, backup)
    return backup


def _unlink_quietly(path: Path | None) -> None:
    if path is None:
        return
    try:
        path.unlink()
    except OSError:
        pass


def _output_error(dest: Path, tmp: Path | None, exc: OSError) -> OutputError:
    reason = (exc.strerror or str(exc) or type(exc).__name__).rstrip(". ")
    if tmp is not None:
        reason = reason.replace(str(tmp), str(dest))
    return OutputError(f"cannot write '{dest}': {reason}; nothing was replaced")


def _commit(temps: list[tuple[Path, Path]]) -> None:
    """Rename every temporary onto its destination, or, if any step fails, put every destination
    back as it was (the previous file or none) and remove the temporaries and backups."""
    backups: list[Path | None] = []
    replaced: list[tuple[Path, Path | None]] = []
    current = None
    try:
        for current in temps:
            backups.append(_backup(current[1], current[0]))
        for current, backup in zip(temps, backups):
            os.replace(*current)
            replaced.append((current[1], backup))
    except BaseException as exc:
        kept = []
        for dest, backup in reversed(replaced):
            try:
                if backup is None:
                    dest.unlink()
                else:
                    os.replace(backup, dest)
            except OSError:
                kept.append((dest, backup))
        for tmp, _ in temps:
            _unlink_quietly(tmp)
        for backup in backups:
            if all(backup != b for _, b in kept):
                _unlink_quietly(backup)
        if kept:
            raise OutputError("the set of outputs could not be put back as it was: " + "; ".join(
                f"'{d}' is new, " + (f"the previous one is '{b}'" if b else "it did not exist before")
                for d, b in kept)) from None
        if isinstance(exc, OSError) and current is not None:
            raise _output_error(current[1], current[0], exc) from exc
        raise
    for backup in backups:
        _unlink_quietly(backup)


def atomic_write(path: str | os.PathLike[str], writer: Callable[[Path], Any], inputs=()) -> Path:
    """Write `path` atomically: `writer(tmp_path)` fills a temporary file, which then replaces `path`.

    The same as `atomic_write_all` with one file. The writer receives a path (not a file object)
    so that C libraries such as OpenEXR can write it themselves; it must write to that path and
    not rename it. Returns the destination path.
    """
    return atomic_write_all([(path, writer)], inputs)[0]


def atomic_write_all(files: list[tuple[str | os.PathLike[str], Callable[[Path], Any]]], inputs=()) -> list[Path]:
    """Write several files as one set: each ``writer(tmp)`` fills a temporary, then all replace their
    destinations together, or none does.

    First `check_outputs(paths, inputs)` refuses folders, non-regular files, inputs and unwritable
    folders, and temporaries that killed processes left for these outputs are removed
    (`remove_stale_temporaries`). The temporaries, ``.NAME.caustica-HOST-PID-*.tmp``, sit beside
    their destinations (same filesystem, so each rename is atomic) and are fsynced. Then every
    existing destination gets a second name (a hard link: no copy) and the temporaries are renamed
    into place; if any rename fails, the ones already done are undone, so the previous set stays
    whole. On any failure, KeyboardInterrupt included, no temporary is left and the exception
    propagates; an OSError (a full disk, a permission) becomes an OutputError naming the file.
    Ctrl-C or SIGTERM during the renames is held until the set is complete and then raised as
    InterruptedAfterSaving. Only a process killed during the renames (SIGKILL, a power cut) can
    leave a set mixing two saves, each file whole. Parent folders are created.
    """
    dests = [Path(path) for path, _ in files]
    check_outputs(dests, inputs)
    temps: list[tuple[Path, Path]] = []
    tmp = None
    try:
        for dest, (_, writer) in zip(dests, files):
            parent = dest.parent if str(dest.parent) else Path(".")
            tmp = None
            parent.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(dest)
            fd, tmp_name = tempfile.mkstemp(prefix=_temp_prefix(dest), suffix=".tmp", dir=parent)
            os.close(fd)
            tmp = Path(tmp_name)
            temps.append((tmp, dest))
            writer(tmp)
            with open(tmp, "rb+") as fh:
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o666 & ~_current_umask())
        with interrupts.held() as interrupted:
            _commit(temps)
    except OSError as exc:
        for t, _ in temps:
            _unlink_quietly(t)
        if isinstance(exc, OutputError):
            raise
        raise _output_error(dest, tmp, exc) from exc
    except BaseException:
        for t, _ in temps:
            _unlink_quietly(t)
        raise
    for parent in {dest.parent for dest in dests}:
        _fsync_dir(parent if str(parent) else Path("."))
    interrupts.raise_held(interrupted, "the outputs")
    return dests


# --------------------------------------------------------------------------- OpenEXR


def _as_rgb(image: Any, what: str = "image") -> np.ndarray:
    """Check and convert an H×W×3 (or H×W grey) image to a C-contiguous float32 array."""
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{what} must be an H×W×3 RGB array, got shape {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def exr_writer(image: Any) -> Callable[[Path], None]:
    """A writer (for `atomic_write`) of a linear RGB OpenEXR file: float32 "R", "G", "B" channels, ZIP."""
    rgb = _as_rgb(image)

    def writer(tmp: Path) -> None:
        import OpenEXR

        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        channels = {name: np.ascontiguousarray(rgb[:, :, i]) for i, name in enumerate("RGB")}
        try:
            with OpenEXR.File(header, channels) as f:
                f.write(str(tmp))
        except RuntimeError as exc:  # OpenEXR's I/O errors (a full disk) are RuntimeErrors
            raise OSError(str(exc)) from exc

    return writer


def write_exr(path: str | os.PathLike[str], image: Any) -> Path:
    """Write a linear RGB image as an OpenEXR file with float32 "R", "G", "B" channels (ZIP), atomically."""
    return atomic_write(path, exr_writer(image))


@contextlib.contextmanager
def _c_output_captured():
    """While the block runs, what C libraries print on file descriptors 1 and 2 goes to a temporary
    file; afterwards the yielded list holds that text (OpenEXR prints its own lines about a corrupt
    file, which would break the one-line error). Python's own sys.stdout/stderr are flushed first."""
    printed: list[str] = []
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, OSError, ValueError):
            pass
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:
        yield printed
        return
    said = io.StringIO()  # what the bindings print through Python's sys.stdout / sys.stderr
    with tempfile.TemporaryFile() as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
                yield printed
        finally:
            _flush_c_stdio()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            sink.seek(0)
            printed.append(sink.read().decode("utf-8", "replace"))
            printed.append(said.getvalue())


def _flush_c_stdio() -> None:
    """fflush(NULL): push C stdio buffers out before a file descriptor is switched back."""
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


def read_exr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an OpenEXR file's R, G, B channels as float32 H×W×3 (alpha dropped; a lone Y channel is greyed).

    Reads caustica's own files and Mitsuba 3's (which store plain float R, G, B channels).
    A missing or unreadable file raises CausticaError naming the path.
    """
    import OpenEXR

    p = Path(path)
    if not p.is_file():
        raise CausticaError(f"cannot read EXR image '{p}': no such file")
    failure = None
    with _c_output_captured() as printed:
        try:
            with OpenEXR.File(str(p), separate_channels=True) as f:
                channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
        except Exception as exc:  # RuntimeError, ValueError (a truncated file), MemoryError, ...
            failure = exc
    said = [line.strip() for line in "".join(printed).splitlines() if line.strip()]
    if failure is not None:
        # OpenEXR's own "(EXR_ERR_...)" line is the most precise; the exception text is the fallback
        coded = [line for line in said if "EXR_ERR" in line]
        detail = (coded or said or [str(failure) or type(failure).__name__])[0]
        detail = detail.removeprefix(f"{p}: ").removeprefix(f"{os.fspath(path)}: ")
        raise CausticaError(f"cannot read EXR image '{p}': {detail} "
                            "(a damaged, truncated or non-EXR file)") from None
    if said:  # a warning on a file that could be read: pass it on
        print("\n".join(said), file=sys.stderr)
    if all(c in channels for c in "RGB"):
        planes = [channels[c] for c in "RGB"]
    elif "Y" in channels:
        planes = [channels["Y"]] * 3
    else:
        raise CausticaError(
            f"EXR image '{p}' has no R, G, B (or Y) channels; it has: {', '.join(sorted(channels)) or 'none'}"
        )
    return np.ascontiguousarray(np.stack(planes, axis=-1), dtype=np.float32)


# --------------------------------------------------------------------------- sRGB / PNG


#: The largest preview exposure, in stops, either way. float32 values lie in [2^-149, 2^128), so
#: at +150 every nonzero pixel is white and at -150 every pixel is black: beyond, nothing changes.
EXPOSURE_LIMIT = 150.0


def check_exposure(exposure_stops: Any) -> float:
    """The preview exposure as a float, or ParameterError unless it is a finite number of stops
    within ±EXPOSURE_LIMIT (NaN would make a black preview, 1e6 overflow 2**stops)."""
    try:
        value = float(exposure_stops)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"--exposure: '{exposure_stops}' is not a number of stops") from None
    if isinstance(exposure_stops, bool) or not math.isfinite(value) or abs(value) > EXPOSURE_LIMIT:
        shown = str(exposure_stops) if len(str(exposure_stops)) <= 40 else str(exposure_stops)[:40] + "..."
        raise ParameterError(f"--exposure: the preview exposure must be a finite number of stops between "
                             f"-{EXPOSURE_LIMIT:g} and {EXPOSURE_LIMIT:g} (got {shown}); beyond, every "
                             "float32 pixel is already black or white")
    return value


def to_srgb8(image: Any, exposure_stops: float = 0.0) -> np.ndarray:
    """Linear RGB to an 8-bit sRGB preview: scale by 2**exposure_stops, clamp to [0, 1], apply the
    exact piecewise sRGB transfer function, round to nearest (halves up). NaN shows as black.

    exposure_stops must be finite and within ±EXPOSURE_LIMIT (`check_exposure`)."""
    scale = 2.0 ** check_exposure(exposure_stops)
    rgb = _as_rgb(image).astype(np.float64)
    rgb *= scale
    rgb = np.nan_to_num(rgb, nan=0.0, posinf=1.0, neginf=0.0)
    np.clip(rgb, 0.0, 1.0, out=rgb)
    encoded = np.where(
        rgb <= 0.0031308,
        12.92 * rgb,
        1.055 * np.power(np.maximum(rgb, 0.0031308), 1.0 / 2.4) - 0.055,
    )
    return np.floor(encoded * 255.0 + 0.5).clip(0, 255).astype(np.uint8)


def encode_png(image: Any, exposure_stops: float = 0.0) -> bytes:
    """The sRGB preview of a linear image as PNG bytes (for Jupyter and for `write_png`)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(to_srgb8(image, exposure_stops)).save(buf, format="PNG")
    return buf.getvalue()


def png_writer(image: Any, exposure_stops: float = 0.0) -> Callable[[Path], None]:
    """A writer (for `atomic_write`) of the sRGB preview PNG (see `to_srgb8`) of a linear image."""
    data = encode_png(image, exposure_stops)
    return lambda tmp: tmp.write_bytes(data)


def write_png(path: str | os.PathLike[str], image: Any, exposure_stops: float = 0.0, inputs=()) -> Path:
    """Write the sRGB preview (see `to_srgb8`) of a linear image as a PNG, atomically (never onto `inputs`)."""
    return atomic_write(path, png_writer(image, exposure_stops), inputs)


def read_png_mask(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a mask image as bool H×W: a pixel is inside where any colour channel is nonzero (alpha ignored)."""
    from PIL import Image

    p = Path(path)
    if not p.is_file():
        raise CausticaError(f"cannot read mask image '{p}': no such file")
    try:
        with Image.open(p) as im:
            if im.mode == "P":
                im = im.convert("RGBA")
            if im.mode in ("LA", "PA", "RGBA", "La", "RGBa"):
                im = im.convert("RGB" if im.mode[0] in "RPr" else "L")
            arr = np.asarray(im)
    except Exception as exc:  # not an image, truncated, too large (PIL's errors differ by format)
        raise CausticaError(f"cannot read mask image '{p}': {exc} (give a PNG; nonzero pixels are "
                            "inside the mask)") from None
    if arr.ndim not in (2, 3) or arr.size == 0:
        raise CausticaError(f"cannot read mask image '{p}': it has no pixels a mask can use (shape {arr.shape})")
    if arr.ndim == 3:
        return np.any(arr != 0, axis=2)
    return arr != 0


# --------------------------------------------------------------------------- JSON


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, paths, mappings (a render's Settings too), tuples and sets to plain JSON values
    (recursively).

    Non-finite floats (NaN, ±inf) become null, since strict JSON has no spelling for them.
    """
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if hasattr(obj, "__dataclass_fields__"):
        import dataclasses

        return to_jsonable(dataclasses.asdict(obj))
    return str(obj)


def json_writer(data: Any) -> Callable[[Path], None]:
    """A writer (for `atomic_write`) of `data` as pretty-printed UTF-8 JSON (2-space indent, trailing newline)."""
    text = json.dumps(to_jsonable(data), indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    return lambda tmp: tmp.write_text(text, encoding="utf-8")


def write_json(path: str | os.PathLike[str], data: Any) -> Path:
    """Write `data` as pretty-printed UTF-8 JSON (2-space indent, trailing newline), atomically."""
    return atomic_write(path, json_writer(data))


# --------------------------------------------------------------------------- output names


def output_paths(path: str | os.PathLike[str]) -> tuple[Path, Path, Path]:
    """The (name.exr, name.png, name.json) siblings for an output path given as name.exr, name.png or name.

    Any other suffix raises ParameterError naming the allowed ones (so "out.jpg" is not
    silently turned into "out.jpg.exr"), and so does a path that names no file: a folder (an
    existing one, or one written with a trailing slash, which would give "folder.exr" beside
    it) or an existing device such as /dev/null. The CLI turns a folder into
    folder/<scene>_<method>.exr before calling this.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise ParameterError(f"output path {quoted(path)}: a file name (str or os.PathLike), not a "
                             f"{type(path).__name__}")
    text = os.fspath(path)
    if not isinstance(text, str):
        raise ParameterError(f"output path {quoted(text)}: a file name as text, not bytes")
    p = Path(text)
    if not text or not p.name or p.name in (".", "..") or text.endswith(os.sep) or (
            os.altsep and text.endswith(os.altsep)):
        raise ParameterError(f"output path '{path}' has no file name; give e.g. out/render.exr")
    check_name_length(p, f"output path {quoted(text)}")
    if p.is_dir():
        raise ParameterError(f"output path '{path}' is a folder; give a file name in it, e.g. {p / 'render.exr'}")
    if p.exists() and not p.is_file():
        raise ParameterError(f"output path '{path}' exists and is not a regular file (a device, FIFO or "
                             "socket); give a file name, e.g. out/render.exr")
    suffix = p.suffix
    if suffix.lower() not in OUTPUT_SUFFIXES:
        raise ParameterError(
            f"output path '{path}' has suffix '{suffix}'; allowed: .exr, .png or none "
            "(the .exr, .png and .json files are written side by side)"
        )
    stem = p.with_suffix("") if suffix else p
    return stem.with_name(stem.name + ".exr"), stem.with_name(stem.name + ".png"), stem.with_name(stem.name + ".json")


# --------------------------------------------------------------------------- radiance images (envmaps)

#: The image files :func:`read_radiance_image` reads: OpenEXR and Radiance RGBE (linear), and 8/16-bit images
#: through Pillow (sRGB-encoded, as Mitsuba 3 takes them).
RADIANCE_IMAGE_SUFFIXES = (".exr", ".hdr", ".rgbe", ".png", ".jpg", ".jpeg", ".bmp", ".tga")


def read_rgbe(path: Path) -> np.ndarray:
    """A Radiance RGBE (.hdr) file as linear RGB float64 H×W×3, read as Mitsuba 3 reads it (Bitmap::read_rgbe):
    a "#?" header, FORMAT=32-bit_rle_rgbe, the resolution "-Y H +X W"; scanlines flat or new-style run-length
    encoded; a pixel (r, g, b, e) is (r, g, b) 2^(e - 136), 0 when e = 0.  Raises ValueError on a malformed file."""
    data = path.read_bytes()
    pos = data.find(b"\n")
    if not data.startswith(b"#?") or pos < 0:
        raise ValueError("not a Radiance RGBE file (no '#?' header)")
    fmt = None
    width = height = None
    while width is None:
        end = data.find(b"\n", pos + 1)
        if end < 0:
            raise ValueError("the header ends before the resolution line")
        line = data[pos + 1:end].decode("latin-1").strip()
        pos = end
        if line.startswith("FORMAT="):
            fmt = line[len("FORMAT="):]
        tokens = line.split()
        if len(tokens) == 4 and tokens[0] in ("-Y", "+Y") and tokens[2] in ("+X", "-X"):
            if (tokens[0], tokens[2]) != ("-Y", "+X"):
                raise ValueError(f"orientation {quoted(line)} is not supported (only '-Y H +X W', as in Mitsuba)")
            height, width = int(tokens[1]), int(tokens[3])
    if fmt != "32-bit_rle_rgbe":
        raise ValueError(f"format {quoted(fmt or 'none')} is not supported (only 32-bit_rle_rgbe)")
    if width <= 0 or height <= 0 or width * height > 1 << 28:
        raise ValueError(f"bad size {width}x{height}")
    body = np.frombuffer(data, np.uint8, offset=pos + 1)
    out = np.empty((height, width, 4), np.uint8)
    raw = body.tobytes()
    i = 0
    for y in range(height):
        head = body[i:i + 4]
        if width < 8 or width > 0x7FFF or len(head) < 4 or head[0] != 2 or head[1] != 2 or head[2] & 0x80:
            flat = body[i:i + 4 * width * (height - y)]   # not run-length encoded: the rest is flat
            if flat.size != 4 * width * (height - y):
                raise ValueError("the file is truncated")
            out[y:] = flat.reshape(height - y, width, 4)
            break
        if (int(head[2]) << 8 | int(head[3])) != width:
            raise ValueError("wrong scanline width")
        i += 4
        for c in range(4):
            x = 0
            row = out[y, :, c]
            while x < width:
                if i + 2 > len(raw):
                    raise ValueError("the file is truncated")
                count = raw[i]
                if count > 128:
                    count -= 128
                    if count > width - x:
                        raise ValueError("bad scanline data")
                    row[x:x + count] = raw[i + 1]
                    i += 2
                else:
                    if count == 0 or count > width - x or i + 1 + count > len(raw):
                        raise ValueError("bad scanline data")
                    row[x:x + count] = np.frombuffer(raw, np.uint8, count, i + 1)
                    i += 1 + count
                x += count
    e = out[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0)
    return out[..., :3].astype(np.float64) * scale[..., None]


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The exact piecewise sRGB decoding of values in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, np.power((np.maximum(c, 0.04045) + 0.055) / 1.055, 2.4))


def read_radiance_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Linear RGB float64 H×W×3 from an image file, as Mitsuba 3's Bitmap reads it for an emitter.

    OpenEXR as stored (:func:`read_exr`), Radiance RGBE (:func:`read_rgbe`); PNG, JPEG, BMP and TGA through
    Pillow, their 8- or 16-bit values decoded from sRGB (grey replicated, alpha dropped).  Raises CausticaError
    naming the file when it is missing, not an image, or of a kind not read here (PFM).
    """
    p = Path(path)
    if not p.is_file():
        raise CausticaError(f"cannot read image '{p}': no such file")
    suffix = p.suffix.lower()
    if suffix == ".exr":
        return read_exr(p).astype(np.float64)
    if suffix in (".hdr", ".rgbe"):
        try:
            return read_rgbe(p)
        except (ValueError, OSError) as exc:
            raise CausticaError(f"cannot read image '{p}': {exc}") from None
    if suffix not in RADIANCE_IMAGE_SUFFIXES:
        raise CausticaError(f"cannot read image '{p}': {quoted(suffix or 'no suffix')} images are not supported; "
                            f"supported: {', '.join(RADIANCE_IMAGE_SUFFIXES)} (convert others to OpenEXR)")
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(p) as im:
            im.load()
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                data = np.asarray(im, dtype=np.float64) / 65535.0
            else:
                if im.mode not in ("L", "RGB"):
                    im = im.convert("RGBA" if "A" in im.getbands() or im.mode == "P" else "RGB")
                data = np.asarray(im, dtype=np.float64) / 255.0
    except UnidentifiedImageError:
        raise CausticaError(f"cannot read image '{p}': not an image file Pillow recognises") from None
    except (OSError, ValueError) as exc:
        raise CausticaError(f"cannot read image '{p}': {exc}") from None
    if data.ndim == 2:
        data = np.repeat(data[:, :, None], 3, axis=2)
    return np.ascontiguousarray(srgb_to_linear(data[:, :, :3]))
