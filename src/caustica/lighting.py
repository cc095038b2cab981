"""Direct lighting: shadow rays from a scattering point to the emitters.

* :func:`direct_stratified` — at a photon method's diffuse point (SPEC §2): every emitter, ``n x n``
  stratified points on each area light (or the fixed centres of the n x n grid), point, spot, projector and
  directional lights exactly, through media and null boundaries.  It returns an irradiance-like E that the caller scales by
  f_r = ρ / π; at a point that evaluates its BSDF (pplastic, principled: pm's gather) each shadow ray is weighted by
  the BSDF's f instead (of the lobes the point holds: :func:`caustica.bsdfs.eval_radiance`), and it returns the
  radiance.
* :func:`next_event` — one light sample (:func:`caustica.media.light_sample`) at any scattering point,
  weighted by multiple importance sampling against the BSDF's (or phase function's) own sampling; the
  matching weights of an emitter or the environment reached by that sampling are :func:`emission_mis`
  and :func:`environment_mis`.  The path tracer takes them at every vertex, the progressive methods'
  camera paths at the glossy surfaces and glossy lobes they pass (:mod:`caustica.photons.visible_points`).
"""
from __future__ import annotations

import math

from .bsdfs import GLOSSY_TRANSMISSION, camera_scale, entry, eval_part, eval_pdf, eval_radiance, \
    held_lobes_transmit
from .emitters import AREA, DIRECTIONAL, ENV, SPOT, TEX_OF, TEXTURED_AREA, emitter_point, env_pdf, env_radiance, \
    env_sample, profile, profiled, spot_falloff
from .geometry import vec
from .features import has
from .scene.description import PLASTIC, ROUGHPLASTIC
from .jit import kernel
from .transport import ShadingPoint
from .media import env_shadow_length, escape_transmittance, light_sample, medium_after, phase_pdf, phase_value, \
    power_heuristic, shadow_transmittance
from .sampling.rng import KRONECKER_ALPHA, kronecker, uniform
from .sampling.warps import square_to_cosine_hemisphere

INV_PI = 1.0 / math.pi


@kernel(inline=True)
def stratum_point(s, key, dim, n_strata, fixed_grid, pass_index):
    """(u1, u2) of stratum s = (i, j) of n_strata x n_strata, as :func:`direct_stratified` says."""
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
    return u1, u2


@kernel(inline=True)
def times_bsdf(bsdf, wi, T):
    """A shadow ray's T times the BSDF's value f(d, wi) at a point that evaluates its BSDF, ``bsdf`` = (mats, m, d, ng,
    ns, uv) as :func:`caustica.photons.grid.grid_range_sum` takes it; T itself when ``bsdf`` is None (a separate
    compilation: Numba prunes the branch, so every other point's arithmetic is what it was)."""
    if bsdf is not None:
        f, f_scale = eval_radiance(bsdf[0], bsdf[1], bsdf[2], bsdf[3], bsdf[4], bsdf[5], wi)
        return vec.mul(vec.hadamard(T, f), f_scale)
    return T


@kernel
def env_direct(tables, at, key, dim, strata, coated, bsdf):
    """The environment's share of :func:`direct_stratified`: E = ∫ L T cos θ dω over the hemisphere of ``at``.

    ``strata`` = (n_strata, fixed_grid, pass_index) give n² stratified points (u1, u2) as for an area light.
    A constant environment: each is a cosine-weighted direction about the shading normal (L T π each: exact
    where nothing occludes).  A map: each gives a direction by the map's importance and one by the cosine,
    combined by MIS (power heuristic), so a small bright sun and a dim wide sky are both found.  Shadow rays
    as :func:`caustica.media.env_light_sample` traces them.  ``coated`` and ``bsdf`` as for :func:`direct_stratified`.
    """
    _, mats, lights, _ = tables
    n_strata, fixed_grid, pass_index = strata
    p, ng, ns, ng_front, shape, medium, _ = at
    n_total = n_strata * n_strata
    constant = lights.env[1] == 1
    s_axis, t_axis = vec.orthonormal_basis(ns)
    acc = (0.0, 0.0, 0.0)
    for s in range(n_total):
        u1, u2 = stratum_point(s, key, dim, n_strata, fixed_grid, pass_index)
        wc = vec.normalize(vec.from_local(s_axis, t_axis, ns, square_to_cosine_hemisphere(u1, u2)))
        cos_c = vec.dot(ns, wc)
        if cos_c > 0.0 and vec.dot(ng, wc) > 0.0:
            w = 1.0
            if not constant:
                w = power_heuristic(cos_c * INV_PI, env_pdf(lights, wc))
            if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
                w *= entry(mats, coated, cos_c)
            T = times_bsdf(bsdf, wc, env_transmittance(tables, at, wc))
            acc = vec.madd(acc, vec.hadamard(env_radiance(lights, wc), T), math.pi * w)
        if constant:
            continue
        we, pdf_e, Le = env_sample(lights, u1, u2)
        cos_e = vec.dot(ns, we)
        if pdf_e > 0.0 and cos_e > 0.0 and vec.dot(ng, we) > 0.0:
            w = power_heuristic(pdf_e, cos_e * INV_PI)
            if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
                w *= entry(mats, coated, cos_e)
            T = times_bsdf(bsdf, we, env_transmittance(tables, at, we))
            acc = vec.madd(acc, vec.hadamard(Le, T), cos_e * w / pdf_e)
    return vec.mul(acc, 1.0 / n_total)


@kernel
def env_transmittance(tables, at, wi):
    """T along a shadow ray from surface point ``at`` towards the environment in direction wi."""
    geom, mats, lights, media = tables
    p, ng, _, ng_front, shape, medium, _ = at
    T, _ = shadow_transmittance(geom, mats, media, vec.offset_origin(p, ng, wi),
                                vec.madd(p, wi, env_shadow_length(lights, p)),
                                medium_after(media, shape, ng_front, wi, medium))
    return T


@kernel
def direct_stratified(tables, at, key, dim, strata, coated, bsdf):
    """Irradiance E = Σ_lights ∫ L T cos θ dω at ``at`` (a :class:`caustica.transport.ShadingPoint` on a
    surface), every light sampled (SPEC §2).

    Area lights (:func:`area_direct`), ``strata`` = (n_strata, fixed_grid, pass_index): n_strata x n_strata strata;
    stratum s = (i, j) is jittered by its cell centre when ``fixed_grid`` (the paper's grid of point lights); else,
    when ``pass_index`` < 0, by numbers dim + 2 s, dim + 2 s + 1 of ``key``; else by frac(u + k alpha) over the
    passes k, u those numbers (a shifted Kronecker sequence: each pass's point is uniform in its stratum and a
    pixel's passes fill it evenly).  Point and spot lights exactly (a spot's intensity times its falloff; a projector's or a textured
    spot's by :func:`profiled_direct`), a directional light by one shadow ray against its direction (E cos θ T); the environment by :func:`env_direct`.  Each shadow ray's
    visibility is its transmittance (:func:`caustica.media.shadow_transmittance`, from the medium on the
    light's side of the surface; 0 or 1 in vacuum, with the vacuum arithmetic).  ``at``'s ng, ns: normals on
    the lit side; ng_front: the front.  ``coated``: -1, or a material with a delta or glossy coating over a diffuse
    lobe (:func:`caustica.bsdfs.coat`, :func:`caustica.bsdfs.rough_coat`), whose factor B on the light's side (:func:`caustica.bsdfs.entry`) then
    weights each shadow ray.  Returns E per channel, before the diffuse BRDF ρ / π (or the coated lobe's A).
    ``bsdf``: None, or (mats, m, d, ng, ns, uv), a point that evaluates its BSDF (the diffuse lobes beside glossy ones
    of pplastic, principled and principledthin, or a diffuse lobe under a map), each shadow ray then weighted by the
    held lobes' f(d, wi) (:func:`times_bsdf`, :func:`caustica.bsdfs.eval_radiance`): the radiance towards -d; where
    those lobes transmit (principledthin's diffuse transmission: :func:`caustica.bsdfs.held_lobes_transmit`), the
    lights behind the surface too, on the same numbers (:func:`lights_direct` again with the normals turned).
    """
    E = lights_direct(tables, at, key, dim, strata, coated, bsdf)
    if bsdf is not None and held_lobes_transmit(bsdf[0], bsdf[1]):
        behind = ShadingPoint(at.p, vec.neg(at.ng), vec.neg(at.ns), at.ng_front, at.shape, at.medium, at.uv)
        E = vec.add(E, lights_direct(tables, behind, key, dim, strata, coated, bsdf))
    return E


@kernel(inline=True)
def lights_direct(tables, at, key, dim, strata, coated, bsdf):
    """:func:`direct_stratified` over the hemisphere of ``at``'s normals, the same arguments."""
    lights = tables[2]
    E = (0.0, 0.0, 0.0)
    for li in range(lights.kind.shape[0]):
        if has(lights, ENV) and lights.kind[li] == ENV:
            E = vec.add(E, env_direct(tables, at, key, dim, strata, coated, bsdf))
        elif lights.kind[li] == AREA:
            E = vec.add(E, area_direct(tables, at, li, (key, dim, strata), coated, bsdf))
        elif has(lights, DIRECTIONAL) and lights.kind[li] == DIRECTIONAL:
            lit, value, cos_s = directional_direct(tables, at, li, coated, bsdf)
            if lit:
                E = vec.madd(E, value, cos_s)
        elif profiled(lights, li):
            E = vec.add(E, profiled_direct(tables, at, li, coated, bsdf))
        else:
            lit, value, g = point_direct(tables, at, li, coated, bsdf)
            if lit:
                E = vec.madd(E, value, g)
    return E


@kernel(inline=True)
def area_direct(tables, at, li, numbers, coated, bsdf):
    """Area light li's share of :func:`direct_stratified`: a shadow ray to a point of each of its strata, ``numbers``
    = (key, dim, strata)."""
    geom, mats, lights, media = tables
    p, ng, ns, ng_front, shape, medium, _ = at
    key, dim, strata = numbers
    n_strata, fixed_grid, pass_index = strata
    n_total = n_strata * n_strata
    rad = vec.row(lights.radiance, li)
    acc = (0.0, 0.0, 0.0)
    textured = has(lights, TEXTURED_AREA) and lights.tex_int[li, TEX_OF] != 0
    for s in range(n_total):
        u1, u2 = stratum_point(s, key, dim, n_strata, fixed_grid, pass_index)
        q, nq, Lq = emitter_point(lights, geom, li, u1, u2)
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
        g = cos_s * cos_l / dist2
        if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
            g *= entry(mats, coated, cos_s)
        if textured:
            T = vec.hadamard(T, Lq)   # the radiance there, the row's included
        acc = vec.madd(acc, times_bsdf(bsdf, wi, T), g)
    if textured:
        rad = (1.0, 1.0, 1.0)
    area = lights.area[li]
    return (rad[0] * (acc[0] * area / n_total), rad[1] * (acc[1] * area / n_total),
            rad[2] * (acc[2] * area / n_total))


@kernel(inline=True)
def directional_direct(tables, at, li, coated, bsdf):
    """Directional light li's share of :func:`direct_stratified`, as (lit, E_i, cos θ): E cos θ T by one shadow ray
    against its direction."""
    lights = tables[2]
    mats = tables[1]
    _, ng, ns, _, _, _, _ = at
    wi = vec.neg(vec.row(lights.normal, li))
    cos_s = vec.dot(ns, wi)
    zero = (0.0, 0.0, 0.0)
    if cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return False, zero, 0.0
    if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
        cos_s *= entry(mats, coated, cos_s)
    return True, vec.hadamard(vec.row(lights.radiance, li), times_bsdf(bsdf, wi, env_transmittance(tables, at, wi))), \
        cos_s


@kernel(inline=True)
def towards_position(lights, li, at):
    """From ``at`` towards light li's position q: (whether the surface's lit side faces it, q, q - p, |q - p|², the
    unit direction wi, cos θ = ns·wi)."""
    p, ng, ns = at.p, at.ng, at.ns
    q = vec.row(lights.position, li)
    to_l = vec.sub(q, p)
    dist2 = vec.dot(to_l, to_l)
    if not dist2 > 0.0:
        return False, q, to_l, dist2, to_l, 0.0
    wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
    cos_s = vec.dot(ns, wi)
    return not (cos_s <= 0.0 or vec.dot(ng, wi) <= 0.0), q, to_l, dist2, wi, cos_s


@kernel(inline=True)
def point_direct(tables, at, li, coated, bsdf):
    """Point or spot light li's share of :func:`direct_stratified`, as (lit, I T, cos θ / r² (times the spot's
    falloff)): one shadow ray."""
    geom, mats, lights, media = tables
    p, ng, ns, ng_front, shape, medium, _ = at
    zero = (0.0, 0.0, 0.0)
    faces, q, to_l, dist2, wi, cos_s = towards_position(lights, li, at)
    if not faces:
        return False, zero, 0.0
    falloff = spot_falloff(lights, li, vec.neg(wi)) if has(lights, SPOT) and lights.kind[li] == SPOT else 1.0
    if not falloff > 0.0:
        return False, zero, 0.0
    T, _ = shadow_transmittance(geom, mats, media, vec.offset_origin(p, ng, to_l), q,
                                medium_after(media, shape, ng_front, wi, medium))
    g = cos_s / dist2
    if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
        g *= entry(mats, coated, cos_s)
    if has(lights, SPOT) and lights.kind[li] == SPOT:
        g *= falloff
    return True, vec.hadamard(vec.row(lights.radiance, li), times_bsdf(bsdf, wi, T)), g


@kernel
def profiled_direct(tables, at, li, coated, bsdf):
    """:func:`direct_stratified`'s irradiance from projector or textured spot li at ``at``: its intensity towards
    p (radiance x :func:`caustica.emitters.profile`) T cos θ / r², by one shadow ray (times B with ``coated``, times f
    with ``bsdf``)."""
    geom, mats, lights, media = tables
    p, ng, ns, ng_front, shape, medium, _ = at
    zero = (0.0, 0.0, 0.0)
    faces, q, to_l, dist2, wi, cos_s = towards_position(lights, li, at)
    if not faces:
        return zero
    intensity = vec.hadamard(vec.row(lights.radiance, li), profile(lights, li, vec.neg(wi)))
    if not (intensity[0] > 0.0 or intensity[1] > 0.0 or intensity[2] > 0.0):
        return zero
    T, _ = shadow_transmittance(geom, mats, media, vec.offset_origin(p, ng, to_l), q,
                                medium_after(media, shape, ng_front, wi, medium))
    g = cos_s / dist2
    if (has(mats, PLASTIC) or has(mats, ROUGHPLASTIC)) and coated >= 0:
        g *= entry(mats, coated, cos_s)
    return vec.mul(vec.hadamard(intensity, times_bsdf(bsdf, wi, T)), g)


@kernel(inline=True)
def next_event(tables, at, m, d, beta, key, dim, lobes=None):
    """Next-event estimation at ``at`` (a surface of material m, or a point in a medium) for a path arriving along
    d with throughput β: one light sample (numbers dim .. dim + 2), weighted by MIS against the BSDF's or the
    phase function's sampling for area lights.  With ``lobes`` = (part, P), the lobes ``part`` of a material that
    splits its lobes (:func:`caustica.bsdfs.eval_part`) alone, P the probability that its sampling picks one of
    them: their f, and MIS against their sampling given that pick (density over P).  Returns (ok, term, scale,
    shadow rays, dim): L += term · scale.
    """
    mats, media = tables[1], tables[3]
    through = at.shape >= 0 and mats.flags[m] & GLOSSY_TRANSMISSION != 0   # lights on either side
    contrib, wi, pdf_light, _, is_area, ok, shadow = light_sample(tables, at, (uniform(key, dim), uniform(key, dim + 1),
                                                                  uniform(key, dim + 2)), through)
    if not ok:
        return False, contrib, 0.0, shadow, dim + 3
    if at.shape < 0:
        w_l = power_heuristic(pdf_light, phase_pdf(media, at.medium, d, wi)) if is_area else 1.0
        return True, vec.hadamard(beta, contrib), w_l * phase_value(media, at.medium, d, wi), shadow, dim + 3
    if lobes is None:
        f, f_scale, pdf_bsdf = eval_pdf(mats, m, d, at.ng, at.ns, at.uv, wi)
    else:
        f, f_scale, pdf_bsdf = eval_part(mats, m, d, at.ng, at.ns, at.uv, wi, lobes[0])
        pdf_bsdf /= lobes[1]
    if through:
        f_scale *= camera_scale(mats, m, d, at.ng, at.ns, wi)
    w_l = power_heuristic(pdf_light, pdf_bsdf) if is_area else 1.0
    return True, vec.hadamard(beta, vec.hadamard(f, contrib)), w_l * f_scale, shadow, dim + 3


@kernel(inline=True)
def emission_mis(lights, e, last, cos_l, t, crossings, p):
    """The MIS weight of emitter e's radiance (at p, cosine cos_l) reached by BSDF or phase sampling from the
    last scattering, ``last`` = (specular, pdf_last, p_last), against light sampling from there: 1 after a
    delta bounce or from the camera (``specular``).  The distance is the ray's t, or |p - p_last| when null
    surfaces were crossed since that point."""
    specular, pdf_last, p_last = last
    if specular:
        return 1.0
    if crossings == 0:
        pdf_light = lights.select_pdf[e] * t * t / (lights.area[e] * cos_l)
    else:
        to_p = vec.sub(p, p_last)
        pdf_light = lights.select_pdf[e] * vec.dot(to_p, to_p) / (lights.area[e] * cos_l)
    return power_heuristic(pdf_last, pdf_light)


@kernel
def environment_mis(lights, media, d, medium, last):
    """The environment's radiance along an escaping ray d, MIS-weighted against light sampling from the last
    scattering, ``last`` = (specular, pdf_last): weight 1 from the camera or after a delta bounce.  A ray
    that escapes from inside a medium (one that nothing bounds) escaped in the channels that do not
    attenuate: their radiance is divided by the probability of escaping, the others' is 0 (docs/media.md)."""
    specular, pdf_last = last
    Le = env_radiance(lights, d)
    if medium >= 0:
        T = escape_transmittance(media, medium)
        p = (T[0] + T[1] + T[2]) / 3.0
        if not p > 0.0:
            return (0.0, 0.0, 0.0)
        Le = vec.mul(vec.hadamard(Le, T), 1.0 / p)
    if specular:
        return Le
    return vec.mul(Le, power_heuristic(pdf_last, lights.select_pdf[lights.env[0]] * env_pdf(lights, d)))
