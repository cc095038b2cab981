"""Tracing streams for streamed photon mapping (SPEC §4), and the stream map they leave.

A *stream* is a leading photon plus up to n_fa associated photons.

1. Emission: a stream starts at a point on a light with a direction from the
   light's emission; its power is E_s = E_z / n_fs (eq. 1; E_z the light's power,
   chosen in proportion to power), split equally among its n_fa + 1 photons.
2. The leading photon is traced.  At a mirror or glass surface every associated
   photon is *merged* into the leading photon (its power is added; it ceases to
   exist) and the leading photon reflects or refracts (Fresnel).  This is what
   concentrates caustic energy.
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
     roulette once, with the leading photon (survival p = mean albedo, every power
     scaled by albedo / p), which keeps the expected power right.
   - after mr diffuse bounces the stream ends.
4. Only leading photons go into the kd-tree (:class:`StreamMap`); the ``photons``
   view counts every photon at its own position.

All associated photons of a stream share one power value at any moment (they
start equal and decay by the same factor), so the tracer carries a count and a
power rather than one power per photon.  Stream i is a pure function of
(seed, stream tag, i): the map is the same for any thread count.
"""
from __future__ import annotations

import numpy as np

from ..bsdf import scattering_side
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..sampling.rng import path_key, uniform
from ..sampling.warps import square_to_uniform_disk
from ..scene.description import DIFFUSE
from .emission import emit_photon
from .records import CAUSTIC, INDIRECT, VOLUME_CAUSTIC, VOLUME_INDIRECT, build_photon_map, build_photon_map_with_order
from .trace import SPECULAR_CAP, TERMINATION_ROULETTE, diffuse_bounce, specular_scatter

#: Sub-stream of a stream's key for its split associated photons (one key per chain and photon).
SPLIT_TAG = 1


@kernel
def split_off(geom, mats, key, o, d, power, scattered, slot, split_pos, split_dir, split_pow, split_nrm,
              split_valid):
    """An associated photon that keeps its own path through mirrors and glass (``--specular split``).

    It follows its own specular chain (Fresnel per photon, numbers from its own key) to
    the diffuse surface it lands on, is stored there in split slot ``slot`` (unless it is
    direct light), and decays there like an associated photon: it survives with
    p = mean albedo, its power scaled by albedo / p.
    Returns (kept, survived, power): not kept when it escapes or is absorbed (the
    caller merges it into the leading photon, as SPEC §4 does with a miss).
    """
    n_spec = 0
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, 1e30)
        if prim < 0:
            return False, False, power
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        m = geom.prim_material[prim]
        if mats.kind[m] == DIFFUSE:
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                return False, False, power
            if scattered or n_spec > 0:
                for c in range(3):
                    split_pos[slot, c] = p[c]
                    split_dir[slot, c] = d[c]
                    split_pow[slot, c] = power[c]
                    split_nrm[slot, c] = ns[c]
                split_valid[slot] = 1
            q = mats.albedo_mean[m]
            if q > 0.0 and uniform(key, 2) < q:
                return True, True, vec.mul(vec.hadamard(power, vec.row(mats.rgb, m)), 1.0 / q)
            return True, False, power
        n_spec += 1
        if n_spec > SPECULAR_CAP:
            return False, False, power
        d_new, power, alive, ng_out = specular_scatter(mats, m, d, ng, ns, power, front, uniform(key, 2 + n_spec))
        if not alive:
            return False, False, power
        o = vec.offset_origin(p, ng_out, d_new)
        d = d_new


@kernel(inline=True)
def associated_decay(mats, m, key, dim, n_alive, p_assoc, termination):
    """The associated photons after a diffuse bounce on material m: (how many survive, their power).

    Each survives with p = mean albedo, its power scaled by albedo / p (numbers key, dim + j).
    With roulette the leading photon has already survived with probability p, and the stream
    lives or dies with it: a second, per-photon roulette would leave the associated photons
    alive with probability p^2 while compensating only 1 / p, so they all survive, scaled.
    """
    q = mats.albedo_mean[m]
    if termination == TERMINATION_ROULETTE:
        survivors = n_alive
    else:
        survivors = 0
        for j in range(n_alive):
            if uniform(key, dim + j) < q:
                survivors += 1
    if q > 0.0:
        p_assoc = vec.mul(vec.hadamard(p_assoc, vec.row(mats.rgb, m)), 1.0 / q)
    return survivors, p_assoc


@kernel(inline=True)
def store_stream_record(rec, p, d, n, lead, p_assoc, landed, kind, rec_pos, rec_dir, rec_nrm, rec_lead_power,
                        rec_assoc_power, rec_energy, rec_count, rec_valid):
    """Write one stream record: leading photon (position, direction, normal, power), the associated photons' power."""
    for c in range(3):
        rec_pos[rec, c] = p[c]
        rec_dir[rec, c] = d[c]
        rec_nrm[rec, c] = n[c]
        rec_lead_power[rec, c] = lead[c]
        rec_assoc_power[rec, c] = p_assoc[c]
        rec_energy[rec, c] = lead[c] + landed * p_assoc[c]
    rec_count[rec] = landed
    rec_valid[rec] = kind


@kernel
def place_associated(geom, mats, o, n_from, x_lead, d_lead, r_s, key, dim, n_alive, p_assoc, store, rec,
                     assoc_pos, assoc_dir, assoc_nrm, n_assoc, split, split_row, scattered,
                     split_pos, split_dir, split_pow, split_nrm, split_valid):
    """Trace the stream's associated photons from o towards the disc about x_lead.

    Returns (landed, split off, split survivors, their power): ``landed`` photons met a
    diffuse surface and are written to assoc slots [rec * n_assoc, ...) when ``store``;
    the rest merge into the leading photon — except, with ``split``, those whose ray
    meets a mirror or glass, which follow their own path (:func:`split_off`, split slot
    row ``split_row``).  ``n_from`` is the normal of the surface o lies on, facing the
    side the stream leaves by (zero for a point light): a photon whose direction q - o
    points into that surface cannot leave it and is merged (before this check such rays
    met the surface again at t ~ 1e-4 and landed where the stream left from).
    """
    s, t = vec.orthonormal_basis(d_lead)
    check_side = vec.dot(n_from, n_from) > 0.5
    landed = 0
    n_split = 0
    survivors = 0
    survivor_power = (0.0, 0.0, 0.0)
    for j in range(n_alive):
        u, v = square_to_uniform_disk(uniform(key, dim + 2 * j), uniform(key, dim + 2 * j + 1))
        q = vec.madd(vec.madd(x_lead, s, u * r_s), t, v * r_s)
        d = vec.normalize(vec.sub(q, o))
        if check_side and vec.dot(d, n_from) <= 0.0:
            continue  # into the surface it leaves: merged
        prim, th, b1, b2 = intersect(geom, o, d, 1e30)
        if prim < 0:
            continue  # escaped: merged into the leading photon
        m = geom.prim_material[prim]
        if mats.kind[m] != DIFFUSE:
            if split:
                kj = path_key(key, SPLIT_TAG, split_row * n_assoc + j)
                kept, alive, pw = split_off(geom, mats, kj, o, d, p_assoc, scattered, split_row * n_assoc + j,
                                            split_pos, split_dir, split_pow, split_nrm, split_valid)
                if kept:
                    n_split += 1
                    if alive:
                        survivors += 1
                        survivor_power = vec.add(survivor_power, pw)
            continue  # met a mirror or glass: merged (or split off)
        p, ng, ns = surface_at(geom, prim, o, d, th, b1, b2)
        if vec.dot(d, ng) >= 0.0:
            if mats.twosided[m] == 0:
                continue  # the black back of a one-sided surface: merged
            ns = vec.neg(ns)
        if store:
            a = rec * n_assoc + landed
            for c in range(3):
                assoc_pos[a, c] = p[c]
                assoc_dir[a, c] = d[c]
                assoc_nrm[a, c] = ns[c]
        landed += 1
    return landed, n_split, survivors, survivor_power


@kernel
def trace_streams(geom, mats, lights, seed, stream, n_streams, n_assoc, r_s, max_bounces, termination, split,
                  rec_pos, rec_dir, rec_nrm, rec_lead_power, rec_assoc_power, rec_energy, rec_count,
                  rec_valid, assoc_pos, assoc_dir, assoc_nrm, split_pos, split_dir, split_pow, split_nrm,
                  split_valid, i0, i1):
    """Emit and trace streams [i0, i1) of n_streams; stream i owns records [i * (mr + 1), (i + 1) * (mr + 1)).

    ``split`` (``--specular split``): associated photons do not merge at mirrors and
    glass.  At the leading photon's first mirror or glass of a specular chain each
    associated photon is aimed from o through a point of the disc of radius r_s about
    the hit (as at a diffuse hit); at a diffuse hit, those whose ray meets a mirror or
    glass go on too.  Each follows its own specular path and is stored where it lands
    as a photon of its own (:func:`split_off`; the stream's split slot rows
    [i * SPLIT_ROWS(mr), ...)), decays there, and the survivors rejoin the stream after
    the leading photon's next diffuse bounce, their powers pooled (the stream's
    associated photons share one power).  What the split photons deposit where they land
    is kept in expectation; their later bounces start from the leading photon's path
    and end with it (when the leading photon escapes or is absorbed first, they are lost).
    """
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    slots = max_bounces + 1
    rows = 2 * slots
    share = 1.0 / (n_assoc + 1)
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, e_s, n_from = emit_photon(geom, lights, key, n_streams)      # eq. 1: E_s = E_z / n_fs
        lead = vec.mul(e_s, share)
        p_assoc = vec.mul(e_s, share)
        n_alive = n_assoc
        dim = 8
        diffuse_bounces = 0
        specular_events = 0
        scattered = False
        stored = 0
        split_rows = 0
        pending = 0
        pending_power = (0.0, 0.0, 0.0)
        while True:
            prim, t, b1, b2 = intersect(geom, o, d, 1e30)
            if prim < 0:
                break
            p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
            front = vec.dot(d, ng) < 0.0
            m = geom.prim_material[prim]
            if mats.kind[m] != DIFFUSE:
                if split and n_alive > 0 and split_rows < rows:
                    # each associated photon takes its own path through the specular chain
                    row = i * rows + split_rows
                    s_ax, t_ax = vec.orthonormal_basis(d)
                    check_side = vec.dot(n_from, n_from) > 0.5
                    for j in range(n_alive):
                        kj = path_key(key, SPLIT_TAG, row * n_assoc + j)
                        u, v = square_to_uniform_disk(uniform(kj, 0), uniform(kj, 1))
                        q = vec.madd(vec.madd(p, s_ax, u * r_s), t_ax, v * r_s)
                        dj = vec.normalize(vec.sub(q, o))
                        kept = False
                        if not check_side or vec.dot(dj, n_from) > 0.0:
                            kept, alive_j, pw = split_off(geom, mats, kj, o, dj, p_assoc, scattered,
                                                          row * n_assoc + j, split_pos, split_dir, split_pow,
                                                          split_nrm, split_valid)
                            if kept and alive_j:
                                pending += 1
                                pending_power = vec.add(pending_power, pw)
                        if not kept:
                            lead = vec.add(lead, p_assoc)  # aimed into its surface, escaped or absorbed: merged
                    n_alive = 0
                    split_rows += 1
                # mirror or glass: merge every associated photon (left) into the leading one
                lead = vec.madd(lead, p_assoc, float(n_alive))
                n_alive = 0
                specular_events += 1
                if specular_events > SPECULAR_CAP:
                    break
                d_new, lead, alive, ng_out = specular_scatter(mats, m, d, ng, ns, lead, front, uniform(key, dim))
                dim += 1
                if not alive:
                    break
                o = vec.offset_origin(p, ng_out, d_new)
                n_from = (0.0, 0.0, 0.0)  # associated photons are placed from here only after a split
                d = d_new
                scattered = True
                continue
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                break  # absorbed by the black back of a one-sided surface
            rec = i * slots + stored
            use_row = split and n_alive > 0 and split_rows < rows
            landed, n_split, surv, surv_power = place_associated(
                geom, mats, o, n_from, p, d, r_s, key, dim, n_alive, p_assoc, scattered, rec,
                assoc_pos, assoc_dir, assoc_nrm, n_assoc, use_row, i * rows + split_rows, scattered,
                split_pos, split_dir, split_pow, split_nrm, split_valid)
            if use_row:
                split_rows += 1
            dim += 2 * n_assoc
            lead = vec.madd(lead, p_assoc, float(n_alive - landed - n_split))   # the ones that did not land merge
            n_alive = landed
            pending += surv
            pending_power = vec.add(pending_power, surv_power)
            if scattered:  # a stream record (direct light is not stored)
                # CAUSTIC: a light -> specular+ -> diffuse record (no diffuse bounce before it), the
                # caustic that aimed caustic photons may carry instead (pspm --caustic-photons)
                store_stream_record(rec, p, d, ns, lead, p_assoc, landed,
                                    CAUSTIC if diffuse_bounces == 0 else INDIRECT, rec_pos, rec_dir, rec_nrm,
                                    rec_lead_power, rec_assoc_power, rec_energy, rec_count, rec_valid)
                stored += 1
            if diffuse_bounces >= max_bounces:
                break
            # stream decay
            d_new, lead, alive = diffuse_bounce(mats, m, ng, ns, lead, key, dim, termination)
            dim += 3
            if not alive:
                break
            q = mats.albedo_mean[m]
            n_alive, p_assoc = associated_decay(mats, m, key, dim, n_alive, p_assoc, termination)
            dim += n_assoc
            if pending > 0:
                # split photons that survived their own landing rejoin the stream, powers pooled;
                # with roulette they rejoin only if the leading photon survived (probability q)
                if termination == TERMINATION_ROULETTE and q > 0.0:
                    pending_power = vec.mul(pending_power, 1.0 / q)
                total = vec.add(vec.mul(p_assoc, float(n_alive)), pending_power)
                n_alive += pending
                p_assoc = vec.mul(total, 1.0 / n_alive)
                pending = 0
                pending_power = (0.0, 0.0, 0.0)
            diffuse_bounces += 1
            o = vec.offset_origin(p, ng, d_new)
            n_from = ng
            d = d_new
            scattered = True


class StreamBuffers:
    """Fixed record and associated-photon slots of the stream tracer (float32)."""

    def __init__(self, n_streams, n_assoc, max_bounces, split=False):
        s = n_streams * (max_bounces + 1)
        a = s * n_assoc
        f = np.float32
        self.rec = (np.zeros((s, 3), f), np.zeros((s, 3), f), np.zeros((s, 3), f), np.zeros((s, 3), f),
                    np.zeros((s, 3), f), np.zeros((s, 3), f), np.zeros(s, np.int32), np.zeros(s, np.int8))
        self.assoc = (np.zeros((a, 3), f), np.zeros((a, 3), f), np.zeros((a, 3), f))
        b = 2 * a if split else 0   # split slot rows: two per bounce (a specular chain and a diffuse hit)
        self.split = (np.zeros((b, 3), f), np.zeros((b, 3), f), np.zeros((b, 3), f), np.zeros((b, 3), f),
                      np.zeros(b, np.int8))
        self.n_assoc = n_assoc

    @property
    def kernel_args(self) -> tuple:
        """The buffers in trace_streams' argument order."""
        return (*self.rec, *self.assoc, *self.split)

    @staticmethod
    def bytes_needed(n_streams, n_assoc, max_bounces, split=False):
        s = n_streams * (max_bounces + 1)
        return s * (6 * 12 + 5) + s * n_assoc * (36 + (2 * 49 if split else 0))

    def _records(self, estimator: str, keep: np.ndarray) -> list:
        """(position, direction, power, normal) parts of the records ``keep`` under ``estimator``.

        ``stream``: each record's energy E_i at its leading position (eq. 2's reading);
        ``photons``: the leading and every associated photon at its own position.
        """
        pos, dirs, nrm, lead_pow, assoc_pow, energy, count, _ = self.rec
        if estimator == "stream":
            return [(pos[keep], dirs[keep], energy[keep], nrm[keep])]
        parts = [(pos[keep], dirs[keep], lead_pow[keep], nrm[keep])]
        if self.n_assoc > 0:
            used = ((np.arange(self.n_assoc)[None, :] < count[:, None]) & keep[:, None]).reshape(-1)
            parts.append((self.assoc[0][used], self.assoc[1][used],
                          np.repeat(assoc_pow[keep], count[keep], axis=0), self.assoc[2][used]))
        return parts

    def events(self, estimator: str, leave_caustics: bool = False):
        """This pass's surface photon events (position, direction, power, normal) for a progressive gather.

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
        sp, sd, spow, sn, sv = self.split
        if sv.shape[0]:
            ok = sv == 1
            parts.append((sp[ok], sd[ok], spow[ok], sn[ok]))
        return tuple(np.concatenate([part[c] for part in parts]) for c in range(4))

    def volume_events(self, estimator: str, leave_caustics: bool = False):
        """This pass's volume photons (position, direction of travel, power), as :meth:`events` for surfaces.

        ``leave_caustics``: the light -> specular+ -> medium records are left out (kind VOLUME_CAUSTIC),
        as the aimed caustic photons carry them.
        """
        valid = self.rec[7]
        keep = (valid == VOLUME_INDIRECT) if leave_caustics else ((valid == VOLUME_INDIRECT) |
                                                                  (valid == VOLUME_CAUSTIC))
        parts = self._records(estimator, keep)
        return tuple(np.concatenate([part[c] for part in parts]) for c in range(3))


class StreamMap:
    """The stored stream records, compacted, with the kd-tree over leading photons."""

    def __init__(self, buf: StreamBuffers):
        self.volume = None   # (position, direction, power) of the volume photons, in a scene with media
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
        else:
            self.assoc_pos = self.assoc_dir = self.assoc_nrm = np.zeros((0, 3), np.float32)
        self.assoc_power = assoc_pow[keep]
        # The paper's map: leading positions in the kd-tree, each carrying its stream's energy E_i.
        # Its records are in kd-tree order; ``count`` and ``assoc_power`` stay in tracing
        # order, which the associated photons' flat arrays follow; ``order`` links the two.
        self.records, self.order = build_photon_map_with_order(pos[keep], dirs[keep], energy[keep], nrm[keep])
        self.lead_power = np.ascontiguousarray(lead_pow[keep][self.order])  # aligned with self.records

    @property
    def n_records(self) -> int:
        return self.records.count

    @property
    def n_associated(self) -> int:
        return int(self.assoc_pos.shape[0])

    def memory_bytes(self) -> int:
        """Stream records (leading photon + energy), associated photons and the kd-tree."""
        extra = sum(a.nbytes for a in (self.count, self.assoc_pos, self.assoc_dir, self.assoc_nrm,
                                       self.lead_power, self.assoc_power))  # ``order`` is bookkeeping only
        return self.records.memory_bytes() + extra

    def photon_map(self):
        """Every photon at its own position: leading photons and associated photons (the ``photons`` estimator)."""
        r = self.records
        assoc_power = np.repeat(self.assoc_power, self.count, axis=0)
        return build_photon_map(np.concatenate([r.position, self.assoc_pos]),
                                np.concatenate([r.direction, self.assoc_dir]),
                                np.concatenate([self.lead_power, assoc_power]),
                                np.concatenate([r.normal, self.assoc_nrm]))
