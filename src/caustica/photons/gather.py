"""The camera pass shared by every photon-mapping method (SPEC §2).

Camera rays are followed through mirrors and glass until they reach a diffuse
surface; a glossy surface (rough metal or glass) they pass as SPPM's camera paths do, by one
MIS-weighted light sample and the BSDF's own sample
(:func:`caustica.photons.visible_points.glossy_step`).  At the first :data:`SPLIT_DEPTH`
specular bounces a glass interface splits the ray into its reflected and refracted parts, weighted by Fresnel (so a
glass sphere shows its reflection, its refraction and its first inner reflection
without noise at one sample per pixel); deeper interfaces choose one branch with
the Fresnel probability, which is unbiased and avoids spending a full gather (25
shadow rays and a k-nearest search) on branches carrying a fraction of a percent.  At the diffuse point the
radiance is

    L = f_r · (E_direct + Σ_global W Φ + Σ_caustic W Φ),   f_r = ρ / π,

with E_direct from shadow rays to every emitter (n x n stratified samples on
area lights) and the photon-map sums of :mod:`caustica.photons.estimate`.
Emitters seen directly or through mirrors and glass add their radiance.  At a delta coating over a diffuse
lobe (plastic, :func:`caustica.bsdfs.coat`) the diffuse lobe's estimate is made there, f_r = A and the
photons and shadow rays weighted by the lobe's other factor B, and the coating's reflection is split off
as a glass's reflection is (at the first SPLIT_DEPTH bounces; deeper, one of the two with the BSDF's
sampling probability).  A glossy coating (roughplastic, :func:`caustica.bsdfs.rough_coat`) is taken as SPPM's
camera pass takes it (:func:`caustica.photons.visible_points.rough_coating_step`): its glossy lobe with its sampling
probability P, as a glossy vertex, else the diffuse lobe's estimate with f_r = A / (1 - P), B on photons and shadow
rays; with a caustic map (PM+C) that estimate is a split point, as sppm's with its caustic photons' own statistics:
the caustic map's records weighted by A + f_glossy / B (:func:`split_estimate`), and a path that took the coating
leaves out what it then meets through caustic casters alone (:func:`gather_radiance`'s ``claim``).  At narrow glossy
lobes beside a diffuse one, or a glossy transmission beside one (pplastic, principled, principledthin:
bsdfs.splits_lobes) the path picks its glossy lobes or its diffuse ones
(:func:`caustica.photons.visible_points.lobe_choice`, as sppm's): the glossy ones it follows as a glossy vertex of
those lobes, else it ends there and its estimate weights every photon of both maps and every shadow ray by the
diffuse lobes' f(d, wi) (:func:`diffuse_estimate`'s ``bsdf``, :func:`caustica.bsdfs.eval_radiance`), as
sppm's visible points weight their photons: L = β / (1 - Q) (Σ_shadow f L cos / p + Σ_p W f Φ_p).  At broader
reflections the estimate weighs them by the whole BSDF (L = β (Σ_shadow f L cos / p + Σ_p W f Φ_p)).
"""
from __future__ import annotations

import math

import numpy as np

from ..bsdfs import ANISOTROPIC, DELTA, DIFFUSE_REFLECTION, GLOSSY, GLOSSY_LOBES, SMOOTH, coat, colour, \
    delta_branches, has_null_lobe, oriented, resolve, splits_lobes, wrapped
from ..bsdfs.textures import needs_tangent, needs_uv
from ..camera import generate_ray, pixel_of
from ..emitters import ENV, env_radiance, radiance_at_hit
from ..features import has
from ..geometry import vec
from ..geometry.scene_geometry import NO_UV, intersect, surface_at, surface_uv
from ..jit import borrowed, kernel
from ..lighting import direct_stratified
from ..sampling.rng import STREAM_CAMERA, path_key, uniform
from ..scene.description import BLEND, BUMPMAP, NORMALMAP, NULL, PLASTIC, ROUGHPLASTIC
from ..transport import ShadingPoint, unwrap, with_tangent
from .estimate import flux_density, none_admitted
from .visible_points import BSDF_MATERIAL, bsdf_point, claim_at, claim_onward, claimed, escape_weight, glossy_step, \
    lobe_choice, rough_coating_step, seen_weight, split_diffuse, split_point

SPLIT_STACK = 8
#: Glass splits a camera ray into both branches only at its first SPLIT_DEPTH specular
#: bounces; deeper interactions choose one branch with the Fresnel probability.  (A null-thin crossing adds no
#: depth: each one before that depth pushes its reflection, null_thin_branch.)
SPLIT_DEPTH = 2
INV_PI = 1.0 / math.pi


@kernel(inline=True)
def push_branch(scratch, top, o, d, beta, depth):
    """Put a camera-path branch (origin, direction, throughput, specular depth) on the split stack at ``top``;
    the stack's new top."""
    vec.set_row(scratch[0], top, o)
    vec.set_row(scratch[1], top, d)
    vec.set_row(scratch[2], top, beta)
    scratch[3][top] = depth
    return top + 1


@kernel(inline=True)
def ends_at(max_depth, k):
    """Whether a camera path that reached a surface in k segments ends there (its emission added, nothing
    scattered): Mitsuba's ``max_depth`` reached.  Never without one (None)."""
    if max_depth is None:
        return False
    return k >= max_depth


@kernel(inline=True)
def diffuse_estimate(tables, lookup, params, at, lobe_b, bsdf, key, dim):
    """What arrives at the diffuse point ``at`` as an irradiance-like E (the caller scales it by f_r): shadow rays
    to every emitter (numbers from ``dim`` on; weighted by B of plastic ``lobe_b``'s coating, -1 for none) and
    both maps' k-nearest estimates.  ``lookup`` = (maps, estimate, (indices, squared distances), (max_depth, k):
    the records the estimates take, :func:`~caustica.photons.estimate.flux_density`).  With ``bsdf`` =
    (mats, m, d, ng, ns, uv) (the diffuse lobes beside a glossy one, or a diffuse lobe under a map) every shadow ray
    and every photon is weighted by the f(d, wi) of the lobes the point holds instead (:func:`caustica.bsdfs.
    eval_radiance`), and E is the radiance towards -d; None elsewhere (the Lambertian arithmetic, a
    separate compilation).  Returns (E, the dimension past the shadow rays' numbers, k-nearest searches made)."""
    (gmap, cmap), (k_g, r_g, k_c, r_c, filt), scratch, limit = lookup
    n_strata, fixed_grid = params[0], params[1]
    E = direct_stratified(tables, at, key, dim, (n_strata, fixed_grid, -1), lobe_b, bsdf)
    facing = at.ns   # the same-side test's normal: the geometric one under a map (the records carry theirs)
    if bsdf is not None and wrapped(bsdf[0], bsdf[1]):
        facing = at.ng
    Eg, _ = flux_density(gmap, (at.p, facing, limit), (k_g, r_g, filt), scratch, bsdf)
    Ec, _ = flux_density(cmap, (at.p, facing, limit), (k_c, r_c, filt), scratch, bsdf)
    queries = 0 if none_admitted(limit[0], limit[1]) else (gmap.position.shape[0] > 0) + (cmap.position.shape[0] > 0)
    return vec.add(E, vec.add(Eg, Ec)), dim + 2 * n_strata * n_strata, queries


@kernel(inline=True)
def split_estimate(tables, lookup, params, at, coating, key, dim):
    """At the split point of ``coating`` = (roughplastic m, the camera ray's direction d, the diffuse lobe's A), where
    the caustic map's records claim the glossy lobe's share of the caustic too (``claim``, :func:`gather_radiance`):
    A (E_direct + E_global) + Σ_caustic W (A + f_glossy / B) Φ, the shadow rays and the global map's records carrying
    the lobe's B as :func:`diffuse_estimate`'s, the caustic map's weighted by :func:`caustica.bsdfs.split_record_weight`
    (the caller scales it by β / (1 - P)).  Returns (that sum, the dimension past the shadow rays' numbers, k-nearest
    searches made)."""
    m, d, A = coating
    (gmap, cmap), (k_g, r_g, k_c, r_c, filt), scratch, limit = lookup
    n_strata, fixed_grid = params[0], params[1]
    E = direct_stratified(tables, at, key, dim, (n_strata, fixed_grid, -1), m, None)
    Eg, _ = flux_density(gmap, (at.p, at.ns, limit), (k_g, r_g, filt), scratch, None)
    Ec, _ = flux_density(cmap, (at.p, at.ns, limit), (k_c, r_c, filt), scratch, (tables[1], m, d, at.ng, at.ns, at.uv),
                         A)
    queries = 0 if none_admitted(limit[0], limit[1]) else (gmap.position.shape[0] > 0) + (cmap.position.shape[0] > 0)
    return vec.add(vec.hadamard(A, vec.add(E, Eg)), Ec), dim + 2 * n_strata * n_strata, queries


@kernel(inline=True)
def camera_surface(geom, mats, hit, o, d, key, dim):
    """The surface a camera ray from o along d meets at ``hit`` = (prim, t, b1, b2): (p, ng, ns, front, m, uv, passed,
    dim), a blend resolved to one of its parts with one number; ``passed``: that part is null, the ray goes on (a
    scene with a mask or null has media); a normal or bump map resolved to its nested material, ns perturbed
    (:func:`caustica.transport.unwrap`)."""
    prim, t, b1, b2 = hit
    p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
    front = vec.dot(d, ng) < 0.0
    m = geom.prim_material[prim]
    blend = has(mats, BLEND) and mats.kind[m] == BLEND
    uv = surface_uv(geom, prim, o, d, t, b1, b2) if needs_uv(mats, m) or blend else NO_UV
    passed = False
    if blend:
        m, dim = resolve(mats, m, uv, key, dim)
        passed = mats.kind[m] == NULL
    if has(mats, NORMALMAP) and mats.kind[m] == NORMALMAP or has(mats, BUMPMAP) and mats.kind[m] == BUMPMAP:
        m, ns, uv = unwrap(geom, mats, prim, (o, d, t, b1, b2), m, (ng, ns))
    if has(mats, ANISOTROPIC) and needs_tangent(mats, m):
        uv = with_tangent(geom, prim, (o, d, t, b1, b2), surface_uv(geom, prim, o, d, t, b1, b2))
    return p, ng, ns, front, m, uv, passed, dim


@kernel(inline=True)
def diffuse_or_coating(mats, m, d, at, path, stack, key, dim):
    """At a diffuse lobe: f_r = ρ / π.  Under a delta coating (plastic) the diffuse lobe's estimate is made with
    f = A B (the photons and shadow rays carry B); the coating's reflection is split off as glass's branches are
    (pushed on ``stack`` = (scratch, top)), or chosen with its sampling probability P (the estimate then weighted
    1 / (1 - P)).  ``path`` = (β, specular depth, max_specular).  Returns (take the coating, f_r, the coated lobe
    (-1: none), top, the coating's direction and weight, dim)."""
    beta, depth, max_specular = path
    scratch, top = stack
    fr = vec.mul(colour(mats, m, at.uv), INV_PI)
    lobe_b = -1
    wc, w_coat = d, fr
    if has(mats, PLASTIC) and mats.flags[m] & DELTA:
        wc, P, w_coat, A = coat(mats, m, d, at.ng, at.ns, at.uv)
        fr, lobe_b = A, m
        if depth < max_specular and P > 0.0:
            if depth < SPLIT_DEPTH and top < scratch[0].shape[0]:
                top = push_branch(scratch, top, vec.offset_origin(at.p, at.ng, wc), wc,
                                  vec.mul(vec.hadamard(beta, w_coat), P), depth + 1)
            else:
                u = uniform(key, dim)
                dim += 1
                if u < P:
                    return True, fr, lobe_b, top, wc, w_coat, dim
                fr = vec.mul(A, 1.0 / (1.0 - P))
    return False, fr, lobe_b, top, wc, w_coat, dim


@kernel(inline=True)
def delta_branch(mats, m, d, at, path, stack, key, dim):
    """At a mirror or glass: glass splits into reflection and refraction weighted by Fresnel (the reflection pushed
    on ``stack`` = (scratch, top)) at the first SPLIT_DEPTH bounces, deeper it takes one with the Fresnel
    probability.  ``path`` = (β, specular depth).  Returns (direction, β, top, dim)."""
    beta, depth = path
    scratch, top = stack
    d_r, d_t, F, eta, tints = delta_branches(mats, m, d, at.ng, at.ns, at.uv)
    beta_r, beta_t = vec.hadamard(beta, tints[0]), vec.hadamard(beta, tints[1])
    if F >= 1.0:
        return d_r, beta_r, top, dim
    if depth <= SPLIT_DEPTH and top < scratch[0].shape[0]:
        top = push_branch(scratch, top, vec.offset_origin(at.p, at.ng, d_r), d_r, vec.mul(beta_r, F), depth)
        return d_t, vec.mul(beta_t, (1.0 - F) / (eta * eta)), top, dim
    u = uniform(key, dim)
    if u < F:
        return d_r, beta_r, top, dim + 1
    return d_t, vec.mul(beta_t, 1.0 / (eta * eta)), top, dim + 1


@kernel(inline=True)
def null_thin_branch(mats, m, d, at, path, stack, key, dim):
    """At a thindielectric whose straight-on lobe is volpath's null event (``null_thin_dielectric``): the path goes
    on straight with (1 - R), no vertex, and the reflection, a vertex, is pushed on ``stack`` = (scratch, top) as
    :func:`delta_branch` pushes glass's; deeper, or when the stack is full, one of them is taken with the Fresnel
    probability.  ``path`` = (β, specular depth, max_specular, max_depth): no reflection where a vertex would pass
    either (then straight on with 1 - R).  A straight crossing counts towards neither limit (sppm's visible points
    count it towards max_specular, photons towards their SPECULAR_CAP).  Returns (alive, the direction, whether it
    is the reflection, β, top, dim)."""
    beta, depth, max_specular, max_depth = path
    scratch, top = stack
    d_r, _, F, _, tints = delta_branches(mats, m, d, at.ng, at.ns, at.uv)
    beta_r, beta_t = vec.hadamard(beta, tints[0]), vec.hadamard(beta, tints[1])
    reflects = not ends_at(max_depth, depth + 1) and depth + 1 <= max_specular
    if F >= 1.0:   # nothing passes straight on
        return reflects, d_r, True, beta_r, top, dim
    if depth + 1 <= SPLIT_DEPTH and top < scratch[0].shape[0]:
        if reflects:
            top = push_branch(scratch, top, vec.offset_origin(at.p, at.ng, d_r), d_r, vec.mul(beta_r, F), depth + 1)
        return True, d, False, vec.mul(beta_t, 1.0 - F), top, dim
    if not reflects:   # no reflection may follow: straight on with (1 - F), no number drawn
        return True, d, False, vec.mul(beta_t, 1.0 - F), top, dim
    u = uniform(key, dim)
    if u >= F:
        return True, d, False, beta_t, top, dim + 1
    return True, d_r, True, beta_r, top, dim + 1


@kernel(inline=True)
def camera_vertex(tables, lookups, at, m, path, stack, key, dim):
    """What :func:`gather_radiance`'s camera path does at ``at`` (material m; normals turned to the ray): an estimate
    that ends it, or a bounce it goes on by.  ``lookups`` = (the maps' lookup, gather_radiance's params); ``path`` =
    (L, β, d, specular depth, last, surfaces crossed since it, whether m is a null-thin thindielectric); ``stack`` =
    (scratch, top).  Returns (goes on, L, β, the new direction, depth, last, crossed, k-nearest searches, top,
    dim)."""
    mats = tables[1]
    lookup, params = lookups
    max_specular, max_depth = params[2], params[3]
    L, beta, d, depth, last, crossed, null_lobe = path
    scratch, top = stack
    p = at.p
    flags = mats.flags[m]
    wrap = wrapped(mats, m)   # under a normal or bump map
    if (has(mats, GLOSSY_LOBES) and flags & SMOOTH or wrap) and not flags & DIFFUSE_REFLECTION:
        # a glossy surface (or a mirror or glass under a map): no estimate here, the path goes on by the BSDF's
        # sample (as SPPM's camera paths)
        depth += 1
        if depth > max_specular:
            return False, L, beta, d, depth, last, crossed, 0, top, dim
        L, alive, wi, beta, lobe, pdf, dim = glossy_step(tables, at, m, d, (L, beta), key, dim)
        return alive, L, beta, wi, depth, (lobe & DELTA != 0, pdf, p), 0, 0, top, dim
    if splits_lobes(mats, m):
        # glossy lobes beside diffuse ones (pplastic, principled, principledthin; under a map too): a glossy one picked
        # goes on as a glossy vertex of those lobes alone, else the estimate here weighs each shadow ray and photon by
        # the diffuse lobes' f(d, wi) (as sppm's visible points: lobe_choice)
        glossy, L, alive, wi, w, pdf, dim = lobe_choice(tables, at, m, d, (L, beta), (key, dim), depth >= max_specular)
        if glossy:
            if not alive:
                return False, L, beta, d, depth + 1, last, crossed, 0, top, dim
            return True, L, vec.hadamard(beta, w), wi, depth + 1, (False, pdf, p), 0, 0, top, dim
        E, dim, q = diffuse_estimate(tables, lookup, params, at, -1, (mats, m, d, at.ng, at.ns, at.uv), key, dim)
        return False, vec.add(L, vec.hadamard(vec.hadamard(beta, w), E)), beta, d, depth, last, crossed, q, top, dim
    if has(mats, ROUGHPLASTIC) and mats.kind[m] == ROUGHPLASTIC and not wrap:
        # a glossy coating over a diffuse lobe: its lobe as a glossy vertex with probability P, else estimate
        take_coat, (wc, P, w_coat, A), L, pdf, _, dim = rough_coating_step(
            tables, at, m, d, (L, beta), (False, (key, key, key, 0), dim), depth >= max_specular)
        if take_coat:
            if w_coat[0] == 0.0 and w_coat[1] == 0.0 and w_coat[2] == 0.0:
                return False, L, beta, d, depth + 1, last, crossed, 0, top, dim   # the sample fell below the surface
            return True, L, vec.hadamard(beta, w_coat), wc, depth + 1, (False, pdf, p), 0, 0, top, dim
        if params[5]:   # the caustic map claims the glossy lobe's share of the caustic: a split point
            S, dim, q = split_estimate(tables, lookup, params, at, (m, d, A), key, dim)
            L = vec.add(L, vec.hadamard(beta, vec.mul(S, 1.0 / (1.0 - P))))
            return False, L, beta, d, depth, last, crossed, q, top, dim
        E, dim, q = diffuse_estimate(tables, lookup, params, at, m, None, key, dim)
        L = vec.add(L, vec.hadamard(beta, vec.hadamard(vec.mul(A, 1.0 / (1.0 - P)), E)))
        return False, L, beta, d, depth, last, crossed, q, top, dim
    if (has(mats, GLOSSY_LOBES) and flags & GLOSSY or wrap) and flags & DIFFUSE_REFLECTION:
        # a broad glossy lobe beside a diffuse one (pplastic, principled), or any other diffuse lobe under a map: the
        # estimate here weighs each shadow ray and photon by the whole BSDF's f(d, wi), in the perturbed frame (as
        # sppm's visible points)
        E, dim, q = diffuse_estimate(tables, lookup, params, at, -1, (mats, m, d, at.ng, at.ns, at.uv), key, dim)
        return False, vec.add(L, vec.hadamard(beta, E)), beta, d, depth, last, crossed, q, top, dim
    if null_lobe:
        alive, d, reflected, beta, top, dim = null_thin_branch(
            mats, m, d, at, (beta, depth, max_specular, max_depth), (scratch, top), key, dim)
        if reflected:
            return alive, L, beta, d, depth + 1, (True, 0.0, p), 0, 0, top, dim
        return alive, L, beta, d, depth, last, crossed + 1, 0, top, dim
    last = (True, 0.0, p)
    if flags & SMOOTH:
        take_coat, fr, lobe_b, top, wc, w_coat, dim = diffuse_or_coating(
            mats, m, d, at, (beta, depth, max_specular), (scratch, top), key, dim)
        if take_coat:
            return True, L, vec.hadamard(beta, w_coat), wc, depth + 1, last, 0, 0, top, dim
        E, dim, q = diffuse_estimate(tables, lookup, params, at, lobe_b, None, key, dim)
        return False, vec.add(L, vec.hadamard(beta, vec.hadamard(fr, E))), beta, d, depth, last, crossed, q, top, dim
    depth += 1
    if depth > max_specular:
        return False, L, beta, d, depth, last, crossed, 0, top, dim
    d, beta, top, dim = delta_branch(mats, m, d, at, (beta, depth), (scratch, top), key, dim)
    return True, L, beta, d, depth, last, 0, 0, top, dim


@kernel
def gather_radiance(tables, maps, estimate, params, o, d, key, scratch):
    """Radiance arriving at o from -d: the camera path through mirrors and glass to diffuse points, where the
    direct light and the maps' estimates are gathered (:func:`diffuse_estimate`).  Returns (L, k-nearest searches
    made).  ``maps`` = (global map, caustic map); ``estimate`` = (k_g, r_g, k_c, r_c, filter) their k-nearest
    estimates' parameters; ``params`` = (n_strata, fixed_grid, max_specular, max_depth, hide_emitters, claim):
    Mitsuba's max_depth (segments of a whole path, None for none) ends a path at the surface it reaches in
    max_depth segments once its emission is added, and a diffuse point k segments from the camera gathers the
    records of at most max_depth - k segments; hide_emitters leaves out what the camera
    sees first.  A path's segments to a surface are its specular depth + 1 (blends' null parts and, under
    ``null_thin_dielectric``, a thindielectric crossed straight on are not vertices).  With ``claim`` (a caustic map
    is gathered) a roughplastic's diffuse lobe is a split point (:func:`split_estimate`) and a path that took its
    coating leaves out what it then meets through caustic casters alone, as sppm's visible points do
    (:func:`~caustica.photons.visible_points.claimed`); each branch on the split stack carries that state.
    ``scratch`` = the split stack (origins, directions, throughputs, depths), the k-nearest buffers (indices,
    squared distances) and the stack's claim states (0 none, 1 after a coating, 2 casters only since).
    """
    geom, mats, lights, media = tables
    max_depth, hide_emitters = params[3], params[4]
    knn_scratch = (scratch[4], scratch[5])
    st_o, st_d, st_beta, st_depth, st_claim = scratch[0], scratch[1], scratch[2], scratch[3], scratch[6]
    L = (0.0, 0.0, 0.0)
    queries = 0
    top = push_branch(scratch, 0, o, d, (1.0, 1.0, 1.0), 0)
    st_claim[0] = 0
    dim = 2
    while top > 0:
        top -= 1
        o, d, beta, depth = vec.row(st_o, top), vec.row(st_d, top), vec.row(st_beta, top), st_depth[top]
        claim = (st_claim[top] == 1, st_claim[top] == 2, L)   # (after a coating, casters only since, L before them)
        last = (True, 0.0, o)   # (specular, pdf_last, p_last): a split branch starts after a delta bounce
        crossed = 0   # surfaces passed since the last vertex (MIS's distance to an emitter: seen_weight)
        while True:
            prim, t, b1, b2 = intersect(geom, o, d, np.inf)
            if prim < 0:
                if has(lights, ENV) and lights.env[0] >= 0 and (depth > 0 or not hide_emitters):
                    # the environment, seen directly or through mirrors, glass or glossy
                    L = vec.madd(L, vec.hadamard(beta, env_radiance(lights, d)), escape_weight(lights, d, last))
                break
            p, ng, ns, front, m, uv, passed, dim = camera_surface(geom, mats, (prim, t, b1, b2), o, d, key, dim)
            e = geom.prim_emitter[prim]
            if e >= 0 and front and (depth > 0 or not hide_emitters):
                L = vec.madd(L, vec.hadamard(beta, radiance_at_hit(geom, lights, e, prim, (o, d, t, b1, b2))),
                             seen_weight(lights, e, last, (-vec.dot(d, ng), t, crossed, p)))
            if passed:
                o = vec.offset_origin(p, ng, d)
                crossed += 1
                continue
            # volpath's thindielectric (null_thin_dielectric): its straight-on lobe is a null crossing, no vertex
            null_lobe = has_null_lobe(mats, m)
            if ends_at(max_depth, depth + 1) and not null_lobe:
                break
            lookup = (maps, estimate, knn_scratch, (max_depth, depth + 1))
            ng_front = ng
            scatters, ng, ns = oriented(mats, m, front, ng, ns)
            if not scatters:
                break
            if has(mats, ROUGHPLASTIC) and params[5]:
                L, claim = claim_at(tables, (prim, m), L, claim)
            at = ShadingPoint(p, ng, ns, ng_front, geom.prim_shape[prim], media.camera[0], uv)
            pushed = top
            d_in = d
            go, L, beta, d, depth, last, crossed, q, top, dim = camera_vertex(
                tables, (lookup, params), at, m, (L, beta, d, depth, last, crossed, null_lobe), (scratch, top), key,
                dim)
            queries += q
            if has(mats, ROUGHPLASTIC) and params[5]:
                # the branches pushed here: glass's (after claim_at), a plastic's coating (none), volpath's thin
                # dielectric's reflection (right after a coating, a caster's event: casters only from there)
                state = 2 if claim[1] or (claim[0] and null_lobe) else (1 if claim[0] else 0)
                for j in range(pushed, top):
                    st_claim[j] = state
                if go:
                    claim = claim_onward(mats, m, (d_in, d), L, claim)
            if not go:
                break
            o = vec.offset_origin(p, ng, d)
        if has(mats, ROUGHPLASTIC) and params[5]:
            L = claimed(mats, L, claim)
    return L, queries


@kernel
def gather_pixels(tables, camera, maps, estimate, params, out, i0, i1):
    """The camera pass over pixels [i0, i1) in row-major order: ``camera`` = (cam, seed, spp), spp jittered rays
    per pixel (:func:`gather_radiance`) into ``out`` = (image, knn_queries): knn_queries[i] receives the number
    of k-nearest searches pixel i made.
    """
    tables = borrowed(tables)
    gmap, cmap = maps
    maps = (borrowed(gmap), borrowed(cmap))
    cam, seed, spp = camera
    cam = borrowed(cam)
    k_g, _, k_c, _, _ = estimate
    image, knn_queries = out
    kmax = max(k_g, k_c, 1)
    # scratch for every path of these pixels (each path writes what it reads): allocated once, not per pixel
    st_o = np.empty((SPLIT_STACK, 3))
    st_d = np.empty((SPLIT_STACK, 3))
    st_beta = np.empty((SPLIT_STACK, 3))
    st_depth = np.empty(SPLIT_STACK, np.int64)
    st_claim = np.zeros(SPLIT_STACK, np.int8)
    idx = np.empty(kmax, np.int64)
    d2 = np.empty(kmax)
    for i in range(i0, i1):
        x, y = pixel_of(cam, i)
        acc = (0.0, 0.0, 0.0)
        nq = 0
        for s in range(spp):
            key = path_key(seed, STREAM_CAMERA, i * spp + s)
            o, d = generate_ray(cam, x, y, uniform(key, 0), uniform(key, 1), key)
            L, q = gather_radiance(tables, maps, estimate, params, o, d, key,
                                   (st_o, st_d, st_beta, st_depth, idx, d2, st_claim))
            nq += q
            if math.isfinite(L[0] + L[1] + L[2]):
                acc = vec.add(acc, L)
        knn_queries[i] = nq
        inv = 1.0 / spp
        image[y, x, 0] = acc[0] * inv
        image[y, x, 1] = acc[1] * inv
        image[y, x, 2] = acc[2] * inv


@kernel
def gather_at_visible_points(maps, estimate, points, out, i0, i1):
    """radiance[i] += W_i (E_global + E_caustic) at visible point i, for i in [i0, i1): the k-nearest estimates of
    ``maps`` = (global, caustic) with ``estimate`` = (k_g, r_g, k_c, r_c, filter); ``out`` = (radiance,
    knn_queries), knn_queries[i] counting the searches made.

    The one-shot methods' surface estimate at visible points found by the camera pass in media
    (:func:`caustica.photons.visible_points.camera_pass`): ``points`` = (position, normal, found, weight
    W_i = β ρ / π, the BSDF rows, the material table, the camera path's segments to each point, max_depth or None):
    point i takes the records of depth max_depth - segments[i] at most.  A point whose row names a material (the
    diffuse lobes beside glossy ones, or a diffuse lobe under a map; its weight then β / (1 - P), or β) weighs each
    photon by the lobes it holds (:func:`flux_density`'s ``bsdf``); at a roughplastic's split point (the camera
    pass's ``claim``; its weight β / (1 - P)) the global map's records are weighted by the diffuse lobe's A and the
    caustic map's by A + f_glossy / B.
    """
    gmap, cmap = maps
    gmap, cmap = borrowed(gmap), borrowed(cmap)
    k_g, r_g, k_c, r_c, filt = estimate
    vp_pos, vp_nrm, vp_found, vp_weight, rows, mats, segments, max_depth = points
    mats = borrowed(mats)
    out, knn_queries = out
    kmax = max(k_g, k_c, 1)
    idx = np.empty(kmax, np.int64)
    d2 = np.empty(kmax)
    for i in range(i0, i1):
        if not vp_found[i]:
            continue
        p = vec.row(vp_pos, i)
        n = vec.row(vp_nrm, i)
        if split_point(mats, rows, i):   # roughplastic's split point: the caustic map claims the glossy lobe's share
            A = split_diffuse(mats, rows, i)
            Eg, _ = flux_density(gmap, (p, n, (max_depth, segments[i])), (k_g, r_g, filt), (idx, d2), None)
            Eg = vec.hadamard(A, Eg)
            Ec, _ = flux_density(cmap, (p, n, (max_depth, segments[i])), (k_c, r_c, filt), (idx, d2),
                                 bsdf_point(mats, rows, i), A)
        elif rows[i, BSDF_MATERIAL] < 0.0:
            Eg, _ = flux_density(gmap, (p, n, (max_depth, segments[i])), (k_g, r_g, filt), (idx, d2), None)
            Ec, _ = flux_density(cmap, (p, n, (max_depth, segments[i])), (k_c, r_c, filt), (idx, d2), None)
        else:
            bsdf = bsdf_point(mats, rows, i)
            Eg, _ = flux_density(gmap, (p, n, (max_depth, segments[i])), (k_g, r_g, filt), (idx, d2), bsdf)
            Ec, _ = flux_density(cmap, (p, n, (max_depth, segments[i])), (k_c, r_c, filt), (idx, d2), bsdf)
        if not none_admitted(max_depth, segments[i]):   # (no search made when no record may be gathered)
            knn_queries[i] += (gmap.position.shape[0] > 0) + (cmap.position.shape[0] > 0)
        for c in range(3):
            out[i, c] += vp_weight[i, c] * (Eg[c] + Ec[c])
