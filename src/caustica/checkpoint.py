"""Checkpoints of progressive renders: the state after a number of passes, resumable bit for bit.

A checkpoint is one ``.npz`` file (written atomically; see :mod:`caustica.driver` for when) holding the
method's state arrays and a JSON header: the method, the scene's fingerprint, every
setting that changes the image (seed, size, spp, the method's parameters) and the
passes done.  Resuming with different settings is refused with the first
difference named, so a checkpoint can never be continued into a mixed image.
Threads, --time and --passes may change between runs: they do not change the bits.
"""
from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path

import numpy as np

from .version import __version__
from .errors import ParameterError
from .jit import source_hash

#: Settings that may differ between the run that wrote a checkpoint and the one resuming it.
FREE_SETTINGS = ("threads",)
FORMAT = 1


def scene_fingerprint(scene) -> str:
    """A hash of what the renderer sees of the scene: geometry, materials, lights, media (if any), camera."""
    h = hashlib.sha1()
    tables = (scene.geometry, scene.materials, scene.lights) + ((scene.media,) if scene.has_media else ())
    for table in tables:
        for a in table:
            a = np.ascontiguousarray(a)
            h.update(str(a.dtype).encode())
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    h.update(repr(scene.camera()).encode())
    return h.hexdigest()[:20]


def _header(method_cls, scene, settings, passes):
    fixed = {k: v for k, v in sorted(settings.items()) if k not in FREE_SETTINGS}
    return {"format": FORMAT, "caustica_version": __version__, "source": source_hash(), "method": method_cls.name,
            "scene": scene.name, "scene_fingerprint": scene_fingerprint(scene),
            "settings": fixed, "passes": int(passes)}


def save(path, method_cls, scene, settings, state) -> None:
    """Write ``state`` (after ``state.passes`` passes) to ``path`` atomically."""
    from .imageio import atomic_write
    header = json.dumps(_header(method_cls, scene, settings, state.passes))
    arrays = state.to_arrays()

    def writer(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, _header=np.frombuffer(header.encode(), np.uint8), **arrays)
    try:
        atomic_write(path, writer)
    except OSError as exc:
        raise ParameterError(f"--checkpoint {path}: cannot write the checkpoint: {exc.strerror or exc}") \
            from None


def load(path, method_cls, scene, settings):
    """The state saved in ``path`` (None when the file does not exist yet)."""
    p = Path(path)
    if not p.exists():
        return None
    if p.is_dir():
        raise ParameterError(f"--checkpoint {path}: is a folder, not a checkpoint file")
    try:
        with np.load(p, allow_pickle=False) as data:
            header = json.loads(bytes(data["_header"]).decode())
            arrays = {k: data[k] for k in data.files if k != "_header"}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ParameterError(f"--checkpoint {path}: not a caustica checkpoint ({exc})") from None
    if not isinstance(header, dict) or not isinstance(header.get("passes"), int):
        raise ParameterError(f"--checkpoint {path}: not a caustica checkpoint (its header is damaged)")
    want = _header(method_cls, scene, settings, header["passes"])
    if header.get("format") != FORMAT:
        raise ParameterError(f"--checkpoint {path}: format {header.get('format')} (this caustica writes {FORMAT})")
    if header.get("source") != want["source"]:
        raise ParameterError(f"--checkpoint {path}: written by another build of caustica (source "
                             f"{header.get('source')}, this one {want['source']}): its passes would not "
                             f"continue bit for bit; use a new checkpoint file")
    for key in ("method", "scene_fingerprint"):
        if header.get(key) != want[key]:
            raise ParameterError(f"--checkpoint {path}: written for {key} {header.get(key)!r}, "
                                 f"this render has {want[key]!r}")
    saved = header.get("settings", {})
    for k in sorted(set(saved) | set(want["settings"])):
        if saved.get(k) != want["settings"].get(k):
            raise ParameterError(f"--checkpoint {path}: written with {k} = {saved.get(k)!r}, this render has "
                                 f"{want['settings'].get(k)!r}; use the same settings or a new checkpoint file")
    state = method_cls.state_from_arrays(scene, settings, arrays)
    if state.passes != header["passes"]:
        raise ParameterError(f"--checkpoint {path}: damaged (header says {header['passes']} passes, "
                             f"the state {state.passes})")
    return state
