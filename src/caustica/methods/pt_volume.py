"""The path tracer's kernel for scenes with participating media (``pt`` on a scene that has them).

A volumetric path tracer after Mitsuba 3's ``volpath`` (docs/media.md):

* the current medium is tracked from the camera's through every boundary (a ray leaving
  a surface towards its front enters the shape's exterior medium, towards its back its
  interior; shapes without media leave it unchanged, :func:`caustica.media.medium_after`);
* in a medium, a free-flight distance is sampled (one channel chosen per flight, weighted
  by the mixture of the channels' densities, :func:`caustica.media.flight_weight`); if it
  ends before the next surface the path scatters there: next-event estimation with the
  phase function (MIS against phase sampling for area lights), then a phase-sampled
  direction;
* null-BSDF surfaces are crossed without scattering and without counting as a bounce
  (Mitsuba's depth), so a medium's boundary is invisible;
* surfaces scatter as in :func:`caustica.methods.pt.radiance`; next-event estimation from
  diffuse points and from medium points traces its shadow ray through null boundaries and
  media (exact transmittance, :func:`caustica.media.transmittance`); glass blocks it, as
  in Mitsuba;
* emission reached by BSDF or phase sampling is weighted by MIS with the light-sampling
  density from the last scattering point (past null surfaces), full weight after a
  specular (delta) bounce or from the camera.

``max_depth`` counts scattering events (surface and medium) as Mitsuba does; Russian
roulette starts after ``rr_depth`` of them.  Scenes without media never reach this
kernel (:func:`caustica.methods.pt.radiance` renders them, bit for bit as before).
"""
from __future__ import annotations

import math

import numpy as np

from ..bsdf import sample_surface, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel
from ..media import cross_null, direct_transmitted, flight_weight, medium_after, phase_pdf, \
    phase_sample, phase_value, power_heuristic, sample_distance
from ..sampling.rng import path_key, uniform
from ..scene.description import DIFFUSE, NULL

INV_PI = 1.0 / math.pi


@kernel(hot=True)
def radiance_media(geom, mats, lights, media, o, d, key, max_depth, rr_depth):
    """Radiance arriving at o from direction -d through media, estimated along one random path.

    The ray starts in the camera's medium.  Returns (L, extension rays, shadow rays).
    """
    zero = (0.0, 0.0, 0.0)
    n_ext = 0
    n_shadow = 0
    L = zero
    beta = (1.0, 1.0, 1.0)
    eta_scale = 1.0
    specular = True      # no scattering yet, or the last one was a delta: emission counts in full
    pdf_last = 0.0       # solid-angle density of the last scattering's sampled direction
    p_last = o           # where that scattering happened
    medium = media.camera[0]
    dim = 2
    depth = 0            # scattering events so far (Mitsuba's depth: null surfaces do not count)
    crossings = 0        # null surfaces crossed since the last scattering event
    while True:
        n_ext += 1
        t_flight = np.inf
        if medium >= 0:
            t_flight = sample_distance(media, medium, uniform(key, dim), uniform(key, dim + 1))
            dim += 2
        prim, t, b1, b2 = intersect(geom, o, d, t_flight)
        if prim < 0 and t_flight == np.inf:
            break        # escaped
        if medium >= 0:
            beta = vec.hadamard(beta, flight_weight(media, medium, t, prim < 0))
            if beta[0] == 0.0 and beta[1] == 0.0 and beta[2] == 0.0:
                break    # absorbed (albedo 0), or a flight no channel can take

        if prim < 0:
            # ---- a scattering event in the medium, at t = t_flight
            p = vec.madd(o, d, t)
            depth += 1
            if depth >= max_depth:
                break
            contrib, wi, pdf_light, is_area, ok, shadow = direct_transmitted(
                geom, mats, lights, media, p, zero, zero, zero, -1, medium, key, dim)
            n_shadow += shadow
            dim += 3
            if ok:
                w = 1.0
                if is_area:
                    w = power_heuristic(pdf_light, phase_pdf(media, medium, d, wi))
                L = vec.madd(L, vec.hadamard(beta, contrib), w * phase_value(media, medium, d, wi))
            wo, weight, pdf = phase_sample(media, medium, d, uniform(key, dim), uniform(key, dim + 1))
            dim += 2
            if not pdf > 0.0:
                break
            beta = vec.mul(beta, weight)
            o = p
            d = wo
            p_last = p
            pdf_last = pdf
            specular = False
            crossings = 0
        else:
            # ---- a surface
            p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
            front = vec.dot(d, ng) < 0.0
            e = geom.prim_emitter[prim]
            if e >= 0 and front:
                w = 1.0
                if not specular:
                    cos_l = -vec.dot(d, ng)
                    to_p = vec.sub(p, p_last)
                    pdf_light = lights.select_pdf[e] * vec.dot(to_p, to_p) / (lights.area[e] * cos_l)
                    w = power_heuristic(pdf_last, pdf_light)
                L = vec.madd(L, vec.hadamard(beta, vec.row(lights.radiance, e)), w)
            m = geom.prim_material[prim]
            kind = mats.kind[m]
            shape = geom.prim_shape[prim]
            if kind == NULL:
                medium, o, crossings, within = cross_null(media, shape, p, ng, d, medium, crossings)
                if not within:
                    break
                continue
            depth += 1
            if depth >= max_depth:
                break
            ng_front = ng
            rgb = vec.row(mats.rgb, m)
            scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
            if not scatters:
                break
            if kind == DIFFUSE:
                contrib, wi, pdf_light, is_area, ok, shadow = direct_transmitted(
                    geom, mats, lights, media, p, ng, ns, ng_front, shape, medium, key, dim)
                n_shadow += shadow
                dim += 3
                if ok:
                    cos_s = vec.dot(ns, wi)
                    w = 1.0
                    if is_area:
                        w = power_heuristic(pdf_light, cos_s * INV_PI)
                    L = vec.madd(L, vec.hadamard(beta, vec.hadamard(rgb, contrib)), w * cos_s * INV_PI)
            alive, wi, beta, eta_scale, pdf, specular, dim = sample_surface(kind, rgb, mats.eta[m], d, ng, ns,
                                                                            key, dim, beta, eta_scale)
            if not alive:
                break
            if not specular:
                pdf_last = pdf
            medium = medium_after(media, shape, ng_front, wi, medium)
            p_last = p
            crossings = 0
            o = vec.offset_origin(p, ng, wi)
            d = wi
        if depth >= rr_depth:
            q = min(vec.max_component(beta) * eta_scale, 0.95)
            if uniform(key, dim) >= q:
                break
            dim += 1
            beta = vec.mul(beta, 1.0 / q)
    return L, n_ext, n_shadow


@kernel
def render_pixels_media(geom, mats, lights, media, cam, seed, stream, spp, max_depth, rr_depth, image, rays,
                        i0, i1):
    """:func:`caustica.methods.pt.render_pixels` for a scene with media: the same samples and keys."""
    geom, mats, lights, media = borrowed(geom), borrowed(mats), borrowed(lights), borrowed(media)
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        acc = (0.0, 0.0, 0.0)
        for s in range(spp):
            key = path_key(seed, stream, (y * width + x) * spp + s)
            o, d = generate_ray(cam, x, y, uniform(key, 0), uniform(key, 1))
            L, n_ext, n_shadow = radiance_media(geom, mats, lights, media, o, d, key, max_depth, rr_depth)
            rays[i, 0] += n_ext
            rays[i, 1] += n_shadow
            if math.isfinite(L[0] + L[1] + L[2]):
                acc = vec.add(acc, L)
        inv = 1.0 / spp
        image[y, x, 0] = acc[0] * inv
        image[y, x, 1] = acc[1] * inv
        image[y, x, 2] = acc[2] * inv
