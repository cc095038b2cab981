"""The progressive camera pass in a scene with participating media (sppm; docs/media.md).

The pass of :mod:`caustica.photons.visible_points` — one camera ray per pixel through a
jittered (Sobol') position, followed through mirrors and glass to its first diffuse point —
with three additions:

* **Attenuation.**  The camera path tracks the medium it is in (the camera's, then
  :func:`caustica.media.medium_after` at every surface it leaves) and crosses null
  boundaries without scattering.  It samples no free flights: over each medium segment its
  throughput β is multiplied by the exact transmittance exp(−σt s) (homogeneous media), so the
  visible point's weight W = β ρ / π and every emitter the path sees are attenuated exactly.
* **Segments.**  Each medium segment of the path (origin, direction, length, medium, β at its
  origin) is written out for the volume radiance estimate (:mod:`caustica.photons.beams`).  A
  path has room for :data:`MEDIUM_SEGMENTS` of them; one that would need more ends there, as a
  path ends after ``max_specular`` mirror or glass bounces.
* **Direct light scattered along a segment** (single scattering of the lights' own light) is
  estimated here, not by photons — as direct light at surfaces is (SPEC §2): one distance per
  segment per pass, drawn within the segment (:func:`caustica.media.sample_distance_within`,
  weight T σs / pdf); from it one light sample through media and null boundaries
  (:func:`caustica.media.direct_transmitted_u`, exact transmittance) and one phase-function sample
  that counts the emitter it sees, combined by MIS (:func:`segment_inscatter`).  Unbiased, two rays
  per segment.  On the first segment (the camera's own ray, usually the longest), the distance and
  the point on the light are points ``pass`` of randomly shifted Kronecker sequences, as the
  surface's shadow rays are (visible_points.py): each pass alone is still an unbiased sample, and
  a pixel's passes cover the segment and the light evenly.

Direct light at the visible point is :func:`caustica.media.direct_stratified_transmitted`:
the same strata and Kronecker jitter as without media, each shadow ray weighted by its
transmittance.  Random numbers: the camera pass's own keys and dimensions for the path;
the segments' next-event estimates draw from a stream of their own (``STREAM_CAMERA_MEDIA``,
seven numbers per segment; the first segment's stratified numbers are shifted by numbers
QMC_SEGMENT_DIM .. + 2 of the scramble key), so a scene's media never shift the numbers of anything else.
"""
from __future__ import annotations

import math

import numpy as np

from ..bsdf import dielectric_branches, mirror_reflect, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel, parallel_for
from ..media import NULL_CROSSINGS_CAP, cross_null, attenuation, direct_stratified_transmitted, direct_transmitted_u, \
    medium_after, phase_pdf, phase_sample, phase_value, power_heuristic, sample_distance_within, within_weight
from ..memory import check_budget
from ..sampling.rng import KRONECKER_ALPHA, STREAM_CAMERA, STREAM_CAMERA_MEDIA, STREAM_CAMERA_SCRAMBLE, kronecker, \
    pass_stream, path_key, sobol02, uniform
from ..scene.description import CONDUCTOR, DIFFUSE, NULL
from .visible_points import glass_branch_number, glass_step

INV_PI = 1.0 / math.pi

#: Medium segments a camera path may have (room for them is allocated per pixel); a path that
#: would need more ends, as at the specular depth cap.
MEDIUM_SEGMENTS = 8
#: The per-pixel shifts (numbers of the camera pass's scramble key) of the Kronecker points that stratify the
#: first segment's next-event estimate over the passes; the surface's own numbers of that key are 0 .. 3 + 2 n²,
#: with n = --light-samples at most 64 (ESTIMATE_PARAMS), so these start past 3 + 2 * 64².
QMC_SEGMENT_DIM = 3 + 2 * 64 * 64 + 1
#: Bytes per pixel of the segment arrays (origin, direction, β: 3 float64 each; length; medium; count).
SEGMENT_BYTES = MEDIUM_SEGMENTS * (9 * 8 + 8 + 4) + 4


@kernel
def emission_weighted(geom, mats, lights, media, o, d, medium, pdf_dir):
    """Emission reaching o from along d (past null boundaries, attenuated), each emitter weighted by MIS.

    d was sampled with solid-angle density pdf_dir (the phase function); an area emitter met at
    distance r with cosine cos_l is weighted by the power heuristic against light sampling's density
    select_pdf r² / (area cos_l), as :func:`caustica.media.direct_transmitted_u` samples it.
    pdf_dir < 0: no MIS (weight 1).  Emitters on null surfaces crossed count, as in the path
    tracer; the first other surface ends the ray (its emission counts if it is an emitter's front).
    """
    L = (0.0, 0.0, 0.0)
    T = (1.0, 1.0, 1.0)
    dist = 0.0
    for _ in range(NULL_CROSSINGS_CAP):
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            return L
        if medium >= 0:
            T = vec.hadamard(T, attenuation(media, medium, t))
        dist += t
        p, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        e = geom.prim_emitter[prim]
        cos_l = -vec.dot(d, ng)
        if e >= 0 and cos_l > 0.0:
            w = 1.0
            if pdf_dir >= 0.0:
                pdf_light = lights.select_pdf[e] * dist * dist / (lights.area[e] * cos_l)
                w = power_heuristic(pdf_dir, pdf_light)
            L = vec.madd(L, vec.hadamard(T, vec.row(lights.radiance, e)), w)
        if mats.kind[geom.prim_material[prim]] != NULL:
            return L
        medium = medium_after(media, geom.prim_shape[prim], ng, d, medium)
        o = vec.offset_origin(p, ng, d)
    return L


@kernel
def emitted_along_media(geom, mats, lights, media, o, d, medium):
    """The radiance reaching o from along d from emitters, attenuated by the media and past null boundaries."""
    return emission_weighted(geom, mats, lights, media, o, d, medium, -1.0)


@kernel
def segment_inscatter(geom, mats, lights, media, o, d, s, m, beta, u_channel, u_dist, u_light, u1, u2, u_ph1, u_ph2):
    """β times one estimate of the direct light scattered towards o along the segment (o, d, s) in m.

    One distance (u_channel, u_dist: :func:`caustica.media.sample_distance_within`); from there one
    light sample (u_light chooses the light, (u1, u2) the point on it) and one phase-function sample
    (u_ph1, u_ph2) that counts the emitter it sees, combined by MIS (power heuristic) for area
    lights.  Light sampling alone has unbounded variance where a segment passes close to an area
    light (its value grows as 1 / distance²); the phase sample takes over there.
    """
    zero = (0.0, 0.0, 0.0)
    t = sample_distance_within(media, m, s, u_channel, u_dist)
    w = within_weight(media, m, s, t)
    if w[0] == 0.0 and w[1] == 0.0 and w[2] == 0.0:
        return zero
    p = vec.madd(o, d, t)
    bw = vec.hadamard(beta, w)
    L = zero
    contrib, wi, pdf_light, is_area, ok, _ = direct_transmitted_u(geom, mats, lights, media, p, zero, zero, zero,
                                                                  -1, m, u_light, u1, u2)
    if ok:
        mis = power_heuristic(pdf_light, phase_pdf(media, m, d, wi)) if is_area else 1.0
        L = vec.mul(vec.hadamard(bw, contrib), mis * phase_value(media, m, d, wi))
    wo, weight, pdf = phase_sample(media, m, d, u_ph1, u_ph2)
    if pdf > 0.0:
        Le = emission_weighted(geom, mats, lights, media, p, wo, m, pdf)
        L = vec.add(L, vec.mul(vec.hadamard(bw, Le), weight))
    return L


@kernel(inline=True)
def first_segment_numbers(pass_index, qkey):
    """(distance, light u1, u2) numbers of a camera path's first medium segment: pass ``pass_index`` of
    Kronecker sequences with generators of their own (KRONECKER_ALPHA[3:6]), jointly uniform with the
    glass branch's and the light strata's over the passes."""
    return (kronecker(pass_index, KRONECKER_ALPHA[3], uniform(qkey, QMC_SEGMENT_DIM)),
            kronecker(pass_index, KRONECKER_ALPHA[4], uniform(qkey, QMC_SEGMENT_DIM + 1)),
            kronecker(pass_index, KRONECKER_ALPHA[5], uniform(qkey, QMC_SEGMENT_DIM + 2)))


@kernel
def visible_point_media(geom, mats, lights, media, o, d, key, qkey, vkey, pass_index, n_strata, max_specular,
                        seg_o, seg_d, seg_len, seg_beta, seg_medium, slot0):
    """Follow a camera ray through media to its visible point: (found, position, normal, W, L_direct, segments).

    The segments are written to slots slot0, slot0 + 1, ... of the seg_* arrays.
    """
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    zero = (0.0, 0.0, 0.0)
    dim = 2
    depth = 0
    first_glass = True
    counted = False   # the next surface's emission was already added, in expectation, at the glass before it
    medium = media.camera[0]
    n_seg = 0
    crossings = 0
    while True:
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if medium >= 0:
            if n_seg >= MEDIUM_SEGMENTS:
                return False, zero, zero, zero, L, n_seg
            s = t if prim >= 0 else np.inf
            k = slot0 + n_seg
            for c in range(3):
                seg_o[k, c] = o[c]
                seg_d[k, c] = d[c]
                seg_beta[k, c] = beta[c]
            seg_len[k] = s
            seg_medium[k] = medium
            vd = 7 * n_seg
            u_dist = uniform(vkey, vd + 1)
            u1 = uniform(vkey, vd + 3)
            u2 = uniform(vkey, vd + 4)
            if n_seg == 0:   # the first segment's distance and light point: stratified over the passes
                u_dist, u1, u2 = first_segment_numbers(pass_index, qkey)
            L = vec.add(L, segment_inscatter(geom, mats, lights, media, o, d, min(s, 1e30), medium, beta,
                                             uniform(vkey, vd), u_dist, uniform(vkey, vd + 2), u1, u2,
                                             uniform(vkey, vd + 5), uniform(vkey, vd + 6)))
            n_seg += 1
            if prim < 0:
                return False, zero, zero, zero, L, n_seg
            beta = vec.hadamard(beta, attenuation(media, medium, t))
        if prim < 0:
            return False, zero, zero, zero, L, n_seg
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        e = geom.prim_emitter[prim]
        if e >= 0 and front and not counted:
            L = vec.add(L, vec.hadamard(beta, vec.row(lights.radiance, e)))
        m = geom.prim_material[prim]
        kind = mats.kind[m]
        shape = geom.prim_shape[prim]
        if kind == NULL:
            medium, o, crossings, within = cross_null(media, shape, p, ng, d, medium, crossings)
            if not within:
                return False, zero, zero, zero, L, n_seg
            continue
        crossings = 0
        counted = False
        ng_front = ng
        scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
        if not scatters:
            return False, zero, zero, zero, L, n_seg
        rgb = vec.row(mats.rgb, m)
        if kind == DIFFUSE:
            w = vec.mul(vec.hadamard(beta, rgb), INV_PI)
            E = direct_stratified_transmitted(geom, mats, lights, media, p, ng, ns, ng_front, shape, medium,
                                              qkey, 3, pass_index, n_strata)
            L = vec.add(L, vec.hadamard(w, E))
            return True, p, ns, w, L, n_seg
        depth += 1
        if depth > max_specular:
            return False, zero, zero, zero, L, n_seg
        if kind == CONDUCTOR:
            wi = mirror_reflect(d, ng, ns)
            beta = vec.hadamard(beta, rgb)
        else:
            u = glass_branch_number(first_glass, pass_index, qkey, key, dim)
            first_glass = False
            wr, wt, F, eta = dielectric_branches(d, ng, ns, mats.eta[m])
            dim += 1
            beta = vec.hadamard(beta, rgb)
            # emitters seen along either branch, with their expected weights (visible_points.glass_step)
            Lr = emitted_along_media(geom, mats, lights, media, vec.offset_origin(p, ng, wr), wr,
                                     medium_after(media, shape, ng_front, wr, medium))
            Lt = zero
            if F < 1.0:
                Lt = emitted_along_media(geom, mats, lights, media, vec.offset_origin(p, ng, wt), wt,
                                         medium_after(media, shape, ng_front, wt, medium))
            L, wi, beta = glass_step(L, beta, Lr, Lt, F, eta, u, wr, wt)
            counted = True
        medium = medium_after(media, shape, ng_front, wi, medium)
        o = vec.offset_origin(p, ng, wi)
        d = wi


@kernel
def visible_points_media(geom, mats, lights, media, cam, seed, stream, vstream, pass_index, n_strata, max_specular,
                         vp_pos, vp_nrm, vp_weight, vp_found, direct, seg_o, seg_d, seg_len, seg_beta, seg_medium,
                         seg_count, i0, i1):
    """:func:`caustica.photons.visible_points.visible_points` through media, with each pixel's medium segments."""
    geom, mats, lights, media = borrowed(geom), borrowed(mats), borrowed(lights), borrowed(media)
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        key = path_key(seed, stream, i)
        qkey = path_key(seed, STREAM_CAMERA_SCRAMBLE, i)
        vkey = path_key(seed, vstream, i)
        u1, u2 = sobol02(pass_index, qkey)
        o, d = generate_ray(cam, x, y, u1, u2)
        found, p, n, w, L, n_seg = visible_point_media(geom, mats, lights, media, o, d, key, qkey, vkey, pass_index,
                                                       n_strata, max_specular, seg_o, seg_d, seg_len, seg_beta,
                                                       seg_medium, i * MEDIUM_SEGMENTS)
        if not math.isfinite(L[0] + L[1] + L[2]):
            L = (0.0, 0.0, 0.0)
        for c in range(3):
            vp_pos[i, c] = p[c]
            vp_nrm[i, c] = n[c]
            vp_weight[i, c] = w[c]
            direct[i, c] = L[c]
        vp_found[i] = found
        seg_count[i] = n_seg


def check_segment_memory(pixels: int) -> None:
    """Refuse, with the estimate, a camera pass whose medium segments (SEGMENT_BYTES a pixel) would not fit."""
    check_budget(pixels * SEGMENT_BYTES, f"{pixels:,} pixels x {MEDIUM_SEGMENTS} camera segments in media",
                 "lower the resolution")


def camera_pass_media(scene, settings, pass_index, bar=None):
    """Run :func:`visible_points_media` over every pixel for pass (or sample) ``pass_index``.

    Returns ((vp_pos, vp_nrm, vp_weight, vp_found, direct), segments, compile seconds), the segments
    as beam_gather takes them: (origin, direction, length, β, medium, count per pixel).  The camera
    keys are ``pass_stream(STREAM_CAMERA, pass_index)`` and its media's own.
    """
    n = settings["width"] * settings["height"]
    check_segment_memory(n)
    # every entry is written by the kernel
    points = (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.bool_), np.empty((n, 3)))
    k = n * MEDIUM_SEGMENTS
    segments = (np.empty((k, 3)), np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k, np.int32),
                np.empty(n, np.int32))
    cam = scene.camera(settings["width"], settings["height"])
    compile_s = parallel_for(visible_points_media, n, (scene.geometry, scene.materials, scene.lights, scene.media, cam,
                                                       settings["seed"], pass_stream(STREAM_CAMERA, pass_index),
                                                       pass_stream(STREAM_CAMERA_MEDIA, pass_index), pass_index,
                                                       settings["light_samples"], settings["max_specular_depth"],
                                                       *points, *segments),
                             threads=settings["threads"], progress=bar)
    return points, segments, compile_s
