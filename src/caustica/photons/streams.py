"""Tracing streams for streamed photon mapping (SPEC §4), and the stream map they leave.

A *stream* is a leading photon plus up to n_fa associated photons.

1. Emission: a stream starts at a point on a light with a direction from the
   light's emission; its power is E_s = E_z / n_fs (eq. 1; E_z the light's power,
   chosen in proportion to power), split equally among its n_fa + 1 photons.
2. The leading photon is traced.  At a mirror or glass surface every associated
   photon is *merged* into the leading photon (its power is added; it ceases to
   exist) and the leading photon reflects or refracts (Fresnel).  This is what
   concentrates caustic energy.  A glossy surface without a diffuse lobe (rough metal or
   glass) is met as a mirror is, as the photon tracer meets it (:mod:`caustica.photons.trace`):
   the associated photons merge (or split off), nothing is stored there, and the leading photon
   goes on by its BSDF's sample (Russian roulette after it, as after any non-delta lobe); the
   bounce counts towards the specular cap, not ``max_bounces``, and the records after it stay
   caustic (light -> (S|G)+ -> diffuse).
3. At a diffuse hit x_L reached from origin o:
   - each associated photon gets a point q uniform in the disc of radius r_s about
     x_L perpendicular to the leading direction and is traced from o towards q; it
     lands where that ray first meets a diffuse surface.  One whose ray escapes,
     meets a mirror or glass, or meets the black back of a one-sided surface is
     merged into the leading photon.  A stream is a beam of width r_s that respects
     occlusion.
   - a *stream record* is stored (unless this is direct light): the leading
     position, normal, incoming direction and power, and the associated photons'
     positions, directions and normals with their (common) power.  Its energy E_i
     is the sum of its photons' powers.
   - stream decay: the leading photon's power is scaled by the albedo and it
     bounces in a cosine-distributed direction; each associated photon survives with
     probability p = mean albedo, its power scaled by albedo / p, so streams thin out
     as they travel.  With ``termination=roulette`` the whole stream plays Russian
     roulette once, with the leading photon (survival p = its largest albedo, every power
     scaled by albedo / p), which keeps the expected power right.
   - after mr diffuse bounces the stream ends.
   - under ``null_thin_dielectric`` (volpath's thin dielectric), where the leading photon goes straight on, the
     whole stream crosses with no event, every photon taking its weight (:func:`null_thin_crossing`); where it
     reflects, the associated photons merge, even under ``--specular split``.
   - at a coated diffuse surface (plastic, roughplastic) every photon's record carries the coating's factor B
     at its own direction (as :func:`~caustica.photons.trace.record_power`), and the stream reflects whole by
     the lobe its leading photon samples, its associated photons decaying by that lobe's weight; a coating's
     reflection is no diffuse bounce, but the records after it are not caustic (plastic is no caustic caster).
   - under a normal or bump map the leading photon bounces as the photon tracer's does
     (:func:`~caustica.photons.trace.bounce_at`: Mitsuba's flip by the side it leaves to, the adjoint's weights),
     the stream decaying by that weight; its record, and each associated photon that lands under a map (each
     resolves the surface it meets: :func:`unwrapped`), carry the geometric normal and no coating's factor, as the
     photon tracer's records: the visible points there weight each photon by the BSDF in their own perturbed frame.
4. Only leading photons go into the kd-tree (:class:`StreamMap`); the ``photons``
   view counts every photon at its own position.

All associated photons of a stream share one power value at any moment (they
start equal and decay by the same factor), so the tracer carries a count and a
power rather than one power per photon.  Stream i is a pure function of
(seed, stream tag, i): the map is the same for any thread count.
"""
from __future__ import annotations

import numpy as np

from typing import NamedTuple

from ..bsdfs import DIFFUSE_REFLECTION, TRANSMISSION, has_null_lobe, oriented, wrapped
from ..bsdfs.mixtures import resolve
from ..features import guarded_by, has
from ..geometry import vec
from ..geometry.primitives import borrow
from ..geometry.scene_geometry import NO_UV, intersect, surface_at, surface_uv
from ..jit import borrowed, kernel, parallel_for
from ..media import free_flight, in_a_medium, medium_after, photon_scatter
from ..sampling.rng import path_key, uniform
from ..sampling.warps import square_to_uniform_disk
from ..scene.description import BLEND, BUMPMAP, MASK, NORMALMAP, NULL, PLASTIC, ROUGHPLASTIC
from ..transport import CROSSED, TRAPPED, surface_interaction
from .emission import emit_photon, start_medium
from .records import (CAUSTIC, EMPTY, INDIRECT, MAX_RECORD_DEPTH, SLOT_BYTES, VOLUME_CAUSTIC, VOLUME_INDIRECT,
                      allocate_buffers, build_photon_map, build_photon_map_with_order, no_records)
from .trace import SPECULAR_CAP, TERMINATION_DECAY, TERMINATION_ROULETTE, beside_diffuse, bounce_at, \
    count_bounce, record_factor, record_power, trace_one

#: Sub-streams of a stream's key: its split photons' own paths (one key per split photon), and the disc
#: points its associated photons are aimed through at a specular split.
SPLIT_TAG = 1
SPLIT_DISC_TAG = 2
#: ... and the number with which associated photon j resolves a mixture it meets (its crossing c: dimension c).
ASSOCIATED_PART_TAG = 3
#: Mask surfaces an associated photon may pass through on its way to a surface (more: it merges).
ASSOCIATED_CROSSINGS = 16

#: What a stream does at a scattering event in a medium (``--medium-scattering``).
MEDIUM_SCATTERING = ("merge", "spread")


@guarded_by(INDIRECT, CAUSTIC)
@kernel(inline=True)
def may_split(split_buf):
    """Whether ``split_buf`` can take split photons' records: False, folded before typing, for
    :func:`~caustica.photons.records.no_records` (``--specular merge``), so that a stream pass that cannot split
    never compiles :func:`split_off` and the photon tracer behind it (1-2 s of ``make render``'s cold start)."""
    return has(split_buf, INDIRECT) or has(split_buf, CAUSTIC)


@kernel(inline=True)
def split_off(tables, key, o, d, power, split_path, k, split):
    """An associated photon that leaves its stream at a mirror or glass (``--specular split``): the stream's
    split photon number split_path[1] + k, with ``split_path`` = (the stream's first split path, its split
    photons so far, its medium, diffuse bounces, whether it has scattered, the scattering events of its path up
    to o, that at o included (added to the depths of the split photon's records), the stream's (max_bounces,
    termination)).

    From o along d it is a photon of its own (:func:`caustica.photons.trace.trace_one`) with a key of its
    own: its own specular chain (Fresnel per photon), stored where it lands (unless that is direct light)
    and at every later diffuse hit, in its own mr + 1 slots of ``split``.  It decays as an associated
    photon does — under the cap it survives a diffuse bounce with p = mean albedo, power scaled by albedo / p
    (``TERMINATION_DECAY``), under roulette with the largest albedo, as the stream's roulette does
    (``TERMINATION_ROULETTE``) — and ends after the stream's ``max_bounces`` in all.  What escapes or is
    absorbed on its way is lost, as any photon's power is.
    """
    first_path, before, medium, diffuse_bounces, scattered, events, (max_bounces, termination) = split_path
    index = before + k
    slot0 = (first_path + index) * (max_bounces + 1)
    decay = TERMINATION_ROULETTE if termination == TERMINATION_ROULETTE else TERMINATION_DECAY
    made = trace_one(tables, path_key(key, SPLIT_TAG, index), (o, d, power, medium, diffuse_bounces, scattered),
                     (max_bounces, decay, False), (slot0, 0, max_bounces + 1, split))
    # trace_one counts the depths from o; the stream's events up to o come first.  (Not passed into trace_one:
    # a seventh element of its photon made the aimed caustic photons' kernel 55 % slower, measured.)
    for s in range(slot0, slot0 + min(made, max_bounces + 1)):
        split.depth[s] = min(split.depth[s] + events, MAX_RECORD_DEPTH)


@kernel(inline=True)
def associated_decay(key, dim, n_alive, p_assoc, weight, roulette_inv_q):
    """The associated photons after the leading photon's bounce, whose BSDF weight (f cos / pdf of the lobe it
    sampled) was ``weight``: (how many survive, their power).  The stream moves as one, so they take its lobe.

    Each survives with p = the weight's mean (at a diffuse surface its albedo), its power scaled by weight / p
    (numbers key, dim + j).  With roulette (``roulette_inv_q`` > 0: the 1 / p of the leading photon's game,
    :func:`~caustica.photons.trace.bounce`) the stream lives or dies with the leading photon: a second,
    per-photon roulette would leave the associated photons alive with probability p^2 while compensating only
    1 / p, so they all survive, scaled by weight / p.  p is at most 1: a weight's mean may pass 1 (a plastic's
    coating taken with a probability below its reflectance; under a normal or bump map, the adjoint's ratio of
    shading and geometric cosines, :func:`~caustica.photons.trace.wrapped_bounce`), and p = the mean there would
    lose power (every photon survives, scaled by weight / mean).
    """
    if roulette_inv_q > 0.0:
        return n_alive, vec.mul(vec.hadamard(p_assoc, weight), roulette_inv_q)
    q = min((weight[0] + weight[1] + weight[2]) / 3.0, 1.0)
    survivors = 0
    for j in range(n_alive):
        if uniform(key, dim + j) < q:
            survivors += 1
    if q > 0.0:
        p_assoc = vec.mul(vec.hadamard(p_assoc, weight), 1.0 / q)
    return survivors, p_assoc


@kernel(inline=True)
def store_stream_record(r, p, d, n, stream, entered, kind, rec):
    """Write stream record r: the leading photon (position, direction, normal), and of ``stream`` = (the power the
    leading photon stores, the associated photons' power, how many landed) the powers and the count.  ``entered``
    is the sum of the landed photons' coating factors (:data:`AssociatedPhotons.factor`; their number where no
    coated surface is met), so the energy E_i is what the stream's photons store."""
    lead, p_assoc, landed = stream
    vec.set_row(rec.position, r, p)
    vec.set_row(rec.direction, r, d)
    vec.set_row(rec.normal, r, n)
    vec.set_row(rec.lead_power, r, lead)
    vec.set_row(rec.assoc_power, r, p_assoc)
    for c in range(3):
        rec.energy[r, c] = lead[c] + entered * p_assoc[c]
    rec.count[r] = landed
    rec.kind[r] = kind


@kernel(inline=True)
def store_associated(a, p, d, n, factor, assoc):
    """Write associated photon slot a (position, direction of travel, normal: zero in a medium; the coating
    factor its power carries there)."""
    vec.set_row(assoc.position, a, p)
    vec.set_row(assoc.direction, a, d)
    vec.set_row(assoc.normal, a, n)
    assoc.factor[a] = factor


@kernel(inline=True)
def disc_point(beam, u1, u2):
    """The point of the stream's disc for numbers (u1, u2), and the unit direction from the beam's origin to it.

    ``beam`` = (o, n_from, x, d, r_s): the associated photons leave o (on a surface of normal n_from, zero
    if none) towards the disc of radius r_s about the leading photon's event x, across its direction d.
    """
    o, _, x, d, r_s = beam
    s, t = vec.orthonormal_basis(d)
    u, v = square_to_uniform_disk(u1, u2)
    q = vec.madd(vec.madd(x, s, u * r_s), t, v * r_s)
    return q, vec.sub(q, o)


@kernel(inline=True)
def unwrapped(mats, m):
    """Material row m, or a normal or bump map's nested row (its sides and lobes; where an associated photon lands it
    needs no perturbed normal: :func:`place_associated`)."""
    if has(mats, NORMALMAP) and mats.kind[m] == NORMALMAP or has(mats, BUMPMAP) and mats.kind[m] == BUMPMAP:
        return mats.nested[m, 0]
    return m


@kernel(inline=True)
def associated_surface(tables, o, d, key):
    """The surface an associated photon's ray from o along d lands on or merges at: (prim (-1: none), t, b1, b2,
    the ray's origin o' for them, the part m of the surface's material it took, uv).  A mixture
    (mask, blendbsdf) is resolved with the photon's own number (key, c) at its c-th crossing
    (:func:`caustica.bsdfs.resolve`), as the photon tracer resolves it; where a mask is off the ray goes on past it."""
    geom, mats, _, _ = tables
    for c in range(ASSOCIATED_CROSSINGS):
        prim, t, b1, b2 = intersect(geom, o, d, 1e30)
        if prim < 0:
            break
        own = geom.prim_material[prim]
        if not (has(mats, MASK) and mats.kind[own] == MASK or has(mats, BLEND) and mats.kind[own] == BLEND):
            return prim, t, b1, b2, o, own, NO_UV
        uv = surface_uv(geom, prim, o, d, t, b1, b2)
        m, _ = resolve(mats, own, uv, key, c)
        if m >= 0 and mats.kind[m] != NULL:
            return prim, t, b1, b2, o, m, uv
        p, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        o = vec.offset_origin(p, ng, d)   # a mask where it is off: on past it
    return -1, 0.0, 0.0, 0.0, o, 0, NO_UV


@kernel
def place_associated(tables, beam, key, dim, photons, out, splitting):
    """Trace the stream's associated photons, ``photons`` = (how many, their power), from the beam's origin
    towards its disc (:func:`disc_point`, numbers key, dim + 2j and dim + 2j + 1).

    Returns (landed, split off, entered): ``landed`` photons met a diffuse surface and are written, when ``out`` =
    (store, first slot, assoc) says store, to assoc slots from the first on, each with the factor B of a coated
    diffuse lobe it landed on (1 elsewhere; ``entered`` sums them: :func:`store_stream_record`); the rest merge into the
    leading photon — except, with ``splitting`` = (split_path, split_buf) and a buffer that can take them
    (:func:`may_split`), those whose ray meets a mirror or glass, which leave the stream as photons of their own
    (:func:`split_off`).  A mixture is resolved per photon (:func:`associated_surface`); one that takes a part that
    stores nothing there merges, so it is stored with the leading photon's factor.  A normal or bump map is resolved per photon to its nested row
    (:func:`unwrapped`), whose record carries the geometric normal and no coating's factor, as the photon tracer's
    (the visible points there weight each photon by the BSDF in their own perturbed frame).  A photon
    whose direction q - o points into the surface o lies on (``n_from``, facing the side the stream
    leaves by) cannot leave it and is merged (before this check such rays met the surface again at
    t ~ 1e-4 and landed where the stream left from).
    """
    geom, mats, _, _ = tables
    o, n_from, _, _, _ = beam
    n_alive, p_assoc = photons
    store, a0, assoc = out
    split_path, split_buf = splitting
    check_side = vec.dot(n_from, n_from) > 0.5
    landed = 0
    n_split = 0
    entered = 0.0
    for j in range(n_alive):
        _, to_q = disc_point(beam, uniform(key, dim + 2 * j), uniform(key, dim + 2 * j + 1))
        d = vec.normalize(to_q)
        if check_side and vec.dot(d, n_from) <= 0.0:
            continue  # into the surface it leaves: merged
        if has(mats, MASK) or has(mats, BLEND):
            prim, th, b1, b2, o_hit, m, uv = associated_surface(tables, o, d, path_key(key, ASSOCIATED_PART_TAG, j))
        else:   # (no mixture in the scene: no code for one)
            prim, th, b1, b2 = intersect(geom, o, d, 1e30)
            o_hit, uv = o, NO_UV
            m = geom.prim_material[max(prim, 0)]
        if prim < 0:
            continue  # escaped: merged into the leading photon
        m = unwrapped(mats, m)
        if not mats.flags[m] & DIFFUSE_REFLECTION:
            if may_split(split_buf):
                split_off(tables, key, o, d, p_assoc, split_path, n_split, split_buf)
                n_split += 1
            continue  # met a mirror, glass or glossy surface: merged (or split off)
        p, ng, ns = surface_at(geom, prim, o_hit, d, th, b1, b2)
        front = vec.dot(d, ng) < 0.0
        scatters, ng, ns = oriented(mats, m, front, ng, ns)
        if not scatters:
            continue  # the black back of a one-sided surface: merged
        factor = 1.0
        if has(mats, PLASTIC) or has(mats, ROUGHPLASTIC) or has(mats, MASK) or has(mats, BLEND):
            factor = record_factor(geom, mats, (prim, m, uv, front, ng, ns), d)
        if store:   # its normal as the photon tracer's record's (the geometric one under a map)
            store_associated(a0 + landed, p, d, ng if wrapped(mats, m) else ns, factor, assoc)
        landed += 1
        entered += factor
    return landed, n_split, entered


@kernel
def spread_in_medium(geom, beam, key, dim, n_alive, out):
    """Place the stream's associated photons about a medium event (``--medium-scattering spread``); returns
    how many were placed.

    Photon j takes the point q of the beam's disc for numbers key, dim + 2j and dim + 2j + 1
    (:func:`disc_point`); it is placed there, travelling along q - o, when the segment from o to q meets no
    surface (null boundaries included: beyond one is another medium), and written to the next assoc slot
    of ``out`` = (store, first slot, assoc) when it says store.  The others merge.
    """
    o = beam[0]
    store, a0, assoc = out
    placed = 0
    for j in range(n_alive):
        q, to_q = disc_point(beam, uniform(key, dim + 2 * j), uniform(key, dim + 2 * j + 1))
        dist = vec.length(to_q)
        if not dist > 0.0:
            continue
        d = vec.mul(to_q, 1.0 / dist)
        prim, _, _, _ = intersect(geom, o, d, dist)
        if prim >= 0:
            continue  # a surface between: merged into the leading photon
        if store:
            store_associated(a0 + placed, q, d, (0.0, 0.0, 0.0), 1.0, assoc)
        placed += 1
    return placed


@kernel
def split_at_specular(tables, key, beam, photons, lead, splitting):
    """At the leading photon's mirror or glass hit, the beam's x (``--specular split``): each associated photon
    is aimed from o through a point of the beam's disc (numbers of its own disc key) and leaves the stream
    (:func:`split_off`), unless its ray goes into the surface o lies on, escapes or meets a black back first
    (then it merges).  Returns (the leading photon's power, split photons added).
    """
    geom, mats, _, _ = tables
    o, n_from, _, _, _ = beam
    n_alive, p_assoc = photons
    split_path, split_buf = splitting
    check_side = vec.dot(n_from, n_from) > 0.5
    k = 0
    for j in range(n_alive):
        kd = path_key(key, SPLIT_DISC_TAG, j)
        _, to_q = disc_point(beam, uniform(kd, 0), uniform(kd, 1))
        dj = vec.normalize(to_q)
        if leaves_by(geom, mats, o, dj, n_from, check_side):
            split_off(tables, key, o, dj, p_assoc, split_path, k, split_buf)
            k += 1
        else:
            lead = vec.add(lead, p_assoc)  # into its surface, escaped or a black back: merged
    return lead, k


@kernel(inline=True)
def leaves_by(geom, mats, o, d, n_from, check_side):
    """Whether an associated photon aimed from o along d leaves its stream at a specular split: its ray must
    leave the surface o lies on and meet something other than the black back of a one-sided surface (an interface,
    a diffuse lobe beside a transmitting one, has none: :func:`caustica.bsdfs.oriented`)."""
    if check_side and vec.dot(d, n_from) <= 0.0:
        return False
    prim, t, b1, b2 = intersect(geom, o, d, 1e30)
    if prim < 0:
        return False
    m = unwrapped(mats, geom.prim_material[prim])
    if not mats.flags[m] & DIFFUSE_REFLECTION or mats.twosided[m] != 0 or mats.flags[m] & TRANSMISSION:
        return True
    _, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
    return vec.dot(d, ng) < 0.0


@kernel
def trace_streams(tables, light_medium, source, rules, buf, i0, i1):
    """Emit and trace streams [i0, i1) of ``source`` = (seed, stream, n_streams) (:func:`trace_stream`) into
    ``buf`` = (records, associated photons, split photons, the records' depths)."""
    tables, light_medium = borrowed(tables), borrow(light_medium)
    geom, _, lights, _ = tables
    seed, stream, n_streams = source
    rec, assoc, split_buf, depth = buf
    buf = (borrowed(rec), borrowed(assoc), borrowed(split_buf), borrow(depth))   # no reference counts in the loop
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, e_s, n_from = emit_photon(geom, lights, key, n_streams)      # eq. 1: E_s = E_z / n_fs
        medium = start_medium(tables, light_medium, key, (o, d))
        trace_stream(tables, key, (o, d, e_s, n_from, medium), rules, i, buf)


@kernel(inline=True)
def attenuate_stream(stream, medium, w):
    """Every photon of ``stream`` = (the leading photon's power, each associated photon's power, how many are
    alive) times a free flight's weight w in ``medium`` (none: unchanged).  Returns (alive: w is not zero, stream)."""
    if medium < 0:
        return True, stream
    if w[0] == 0.0 and w[1] == 0.0 and w[2] == 0.0:
        return False, stream
    lead, p_assoc, n_alive = stream
    return True, (vec.hadamard(lead, w), vec.hadamard(p_assoc, w), n_alive)


@kernel(inline=True)
def stream_at_medium_event(geom, beam, key, dim, stream, rules, out):
    """At a scattering event x in a medium, ``beam`` = (o, zero, x, d, r_s): the associated photons spread over the
    disc about x (``rules`` = (n_assoc, spread), :func:`spread_in_medium`) or merge into the leading photon, and a
    volume stream record of ``kind`` goes to slot r when ``out`` = (store, r, kind, rec, assoc) says store.
    Returns (the stream, dim past its 2 n_assoc numbers)."""
    lead, p_assoc, n_alive = stream
    n_assoc, spread = rules
    store, r, kind, rec, assoc = out
    landed = 0
    if spread and n_alive > 0:
        landed = spread_in_medium(geom, beam, key, dim, n_alive, (store, r * n_assoc, assoc))
    dim += 2 * n_assoc
    lead = vec.madd(lead, p_assoc, float(n_alive - landed))   # the ones not placed merge
    if store:
        store_stream_record(r, beam[2], beam[3], (0.0, 0.0, 0.0), (lead, p_assoc, landed), float(landed), kind,
                            rec)
    return (lead, p_assoc, landed), dim


@kernel(inline=True)
def stream_medium_event(tables, medium, beam, key, dim, stream, rules, out):
    """The stream at a scattering event in ``medium`` (:func:`stream_at_medium_event`), then, unless it was the last
    bounce, its leading photon samples the phase function there and every photon takes its weight; ``rules`` =
    (n_assoc, spread, termination, last).  Returns (alive, the new direction, the stream, dim)."""
    _, _, _, media = tables
    n_assoc, spread, termination, last = rules
    stream, dim = stream_at_medium_event(tables[0], beam, key, dim, stream, (n_assoc, spread), out)
    if last:
        return False, beam[3], stream, dim
    lead, p_assoc, n_alive = stream
    alive, inv_q, wo, weight, dim = photon_scatter(media, medium, beam[2], beam[3], key, dim,
                                                   termination == TERMINATION_ROULETTE)
    if alive:
        lead = vec.mul(vec.mul(lead, inv_q), weight)
        p_assoc = vec.mul(vec.mul(p_assoc, inv_q), weight)
    return alive, wo, (lead, p_assoc, n_alive), dim


@kernel(inline=True)
def stream_at_specular(tables, key, beam, stream, m, splitting):
    """At the leading photon's mirror or glass, material m: its associated photons split off (``--specular split``,
    once per stream at most, as none is left after it: :func:`split_at_specular`) or merge into it.  Where volpath's
    thin dielectric reflects (straight on it is :func:`null_thin_crossing`) they merge even so: split off, each would
    draw the reflection again (R² of them).  Returns (the stream, with no associated photon left, split photons
    added)."""
    lead, p_assoc, n_alive = stream
    k = 0
    if may_split(splitting[1]) and n_alive > 0 and not has_null_lobe(tables[1], m):
        lead, k = split_at_specular(tables, key, beam, (n_alive, p_assoc), lead, splitting)
        n_alive = 0
    lead = vec.madd(lead, p_assoc, float(n_alive))
    return (lead, p_assoc, 0), k


@kernel(inline=True)
def stream_at_diffuse(tables, key, dim, beam, stream, hit, out, splitting):
    """At the leading photon's diffuse hit x, ``hit`` = (prim, m, uv, front, ng, ns) (m the part of a mixture taken,
    normals turned to the ray): its associated photons land where their rays meet a diffuse surface
    (:func:`place_associated`, written from assoc slot r * n_assoc on), split off or merge into it; with ``out`` =
    (store, r, kind, n_assoc, rec, assoc), stream record r of ``kind`` is written when ``store`` says, the leading
    photon's power as the photon tracer stores it (:func:`~caustica.photons.trace.record_power`: a coated lobe's
    factor B, a mixture's storing probability) and its normal as the photon tracer's (the geometric one under a
    normal or bump map, for the gather's same-side test).  Returns (the stream, split photons added, dim past its
    2 n_assoc numbers)."""
    geom, mats, _, _ = tables
    m, ng, ns = hit[1], hit[4], hit[5]
    lead, p_assoc, n_alive = stream
    store, r, kind, n_assoc, rec, assoc = out
    landed, split_now, entered = place_associated(tables, beam, key, dim, (n_alive, p_assoc),
                                                  (store, r * n_assoc, assoc), splitting)
    dim += 2 * n_assoc
    lead = vec.madd(lead, p_assoc, float(n_alive - landed - split_now))   # the ones that did not land merge
    if store:
        stored = record_power(geom, mats, hit, beam[3], lead)
        store_stream_record(r, beam[2], beam[3], ng if wrapped(mats, m) else ns, (stored, p_assoc, landed), entered,
                            kind, rec)
    return (lead, p_assoc, landed), split_now, dim


@kernel(inline=True)
def stream_at_surface(tables, key, dim, beam, stream, hit, out, splitting):
    """What the stream does at a surface, ``hit`` = (prim, m, uv, front, ng, ns): at a mirror, glass or glossy surface
    (:func:`stream_at_specular`, before the side is known) or at a diffuse surface that scatters on this side
    (:func:`stream_at_diffuse`, ``out`` as it takes it), ``splitting`` = (split_path, split_buf).  Returns (scatters,
    diffuse, ng, ns turned to the ray, the stream, the split photons so far (split_path's with those added here),
    dim)."""
    _, mats, _, _ = tables
    prim, m, uv, front, ng, ns = hit
    split_path = splitting[0]
    diffuse = mats.flags[m] & DIFFUSE_REFLECTION
    k = 0
    if not diffuse:
        stream, k = stream_at_specular(tables, key, beam, stream, m, splitting)
    scatters, ng, ns = oriented(mats, m, front, ng, ns)
    if scatters and diffuse:
        stream, k, dim = stream_at_diffuse(tables, key, dim, beam, stream, (prim, m, uv, front, ng, ns), out,
                                           splitting)
    return scatters, diffuse, ng, ns, stream, split_path[1] + k, dim


@kernel(inline=True)
def stream_bounce(tables, surface, ray, key, dim, stream, decay):
    """The leading photon's bounce at ``surface`` = (p, ng, ns, uv, ng_front, m, shape, medium, prim) where ``ray`` =
    (o, d, t, b1, b2) met primitive prim (normals from :func:`stream_at_surface`): the photon tracer's
    (:func:`~caustica.photons.trace.bounce_at`: under a normal or bump map its wrapped bounce, Mitsuba's flip by the
    side it leaves to) and, after a non-delta lobe or at a coated diffuse surface, stream decay
    (:func:`associated_decay`, n_assoc numbers); ``decay`` = (n_assoc, termination).
    Returns (alive, the new origin, direction and medium, the stream, delta, dim)."""
    _, mats, _, media = tables
    p, ng, ns, uv, ng_front, m, shape, medium, prim = surface
    lead, p_assoc, n_alive = stream
    n_assoc, termination = decay
    alive, d_new, weight, inv_q, delta, dim = bounce_at(tables, m, prim, ray, (ng, ns, uv), (key, dim, termination))
    if alive:
        lead = vec.mul(vec.hadamard(lead, weight), inv_q)
        if not delta or has(mats, PLASTIC) and mats.flags[m] & DIFFUSE_REFLECTION:   # (a plastic's coating:
            #                                                                     the stream reflects whole)
            n_alive, p_assoc = associated_decay(key, dim, n_alive, p_assoc, weight,
                                                inv_q if termination == TERMINATION_ROULETTE else 0.0)
            dim += n_assoc
    o = vec.offset_origin(p, ng, d_new)
    return alive, o, d_new, medium_after(media, shape, ng_front, d_new, medium), (lead, p_assoc, n_alive), delta, dim


@kernel(inline=True)
def null_thin_crossing(tables, m, hit, stream, numbers, place):
    """At a thindielectric whose straight-on lobe is volpath's null event (``null_thin_dielectric``), ``hit`` =
    (the ray (o, d, t, b1, b2), the primitive it met, front, ng, ns, uv, p) (front normals): the leading photon's
    sample (:func:`~caustica.photons.trace.bounce_at`, the wrapped one under a normal or bump map, ``numbers`` =
    (key, dim, termination), as :func:`stream_bounce` after it draws it).  Straight on, the stream crosses whole,
    no event, every photon taking the leading photon's weight, and its associated photons are aimed from past the
    surface; where it reflects, that bounce takes the same sample.  ``place`` = (shape, medium): the surface's shape
    and the medium the stream arrives in.  Returns (crossed straight on, the origin past it, the medium there, the
    stream, dim past the sample); at any other material, or not crossed: (False, p, the medium, the stream and dim
    as they came)."""
    _, mats, _, media = tables
    ray, prim, front, ng_front, ns, uv, p = hit
    d, dim = ray[1], numbers[1]
    shape, medium = place
    if not has_null_lobe(mats, m):
        return False, p, medium, stream, dim
    _, ng, ns = oriented(mats, m, front, ng_front, ns)
    alive, d_new, weight, inv_q, _, dim_past = bounce_at(tables, m, prim, ray, (ng, ns, uv), numbers)
    if not alive or vec.dot(d_new, ng) * vec.dot(d, ng) <= 0.0:
        return False, p, medium, stream, dim
    lead, p_assoc, n_alive = stream
    stream = (vec.mul(vec.hadamard(lead, weight), inv_q), vec.mul(vec.hadamard(p_assoc, weight), inv_q), n_alive)
    return True, vec.offset_origin(p, ng, d), medium_after(media, shape, ng_front, d, medium), stream, dim_past


@kernel(inline=True)
def emitted_stream(e_s, n_assoc):
    """A stream as it leaves its light with power E_s (eq. 1): (the leading photon's power, each associated
    photon's, how many are alive), E_s split equally among its n_fa + 1 photons."""
    share = 1.0 / (n_assoc + 1)
    return vec.mul(e_s, share), vec.mul(e_s, share), n_assoc


@kernel(inline=True)
def record_slot(scattered, stored, i, max_bounces):
    """Whether stream i's next event stores a record, having stored ``stored``, and the slot it goes to: its records
    take slots [i (mr + 1), (i + 1) (mr + 1)) in turn, once it has ``scattered`` (before, what it carries is direct
    light)."""
    slots = max_bounces + 1
    return scattered and stored < slots, i * slots + stored


@kernel(inline=True)
def count_stored(store, r, events, depth, stored):
    """After an event that stores stream record r when ``store`` says so: its depth, events + 1 (the segments from
    the light, Mitsuba's count), into ``depth``.  Returns the records the stream has stored."""
    if store:
        depth[r] = min(events + 1, MAX_RECORD_DEPTH)
        stored += 1
    return stored


@kernel(inline=True)
def stream_goes_indirect(geom, mats, prim, diffuse):
    """Whether the records after the stream's bounce at primitive prim are INDIRECT whichever lobe it takes
    there: a ``diffuse`` one, or the reflection of a plastic's coating or of a blend's mirror or glossy part
    beside a diffuse one (:func:`~caustica.photons.trace.beside_diffuse`), as the photon tracer's (trace_one).
    Asked before the bounce, not after it: the same test after it made stream tracing 25 % slower, measured."""
    if diffuse:
        return True
    return (has(mats, MASK) or has(mats, BLEND)) and beside_diffuse(geom, mats, prim)


@kernel
def trace_stream(tables, key, start, rules, i, buf):
    """Stream i from ``start`` = (o, d, its power E_s, the normal n_from of the surface it leaves, its medium)
    into records [i * (mr + 1), (i + 1) * (mr + 1)) of ``buf``; ``rules`` = (n_assoc, r_s, mr, termination, spread).
    The stream moves as one: in a medium every photon takes the leading photon's flight weight.  At a medium event,
    a surface and a bounce: :func:`stream_medium_event`, :func:`stream_at_surface`, :func:`stream_bounce`.
    """
    geom, mats, _, media = tables
    o, d, e_s, n_from, medium = start
    n_assoc, r_s, max_bounces, termination, spread = rules
    rec, assoc, split_buf, depth = buf
    zero = (0.0, 0.0, 0.0)
    stream = emitted_stream(e_s, n_assoc)
    dim = 8
    bounces = 0           # diffuse and medium scattering events
    specular_events = stored = crossings = 0
    events = 0            # scattering events of every kind (null crossings not): a record's depth is events + 1
    scattered = False     # any event so far: what is stored from now on is not direct light
    diffuse_like = False  # a diffuse or medium event so far: records are (VOLUME_)INDIRECT
    n_split = 0           # associated photons split off so far
    while specular_events <= SPECULAR_CAP:
        prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
        if escaped:
            break
        alive, stream = attenuate_stream(stream, medium, w)
        if not alive:
            break
        store, r = record_slot(scattered, stored, i, max_bounces)
        if in_a_medium(media, medium) and prim < 0:
            # ---- a scattering event in the medium: a point, no surface the associated photons could aim into
            x = vec.madd(o, d, t)
            alive, wo, stream, dim = stream_medium_event(
                tables, medium, (o, zero, x, d, r_s), key, dim, stream,
                (n_assoc, spread, termination, bounces >= max_bounces),
                (store, r, VOLUME_INDIRECT if diffuse_like else VOLUME_CAUSTIC, rec, assoc))
            stored = count_stored(store, r, events, depth, stored)
            if not alive:
                break
            o, d, n_from, crossings = x, wo, zero, 0
            bounces += 1
            events += 1
            scattered = diffuse_like = True
            continue
        # ---- a surface
        p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, nxt, dim = surface_interaction(
            tables, (prim, t, b1, b2), o, d, medium, crossings, key, dim)
        if nxt == CROSSED:
            n_from = zero
            continue
        if nxt == TRAPPED:
            break
        crossed, o_past, medium_past, stream, dim_past = null_thin_crossing(
            tables, m, ((o, d, t, b1, b2), prim, front, ng, ns, uv, p), stream, (key, dim, termination),
            (shape, medium))
        if crossed:   # volpath's thin dielectric straight on: no event, but a specular one towards the cap
            specular_events += 1
            o, medium, n_from, dim = o_past, medium_past, zero, dim_past
            continue
        # CAUSTIC: a light -> specular+ -> diffuse record (no diffuse bounce before it), the caustic that aimed
        # caustic photons may carry instead (pspm --caustic-photons)
        ng_front = ng
        scatters, diffuse, ng, ns, stream, n_split, dim = stream_at_surface(
            tables, key, dim, (o, n_from, p, d, r_s), stream, (prim, m, uv, front, ng, ns),
            (store, r, INDIRECT if diffuse_like else CAUSTIC, n_assoc, rec, assoc),
            ((i * n_assoc, n_split, medium, bounces, scattered, events, (max_bounces, termination)), split_buf))
        if not scatters:
            break  # absorbed by the black back of a one-sided surface
        if diffuse:
            stored = count_stored(store, r, events, depth, stored)
            if bounces >= max_bounces:
                break
        diffuse_like = diffuse_like or stream_goes_indirect(geom, mats, prim, diffuse)
        alive, o, d, medium, stream, delta, dim = stream_bounce(
            tables, (p, ng, ns, uv, ng_front, m, shape, medium, prim), (o, d, t, b1, b2), key, dim, stream,
            (n_assoc, termination))
        if not alive:
            break
        specular_events, bounces = count_bounce(delta or not diffuse, (specular_events, bounces))
        n_from = ng if diffuse else zero   # from a mirror, glass or glossy surface only after a split
        events += 1
        scattered = True


def trace_stream_pass(scene, buf, seed, stream, n_streams, n_assoc, r_s, max_bounces, termination, *,
                      spread=False, threads=None, progress=None) -> float:
    """Trace ``n_streams`` streams of (seed, stream) into ``buf`` (a :class:`StreamBuffers`) on the thread
    pool; returns the compile seconds.  ``termination`` is TERMINATION_CAP or TERMINATION_ROULETTE; the associated
    photons split off at mirrors and glass (``--specular split``) when the buffers were made for it."""
    if buf.rec.kind.shape[0] != n_streams * (max_bounces + 1) or buf.n_assoc != n_assoc:
        raise ValueError(f"stream buffers of {buf.rec.kind.shape[0]} record slots and {buf.n_assoc} associated photons "
                         f"each do not fit {n_streams} streams of {n_assoc} with {max_bounces} bounces")
    rules = (n_assoc, float(r_s), max_bounces, termination, bool(spread))
    return parallel_for(trace_streams, n_streams,
                        (scene.tables, scene.light_media(), (seed, stream, n_streams), rules, buf.kernel_args),
                        threads=threads, progress=progress)


class StreamRecords(NamedTuple):
    """Stream records, one slot per stream and bounce (float32 vectors)."""
    position: np.ndarray      # leading photon
    direction: np.ndarray     # its direction of travel
    normal: np.ndarray        # its surface normal (zero for a volume record)
    lead_power: np.ndarray
    assoc_power: np.ndarray   # the power of each associated photon (they share one)
    energy: np.ndarray        # E_i: the record's photons' powers summed
    count: np.ndarray         # int32: associated photons that landed
    kind: np.ndarray          # int8: EMPTY, INDIRECT, CAUSTIC, VOLUME_INDIRECT or VOLUME_CAUSTIC


class AssociatedPhotons(NamedTuple):
    """The associated photons of the stream records, n_fa slots per record (float32)."""
    position: np.ndarray
    direction: np.ndarray
    normal: np.ndarray
    factor: np.ndarray        # what of the record's associated power this photon stores: a coated diffuse
    #                           lobe's factor B where it landed (trace.record_power), else 1


class StreamBuffers:
    """Fixed record and associated-photon slots of the stream tracer (float32)."""

    def __init__(self, n_streams, n_assoc, max_bounces, split=False):
        s = n_streams * (max_bounces + 1)
        a = s * n_assoc
        f = np.float32
        self.rec = StreamRecords(*(np.zeros((s, 3), f) for _ in range(6)), np.zeros(s, np.int32),
                                 np.zeros(s, np.int8))
        self.assoc = AssociatedPhotons(*(np.zeros((a, 3), f) for _ in range(3)), np.zeros(a, f))
        # split photons (--specular split): at most n_assoc per stream, mr + 1 slots each; else none, which the
        # stream kernels then compile without (may_split)
        self.splits = bool(split)
        self.split = allocate_buffers(n_streams * n_assoc, max_bounces + 1) if split else no_records()
        self.depth = np.zeros(s, np.uint16)   # each record's depth: segments from the light (TraceBuffers.depth)
        self.n_assoc = n_assoc

    @property
    def kernel_args(self) -> tuple:
        """The buffers in trace_streams' argument order."""
        return self.rec, self.assoc, self.split, self.depth

    @staticmethod
    def bytes_needed(n_streams, n_assoc, max_bounces, split=False):
        s = n_streams * (max_bounces + 1)
        return s * (6 * 12 + 7) + s * n_assoc * (40 + (SLOT_BYTES if split else 0))

    def _records(self, estimator: str, keep: np.ndarray) -> list:
        """(position, direction, power, normal, depth) parts of the records ``keep`` under ``estimator`` (an
        associated photon has its record's depth: it took the same path).

        ``stream``: each record's energy E_i at its leading position (eq. 2's reading);
        ``photons``: the leading and every associated photon at its own position.
        """
        pos, dirs, nrm, lead_pow, assoc_pow, energy, count, _ = self.rec
        if estimator == "stream":
            return [(pos[keep], dirs[keep], energy[keep], nrm[keep], self.depth[keep])]
        parts = [(pos[keep], dirs[keep], lead_pow[keep], nrm[keep], self.depth[keep])]
        if self.n_assoc > 0:
            used = ((np.arange(self.n_assoc)[None, :] < count[:, None]) & keep[:, None]).reshape(-1)
            parts.append((self.assoc[0][used], self.assoc[1][used],
                          associated_power(assoc_pow[keep], count[keep], self.assoc.factor[used]),
                          self.assoc[2][used], np.repeat(self.depth[keep], count[keep])))
        return parts

    def events(self, estimator: str, leave_caustics: bool = False, depths: bool = False):
        """This pass's surface photon events (position, direction, power, normal[, depth]) for a progressive
        gather; ``depths``: with each event's depth (segments from the light), which a finite max_depth limits.

        The records under ``estimator`` (:meth:`_records`).  Split photons (``--specular split``)
        are photons of their own under either estimator.  ``leave_caustics``: the
        light -> specular+ -> diffuse records are left out (aimed caustic photons carry that light
        instead; only with ``--specular merge``, where such a record holds its whole stream and no
        associated photon).  Volume records (kinds 3 and 4, streams in media) are not events here:
        :meth:`volume_events`.
        """
        valid = self.rec[7]
        keep = (valid == INDIRECT) if leave_caustics else ((valid == INDIRECT) | (valid == CAUSTIC))
        parts = self._records(estimator, keep)
        sp, sd, spow, sn, kind = (self.split.position, self.split.direction, self.split.power, self.split.normal,
                                  self.split.kind)
        if kind.shape[0]:
            ok = kind != EMPTY
            parts.append((sp[ok], sd[ok], spow[ok], sn[ok], self.split.depth[ok]))
        return tuple(np.concatenate([part[c] for part in parts]) for c in range(5 if depths else 4))

    def volume_events(self, estimator: str, leave_caustics: bool = False):
        """This pass's volume photons (position, direction of travel, power, depth), as :meth:`events` for
        surfaces.

        ``leave_caustics``: the light -> specular+ -> medium records are left out (kind VOLUME_CAUSTIC),
        as the aimed caustic photons carry them.
        """
        valid = self.rec[7]
        keep = (valid == VOLUME_INDIRECT) if leave_caustics else ((valid == VOLUME_INDIRECT) |
                                                                  (valid == VOLUME_CAUSTIC))
        parts = self._records(estimator, keep)
        return tuple(np.concatenate([part[c] for part in parts]) for c in (0, 1, 2, 4))


def associated_power(assoc_power, count, factor) -> np.ndarray:
    """Each associated photon's stored power: its record's associated power (``assoc_power``, one row per record,
    ``count`` photons each, in slot order) times the photon's own coating factor."""
    return np.repeat(assoc_power, count, axis=0) * factor[:, None]


class StreamMap:
    """The stored stream records, compacted, with the kd-tree over leading photons."""

    def __init__(self, buf: StreamBuffers):
        self.volume = None   # (position, direction, power, depth) of the volume photons, in a scene with media
        pos, dirs, nrm, lead_pow, assoc_pow, energy, count, valid = buf.rec
        keep = (valid == INDIRECT) | (valid == CAUSTIC)   # every surface record (volume ones: volume_events)
        self.count = count[keep]
        n_fa = buf.n_assoc
        if n_fa > 0:
            slot_used = (np.arange(n_fa)[None, :] < count[:, None]) & keep[:, None]
            flat = slot_used.reshape(-1)
            self.assoc_pos = buf.assoc[0][flat]
            self.assoc_dir = buf.assoc[1][flat]
            self.assoc_nrm = buf.assoc[2][flat]
            self.assoc_factor = buf.assoc.factor[flat]
        else:
            self.assoc_pos = self.assoc_dir = self.assoc_nrm = np.zeros((0, 3), np.float32)
            self.assoc_factor = np.zeros(0, np.float32)
        self.assoc_power = assoc_pow[keep]
        self.depth_traced = buf.depth[keep]   # in tracing order, as ``count``: the associated photons' depths
        # The paper's map: leading positions in the kd-tree, each carrying its stream's energy E_i.
        # Its records are in kd-tree order; ``count`` and ``assoc_power`` stay in tracing
        # order, which the associated photons' flat arrays follow; ``order`` links the two.
        self.records, self.order = build_photon_map_with_order(pos[keep], dirs[keep], energy[keep], nrm[keep],
                                                               buf.depth[keep])
        self.lead_power = np.ascontiguousarray(lead_pow[keep][self.order])  # aligned with self.records

    @property
    def n_records(self) -> int:
        return self.records.count

    @property
    def n_associated(self) -> int:
        return int(self.assoc_pos.shape[0])

    def memory_bytes(self) -> int:
        """Stream records (leading photon + energy), associated photons and the kd-tree."""
        extra = sum(a.nbytes for a in (self.count, self.assoc_pos, self.assoc_dir, self.assoc_nrm, self.assoc_factor,
                                       self.lead_power, self.assoc_power, self.depth_traced))
        # ``order`` is bookkeeping only
        return self.records.memory_bytes() + extra

    def associated_power(self) -> np.ndarray:
        """(n_associated, 3) float32: the power each associated photon stores, in the order of ``assoc_pos``."""
        return associated_power(self.assoc_power, self.count, self.assoc_factor)

    def photon_map(self):
        """Every photon at its own position: leading photons and associated photons (the ``photons`` estimator)."""
        r = self.records
        assoc_power = self.associated_power()
        return build_photon_map(np.concatenate([r.position, self.assoc_pos]),
                                np.concatenate([r.direction, self.assoc_dir]),
                                np.concatenate([self.lead_power, assoc_power]),
                                np.concatenate([r.normal, self.assoc_nrm]),
                                np.concatenate([r.depth, np.repeat(self.depth_traced, self.count)]))
