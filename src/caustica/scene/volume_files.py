"""Reading Mitsuba's binary grid volumes (``.vol``), the data of a ``gridvolume``.

The format (Mitsuba 3's ``VolumeGrid``, little endian): the bytes ``VOL``, a version byte (3), an int32
encoding (1: float32), int32 resolutions nx, ny, nz, an int32 channel count, six float32 giving the data's
bounding box (x, y, z minimum, then maximum), then nx ny nz channels float32 values, x fastest: the value of
channel c of voxel (x, y, z) is number ((z ny + y) nx + x) channels + c.  Read with NumPy, checked before
anything is allocated: a file that is not a grid, a truncated one, a grid that would not fit in memory.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ParameterError, SceneError
from ..memory import check_budget

MAGIC = b"VOL"
VERSION = 3
FLOAT32 = 1
HEADER = np.dtype([("magic", "S3"), ("version", "u1"), ("encoding", "<i4"), ("res", "<i4", 3),
                   ("channels", "<i4"), ("bbox", "<f4", 6)])
#: Bytes a voxel value takes while a grid is loaded: the file's float32, and the scaled float32 copy the
#: medium table keeps (and a float64 check of its range, in chunks too small to count).
BYTES_PER_VALUE = 8


def read_grid(path: str | Path, channels: tuple[int, ...] = (1, 3),
              purpose: str = "a medium's sigma_t or albedo takes 1 (grey) or 3 (RGB)") -> tuple[np.ndarray, np.ndarray]:
    """(data float32 (nz, ny, nx, channels), bbox float64 (2, 3)) of the .vol file at ``path``.

    SceneError naming the file when it is not a version-3 float32 grid, has a channel count outside ``channels``
    (the message then says ``purpose``), is truncated, holds a value that is not a finite number, or would need
    more memory than a render may take."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(HEADER.itemsize)
            size = path.stat().st_size
    except OSError as exc:
        raise SceneError(f"grid volume '{path}' cannot be read: {exc.strerror}") from None
    if len(head) < 3 or head[:3] != MAGIC:
        raise SceneError(f"grid volume '{path}' is not a Mitsuba .vol file (it does not start with 'VOL')")
    if len(head) < HEADER.itemsize:
        raise SceneError(f"grid volume '{path}' is truncated: {size} bytes, shorter than the "
                         f"{HEADER.itemsize}-byte header")
    h = np.frombuffer(head, HEADER)[0]
    if h["version"] != VERSION:
        raise SceneError(f"grid volume '{path}' is version {h['version']}; Mitsuba 3 reads version {VERSION} only")
    if h["encoding"] != FLOAT32:
        raise SceneError(f"grid volume '{path}' has encoding {h['encoding']}; only {FLOAT32} (float32) is supported, "
                         f"as in Mitsuba 3")
    nx, ny, nz = (int(v) for v in h["res"])
    allowed, channels = channels, int(h["channels"])
    if min(nx, ny, nz) < 1:
        raise SceneError(f"grid volume '{path}' has resolution {nx} x {ny} x {nz}; each must be at least 1")
    if channels not in allowed:
        raise SceneError(f"grid volume '{path}' has {channels} channels; {purpose}")
    n = nx * ny * nz * channels
    try:
        check_budget(n * BYTES_PER_VALUE, f"grid volume '{path}' ({nx} x {ny} x {nz} voxels x {channels} channels)",
                     "use a coarser grid")
    except ParameterError as exc:
        raise SceneError(str(exc)) from None
    if size < HEADER.itemsize + 4 * n:
        raise SceneError(f"grid volume '{path}' is truncated: its header promises {nx} x {ny} x {nz} voxels x "
                         f"{channels} channels ({HEADER.itemsize + 4 * n:,} bytes), the file has {size:,}")
    data = np.fromfile(path, dtype="<f4", count=n, offset=HEADER.itemsize)
    if data.size < n:
        raise SceneError(f"grid volume '{path}' is truncated: {data.size:,} of its {n:,} values could be read")
    if not np.all(np.isfinite(data)):
        raise SceneError(f"grid volume '{path}' holds a value that is not a finite number")
    bbox = np.asarray(h["bbox"], np.float64).reshape(2, 3)
    return data.astype(np.float32).reshape(nz, ny, nx, channels), bbox


def write_grid(path: str | Path, data: np.ndarray, bbox=((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))) -> None:
    """Write ``data`` (nz, ny, nx) or (nz, ny, nx, channels) as a .vol file (for tests and tools)."""
    data = np.asarray(data, np.float32)
    if data.ndim == 3:
        data = data[..., None]
    nz, ny, nx, channels = data.shape
    head = np.zeros((), HEADER)
    head["magic"], head["version"], head["encoding"] = MAGIC, VERSION, FLOAT32
    head["res"], head["channels"] = (nx, ny, nz), channels
    head["bbox"] = np.asarray(bbox, np.float32).reshape(6)
    with open(path, "wb") as f:
        f.write(head.tobytes())
        f.write(np.ascontiguousarray(data, "<f4").tobytes())
