"""The camera pass of the progressive methods: one visible point per pixel per pass (SPEC §7).

Each pass, pixel i sends one camera ray through a new jittered position (random
path i of the pass's camera stream).  It is followed through mirrors and glass —
glass picks reflection or refraction with the Fresnel probability, as in the path
tracer, so each pass sees one branch and the passes average them — until it reaches
a diffuse surface, escapes, or exceeds ``max_specular`` bounces.  Along the way the
radiance of emitters it sees is added; at the diffuse point the direct light from
every emitter is added (n × n stratified shadow rays per area light), and that point
becomes the pixel's *visible point*: position, shading normal on the viewed side,
and weight W = β · ρ / π (the throughput β of the specular chain times the diffuse
BRDF), so that the photons' flux Φ gathered there contributes W · Φ.
"""
from __future__ import annotations

import math

import numpy as np

from ..bsdf import mirror_reflect, sample_dielectric, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..lighting import direct_stratified
from ..sampling.rng import path_key, uniform
from ..scene.description import CONDUCTOR, DIFFUSE

INV_PI = 1.0 / math.pi


@kernel
def visible_point(geom, mats, lights, o, d, key, n_strata, fixed_grid, max_specular):
    """Follow a camera ray to its visible point: (found, position, normal, weight W, radiance L_direct)."""
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    zero = (0.0, 0.0, 0.0)
    dim = 2
    depth = 0
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            return False, zero, zero, zero, L
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        e = geom.prim_emitter[prim]
        if e >= 0 and front:
            L = vec.add(L, vec.hadamard(beta, vec.row(lights.radiance, e)))
        m = geom.prim_material[prim]
        kind = mats.kind[m]
        scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
        if not scatters:
            return False, zero, zero, zero, L
        rgb = vec.row(mats.rgb, m)
        if kind == DIFFUSE:
            w = vec.mul(vec.hadamard(beta, rgb), INV_PI)
            E = direct_stratified(geom, lights, p, ng, ns, key, dim, n_strata, fixed_grid)
            L = vec.add(L, vec.hadamard(w, E))
            return True, p, ns, w, L
        depth += 1
        if depth > max_specular:
            return False, zero, zero, zero, L
        if kind == CONDUCTOR:
            wi = mirror_reflect(d, ng, ns)
            beta = vec.hadamard(beta, rgb)
        else:
            wi, is_reflection, eta = sample_dielectric(d, ng, ns, mats.eta[m], uniform(key, dim))
            dim += 1
            beta = vec.hadamard(beta, rgb)
            if not is_reflection:
                beta = vec.mul(beta, 1.0 / (eta * eta))
        o = vec.offset_origin(p, ng, wi)
        d = wi


@kernel
def visible_points(geom, mats, lights, cam, seed, stream, n_strata, fixed_grid, max_specular,
                   vp_pos, vp_nrm, vp_weight, vp_found, direct, i0, i1):
    """The visible points of pixels [i0, i1) (row-major), and the radiance each pixel saw directly."""
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        key = path_key(seed, stream, i)
        o, d = generate_ray(cam, x, y, uniform(key, 0), uniform(key, 1))
        found, p, n, w, L = visible_point(geom, mats, lights, o, d, key, n_strata, fixed_grid, max_specular)
        if not math.isfinite(L[0] + L[1] + L[2]):
            L = (0.0, 0.0, 0.0)
        for c in range(3):
            vp_pos[i, c] = p[c]
            vp_nrm[i, c] = n[c]
            vp_weight[i, c] = w[c]
            direct[i, c] = L[c]
        vp_found[i] = found
