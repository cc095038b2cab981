"""Tracing photons through the scene: PM's global and caustic maps, SPPM's photons, split stream photons.

One path loop, :func:`trace_one`, for every scene: with media or without (vacuum is the case of
no medium, ``medium`` = -1, with the same arithmetic; a scene without media has a trivial medium
table).  Each photon i is a pure function of (seed, pass, i): parallel tracing writes into its
own fixed slots, so the maps are identical for any thread count.

* A photon starts in the medium of its light (:func:`caustica.media.light_media`) and keeps
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
* Under a normal or bump map (:mod:`caustica.bsdfs.perturb`) the photon scatters in the perturbed frame with the
  adjoint weight (:func:`caustica.bsdfs.photon_shading`: the terminator's shadowing falls on its arriving side);
  its records there carry the geometric normal, for the same-side test, and no coating's factor: the visible
  points there weight each photon by the whole BSDF in their own perturbed frame.

What is stored obeys SPEC §2 (surfaces and volume alike): an event only after the photon has
scattered at least once, so no direct light.  Kinds: CAUSTIC / VOLUME_CAUSTIC when every earlier
event was a mirror, glass or glossy surface (light -> (S|G)+ -> event: what aimed caustic photons carry),
INDIRECT / VOLUME_INDIRECT otherwise.
"""
from __future__ import annotations

from ..features import has
from ..bsdfs import DELTA, DIFFUSE_REFLECTION, entry, oriented, photon_shading, sample, sample_kind, wrapped
from ..bsdfs.mixtures import weight
from ..emitters import choose_light
from ..geometry import vec
from ..jit import kernel, parallel_for
from ..media import free_flight, light_media, medium_after, photon_scatter
from ..sampling.rng import path_key, uniform
from ..scene.description import BLEND, MASK, PLASTIC, ROUGHPLASTIC
from ..transport import CROSSED, TRAPPED, borrow_tables, surface_interaction
from .emission import emit_caustic_photon, emit_photon
from .records import CAUSTIC, INDIRECT, VOLUME_CAUSTIC, VOLUME_INDIRECT

SPECULAR_CAP = 64
TERMINATION_CAP = 0       # scale power by the albedo, stop after mr diffuse bounces (the paper)
TERMINATION_ROULETTE = 1  # survive with p = the BSDF sample's mean weight (a diffuse albedo), power scaled by 1 / p


@kernel(inline=True)
def store_record(s, p, d, power, n, kind, buf):
    """Write one photon record (position, direction of travel, power, normal, kind) into slot s of ``buf``."""
    vec.set_row(buf.position, s, p)
    vec.set_row(buf.direction, s, d)
    vec.set_row(buf.power, s, power)
    vec.set_row(buf.normal, s, n)
    buf.kind[s] = kind


@kernel(inline=True)
def bounce(mats, m, d, at, key, dim, termination):
    """Continue a photon from material m at ``at`` = (ng, ns, uv) (normals from :func:`caustica.bsdfs.oriented`,
    surface coordinates): its BSDF sampled, then, after a non-delta lobe, Russian roulette on the number after the
    sample's (``TERMINATION_ROULETTE``: survive with probability p, power scaled by 1 / p).  p is the mean of the
    sample's weight f cos / pdf, capped at 1: a diffuse surface's albedo, and for a lobe whose weight is not the
    material's colour (a rough coating over a black base, a metal) what that lobe keeps, so a photon's power stays
    about what it was and no lobe that reflects light loses all its photons.

    On a normal or bump map's nested row the weight is the adjoint one (:func:`caustica.bsdfs.photon_shading`).

    Returns (alive, new direction, the BSDF's weight, the roulette's 1 / p (1 without one), delta: the lobe
    was a mirror's or glass's, dim); the power becomes power · weight · (1 / p), in that order.
    """
    ng, ns, uv = at
    if wrapped(mats, m):   # a normal or bump map's nested row: the photon's own weight (its shadowing on -d's side)
        ok, wi, weight, _, lobe, _, dim = sample_kind(mats, m, d, ng, ns, uv, key, dim)
        weight = vec.mul(weight, photon_shading(mats, m, ng, ns, vec.neg(d), wi))
    else:
        ok, wi, weight, _, lobe, _, dim = sample(mats, m, d, ng, ns, uv, key, dim)
    if lobe & DELTA:
        return ok, wi, weight, 1.0, True, dim
    u = uniform(key, dim)
    dim += 1
    if termination == TERMINATION_ROULETTE:
        q = min((weight[0] + weight[1] + weight[2]) / 3.0, 1.0)   # a probability, for a weight above 1 too
        if not q > 0.0:
            return False, wi, weight, 0.0, False, dim
        return ok and u < q, wi, weight, 1.0 / q, False, dim
    return ok, wi, weight, 1.0, False, dim


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
def scatter_photon(media, medium, d, key, dim, power, roulette):
    """A photon at a scattering event in ``medium`` samples the phase function (Russian roulette if ``roulette``).
    Returns (alive, the new direction, its power times the roulette's 1 / p and the phase weight, dim)."""
    alive, inv_q, wo, weight, dim = photon_scatter(media, medium, d, key, dim, roulette)
    if alive:
        power = vec.mul(vec.mul(power, inv_q), weight)
    return alive, wo, power, dim


@kernel(inline=True)
def coated(mats, m):
    """Whether material m is a coated diffuse lobe (plastic, roughplastic), whose photons carry its factor B
    (:func:`caustica.bsdfs.entry`: what of the light arriving enters the coating) in their records.  Not under a
    normal or bump map: visible points there weight each photon by the whole BSDF (api.check_bsdfs refuses a delta
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


@kernel
def trace_one(tables, key, photon, rules, out):
    """Follow one photon, ``photon`` = (o, d, power, medium, diffuse_bounces, scattered): from o along d in
    ``medium``.  Its records go to ``out`` = (slot0, slots, buf): slots slot0 .. slot0 + slots - 1 of ``buf``
    (a :class:`~caustica.photons.records.TraceBuffers`).  Returns the records stored.

    A photon from a light starts with no bounce and not ``scattered``; a split photon of a stream
    (:mod:`caustica.photons.streams`) starts with its stream's.  ``rules`` = (max_bounces, termination,
    caustic_only); ``caustic_only``: stop at the first diffuse or medium event (the aimed caustic
    photons).  Random numbers from 8 on.
    """
    geom, mats, _, media = tables
    o, d, power, medium, diffuse_bounces, scattered = photon
    max_bounces, termination, caustic_only = rules
    slot0, slots, buf = out
    dim = 8
    specular_events = 0
    diffuse_like = diffuse_bounces > 0   # a diffuse or medium event so far: records are INDIRECT
    crossings = stored = 0
    while True:
        prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
        if escaped:
            break
        if medium >= 0:
            power = vec.hadamard(power, w)
            if power[0] == 0.0 and power[1] == 0.0 and power[2] == 0.0:
                break
        if prim < 0:
            # ---- a scattering event in the medium
            p = vec.madd(o, d, t)
            if scattered and stored < slots:
                store_record(slot0 + stored, p, d, power, (0.0, 0.0, 0.0),   # a volume photon has no normal
                             VOLUME_INDIRECT if diffuse_like else VOLUME_CAUSTIC, buf)
                stored += 1
            if caustic_only or diffuse_bounces >= max_bounces:
                break
            alive, wo, power, dim = scatter_photon(media, medium, d, key, dim, power,
                                                   termination == TERMINATION_ROULETTE)
            if not alive:
                break
            o, d, crossings = p, wo, 0
            diffuse_bounces += 1
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
            if scattered and stored < slots:
                store_record(slot0 + stored, p, d, record_power(geom, mats, (prim, m, uv, front, ng, ns), d, power),
                             ng if wrapped(mats, m) else ns, INDIRECT if diffuse_like else CAUSTIC, buf)
                stored += 1
            if caustic_only or diffuse_bounces >= max_bounces:
                break
        alive, d_new, weight, inv_q, delta, dim = bounce(mats, m, d, (ng, ns, uv), key, dim, termination)
        if not alive:
            break
        power = vec.mul(vec.hadamard(power, weight), inv_q)
        if delta or not mats.flags[m] & DIFFUSE_REFLECTION:
            # a mirror, glass or glossy bounce: the photon is still on a caustic path, light -> (S|G)+
            specular_events += 1
            if specular_events > SPECULAR_CAP:
                break
            if mats.flags[geom.prim_material[prim]] & DIFFUSE_REFLECTION:
                # a coating's reflection (plastic), or a blend's delta or glossy part beside a diffuse one: no caustic
                # caster (tables.py), so records after it are INDIRECT, though it is no diffuse bounce
                diffuse_like = True
        else:
            diffuse_bounces += 1
            diffuse_like = True
        o, d, medium = vec.offset_origin(p, ng, d_new), d_new, medium_after(media, shape, ng_front, d_new, medium)
        scattered = True
    return stored


@kernel
def trace_photons(tables, light_medium, source, rules, buf, i0, i1):
    """Emit and trace photons [i0, i1) of ``source`` = (seed, stream, n_paths); photon i writes slots
    [i * (mr + 1), (i + 1) * (mr + 1)).  ``rules`` = (max_bounces mr, termination)."""
    tables = borrow_tables(tables)
    geom, _, lights, _ = tables
    seed, stream, n_paths = source
    max_bounces, termination = rules
    slots = max_bounces + 1
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, _ = emit_photon(geom, lights, key, n_paths)
        li, _, _ = choose_light(lights, uniform(key, 0))   # the light emit_photon chose
        trace_one(tables, key, (o, d, power, light_medium[li], 0, False), (max_bounces, termination, False),
                  (i * slots, slots, buf))


@kernel
def trace_caustic_photons(tables, light_medium, spheres, source, buf, i0, i1):
    """Caustic photons [i0, i1) of ``source`` = (seed, stream, n_paths), aimed at the caustic casters (mirrors,
    glass, glossy objects): the first event after a chain of them only (one slot each).  A photon that scatters in
    a medium or meets a diffuse surface before any of them stores nothing (that light is the other photons' and
    the direct light's)."""
    tables = borrow_tables(tables)
    geom, _, lights, _ = tables
    seed, stream, n_paths = source
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, ok = emit_caustic_photon(geom, lights, spheres, key, n_paths)
        if ok:
            li, _, _ = choose_light(lights, uniform(key, 0))
            trace_one(tables, key, (o, d, power, light_medium[li], 0, False), (0, TERMINATION_CAP, True), (i, 1, buf))


def trace_photon_pass(scene, buf, seed, stream, n_paths, max_bounces, termination, *, threads=None,
                      progress=None) -> float:
    """Trace ``n_paths`` photons of (seed, stream) into ``buf`` (mr + 1 slots each) on the thread pool;
    returns the compile seconds."""
    return parallel_for(trace_photons, n_paths, (scene.tables, light_media(scene), (seed, stream, n_paths),
                                                 (max_bounces, termination), buf), threads=threads, progress=progress)


def trace_caustic_photon_pass(scene, buf, seed, stream, n_paths, *, spheres=None, threads=None,
                              progress=None) -> float:
    """Trace ``n_paths`` photons aimed at the scene's caustic casters (or at ``spheres``, (n, 4) centre and
    radius) into ``buf`` (one slot each); returns the compile seconds."""
    spheres = scene.specular_bounding_spheres() if spheres is None else spheres
    return parallel_for(trace_caustic_photons, n_paths,
                        (scene.tables, light_media(scene), spheres, (seed, stream, n_paths), buf),
                        threads=threads, progress=progress)
