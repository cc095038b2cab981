"""The camera pass of the progressive methods: one visible point per pixel per pass (SPEC §7).

Each pass, pixel i sends one camera ray through a new jittered position.  It is
followed through mirrors and glass — glass picks reflection or refraction with the
Fresnel probability, as in the path tracer, so each pass sees one branch and the
passes average them — until it reaches a diffuse surface, escapes, or exceeds
``max_specular`` bounces.  Along the way the radiance of emitters it sees is added;
at the diffuse point the direct light from every emitter is added (n × n stratified
shadow rays per area light), and that point becomes the pixel's *visible point*:
position, shading normal on the viewed side, and weight W = β · ρ / π (the
throughput β of the specular chain times the diffuse BRDF), so that the photons'
flux Φ gathered there contributes W · Φ.

**Samples stratified over the passes.**  A pixel's passes are the samples of one
estimate, so the numbers that matter most are drawn from low-discrepancy sequences
indexed by the pass, each randomised per pixel (keys of ``STREAM_CAMERA_SCRAMBLE``):
the sub-pixel position is point ``pass`` of the 2-D Sobol' (0, 2)-sequence with a
random digital shift (:func:`~caustica.sampling.rng.sobol02`); the choice at the first
glass surface and each stratum's shadow-ray jitter at the visible point are points of
a randomly shifted Kronecker sequence (R_3, :func:`~caustica.sampling.rng.kronecker`).
Every single pass is still an unbiased sample (each point is uniform), and the points
of P passes cover the pixel, the Fresnel choice and the light evenly, where P
independent points clump: at 250 passes on the caustic scenes this halved the whole
image's error at equal passes (docs/progressive.md).  Later glass choices use the
pass's own random numbers (path i of the pass's camera stream), as does the
``--fixed-light-grid`` variant.  Everything is a function of (seed, pass, pixel), so
the bits do not depend on threads or on how passes are grouped.
"""
from __future__ import annotations

import math

import numpy as np

from ..bsdf import mirror_reflect, sample_dielectric, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..lighting import direct_stratified, direct_stratified_qmc
from ..sampling.rng import KRONECKER_ALPHA, STREAM_CAMERA_SCRAMBLE, kronecker, path_key, sobol02, uniform
from ..scene.description import CONDUCTOR, DIFFUSE

INV_PI = 1.0 / math.pi


@kernel
def visible_point(geom, mats, lights, o, d, key, qkey, pass_index, n_strata, fixed_grid, max_specular):
    """Follow a camera ray to its visible point: (found, position, normal, weight W, radiance L_direct)."""
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    zero = (0.0, 0.0, 0.0)
    dim = 2
    depth = 0
    first_glass = True
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
            if fixed_grid:
                E = direct_stratified(geom, lights, p, ng, ns, key, dim, n_strata, fixed_grid)
            else:
                E = direct_stratified_qmc(geom, lights, p, ng, ns, qkey, 3, pass_index, n_strata)
            L = vec.add(L, vec.hadamard(w, E))
            return True, p, ns, w, L
        depth += 1
        if depth > max_specular:
            return False, zero, zero, zero, L
        if kind == CONDUCTOR:
            wi = mirror_reflect(d, ng, ns)
            beta = vec.hadamard(beta, rgb)
        else:
            if first_glass:
                u = kronecker(pass_index, KRONECKER_ALPHA[0], uniform(qkey, 2))
                first_glass = False
            else:
                u = uniform(key, dim)
            wi, is_reflection, eta = sample_dielectric(d, ng, ns, mats.eta[m], u)
            dim += 1
            beta = vec.hadamard(beta, rgb)
            if not is_reflection:
                beta = vec.mul(beta, 1.0 / (eta * eta))
        o = vec.offset_origin(p, ng, wi)
        d = wi


@kernel
def visible_points(geom, mats, lights, cam, seed, stream, pass_index, n_strata, fixed_grid, max_specular,
                   vp_pos, vp_nrm, vp_weight, vp_found, direct, i0, i1):
    """The visible points of pixels [i0, i1) (row-major), and the radiance each pixel saw directly."""
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        key = path_key(seed, stream, i)
        qkey = path_key(seed, STREAM_CAMERA_SCRAMBLE, i)
        u1, u2 = sobol02(pass_index, qkey)
        o, d = generate_ray(cam, x, y, u1, u2)
        found, p, n, w, L = visible_point(geom, mats, lights, o, d, key, qkey, pass_index, n_strata, fixed_grid,
                                          max_specular)
        if not math.isfinite(L[0] + L[1] + L[2]):
            L = (0.0, 0.0, 0.0)
        for c in range(3):
            vp_pos[i, c] = p[c]
            vp_nrm[i, c] = n[c]
            vp_weight[i, c] = w[c]
            direct[i, c] = L[c]
        vp_found[i] = found
