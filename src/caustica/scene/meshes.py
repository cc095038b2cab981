"""Triangle meshes: OBJ/PLY files (through trimesh) and the built-in rectangle and cube.

Files are read with trimesh's own readers without processing, so vertices keep
their order and are not merged, and the file's vertex normals (OBJ ``vn``, PLY
``nx ny nz``) are kept for shading.  :func:`to_world_mesh` places a mesh in the
world the way Mitsuba does: points by the matrix, normals by its inverse transpose,
``flip_normals`` by reversing the winding and negating the normals.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SceneError
from .description import Mesh
from .transforms import MAX_ABS_FLOAT, check_transform, transform_normals, transform_points


def _triangulate(faces) -> np.ndarray:
    """(m, k) polygon faces -> (m * (k - 2), 3) triangles by fans (as Mitsuba does for quads)."""
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        if faces.shape[1] == 3:
            return faces.astype(np.int64)
        faces = faces.tolist()
    tris = []
    for f in faces:
        f = list(f)
        for i in range(1, len(f) - 1):
            tris.append((f[0], f[i], f[i + 1]))
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _single_geometry(loaded: dict, path: Path) -> dict:
    """trimesh's loaders return either one mesh's kwargs or a dict of named geometries."""
    if "geometry" in loaded:
        geoms = [g for g in loaded["geometry"].values() if g.get("faces") is not None]
        if len(geoms) == 1:
            return geoms[0]
        if not geoms:
            return {}
        # Several OBJ groups/materials: concatenate them into one mesh.
        verts, faces, normals, offset = [], [], [], 0
        has_n = all(g.get("vertex_normals") is not None for g in geoms)
        for g in geoms:
            v = np.asarray(g["vertices"], dtype=np.float64)
            verts.append(v)
            faces.append(_triangulate(g["faces"]) + offset)
            if has_n:
                normals.append(np.asarray(g["vertex_normals"], dtype=np.float64))
            offset += len(v)
        return {"vertices": np.concatenate(verts), "faces": np.concatenate(faces),
                "vertex_normals": np.concatenate(normals) if has_n else None}
    return loaded


def load_mesh_file(path: str | Path, kind: str | None = None) -> Mesh:
    """Read an OBJ or PLY file into an object-space :class:`Mesh`.

    kind: "obj" or "ply" (default: from the suffix).  Raises SceneError naming the
    file when it is missing, unreadable, or holds no triangles.
    """
    path = Path(path)
    kind = (kind or path.suffix.lstrip(".")).lower()
    if not path.is_file():
        raise SceneError(f"mesh file '{path}' not found")
    try:
        from trimesh.exchange.obj import load_obj
        from trimesh.exchange.ply import load_ply

        with open(path, "rb") as f:
            if kind == "obj":
                loaded = load_obj(f, maintain_order=True, skip_materials=True)
            elif kind == "ply":
                loaded = load_ply(f)
            else:
                raise SceneError(f"mesh file '{path}': unknown mesh format '{kind}'; supported: obj, ply")
        geom = _single_geometry(loaded, path)
    except SceneError:
        raise
    except Exception as exc:  # trimesh raises many kinds of errors on corrupt files
        raise SceneError(f"mesh file '{path}' cannot be read as {kind.upper()}: "
                         f"{type(exc).__name__}: {exc}") from None
    verts = geom.get("vertices")
    faces = geom.get("faces")
    if verts is None or faces is None or len(verts) == 0 or len(faces) == 0:
        raise SceneError(f"mesh file '{path}' holds no triangles")
    positions = np.ascontiguousarray(np.asarray(verts, dtype=np.float64).reshape(-1, 3))
    triangles = np.ascontiguousarray(_triangulate(faces))
    if triangles.min() < 0 or triangles.max() >= len(positions):
        raise SceneError(f"mesh file '{path}': a face refers to a vertex that does not exist")
    if not np.all(np.isfinite(positions)):
        raise SceneError(f"mesh file '{path}': vertex positions contain NaN or infinity")
    normals = geom.get("vertex_normals")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if normals.shape != positions.shape or not np.all(np.isfinite(normals)):
            normals = None
        else:
            lengths = np.linalg.norm(normals, axis=1, keepdims=True)
            if np.any(lengths == 0.0):
                normals = None
            else:
                normals = np.ascontiguousarray(normals / lengths)
    return Mesh(positions, triangles, normals)


def rectangle_mesh() -> Mesh:
    """Mitsuba's rectangle: [-1, 1]^2 in the z = 0 plane, front side +z, 2 triangles."""
    p = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    t = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return Mesh(p, t, None)


def cube_mesh() -> Mesh:
    """Mitsuba's cube: [-1, 1]^3, outward-facing, 12 triangles, flat (no vertex normals).

    Each face has its own 4 vertices (24 in all, as Mitsuba's cube), so nothing is shared
    across the cube's edges.
    """
    positions, tris = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed, so u x v = n: CCW seen from outside
            c = n
            base = len(positions)
            positions += [c - u - v, c + u - v, c + u + v, c - u + v]
            tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return Mesh(np.array(positions, dtype=np.float64), np.array(tris, dtype=np.int64), None)


def to_world_mesh(mesh: Mesh, to_world: np.ndarray | None, flip_normals: bool = False) -> Mesh:
    """A world-space copy of an object-space mesh.

    Points go through to_world, normals through its inverse transpose (renormalised);
    flip_normals reverses each triangle's winding and negates the normals.
    """
    m = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
    try:
        check_transform(m)
    except ValueError as exc:
        raise SceneError(f"to_world: {exc}") from None
    positions = transform_points(m, mesh.positions)
    far = np.abs(positions).max(axis=1)
    if not np.all(far <= MAX_ABS_FLOAT):
        i = int(np.argmax(~(far <= MAX_ABS_FLOAT)))
        raise SceneError(f"to_world places vertex {i} at {tuple(float(c) for c in positions[i])}, beyond "
                         f"±{MAX_ABS_FLOAT:.3g} (float32's range, which the image uses)")
    normals = None if mesh.normals is None else transform_normals(m, mesh.normals)
    triangles = mesh.triangles.copy()
    if flip_normals:
        triangles = triangles[:, ::-1].copy()
        if normals is not None:
            normals = -normals
    return Mesh(np.ascontiguousarray(positions), np.ascontiguousarray(triangles),
                None if normals is None else np.ascontiguousarray(normals))
