"""Emitters: area lights (one-sided Lambertian, on any shape) and point lights.

A :class:`LightTable` lists every emitter once: area emitters first (one per
emissive shape, in scene order, matching ``Geometry.prim_emitter``), then point
lights.  Lights are chosen in proportion to their power (mean over RGB), both for
next-event estimation and for photon emission.

Power of a one-sided Lambertian area emitter of radiance L and area A is
Φ = π L A; of a point light of intensity I it is Φ = 4 π I (watts per channel).

Points on an area emitter are sampled uniformly by area.  A rectangle (a
parallelogram of two triangles) is sampled through its own (u, v) parametrisation,
so a regular grid of (u, v) lands on a regular grid on the light (the paper's
"25 point lights distributed evenly"); other shapes pick a primitive by area and
sample it uniformly.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .geometry import vec
from .geometry.scene_geometry import Geometry, sample_on_primitive
from .jit import kernel
from .scene.description import SceneDescription

AREA = 0
POINT = 1


class LightTable(NamedTuple):
    kind: np.ndarray          # int32[L]: AREA or POINT
    radiance: np.ndarray      # float64[L, 3]: radiance (area) or intensity W/sr (point)
    position: np.ndarray      # float64[L, 3]: point lights' position
    area: np.ndarray          # float64[L]: total area of an area emitter
    power: np.ndarray         # float64[L, 3]: emitted power per channel (W)
    select_pdf: np.ndarray    # float64[L]: probability of choosing the light
    select_cdf: np.ndarray    # float64[L]: running sum of select_pdf (last = 1)
    prim_first: np.ndarray    # int32[L]: first index into prims / prim_cdf
    prim_count: np.ndarray    # int32[L]
    prims: np.ndarray         # int32[*]: the emitters' primitives (Geometry.emitter_prim_ids)
    prim_cdf: np.ndarray      # float64[*]: area CDF within each emitter (Geometry.emitter_cdf)
    is_parallelogram: np.ndarray  # int8[L]: 1 when sampled through corner + u e1 + v e2
    corner: np.ndarray        # float64[L, 3]
    edge1: np.ndarray         # float64[L, 3]
    edge2: np.ndarray         # float64[L, 3]
    normal: np.ndarray        # float64[L, 3]: the parallelogram's front normal


def _parallelogram(shape):
    """(corner, e1, e2, normal) if the emissive shape is one planar quad of two triangles."""
    mesh = shape.mesh
    if mesh is None or len(mesh.triangles) != 2 or len(mesh.positions) != 4:
        return None
    p = mesh.positions
    # A parallelogram has one corner c with neighbours a, b such that the fourth = a + b - c.
    for c in range(4):
        others = [i for i in range(4) if i != c]
        for far in others:
            a, b = [i for i in others if i != far]
            if np.allclose(p[a] + p[b] - p[c], p[far], atol=1e-9 * (1 + np.abs(p).max())):
                e1, e2 = p[a] - p[c], p[b] - p[c]
                t = mesh.triangles[0]
                n = np.cross(p[t[1]] - p[t[0]], p[t[2]] - p[t[0]])
                return p[c], e1, e2, n / np.linalg.norm(n)
    return None


def build_light_table(desc: SceneDescription, geom: Geometry) -> LightTable:
    emissive = [s for s in desc.shapes if s.emitter_radiance is not None]
    n_area = len(emissive)
    n = n_area + len(desc.point_lights)
    kind = np.zeros(n, np.int32)
    radiance = np.zeros((n, 3))
    position = np.zeros((n, 3))
    area = np.zeros(n)
    power = np.zeros((n, 3))
    first = np.zeros(n, np.int32)
    count = np.zeros(n, np.int32)
    is_para = np.zeros(n, np.int8)
    corner = np.zeros((n, 3))
    edge1 = np.zeros((n, 3))
    edge2 = np.zeros((n, 3))
    normal = np.zeros((n, 3))
    for e, shape in enumerate(emissive):
        # The geometry lists each emitter's primitives with their area CDF (CSR).
        first[e] = geom.emitter_offset[e]
        count[e] = geom.emitter_offset[e + 1] - geom.emitter_offset[e]
        kind[e] = AREA
        radiance[e] = shape.emitter_radiance
        area[e] = geom.emitter_area[e]
        power[e] = math.pi * area[e] * np.asarray(shape.emitter_radiance)
        quad = _parallelogram(shape)
        if quad is not None:
            is_para[e] = 1
            corner[e], edge1[e], edge2[e], normal[e] = quad
    for j, light in enumerate(desc.point_lights):
        i = n_area + j
        kind[i] = POINT
        radiance[i] = light.intensity
        position[i] = light.position
        power[i] = 4.0 * math.pi * np.asarray(light.intensity)
    scalar = power.mean(axis=1)
    total_power = scalar.sum()
    select_pdf = scalar / total_power if total_power > 0 else np.zeros(n)
    select_cdf = np.cumsum(select_pdf)
    if n:
        select_cdf[-1] = 1.0
    return LightTable(kind, radiance, position, area, power, select_pdf, select_cdf,
                      first, count, geom.emitter_prim_ids.astype(np.int32),
                      geom.emitter_cdf.astype(np.float64), is_para,
                      corner, edge1, edge2, normal)


@kernel
def find_cdf(cdf, first, count, u):
    """Index in [first, first + count) of the first cdf entry above u (binary search)."""
    lo = first
    hi = first + count - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= u:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel
def choose_light(lights, u):
    """A light chosen in proportion to power: (index, probability, u rescaled to [0,1))."""
    n = lights.kind.shape[0]
    i = find_cdf(lights.select_cdf, 0, n, u)
    lo = lights.select_cdf[i - 1] if i > 0 else 0.0
    p = lights.select_pdf[i]
    u_rest = (u - lo) / p if p > 0.0 else 0.0
    return i, p, min(max(u_rest, 0.0), 0.99999999)


@kernel(inline=True)
def parallelogram_point(lights, e, u1, u2):
    """corner + u1 edge1 + u2 edge2 on rectangle emitter e: (position, front normal)."""
    c = vec.row(lights.corner, e)
    p = vec.madd(vec.madd(c, vec.row(lights.edge1, e), u1), vec.row(lights.edge2, e), u2)
    return p, vec.row(lights.normal, e)


@kernel
def sample_emitter_primitives(lights, geom, e, u1, u2):
    """A point uniformly by area on emitter e via its primitives' area CDF: (position, front normal)."""
    first = lights.prim_first[e]
    count = lights.prim_count[e]
    j = find_cdf(lights.prim_cdf, first, count, u1)
    lo = lights.prim_cdf[j - 1] if j > first else 0.0
    width = lights.prim_cdf[j] - lo
    u1r = (u1 - lo) / width if width > 0.0 else 0.0
    u1r = min(max(u1r, 0.0), 0.99999999)
    return sample_on_primitive(geom, lights.prims[j], u1r, u2)


@kernel(inline=True)
def sample_area_emitter(lights, geom, e, u1, u2):
    """A point uniformly by area on area emitter e: (position, front normal); pdf = 1 / area[e].

    Rectangles take the fast path through their (u, v) parametrisation; the general
    path is a separate call so that the common case never touches ``geom``
    (binding Geometry's many arrays costs reference-count updates per call).
    """
    if lights.is_parallelogram[e] == 1:
        return parallelogram_point(lights, e, u1, u2)
    return sample_emitter_primitives(lights, geom, e, u1, u2)


@kernel
def total_power(lights):
    """Sum of all lights' power per channel (W)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for i in range(lights.kind.shape[0]):
        s0 += lights.power[i, 0]
        s1 += lights.power[i, 1]
        s2 += lights.power[i, 2]
    return (s0, s1, s2)
