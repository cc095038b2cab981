"""Direct lighting at a diffuse point for the photon methods: shadow rays to every emitter (SPEC §2).

:func:`direct_stratified` — every emitter, ``n x n`` stratified points on each area light (or the
fixed centres of the n x n grid), point lights exactly, through media and null boundaries.  It
returns an irradiance-like E that the caller scales by f_r = ρ / π.  The path tracer's one-sample
estimate (with MIS) is :func:`caustica.media.light_sample`.
"""
from __future__ import annotations

import math

from .emitters import AREA, sample_area_emitter
from .geometry import vec
from .jit import kernel
from .media import medium_after, shadow_transmittance
from .sampling.rng import KRONECKER_ALPHA, kronecker, uniform


@kernel
def direct_stratified(tables, at, key, dim, n_strata, fixed_grid, pass_index):
    """Irradiance E = Σ_lights ∫ L T cos θ dω at ``at`` (a :class:`caustica.transport.ShadingPoint` on a
    surface), every light sampled (SPEC §2).

    Area lights: n_strata x n_strata strata; stratum s = (i, j) is jittered by its cell centre when
    ``fixed_grid`` (the paper's grid of point lights); else, when ``pass_index`` < 0, by numbers
    dim + 2 s, dim + 2 s + 1 of ``key``; else by frac(u + k alpha) over the passes k, u those numbers
    (a shifted Kronecker sequence: each pass's point is uniform in its stratum and a pixel's passes
    fill it evenly).  Point lights exactly.  Each shadow ray's visibility is its transmittance
    (:func:`caustica.media.shadow_transmittance`, from the medium on the light's side of the surface; 0 or 1
    in vacuum, with the vacuum arithmetic).  ``at``'s ng, ns: normals on the lit side; ng_front: the front.
    Returns E per channel, before the diffuse BRDF ρ / π.
    """
    geom, mats, lights, media = tables
    p, ng, ns, ng_front, shape, medium, _ = at
    E = (0.0, 0.0, 0.0)
    n_total = n_strata * n_strata
    for li in range(lights.kind.shape[0]):
        rad = vec.row(lights.radiance, li)
        if lights.kind[li] == AREA:
            acc = (0.0, 0.0, 0.0)
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
                to_l = vec.sub(q, p)
                dist2 = vec.dot(to_l, to_l)
                if not dist2 > 0.0:
                    continue
                wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
                cos_l = -vec.dot(nq, wi)
                cos_s = vec.dot(ns, wi)
                if cos_l <= 0.0 or cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0:
                    continue
                T, _ = shadow_transmittance(geom, mats, media, vec.offset_origin(p, ng, to_l),
                                     vec.offset_origin(q, nq, vec.neg(to_l)),
                                     medium_after(media, shape, ng_front, wi, medium))
                acc = vec.madd(acc, T, cos_s * cos_l / dist2)
            area = lights.area[li]
            E = (E[0] + rad[0] * (acc[0] * area / n_total), E[1] + rad[1] * (acc[1] * area / n_total),
                 E[2] + rad[2] * (acc[2] * area / n_total))
        else:
            q = vec.row(lights.position, li)
            to_l = vec.sub(q, p)
            dist2 = vec.dot(to_l, to_l)
            if not dist2 > 0.0:
                continue
            wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
            cos_s = vec.dot(ns, wi)
            if cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0:
                continue
            T, _ = shadow_transmittance(geom, mats, media, vec.offset_origin(p, ng, to_l), q,
                                 medium_after(media, shape, ng_front, wi, medium))
            E = vec.madd(E, vec.hadamard(rad, T), cos_s / dist2)
    return E
