"""Participating media: homogeneous media, their phase functions, free flights and transmittance.

Heterogeneous media (Mitsuba's ``heterogeneous``: coefficients from grid volumes) are tracked by null collisions
in :mod:`caustica.volumes`; :func:`free_flight` and :func:`transmittance` hand them over there, behind the medium
table's feature ``HETEROGENEOUS`` (:mod:`caustica.features`), so a scene without one compiles none of that code.

A scene's media live in a :class:`MediumTable` (structure of arrays, indexed by the
medium's position in :attr:`SceneDescription.media`), with each shape's interior and
exterior medium and the camera's.  -1 means no medium (vacuum).  Every scene has one: in a
scene without media it says "vacuum" everywhere, and the kernels' medium branches are never
taken, so the same loops render it with the vacuum arithmetic.

Conventions (Mitsuba 3's):

* A ray leaving a surface towards its front (``dot(d, ng) > 0``, ``ng`` the front normal)
  is in the shape's exterior medium, towards its back in the interior one; a shape with
  neither does not change the ray's medium.  So glass without media inside fog is full
  of fog, and a null-BSDF shape with an interior medium is a medium without a surface.
* ``sigma_t`` is the extinction per scene unit (``scale`` applied), ``albedo`` =
  sigma_s / sigma_t; the transmittance over a distance t is exp(-sigma_t t) per channel.
* Phase functions are written for the direction of propagation: p(d -> wo) depends on
  mu = dot(d, wo), and Henyey-Greenstein with g > 0 scatters forwards (mu near 1).

Free-flight sampling with spectrally varying sigma_t (docs/media.md): a channel c is
chosen uniformly at each flight and the distance drawn from exp(-sigma_c t) sigma_c;
the weight divides by the *mixture* of the three channels' densities (the one-sample
balance heuristic over channels, "spectral MIS").  Its weights are bounded (by 3
times the albedo for a scattering event, by 3 for a flight that reaches a surface),
where the single-channel scheme of Mitsuba's ``volpath`` (one channel per path, weights
T_k / T_c that grow exponentially with distance) is not.  For a grey medium both reduce
to the classic estimator: weight 1 for passing, the albedo for scattering.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .bsdfs import TEXTURED, has_null_lobe, null_transmission
from .bsdfs.mixtures import pass_probability
from .emitters import AREA, DIRECTIONAL, ENV, SPOT, choose_light, emitter_point, env_sample, profile, profiled, \
    sample_area_emitter, spot_falloff
from .geometry import vec
from .geometry.scene_geometry import NO_UV, intersect, occluded, surface_at, surface_uv
from .features import ALL, bits, guarded_by, has, specialisable, specialised
from .jit import kernel
from .sampling.rng import uniform
from .scene.description import BLEND, HENYEY_GREENSTEIN, HETEROGENEOUS, HOMOGENEOUS, MASK, NULL, SceneDescription
from .volumes import clip, coefficients, delta_tracking, grid_columns, ratio_tracking, ray_key, volume_at, \
    walk_start

INV_4PI = 1.0 / (4.0 * math.pi)

#: Null-surface crossings a ray or shadow ray may make in a row (without scattering) before it
#: is given up: a guard against a ray trapped between coincident null surfaces, never reached
#: in a sensible scene (each crossing moves the ray forwards).
NULL_CROSSINGS_CAP = 256

#: |g| below which a Henyey-Greenstein phase function is sampled as the isotropic one (its
#: inverse CDF loses precision as g -> 0); its value is still the exact HG value.
HG_ISOTROPIC_G = 1e-4
#: A media table's feature (:mod:`caustica.features`) beside the media's kinds: shadow rays may cross surfaces
#: (``null_surfaces``), so :func:`shadow_transmittance` needs :func:`transmittance` even in vacuum.  A code beside
#: the medium kinds' (HOMOGENEOUS 0, HETEROGENEOUS 1): a new kind of medium takes a code other than 2.
CROSSABLE = 2


@specialisable
class MediumTable(NamedTuple):
    sigma_t: np.ndarray    # float64[K, 3]: extinction per scene unit (scale applied); 0 for a heterogeneous medium
    albedo: np.ndarray     # float64[K, 3]: sigma_s / sigma_t; 0 for a heterogeneous medium
    phase: np.ndarray      # int32[K]: ISOTROPIC or HENYEY_GREENSTEIN
    g: np.ndarray          # float64[K]: HG asymmetry (0 for isotropic)
    interior: np.ndarray   # int32[S]: each shape's interior medium, -1 for none
    exterior: np.ndarray   # int32[S]: each shape's exterior medium, -1 for none
    camera: np.ndarray     # int32[1]: the medium the camera is in, -1 for none
    null_surfaces: np.ndarray  # int8[1]: 1 when a shape has the null BSDF or a mask (shadow rays may cross surfaces;
    #                            pt's copy for a volpath scene with thindielectric: 1 too)
    # heterogeneous media (caustica.volumes, feature HETEROGENEOUS; trivial columns in a scene without them):
    kind: np.ndarray       # int32[K]: HOMOGENEOUS or HETEROGENEOUS
    volumes: np.ndarray    # int32[K, 2]: the grids of sigma_t (scale applied) and albedo, -1 for a homogeneous medium
    bounds: np.ndarray     # float64[K, 6]: the world box (lo, hi) outside which the medium is vacuum
    grid_shape: np.ndarray     # int64[G, 7]: nx, ny, nz, channels, first value in voxels, filter, wrap
    grid_to_local: np.ndarray  # float64[G, 12]: world to the grid's unit cube, the 3 x 4 rows
    voxels: np.ndarray     # float32[N]: every grid's values, (z, y, x, channel) order, one grid after another
    cells: np.ndarray      # int64[K, 4]: the majorant grid's cells along x, y, z over the sigma_t grid's unit cube,
    #                        and its first value in cell_majorant
    cell_majorant: np.ndarray  # float64[C]: per cell, the largest sigma_t a point of it reads, (z, y, x) order


def medium_features(heterogeneous: bool, media: bool, crossable: bool) -> int:
    """The feature set of a media table (:mod:`caustica.features`), rounded to one of three so that a kernel compiles
    at most three times for it: none (no medium, no null surface: the media's code is not compiled at all,
    :func:`in_a_medium`), HOMOGENEOUS | CROSSABLE (homogeneous media or surfaces shadow rays cross), or every feature
    (a heterogeneous medium: its tracking compiled too)."""
    if heterogeneous:
        return ALL
    return bits(HOMOGENEOUS, CROSSABLE) if media or crossable else 0


def build_medium_table(desc: SceneDescription) -> MediumTable:
    k = max(1, len(desc.media))
    sigma_t = np.zeros((k, 3))
    albedo = np.zeros((k, 3))
    phase = np.zeros(k, np.int32)
    g = np.zeros(k)
    for i, m in enumerate(desc.media):
        sigma_t[i] = m.sigma_t
        albedo[i] = m.albedo
        phase[i] = m.phase
        g[i] = m.g
    interior = np.array([s.interior for s in desc.shapes], np.int32).reshape(-1)
    exterior = np.array([s.exterior for s in desc.shapes], np.int32).reshape(-1)
    null = any(desc.may_pass(s.material) for s in desc.shapes)
    grids = grid_columns(desc.media, k)
    features = medium_features(bool(np.any(grids["kind"] == HETEROGENEOUS)), bool(desc.media), null)
    return specialised(MediumTable, features)(sigma_t, albedo, phase, g, interior, exterior,
                                              np.array([desc.camera.medium], np.int32),
                                              np.array([1 if null else 0], np.int8), **grids)


# ----------------------------------------------------------------------------- boundaries

@kernel(inline=True)
def medium_after(media, shape, ng, d, current):
    """The medium a ray is in after leaving a surface of ``shape`` in direction d (ng: its front normal)."""
    inside = media.interior[shape]
    outside = media.exterior[shape]
    if inside < 0 and outside < 0:
        return current
    if vec.dot(d, ng) > 0.0:
        return outside
    return inside


# ----------------------------------------------------------------------------- free flights

@kernel(inline=True)
def cross_null(media, shape, p, ng, d, medium, crossings):
    """A ray passing a null boundary at p: (the medium beyond, the origin past it, crossings + 1, whether
    that is still within NULL_CROSSINGS_CAP)."""
    crossings += 1
    return medium_after(media, shape, ng, d, medium), vec.offset_origin(p, ng, d), crossings, \
        crossings <= NULL_CROSSINGS_CAP


@kernel(inline=True)
def sample_distance(media, m, u_channel, u):
    """A free-flight distance in medium m: channel chosen by u_channel, distance exp-distributed in it.

    Infinite when the chosen channel does not attenuate; the density of the result is the mean
    of the three channels' densities (see :func:`flight_weight`).
    """
    c = min(int(u_channel * 3.0), 2)
    s = media.sigma_t[m, c]
    if s <= 0.0:
        return np.inf
    return -math.log(1.0 - u) / s


@guarded_by(HOMOGENEOUS, HETEROGENEOUS)
@kernel(inline=True)
def holds_media(media):
    """Whether the media table may hold a medium; in a scene without media a constant False, folded before typing
    (:func:`caustica.features.guarded_by`), so the code only media reach is not compiled for it."""
    return has(media, HOMOGENEOUS) or has(media, HETEROGENEOUS)


@guarded_by(HOMOGENEOUS, HETEROGENEOUS)
@kernel(inline=True)
def in_a_medium(media, medium):
    """Whether a path in ``medium`` is in one (>= 0): :func:`holds_media` at run time, so folded the same way."""
    return holds_media(media) and medium >= 0


@kernel(inline=True)
def free_flight(geom, media, medium, o, d, key, dim):
    """A photon's next event along o + t d: (prim, t, b1, b2, weight, dim, escaped).

    In a medium (``medium`` >= 0) a free-flight distance is sampled (numbers dim and dim + 1 of
    ``key``; dim comes back advanced by 2) and the flight ends at the nearer of it and the next
    surface: ``prim`` >= 0 a surface at t, ``prim`` < 0 a scattering event in the medium at t,
    ``weight`` the flight's :func:`flight_weight`.  In vacuum only the surface, weight (1, 1, 1).
    ``escaped``: nothing ahead (vacuum, or a channel that does not attenuate, and no surface).
    """
    if in_a_medium(media, medium):
        if has(media, HETEROGENEOUS) and media.kind[medium] == HETEROGENEOUS:
            return tracked_flight(geom, media, medium, o, d, key, dim)
        t_flight = sample_distance(media, medium, uniform(key, dim), uniform(key, dim + 1))
        prim, t, b1, b2 = intersect(geom, o, d, t_flight)
        if prim < 0 and t_flight == np.inf:
            return prim, t, b1, b2, (1.0, 1.0, 1.0), dim + 2, True
        return prim, t, b1, b2, flight_weight(media, medium, t, prim < 0), dim + 2, False
    prim, t, b1, b2 = intersect(geom, o, d, np.inf)
    return prim, t, b1, b2, (1.0, 1.0, 1.0), dim, prim < 0


@kernel
def tracked_flight(geom, media, m, o, d, key, dim):
    """:func:`free_flight` in heterogeneous medium m: the next surface, then a delta-tracked flight up to it
    (:func:`caustica.volumes.delta_tracking`).  ``escaped`` keeps the tracked weight, which the caller applies."""
    prim, t, b1, b2 = intersect(geom, o, d, np.inf)
    t_scatter, scattered, w, dim = delta_tracking(media, m, (o, d), t, key, dim)
    if scattered:
        return -1, t_scatter, 0.0, 0.0, w, dim, False
    return prim, t, b1, b2, w, dim, prim < 0


@kernel(inline=True)
def flight_weight(media, m, t, scattered):
    """Per channel: the path throughput's factor for a flight of length t sampled by :func:`sample_distance`.

    scattered: the flight ended in a scattering event at t (weight T_k(t) sigma_s,k / p(t),
    p(t) = mean_c sigma_c T_c(t)); otherwise it reached a surface at t first (weight
    T_k(t) / P(t), P(t) = mean_c T_c(t), the probability of flying at least t).  The common
    factor exp(-min_c sigma_c t) is taken out of both, so that long flights do not
    underflow to 0 / 0.  Finite t only.
    """
    s0 = media.sigma_t[m, 0]
    s1 = media.sigma_t[m, 1]
    s2 = media.sigma_t[m, 2]
    smin = min(s0, min(s1, s2))
    e0 = math.exp(-(s0 - smin) * t)
    e1 = math.exp(-(s1 - smin) * t)
    e2 = math.exp(-(s2 - smin) * t)
    if scattered:
        p = (s0 * e0 + s1 * e1 + s2 * e2) / 3.0
        if not p > 0.0:
            return (0.0, 0.0, 0.0)
        return (media.albedo[m, 0] * s0 * e0 / p, media.albedo[m, 1] * s1 * e1 / p,
                media.albedo[m, 2] * s2 * e2 / p)
    p = (e0 + e1 + e2) / 3.0
    return (e0 / p, e1 / p, e2 / p)


@kernel(inline=True)
def attenuation(media, m, t):
    """exp(-sigma_t t) per channel in medium m (1 in vacuum, m < 0)."""
    if m < 0:
        return (1.0, 1.0, 1.0)
    return (math.exp(-media.sigma_t[m, 0] * t), math.exp(-media.sigma_t[m, 1] * t),
            math.exp(-media.sigma_t[m, 2] * t))


@kernel(inline=True)
def segment_attenuation(media, m, ray, t):
    """The transmittance of the first t of ``ray`` = (o, d) in medium m: :func:`attenuation`, or in a heterogeneous
    medium its ratio-tracking estimate (:func:`caustica.volumes.ratio_tracking`, numbers keyed by the ray)."""
    if has(media, HETEROGENEOUS) and m >= 0 and media.kind[m] == HETEROGENEOUS:
        return ratio_tracking(media, m, ray, t, ray_key(ray[0], ray[1]))
    return attenuation(media, m, t)


@kernel(inline=True)
def shadow_transmittance(geom, mats, media, o, target, medium):
    """:func:`transmittance`, with the case of every vacuum scene inlined into the caller: no medium and no
    null surface to cross, so the shadow ray is an any-hit test (visible: 1, blocked: 0).  Shadow rays are
    the bulk of the rays traced; a call that is not inlined passes the scene tables field by field.  In a scene
    without media or null surfaces (the features of ``media``) :func:`transmittance` is not even compiled."""
    if in_a_medium(media, medium) or has(media, CROSSABLE):   # (neither in a vacuum scene without null surfaces)
        if medium >= 0 or media.null_surfaces[0] != 0:
            return transmittance(geom, mats, media, o, target, medium)
    seg = vec.sub(target, o)
    dist = vec.length(seg)
    if dist <= 0.0:
        return (1.0, 1.0, 1.0), 0
    if occluded(geom, o, vec.mul(seg, 1.0 / dist), dist):
        return (0.0, 0.0, 0.0), 1
    return (1.0, 1.0, 1.0), 1


@kernel(inline=True)
def transmittance(geom, mats, media, o, target, medium):
    """(T per channel, rays traced) along the segment from o to target, starting in ``medium``.

    Null-BSDF surfaces are crossed (switching medium as :func:`medium_after` says); any other
    surface blocks (T = 0): glass too, as in Mitsuba's volpath.  A mask passes its chance of being off,
    1 - opacity at the point (:func:`caustica.bsdfs.pass_probability`, Mitsuba's ``eval_null_transmission``), a
    material flagged ``NULL_TRANSMISSION`` (thindielectric in ``pt`` for a volpath scene) 1 - R (:func:`crossing`).
    The transmittance of each medium segment is exp(-sigma_t length), evaluated exactly in homogeneous media, so
    a shadow ray adds no noise of its own there; in a heterogeneous medium it is ratio tracked
    (:func:`segment_attenuation`).  The caller moves both ends off their surfaces.
    Inlined by LLVM: called per shadow ray in every scene with media or null surfaces, and a call would
    copy every array of three scene tables (the fog box's ``pt`` ran 2.6-3.9x slower per pass that way).
    """
    T = (1.0, 1.0, 1.0)
    seg = vec.sub(target, o)
    dist = vec.length(seg)
    if dist <= 0.0:
        return T, 0
    d = vec.mul(seg, 1.0 / dist)
    rays = 0
    for _ in range(NULL_CROSSINGS_CAP):
        rays += 1
        prim, t, b1, b2 = intersect(geom, o, d, dist)
        if prim < 0:
            return vec.hadamard(T, segment_attenuation(media, medium, (o, d), dist)), rays
        m = geom.prim_material[prim]
        if mats.kind[m] != NULL:
            passing = crossing(geom, mats, prim, (o, d, t, b1, b2))
            if not (passing[0] > 0.0 or passing[1] > 0.0 or passing[2] > 0.0):
                return (0.0, 0.0, 0.0), rays
            T = vec.hadamard(T, passing)
        T = vec.hadamard(T, segment_attenuation(media, medium, (o, d), t))
        p, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        medium = medium_after(media, geom.prim_shape[prim], ng, d, medium)
        o = vec.offset_origin(p, ng, d)
        dist = vec.length(vec.sub(target, o))
    return (0.0, 0.0, 0.0), rays


@kernel(inline=True)
def crossing(geom, mats, prim, ray):
    """Per channel, the share of a ray that crosses primitive prim's surface unscattered, where ``ray`` =
    (o, d, t, b1, b2) meets it: 1 for the null BSDF; a mixture's chance of being off at the hit's (u, v)
    (:func:`caustica.bsdfs.pass_probability`); a ``NULL_TRANSMISSION`` material's
    :func:`caustica.bsdfs.null_transmission` (Mitsuba's ``eval_null_transmission``); else 0."""
    m = geom.prim_material[prim]
    kind = mats.kind[m]
    if kind == NULL:
        return (1.0, 1.0, 1.0)
    o, d, t, b1, b2 = ray
    if has_null_lobe(mats, m):
        _, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        uv = surface_uv(geom, prim, o, d, t, b1, b2) if has(mats, TEXTURED) and mats.texture[m] >= 0 else NO_UV
        return null_transmission(mats, m, d, ng, ns, uv)
    if not (has(mats, MASK) and kind == MASK or has(mats, BLEND) and kind == BLEND):
        return (0.0, 0.0, 0.0)
    s = pass_probability(mats, m, surface_uv(geom, prim, o, d, t, b1, b2))
    return (s, s, s)


# ----------------------------------------------------------------------------- phase functions

@kernel(inline=True)
def phase_value(media, m, d, wo):
    """p(d -> wo) per steradian (d: the direction the light was travelling in)."""
    if media.phase[m] == HENYEY_GREENSTEIN:
        g = media.g[m]
        denom = 1.0 + g * g - 2.0 * g * vec.dot(d, wo)
        return INV_4PI * (1.0 - g * g) / (denom * math.sqrt(denom))
    return INV_4PI


@kernel(inline=True)
def phase_pdf(media, m, d, wo):
    """The density with which :func:`phase_sample` picks wo (its value, except for HG with g ~ 0)."""
    if media.phase[m] == HENYEY_GREENSTEIN and abs(media.g[m]) >= HG_ISOTROPIC_G:
        return phase_value(media, m, d, wo)
    return INV_4PI


@kernel(inline=True)
def phase_sample(media, m, d, u1, u2):
    """(wo, value / pdf, pdf): a direction sampled from medium m's phase function about d.

    Henyey-Greenstein by its inverse CDF in mu = cos(d, wo):
    mu = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u))^2) / (2 g); isotropic uniformly.
    """
    g = media.g[m] if media.phase[m] == HENYEY_GREENSTEIN else 0.0
    if abs(g) >= HG_ISOTROPIC_G:
        sq = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1)
        mu = (1.0 + g * g - sq * sq) / (2.0 * g)
    else:
        mu = 1.0 - 2.0 * u1
    mu = min(1.0, max(-1.0, mu))
    sin_t = math.sqrt(max(0.0, 1.0 - mu * mu))
    phi = 2.0 * math.pi * u2
    s, t = vec.orthonormal_basis(d)
    wo = vec.normalize(vec.from_local(s, t, d, (sin_t * math.cos(phi), sin_t * math.sin(phi), mu)))
    pdf = phase_pdf(media, m, d, wo)
    if not pdf > 0.0:
        return wo, 0.0, 0.0
    return wo, phase_value(media, m, d, wo) / pdf, pdf


@kernel(inline=True)
def albedo_at(media, m, p):
    """Medium m's single-scattering albedo per channel at point p: its row's, or a heterogeneous medium's albedo
    volume there (its row holds none)."""
    if has(media, HETEROGENEOUS) and media.kind[m] == HETEROGENEOUS:
        return volume_at(media, media.volumes[m, 1], p)
    return (media.albedo[m, 0], media.albedo[m, 1], media.albedo[m, 2])


@kernel(inline=True)
def photon_scatter(media, m, p, d, key, dim, roulette):
    """A photon (or stream) scattering at p in medium m: (alive, 1 / q, wo, phase weight, dim + 3); numbers
    dim .. dim + 2.

    With ``roulette`` it survives with q = the largest albedo there (:func:`albedo_at`), to be scaled by 1 / q
    (else 1 / q is 1; the flight's weight already holds the albedo); then wo from the phase function, with its
    value / pdf.  Not alive when roulette ends it or the pdf is 0.  The largest, not the mean: with the mean a
    channel of albedo a above it gains a / q a scattering, and its power's second moment a² / q a scattering
    grows without bound along the long paths of a bright medium (docs/media.md).
    """
    inv_q = 1.0
    if roulette:
        a = albedo_at(media, m, p)
        q = max(a[0], max(a[1], a[2]))
        if uniform(key, dim) >= q:
            return False, 1.0, d, 0.0, dim + 3
        inv_q = 1.0 / q
    wo, weight, pdf = phase_sample(media, m, d, uniform(key, dim + 1), uniform(key, dim + 2))
    return pdf > 0.0, inv_q, wo, weight if pdf > 0.0 else 0.0, dim + 3


# ----------------------------------------------------------------------------- direct light

@kernel(inline=True)
def power_heuristic(a, b):
    """Veach's power heuristic (β = 2): the MIS weight of a sample of the strategy with density a."""
    return a * a / (a * a + b * b)


@kernel(inline=True)
def shadow_ray_start(media, at, wi, towards, through):
    """Where a shadow ray towards unit direction wi leaves ``at``: (faces, cos_s, origin, medium).

    At a surface: cos_s = ns·wi, and the light must be on the scattering side of both normals (or, with
    ``through``, behind both, with |cos|), else ``faces`` is False; the origin is offset off the surface
    towards ``towards`` (wi, or the vector to the light), in the medium on that side.  In a medium
    (shape < 0): cos_s = 1, the point itself, its medium.
    """
    p, ng, ns, ng_front, shape, medium, _ = at
    if shape < 0:
        return True, 1.0, p, medium
    cos_s = vec.dot(ns, wi)
    cos_g = vec.dot(ng, wi)
    if through and cos_s < 0.0 and cos_g < 0.0:
        cos_s, cos_g = -cos_s, -cos_g
    if cos_s <= 0.0 or cos_g <= 0.0:
        return False, cos_s, p, medium
    return True, cos_s, vec.offset_origin(p, ng, towards), medium_after(media, shape, ng_front, wi, medium)


@kernel(inline=True)
def light_sample(tables, at, u, through):
    """One light sample seen from ``at`` through media and null boundaries (next-event estimation).

    ``at`` (a :class:`caustica.transport.ShadingPoint`) is a surface point p of ``shape`` (ng, ns its
    normals on the scattering side, ng_front its front normal) or, with shape < 0, a point in ``medium``.  u0 chooses the light (by power),
    (u1, u2) the point on an area light; u = (u0, u1, u2).  ``through``: the surface transmits (a glossy
    transmission lobe), so a light behind it counts too, with |cos|.
    Returns (contrib, wi, pdf, cos_s, is_area, ok, shadow rays):
    contrib = L_e T cos_s / pdf at a surface (the caller multiplies by f_r), L_e T / pdf in a medium
    (the caller multiplies by the phase function); wi the unit direction to the light; pdf the
    solid-angle density of choosing it (light choice included; 0 for a point, spot or directional light, a
    delta); ok
    False when the sample cannot light p (behind the light or the surface, or blocked: contrib 0).
    In vacuum (T = 1) it is the path tracer's classic estimate, number for number.
    """
    geom, mats, lights, media = tables
    p, shape = at.p, at.shape
    u0, u1, u2 = u
    zero = (0.0, 0.0, 0.0)
    if lights.kind.shape[0] == 0:
        return zero, zero, 0.0, 0.0, False, False, 0
    li, sel_pdf, _ = choose_light(lights, u0)
    if has(lights, ENV) and lights.kind[li] == ENV:
        return env_light_sample(tables, at, sel_pdf, (u1, u2), through)
    if has(lights, DIRECTIONAL) and lights.kind[li] == DIRECTIONAL:
        return directional_light_sample(tables, at, li, sel_pdf, through)
    if profiled(lights, li):
        return profiled_light_sample(tables, at, li, sel_pdf, through)
    is_area = lights.kind[li] == AREA
    if is_area:
        q, nq, Lq = emitter_point(lights, geom, li, u1, u2)
    else:
        q = vec.row(lights.position, li)
        nq = zero
        Lq = vec.row(lights.radiance, li)
    to_l = vec.sub(q, p)
    dist2 = vec.dot(to_l, to_l)
    if not dist2 > 0.0:
        return zero, zero, 0.0, 0.0, is_area, False, 0
    wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
    pdf = sel_pdf * dist2
    if is_area:
        cos_l = -vec.dot(nq, wi)
        if cos_l <= 0.0:
            return zero, wi, 0.0, 0.0, True, False, 0
        pdf = sel_pdf * dist2 / (lights.area[li] * cos_l)
    falloff = spot_falloff(lights, li, vec.neg(wi)) if has(lights, SPOT) and lights.kind[li] == SPOT else 1.0
    if not falloff > 0.0:
        return zero, wi, 0.0, 0.0, False, False, 0
    faces, cos_s, o, medium = shadow_ray_start(media, at, wi, to_l, through)
    if not faces:
        return zero, wi, 0.0, 0.0, is_area, False, 0
    target = vec.offset_origin(q, nq, vec.neg(to_l))
    T, rays = shadow_transmittance(geom, mats, media, o, target, medium)
    if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
        return zero, wi, 0.0, 0.0, is_area, False, rays
    Le = vec.hadamard(Lq, T)
    if has(lights, SPOT) and lights.kind[li] == SPOT:
        Le = vec.mul(Le, falloff)
    return vec.mul(Le, (cos_s if shape >= 0 else 1.0) / pdf), wi, pdf if is_area else 0.0, cos_s, is_area, True, \
        rays


@kernel
def profiled_light_sample(tables, at, li, sel_pdf, through):
    """:func:`light_sample` of a projector or textured spot li (chosen with probability sel_pdf): a point light
    whose intensity towards ``at`` is radiance x :func:`caustica.emitters.profile`; contrib I T cos_s / (r² sel_pdf)
    (without cos_s in a medium).  A delta: pdf 0, ``is_area`` False (no MIS)."""
    geom, mats, lights, media = tables
    zero = (0.0, 0.0, 0.0)
    q = vec.row(lights.position, li)
    to_l = vec.sub(q, at.p)
    dist2 = vec.dot(to_l, to_l)
    if not dist2 > 0.0:
        return zero, zero, 0.0, 0.0, False, False, 0
    wi = vec.mul(to_l, 1.0 / math.sqrt(dist2))
    shape = profile(lights, li, vec.neg(wi))
    if not (shape[0] > 0.0 or shape[1] > 0.0 or shape[2] > 0.0):
        return zero, wi, 0.0, 0.0, False, False, 0
    faces, cos_s, o, medium = shadow_ray_start(media, at, wi, to_l, through)
    if not faces:
        return zero, wi, 0.0, 0.0, False, False, 0
    T, rays = shadow_transmittance(geom, mats, media, o, q, medium)
    if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
        return zero, wi, 0.0, 0.0, False, False, rays
    Le = vec.hadamard(vec.hadamard(vec.row(lights.radiance, li), shape), T)
    return vec.mul(Le, (cos_s if at.shape >= 0 else 1.0) / (sel_pdf * dist2)), wi, 0.0, cos_s, False, True, rays


@kernel
def env_light_sample(tables, at, sel_pdf, u, through):
    """:func:`light_sample` of the environment (chosen with probability sel_pdf): a direction by
    :func:`caustica.emitters.env_sample` (u = (u1, u2)), its shadow ray to 2 max(R, |p - c|) along it (c, R
    the scene's bounding sphere, as Mitsuba 3 does), through media and null boundaries.  Returns what
    light_sample does, ``is_area`` True (not a delta: MIS applies)."""
    lights = tables[2]
    zero = (0.0, 0.0, 0.0)
    wi, pdf_dir, Le = env_sample(lights, u[0], u[1])
    pdf = sel_pdf * pdf_dir
    if not pdf > 0.0:   # a direction of zero density, or an environment that emits nothing (never chosen)
        return zero, wi, 0.0, 0.0, True, False, 0
    faces, cos_s, T, rays = distant_light_shadow(tables, at, wi, through)
    if not faces:
        return zero, wi, 0.0, 0.0, True, False, 0
    if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
        return zero, wi, 0.0, 0.0, True, False, rays
    return vec.mul(vec.hadamard(Le, T), cos_s / pdf), wi, pdf, cos_s, True, True, rays


@kernel(inline=True)
def distant_light_shadow(tables, at, wi, through):
    """The shadow ray towards a light at infinity (the environment, a directional light) along wi: from ``at``
    (:func:`shadow_ray_start`) to 2 max(R, |p - c|) (c, R the scene's bounding sphere, as Mitsuba 3 does), through
    media and null boundaries.  Returns (faces: the light is on a side that scatters, cos_s, T, rays)."""
    geom, mats, lights, media = tables
    faces, cos_s, o, medium = shadow_ray_start(media, at, wi, wi, through)
    if not faces:
        return False, cos_s, (0.0, 0.0, 0.0), 0
    T, rays = shadow_transmittance(geom, mats, media, o, vec.madd(at.p, wi, env_shadow_length(lights, at.p)),
                                   medium)
    return True, cos_s, T, rays


@kernel
def directional_light_sample(tables, at, li, sel_pdf, through):
    """:func:`light_sample` of directional light li (chosen with probability sel_pdf): its shadow ray against the
    light's direction, to 2 max(R, |p - c|) as the environment's (Mitsuba 3's ``directional``); contrib
    E T cos_s / sel_pdf (E T / sel_pdf in a medium).  A delta: pdf 0, ``is_area`` False (no MIS)."""
    lights = tables[2]
    zero = (0.0, 0.0, 0.0)
    wi = vec.neg(vec.row(lights.normal, li))
    faces, cos_s, T, rays = distant_light_shadow(tables, at, wi, through)
    if not faces:
        return zero, wi, 0.0, 0.0, False, False, 0
    if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
        return zero, wi, 0.0, 0.0, False, False, rays
    return vec.mul(vec.hadamard(vec.row(lights.radiance, li), T), cos_s / sel_pdf), wi, 0.0, cos_s, False, True, \
        rays


@kernel(inline=True)
def env_shadow_length(lights, p):
    """How far a shadow ray from p towards the environment goes: 2 max(R, |p - c|), (c, R) the scene's bounding
    sphere (Mitsuba 3's distance to an infinite emitter)."""
    sphere = lights.env_data
    to_c = (p[0] - sphere[0], p[1] - sphere[1], p[2] - sphere[2])
    return 2.0 * max(sphere[3], vec.length(to_c))


@kernel
def escape_transmittance(media, medium):
    """Per channel, the transmittance of an unbounded ray in ``medium``: 1 in vacuum or where sigma_t is 0, else 0.
    A heterogeneous medium's row has sigma_t 0: it ends at its box, and its tracked flight weighs the ray.

    An environment seen from inside a medium that nothing bounds is attenuated to nothing, except in
    channels that do not attenuate (docs/media.md)."""
    if medium < 0:
        return (1.0, 1.0, 1.0)
    return (1.0 if media.sigma_t[medium, 0] <= 0.0 else 0.0, 1.0 if media.sigma_t[medium, 1] <= 0.0 else 0.0,
            1.0 if media.sigma_t[medium, 2] <= 0.0 else 0.0)


@kernel(inline=True)
def escape_attenuation(media, medium, ray):
    """Per channel, the transmittance of a ray = (o, d) that meets nothing, from o on, in ``medium``: in a
    heterogeneous medium (which ends at its box) ratio tracked through the box (numbers keyed by the ray, as
    :func:`segment_attenuation`'s), else :func:`escape_transmittance`."""
    if has(media, HETEROGENEOUS) and medium >= 0 and media.kind[medium] == HETEROGENEOUS:
        return ratio_tracking(media, medium, ray, np.inf, ray_key(ray[0], ray[1]))
    return escape_transmittance(media, medium)


# ----------------------------------------------------------------------------- distances within a segment

@kernel(inline=True)
def _within_rate(sigma, mu, span):
    """The rate of a channel's exponential over a span (:func:`tracked_within`): sigma, or where sigma is 0 over an
    unbounded span the majorant mu; 0 means uniform over a bounded span, -1 nothing to sample."""
    if sigma * span > 1e-12:
        return sigma
    if span < np.inf:
        return 0.0
    return mu if mu > 0.0 else -1.0


@kernel(inline=True)
def _within_pdf(rate, span, x):
    """The density at x of the exponential of ``rate`` truncated to [0, span] (uniform for rate 0)."""
    if rate == 0.0:
        return 1.0 / span
    return rate * math.exp(-rate * x) / -math.expm1(-rate * span)


@kernel
def tracked_within(media, m, ray, s, u_channel, u):
    """A distance t in [0, s] along ``ray`` = (o, d) in heterogeneous medium m, and per channel
    T(t) sigma_s(t) / pdf(t): the photon methods' in-scatter distance (:func:`sample_distance_within`'s twin).

    As that one samples, with sigma_t read where the ray enters the medium's box: a channel chosen by u_channel, t
    from its exponential truncated to the part of [0, s] inside the box, the density the mean of the three channels'
    (uniform for a channel of sigma_t 0 there; over an unbounded span the majorant instead).  For a constant sigma_t
    (an albedo grid) the homogeneous medium's density; any positive density is unbiased.  T is ratio tracked with the
    numbers of :func:`segment_attenuation` for this ray, a prefix of the segment's.  (0, zero) when the segment
    misses the box."""
    zero = (0.0, 0.0, 0.0)
    t0, t1 = clip(media, m, ray[0], ray[1], s)
    if not t0 < t1:
        return 0.0, zero
    span = t1 - t0
    sigma, _ = coefficients(media, m, vec.madd(ray[0], ray[1], t0))
    mu = 0.0
    if span == np.inf:   # only an unbounded span reads the majorant (for a channel of sigma_t 0)
        _, state = walk_start(media, m, ray, t0)
        cx, cy = media.cells[m, 0], media.cells[m, 1]
        mu = media.cell_majorant[media.cells[m, 3] + (state[3] * cy + state[2]) * cx + state[1]]
    r0, r1, r2 = _within_rate(sigma[0], mu, span), _within_rate(sigma[1], mu, span), _within_rate(sigma[2], mu, span)
    if r0 < 0.0 or r1 < 0.0 or r2 < 0.0:
        return 0.0, zero
    c = min(int(u_channel * 3.0), 2)
    rate = r0 if c == 0 else r1 if c == 1 else r2
    x = u * span if rate == 0.0 else min(-math.log1p(u * math.expm1(-rate * span)) / rate, span)
    pdf = (_within_pdf(r0, span, x) + _within_pdf(r1, span, x) + _within_pdf(r2, span, x)) / 3.0
    if not pdf > 0.0:
        return 0.0, zero
    t = t0 + x
    _, ss = coefficients(media, m, vec.madd(ray[0], ray[1], t))
    T = ratio_tracking(media, m, ray, t, ray_key(ray[0], ray[1]))
    return t, vec.mul(vec.hadamard(T, ss), 1.0 / pdf)


@kernel(inline=True)
def sample_distance_within(media, m, s, u_channel, u):
    """A distance in [0, s] of medium m: a channel c chosen by u_channel, t from σc e^(−σc t) / (1 − e^(−σc s)).

    Uniform in [0, s] when the chosen channel does not attenuate.  Unlike :func:`sample_distance`
    it always lands inside the segment: the photon methods' next-event estimate of the direct
    light scattered along a camera segment (docs/media.md).  Its density is the mean of the three
    channels' (:func:`within_weight`).
    """
    c = min(int(u_channel * 3.0), 2)
    sc = media.sigma_t[m, c]
    if not sc * s > 1e-12:
        return u * s
    return min(-math.log1p(u * math.expm1(-sc * s)) / sc, s)


@kernel(inline=True)
def within_weight(media, m, s, t):
    """Per channel T_k(t) σs,k / p(t) for t drawn by :func:`sample_distance_within` over [0, s].

    p(t) = mean_c q_c(t), q_c = σc e^(−σc t) / (1 − e^(−σc s)) (1 / s for σc = 0); the common
    factor exp(−min σ t) is taken out of numerator and denominator, as in :func:`flight_weight`.
    """
    s0 = media.sigma_t[m, 0]
    s1 = media.sigma_t[m, 1]
    s2 = media.sigma_t[m, 2]
    smin = min(s0, min(s1, s2))
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    p = 0.0
    for c in range(3):
        sc = media.sigma_t[m, c]
        e = math.exp(-(sc - smin) * t)
        if sc * s > 1e-12:
            p += sc * e / (-math.expm1(-sc * s))
        else:
            p += e / s
        if c == 0:
            out0 = media.albedo[m, 0] * sc * e
        elif c == 1:
            out1 = media.albedo[m, 1] * sc * e
        else:
            out2 = media.albedo[m, 2] * sc * e
    p /= 3.0
    if not p > 0.0:
        return (0.0, 0.0, 0.0)
    return (out0 / p, out1 / p, out2 / p)


# ----------------------------------------------------------------------------- where a point is

@kernel
def medium_at(geom, media, o, d, fallback):
    """The medium point o is in, found by a probe ray along d: the first surface of a shape with media decides.

    Hit on its front (the ray arrives from outside), o is in the shape's exterior medium; on its back,
    in its interior.  Shapes without media are passed.  A probe that meets none gives ``fallback``
    (the camera's medium: the medium that fills what nothing bounds).  For a consistent scene
    (docs/media.md) any direction gives the same answer.
    """
    for _ in range(4 * NULL_CROSSINGS_CAP):
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            return fallback
        shape = geom.prim_shape[prim]
        p, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        if media.interior[shape] >= 0 or media.exterior[shape] >= 0:
            if vec.dot(d, ng) < 0.0:
                return media.exterior[shape]
            return media.interior[shape]
        o = vec.offset_origin(p, ng, d)
    return fallback


#: :func:`light_media`'s value for a light that spans media (part of an area light inside a medium, part
#: outside): each photon finds its own (:func:`photon_medium`).
PROBE_EACH = -2

#: Points on an area light that :func:`light_medium` probes (a Hammersley set: the first number, which picks a mesh's
#: triangle by area, takes every value apart).
LIGHT_PROBES = 256


@kernel(inline=True)
def radical_inverse_2(i):
    """i's binary digits mirrored about the point (van der Corput): 0, 1/2, 1/4, 3/4, ..."""
    out, f = 0.0, 0.5
    while i > 0:
        out += f * (i & 1)
        i >>= 1
        f *= 0.5
    return out


@kernel
def light_medium(geom, lights, media, e):
    """The medium light e emits into: its shape's exterior medium, else the medium around it (a probe);
    :data:`PROBE_EACH` when an area light's points are in different media.

    An area light on a shape with media emits into that shape's exterior (its front side, as
    Mitsuba); the environment into what a probe from outside the scene's bounding sphere meets first (a
    directional light: a probe along its direction); a point, spot or projector is probed from its position.
    Another area light is probed (:func:`medium_at`) from just in front of :data:`LIGHT_PROBES` points spread over
    it by area, along its normal: one medium when they agree, else :data:`PROBE_EACH` (a light that pierces a
    medium's boundary, as the torus of Mitsuba's ``test_homo_emitter_inside_medium``).  A part of less than about
    1 / LIGHT_PROBES of its area can be missed.
    """
    fallback = media.camera[0]
    if has(lights, ENV) and lights.kind[e] == ENV:   # from outside the scene's bounding sphere, towards its centre
        d = vec.normalize((0.3, 0.5, 0.81))
        c = (lights.env_data[0], lights.env_data[1], lights.env_data[2])
        return medium_at(geom, media, vec.madd(c, d, -2.0 * lights.env_data[3]), d, fallback)
    if has(lights, DIRECTIONAL) and lights.kind[e] == DIRECTIONAL:
        d = vec.row(lights.normal, e)
        c = (lights.env_data[0], lights.env_data[1], lights.env_data[2])
        return medium_at(geom, media, vec.madd(c, d, -2.0 * lights.env_data[3]), d, fallback)
    if lights.kind[e] == AREA:
        shape = geom.prim_shape[lights.prims[lights.prim_first[e]]]
        if media.interior[shape] >= 0 or media.exterior[shape] >= 0:
            return media.exterior[shape]
        first = 0
        for i in range(LIGHT_PROBES):
            p, n = sample_area_emitter(lights, geom, e, (i + 0.5) / LIGHT_PROBES, radical_inverse_2(i))
            m = medium_at(geom, media, vec.offset_origin(p, n, n), n, fallback)
            if i == 0:
                first = m
            elif m != first:
                return PROBE_EACH
        return first
    return medium_at(geom, media, vec.row(lights.position, e), vec.normalize((0.3, 0.5, 0.81)), fallback)


@kernel(inline=True)
def photon_medium(geom, media, light_medium, li, o, d):
    """The medium a photon leaving light li from o along d starts in: the light's (:func:`light_media`), or for
    a light that spans media (:data:`PROBE_EACH`) a probe from o along d, the first boundary it meets."""
    m = light_medium[li]
    if m == PROBE_EACH:
        return medium_at(geom, media, o, d, media.camera[0])
    return m


def light_media(scene) -> np.ndarray:
    """int32[L]: the medium each light emits into, or :data:`PROBE_EACH` (:func:`light_medium`)."""
    lights = scene.lights
    if not scene.has_media:
        return np.full(lights.kind.shape[0], -1, np.int32)
    return np.array([light_medium(scene.geometry, lights, scene.media, e) for e in range(lights.kind.shape[0])],
                    np.int32)
