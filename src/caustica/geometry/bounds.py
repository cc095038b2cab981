"""Bounding spheres of shapes: what the caustic map aims its photons at (SPEC §3).

A caustic photon is aimed at the cone a shape's bounding sphere subtends from the
light, so every direction outside the shape's silhouette but inside the cone is a
photon wasted; a sphere that does not *contain* the shape would miss caustic paths
outright (a bias: the global map leaves those paths out).  So these spheres are
conservative first and tight second:

* analytic shapes from their canonical form and ``to_world`` (exact for a sphere
  under a similarity, a disk, and a cylinder whose axis is perpendicular to its
  cross-section; a bound through the largest singular value otherwise);
* meshes from their vertices: the centre is the best of Ritter's sphere (1990), the
  bounding box's centre and a few hundred Bădoiu–Clarkson steps (which converge to
  the minimal enclosing sphere) from Ritter's centre, and the radius is the largest
  distance from that centre to any vertex.  So the sphere always contains every
  vertex (hence every triangle: a ball is convex) and its radius is within a few
  percent of the minimal one (an exact minimal sphere, Welzl's algorithm, is not
  worth its cost here).

Every radius is padded by a relative 1e-9 so rounding cannot leave a surface point
just outside.
"""
from __future__ import annotations

import math

import numpy as np

from .primitives import CYLINDER, DISK, SPHERE

PAD = 1e-9
BC_STEPS = 256


def _max_dist(points: np.ndarray, c: np.ndarray) -> float:
    return float(np.sqrt(np.max(np.sum((points - c) ** 2, axis=1))))


def _ritter(points: np.ndarray) -> np.ndarray:
    """Ritter's centre: the diameter of two far-apart points, grown to take in every point."""
    x = points[0]
    y = points[np.argmax(np.sum((points - x) ** 2, axis=1))]
    z = points[np.argmax(np.sum((points - y) ** 2, axis=1))]
    c = 0.5 * (y + z)
    r = 0.5 * float(np.linalg.norm(z - y))
    for _ in range(10_000):   # grow towards the farthest point outside until none is left
        d2 = np.sum((points - c) ** 2, axis=1)
        i = int(np.argmax(d2))
        d = math.sqrt(float(d2[i]))
        if d <= r * (1.0 + 1e-12):
            return c
        new_r = 0.5 * (r + d)
        c = c + (points[i] - c) * ((new_r - r) / d)
        r = new_r
    return c   # the caller's radius is the largest distance from c, so c need not be converged


def enclosing_sphere(points) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of a sphere containing every point; within a few percent of the smallest."""
    p = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0)
    if p.shape[0] == 0:
        raise ValueError("enclosing_sphere: no points")
    best_c = 0.5 * (p.min(axis=0) + p.max(axis=0))
    best_r = _max_dist(p, best_c)
    c = _ritter(p)
    r = _max_dist(p, c)
    if r < best_r:
        best_c, best_r = c, r
    for i in range(1, BC_STEPS + 1):    # Bădoiu–Clarkson: step 1/(i+1) towards the farthest point
        far = p[np.argmax(np.sum((p - c) ** 2, axis=1))]
        c = c + (far - c) / (i + 1)
        r = _max_dist(p, c)
        if r < best_r:
            best_c, best_r = c, r
    return best_c, best_r * (1.0 + PAD)


def analytic_sphere(kind: int, m34: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, radius) of a sphere containing the canonical ``kind`` mapped by the 3x4 affine ``m34``.

    Canonical shapes (Mitsuba's): the unit sphere, the unit disk in z = 0, the unit
    cylinder x² + y² = 1, 0 <= z <= 1 (open).
    """
    lin = np.asarray(m34, dtype=np.float64)[:, :3]
    c = np.asarray(m34, dtype=np.float64)[:, 3]
    if kind == SPHERE:
        return c.copy(), float(np.linalg.norm(lin, 2)) * (1.0 + PAD)
    a = lin[:, :2]                     # the cross-section's map
    s = float(np.linalg.norm(a, 2))    # its largest stretch
    if kind == DISK:
        return c.copy(), s * (1.0 + PAD)
    if kind == CYLINDER:
        # x = c + A u + b z, u on the unit circle, z in [0, 1]; about m = c + b / 2 with w = z - 1/2:
        # |A u + b w|^2 = |A u|^2 + 2 w (A u . b) + w^2 |b|^2 <= s^2 + |A^T b| + |b|^2 / 4 (|w| <= 1/2),
        # exact when the axis b is perpendicular to the cross-section (A^T b = 0).
        b = lin[:, 2]
        r2 = s * s + float(np.linalg.norm(a.T @ b)) + 0.25 * float(b @ b)
        return c + 0.5 * b, math.sqrt(r2) * (1.0 + PAD)
    raise ValueError(f"analytic_sphere: unknown primitive kind {kind}")


def shape_bounding_sphere(geom, shape: int) -> tuple[np.ndarray, float]:
    """(centre, radius) of a sphere containing every primitive of ``shape`` in the Geometry ``geom``."""
    from .primitives import TRIANGLE
    prims = np.nonzero(geom.prim_shape == shape)[0]
    if prims.size == 0:
        raise ValueError(f"shape {shape} has no primitives")
    tris = prims[geom.prim_kind[prims] == TRIANGLE]
    others = prims[geom.prim_kind[prims] != TRIANGLE]
    spheres = []
    if tris.size:
        j = geom.prim_index[tris]
        p0 = geom.tri_p0[j]
        spheres.append(enclosing_sphere(np.concatenate([p0, p0 + geom.tri_e1[j], p0 + geom.tri_e2[j]])))
    for prim in others:
        a = geom.prim_index[prim]
        spheres.append(analytic_sphere(int(geom.ana_kind[a]), geom.ana_to_world[a]))
    if len(spheres) == 1:
        return spheres[0]
    # several parts (not produced by the scene loader today): a sphere about their spheres
    c = np.mean([s[0] for s in spheres], axis=0)
    return c, max(float(np.linalg.norm(s[0] - c)) + s[1] for s in spheres) * (1.0 + PAD)
