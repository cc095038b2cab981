"""The camera pass of the progressive methods: one visible point per pixel per pass (SPEC §7).

Each pass, pixel i sends one camera ray through a new jittered position.  It is
followed through mirrors and glass — glass picks reflection or refraction with the
Fresnel probability, as in the path tracer, so each pass sees one branch and the
passes average them — until it reaches a diffuse surface, escapes, or exceeds
``max_specular`` bounces.  Along the way the radiance of emitters it sees is added (the environment's
too, where it escapes);
at the diffuse point the direct light from every emitter is added (n × n stratified
shadow rays per area light), and that point becomes the pixel's *visible point*:
position, shading normal on the viewed side (the geometric one under a normal or bump map, whose
perturbed normal goes to the BSDF's row), and weight W = β · ρ / π (the
throughput β of the specular chain times the diffuse BRDF), so that the photons'
flux Φ gathered there contributes W · Φ.

**Emitters seen in glass.**  At glass the path takes one branch (reflection with the Fresnel
probability F), but an emitter met first along either branch is added with its expected weight
β F Le or β (1 − F) Le / η² at once, and the branch taken leaves its next hit's emission out: the
same expectation, without the rare spike of a light's reflection seen in a few passes only (on the
diacaustic scene the brightest noise of the caustic's pixels was the area light glinting in the
sphere's silhouette).  It costs one or two rays at each glass hit of a camera path.

**A delta coating over a diffuse lobe** (plastic, :func:`caustica.bsdfs.coat`).  The path takes the
coating's reflection with the probability P that the BSDF's own sampling gives it (the number as glass's,
stratified over the passes at the path's first choice), weight β F_i specular / P, and otherwise makes its
visible point there with weight W = β A / (1 − P), A the diffuse lobe's outgoing factor; the photons
gathered there carry the lobe's other factor B (:mod:`caustica.photons.trace`), and so does each shadow ray
of its direct light.  The emitters the coating reflects are added in expectation, β F_i specular Le, as
glass's are.  Each pass is an unbiased sample of both lobes, as of glass's two branches.

**A glossy coating over a diffuse lobe** (roughplastic, :func:`caustica.bsdfs.rough_coat`) is split the same way:
its diffuse lobe is separable too (f = A(wo) B(wi), B the coating's tabulated transmittance), so the visible point
takes W = β A / (1 − P) and the photons and shadow rays B; with the probability P of the BSDF's own sampling the
path takes the glossy lobe instead, as a glossy vertex of that lobe alone: one light sample MIS-weighted against
the lobe's sampling (:func:`caustica.bsdfs.eval_coating`), then the lobe's sample
(:func:`caustica.bsdfs.sample_coating`), both divided by P.  (Without the light sample, the coating's reflection of
a small light was a scatter of fireflies over a rough plastic floor at 100 passes.)

**The coating's reflection of a caustic** (``claim``: when the caustic photons keep statistics of their own).  A
camera path that takes the glossy lobe finds light that reached the floor through glass only by meeting the light
through that glass: on tests/scenes/plastic-caustic.xml that share was a quarter of the caustic and most of its
noise.  So, as pbrt-v4's visible points weigh each photon by the whole BSDF, the point on the diffuse lobe becomes a
*split point* (:func:`split_visible_point`): weight β / (1 − P), the global records (power times B) weighted by A,
each caustic record by A + f_glossy(d, wi) / B(wi) (:func:`caustica.bsdfs.split_record_weight`), which is the whole
f times the photon's power; and a path that took the coating leaves out what it gathers through caustic casters
alone after it (:func:`claimed`: the photons' own rule for a caustic path, light → casters → here), so nothing
counts twice.  The glossy lobe still carries the rest by the camera path (the direct highlight with its light
sample, what it sees of lit walls), where a photon estimate through a narrow lobe would be the noisier: in a
Cornell box with a rough plastic floor and back wall (GGX, α 0.1) weighting every photon by the whole BSDF doubled
the image's noise, and the split points leave it as it was (docs/results.md, 2026-12-06).

**Glossy surfaces** (rough metal and glass: smooth lobes, none diffuse) hold no visible point, as in pbrt-v4's
SPPM: the path takes one light sample there, MIS-weighted against the BSDF's sampling (the path tracer's
:func:`caustica.lighting.next_event`), and goes on by the BSDF's sample; an emitter or the environment it meets
next is weighted to match (:func:`seen_weight`).  Glossy bounces count towards ``max_specular``; a path that
reaches it ends (its light beyond is lost, as a path tracer's past its depth).

**Narrow glossy lobes beside diffuse ones** (pplastic, principled, principledthin with some glossy lobe's roughness
below :data:`caustica.bsdfs.NARROW_ALPHA`, or with a glossy transmission at any roughness:
:func:`caustica.bsdfs.splits_lobes`; broader reflections the visible point weighs with the photons, as pbrt-v4's SPPM,
:func:`bsdf_visible_point`): the path picks the glossy lobes or the diffuse ones (:func:`lobe_choice`).  A glossy pick
(probability Q, :func:`caustica.bsdfs.glossy_pick`: the mean of the BSDF's own sampling rate P and the glossy lobes'
share of its albedo) makes a glossy vertex of the glossy lobes alone, sampled as the BSDF samples them, everything over
Q; a diffuse one makes the visible point here, weight β / (1 − Q), which holds the diffuse lobes alone: the photons and
its light sample are weighed by their f (:func:`bsdf_visible_point`).  pbrt-v4's SPPM weighs the photons by the whole
BSDF instead, which leaves a narrow glossy lobe to the few photons that arrive within it: a frosted panel of roughness
0.01 in front of a lit wall rendered black but for a few fireflies (tests/test_principled.py; sppm 12 % dark).  The
choice costs noise where the lobe sees little but the lights (a third more error on a floor under a caustic,
benchmarks/narrow_threshold.py), so broad reflections are not split; a glossy transmission is, however broad (4-220x
less error through a frosted panel, where photons on the panel are few).  On a pplastic floor of roughness 0.15 under a
caustic the split raised the noise by 60 % at equal passes before Q; picking by P alone (Mitsuba's rate: two thirds
glossy on that plastic) left the floor under a caustic of roughness 0.05 with 1.7x the per-pixel deviation outside the
highlight that Q leaves (docs/results.md).  Unlike roughplastic's split points these claim no caustic: the glossy lobes'
share of one is the camera path's.

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

**Media** (the same loop; a scene without media takes none of these branches).  The camera path
tracks the medium it is in (the camera's, then :func:`caustica.media.medium_after` at every surface
it leaves) and crosses null boundaries without scattering.  It samples no free flights: over each
medium segment its throughput β is multiplied by the exact transmittance exp(−σt s), so the visible
point's weight and every emitter the path sees are attenuated exactly.  Each medium segment is
written out for the volume estimate, with the direct light scattered along it
(:mod:`caustica.photons.segments`); the direct light at the visible point weights each shadow ray by
its transmittance (:func:`caustica.lighting.direct_stratified`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..bsdfs import DELTA, DIFFUSE_REFLECTION, GLOSSY, GLOSSY_LOBES, GLOSSY_PART, SMOOTH, TRANSMISSION, \
    coat, colour, delta_branches, eval_coating, eval_part, eval_radiance, glossy_pick, glossy_share, has_null_lobe, \
    held_lobes_transmit, oriented, rough_coat, sample, sample_coating, sample_glossy, splits_lobes, wrapped
from ..camera import generate_ray, pixel_of
from ..geometry import vec
from ..geometry.scene_geometry import intersect
from ..jit import borrowed, kernel, parallel_for
from ..memory import check_budget
from ..emitters import ENV, env_pdf, radiance_at_hit
from ..features import guarded_by, has
from ..scene.description import PLASTIC, ROUGHPLASTIC
from ..lighting import direct_stratified, emission_mis, next_event
from ..media import in_a_medium, light_sample, medium_after, power_heuristic, segment_attenuation
from ..sampling.rng import KRONECKER_ALPHA, STREAM_CAMERA, STREAM_CAMERA_MEDIA, STREAM_CAMERA_SCRAMBLE, kronecker, \
    pass_stream, path_key, sobol02, uniform
from ..transport import CROSSED, TRAPPED, ShadingPoint, surface_interaction
from .trace import beside_diffuse
from .segments import MEDIUM_SEGMENTS, SEGMENT_BYTES, allocate_segments, emitted_along, emission_weighted, \
    end_segment_at_wall, escaped_radiance, first_segment_numbers, segment_inscatter, store_segment, wall_normal

INV_PI = 1.0 / math.pi
#: A camera path's max_depth where a render sets none (-1): more segments than any path takes.
UNLIMITED_DEPTH = 1 << 30


def max_depth_of(settings) -> int | None:
    """The render's max_depth (Mitsuba's: segments of a whole path); None for -1 or none (no limit)."""
    m = settings.max_depth
    return None if m is None or m < 0 else int(m)


def depth_limit(settings) -> int:
    """:func:`max_depth_of` as an int for the camera path's own counting: :data:`UNLIMITED_DEPTH` for no limit."""
    m = max_depth_of(settings)
    return UNLIMITED_DEPTH if m is None else m


#: Columns of :attr:`VisiblePoints.bsdf`: the material (as a float), d, the geometric normal, the surface coordinates,
#: the shading normal (perturbed under a normal or bump map).
BSDF_MATERIAL, BSDF_INCOMING, BSDF_NG, BSDF_UV, BSDF_NS, BSDF_COLUMNS = 0, 1, 4, 7, 15, 18
#: The material column of a roughplastic's split point (:func:`split_visible_point`): SPLIT_ROW - m for material m
#: (-1: no row; m >= 0: a point that evaluates its BSDF).
SPLIT_ROW = -2.0


@kernel(inline=True)
def branch_number(first_glass, numbers, dim):
    """The number that picks a glass branch or a coating, and the path's state after it: (u, False, dim + 1).

    At the path's first such choice u is point ``pass`` of a shifted Kronecker sequence (the branches stratified
    over the passes), later uniform(key, dim); ``numbers`` as :func:`visible_point` takes them."""
    key, qkey, _, pass_index = numbers
    if first_glass:
        return kronecker(pass_index, KRONECKER_ALPHA[0], uniform(qkey, 2)), False, dim + 1
    return uniform(key, dim), False, dim + 1


@kernel(inline=True)
def glass_step(L, betas, seen, branches, u):
    """At glass: the emitters seen along both branches added with their expected weights, then the branch u picks.

    ``betas`` = (β times the reflected tint, β times the transmitted tint); ``seen`` = (Lr, Lt): the emission first
    met along the reflected and the refracted direction (Lt unused when F = 1); ``branches`` = (wr, wt, F, eta) as
    :func:`caustica.bsdfs.delta_branches` gives them.  An emitter seen along either branch is added with weight F or (1 - F) / η² rather than
    when the choice happens to take that branch: a light's reflection in the glass is a smooth term,
    not a rare spike; the branch taken must then leave its first hit's emission out.  Returns
    (L, the new direction, β for it).
    """
    Lr, Lt = seen
    wr, wt, F, eta = branches
    beta_r, beta_t = betas
    L = vec.add(L, vec.mul(vec.hadamard(beta_r, Lr), F))
    inv_eta2 = 1.0 / (eta * eta)
    if F < 1.0:
        L = vec.add(L, vec.mul(vec.hadamard(beta_t, Lt), (1.0 - F) * inv_eta2))
    if u < F:
        return L, wr, beta_r
    return L, wt, vec.mul(beta_t, inv_eta2)


@kernel
def medium_segment(tables, segment, medium, beta, n_seg, numbers, out):
    """A camera path's flight through ``medium``, ``segment`` = (o, d, its length s: to a surface, or inf, the
    path's surface vertices k before it, max_depth, the normal of the wall it starts at or zero,
    :func:`~caustica.photons.segments.wall_normal`): it is stored in slot slot0 + n_seg of ``out`` = (slot0,
    segments).  Returns (the direct light scattered along it towards o, times β: none when a path of k + 2
    segments would pass max_depth; β past it).  ``numbers`` = (key, qkey, vkey, pass_index), see
    :func:`visible_point`.
    """
    o, d, s, k, max_depth, start_wall = segment
    _, qkey, vkey, pass_index = numbers
    slot0, segments = out
    store_segment(slot0 + n_seg, (o, d, s), (beta, medium, k), start_wall, segments)
    if k + 2 > max_depth:   # camera -> k surfaces -> the scattering point -> the light
        if s < np.inf:
            beta = vec.hadamard(beta, segment_attenuation(tables[3], medium, (o, d), s))
        return (0.0, 0.0, 0.0), beta
    vd = 7 * n_seg
    u_dist = uniform(vkey, vd + 1)
    u1 = uniform(vkey, vd + 3)
    u2 = uniform(vkey, vd + 4)
    if n_seg == 0:   # the first segment's distance and light point: stratified over the passes
        u_dist, u1, u2 = first_segment_numbers(pass_index, qkey)
    Ls = segment_inscatter(tables, o, d, min(s, 1e30), medium, beta,
                           (uniform(vkey, vd), u_dist, uniform(vkey, vd + 2), u1, u2, uniform(vkey, vd + 5),
                            uniform(vkey, vd + 6)))
    if s < np.inf:
        beta = vec.hadamard(beta, segment_attenuation(tables[3], medium, (o, d), s))
    return Ls, beta


@kernel(inline=True)
def seen_weight(lights, e, last, hit):
    """The weight of emitter e's radiance a camera path meets at ``hit`` = (cos_l, t, null crossings, point): 1 from
    the camera or after a delta scattering; after a glossy one, ``last`` = (specular, pdf_last, p_last), its MIS
    weight against the light sample taken there (:func:`caustica.lighting.emission_mis`)."""
    if last[0]:
        return 1.0
    cos_l, t, crossed, p = hit
    return emission_mis(lights, e, last, cos_l, t, crossed, p)


@kernel(inline=True)
def escape_weight(lights, d, last):
    """:func:`seen_weight` for the environment, along the escaping direction d."""
    specular, pdf_last, _ = last
    if specular:
        return 1.0
    return power_heuristic(pdf_last, lights.select_pdf[lights.env[0]] * env_pdf(lights, d))


@kernel(inline=True)
def glossy_step(tables, at, m, d, path, key, dim):
    """At a glossy surface (rough metal or glass: no visible point here, as in pbrt-v4's SPPM), or for the direct light
    of a visible point on roughplastic under a map (:func:`bsdf_visible_point`): its direct light by one light sample,
    MIS-weighted against the BSDF's sampling (:func:`caustica.lighting.next_event`), then the BSDF's own sample.
    ``path`` = (L, β).  Returns (L, alive, the new direction, β for it, the lobe, its density, dim)."""
    L, beta = path
    ok, term, scale, _, dim = next_event(tables, at, m, d, beta, key, dim)
    if ok:
        L = vec.madd(L, term, scale)
    alive, wi, weight, pdf, lobe, eta, dim = sample(tables[1], m, d, at.ng, at.ns, at.uv, key, dim)
    beta = vec.hadamard(beta, weight)
    if lobe & TRANSMISSION:
        beta = vec.mul(beta, 1.0 / (eta * eta))   # radiance is compressed into the denser medium
    return L, alive, wi, beta, lobe, pdf, dim


@kernel
def lobe_choice(tables, at, m, d, path, numbers, last):
    """At a material with glossy lobes beside diffuse ones (:func:`caustica.bsdfs.splits_lobes`), its glossy lobes or
    its diffuse ones picked (numbers ``numbers`` = (key, dim): dim + 3 picks, dim + 3 .. dim + 5 sample).  The glossy
    ones, with probability Q (:func:`caustica.bsdfs.glossy_pick`), make this a glossy vertex of the glossy lobes alone:
    one light sample (numbers dim .. dim + 2) MIS-weighted against their sampling (:func:`caustica.bsdfs.sample_glossy`,
    density eval_part's over the BSDF's own rate P, :func:`caustica.bsdfs.glossy_share`), then that sample, both over
    Q.  The diffuse ones make the visible point here, weight β / (1 - Q), which holds the diffuse lobes alone
    (:func:`caustica.bsdfs.eval_radiance`).  So no photon estimate goes through a narrow glossy lobe (a frosted panel
    of roughness 0.01 was black, but for a few fireflies, when photons were weighed by its whole BSDF).  At the
    ``last`` specular vertex allowed the visible point is made with weight β, no glossy vertex may follow (the
    glossy lobes' light is lost there, as roughplastic's coating's: :func:`rough_coating_step`).  ``path`` = (L, β).
    Returns (glossy, L, alive, the new direction, the weight β is multiplied by for it or for the visible point, the
    glossy sample's density given the pick, dim)."""
    mats = tables[1]
    L, beta = path
    key, dim = numbers
    zero = (0.0, 0.0, 0.0)
    if last:
        return False, L, False, d, (1.0, 1.0, 1.0), 0.0, dim
    P = glossy_share(mats, m, d, at.ns, at.uv)
    Q = glossy_pick(mats, m, d, at.ns, at.uv, P)
    u = uniform(key, dim + 3)
    if not u < Q:
        w = 1.0 / (1.0 - Q)
        return False, L, False, d, (w, w, w), 0.0, dim + 6
    ok, term, scale, _, _ = next_event(tables, at, m, d, beta, key, dim, (GLOSSY_PART, P))
    if ok:
        L = vec.madd(L, term, scale / Q)
    alive, wi, _, _, lobe, eta, dim_on = sample_glossy(mats, m, d, at.ng, at.ns, at.uv, (key, dim + 3), u / Q)
    f, f_scale, pdf = eval_part(mats, m, d, at.ng, at.ns, at.uv, wi, GLOSSY_PART)
    if not (alive and pdf > 0.0):
        return True, L, False, wi, zero, 0.0, dim_on
    # the glossy lobes' density given this pick is pdf / P
    scale = f_scale * abs(vec.dot(wi, at.ns)) * P / (pdf * Q)
    if lobe & TRANSMISSION:
        scale /= eta * eta   # radiance is compressed into the denser medium
    return True, L, True, wi, vec.mul(f, scale), pdf / P, dim_on


@kernel(inline=True)
def delta_step(tables, at, m, d, path, u):
    """At a mirror or glass: the direction the path takes and β for it (glass: the branch u picks, with the emitters
    seen along both added in expectation, :func:`glass_step`).  ``path`` = (L, β).  Returns (L, direction, β,
    whether the next hit's emission was already added)."""
    mats, media = tables[1], tables[3]
    L, beta = path
    wr, wt, F, eta, tints = delta_branches(mats, m, d, at.ng, at.ns, at.uv)
    if not mats.flags[m] & TRANSMISSION:
        return L, wr, vec.hadamard(beta, tints[0]), False
    Lr = emitted_along(tables, vec.offset_origin(at.p, at.ng, wr), wr,
                       medium_after(media, at.shape, at.ng_front, wr, at.medium))
    Lt = (0.0, 0.0, 0.0)
    if F < 1.0:
        Lt = emitted_along(tables, vec.offset_origin(at.p, at.ng, wt), wt,
                           medium_after(media, at.shape, at.ng_front, wt, at.medium))
    L, wi, beta = glass_step(L, (vec.hadamard(beta, tints[0]), vec.hadamard(beta, tints[1])), (Lr, Lt),
                             (wr, wt, F, eta), u)
    return L, wi, beta, True


@kernel(inline=True)
def visible_point_here(tables, at, m, beta, coating, numbers, params, dim):
    """The visible point's weight W and its direct light W E at ``at``: W = β ρ / π, or, under a delta coating
    ``coating`` = (P, A) (:func:`caustica.bsdfs.coat`; P < 0 without one), β A / (1 - P) with each shadow ray
    weighted by the lobe's factor B (:func:`caustica.lighting.direct_stratified`)."""
    key, qkey, _, pass_index = numbers
    n_strata, fixed_grid = params[0], params[1]
    P, A = coating
    if P >= 0.0:
        w = vec.mul(vec.hadamard(beta, A), 1.0 / (1.0 - P))
    else:
        w = vec.mul(vec.hadamard(beta, colour(tables[1], m, at.uv)), INV_PI)
    lobe_b = m if P >= 0.0 else -1
    if fixed_grid:
        E = direct_stratified(tables, at, key, dim, (n_strata, True, -1), lobe_b, None)
    else:
        E = direct_stratified(tables, at, qkey, 3, (n_strata, False, pass_index), lobe_b, None)
    return w, vec.hadamard(w, E)


@kernel
def bsdf_visible_point(tables, at, m, d, beta, numbers, pixel):
    """A visible point that evaluates its BSDF: on the diffuse lobes of a BSDF with glossy ones beside them
    (:func:`lobe_choice` picked them), or on any diffuse lobe under a normal or bump map (its frame perturbed), made as
    pbrt-v4's SPPM makes every one: its weight is β (β / (1 - P) after a lobe choice, passed as ``beta``), the gather
    weights each photon by the BSDF's value f(d, the photon's direction) of the lobes it holds
    (:func:`caustica.bsdfs.eval_photon`, :func:`caustica.photons.grid.grid_range_sum`).  Its direct light, the path ending here: one light sample times that
    f (on either side where a diffuse lobe transmits).  On roughplastic under a map (its glossy lobe not split off) a
    glossy vertex's, one light sample and one BSDF sample whose ray counts only the emitters it meets (past null
    boundaries, through media: :func:`caustica.photons.segments.emission_weighted`), combined by MIS (power heuristic).
    Numbers ``numbers`` = (key, dim) on.  The BSDF's point (material, d, normals, uv) goes to row i of ``pixel`` =
    (i, :attr:`VisiblePoints.bsdf`).  Returns the direct light, β included."""
    key, dim = numbers
    mats = tables[1]
    write_bsdf_row(at, m, d, pixel)
    if mats.flags[m] & GLOSSY and not splits_lobes(mats, m):
        Ld, alive, wi, beta_wi, lobe, pdf, _ = glossy_step(tables, at, m, d, ((0.0, 0.0, 0.0), beta), key, dim)
        if alive and pdf > 0.0 and not lobe & DELTA:
            medium = medium_after(tables[3], at.shape, at.ng_front, wi, at.medium)
            Le = emission_weighted(tables, vec.offset_origin(at.p, at.ng, wi), wi, medium, pdf)
            Ld = vec.add(Ld, vec.hadamard(beta_wi, Le))
        return Ld
    through = held_lobes_transmit(mats, m)   # principledthin's diffuse transmission: lights behind it too
    contrib, wi, _, _, _, ok, _ = light_sample(tables, at, (uniform(key, dim), uniform(key, dim + 1),
                                                            uniform(key, dim + 2)), through)
    if not ok:
        return (0.0, 0.0, 0.0)
    f, f_scale = eval_radiance(mats, m, d, at.ng, at.ns, at.uv, wi)
    return vec.mul(vec.hadamard(beta, vec.hadamard(f, contrib)), f_scale)


@kernel
def write_bsdf_row(at, code, d, pixel):
    """Row i of ``pixel`` = (i, :attr:`VisiblePoints.bsdf`): the material column ``code``, then d, the normals and uv
    of ``at``."""
    i, rows = pixel
    rows[i, BSDF_MATERIAL] = code
    for k in range(3):
        rows[i, BSDF_INCOMING + k] = d[k]
        rows[i, BSDF_NG + k] = at.ng[k]
        rows[i, BSDF_NS + k] = at.ns[k]
    for k in range(8):
        rows[i, BSDF_UV + k] = at.uv[k]


@kernel
def split_visible_point(at, m, d, pixel):
    """The row of a visible point on roughplastic m's diffuse lobe that also claims the glossy lobe's share of the
    caustic (``claim``, :func:`visible_point`): its material column SPLIT_ROW - m (:func:`write_bsdf_row`)."""
    write_bsdf_row(at, SPLIT_ROW - m, d, pixel)


@kernel
def bsdf_point(mats, rows, i):
    """(mats, m, d, ng, ns, uv): visible point i's BSDF as :func:`caustica.photons.grid.grid_range_sum` weighs with it,
    from its row of :attr:`VisiblePoints.bsdf` (:func:`bsdf_visible_point` or :func:`split_visible_point` writes
    it)."""
    r = rows[i]
    code = r[BSDF_MATERIAL]
    m = int(code) if code >= 0.0 else int(SPLIT_ROW - code)
    return (mats, m, (r[BSDF_INCOMING], r[BSDF_INCOMING + 1], r[BSDF_INCOMING + 2]),
            (r[BSDF_NG], r[BSDF_NG + 1], r[BSDF_NG + 2]), (r[BSDF_NS], r[BSDF_NS + 1], r[BSDF_NS + 2]),
            (r[BSDF_UV], r[BSDF_UV + 1], r[BSDF_UV + 2], r[BSDF_UV + 3], r[BSDF_UV + 4], r[BSDF_UV + 5], r[BSDF_UV + 6],
             r[BSDF_UV + 7]))


@guarded_by(ROUGHPLASTIC)
@kernel(inline=True)
def split_point(mats, rows, i):
    """Whether visible point i's row is a roughplastic's split point (:func:`split_visible_point`); never in a scene
    without roughplastic."""
    return has(mats, ROUGHPLASTIC) and rows[i, BSDF_MATERIAL] <= SPLIT_ROW


@kernel
def split_diffuse(mats, rows, i):
    """The diffuse lobe's factor A (:func:`caustica.bsdfs.rough_coat`) of split point i, from its row: what the
    records of the global photons (power times B) are weighted by there."""
    _, m, d, _, ns, uv = bsdf_point(mats, rows, i)
    return rough_coat(mats, m, d, ns, uv)[1]


@kernel(inline=True)
def coating_step(tables, at, m, d, path, branch, last):
    """At a delta coating over a diffuse lobe (plastic): the coating's reflection taken with its sampling
    probability P (0 at the ``last`` specular vertex allowed), the emitters it reflects added in expectation,
    as glass's.  ``path`` = (L, β); ``branch`` = (first_glass, numbers, dim), the state :func:`branch_number`
    takes.  Returns (take the coating, (wc, P, its weight, A) of :func:`caustica.bsdfs.coat`, L, first_glass, dim)."""
    mats, media = tables[1], tables[3]
    L, beta = path
    first_glass, numbers, dim = branch
    wc, P, w_coat, A = coat(mats, m, d, at.ng, at.ns, at.uv)
    if last:
        P = 0.0
    take = False
    if P > 0.0:
        u, first_glass, dim = branch_number(first_glass, numbers, dim)
        Lr = emitted_along(tables, vec.offset_origin(at.p, at.ng, wc), wc,
                           medium_after(media, at.shape, at.ng_front, wc, at.medium))
        L = vec.add(L, vec.mul(vec.hadamard(beta, vec.hadamard(w_coat, Lr)), P))
        take = u < P
    return take, (wc, P, w_coat, A), L, first_glass, dim


@kernel(inline=True)
def rough_coating_step(tables, at, m, d, path, branch, last):
    """At a glossy coating over a diffuse lobe (roughplastic): the coating's glossy lobe taken with the probability P
    that the BSDF's own sampling gives it (0 at the ``last`` specular vertex allowed), else the visible point here.
    Taken, the lobe alone is a glossy vertex: one light sample MIS-weighted against the lobe's sampling, then the
    lobe's sample, both divided by P.  ``path`` = (L, β); ``branch`` = (first_glass, numbers, dim) as for
    :func:`coating_step`.  Returns (take the coating, (direction, P, its weight, A) as :func:`coating_step`'s, L,
    the sampled direction's density, first_glass, dim); a sample below the surface comes back taken with weight
    zero (the path ends)."""
    mats = tables[1]
    L, beta = path
    first_glass, numbers, dim = branch
    key = numbers[0]
    P, A = rough_coat(mats, m, d, at.ns, at.uv)
    if last:
        P = 0.0
    wc = w_coat = zero = (0.0, 0.0, 0.0)
    take = False
    pdf = 0.0
    if P > 0.0:
        u, first_glass, dim = branch_number(first_glass, numbers, dim)
        take = u < P
        if take:
            contrib, wl, pdf_light, _, is_area, ok, _ = light_sample(
                tables, at, (uniform(key, dim), uniform(key, dim + 1), uniform(key, dim + 2)), False)
            if ok:
                f, pdf_l = eval_coating(mats, m, d, at.ng, at.ns, wl)
                w_l = power_heuristic(pdf_light, pdf_l) if is_area else 1.0
                L = vec.madd(L, vec.hadamard(beta, vec.hadamard(f, contrib)), w_l / P)
            ok, wc, w, pdf, dim = sample_coating(mats, m, d, at.ng, at.ns, key, dim + 3)
            w_coat = vec.mul(w, 1.0 / P) if ok else zero
    return take, (wc, P, w_coat, A), L, pdf, first_glass, dim


@kernel(inline=True)
def delta_vertex(tables, at, m, d, path, branch):
    """The path at a mirror or glass (:func:`delta_step`), glass's branch number drawn first
    (:func:`branch_number`; ``branch`` = (first_glass, numbers, dim)).
    Returns (L, direction, β, whether the next hit's emission was already added, first_glass, dim)."""
    first_glass, numbers, dim = branch
    u = 0.0
    if tables[1].flags[m] & TRANSMISSION:
        u, first_glass, dim = branch_number(first_glass, numbers, dim)
    L, wi, beta, counted = delta_step(tables, at, m, d, path, u)
    return L, wi, beta, counted, first_glass, dim


@kernel(inline=True)
def diffuse_vertex(tables, at, m, d, path, branch, rules):
    """The visible point on a surface with a diffuse lobe, unless a coating over it is taken instead
    (:func:`coating_step`, :func:`rough_coating_step`; ``rules`` = (params as :func:`visible_point` takes them, the
    last specular vertex allowed, the pixel's row of :attr:`VisiblePoints.bsdf`)), or a glossy lobe beside it
    (:func:`lobe_choice`: pplastic, principled, principledthin).  Under a normal or bump map, or beside a glossy lobe,
    the point evaluates the BSDF (:func:`bsdf_visible_point`).
    ``path`` = (L, β); ``branch`` = (first_glass, numbers, dim) as :func:`branch_number` takes it.  Returns (found,
    its normal, its weight W, L with its direct light, take the coating, (wc, P, its weight, A) with P < 0 without a
    coating, the coating's sampled density, first_glass, dim)."""
    mats = tables[1]
    L, beta = path
    params, last, pixel = rules
    first_glass, numbers, dim = branch
    flags = mats.flags[m]
    zero = (0.0, 0.0, 0.0)
    take_coat, coating, pdf_coat = False, (zero, -1.0, zero, zero), 0.0
    if splits_lobes(mats, m):
        # glossy lobes beside diffuse ones (pplastic, principled, principledthin; under a map too): a glossy one taken
        # as a coating's lobe is, else the visible point on the diffuse ones (its normal the geometric one under a map)
        glossy, L, alive, wi, w, pdf, dim = lobe_choice(tables, at, m, d, path, (numbers[0], dim), last)
        if glossy:
            return False, zero, zero, L, True, (wi, -1.0, w, zero), pdf, first_glass, dim
        w = vec.hadamard(beta, w)
        Ld = bsdf_visible_point(tables, at, m, d, w, (numbers[0], dim), pixel)
        return True, at.ng if wrapped(mats, m) else at.ns, w, vec.add(L, Ld), take_coat, coating, pdf_coat, \
            first_glass, dim
    if wrapped(mats, m):
        # a diffuse lobe under a map: the visible point evaluates the BSDF in its perturbed frame (at.ns); its
        # normal for the same-side test is the geometric one (the photons' records carry theirs)
        Ld = bsdf_visible_point(tables, at, m, d, beta, (numbers[0], dim), pixel)
        return True, at.ng, beta, vec.add(L, Ld), take_coat, coating, pdf_coat, first_glass, dim
    if has(mats, PLASTIC) and flags & SMOOTH and flags & DELTA:
        # a delta coating over a diffuse lobe (plastic): the coating, else the visible point here
        take_coat, coating, L, first_glass, dim = coating_step(tables, at, m, d, path, branch, last)
    elif has(mats, ROUGHPLASTIC) and mats.kind[m] == ROUGHPLASTIC:
        # a glossy coating over a diffuse lobe: the coating's lobe, else the visible point here
        take_coat, coating, L, pdf_coat, first_glass, dim = rough_coating_step(tables, at, m, d, path, branch, last)
    elif has(mats, GLOSSY_LOBES) and flags & GLOSSY and flags & DIFFUSE_REFLECTION:
        # a broad glossy lobe beside a diffuse one (pplastic, principled): the visible point evaluates the whole BSDF
        Ld = bsdf_visible_point(tables, at, m, d, beta, (numbers[0], dim), pixel)
        return True, at.ns, beta, vec.add(L, Ld), take_coat, coating, pdf_coat, first_glass, dim
    if flags & SMOOTH and not take_coat:
        w, Ld = visible_point_here(tables, at, m, beta, (coating[1], coating[3]), numbers, params, dim)
        if has(mats, ROUGHPLASTIC) and params[5] and mats.kind[m] == ROUGHPLASTIC and coating[1] >= 0.0:
            # the caustic photons claim the glossy lobe's share of the caustic here (visible_point's ``claim``):
            # weight β / (1 - P), the gather weighs by A (and the caustic records by A + f_glossy / B)
            split_visible_point(at, m, d, pixel)
            w = vec.mul(beta, 1.0 / (1.0 - coating[1]))
        return True, at.ns, w, vec.add(L, Ld), take_coat, coating, pdf_coat, first_glass, dim
    return False, zero, zero, L, take_coat, coating, pdf_coat, first_glass, dim


@kernel(inline=True)
def null_thin_vertex(mats, at, m, d, beta, branch):
    """volpath's thin dielectric (null_thin_dielectric): crossed straight on as a null boundary, or reflected, by the
    branch number (:func:`branch_number`; ``branch`` as it takes it).  Returns (straight on, the direction, β for it,
    first_glass, dim)."""
    u, first_glass, dim = branch_number(branch[0], branch[1], branch[2])
    wr, _, F, _, tints = delta_branches(mats, m, d, at.ng, at.ns, at.uv)
    if u >= F:
        return True, d, vec.hadamard(beta, tints[1]), first_glass, dim
    return False, wr, vec.hadamard(beta, tints[0]), first_glass, dim


#: What the camera path does at a surface (:func:`camera_vertex`): it ends, it makes its visible point, it goes on.
ENDED, VISIBLE, ONWARD = 0, 1, 2


@kernel(inline=True)
def camera_vertex(tables, at, m, d, path, counters, branch, rules):
    """The camera path at a surface it scatters at (``at``, material m, arriving along d): on by a glossy step
    (:func:`glossy_step`), its visible point on a diffuse lobe (:func:`diffuse_vertex`), else on by a coating's
    lobe, volpath's thin dielectric (:func:`null_thin_vertex`) or a mirror or glass (:func:`delta_vertex`).
    ``path`` = (L, β, whether this hit's emission was already added, the MIS state (specular, pdf_last, p_last));
    ``counters`` = (null crossings before this surface, the segments k from the camera, the specular depth);
    ``branch`` = (first_glass, numbers, dim); ``rules`` = (params as :func:`visible_point` takes them, the pixel's
    BSDF row).  Returns (ENDED, VISIBLE or ONWARD, the visible point's normal and weight, the path after it, the new
    direction, the counters after it, first_glass, dim)."""
    mats = tables[1]
    L, beta, arrived_counted, mis = path
    crossed, k, depth = counters
    first_glass, numbers, dim = branch
    params, pixel = rules
    max_specular, max_depth = params[2], params[3]
    zero = (0.0, 0.0, 0.0)
    flags = mats.flags[m]
    if (has(mats, GLOSSY_LOBES) and flags & SMOOTH or wrapped(mats, m)) and not flags & DIFFUSE_REFLECTION:
        # a glossy surface, or a mirror or glass under a map (sampled with the terminator's shadowing)
        if depth >= max_specular:
            return ENDED, zero, zero, (L, beta, False, mis), d, (0, k, depth), first_glass, dim
        L, alive, wi, beta, lobe, pdf, dim = glossy_step(tables, at, m, d, (L, beta), numbers[0], dim)
        return (ONWARD if alive else ENDED), zero, zero, (L, beta, False, (lobe & DELTA != 0, pdf, at.p)), wi, \
            (0, k, depth + 1), first_glass, dim
    found, n, w, L, take_coat, (wc, _, w_coat, _), pdf_coat, first_glass, dim = diffuse_vertex(
        tables, at, m, d, (L, beta), (first_glass, numbers, dim), (params, depth >= max_specular, pixel))
    if found or depth >= max_specular:
        return VISIBLE if found else ENDED, n, w, (L, beta, False, mis), d, (0, k, depth), first_glass, dim
    after_delta = (True, mis[1], mis[2])   # emitters the path meets next count in full
    if take_coat:
        # plastic's delta coating added its first hit's emission above; a glossy one (or lobe) did not
        counted, beta = flags & DELTA != 0, vec.hadamard(beta, w_coat)
        if has(mats, GLOSSY_LOBES) and not counted:   # a glossy coating or lobe: its light sample was MIS-weighted
            if w_coat[0] == 0.0 and w_coat[1] == 0.0 and w_coat[2] == 0.0:   # its sample fell below the surface
                return ENDED, zero, zero, (L, beta, False, mis), d, (0, k, depth), first_glass, dim
            after_delta = (False, pdf_coat, at.p)
        return ONWARD, zero, zero, (L, beta, counted, after_delta), wc, (0, k, depth + 1), first_glass, dim
    if has_null_lobe(mats, m):
        # Crossed straight on (no vertex) or reflected (at the last depth that ends the path, as volpath samples the
        # surface there too).  No emission in expectation here: what lies beyond was already counted by a glass
        # before if the path came with it counted (emitted_along passes such a surface), else the path meets it.
        straight, wi, beta, first_glass, dim = null_thin_vertex(mats, at, m, d, beta, (first_glass, numbers, dim))
        if straight:   # no vertex: an emitter met next is weighed from the vertex before (its MIS distance)
            return ONWARD, zero, zero, (L, beta, arrived_counted, mis), wi, (crossed + 1, k - 1, depth + 1), \
                first_glass, dim
        if k >= max_depth:
            return ENDED, zero, zero, (L, beta, False, mis), d, (0, k, depth), first_glass, dim
        return ONWARD, zero, zero, (L, beta, False, after_delta), wi, (0, k, depth + 1), first_glass, dim
    L, wi, beta, counted, first_glass, dim = delta_vertex(tables, at, m, d, (L, beta), (first_glass, numbers, dim))
    return ONWARD, zero, zero, (L, beta, counted, after_delta), wi, (0, k, depth + 1), first_glass, dim


@kernel(inline=True)
def camera_flight(tables, flight, medium, path, n_seg, numbers, out):
    """The camera path's flight ``flight`` = (o, d, the distance to the surface hit or inf, k, max_depth, the wall
    it starts at) through ``medium`` (none: nothing to do): one medium segment (:func:`medium_segment`), its
    in-scattered light added to ``path`` = (L, β) and β attenuated.  Returns (a slot was free: fewer than
    MEDIUM_SEGMENTS segments so far, L, β, n_seg)."""
    L, beta = path
    if in_a_medium(tables[3], medium):   # (never in a scene without media: not compiled there)
        if n_seg >= MEDIUM_SEGMENTS:
            return False, L, beta, n_seg
        Ls, beta = medium_segment(tables, flight, medium, beta, n_seg, numbers, out)
        return True, vec.add(L, Ls), beta, n_seg + 1
    return True, L, beta, n_seg


@kernel(inline=True)
def claimed(mats, L, claim):
    """L as the camera path keeps it (:func:`visible_point`'s ``claim`` = (took a roughplastic's coating last, casters
    only since, L before them)): what it gathered through caustic casters alone after a coating it took is the caustic
    photons' (light -> casters -> the coating, gathered at the coating's split points), so left out."""
    if has(mats, ROUGHPLASTIC) and claim[1]:
        return claim[2]
    return L


@kernel(inline=True)
def claim_at(tables, hit, L, claim):
    """The camera path's ``claim`` state (:func:`claimed`) at a surface ``hit`` = (prim, its material there) before it
    scatters there: a caustic caster (a primitive whose material has no diffuse lobe: the photons' rule,
    :func:`~caustica.photons.trace.beside_diffuse`) right after a coating starts leaving out what follows, L kept; any
    other surface ends it, L back to what was kept (its emission seen through the casters was the photons' too).  A
    surface with a null lobe (volpath's thin dielectric) changes nothing here: crossed straight on it is no event,
    and a reflection off it right after a coating starts the leaving-out once the path has taken it
    (:func:`claim_onward`).  Returns (L, claim)."""
    geom, mats = tables[0], tables[1]
    prim, m = hit
    after_coat, dropping, kept = claim
    if has_null_lobe(mats, m):
        return L, claim
    if not beside_diffuse(geom, mats, prim):   # a caustic caster
        if after_coat:
            return L, (False, True, L)
        return L, claim
    if dropping:
        return kept, (False, False, kept)
    return L, (False, False, kept)


@kernel(inline=True)
def claim_onward(mats, m, turn, L, claim):
    """The ``claim`` state (:func:`claimed`) once the camera path goes on from material m, ``turn`` = (arriving,
    leaving direction): it took a roughplastic's coating, or, right after one, reflected off volpath's thin
    dielectric (a caster's event to the photons, where crossing it straight on is none: :func:`claim_at`)."""
    d, wi = turn
    if mats.kind[m] == ROUGHPLASTIC and not wrapped(mats, m):
        return (True, False, (0.0, 0.0, 0.0))
    if claim[0] and has_null_lobe(mats, m) and (wi[0] != d[0] or wi[1] != d[1] or wi[2] != d[2]):
        return (False, True, L)
    return claim


@kernel
def visible_point(tables, o, d, numbers, params, out):
    """Follow a camera ray to its visible point: (found, position, normal, weight W, radiance L_direct, the medium
    segments written, k).

    ``numbers`` = (key, qkey, vkey, pass_index): the path's own key, the key that scrambles the pass-indexed
    sequences, the medium segments' key, and the pass.  ``params`` = (n_strata, fixed_grid, max_specular,
    max_depth, hide_emitters, claim): Mitsuba's max_depth (segments of a whole path; :data:`UNLIMITED_DEPTH` for
    none) ends the path at a surface reached in max_depth segments once its emission is added, as Mitsuba's path
    integrator does, and hide_emitters leaves out the emitters the camera sees first.  With ``claim`` (the caustic
    photons have statistics of their own) a roughplastic's split point gathers the caustic through both lobes
    (:func:`split_visible_point`), so a path that took the coating leaves out what it gathers through caustic
    casters alone after it (light -> casters -> the coating: :func:`claimed`).
    The path's medium segments are written to ``out`` = (slot0, segments, pixel): slots slot0, slot0 + 1, ...;
    a visible point that evaluates its BSDF writes it to ``pixel`` (:func:`bsdf_visible_point`).
    k, the last of what it returns, is the path's segments from the camera to the visible point (the photons
    gathered there may take max_depth - k more).  At each surface: :func:`camera_vertex`.
    """
    geom, mats, lights, media = tables
    key = numbers[0]
    max_depth, hide_emitters = params[3], params[4]
    L = zero = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    dim = 2
    depth = n_seg = crossings = 0
    k = 0   # segments from the camera to the current surface (null crossings are not vertices)
    first_glass = True
    counted = False   # the next surface's emission was already added, in expectation, at the glass before it
    mis = (True, 0.0, o)   # (no glossy scattering yet, or a delta one since; after one, its sample's density, where)
    medium = media.camera[0]
    wall = zero   # the wall the path leaves (none at the camera), where a medium segment starting here starts
    claim = (False, False, zero)   # (took a roughplastic's coating last, casters only since, L before them)
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        in_segment = medium >= 0
        free, L_flight, beta, n_seg = camera_flight(tables, (o, d, t if prim >= 0 else np.inf, k, max_depth, wall),
                                                    medium, (L, beta), n_seg, numbers, (out[0], out[1]))
        if has(mats, ROUGHPLASTIC) and claim[1]:   # a medium's light is no caustic photon's: kept
            claim = (claim[0], True, vec.add(claim[2], vec.sub(L_flight, L)))
        L = L_flight
        if not free:
            return False, zero, zero, zero, claimed(mats, L, claim), n_seg, k
        if prim < 0:
            if has(lights, ENV) and lights.env[0] >= 0 and not counted and (k > 0 or not hide_emitters):
                L = vec.madd(L, vec.hadamard(beta, escaped_radiance(lights, media, (o, d), medium)),
                             escape_weight(lights, d, mis))
            return False, zero, zero, zero, claimed(mats, L, claim), n_seg, k
        crossed = crossings
        ray = (o, d, t, b1, b2)
        before = medium
        p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, nxt, dim = surface_interaction(
            tables, (prim, t, b1, b2), o, d, medium, crossings, key, dim)
        wall = wall_normal(ng, nxt == CROSSED, before, medium)
        if in_segment:
            end_segment_at_wall(out[0] + n_seg - 1, wall, out[1])
        e = geom.prim_emitter[prim]
        if nxt != CROSSED:
            k += 1
        if e >= 0 and front and not counted and (k > (0 if nxt == CROSSED else 1) or not hide_emitters):
            L = vec.madd(L, vec.hadamard(beta, radiance_at_hit(geom, lights, e, prim, ray)),
                         seen_weight(lights, e, mis, (-vec.dot(d, ng), t, crossed, p)))
        if nxt == CROSSED:
            continue
        # at max_depth no light scattered here can count (volpath's thin dielectric may still be crossed)
        if nxt == TRAPPED or k >= max_depth and not has_null_lobe(mats, m):
            return False, zero, zero, zero, claimed(mats, L, claim), n_seg, k
        scatters, ng_seen, ns_seen = oriented(mats, m, front, ng, ns)
        if not scatters:
            return False, zero, zero, zero, claimed(mats, L, claim), n_seg, k
        if has(mats, ROUGHPLASTIC) and params[5]:
            L, claim = claim_at(tables, (prim, m), L, claim)
        at = ShadingPoint(p, ng_seen, ns_seen, ng, shape, medium, uv)
        status, n, w, (L, beta, counted, mis), wi, (crossings, k, depth), first_glass, dim = camera_vertex(
            tables, at, m, d, (L, beta, counted, mis), (crossed, k, depth), (first_glass, numbers, dim),
            (params, out[2]))
        if status != ONWARD:
            return status == VISIBLE, p if status == VISIBLE else zero, n, w, claimed(mats, L, claim), n_seg, k
        if has(mats, ROUGHPLASTIC) and params[5]:
            claim = claim_onward(mats, m, (d, wi), L, claim)
        o, d, medium = vec.offset_origin(p, ng_seen, wi), wi, medium_after(media, shape, ng, wi, medium)


@kernel
def visible_points(tables, cam, keys, params, out, i0, i1):
    """The visible points of pixels [i0, i1) (row-major) into ``out`` = (points: :class:`VisiblePoints`, segments):
    the radiance each pixel saw directly, and each pixel's medium segments.  ``keys`` = (seed, camera
    stream, media stream, pass index); ``params`` as :func:`visible_point` takes them."""
    tables, cam = borrowed(tables), borrowed(cam)
    seed, stream, vstream, pass_index = keys
    points, segments = out
    points, segments = borrowed(points), borrowed(segments)   # no reference counts where the path passes them
    for i in range(i0, i1):
        x, y = pixel_of(cam, i)
        key = path_key(seed, stream, i)
        qkey = path_key(seed, STREAM_CAMERA_SCRAMBLE, i)
        vkey = path_key(seed, vstream, i)
        u1, u2 = sobol02(pass_index, qkey)
        o, d = generate_ray(cam, x, y, u1, u2, key)
        points.bsdf[i, BSDF_MATERIAL] = -1.0
        found, p, n, w, L, n_seg, k = visible_point(tables, o, d, (key, qkey, vkey, pass_index), params,
                                                    (i * MEDIUM_SEGMENTS, segments, (i, points.bsdf)))
        if not math.isfinite(L[0] + L[1] + L[2]):
            L = (0.0, 0.0, 0.0)
        vec.set_row(points.position, i, p)
        vec.set_row(points.normal, i, n)
        vec.set_row(points.weight, i, w)
        vec.set_row(points.direct, i, L)
        points.found[i] = found
        points.segments[i] = k
        segments.count[i] = n_seg


class VisiblePoints(NamedTuple):
    """One pass's visible point of each pixel (every entry written by the camera pass)."""
    position: np.ndarray   # float64[n, 3]
    normal: np.ndarray     # float64[n, 3]: shading normal on the viewed side (ng under a normal or bump map)
    weight: np.ndarray     # float64[n, 3]: W = β ρ / π (β where material >= 0, β / (1 - P) beside glossy lobes and
    #                        at a split point)
    found: np.ndarray      # bool[n]
    direct: np.ndarray     # float64[n, 3]: the radiance the path saw directly (emitters, direct light)
    bsdf: np.ndarray       # float64[n, BSDF_COLUMNS] (or [n, 1] in a scene without such a BSDF: its first column
    #                        only, -1 everywhere): a visible point whose BSDF the gather evaluates
    #                        (:func:`bsdf_visible_point`): its material (-1: none; SPLIT_ROW - m at a roughplastic's
    #                        split point, :func:`split_visible_point`; m >= 0 the others), the camera path's
    #                        direction arriving there, the geometric normal on the viewed side, the surface coordinates,
    #                        the shading normal
    segments: np.ndarray   # int32[n]: the camera path's segments to the visible point (Mitsuba's depth there)


#: Bytes a pixel's :class:`VisiblePoints` take with a one-column ``bsdf``: position, normal, weight and direct
#: (float64[3] each), found, the first BSDF column, segments.
VISIBLE_POINT_BYTES = 4 * 24 + 1 + 8 + 4


def evaluates_bsdf(materials, claim: bool) -> bool:
    """Whether the camera pass keeps a whole BSDF row per visible point (:data:`BSDF_COLUMNS`, not one): the scene
    has a material the gather evaluates, a glossy one with a diffuse lobe (roughplastic only under ``claim``, as its
    split point) or a wrapped one."""
    flags, kinds = materials.flags, materials.kind
    return bool(np.any((flags & DIFFUSE_REFLECTION != 0) & ((flags & GLOSSY != 0) & ((kinds != ROUGHPLASTIC) | claim)
                                                            | (materials.wrapped != 0))))


def camera_pass_bytes(scene, claim: bool) -> int:
    """Bytes a pixel of :func:`camera_pass` holds: its visible point, the rest of its BSDF row where the gather
    evaluates BSDFs (:func:`evaluates_bsdf`), and its medium segments in a scene with media.  Checked against the
    measured peak by ``benchmarks/pixel_memory.py``."""
    rows = (BSDF_COLUMNS - 1) * 8 if evaluates_bsdf(scene.materials, claim) else 0
    return VISIBLE_POINT_BYTES + rows + (SEGMENT_BYTES if scene.has_media else 0)


def camera_pass(scene, settings, pass_index, bar=None, claim=False):
    """Run :func:`visible_points` over every pixel for pass (or sample) ``pass_index``; ``claim``: the caustic
    photons have statistics of their own, gathered at roughplastic's split points through both lobes
    (:func:`visible_point`).

    Returns (:class:`VisiblePoints`, :class:`~caustica.photons.segments.CameraSegments` or None without media,
    compile seconds).  The camera keys are ``pass_stream(STREAM_CAMERA, pass_index)`` and its media's own.
    """
    n = settings.width * settings.height
    segments_note = f" and {MEDIUM_SEGMENTS} medium segments" if scene.has_media else ""
    check_budget(n * camera_pass_bytes(scene, claim), f"a camera pass of {n:,} pixels (visible points{segments_note} "
                 f"each)", "lower the resolution")
    columns = BSDF_COLUMNS if evaluates_bsdf(scene.materials, claim) else 1
    points = VisiblePoints(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.bool_),
                           np.empty((n, 3)), np.empty((n, columns)), np.empty(n, np.int32))   # camera_pass_bytes
    segments = allocate_segments(n, scene.has_media)
    cam = scene.camera(settings.width, settings.height)
    keys = (settings.seed, pass_stream(STREAM_CAMERA, pass_index), pass_stream(STREAM_CAMERA_MEDIA, pass_index),
            pass_index)
    params = (settings.light_samples, settings.fixed_light_grid, settings.max_specular_depth,
              depth_limit(settings), settings.hide_emitters, bool(claim))
    compile_s = parallel_for(visible_points, n, (scene.tables, cam, keys, params, (points, segments)),
                             threads=settings.threads, progress=bar)
    return points, (segments if scene.has_media else None), compile_s
