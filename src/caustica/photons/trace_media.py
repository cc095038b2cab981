"""Tracing photons through participating media (sppm in a scene with media; docs/media.md).

:func:`caustica.photons.trace.trace_one` with media, using the path tracer's own sampling
(:mod:`caustica.media`):

* a photon starts in the medium of its light (:func:`caustica.media.light_media`) and keeps
  track of the medium it is in across every surface it leaves (``medium_after``); null
  boundaries are crossed without scattering;
* in a medium it samples a free flight; the flight ends in a **medium scattering event** or
  at the next surface, and its power is multiplied by the flight's weight
  (:func:`caustica.media.flight_weight`: T / P at a surface, T σs / p at a scattering event —
  so the transmittance is in the power, and at a scattering event so is the albedo);
* at a medium scattering event the photon is stored as a **volume photon** (position, power
  after the weight above, direction of travel), then continues in a direction sampled from the
  phase function; the event counts as a bounce towards ``max_bounces``, as a diffuse bounce
  does (cap: continue with the albedo in the power; roulette: survive with the medium's mean
  albedo, power divided by it);
* surfaces as in ``trace_one``: diffuse hits are stored as surface records, mirrors and glass
  reflect or refract.

What is stored obeys SPEC §2 in the volume too: an event is stored only after the photon has
scattered at least once (surface or medium, specular included).  The first scattering event
after emission is direct light: at surfaces the shadow rays of the camera pass compute it, in
the media the camera segments' next-event estimate does (:mod:`caustica.photons.visible_points_media`).
Record kinds: CAUSTIC / VOLUME_CAUSTIC when every earlier event was a mirror or glass (the
light -> S+ -> event paths the aimed caustic photons carry), INDIRECT / VOLUME_INDIRECT otherwise.
"""
from __future__ import annotations

from ..bsdf import scattering_side
from ..emitters import choose_light
from ..geometry import vec
from ..geometry.scene_geometry import surface_at
from ..jit import borrowed, kernel
from ..media import cross_null, free_flight, medium_after, photon_scatter
from ..sampling.rng import path_key, uniform
from ..scene.description import DIFFUSE, NULL
from .emission import emit_caustic_photon, emit_photon
from .records import CAUSTIC, INDIRECT, VOLUME_CAUSTIC, VOLUME_INDIRECT
from .trace import SPECULAR_CAP, TERMINATION_ROULETTE, diffuse_bounce, specular_scatter, store_record


@kernel
def trace_one_media(geom, mats, media, key, o, d, power, medium, max_bounces, termination, caustic_only,
                    slot0, slots, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind):
    """Follow one photon through media, storing surface and volume records in slots slot0 .. slot0 + slots - 1."""
    dim = 8
    bounces = 0          # diffuse and medium scattering events
    specular_events = 0
    scattered = False    # any event so far (specular too): what is stored from now on is not direct light
    diffuse_like = False  # a diffuse or medium event so far: records are INDIRECT, not CAUSTIC
    crossings = 0
    stored = 0
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
                             VOLUME_INDIRECT if diffuse_like else VOLUME_CAUSTIC,
                             buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)
                stored += 1
            if caustic_only or bounces >= max_bounces:
                break
            alive, inv_q, wo, weight = photon_scatter(media, medium, d, key, dim, termination == TERMINATION_ROULETTE)
            dim += 3
            if not alive:
                break
            if termination == TERMINATION_ROULETTE:
                power = vec.mul(power, inv_q)
            power = vec.mul(power, weight)
            o = p
            d = wo
            bounces += 1
            scattered = True
            diffuse_like = True
            crossings = 0
            continue
        # ---- a surface
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        m = geom.prim_material[prim]
        kind = mats.kind[m]
        shape = geom.prim_shape[prim]
        if kind == NULL:
            medium, o, crossings, within = cross_null(media, shape, p, ng, d, medium, crossings)
            if not within:
                break
            continue
        crossings = 0
        ng_front = ng
        if kind == DIFFUSE:
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                break
            if scattered and stored < slots:
                store_record(slot0 + stored, p, d, power, ns, INDIRECT if diffuse_like else CAUSTIC,
                             buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)
                stored += 1
            if caustic_only or bounces >= max_bounces:
                break
            d, power, alive = diffuse_bounce(mats, m, ng, ns, power, key, dim, termination)
            dim += 3
            if not alive:
                break
            bounces += 1
            diffuse_like = True
            medium = medium_after(media, shape, ng_front, d, medium)
            o = vec.offset_origin(p, ng, d)
        else:
            specular_events += 1
            if specular_events > SPECULAR_CAP:
                break
            d_new, power, alive, ng_out = specular_scatter(mats, m, d, ng, ns, power, front, uniform(key, dim))
            dim += 1
            if not alive:
                break
            medium = medium_after(media, shape, ng_front, d_new, medium)
            o = vec.offset_origin(p, ng_out, d_new)
            d = d_new
        scattered = True
    return stored


@kernel
def trace_photons_media(geom, mats, lights, media, light_medium, seed, stream, n_paths, max_bounces, termination,
                        buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind, i0, i1):
    """:func:`caustica.photons.trace.trace_photons` through media: photon i writes slots [i (mr + 1), (i + 1) (mr + 1))."""
    geom, mats, lights, media = borrowed(geom), borrowed(mats), borrowed(lights), borrowed(media)
    slots = max_bounces + 1
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, _ = emit_photon(geom, lights, key, n_paths)
        li, _, _ = choose_light(lights, uniform(key, 0))   # the light emit_photon chose
        trace_one_media(geom, mats, media, key, o, d, power, light_medium[li], max_bounces, termination, False,
                        i * slots, slots, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)


@kernel
def trace_caustic_photons_media(geom, mats, lights, media, light_medium, spheres, seed, stream, n_paths,
                                buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind, i0, i1):
    """Caustic photons [i0, i1) through media: the first event after a mirror or glass only (one slot each).

    A photon that scatters in a medium or meets a diffuse surface before any mirror or glass
    stores nothing (that light is the other photons' and the direct light's).
    """
    geom, mats, lights, media = borrowed(geom), borrowed(mats), borrowed(lights), borrowed(media)
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, ok = emit_caustic_photon(geom, lights, spheres, key, n_paths)
        if ok:
            li, _, _ = choose_light(lights, uniform(key, 0))
            trace_one_media(geom, mats, media, key, o, d, power, light_medium[li], 0, 0, True,
                            i, 1, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)
