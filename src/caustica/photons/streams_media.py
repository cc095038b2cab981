"""Tracing streams through participating media (pspm in a scene with media; docs/media.md).

:func:`caustica.photons.streams.trace_streams` with media, by the photon tracer's rules in
media (:mod:`caustica.photons.trace_media`): the stream starts in its light's medium, the
leading photon samples the free flights (one channel per flight) and every photon of the
stream takes the flight's weight (:func:`caustica.media.flight_weight`), so the stream moves
and is attenuated as one; null boundaries are crossed; surfaces are treated as in SPM
(associated photons land on diffuse surfaces around the leading one, merge at mirrors and
glass).  At a **scattering event in a medium** the stream either

* ``spread`` (as at a diffuse surface): each associated photon is placed at a point of the
  disc of radius r_s about the event, across the direction of travel, if the segment from
  the stream's last origin to it meets no surface (otherwise it merges into the leading
  photon); a volume stream record holds the leading photon at the event and the associated
  photons at their points, and the stream goes on together in the leading photon's new
  direction (sampled from the phase function), a beam of width r_s; or
* ``merge`` (as at a mirror or glass): every associated photon merges into the leading one;
  the record is the whole stream at the event, and the rest of the path is one photon.

The record is stored only after the stream has scattered at least once (SPEC §2: the first
event after emission is direct light, which the camera pass estimates); its kind is
VOLUME_CAUSTIC (4) when every earlier event was a mirror or glass, else VOLUME_INDIRECT (3),
in the stream records' ``valid`` (surface records: 2 and 1).  A medium event counts as a
bounce towards ``max_bounces``; with ``termination=roulette`` the whole stream survives it
with the medium's mean albedo, every power divided by it (the flight's weight already holds
the albedo).

The associated photons share the leading photon's flights: one that lands within r_s of the
leading photon is attenuated by the leading photon's path, not its own, a blur of the
transmittance at the scale r_s that vanishes with r_s as the passes shrink it.
``--specular split`` is not supported in media.  Stream i is a pure function of
(seed, stream tag, i): the same records for any thread count.
"""
from __future__ import annotations

from ..bsdf import scattering_side
from ..emitters import choose_light
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..media import cross_null, free_flight, medium_after, photon_scatter
from ..sampling.rng import uniform, path_key
from ..sampling.warps import square_to_uniform_disk
from ..scene.description import DIFFUSE, NULL
from .emission import emit_photon
from .records import CAUSTIC, INDIRECT, VOLUME_CAUSTIC, VOLUME_INDIRECT
from .streams import associated_decay, place_associated, store_stream_record
from .trace import SPECULAR_CAP, TERMINATION_ROULETTE, diffuse_bounce, specular_scatter

#: What a stream does at a scattering event in a medium (``pspm --medium-scattering``).
MEDIUM_SCATTERING = ("merge", "spread")


@kernel
def spread_in_medium(geom, o, x_lead, d_lead, r_s, key, dim, n_alive, store, rec, assoc_pos, assoc_dir, assoc_nrm,
                     n_assoc):
    """Place the stream's associated photons about a medium event at x_lead; returns how many were placed.

    Photon j takes a point q of the disc of radius r_s about x_lead across d_lead (numbers
    key, dim + 2j and dim + 2j + 1); it is placed there, travelling along q - o, when the segment
    from o to q meets no surface (null boundaries included: beyond one is another medium), and
    written to assoc slot rec * n_assoc + (its rank) when ``store``.  The others merge.
    """
    s, t = vec.orthonormal_basis(d_lead)
    placed = 0
    for j in range(n_alive):
        u, v = square_to_uniform_disk(uniform(key, dim + 2 * j), uniform(key, dim + 2 * j + 1))
        q = vec.madd(vec.madd(x_lead, s, u * r_s), t, v * r_s)
        to_q = vec.sub(q, o)
        dist = vec.length(to_q)
        if not dist > 0.0:
            continue
        d = vec.mul(to_q, 1.0 / dist)
        prim, _, _, _ = intersect(geom, o, d, dist)
        if prim >= 0:
            continue  # a surface between: merged into the leading photon
        if store:
            a = rec * n_assoc + placed
            for c in range(3):
                assoc_pos[a, c] = q[c]
                assoc_dir[a, c] = d[c]
                assoc_nrm[a, c] = 0.0  # a volume photon has no normal
        placed += 1
    return placed


@kernel
def trace_streams_media(geom, mats, lights, media, light_medium, seed, stream, n_streams, n_assoc, r_s, max_bounces,
                        termination, spread, rec_pos, rec_dir, rec_nrm, rec_lead_power, rec_assoc_power, rec_energy,
                        rec_count, rec_valid, assoc_pos, assoc_dir, assoc_nrm, split_pos, split_dir, split_pow,
                        split_nrm, split_kind, i0, i1):
    """Emit and trace streams [i0, i1) through media; stream i owns records [i * (mr + 1), (i + 1) * (mr + 1)).

    ``spread``: associated photons spread about a medium scattering event (else they merge).
    The split buffers are unused (empty): ``--specular split`` is refused in media.
    """
    geom, mats, lights, media = borrowed(geom), borrowed(mats), borrowed(lights), borrowed(media)
    slots = max_bounces + 1
    share = 1.0 / (n_assoc + 1)
    zero = (0.0, 0.0, 0.0)
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, e_s, n_from = emit_photon(geom, lights, key, n_streams)      # eq. 1: E_s = E_z / n_fs
        li, _, _ = choose_light(lights, uniform(key, 0))                   # the light emit_photon chose
        medium = light_medium[li]
        lead = vec.mul(e_s, share)
        p_assoc = vec.mul(e_s, share)
        n_alive = n_assoc
        dim = 8
        bounces = 0           # diffuse and medium scattering events
        specular_events = 0
        scattered = False     # any event so far: what is stored from now on is not direct light
        diffuse_like = False  # a diffuse or medium event so far: records are (VOLUME_)INDIRECT
        crossings = 0
        stored = 0
        while True:
            prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
            if escaped:
                break
            if medium >= 0:
                if w[0] == 0.0 and w[1] == 0.0 and w[2] == 0.0:
                    break
                lead = vec.hadamard(lead, w)
                p_assoc = vec.hadamard(p_assoc, w)
            if prim < 0:
                # ---- a scattering event in the medium
                x = vec.madd(o, d, t)
                rec = i * slots + stored
                store = scattered and stored < slots
                landed = 0
                if spread and n_alive > 0:
                    landed = spread_in_medium(geom, o, x, d, r_s, key, dim, n_alive, store, rec,
                                              assoc_pos, assoc_dir, assoc_nrm, n_assoc)
                dim += 2 * n_assoc
                lead = vec.madd(lead, p_assoc, float(n_alive - landed))   # the ones not placed merge
                n_alive = landed
                if store:
                    store_stream_record(rec, x, d, zero, lead, p_assoc, landed,
                                        VOLUME_INDIRECT if diffuse_like else VOLUME_CAUSTIC, rec_pos, rec_dir,
                                        rec_nrm, rec_lead_power, rec_assoc_power, rec_energy, rec_count, rec_valid)
                    stored += 1
                if bounces >= max_bounces:
                    break
                alive, inv_q, wo, weight = photon_scatter(media, medium, d, key, dim,
                                                          termination == TERMINATION_ROULETTE)
                dim += 3
                if not alive:
                    break
                if termination == TERMINATION_ROULETTE:
                    lead = vec.mul(lead, inv_q)
                    p_assoc = vec.mul(p_assoc, inv_q)
                lead = vec.mul(lead, weight)
                p_assoc = vec.mul(p_assoc, weight)
                o = x
                d = wo
                n_from = zero     # a point in a medium: no surface the associated photons could aim into
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
                n_from = zero
                continue
            crossings = 0
            ng_front = ng
            if kind != DIFFUSE:
                # mirror or glass: merge every associated photon into the leading one
                lead = vec.madd(lead, p_assoc, float(n_alive))
                n_alive = 0
                specular_events += 1
                if specular_events > SPECULAR_CAP:
                    break
                d_new, lead, alive, ng_out = specular_scatter(mats, m, d, ng, ns, lead, front, uniform(key, dim))
                dim += 1
                if not alive:
                    break
                medium = medium_after(media, shape, ng_front, d_new, medium)
                o = vec.offset_origin(p, ng_out, d_new)
                n_from = zero
                d = d_new
                scattered = True
                continue
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                break  # absorbed by the black back of a one-sided surface
            rec = i * slots + stored
            store = scattered and stored < slots
            landed, _ = place_associated(
                geom, mats, o, n_from, p, d, r_s, key, dim, n_alive, p_assoc, store, rec,
                assoc_pos, assoc_dir, assoc_nrm, n_assoc, False, (0, 0, 0, False, 0),
                split_pos, split_dir, split_pow, split_nrm, split_kind)
            dim += 2 * n_assoc
            lead = vec.madd(lead, p_assoc, float(n_alive - landed))   # the ones that did not land merge
            n_alive = landed
            if store:
                store_stream_record(rec, p, d, ns, lead, p_assoc, landed, INDIRECT if diffuse_like else CAUSTIC,
                                    rec_pos, rec_dir, rec_nrm, rec_lead_power, rec_assoc_power, rec_energy,
                                    rec_count, rec_valid)
                stored += 1
            if bounces >= max_bounces:
                break
            # stream decay
            d_new, lead, alive = diffuse_bounce(mats, m, ng, ns, lead, key, dim, termination)
            dim += 3
            if not alive:
                break
            n_alive, p_assoc = associated_decay(mats, m, key, dim, n_alive, p_assoc, termination)
            dim += n_assoc
            bounces += 1
            diffuse_like = True
            medium = medium_after(media, shape, ng_front, d_new, medium)
            o = vec.offset_origin(p, ng, d_new)
            n_from = ng
            d = d_new
            scattered = True
