"""Reading and writing caustica's outputs: OpenEXR images, sRGB PNG previews and JSON sidecars.

Every writer goes through `atomic_write`, so a failed or interrupted render never leaves a
broken or half-written file where a good one was (SPEC §5).
"""
from __future__ import annotations

import io
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from caustica.errors import CausticaError, ParameterError

__all__ = [
    "atomic_write",
    "write_exr",
    "read_exr",
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


def atomic_write(path: str | os.PathLike[str], writer: Callable[[Path], Any]) -> Path:
    """Write `path` atomically: `writer(tmp_path)` fills a temporary file, which then replaces `path`.

    The temporary sits in the destination's directory (same filesystem, so os.replace is an
    atomic rename); it is fsynced before the rename. On any exception, KeyboardInterrupt
    included, the temporary is removed, the destination is left exactly as it was, and the
    exception propagates. Parent directories are created. The writer receives a path (not a
    file object) so that C libraries such as OpenEXR can write it themselves; it must write
    to that path and not rename it. Returns the destination path.
    """
    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        writer(tmp)
        with open(tmp, "rb+") as fh:
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_current_umask())
        os.replace(tmp, dest)
    except BaseException:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        raise
    _fsync_dir(parent)
    return dest


def atomic_write_all(files: list[tuple[str | os.PathLike[str], Callable[[Path], Any]]]) -> list[Path]:
    """Write several files as one: every ``writer(tmp)`` fills its temporary first, then all replace.

    An exception while any file is being written (KeyboardInterrupt included) removes every
    temporary and leaves all destinations as they were, so a render's EXR, PNG and JSON never
    mix two renders; only the final renames, one after another, are not a single step.
    """
    temps = []
    try:
        for path, writer in files:
            dest = Path(path)
            parent = dest.parent if str(dest.parent) else Path(".")
            parent.mkdir(parents=True, exist_ok=True)
            fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=parent)
            os.close(fd)
            tmp = Path(tmp_name)
            temps.append((tmp, dest))
            writer(tmp)
            with open(tmp, "rb+") as fh:
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o666 & ~_current_umask())
    except BaseException:
        for tmp, _ in temps:
            try:
                tmp.unlink()
            except FileNotFoundError:
                pass
        raise
    for tmp, dest in temps:
        os.replace(tmp, dest)
    for parent in {dest.parent for _, dest in temps}:
        _fsync_dir(parent if str(parent) else Path("."))
    return [dest for _, dest in temps]


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
        with OpenEXR.File(header, channels) as f:
            f.write(str(tmp))

    return writer


def write_exr(path: str | os.PathLike[str], image: Any) -> Path:
    """Write a linear RGB image as an OpenEXR file with float32 "R", "G", "B" channels (ZIP), atomically."""
    return atomic_write(path, exr_writer(image))


def read_exr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an OpenEXR file's R, G, B channels as float32 H×W×3 (alpha dropped; a lone Y channel is greyed).

    Reads caustica's own files and Mitsuba 3's (which store plain float R, G, B channels).
    A missing or unreadable file raises CausticaError naming the path.
    """
    import OpenEXR

    p = Path(path)
    if not p.is_file():
        raise CausticaError(f"cannot read EXR image '{p}': no such file")
    try:
        with OpenEXR.File(str(p), separate_channels=True) as f:
            channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except RuntimeError as exc:
        raise CausticaError(f"cannot read EXR image '{p}': {exc}") from None
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


def to_srgb8(image: Any, exposure_stops: float = 0.0) -> np.ndarray:
    """Linear RGB to an 8-bit sRGB preview: scale by 2**exposure_stops, clamp to [0, 1], apply the
    exact piecewise sRGB transfer function, round to nearest (halves up). NaN shows as black."""
    rgb = _as_rgb(image).astype(np.float64)
    rgb *= 2.0 ** float(exposure_stops)
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


def write_png(path: str | os.PathLike[str], image: Any, exposure_stops: float = 0.0) -> Path:
    """Write the sRGB preview (see `to_srgb8`) of a linear image as a PNG, atomically."""
    return atomic_write(path, png_writer(image, exposure_stops))


def read_png_mask(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a mask image as bool H×W: a pixel is inside where any colour channel is nonzero (alpha ignored)."""
    from PIL import Image

    p = Path(path)
    if not p.is_file():
        raise CausticaError(f"cannot read mask image '{p}': no such file")
    with Image.open(p) as im:
        if im.mode == "P":
            im = im.convert("RGBA")
        if im.mode in ("LA", "PA", "RGBA", "La", "RGBa"):
            im = im.convert("RGB" if im.mode[0] in "RPr" else "L")
        arr = np.asarray(im)
    if arr.ndim == 3:
        return np.any(arr != 0, axis=2)
    return arr != 0


# --------------------------------------------------------------------------- JSON


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, paths, tuples and sets to plain JSON values (recursively).

    Non-finite floats (NaN, ±inf) become null, since strict JSON has no spelling for them.
    """
    if isinstance(obj, dict):
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
    silently turned into "out.jpg.exr").
    """
    p = Path(path)
    if not p.name or p.name in (".", ".."):
        raise ParameterError(f"output path '{path}' has no file name; give e.g. out/render.exr")
    suffix = p.suffix
    if suffix.lower() not in OUTPUT_SUFFIXES:
        raise ParameterError(
            f"output path '{path}' has suffix '{suffix}'; allowed: .exr, .png or none "
            "(the .exr, .png and .json files are written side by side)"
        )
    stem = p.with_suffix("") if suffix else p
    return stem.with_name(stem.name + ".exr"), stem.with_name(stem.name + ".png"), stem.with_name(stem.name + ".json")
