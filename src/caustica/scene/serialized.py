"""Mitsuba's ``.serialized`` meshes (file format versions 3 and 4), read into an object-space Mesh.

The format (Mitsuba 3's src/shapes/serialized.cpp documents it): each mesh is a little-endian header
(uint16 0x041C, uint16 version) followed by a zlib stream holding a uint32 flag word (0x0001 vertex normals,
0x0002 texture coordinates, 0x0008 vertex colours, 0x2000 double precision), the shape's name as a
null-terminated string (version 4 only), uint64 vertex and triangle counts, then the positions, normals,
texture coordinates and colours (3, 3, 2 and 3 numbers per vertex, float32 or float64) and uint32 vertex
indices, 3 per triangle.  Several meshes are concatenated; the file ends with the offset of each (uint64 in
version 4, uint32 in version 3) and their count (uint32), which ``shape_index`` picks from.  Version 5
(Mitsuba's packed records) is refused with a message.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import SceneError
from .description import Mesh
from .transforms import INT32_MAX, MAX_ABS_FLOAT

MAGIC = 0x041C
VERSIONS = (3, 4)
HAS_NORMALS, HAS_TEXCOORDS, HAS_COLORS, DOUBLE_PRECISION = 0x0001, 0x0002, 0x0008, 0x2000


def _offset(data: bytes, version: int, index: int, path: Path) -> int:
    """Where mesh number ``index`` starts (the end-of-file dictionary)."""
    if index == 0:
        return 0
    if len(data) < 4:
        raise SceneError(f"mesh file '{path}' is cut short (no end-of-file dictionary)")
    (count,) = struct.unpack_from("<I", data, len(data) - 4)
    if index >= count:
        raise SceneError(f"mesh file '{path}' holds {count} meshes (shape_index 0..{count - 1}); "
                         f"shape_index {index} is out of range")
    size = 8 if version == 4 else 4
    pos = len(data) - 4 - size * (count - index)
    if pos < 0:
        raise SceneError(f"mesh file '{path}': its end-of-file dictionary is cut short")
    (off,) = struct.unpack_from("<Q" if size == 8 else "<I", data, pos)
    return int(off)


def load_serialized(path: str | Path, shape_index: int = 0) -> Mesh:
    """Mesh ``shape_index`` of a Mitsuba ``.serialized`` file (positions, triangles, vertex normals and texture
    coordinates if stored, as stored);
    SceneError naming the file for anything it cannot read."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"mesh file '{path}' cannot be read: {exc.strerror or exc}") from None
    if len(data) < 4:
        raise SceneError(f"mesh file '{path}' is not a Mitsuba .serialized file (too short)")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != MAGIC:
        raise SceneError(f"mesh file '{path}' is not a Mitsuba .serialized file (it does not start with 0x041C)")
    if version not in VERSIONS:
        raise SceneError(f"mesh file '{path}': .serialized version {version} is not supported; supported: 3, 4")
    if shape_index < 0:
        raise SceneError(f"shape_index must not be negative, got {shape_index}")
    start = _offset(data, version, shape_index, path)
    if start + 4 > len(data) or struct.unpack_from("<HH", data, start) != (magic, version):
        raise SceneError(f"mesh file '{path}': mesh {shape_index} does not start where the file's dictionary says")
    try:
        body = zlib.decompressobj().decompress(data[start + 4:])
    except zlib.error as exc:
        raise SceneError(f"mesh file '{path}': mesh {shape_index} cannot be decompressed ({exc})") from None
    try:
        return _parse(body, version, path)
    except (struct.error, ValueError) as exc:
        raise SceneError(f"mesh file '{path}': mesh {shape_index} is cut short or corrupt ({exc})") from None


def _parse(body: bytes, version: int, path: Path) -> Mesh:
    (flags,) = struct.unpack_from("<I", body, 0)
    pos = 4
    if version == 4:
        end = body.index(b"\0", pos)   # the shape's name
        pos = end + 1
    n_vertices, n_triangles = struct.unpack_from("<QQ", body, pos)
    pos += 16
    if n_vertices > INT32_MAX or n_triangles > INT32_MAX:
        raise SceneError(f"mesh file '{path}': {n_vertices:,} vertices and {n_triangles:,} triangles; "
                         f"caustica's meshes hold at most {INT32_MAX:,} (int32) of each")
    dtype = np.dtype("<f8") if flags & DOUBLE_PRECISION else np.dtype("<f4")

    def take(count: int, dt: np.dtype) -> np.ndarray:
        nonlocal pos
        n = count * dt.itemsize
        if pos + n > len(body):
            raise ValueError(f"{len(body):,} bytes hold fewer values than the header declares")
        out = np.frombuffer(body, dtype=dt, count=count, offset=pos)
        pos += n
        return out

    positions = take(3 * n_vertices, dtype).astype(np.float64).reshape(-1, 3)
    normals = take(3 * n_vertices, dtype).astype(np.float64).reshape(-1, 3) if flags & HAS_NORMALS else None
    uvs = take(2 * n_vertices, dtype).astype(np.float64).reshape(-1, 2) if flags & HAS_TEXCOORDS else None
    if flags & HAS_COLORS:
        take(3 * n_vertices, dtype)
    triangles = take(3 * n_triangles, np.dtype("<u4")).astype(np.int64).reshape(-1, 3)
    if n_triangles == 0 or n_vertices == 0:
        raise SceneError(f"mesh file '{path}' holds no triangles")
    if triangles.max() >= n_vertices:
        raise SceneError(f"mesh file '{path}': a face refers to a vertex that does not exist")
    bad = ~(np.abs(positions).max(axis=1) <= MAX_ABS_FLOAT)
    if bad.any():
        i = int(np.argmax(bad))
        raise SceneError(f"mesh file '{path}': vertex {i} is {tuple(float(c) for c in positions[i])}; "
                         f"coordinates must be finite numbers within ±{MAX_ABS_FLOAT:.3g}")
    if normals is not None:
        lengths = np.linalg.norm(normals, axis=1, keepdims=True)
        if not np.all(np.isfinite(normals)) or np.any(lengths == 0.0):
            normals = None
        else:
            normals = np.ascontiguousarray(normals / lengths)
    if uvs is not None and not np.all(np.isfinite(uvs)):
        uvs = None
    return Mesh(np.ascontiguousarray(positions), np.ascontiguousarray(triangles), normals,
                None if uvs is None else np.ascontiguousarray(uvs))
