"""Direct lighting at a diffuse point: shadow rays to the emitters.

Two estimators share the same light table:

* :func:`direct_one_sample` — one light chosen by power, one point on it; returns
  the contribution and the light-sampling pdf for multiple importance sampling
  (the path tracer).
* :func:`direct_stratified` — every emitter, ``n x n`` stratified points on each
  area light (or the fixed centres of the n x n grid), point lights exactly (the
  photon-mapping methods, SPEC §2).

Both return outgoing radiance *before* multiplying by the diffuse BSDF's
reflectance/π, i.e. they return E-like sums the caller scales by f_r.
"""
from __future__ import annotations

import math

from .emitters import AREA, choose_light, sample_area_emitter
from .geometry import vec
from .geometry.scene_geometry import occluded
from .jit import kernel
from .sampling.rng import KRONECKER_ALPHA, kronecker, uniform


@kernel(inline=True)
def visible(geom, p, ng, q, nq):
    """True when nothing blocks the segment from surface point p to light point q.

    Both ends are moved off their surfaces (p along ng, q along nq, a zero vector
    for a point light) before the shadow ray is traced, so neither the receiver
    nor the light's own surface counts as a blocker.
    """
    to_q = vec.sub(q, p)
    o = vec.offset_origin(p, ng, to_q)
    target = vec.offset_origin(q, nq, vec.neg(to_q))
    seg = vec.sub(target, o)
    dist = vec.length(seg)
    if dist <= 0.0:
        return True
    return not occluded(geom, o, vec.mul(seg, 1.0 / dist), dist)


@kernel(inline=True)
def area_light_geometry(geom, p, ng, ns, q, nq):
    """(cos θ_surface, cos θ_light, distance², shadow rays traced) between p and light point q;
    the cosines and distance are all 0 if q does not light p (behind either surface, or blocked).
    A shadow ray is traced (1) only when q is in front of both surfaces."""
    to_l = vec.sub(q, p)
    dist2 = vec.dot(to_l, to_l)
    if dist2 <= 0.0:
        return 0.0, 0.0, 0.0, 0
    wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
    cos_l = -vec.dot(nq, wi)
    cos_s = vec.dot(ns, wi)
    if cos_l <= 0.0 or cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return 0.0, 0.0, 0.0, 0
    if not visible(geom, p, ng, q, nq):
        return 0.0, 0.0, 0.0, 1
    return cos_s, cos_l, dist2, 1


@kernel(inline=True)
def point_light_geometry(geom, lights, li, p, ng, ns):
    """(cos θ_surface, distance², shadow rays traced) from point light li to p, cos 0 if it
    does not light p.  A shadow ray is traced (1) only when the light is in front of p."""
    q = vec.row(lights.position, li)
    to_l = vec.sub(q, p)
    dist2 = vec.dot(to_l, to_l)
    wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
    cos_s = vec.dot(ns, wi)
    if cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return 0.0, dist2, 0
    if not visible(geom, p, ng, q, (0.0, 0.0, 0.0)):
        return 0.0, dist2, 1
    return cos_s, dist2, 1


@kernel(hot=True)
def direct_one_sample(geom, lights, p, ng, ns, key, dim):
    """Incident irradiance-like term Σ L cos θ / pdf from one light sample, MIS-ready.

    Returns (contrib_rgb, pdf_light_solid_angle, cos_surface, is_area, shadow_rays) where
    contrib is L_e · cos θ_s / pdf (without f_r) and MIS weighting is left to the caller (it
    knows the BSDF pdf).  pdf is 0 for a point light (a delta: no MIS).  shadow_rays is the
    number of visibility rays traced (0 or 1), for ray counts.
    """
    zero = (0.0, 0.0, 0.0)
    if lights.kind.shape[0] == 0:
        return zero, 0.0, 0.0, False, 0
    li, sel_pdf, _ = choose_light(lights, uniform(key, dim))
    if lights.kind[li] == AREA:
        q, nq = sample_area_emitter(lights, geom, li, uniform(key, dim + 1), uniform(key, dim + 2))
        cos_s, cos_l, dist2, traced = area_light_geometry(geom, p, ng, ns, q, nq)
        if cos_s <= 0.0:
            return zero, 0.0, 0.0, True, traced
        pdf = sel_pdf * dist2 / (lights.area[li] * cos_l)
        return vec.mul(vec.row(lights.radiance, li), cos_s / pdf), pdf, cos_s, True, traced
    # a point light: irradiance I cos / r², chosen with probability sel_pdf
    cos_s, dist2, traced = point_light_geometry(geom, lights, li, p, ng, ns)
    if cos_s <= 0.0:
        return zero, 0.0, 0.0, False, traced
    return vec.mul(vec.row(lights.radiance, li), cos_s / (dist2 * sel_pdf)), 0.0, cos_s, False, traced


@kernel
def _stratified_irradiance(geom, lights, p, ng, ns, key, dim, n_strata, fixed_grid, pass_index):
    """Irradiance E at p from every light, area lights by n_strata x n_strata strata (SPEC §2).

    Stratum s = (i, j) is jittered by: its cell centre when ``fixed_grid``; else, when
    ``pass_index`` < 0, numbers dim + 2 s, dim + 2 s + 1 of ``key``; else frac(u + k alpha)
    over the passes k, u those numbers (a shifted Kronecker sequence).  Point lights exactly.
    """
    E = (0.0, 0.0, 0.0)
    n_total = n_strata * n_strata
    for li in range(lights.kind.shape[0]):
        if lights.kind[li] == AREA:
            acc = 0.0
            for s in range(n_total):
                i = s % n_strata
                j = s // n_strata
                if fixed_grid:
                    u1 = (i + 0.5) / n_strata
                    u2 = (j + 0.5) / n_strata
                elif pass_index < 0:
                    u1 = (i + uniform(key, dim + 2 * s)) / n_strata
                    u2 = (j + uniform(key, dim + 2 * s + 1)) / n_strata
                else:
                    u1 = (i + kronecker(pass_index, KRONECKER_ALPHA[1], uniform(key, dim + 2 * s))) / n_strata
                    u2 = (j + kronecker(pass_index, KRONECKER_ALPHA[2], uniform(key, dim + 2 * s + 1))) / n_strata
                q, nq = sample_area_emitter(lights, geom, li, u1, u2)
                cos_s, cos_l, dist2, _ = area_light_geometry(geom, p, ng, ns, q, nq)
                if cos_s > 0.0:
                    acc += cos_s * cos_l / dist2
            E = vec.madd(E, vec.row(lights.radiance, li), acc * lights.area[li] / n_total)
        else:
            cos_s, dist2, _ = point_light_geometry(geom, lights, li, p, ng, ns)
            E = vec.madd(E, vec.row(lights.radiance, li), cos_s / dist2)
    return E


@kernel
def direct_stratified_qmc(geom, lights, p, ng, ns, qkey, qdim, pass_index, n_strata):
    """``direct_stratified`` with each stratum's jitter from a shifted Kronecker sequence over passes.

    Stratum s of pass k is jittered by frac(u_s + k alpha) with u_s the pixel's own random shift
    (numbers qdim + 2 s, qdim + 2 s + 1 of qkey): each pass's point is uniform in its stratum,
    and over the passes the points of a stratum fill it evenly.
    """
    return _stratified_irradiance(geom, lights, p, ng, ns, qkey, qdim, n_strata, False, pass_index)


@kernel
def direct_stratified(geom, lights, p, ng, ns, key, dim, n_strata, fixed_grid):
    """Irradiance E = Σ_lights ∫ L cos θ dω at p, every light sampled (SPEC §2).

    Area lights: n_strata x n_strata stratified points (jittered, or the cell centres
    when fixed_grid is true: the paper's grid of point lights).  Point lights exactly.
    """
    return _stratified_irradiance(geom, lights, p, ng, ns, key, dim, n_strata, fixed_grid, -1)
