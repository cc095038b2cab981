"""Tracing photons through the scene for photon mapping (PM and its caustic map).

Each photon i is a pure function of (seed, pass, i): parallel tracing writes into
its own fixed slots, so the maps are identical for any thread count.  At every
diffuse hit after the first scattering event a record is stored (SPEC §2: no
direct-light photons), tagged CAUSTIC when every earlier scattering was specular
(light -> S+ -> D) and INDIRECT otherwise.  ``max_bounces`` (mr) counts diffuse
bounces; mirrors and glass have their own cap (:data:`SPECULAR_CAP`).
"""
from __future__ import annotations

from ..bsdf import mirror_reflect, sample_dielectric, scattering_side
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..sampling.rng import path_key, uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import CONDUCTOR, DIFFUSE
from .emission import emit_caustic_photon, emit_photon
from .records import CAUSTIC, INDIRECT

SPECULAR_CAP = 64
TERMINATION_CAP = 0       # scale power by the albedo, stop after mr diffuse bounces (the paper)
TERMINATION_ROULETTE = 1  # survive with probability mean albedo, power scaled by albedo / p


@kernel(inline=True)
def store_record(s, p, d, power, n, kind, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind):
    """Write one photon record (position, direction of travel, power, normal, kind) into slot s."""
    for c in range(3):
        buf_pos[s, c] = p[c]
        buf_dir[s, c] = d[c]
        buf_pow[s, c] = power[c]
        buf_nrm[s, c] = n[c]
    buf_kind[s] = kind


@kernel
def diffuse_bounce(mats, m, ng, ns, power, key, dim, termination):
    """Continue a photon from a diffuse surface: (new direction, power, alive).

    ng, ns are oriented to the side the photon arrived from.
    """
    rgb = vec.row(mats.rgb, m)
    if termination == TERMINATION_ROULETTE:
        q = mats.albedo_mean[m]
        if uniform(key, dim + 2) >= q:
            return ng, power, False
        power = vec.mul(vec.hadamard(power, rgb), 1.0 / q)
    else:
        power = vec.hadamard(power, rgb)
    local = square_to_cosine_hemisphere(uniform(key, dim), uniform(key, dim + 1))
    s, t = vec.orthonormal_basis(ns)
    d = vec.from_local(s, t, ns, local)
    if vec.dot(d, ng) <= 0.0 or local[2] <= 0.0:
        return d, power, False
    return d, power, True


@kernel
def specular_scatter(mats, m, d, ng, ns, power, front, u):
    """Reflect or refract at a mirror or glass: (new direction, power, alive, geometric normal on the exit side)."""
    rgb = vec.row(mats.rgb, m)
    if mats.kind[m] == CONDUCTOR:
        scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
        if not scatters:
            return d, power, False, ng
        return mirror_reflect(d, ng, ns), vec.hadamard(power, rgb), True, ng
    wi, _, _ = sample_dielectric(d, ng, ns, mats.eta[m], u)
    return wi, vec.hadamard(power, rgb), True, ng


@kernel
def trace_one(geom, mats, key, o, d, power, diffuse_bounces, scattered, max_bounces, termination, caustic_only,
              slot0, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind):
    """Follow one photon, storing records in slots slot0, slot0 + 1, ...; returns records stored.

    A photon from a light starts with no diffuse bounce and not ``scattered``; a split photon of a
    stream (:mod:`caustica.photons.streams`) starts with its stream's.  Random numbers from 8 on.
    """
    dim = 8
    specular_events = 0
    stored = 0
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, 1e30)
        if prim < 0:
            break
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        m = geom.prim_material[prim]
        if mats.kind[m] == DIFFUSE:
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                break  # the black back of a one-sided surface absorbs
            if scattered:
                store_record(slot0 + stored, p, d, power, ns, CAUSTIC if diffuse_bounces == 0 else INDIRECT,
                             buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)
                stored += 1
            if caustic_only or diffuse_bounces >= max_bounces:
                break
            d, power, alive = diffuse_bounce(mats, m, ng, ns, power, key, dim, termination)
            dim += 3
            if not alive:
                break
            diffuse_bounces += 1
            o = vec.offset_origin(p, ng, d)
        else:
            specular_events += 1
            if specular_events > SPECULAR_CAP:
                break
            d_new, power, alive, ng_out = specular_scatter(mats, m, d, ng, ns, power, front, uniform(key, dim))
            dim += 1
            if not alive:
                break
            o = vec.offset_origin(p, ng_out, d_new)
            d = d_new
        scattered = True
    return stored


@kernel
def trace_photons(geom, mats, lights, seed, stream, n_paths, max_bounces, termination,
                  buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind, i0, i1):
    """Emit and trace photons [i0, i1) of n_paths; photon i writes slots [i * (mr + 1), (i + 1) * (mr + 1))."""
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    slots = max_bounces + 1
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, _ = emit_photon(geom, lights, key, n_paths)
        trace_one(geom, mats, key, o, d, power, 0, False, max_bounces, termination, False,
                  i * slots, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)


@kernel
def trace_caustic_photons(geom, mats, lights, spheres, seed, stream, n_paths,
                          buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind, i0, i1):
    """Caustic photons [i0, i1) aimed at the specular objects; only light -> S+ -> D records (one slot each)."""
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    for i in range(i0, i1):
        key = path_key(seed, stream, i)
        o, d, power, ok = emit_caustic_photon(geom, lights, spheres, key, n_paths)
        if ok:
            trace_one(geom, mats, key, o, d, power, 0, False, 0, TERMINATION_CAP, True,
                      i, buf_pos, buf_dir, buf_pow, buf_nrm, buf_kind)
