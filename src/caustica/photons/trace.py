"""Tracing photons through the scene: PM's global and caustic maps, SPPM's photons, split stream photons.

One path loop, :func:`trace_one`, for every scene: with media or without (vacuum is the case of
no medium, ``medium`` = -1, with the same arithmetic; a scene without media has a trivial medium
table).  Each photon i is a pure function of (seed, pass, i): parallel tracing writes its first records
into fixed slots of its own and traces a longer path again for the rest (:func:`trace_photon_pass`), so the
records come in photon order and the maps are identical for any thread count.

* A photon starts in the medium of its light (:func:`caustica.media.light_media`), or of the point it leaves
  from when the light spans media (:func:`caustica.media.photon_medium`), and keeps
  track of the medium it is in across every surface it leaves (``medium_after``); null
  boundaries are crossed without scattering.
* In a medium it samples a free flight (:func:`caustica.media.free_flight`); the flight ends in
  a **medium scattering event** or at the next surface, and its power is multiplied by the
  flight's weight (T / P at a surface, T σs / p at a scattering event).  At a scattering event
  it is stored as a **volume photon** (no normal), then continues in a direction sampled from
  the phase function; the event counts as a bounce towards ``max_bounces``, as a diffuse one
  does.
* At every diffuse hit a surface record is stored; mirrors and glass reflect or refract, up to
  their own cap (:data:`SPECULAR_CAP`).  A glossy surface (rough metal or glass, no diffuse lobe) is passed as
  a mirror is: nothing is stored there, as no visible point or gather is made there
  (:mod:`caustica.photons.visible_points`), the photon goes on by its BSDF's sample, and the bounce counts
  towards the same cap.  ``max_bounces`` (mr) counts diffuse and medium bounces.
  At a BSDF with a delta coating over a diffuse lobe (plastic) the photon is stored with its power times
  the lobe's factor B on the light's side (:func:`caustica.bsdfs.coat`), then continues by sampling a lobe:
  the coating's reflection is a specular event, but the records after it are INDIRECT.
* Under a normal or bump map (:mod:`caustica.bsdfs.perturb`) the photon scatters with the adjoint of Mitsuba's BSDF
  (:func:`wrapped_bounce`: the perturbed normal Mitsuba's flip picks by the side it leaves to, the terminator's
  shadowing on its arriving side, the shading and geometric cosines exchanged);
  its records there carry the geometric normal, for the same-side test, and no coating's factor: the visible
  points there weight each photon by the BSDF (its diffuse lobes, beside glossy ones) in their own perturbed frame.

What is stored obeys SPEC §2 (surfaces and volume alike): an event only after the photon has
scattered at least once, so no direct light.  Kinds: CAUSTIC / VOLUME_CAUSTIC when every earlier
event was a mirror, glass or glossy surface (light -> (S|G)+ -> event: what aimed caustic photons carry),
INDIRECT / VOLUME_INDIRECT otherwise.  Every record keeps its depth, the segments of the photon's path from its
light (Mitsuba's count: every scattering event, null crossings not), which every photon method's gather holds
against a finite max_depth.
"""
from __future__ import annotations

import numpy as np

from ..features import guarded_by, has
from ..bsdfs import DELTA, DIFFUSE_REFLECTION, entry, eval_pdf, has_null_lobe, oriented, photon_shading, sample, \
    sample_kind, wrapped
from ..bsdfs.perturb import flip_side
from ..bsdfs.mixtures import weight
from ..geometry import vec
from ..geometry.primitives import borrow
from ..jit import borrowed, kernel, parallel_for
from ..memory import check_budget
from ..media import free_flight, in_a_medium, medium_after, photon_scatter
from ..sampling.rng import path_key, uniform
from ..scene.description import BLEND, MASK, PLASTIC, ROUGHPLASTIC
from ..transport import CROSSED, TRAPPED, map_frames, surface_interaction
from .emission import emit_caustic_photon, emit_photon, start_medium
from .records import CAUSTIC, INDIRECT, MAX_RECORD_DEPTH, SLOT_BYTES, VOLUME_CAUSTIC, VOLUME_INDIRECT, TraceBuffers, \
    allocate_buffers

SPECULAR_CAP = 64
#: A photon's first records go to slots of its own, so parallel tracing needs no atomics and the records
#: come in photon order for any thread count; a path with more is traced again for the rest
#: (:func:`trace_photon_pass`).
FIXED_SLOTS = 8
TERMINATION_CAP = 0       # scale power by the albedo, stop after mr diffuse bounces (the paper)
TERMINATION_ROULETTE = 1  # survive with p = the BSDF sample's largest weight (a diffuse albedo), power scaled by 1 / p
TERMINATION_DECAY = 2     # survive with p = its mean weight: the decay of a stream's associated photons under the cap
#                           (SPEC), which its split photons keep (streams.split_off); in a medium roulette as above


@kernel(inline=True)
def store_record(s, p, d, power, n, tag, buf):
    """Write one photon record (position, direction of travel, power, normal, ``tag`` = (kind, the photon's events
    before it)) into slot s of ``buf``; its depth is the segments from the light, events + 1 (Mitsuba's count)."""
    kind, events = tag
    vec.set_row(buf.position, s, p)
    vec.set_row(buf.direction, s, d)
    vec.set_row(buf.power, s, power)
    vec.set_row(buf.normal, s, n)
    buf.kind[s] = kind
    buf.depth[s] = min(events + 1, MAX_RECORD_DEPTH)


@kernel(inline=True)
def bounce(mats, m, d, at, key, dim, termination):
    """Continue a photon from material m at ``at`` = (ng, ns, uv) (normals from :func:`caustica.bsdfs.oriented`,
    surface coordinates): its BSDF sampled, then, after a non-delta lobe, Russian roulette (:func:`survive`).

    Returns (alive, new direction, the BSDF's weight, the roulette's 1 / p (1 without one), delta: the lobe
    was a mirror's or glass's, dim); the power becomes power · weight · (1 / p), in that order.
    """
    ng, ns, uv = at
    ok, wi, weight, _, lobe, _, dim = sample(mats, m, d, ng, ns, uv, key, dim)
    return survive(ok, wi, weight, lobe & DELTA != 0, (key, dim, termination))


@kernel(inline=True)
def survive(ok, wi, weight, delta, numbers):
    """:func:`bounce`'s end, after a sample (ok, wi, weight, delta lobe): after a non-delta lobe Russian roulette on
    the number ``numbers`` = (key, dim, termination) give (``TERMINATION_ROULETTE``: survive with probability p,
    power scaled by 1 / p).  p is the largest channel of the sample's weight f cos / pdf, capped at 1: a diffuse
    surface's albedo, and for a lobe whose weight is not the material's colour (a rough coating over a black base, a
    metal) what that lobe keeps, so no channel of a photon's power grows and no lobe that reflects light loses all
    its photons.  The largest, not the mean: with the mean, a channel above it gained weight / mean a bounce, and
    its second moment weight² / mean grew without bound in a coloured closed room (docs/results.md).
    ``TERMINATION_DECAY`` takes the mean: the paper's decay of a stream's associated photons under the cap (SPEC),
    whose paths that cap bounds."""
    key, dim, termination = numbers
    if delta:
        return ok, wi, weight, 1.0, True, dim
    u = uniform(key, dim)
    dim += 1
    if termination != TERMINATION_CAP:
        if termination == TERMINATION_ROULETTE:
            q = max(weight[0], max(weight[1], weight[2]))
        else:
            q = (weight[0] + weight[1] + weight[2]) / 3.0
        q = min(q, 1.0)   # a probability, for a weight above 1 too
        if not q > 0.0:
            return False, wi, weight, 0.0, False, dim
        return ok and u < q, wi, weight, 1.0 / q, False, dim
    return ok, wi, weight, 1.0, False, dim


@kernel(inline=True)
def wrapped_bounce(mats, m, d, at, frames, numbers):
    """:func:`bounce` on a normal or bump map's nested row m: the adjoint of Mitsuba's wrapped BSDF.

    Mitsuba's f_M(c, l) = f cos(n_c, l) G(l) takes the perturbed normal n_c flipped by the camera's side c
    (:func:`caustica.bsdfs.perturb.flip_side`), which the photon, arriving from l, only knows once it has chosen c.
    ``frames`` = (the map's normal, its mirror, the unperturbed normal) (:func:`caustica.transport.map_frames`).

    * Smooth lobes: the photon samples its BSDF about one of the two normals, picked with probability 1/2 (one
      frame where they coincide), and weights c by f_M(c, l) |cos_g c| / (|cos_g l| pdf(c)) (Veach 1997, §5.3),
      pdf the two frames' mean density and n_c Mitsuba's flip by c.
    * Delta lobes: the BSDF sampled about both normals with the same numbers; a direction counts where its frame is
      the one Mitsuba's flip gives it, with :func:`caustica.bsdfs.photon_shading`'s weight (one of two such picked
      with probability 1/2, weighted twice; none: the photon ends).

    ``numbers`` = (key, dim, termination)."""
    key, dim, termination = numbers
    ng, _, uv = at
    n_map, n_mirror, ns0 = frames
    light = vec.neg(d)
    zero = (0.0, 0.0, 0.0)
    single = vec.dot(n_map, n_mirror) >= 1.0 - 1e-12   # no tangential part: the flip changes nothing
    weight = zero
    if mats.flags[m] & DELTA:
        ok, c, w, _, _, _, dim2 = sample_kind(mats, m, d, ng, n_map, uv, key, dim)
        good = ok and (single or flip_side(n_map, ns0, c) == 0)
        if not single:
            ok_b, c_b, w_b, _, _, _, _ = sample_kind(mats, m, d, ng, n_mirror, uv, key, dim)
            good_b = ok_b and flip_side(n_map, ns0, c_b) == 1
            scale = 1.0
            if good and good_b:
                scale = 2.0
                if uniform(key, dim2) >= 0.5:
                    good = False
            if good_b and not good:
                c, w = c_b, w_b
            good = good or good_b
            w = vec.mul(w, scale)
        dim = dim2 + 1
        nk = n_map if flip_side(n_map, ns0, c) == 0 else n_mirror
        if good and vec.dot(nk, light) * vec.dot(ns0, light) > 0.0:
            weight = vec.mul(w, photon_shading(mats, m, ng, nk, light, c))
        alive = weight[0] > 0.0 or weight[1] > 0.0 or weight[2] > 0.0   # (a photon of no power stores nothing)
        return survive(alive, c, weight, True, (key, dim, termination))
    k = 0
    if not single:
        k = 0 if uniform(key, dim) < 0.5 else 1
        dim += 1
    ok, c, _, _, _, _, dim = sample_kind(mats, m, d, ng, n_map if k == 0 else n_mirror, uv, key, dim)
    nc = n_map if flip_side(n_map, ns0, c) == 0 else n_mirror   # Mitsuba's frame for a camera arriving from c
    if ok and vec.dot(nc, light) * vec.dot(ns0, light) > 0.0 and vec.dot(nc, c) * vec.dot(ns0, c) > 0.0:
        col, scale, _ = eval_pdf(mats, m, vec.neg(c), ng, nc, uv, light)
        pdf = eval_pdf(mats, m, d, ng, n_map, uv, c)[2]
        if not single:
            pdf = 0.5 * (pdf + eval_pdf(mats, m, d, ng, n_mirror, uv, c)[2])
        cg = abs(vec.dot(ng, light))
        if pdf > 0.0 and cg > 0.0:
            weight = vec.mul(col, scale * abs(vec.dot(nc, light)) * abs(vec.dot(ng, c)) / (cg * pdf))
    alive = ok and (weight[0] > 0.0 or weight[1] > 0.0 or weight[2] > 0.0)
    return survive(alive, c, weight, False, (key, dim, termination))


@kernel(inline=True)
def storing_probability(mats, own, uv, side):
    """The probability that a photon meeting mixture ``own`` at ``side`` = (front, ng, ns) (the hit's front normals)
    resolves to a part that stores a record there: a part with a diffuse lobe that scatters on that side.

    The records are the incident flux a visible point there reads whichever part the photon took; a photon stores
    one only where it took such a part, so its record is divided by this probability (unbiased for a visible point
    of any storing part, as the parts' records carry the same factor: api.check_bsdfs refuses a blend of a coated
    diffuse lobe with another diffuse lobe in the photon methods)."""
    front, ng, ns = side
    w = weight(mats, own, uv)
    blend = mats.kind[own] == BLEND
    p = 0.0
    for j in range(2):
        k = mats.nested[own, j]
        if k < 0 or not mats.flags[k] & DIFFUSE_REFLECTION:
            continue
        scatters, _, _ = oriented(mats, k, front, ng, ns)
        if scatters:
            p += w if (j == 1 or not blend) else 1.0 - w   # a mask's part: its opacity; a blend's: 1 - w, w
    return p


@kernel(inline=True)
def scatter_photon(media, medium, ray, key, dim, power, roulette):
    """A photon at a scattering event in ``medium``, ``ray`` = (its point, its direction), samples the phase function
    (Russian roulette if ``roulette``).  Returns (alive, the new direction, its power times the roulette's 1 / p
    and the phase weight, dim)."""
    alive, inv_q, wo, weight, dim = photon_scatter(media, medium, ray[0], ray[1], key, dim, roulette)
    if alive:
        power = vec.mul(vec.mul(power, inv_q), weight)
    return alive, wo, power, dim


@guarded_by(PLASTIC, ROUGHPLASTIC)
@kernel(inline=True)
def coated(mats, m):
    """Whether material m is a coated diffuse lobe (plastic, roughplastic), whose photons carry its factor B
    (:func:`caustica.bsdfs.entry`: what of the light arriving enters the coating) in their records.  Not under a
    normal or bump map: visible points there weight each photon by the BSDF (api.check_bsdfs refuses a delta
    coating there)."""
    if wrapped(mats, m):
        return False
    if has(mats, PLASTIC) and mats.flags[m] & DELTA:
        return True
    return has(mats, ROUGHPLASTIC) and mats.kind[m] == ROUGHPLASTIC


@kernel(inline=True)
def record_factor(geom, mats, hit, d):
    """What of its power a photon arriving along d stores at a diffuse hit, ``hit`` = (prim, m, uv, front, ng, ns) (m
    the material it resolved to, normals turned to the ray): at a coated diffuse lobe its factor B
    (:func:`caustica.bsdfs.coat`); at a mixture's part 1 / the chance of resolving to a part that stores there
    (:func:`storing_probability`); 1 elsewhere.  (A stream's associated photons carry it as a number of their own.)"""
    prim, m, uv, front, ng, ns = hit
    factor = entry(mats, m, -vec.dot(d, ns)) if coated(mats, m) else 1.0
    if has(mats, MASK) or has(mats, BLEND):   # (no code for a mixture in a scene without one)
        own = geom.prim_material[prim]
        if own != m and (mats.kind[own] == MASK or mats.kind[own] == BLEND):   # (not a normal or bump map's row)
            factor /= storing_probability(mats, own, uv, (front, ng, ns))
    return factor


@kernel(inline=True)
def record_power(geom, mats, hit, d, power):
    """The power a photon arriving along d stores at ``hit`` (:func:`record_factor`)."""
    return vec.mul(power, record_factor(geom, mats, hit, d))


@kernel(inline=True)
def keep_record(out, records, p, d, power, n, tag):
    """Record number ``records`` of a photon's path (position, direction of travel, power, normal, ``tag`` = (kind,
    the photon's events before it)): written by :func:`store_record` when ``out`` = (slot0, skip, slots, buf) keeps
    it (numbers skip .. skip + slots - 1 go to slots slot0 ..), only counted otherwise.  Returns the records the
    path has made, this one included."""
    slot0, skip, slots, buf = out
    if skip <= records < skip + slots:
        store_record(slot0 + records - skip, p, d, power, n, tag, buf)
    return records + 1


@kernel(inline=True)
def attenuate_photon(power, medium, w):
    """A photon's power times a free flight's weight w in ``medium`` (none: unchanged).  Returns (alive: some
    power is left, the power)."""
    if medium < 0:
        return True, power
    power = vec.hadamard(power, w)
    return not (power[0] == 0.0 and power[1] == 0.0 and power[2] == 0.0), power


@kernel(inline=True)
def bounce_at(tables, m, prim, ray, at, numbers):
    """A photon's bounce from material m, where ``ray`` = (o, d, t, b1, b2) met primitive prim, at ``at`` = (ng, ns,
    uv) (:func:`bounce`'s): under a normal or bump map :func:`wrapped_bounce`, Mitsuba's flip by the side the photon
    leaves to; elsewhere :func:`bounce`.  ``numbers`` = (key, dim, termination).  Returns :func:`bounce`'s (alive, the
    new direction, the BSDF's weight, the roulette's 1 / p, delta, dim): the photon tracer's bounce
    (:func:`photon_bounce`) and a stream's leading photon's (:func:`caustica.photons.streams.stream_bounce`)."""
    geom, mats, _, _ = tables
    key, dim, termination = numbers
    d, uv = ray[1], at[2]
    if wrapped(mats, m):
        frames = map_frames(geom, mats, prim, ray, uv)
        return wrapped_bounce(mats, m, d, at, frames, numbers)
    return bounce(mats, m, d, at, key, dim, termination)


@kernel(inline=True)
def photon_bounce(tables, m, prim, ray, at, numbers, power):
    """A photon's bounce (:func:`bounce_at`, the same arguments), its power carried on: returns (alive, the new
    direction, the power times the BSDF's weight and the roulette's 1 / p, in that order, delta, dim)."""
    alive, d_new, weight, inv_q, delta, dim = bounce_at(tables, m, prim, ray, at, numbers)
    return alive, d_new, vec.mul(vec.hadamard(power, weight), inv_q), delta, dim


@kernel(inline=True)
def beside_diffuse(geom, mats, prim):
    """Whether the material of primitive prim itself (not the lobe or part a path took there) has a diffuse lobe.
    A mirror, glass or glossy bounce there (a plastic's coating's reflection, or a blend's delta or glossy part
    beside a diffuse one) is no caustic caster (tables.py): the records after it are INDIRECT, though it is no
    diffuse bounce."""
    return mats.flags[geom.prim_material[prim]] & DIFFUSE_REFLECTION != 0


@kernel(inline=True)
def classify_bounce(tables, prim, m, turn, delta):
    """What a photon's bounce from material m on primitive prim was, ``turn`` = (d, the new direction, ng) and
    ``delta`` :func:`bounce`'s: (a null crossing, a specular event, indirect: the records after it are INDIRECT).

    * volpath's thindielectric (null_thin_dielectric) straight on is a null crossing, no event, so what the photon
      lights next is direct light if it had not scattered (shadow rays pass the surface too); it counts towards the
      specular cap.
    * A mirror, glass or glossy bounce is a specular event: the photon is still on a caustic path, light -> (S|G)+,
      unless it was :func:`beside_diffuse`.
    * Any other is a diffuse bounce."""
    geom, mats, _, _ = tables
    d, d_new, ng = turn
    if has_null_lobe(mats, m) and vec.dot(d_new, ng) * vec.dot(d, ng) > 0.0:
        return True, True, False
    if delta or not mats.flags[m] & DIFFUSE_REFLECTION:
        return False, True, beside_diffuse(geom, mats, prim)
    return False, False, True


@kernel(inline=True)
def count_bounce(specular, counts):
    """``counts`` = (specular events, diffuse bounces) after a bounce: a specular one (a mirror, glass or glossy
    bounce, or a null crossing) counts towards :data:`SPECULAR_CAP`, past which the path ends, any other towards
    max_bounces.  Returns the two."""
    specular_events, bounces = counts
    if specular:
        specular_events += 1
    else:
        bounces += 1
    return specular_events, bounces


@kernel
def trace_one(tables, key, photon, rules, out):
    """Follow one photon, ``photon`` = (o, d, power, medium, diffuse_bounces, scattered): from o along d in
    ``medium``.  ``out`` = (slot0, skip, slots, buf): its records number skip .. skip + slots - 1 (counted
    from 0 along its path) go to slots slot0 .. slot0 + slots - 1 of ``buf`` (a
    :class:`~caustica.photons.records.TraceBuffers`), the others nowhere.  Returns how many records the
    path made, kept or not.

    A photon from a light starts with no bounce and not ``scattered``; a split photon of a stream
    (:mod:`caustica.photons.streams`) starts with its stream's.  ``rules`` = (max_bounces, termination,
    caustic_only); ``caustic_only``: stop at the first diffuse or medium event (the aimed caustic
    photons).  Random numbers from 8 on.
    """
    geom, mats, _, media = tables
    o, d, power, medium, diffuse_bounces, scattered = photon
    max_bounces, termination, caustic_only = rules
    dim = 8
    specular_events = 0
    events = 0   # scattering events of this photon's own path (every kind): its records' depth is events + 1
    diffuse_like = diffuse_bounces > 0   # a diffuse or medium event so far: records are INDIRECT
    crossings = records = 0
    while specular_events <= SPECULAR_CAP:
        prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
        if escaped:
            break
        alive, power = attenuate_photon(power, medium, w)
        if not alive:
            break
        if in_a_medium(media, medium) and prim < 0:
            # ---- a scattering event in the medium (none in a scene without media: not compiled there)
            p = vec.madd(o, d, t)
            if scattered:
                records = keep_record(out, records, p, d, power, (0.0, 0.0, 0.0),   # a volume photon: no normal
                                      (VOLUME_INDIRECT if diffuse_like else VOLUME_CAUSTIC, events))
            if caustic_only or diffuse_bounces >= max_bounces:
                break
            alive, wo, power, dim = scatter_photon(media, medium, (p, d), key, dim, power,
                                                   termination != TERMINATION_CAP)
            if not alive:
                break
            o, d, crossings = p, wo, 0
            diffuse_bounces += 1
            events += 1
            scattered = diffuse_like = True
            continue
        # ---- a surface
        p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, nxt, dim = surface_interaction(
            tables, (prim, t, b1, b2), o, d, medium, crossings, key, dim)
        if nxt == CROSSED:
            continue
        if nxt == TRAPPED:
            break
        ng_front = ng
        scatters, ng, ns = oriented(mats, m, front, ng, ns)
        if not scatters:
            break  # the black back of a one-sided surface absorbs
        if mats.flags[m] & DIFFUSE_REFLECTION:
            if scattered:
                stored_power = record_power(geom, mats, (prim, m, uv, front, ng, ns), d, power)
                records = keep_record(out, records, p, d, stored_power, ng if wrapped(mats, m) else ns,
                                      (INDIRECT if diffuse_like else CAUSTIC, events))
            if caustic_only or diffuse_bounces >= max_bounces:
                break
        alive, d_new, power, delta, dim = photon_bounce(tables, m, prim, (o, d, t, b1, b2), (ng, ns, uv),
                                                        (key, dim, termination), power)
        if not alive:
            break
        null, specular, indirect = classify_bounce(tables, prim, m, (d, d_new, ng), delta)
        specular_events, diffuse_bounces = count_bounce(specular, (specular_events, diffuse_bounces))
        o, medium = vec.offset_origin(p, ng, d_new), medium_after(media, shape, ng_front, d_new, medium)
        if null:   # no event: the photon goes straight on
            continue
        d = d_new
        diffuse_like = diffuse_like or indirect
        events += 1
        scattered = True
    return records


@kernel(inline=True)
def emitted_photon(tables, light_medium, source, i):
    """Photon i of ``source`` = (seed, stream, n_paths) as it leaves its light: (its key, :func:`trace_one`'s
    ``photon``)."""
    geom, _, lights, _ = tables
    seed, stream, n_paths = source
    key = path_key(seed, stream, i)
    o, d, power, _ = emit_photon(geom, lights, key, n_paths)
    return key, (o, d, power, start_medium(tables, light_medium, key, (o, d)), 0, False)


@kernel
def trace_photons(tables, light_medium, source, rules, out, i0, i1):
    """Photons [i0, i1) of ``source`` under ``rules`` = (max_bounces mr, termination), into ``out`` = (buf, slots,
    counts): photon i keeps its first ``slots`` records in slots [i * slots, (i + 1) * slots) of buf, and counts[i]
    = the records its path made."""
    tables, light_medium = borrowed(tables), borrow(light_medium)
    buf, slots, counts = out
    buf = borrowed(buf)   # no reference counts on the records' arrays, wherever trace_one passes them
    for i in range(i0, i1):
        key, photon = emitted_photon(tables, light_medium, source, i)
        counts[i] = trace_one(tables, key, photon, (rules[0], rules[1], False), (i * slots, 0, slots, buf))


@kernel
def trace_photon_tails(tables, light_medium, source, rules, tails, i0, i1):
    """The photons whose paths made more records than their fixed slots, again: ``tails`` = (ids, offsets, skip,
    buf), photon ids[j] for j in [i0, i1), its records from number ``skip`` on into slots [offsets[j],
    offsets[j + 1]) of buf."""
    tables, light_medium = borrowed(tables), borrow(light_medium)
    ids, offsets, skip, buf = tails
    buf = borrowed(buf)
    for j in range(i0, i1):
        key, photon = emitted_photon(tables, light_medium, source, ids[j])
        trace_one(tables, key, photon, (rules[0], rules[1], False),
                  (offsets[j], skip, offsets[j + 1] - offsets[j], buf))


@kernel
def trace_caustic_photons(tables, light_medium, spheres, source, buf, i0, i1):
    """Caustic photons [i0, i1) of ``source`` = (seed, stream, n_paths), aimed at the caustic casters (mirrors,
    glass, glossy objects): the first event after a chain of them only (one slot each).  A photon that scatters in
    a medium or meets a diffuse surface before any of them stores nothing (that light is the other photons' and
    the direct light's)."""
    tables, light_medium, spheres = borrowed(tables), borrow(light_medium), borrow(spheres)
    geom, _, lights, _ = tables
    seed, stream, n_paths = source
    buf = borrowed(buf)
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, ok = emit_caustic_photon(geom, lights, spheres, key, n_paths)
        if ok:
            medium = start_medium(tables, light_medium, key, (o, d))
            trace_one(tables, key, (o, d, power, medium, 0, False), (0, TERMINATION_CAP, True),
                      (i, 0, 1, buf))


def fixed_slots(max_bounces: int) -> int:
    """The records of each photon kept in slots of its own: mr + 1 (every record a capped path makes, unless a
    plastic's coating or a blend's mirror part reflects it without a diffuse bounce), at most :data:`FIXED_SLOTS`."""
    return min(max_bounces + 1, FIXED_SLOTS)


def planned_records(n_paths: int, max_bounces: int, termination: int) -> int:
    """The record slots a pass of ``n_paths`` photons is planned with (its memory check): under the cap every
    photon's mr + 1, which most live out; under roulette the fixed slots only, which a bright closed room's long
    paths exceed (1.5 x in a box of albedo 0.9): :func:`trace_photon_pass` checks their tails when it has counted
    them."""
    if termination == TERMINATION_CAP:
        return n_paths * (max_bounces + 1)
    return n_paths * fixed_slots(max_bounces)


def trace_photon_pass(scene, source, rules, *, reserve=0, threads=None, progress=None):
    """Trace the photons of ``source`` = (seed, stream, n_paths) with ``rules`` = (max_bounces mr, termination):
    returns (buf, records, compile seconds).  ``buf`` (:class:`TraceBuffers`) holds every photon's first
    :func:`fixed_slots` records in slots of its own (EMPTY where it made fewer), then the rest of the records
    of the photons that made more, in photon order (traced a second time, from their own keys: the same
    paths), then ``reserve`` empty slots for the caller (sppm's aimed photons); ``records`` = the slots
    before those.  The same for any thread count, and no slots wasted on paths roulette makes long."""
    n = source[2]
    k = fixed_slots(rules[0])
    buf = allocate_buffers(n * k + reserve, 1)
    counts = np.zeros(n, np.int32)
    common = (scene.tables, scene.light_media(), source, rules)
    compile_s = parallel_for(trace_photons, n, common + ((TraceBuffers(*(a[:n * k] for a in buf)), k, counts),),
                             threads=threads, progress=progress)
    longer = np.flatnonzero(counts > k)
    if longer.size == 0:
        return buf, n * k, compile_s
    offsets = np.empty(longer.size + 1, np.int64)
    offsets[0] = n * k
    np.cumsum(counts[longer] - k, out=offsets[1:])
    offsets[1:] += n * k
    records = int(offsets[-1])
    # the records and a copy of them (the grid's or the kd-tree's), or the first buffer while it is copied
    check_budget(2 * (records + reserve) * SLOT_BYTES,
                 f"{n:,} photons' {records:,} records (the paths past their first {k}) and their copy",
                 "lower --photons or --max-bounces")
    whole = allocate_buffers(records + reserve, 1)
    for a, b in zip(whole, buf):
        a[:n * k] = b[:n * k]
    del buf
    compile_s += parallel_for(trace_photon_tails, longer.size, common + ((longer, offsets, k, whole),),
                              threads=threads)
    return whole, records, compile_s


def trace_caustic_photon_pass(scene, buf, seed, stream, n_paths, *, spheres=None, threads=None,
                              progress=None) -> float:
    """Trace ``n_paths`` photons aimed at the scene's caustic casters (or at ``spheres``, (n, 4) centre and
    radius) into ``buf`` (one slot each); returns the compile seconds."""
    spheres = scene.specular_bounding_spheres() if spheres is None else spheres
    return parallel_for(trace_caustic_photons, n_paths,
                        (scene.tables, scene.light_media(), spheres, (seed, stream, n_paths), buf),
                        threads=threads, progress=progress)
