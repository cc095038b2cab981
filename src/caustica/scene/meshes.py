"""Triangle meshes: OBJ/PLY files (through trimesh) and the built-in rectangle and cube.

Files are read with trimesh's own readers without processing, so vertices keep
their order and are not merged, and the file's vertex normals (OBJ ``vn``, PLY
``nx ny nz``) are kept for shading.  :func:`to_world_mesh` places a mesh in the
world the way Mitsuba does: points by the matrix, normals by its inverse transpose,
``flip_normals`` by reversing the winding and negating the normals.
"""
from __future__ import annotations

import io
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import SceneError, quoted
from .description import Mesh
from .transforms import INT32_MAX, MAX_ABS_FLOAT, check_transform, transform_normals, transform_points

#: Bytes of each PLY scalar type (the PLY spec's names and their sized aliases).
_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2,
              "uint16": 2, "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
              "double": 8, "float64": 8}


_OBJ_VT = re.compile(r"^[ \t]*vt[ \t]", re.M)


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


def _uv_of(geom: dict):
    """The per-vertex texture coordinates trimesh read (its TextureVisuals' uv), or None."""
    uv = getattr(geom.get("visual"), "uv", None)
    return None if uv is None or len(uv) == 0 else np.asarray(uv, dtype=np.float64).reshape(-1, 2)


def _single_geometry(loaded: dict, path: Path) -> dict:
    """trimesh's loaders return either one mesh's kwargs or a dict of named geometries."""
    if "geometry" in loaded:
        geoms = [g for g in loaded["geometry"].values() if g.get("faces") is not None]
        if len(geoms) == 1:
            return geoms[0]
        if not geoms:
            return {}
        # Several OBJ groups/materials: concatenate them into one mesh.
        verts, faces, normals, uvs, offset = [], [], [], [], 0
        has_n = all(g.get("vertex_normals") is not None for g in geoms)
        has_uv = all(_uv_of(g) is not None and len(_uv_of(g)) == len(g["vertices"]) for g in geoms)
        for g in geoms:
            v = np.asarray(g["vertices"], dtype=np.float64)
            verts.append(v)
            faces.append(_triangulate(g["faces"]) + offset)
            if has_n:
                normals.append(np.asarray(g["vertex_normals"], dtype=np.float64))
            if has_uv:
                uvs.append(_uv_of(g))
            offset += len(v)
        return {"vertices": np.concatenate(verts), "faces": np.concatenate(faces),
                "vertex_normals": np.concatenate(normals) if has_n else None,
                "uv": np.concatenate(uvs) if has_uv else None}
    return loaded


def _obj_text(data: bytes) -> str:
    """An OBJ file's text.  OBJ has no declared encoding and its numbers are ASCII; a name
    or comment in another encoding (Latin-1, say) is decoded byte for byte rather than
    handed to trimesh, whose fallback needs the optional charset_normalizer package."""
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _ply_checked(data: bytes, path: Path) -> bytes:
    """The PLY file's bytes once its header agrees with its data; SceneError otherwise.

    trimesh reads a header that promises more data than the file holds as an empty mesh
    (or tries to allocate it), so the element counts are checked here first: each must fit
    int32, and an ASCII body needs a line per element, a binary one at least the bytes of
    the fixed-size properties.  Non-ASCII bytes in the header (comments) become '?', since
    trimesh decodes the header as UTF-8.
    """
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise SceneError(f"mesh file '{path}' is not a PLY file (it must start with 'ply' "
                         f"and have an 'end_header' line)")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    header = data[:body_start].decode("latin-1").splitlines()
    fmt, elements = "", []  # elements: [name, count, fixed bytes per element, list count sizes, known]
    for line in header:
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) > 1:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            try:
                count = int(words[2])
            except ValueError:
                raise SceneError(f"mesh file '{path}': header line {quoted(line)} has no element count") from None
            if not 0 <= count <= INT32_MAX:
                raise SceneError(f"mesh file '{path}': its header declares {count:,} '{words[1][:20]}' elements; "
                                 f"caustica's meshes hold at most {INT32_MAX:,} (int32)")
            elements.append([words[1][:20], count, 0, 0, True])
        elif words[0] == "property" and elements:
            el = elements[-1]
            if len(words) >= 5 and words[1] == "list":
                el[3] += _PLY_SIZES.get(words[2], 0)
                el[4] &= words[2] in _PLY_SIZES
            elif len(words) >= 3:
                el[2] += _PLY_SIZES.get(words[1], 0)
                el[4] &= words[1] in _PLY_SIZES
    body = data[body_start:]
    declared = " and ".join(f"{count:,} '{name}'" for name, count, *_ in elements) or "no"
    if fmt == "ascii":
        needed = sum(el[1] for el in elements)
        lines = sum(1 for ln in body.splitlines() if ln.strip())
        if lines < needed:
            raise SceneError(f"mesh file '{path}': its header declares {declared} elements ({needed:,} lines of "
                             f"data), but only {lines:,} lines follow end_header; the file is cut short or "
                             f"its header is wrong")
    elif all(el[4] for el in elements):
        needed = sum(el[1] * (el[2] + el[3]) for el in elements)
        if len(body) < needed:
            raise SceneError(f"mesh file '{path}': its header declares {declared} elements (at least {needed:,} "
                             f"bytes of data), but only {len(body):,} bytes follow end_header; the file is cut "
                             f"short or its header is wrong")
    head = data[:body_start]
    if not head.isascii():
        head = bytes(b if b < 128 else 0x3F for b in head)
    return head + body


#: PLY vertex properties Mitsuba reads as positions, normals and texture coordinates (not attributes).
_VERTEX_RESERVED = {"x", "y", "z", "nx", "ny", "nz", "u", "v"}
#: The postfix of an attribute's k-th field, by the first field's (Mitsuba's ply.h): x y z w, r g b a, 0 1 2 3, 1 2 3 4.
_POSTFIXES = ("xr01", "yg12", "zb23", "wa34")


def _ply_values(a: np.ndarray) -> np.ndarray:
    """A PLY property's values as Mitsuba 3.9's PLY loader stores them (float32): floats as they are, ``uchar`` as
    its integers (0 to 255, not scaled), other integer types divided by their type's maximum and sRGB-decoded (its
    Struct's ``Normalized | Gamma`` conversion; measured with Mitsuba 3.9.1: a ushort 30000 reads 0.177)."""
    a = np.asarray(a)
    if a.dtype.kind == "f" or a.dtype == np.uint8:
        return a.astype(np.float32)
    x = a.astype(np.float64) / float(np.iinfo(a.dtype).max)
    with np.errstate(invalid="ignore"):
        x = np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)
    return x.astype(np.float32)


def ply_attributes(prefix: str, element, reserved: set) -> dict:
    """Mitsuba's mesh attributes of one PLY element (``vertex`` or ``face``; ``element`` a structured array):
    ``r g b [a]`` (or ``red green blue [alpha]``) become ``{prefix}color``; consecutive fields ``name_x name_y
    name_z`` (postfixes x y z w, r g b a, 0 1 2 3 or 1 2 3 4) become ``{prefix}name`` with 1 or 3 of them
    (``{prefix}name_color`` for r g b); others are ignored, as Mitsuba ignores them.  ``element``: the element's
    scalar properties in the file's order, name -> (rows,) array."""
    out, fields = {}, list(element)
    if {"r", "g", "b"} <= set(fields):
        colour = ["r", "g", "b"] + (["a"] if "a" in fields else [])
    elif {"red", "green", "blue"} <= set(fields):
        colour = ["red", "green", "blue"] + (["alpha"] if "alpha" in fields else [])
        reserved = reserved | set(colour)
    else:
        colour = None
    if colour:
        out[prefix + "color"] = np.column_stack([_ply_values(element[n]) for n in colour])
    reserved = reserved | {"r", "g", "b", "a"}
    groups, current, seen = [], None, set()   # current: [prefix, postfix column, fields]
    for n in fields:
        if n in reserved:
            continue
        head, _, post = n.rpartition("_")
        if not head or len(post) != 1:
            if current:
                groups.append(current)
            current = None
            continue
        if current and head != current[0]:
            groups.append(current)
            current = None
        if current is None:
            if head in seen:
                continue
            column = _POSTFIXES[0].find(post)
            if column < 0:
                continue
            current = [head, column, [n]]
            seen.add(head)
        elif len(current[2]) < 4 and post == _POSTFIXES[len(current[2])][current[1]]:
            current[2].append(n)
        else:
            current[2] = []   # an invalid sequence: Mitsuba ignores the attribute
    if current:
        groups.append(current)
    for head, column, members in groups:
        if len(members) in (1, 3):
            name = prefix + head + ("_color" if column == 1 else "")
            out[name] = np.column_stack([_ply_values(element[n]) for n in members])
    return out


def _ply_columns(element: dict) -> dict:
    """A PLY element trimesh read (a structured array when binary, a dict of (rows, 1) arrays when ASCII) as its
    scalar properties in the file's order, name -> (rows,) array (list properties left out)."""
    data, order = element.get("data"), list(element.get("properties", {}))
    if isinstance(data, np.ndarray) and data.dtype.names:
        get = {n: data[n] for n in data.dtype.names}
    elif isinstance(data, dict):
        get = data
    else:
        return {}
    out = {}
    for n in order:
        a = np.asarray(get.get(n)) if n in get else None
        if a is not None and a.dtype.names is None and (a.ndim == 1 or (a.ndim == 2 and a.shape[1] == 1)):
            out[n] = a.reshape(-1)
    return out


def _ply_mesh_attributes(geom: dict, faces) -> dict | None:
    """The vertex and face attributes of a PLY file trimesh read (its raw elements), face ones repeated for each
    triangle a polygon is cut into; None without any."""
    raw = (geom.get("metadata") or {}).get("_ply_raw") or {}
    out = {}
    vertex, face = (_ply_columns(raw.get(name, {})) for name in ("vertex", "face"))
    if vertex:
        present = set(vertex)
        reserved = set(_VERTEX_RESERVED)
        for a, b in (("texture_u", "texture_v"), ("s", "t")):
            if not {"u", "v"} <= present and {a, b} <= present:
                reserved |= {a, b}
                break
        out.update(ply_attributes("vertex_", vertex, reserved))
    if face:
        per_face = ply_attributes("face_", face, {"vertex_index", "vertex_indices"})
        if per_face:
            sizes = ([faces.shape[1]] * len(faces) if isinstance(faces, np.ndarray) and faces.ndim == 2
                     else [len(f) for f in faces])
            if len(sizes) == len(next(iter(per_face.values()))):
                repeat = np.maximum(np.asarray(sizes, dtype=np.int64) - 2, 0)
                out.update({k: np.repeat(v, repeat, axis=0) for k, v in per_face.items()})
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()} or None


def load_mesh_file(path: str | Path, kind: str | None = None, flip_tex_coords: bool | None = None) -> Mesh:
    """Read an OBJ or PLY file into an object-space :class:`Mesh`.

    kind: "obj" or "ply" (default: from the suffix).  Texture coordinates are kept as Mitsuba keeps them: v
    becomes 1 - v when ``flip_tex_coords`` (by default for OBJ, not for PLY, as in Mitsuba 3).  Raises
    SceneError naming the file when it is missing, unreadable, or holds no triangles.
    """
    path = Path(path)
    kind = (kind or path.suffix.lstrip(".")).lower()
    if not path.is_file():
        raise SceneError(f"mesh file '{path}' not found")
    if kind not in ("obj", "ply"):
        raise SceneError(f"mesh file '{path}': unknown mesh format {quoted(kind)}; supported: obj, ply")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"mesh file '{path}' cannot be read: {exc.strerror or exc}") from None
    if kind == "ply":
        data = _ply_checked(data, path)
    try:
        from trimesh.exchange.obj import load_obj
        from trimesh.exchange.ply import load_ply

        # A number beyond float32 in a PLY 'float' overflows in trimesh's cast: the result
        # is checked below, so numpy's warnings would only precede that error.
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            if kind == "obj":
                text = _obj_text(data)
                # With texture coordinates, a vertex may take a different vt in different faces: trimesh keeps
                # one per vertex when it keeps the file's order, so such a file is read unordered (each distinct
                # v/vt/vn corner its own vertex, as Mitsuba makes them; the triangles are the same).
                ordered = _OBJ_VT.search(text) is None
                loaded = load_obj(io.StringIO(text), maintain_order=ordered, skip_materials=True)
            else:
                loaded = load_ply(io.BytesIO(data))
        geom = _single_geometry(loaded, path)
    except Exception as exc:  # trimesh raises many kinds of errors on corrupt files
        raise SceneError(f"mesh file '{path}' cannot be read as {kind.upper()}: "
                         f"{type(exc).__name__}: {quoted(exc, 120)}") from None
    verts = geom.get("vertices")
    faces = geom.get("faces")
    if verts is None or faces is None or len(verts) == 0 or len(faces) == 0:
        raise SceneError(f"mesh file '{path}' holds no triangles")
    positions = np.ascontiguousarray(np.asarray(verts, dtype=np.float64).reshape(-1, 3))
    triangles = np.ascontiguousarray(_triangulate(faces))
    if len(positions) > INT32_MAX or len(triangles) > INT32_MAX:
        raise SceneError(f"mesh file '{path}': {len(positions):,} vertices and {len(triangles):,} triangles; "
                         f"caustica's meshes hold at most {INT32_MAX:,} (int32) of each")
    if triangles.min() < 0 or triangles.max() >= len(positions):
        raise SceneError(f"mesh file '{path}': a face refers to a vertex that does not exist")
    bad = ~(np.abs(positions).max(axis=1) <= MAX_ABS_FLOAT)
    if bad.any():
        i = int(np.argmax(bad))
        raise SceneError(f"mesh file '{path}': vertex {i} is {tuple(float(c) for c in positions[i])}; "
                         f"coordinates must be finite numbers within ±{MAX_ABS_FLOAT:.3g} (float32's range: "
                         f"a PLY 'float' beyond it reads as infinity)")
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
    uvs = geom["uv"] if "uv" in geom else _uv_of(geom)
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64).reshape(-1, 2)
        if len(uvs) != len(positions) or not np.all(np.isfinite(uvs)):
            uvs = None
        elif flip_tex_coords if flip_tex_coords is not None else kind == "obj":
            uvs = np.column_stack([uvs[:, 0], 1.0 - uvs[:, 1]])
    attributes = _ply_mesh_attributes(geom, faces) if kind == "ply" else None
    return Mesh(positions, triangles, normals, None if uvs is None else np.ascontiguousarray(uvs), attributes)


def rectangle_mesh() -> Mesh:
    """Mitsuba's rectangle: [-1, 1]^2 in the z = 0 plane, front side +z, 2 triangles; uv = ((x + 1) / 2, (y + 1) / 2)
    (Mitsuba 3's src/shapes/rectangle.cpp)."""
    p = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    t = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return Mesh(p, t, None, (p[:, :2] + 1.0) / 2.0)


#: Mitsuba 3's cube (src/shapes/cube.cpp) maps each face onto [0, 1]^2: per outward normal (axis, sign), the
#: coordinate that gives u and the one that gives v, each as (axis, sign): u = (1 + sign * p[axis]) / 2.
_CUBE_UV = {(0, -1.0): ((1, 1.0), (2, 1.0)), (0, 1.0): ((1, 1.0), (2, -1.0)),
            (1, -1.0): ((2, 1.0), (0, 1.0)), (1, 1.0): ((0, -1.0), (2, -1.0)),
            (2, -1.0): ((1, -1.0), (0, 1.0)), (2, 1.0): ((1, 1.0), (0, 1.0))}


def cube_mesh() -> Mesh:
    """Mitsuba's cube: [-1, 1]^3, outward-facing, 12 triangles, flat (no vertex normals).

    Each face has its own 4 vertices (24 in all, as Mitsuba's cube), so nothing is shared
    across the cube's edges.
    """
    positions, tris, uvs = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed, so u x v = n: CCW seen from outside
            c = n
            base = len(positions)
            corners = [c - u - v, c + u - v, c + u + v, c - u + v]
            positions += corners
            (ua, us), (va, vs) = _CUBE_UV[(axis, sign)]
            uvs += [((1.0 + us * q[ua]) / 2.0, (1.0 + vs * q[va]) / 2.0) for q in corners]
            tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return Mesh(np.array(positions, dtype=np.float64), np.array(tris, dtype=np.int64), None,
                np.array(uvs, dtype=np.float64))


def vertex_normals_by_angle(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit vertex normals of a mesh whose file has none, as Mitsuba 3 computes them (Mesh::
    recompute_vertex_normals, after Thuermer and Wuethrich, JGT 1998): each triangle's unit normal,
    weighted by the triangle's angle at the vertex, summed over the triangles using the vertex.
    Degenerate triangles add nothing; a vertex that gets no normal keeps that of its first triangle's
    geometry if any, else (1, 0, 0) (it shades nothing: only degenerate triangles use it)."""
    p = positions[triangles]                                     # (m, 3 corners, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 0
    n = np.where(ok[:, None], n / np.where(ok, length, 1.0)[:, None], 0.0)
    normals = np.zeros_like(positions, dtype=np.float64)
    for c in range(3):
        d0 = p[:, (c + 1) % 3] - p[:, c]
        d1 = p[:, (c + 2) % 3] - p[:, c]
        l0, l1 = np.linalg.norm(d0, axis=1), np.linalg.norm(d1, axis=1)
        good = ok & (l0 > 0) & (l1 > 0)
        cos = np.einsum("ij,ij->i", d0, d1) / np.where(good, l0 * l1, 1.0)
        angle = np.where(good, np.arccos(np.clip(cos, -1.0, 1.0)), 0.0)
        np.add.at(normals, triangles[:, c], n * angle[:, None])
    length = np.linalg.norm(normals, axis=1)
    bad = ~(length > 0)
    normals = normals / np.where(bad, 1.0, length)[:, None]
    normals[bad] = (1.0, 0.0, 0.0)
    return normals


#: Triangles whose winding :func:`to_world_mesh` checks at a time (about 200 MB of temporaries at most).
_WINDING_CHUNK = 1 << 20


def to_world_mesh(mesh: Mesh, to_world: np.ndarray | None, flip_normals: bool = False) -> Mesh:
    """A world-space copy of an object-space mesh.

    Points go through to_world, normals through its inverse transpose (renormalised);
    flip_normals reverses each triangle's winding and negates the normals.  A triangle whose vertex normals lie
    against its winding's normal (every triangle under a mirroring to_world, where the winding turns and the normals
    do not) has its winding reversed: Mitsuba evaluates a BSDF and an emitter in the shading frame, so its front
    side is the vertex normals' side, which is caustica's geometric front.
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
    if normals is not None:
        for start in range(0, triangles.shape[0], _WINDING_CHUNK):   # bounded temporaries on a large mesh
            t = triangles[start:start + _WINDING_CHUNK]
            p0 = positions[t[:, 0]]
            winding = np.cross(positions[t[:, 1]] - p0, positions[t[:, 2]] - p0)
            against = np.einsum("ij,ij->i", winding, normals[t[:, 0]] + normals[t[:, 1]] + normals[t[:, 2]]) < 0.0
            if against.any():
                t[against] = t[against][:, ::-1]
    return Mesh(np.ascontiguousarray(positions), np.ascontiguousarray(triangles),
                None if normals is None else np.ascontiguousarray(normals), mesh.uvs, mesh.attributes)
