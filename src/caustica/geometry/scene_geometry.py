"""The scene's geometry as flat arrays, and the four queries every method uses.

:func:`build_geometry` flattens a :class:`~caustica.scene.description.SceneDescription`
into a :class:`Geometry` (a ``NamedTuple`` of numpy arrays, passed to kernels as is)
and builds its BVH.  The kernels

* :func:`intersect`           closest hit,
* :func:`occluded`            any hit (shadow rays),
* :func:`surface_at`          hit point, geometric and shading normal,
* :func:`surface_uv`          surface coordinates (u, v) at a hit, for textures,
* :func:`sample_on_primitive` a point uniform by area on one primitive,
* :func:`sample_on_emitter`   a point uniform by area on one area emitter,

are Numba device functions: call them from other ``@kernel`` / ``@parallel_kernel``
code; they allocate nothing.  Pass them ``geom`` *borrowed*
(:func:`caustica.jit.borrowed`, which every range kernel applies to the scene tables
it receives): a borrowed Geometry carries no reference counts, so binding it to an
argument costs nothing, inlined or not.  (A plain Geometry costs an increment and a
decrement of each of its ~27 arrays per call: atomic operations, a few hundred ns,
contended across threads.)  :func:`intersect` and :func:`occluded` are
``inline=True`` and hand borrowed views (:func:`caustica.geometry.primitives.borrow`)
of the arrays the traversal needs to the compiled traversal; :func:`surface_at` is
an ordinary kernel, compiled once rather than once per call site (LLVM inlines it).

Primitives
----------
Every primitive has an id ``prim`` in ``[0, n_prims)``: first all mesh triangles
(shape by shape, in scene order), then the analytic shapes (sphere, disk, cylinder;
one primitive each, in scene order).  Per primitive: ``prim_kind`` (TRIANGLE,
SPHERE, DISK, CYLINDER of :mod:`caustica.geometry.primitives`), ``prim_index`` (row in
the ``tri_*`` or ``ana_*`` table), ``prim_material`` (``shape.material``),
``prim_emitter`` (area emitter index or -1), ``prim_shape`` (shape index) and
``prim_area`` (world-space area; pdf per unit area of :func:`sample_on_primitive`
is ``1 / prim_area[prim]``).

Emitters
--------
Area emitter ``e`` is the ``e``-th shape with ``emitter_radiance`` in scene order.
Its primitives are ``emitter_prim_ids[emitter_offset[e] : emitter_offset[e + 1]]``
with the running area fraction ``emitter_cdf`` (last entry of each range is 1), its
shape is ``emitter_shape[e]`` and its total area ``emitter_area[e]``
(:func:`emitter_prims` returns the same as a list of arrays for Python code).
Sampling an analytic emitter uniformly by area needs a similarity ``to_world``
(rotation, translation, *uniform* scale) for spheres and cylinders; disks accept any
affine map (a planar affine map keeps area ratios).  Otherwise :class:`SceneError`.

Front side and normals
----------------------
``ng`` is always the unit normal of the *front* side (Mitsuba's: mesh winding
counter-clockwise seen from the front, disk ``+z``, sphere and cylinder outward;
``flip_normals`` turns analytic shapes around, meshes arrive already flipped); it is
never turned towards the ray.  The shading normal ``ns`` is on the same side.

Self-intersection
-----------------
The queries accept hits with ``t`` strictly in ``(0, tmax)``; there is no
scene-scale epsilon.  A ray leaving a surface must start at
:func:`caustica.geometry.vec.offset_origin` (which moves it ~6e-6 relative off the
surface, far above the float64 error of the intersection tests).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..errors import SceneError
from ..jit import borrowed, kernel
from ..scene.description import CYLINDER as SHAPE_CYLINDER
from ..scene.description import DISK as SHAPE_DISK
from ..scene.description import MESH as SHAPE_MESH
from ..scene.description import SPHERE as SHAPE_SPHERE
from ..scene.description import SceneDescription, Shape
from . import primitives as pr
from .bvh import build_bvh, bvh_any_hit, bvh_closest_hit
from .primitives import CYLINDER, DISK, SPHERE, TRIANGLE
from .vec import dot


class Geometry(NamedTuple):
    """Structure-of-arrays scene geometry (world space, float64 positions, int32 indices).

    Shapes of the arrays: ``T`` triangles, ``A`` analytic shapes, ``N = T + A``
    primitives, ``M`` BVH nodes, ``E`` area emitters, ``S`` shapes.
    """
    # Triangles (T, 3): first vertex, edges p1 - p0 and p2 - p0, unit front normal,
    # unit shading normals at p0, p1, p2 (the geometric normal when the mesh has none).
    tri_p0: np.ndarray
    tri_e1: np.ndarray
    tri_e2: np.ndarray
    tri_ng: np.ndarray
    tri_n0: np.ndarray
    tri_n1: np.ndarray
    tri_n2: np.ndarray
    # Analytic shapes: kind (A,) int32, to_world / to_local (A, 3, 4), normal sign (A,) +1 / -1.
    ana_kind: np.ndarray
    ana_to_world: np.ndarray
    ana_to_local: np.ndarray
    ana_flip: np.ndarray
    # Primitives (N,).
    prim_kind: np.ndarray
    prim_index: np.ndarray
    prim_material: np.ndarray
    prim_emitter: np.ndarray
    prim_shape: np.ndarray
    prim_area: np.ndarray
    # BVH (see caustica.geometry.bvh): box (M, 6), node (M, 3) int32, order (N,) int32.
    bvh_box: np.ndarray
    bvh_node: np.ndarray
    bvh_order: np.ndarray
    # Area emitters (CSR over primitives).
    emitter_offset: np.ndarray   # (E + 1,) int32
    emitter_prim_ids: np.ndarray  # (sum,) int32
    emitter_cdf: np.ndarray      # (sum,) float64, running area fraction within each emitter
    emitter_area: np.ndarray     # (E,) float64
    emitter_shape: np.ndarray    # (E,) int32
    # Bounds: per shape (S, 6) and of the whole scene (6,): xmin, ymin, zmin, xmax, ymax, zmax.
    shape_box: np.ndarray
    scene_box: np.ndarray
    # Texture coordinates at each triangle's corners (T, 6): u0, v0, u1, v1, u2, v2 (a mesh without them has
    # (0, 0), (1, 0), (0, 1): uv = the barycentrics, as in Mitsuba); (0, 6) when no material is textured.
    tri_uv: np.ndarray

    @property
    def n_prims(self) -> int:
        return int(self.prim_kind.shape[0])

    @property
    def n_emitters(self) -> int:
        return int(self.emitter_area.shape[0])


# ---------------------------------------------------------------------------
# Building
# ---------------------------------------------------------------------------

def _f64(a, shape_tail=(3,)):
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape((-1,) + shape_tail))


def _i32(a):
    return np.ascontiguousarray(np.asarray(a, dtype=np.int32).reshape(-1))


def _unit_rows(v, fallback):
    """Rows of v normalised; rows of zero or non-finite length replaced by ``fallback``."""
    n = np.linalg.norm(v, axis=1)
    ok = np.isfinite(n) & (n > 0.0)
    out = np.array(fallback, dtype=np.float64, copy=True)
    out[ok] = v[ok] / n[ok, None]
    return out


def _mesh_triangles(shape: Shape):
    mesh = shape.mesh
    if mesh is None:
        raise SceneError(f"{shape.source}: mesh shape {shape.id!r} has no mesh data")
    pos = np.asarray(mesh.positions, dtype=np.float64)
    tri = np.asarray(mesh.triangles)
    if pos.ndim != 2 or pos.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3:
        raise SceneError(f"{shape.source}: mesh {shape.id!r} needs (n, 3) positions and (m, 3) triangles")
    if not np.all(np.isfinite(pos)):
        raise SceneError(f"{shape.source}: mesh {shape.id!r} has non-finite vertex positions")
    tri = tri.astype(np.int64)
    if tri.size and (tri.min() < 0 or tri.max() >= len(pos)):
        raise SceneError(f"{shape.source}: mesh {shape.id!r} has triangle indices outside its "
                         f"{len(pos)} vertices")
    p0 = pos[tri[:, 0]]
    e1 = pos[tri[:, 1]] - p0
    e2 = pos[tri[:, 2]] - p0
    c = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(c, axis=1)
    ng = _unit_rows(c, np.tile([0.0, 0.0, 1.0], (len(tri), 1)))
    if mesh.normals is not None:
        nrm = np.asarray(mesh.normals, dtype=np.float64)
        if nrm.shape != pos.shape:
            raise SceneError(f"{shape.source}: mesh {shape.id!r} has {len(nrm)} normals for "
                             f"{len(pos)} vertices")
        ns = [_unit_rows(nrm[tri[:, k]], ng) for k in range(3)]
    else:
        ns = [ng, ng, ng]
    if mesh.uvs is not None and len(mesh.uvs) == len(pos):
        uv = np.asarray(mesh.uvs, dtype=np.float64)[tri].reshape(-1, 6)
    else:
        uv = np.tile([0.0, 0.0, 1.0, 0.0, 0.0, 1.0], (len(tri), 1))
    return p0, e1, e2, ng, ns[0], ns[1], ns[2], area, uv


def _affine(shape: Shape):
    """(to_world 3x4, to_local 3x4) of an analytic shape, checked."""
    m = np.eye(4) if shape.to_world is None else np.asarray(shape.to_world, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise SceneError(f"{shape.source}: {shape.kind} {shape.id!r} needs a finite 4x4 to_world")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-12):
        raise SceneError(f"{shape.source}: {shape.kind} {shape.id!r} has a projective to_world; "
                         "only affine transforms are supported")
    lin = m[:3, :3]
    det = np.linalg.det(lin)
    scale = np.max(np.abs(lin)) if lin.size else 0.0
    if not np.isfinite(det) or abs(det) <= 1e-300 or abs(det) <= 1e-12 * scale ** 3:
        raise SceneError(f"{shape.source}: {shape.kind} {shape.id!r} has a singular to_world "
                         "(zero scale?)")
    inv = np.linalg.inv(m)
    return np.ascontiguousarray(m[:3]), np.ascontiguousarray(inv[:3])


def _similarity_scale(lin):
    """Uniform scale s if lin = s * orthogonal (to 1e-6 relative), else None."""
    g = lin.T @ lin
    s2 = np.trace(g) / 3.0
    if s2 <= 0.0 or np.max(np.abs(g - s2 * np.eye(3))) > 1e-6 * s2:
        return None
    return math.sqrt(s2)


def _analytic_area(kind: int, lin) -> float:
    """World area of the canonical shape mapped by the linear map ``lin``.

    Nanson's formula: dA_world = |det M| |M^-T n| dA_local.  Exact for similarities and
    the disk; Gauss-Legendre x periodic trapezoid quadrature (converges to ~1e-12) for
    an ellipsoid or elliptic cylinder.
    """
    det = abs(np.linalg.det(lin))
    mit = np.linalg.inv(lin).T
    s = _similarity_scale(lin)
    if kind == DISK:
        return float(det * np.linalg.norm(mit @ [0.0, 0.0, 1.0]) * math.pi)
    if kind == SPHERE:
        if s is not None:
            return 4.0 * math.pi * s * s
        z, wz = np.polynomial.legendre.leggauss(96)
        phi = (np.arange(192) + 0.5) * (2.0 * math.pi / 192)
        zz, pp = np.meshgrid(z, phi, indexing="ij")
        r = np.sqrt(1.0 - zz ** 2)
        n = np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1)
        f = np.linalg.norm(n @ mit.T, axis=-1)
        return float(det * np.sum(f * wz[:, None]) * (2.0 * math.pi / 192))
    if kind == CYLINDER:
        if s is not None:
            return 2.0 * math.pi * s * s
        phi = (np.arange(384) + 0.5) * (2.0 * math.pi / 384)
        n = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1)
        f = np.linalg.norm(n @ mit.T, axis=-1)
        return float(det * np.sum(f) * (2.0 * math.pi / 384))
    raise AssertionError(kind)


def _analytic_box(kind: int, m34):
    """Axis-aligned bounds (6,) of the canonical shape mapped by the 3x4 affine ``m34``."""
    lin = m34[:, :3]
    c = m34[:, 3]
    if kind == SPHERE:
        h = np.linalg.norm(lin, axis=1)
        lo, hi = c - h, c + h
    elif kind == DISK:
        h = np.linalg.norm(lin[:, :2], axis=1)
        lo, hi = c - h, c + h
    else:  # CYLINDER: union of the end disks
        h = np.linalg.norm(lin[:, :2], axis=1)
        c1 = c + lin[:, 2]
        lo = np.minimum(c, c1) - h
        hi = np.maximum(c, c1) + h
    pad = 1e-12 * (np.abs(lo) + np.abs(hi) + (hi - lo)) + 1e-300
    return np.concatenate([lo - pad, hi + pad])


_ANALYTIC_KIND = {SHAPE_SPHERE: SPHERE, SHAPE_DISK: DISK, SHAPE_CYLINDER: CYLINDER}


def _shape_parts(desc: SceneDescription):
    """Each shape of ``desc`` as triangles or one analytic primitive: (tri_parts, ana_parts, emitter_of_shape),
    tri_parts one (shape index, p0, e1, e2, ng, n0, n1, n2, area, uv) per mesh, ana_parts one (shape index, kind,
    to_world, to_local, flip, area) per analytic shape, emitter_of_shape: shape index -> emitter index."""
    tri_parts = []      # per mesh shape: (shape index, p0, e1, e2, ng, n0, n1, n2, area)
    ana_parts = []      # per analytic shape: (shape index, kind, to_world, to_local, flip, area)
    emitter_of_shape = {}
    for s_idx, shape in enumerate(desc.shapes):
        if shape.emitter_radiance is not None:
            emitter_of_shape[s_idx] = len(emitter_of_shape)
        if shape.kind == SHAPE_MESH:
            tri_parts.append((s_idx,) + _mesh_triangles(shape))
        elif shape.kind in _ANALYTIC_KIND:
            kind = _ANALYTIC_KIND[shape.kind]
            tw, tl = _affine(shape)
            if (shape.emitter_radiance is not None and kind != DISK
                    and _similarity_scale(tw[:, :3]) is None):
                raise SceneError(
                    f"{shape.source}: area emitter on {shape.kind} {shape.id!r} needs a to_world "
                    "with uniform scale (rotation, translation, uniform scale) so it can be "
                    "sampled uniformly by area; use a mesh for a stretched emitter")
            ana_parts.append((s_idx, kind, tw, tl, -1.0 if shape.flip_normals else 1.0,
                              _analytic_area(kind, tw[:, :3])))
        else:
            raise SceneError(f"{shape.source}: unsupported shape kind {shape.kind!r} "
                             "(supported: mesh, sphere, disk, cylinder)")

    return tri_parts, ana_parts, emitter_of_shape


def _bounds(prim_box, prim_shape, n_shapes):
    """Per-shape and scene bounds (lo, hi) from the primitives' ``prim_box`` (N, 6)."""
    N = prim_box.shape[0]
    shape_box = np.empty((n_shapes, 6))
    shape_box[:, :3] = np.inf
    shape_box[:, 3:] = -np.inf
    if N:
        np.minimum.at(shape_box[:, :3], prim_shape, prim_box[:, :3])
        np.maximum.at(shape_box[:, 3:], prim_shape, prim_box[:, 3:])
    scene_box = (np.concatenate([prim_box[:, :3].min(axis=0), prim_box[:, 3:].max(axis=0)])
                 if N else np.zeros(6))
    return np.ascontiguousarray(shape_box), np.ascontiguousarray(scene_box.astype(np.float64))


def _emitter_csr(desc, emitter_of_shape, prim_shape, prim_area) -> dict:
    """The area emitters' primitives (CSR: offsets, ids) with their area CDFs, total areas and shapes, as the
    ``emitter_*`` fields of :class:`Geometry`; SceneError for an emitter of zero area."""
    n_em = len(emitter_of_shape)
    offsets = [0]
    ids, cdfs, areas, em_shape = [], [], [], []
    for s_idx, e in sorted(emitter_of_shape.items(), key=lambda kv: kv[1]):
        prims = np.nonzero(prim_shape == s_idx)[0]
        a = prim_area[prims]
        total = float(a.sum())
        if not (total > 0.0) or not np.isfinite(total):
            raise SceneError(f"{desc.shapes[s_idx].source}: area emitter on shape "
                             f"{desc.shapes[s_idx].id!r} has zero surface area")
        c = np.cumsum(a) / total
        c[-1] = 1.0
        ids.append(prims)
        cdfs.append(c)
        areas.append(total)
        em_shape.append(s_idx)
        offsets.append(offsets[-1] + len(prims))
    return dict(
        emitter_offset=_i32(offsets),
        emitter_prim_ids=_i32(np.concatenate(ids) if ids else []),
        emitter_cdf=np.ascontiguousarray(np.concatenate(cdfs) if cdfs else np.zeros(0)),
        emitter_area=np.ascontiguousarray(np.array(areas, dtype=np.float64).reshape(n_em)),
        emitter_shape=_i32(em_shape))


def build_geometry(desc: SceneDescription) -> Geometry:
    """Flatten every shape of ``desc`` into primitive tables and build the BVH.

    Raises SceneError (naming ``shape.source``) for shapes it cannot represent.
    """
    tri_parts, ana_parts, emitter_of_shape = _shape_parts(desc)
    n_shapes = len(desc.shapes)
    T = sum(len(p[1]) for p in tri_parts)
    A = len(ana_parts)
    N = T + A

    def cat(k, tail=(3,)):
        if not tri_parts:
            return np.zeros((0,) + tail)
        return _f64(np.concatenate([p[k] for p in tri_parts]), tail)

    tri_p0, tri_e1, tri_e2, tri_ng = cat(1), cat(2), cat(3), cat(4)
    tri_n0, tri_n1, tri_n2 = cat(5), cat(6), cat(7)
    tri_area = np.concatenate([p[8] for p in tri_parts]) if tri_parts else np.zeros(0)
    textured = any(getattr(m, "texture", None) is not None or getattr(m, "mix_texture", None) is not None
                   or getattr(m, "anisotropic", False) for m in desc.materials)   # (anisotropic: dp/du from uv)
    textured = textured or any(s.emitter_texture is not None for s in desc.shapes)
    tri_uv = (_f64(np.concatenate([p[9] for p in tri_parts]), (6,)) if textured and tri_parts
              else np.zeros((0, 6)))
    tri_shape = (np.concatenate([np.full(len(p[1]), p[0]) for p in tri_parts])
                 if tri_parts else np.zeros(0, dtype=np.int64))

    ana_kind = _i32([p[1] for p in ana_parts])
    ana_to_world = np.ascontiguousarray(np.array([p[2] for p in ana_parts]).reshape(A, 3, 4))
    ana_to_local = np.ascontiguousarray(np.array([p[3] for p in ana_parts]).reshape(A, 3, 4))
    ana_flip = np.ascontiguousarray(np.array([p[4] for p in ana_parts], dtype=np.float64))
    ana_area = np.array([p[5] for p in ana_parts], dtype=np.float64)
    ana_shape = np.array([p[0] for p in ana_parts], dtype=np.int64)

    prim_kind = _i32(np.concatenate([np.full(T, TRIANGLE), ana_kind]))
    prim_index = _i32(np.concatenate([np.arange(T), np.arange(A)]))
    prim_shape = _i32(np.concatenate([tri_shape, ana_shape]))
    materials = np.array([s.material for s in desc.shapes], dtype=np.int64)
    emitters = np.array([emitter_of_shape.get(i, -1) for i in range(n_shapes)], dtype=np.int64)
    prim_material = _i32(materials[prim_shape] if N else [])
    prim_emitter = _i32(emitters[prim_shape] if N else [])
    prim_area = np.ascontiguousarray(np.concatenate([tri_area, ana_area]).astype(np.float64))

    # Primitive bounds.
    prim_box = np.empty((N, 6))
    if T:
        p1 = tri_p0 + tri_e1
        p2 = tri_p0 + tri_e2
        prim_box[:T, :3] = np.minimum(np.minimum(tri_p0, p1), p2)
        prim_box[:T, 3:] = np.maximum(np.maximum(tri_p0, p1), p2)
    for j, p in enumerate(ana_parts):
        prim_box[T + j] = _analytic_box(p[1], p[2])
    bvh_box, bvh_node, bvh_order = build_bvh(np.ascontiguousarray(prim_box))
    shape_box, scene_box = _bounds(prim_box, prim_shape, n_shapes)
    return Geometry(
        tri_p0=tri_p0, tri_e1=tri_e1, tri_e2=tri_e2, tri_ng=tri_ng,
        tri_n0=tri_n0, tri_n1=tri_n1, tri_n2=tri_n2,
        ana_kind=ana_kind, ana_to_world=ana_to_world, ana_to_local=ana_to_local, ana_flip=ana_flip,
        prim_kind=prim_kind, prim_index=prim_index, prim_material=prim_material,
        prim_emitter=prim_emitter, prim_shape=prim_shape, prim_area=prim_area,
        bvh_box=bvh_box, bvh_node=bvh_node, bvh_order=bvh_order,
        **_emitter_csr(desc, emitter_of_shape, prim_shape, prim_area),
        shape_box=shape_box, scene_box=scene_box, tri_uv=tri_uv,
    )


def emitter_prims(geom: Geometry) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each area emitter ``e``: ``(prim ids, their areas)``; ``areas.sum() == emitter_area[e]``."""
    out = []
    for e in range(geom.n_emitters):
        ids = geom.emitter_prim_ids[geom.emitter_offset[e]:geom.emitter_offset[e + 1]]
        out.append((ids.copy(), geom.prim_area[ids].copy()))
    return out


# ---------------------------------------------------------------------------
# Queries (device functions)
# ---------------------------------------------------------------------------

@kernel(inline=True)
def intersect(geom, o, d, tmax):
    """Closest hit of the ray ``o + t d`` (``d`` unit) with ``t`` in (0, tmax).

    Returns ``(prim, t, b1, b2)``: ``prim = -1`` and ``t = tmax`` on a miss; ``b1, b2``
    are barycentrics for triangles (0 for analytic shapes); pass them on to
    :func:`surface_at`.
    """
    return bvh_closest_hit(geom, o, d, tmax)


@kernel(inline=True)
def occluded(geom, o, d, tmax):
    """True when anything is hit with ``t`` in (0, tmax) (shadow rays; pass tmax slightly below the distance)."""
    return bvh_any_hit(geom, o, d, tmax)


@kernel(inline=True)
def surface_at(geom, prim, o, d, t, b1, b2):
    """``(p, ng, ns)`` at a hit from :func:`intersect`.

    ``ng`` is the unit normal of the primitive's front side (not turned towards the
    ray); ``ns`` the unit shading normal (interpolated vertex normals for meshes),
    flipped if needed to lie on the same side as ``ng``.
    """
    j = geom.prim_index[prim]
    if geom.prim_kind[prim] == TRIANGLE:
        b0 = 1.0 - b1 - b2
        p = (geom.tri_p0[j, 0] + b1 * geom.tri_e1[j, 0] + b2 * geom.tri_e2[j, 0],
             geom.tri_p0[j, 1] + b1 * geom.tri_e1[j, 1] + b2 * geom.tri_e2[j, 1],
             geom.tri_p0[j, 2] + b1 * geom.tri_e1[j, 2] + b2 * geom.tri_e2[j, 2])
        ng = (geom.tri_ng[j, 0], geom.tri_ng[j, 1], geom.tri_ng[j, 2])
        nx = b0 * geom.tri_n0[j, 0] + b1 * geom.tri_n1[j, 0] + b2 * geom.tri_n2[j, 0]
        ny = b0 * geom.tri_n0[j, 1] + b1 * geom.tri_n1[j, 1] + b2 * geom.tri_n2[j, 1]
        nz = b0 * geom.tri_n0[j, 2] + b1 * geom.tri_n1[j, 2] + b2 * geom.tri_n2[j, 2]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            ns = (nx / ln, ny / ln, nz / ln)
        else:
            ns = ng
        if dot(ns, ng) < 0.0:
            ns = (-ns[0], -ns[1], -ns[2])
        return p, ng, ns
    p, n = pr.analytic_surface(geom.prim_kind[prim], geom.ana_to_world, geom.ana_to_local, j, o, d, t)
    f = geom.ana_flip[j]
    ng = (n[0] * f, n[1] * f, n[2] * f)
    return p, ng, ng


#: The surface coordinates of a point without a texture (or in a medium): (u, v, triangle, b1, b2, dp/du), dp/du
#: (three numbers) set only at an anisotropic material's hit (caustica.transport.surface_interaction), zero elsewhere.
NO_UV = (0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@kernel(inline=True)
def surface_uv(geom, prim, o, d, t, b1, b2):
    """Mitsuba's surface coordinates (u, v) at a hit from :func:`intersect`: a triangle's corner coordinates
    interpolated with the barycentrics, an analytic shape's parametrisation
    (:func:`caustica.geometry.primitives.analytic_uv`); returned as (u, v, triangle, b1, b2), the triangle's row
    and barycentrics for mesh attributes (-1, 0, 0 on an analytic shape; :data:`NO_UV` where there is no texture), then
    a zero tangent (:data:`NO_UV`).  Only for scenes with a texture (``tri_uv`` is empty
    otherwise)."""
    return hit_uv((geom.prim_kind, geom.prim_index, geom.tri_uv, geom.ana_to_local), prim, (o, d, t), (b1, b2))


@kernel
def hit_uv(arrays, prim, ray, bary):
    """:func:`surface_uv` on the four arrays it reads, ``arrays`` = (prim_kind, prim_index, tri_uv, ana_to_local),
    ``ray`` = (o, d, t), ``bary`` = (b1, b2): called with these, not the whole Geometry, so that each call site
    passes little."""
    prim_kind, prim_index, w, to_local = arrays
    o, d, t = ray
    b1, b2 = bary
    j = prim_index[prim]
    if prim_kind[prim] == TRIANGLE:
        b0 = 1.0 - b1 - b2
        return (b0 * w[j, 0] + b1 * w[j, 2] + b2 * w[j, 4], b0 * w[j, 1] + b1 * w[j, 3] + b2 * w[j, 5],
                float(j), b1, b2, 0.0, 0.0, 0.0)
    u, v = pr.analytic_uv(prim_kind[prim], to_local, j, o, d, t)
    return u, v, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0


@kernel(inline=True)
def surface_tangents(geom, prim, o, d, t):
    """Mitsuba's position partials (dp/du, dp/dv) at a hit from :func:`intersect`, for the normal and bump maps
    (bsdfs/perturb.py): a triangle's edges in its (u, v) basis (its edges themselves where the mesh has no
    coordinates, uv being the barycentrics; zero where the corner coordinates are degenerate, as Mitsuba's), a
    sphere's (-y, x, 0) 2 pi and (z cos phi, z sin phi, -r) pi in its local frame, mapped to the world (Mitsuba 3's
    src/render/mesh.cpp, src/shapes/sphere.cpp).  Disks and cylinders are refused by the loader."""
    return hit_tangents((geom.prim_kind, geom.prim_index, geom.tri_e1, geom.tri_e2, geom.tri_uv, geom.ana_to_world,
                         geom.ana_to_local), prim, o, d, t)


@kernel
def hit_tangents(arrays, prim, o, d, t):
    """:func:`surface_tangents` on the arrays it reads (called, not inlined)."""
    prim_kind, prim_index, e1, e2, w, to_world, to_local = arrays
    j = prim_index[prim]
    if prim_kind[prim] == TRIANGLE:
        a = (e1[j, 0], e1[j, 1], e1[j, 2])
        b = (e2[j, 0], e2[j, 1], e2[j, 2])
        du0 = w[j, 2] - w[j, 0]
        dv0 = w[j, 3] - w[j, 1]
        du1 = w[j, 4] - w[j, 0]
        dv1 = w[j, 5] - w[j, 1]
        det = du0 * dv1 - dv0 * du1
        inv = 1.0 / det if det != 0.0 else 0.0
        dp_du = ((dv1 * a[0] - dv0 * b[0]) * inv, (dv1 * a[1] - dv0 * b[1]) * inv, (dv1 * a[2] - dv0 * b[2]) * inv)
        dp_dv = ((du0 * b[0] - du1 * a[0]) * inv, (du0 * b[1] - du1 * a[1]) * inv, (du0 * b[2] - du1 * a[2]) * inv)
        return dp_du, dp_dv
    ol = pr.xform_point(to_local, j, o)
    dl = pr.xform_vector(to_local, j, d)
    x = ol[0] + t * dl[0]
    y = ol[1] + t * dl[1]
    z = ol[2] + t * dl[2]
    r = math.sqrt(x * x + y * y + z * z)
    if r > 0.0:
        x, y, z = x / r, y / r, z / r
    rd = math.sqrt(x * x + y * y)
    dv = (z * x / rd, z * y / rd, -rd) if rd > 0.0 else (1.0, 0.0, 0.0)
    du = pr.xform_vector(to_world, j, (-y, x, 0.0))
    dv = pr.xform_vector(to_world, j, dv)
    return ((du[0] * 2.0 * math.pi, du[1] * 2.0 * math.pi, du[2] * 2.0 * math.pi),
            (dv[0] * math.pi, dv[1] * math.pi, dv[2] * math.pi))


@kernel(inline=True)
def sample_on_primitive(geom, prim, u1, u2):
    """``(p, ng)``: a point uniform by area on ``prim`` (pdf per area ``1 / prim_area[prim]``) and its front normal."""
    j = geom.prim_index[prim]
    if geom.prim_kind[prim] == TRIANGLE:
        p0 = (geom.tri_p0[j, 0], geom.tri_p0[j, 1], geom.tri_p0[j, 2])
        e1 = (geom.tri_e1[j, 0], geom.tri_e1[j, 1], geom.tri_e1[j, 2])
        e2 = (geom.tri_e2[j, 0], geom.tri_e2[j, 1], geom.tri_e2[j, 2])
        p = pr.sample_triangle(p0, e1, e2, u1, u2)
        return p, (geom.tri_ng[j, 0], geom.tri_ng[j, 1], geom.tri_ng[j, 2])
    p, n = pr.sample_analytic(geom.prim_kind[prim], geom.ana_to_world, geom.ana_to_local, j, u1, u2)
    f = geom.ana_flip[j]
    return p, (n[0] * f, n[1] * f, n[2] * f)


@kernel(inline=True)
def sample_on_emitter(geom, emitter, u0, u1, u2):
    """``(p, ng, prim)``: a point uniform by area on area emitter ``emitter``.

    ``u0`` picks the primitive in proportion to its area, ``u1, u2`` the point on
    it; the pdf per unit area is ``1 / emitter_area[emitter]``.
    """
    lo = geom.emitter_offset[emitter]
    hi = geom.emitter_offset[emitter + 1] - 1
    # First entry with cdf > u0 (binary search).
    while lo < hi:
        mid = (lo + hi) // 2
        if geom.emitter_cdf[mid] > u0:
            hi = mid
        else:
            lo = mid + 1
    prim = geom.emitter_prim_ids[lo]
    p, ng = sample_on_primitive(geom, prim, u1, u2)
    return p, ng, prim


# ---------------------------------------------------------------------------
# Batches and a brute-force reference (tests, benchmarks, debugging)
# ---------------------------------------------------------------------------

@kernel(inline=True)
def intersect_brute_force(geom, o, d, tmax):
    """Same result as :func:`intersect`, testing every primitive (reference for tests)."""
    best_prim = -1
    best_t = tmax
    best_b1 = 0.0
    best_b2 = 0.0
    for prim in range(geom.prim_kind.shape[0]):
        t, b1, b2 = pr.intersect_primitive(geom, prim, o, d, best_t)
        if t < best_t:
            best_prim = prim
            best_t = t
            best_b1 = b1
            best_b2 = b2
    return best_prim, best_t, best_b1, best_b2


@kernel
def intersect_rays(geom, origins, dirs, tmax):
    """:func:`intersect` for each row of ``origins``/``dirs`` (n, 3): arrays prim (int64), t, b1, b2."""
    geom = borrowed(geom)
    n = origins.shape[0]
    prim = np.empty(n, dtype=np.int64)
    tt = np.empty(n)
    bb1 = np.empty(n)
    bb2 = np.empty(n)
    for i in range(n):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        p, t, b1, b2 = intersect(geom, o, d, tmax)
        prim[i] = p
        tt[i] = t
        bb1[i] = b1
        bb2[i] = b2
    return prim, tt, bb1, bb2
