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

**Emitters seen in glass.**  At glass the path takes one branch (reflection with the Fresnel
probability F), but an emitter met first along either branch is added with its expected weight
β F Le or β (1 − F) Le / η² at once, and the branch taken leaves its next hit's emission out: the
same expectation, without the rare spike of a light's reflection seen in a few passes only (on the
diacaustic scene the brightest noise of the caustic's pixels was the area light glinting in the
sphere's silhouette).  It costs one or two rays at each glass hit of a camera path.

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

from ..bsdf import dielectric_branches, mirror_reflect, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..lighting import direct_stratified, direct_stratified_qmc
from ..sampling.rng import KRONECKER_ALPHA, STREAM_CAMERA_SCRAMBLE, kronecker, path_key, sobol02, uniform
from ..scene.description import CONDUCTOR, DIFFUSE

INV_PI = 1.0 / math.pi


@kernel
def emitted_along(geom, lights, o, d):
    """The radiance of the emitter a ray from o along d meets first, front side (0 if none)."""
    prim, t, b1, b2 = intersect(geom, o, d, np.inf)
    if prim < 0:
        return (0.0, 0.0, 0.0)
    e = geom.prim_emitter[prim]
    if e < 0:
        return (0.0, 0.0, 0.0)
    _, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
    if vec.dot(d, ng) >= 0.0:
        return (0.0, 0.0, 0.0)
    return vec.row(lights.radiance, e)


@kernel(inline=True)
def glass_branch_number(first_glass, pass_index, qkey, key, dim):
    """The number that picks a glass branch: at the path's first glass point ``pass`` of a shifted
    Kronecker sequence (the branches stratified over the passes), later uniform(key, dim)."""
    if first_glass:
        return kronecker(pass_index, KRONECKER_ALPHA[0], uniform(qkey, 2))
    return uniform(key, dim)


@kernel(inline=True)
def glass_step(L, beta, Lr, Lt, F, eta, u, wr, wt):
    """At glass: the emitters seen along both branches added with their expected weights, then the branch u picks.

    Lr, Lt: the emission first met along the reflected and the refracted direction (Lt unused when
    F = 1).  An emitter seen along either branch is added with weight F or (1 - F) / η² rather than
    when the choice happens to take that branch: a light's reflection in the glass is a smooth term,
    not a rare spike; the branch taken must then leave its first hit's emission out.  Returns
    (L, the new direction, β for it).
    """
    L = vec.add(L, vec.mul(vec.hadamard(beta, Lr), F))
    inv_eta2 = 1.0 / (eta * eta)
    if F < 1.0:
        L = vec.add(L, vec.mul(vec.hadamard(beta, Lt), (1.0 - F) * inv_eta2))
    if u < F:
        return L, wr, beta
    return L, wt, vec.mul(beta, inv_eta2)


@kernel
def visible_point(geom, mats, lights, o, d, key, qkey, pass_index, n_strata, fixed_grid, max_specular):
    """Follow a camera ray to its visible point: (found, position, normal, weight W, radiance L_direct)."""
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    zero = (0.0, 0.0, 0.0)
    dim = 2
    depth = 0
    first_glass = True
    counted = False   # this hit's emission was already added, in expectation, at the glass before it
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            return False, zero, zero, zero, L
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        e = geom.prim_emitter[prim]
        if e >= 0 and front and not counted:
            L = vec.add(L, vec.hadamard(beta, vec.row(lights.radiance, e)))
        counted = False
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
            u = glass_branch_number(first_glass, pass_index, qkey, key, dim)
            first_glass = False
            wr, wt, F, eta = dielectric_branches(d, ng, ns, mats.eta[m])
            dim += 1
            beta = vec.hadamard(beta, rgb)
            Lr = emitted_along(geom, lights, vec.offset_origin(p, ng, wr), wr)
            Lt = emitted_along(geom, lights, vec.offset_origin(p, ng, wt), wt) if F < 1.0 else zero
            L, wi, beta = glass_step(L, beta, Lr, Lt, F, eta, u, wr, wt)
            counted = True   # the branch taken leaves its first hit's emission out
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
