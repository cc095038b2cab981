"""The progressive camera pass's medium segments: what a camera path crosses in a medium, and the
direct light scattered towards it along them (scenes with media; docs/media.md).

Each medium segment of a camera path (origin, direction, length, medium, β at its origin) is
written out for the volume radiance estimate (:mod:`caustica.photons.beams`); a path has room for
:data:`MEDIUM_SEGMENTS` of them.  The direct light scattered along a segment (single scattering of
the lights' own light) is estimated here, not by photons — as direct light at surfaces is (SPEC §2):
one distance per segment per pass, drawn within the segment
(:func:`caustica.media.sample_distance_within`, weight T σs / pdf); from it one light sample
through media and null boundaries (:func:`caustica.media.light_sample`, exact transmittance) and
one phase-function sample that counts the emitter it sees, combined by MIS
(:func:`segment_inscatter`).  Unbiased, two rays per segment.  On the first segment (the camera's
own ray, usually the longest) the distance and the point on the light are points ``pass`` of
randomly shifted Kronecker sequences with generators of their own (:func:`first_segment_numbers`).
Random numbers: the segments draw from a stream of their own (``STREAM_CAMERA_MEDIA``, seven
numbers per segment), so a scene's media never shift the numbers of anything else.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..emitters import ENV, env_pdf, env_radiance, radiance_at_hit
from ..features import has
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import kernel
from ..media import NULL_CROSSINGS_CAP, crossing, escape_attenuation, light_sample, medium_after, phase_pdf, \
    phase_sample, phase_value, power_heuristic, sample_distance_within, segment_attenuation, tracked_within, \
    within_weight
from ..sampling.rng import KRONECKER_ALPHA, kronecker, uniform
from ..scene.description import HETEROGENEOUS, NULL
from ..transport import in_medium

#: Medium segments a camera path may have (room for them is allocated per pixel); a path that
#: would need more ends, as at the specular depth cap.
MEDIUM_SEGMENTS = 8
#: The per-pixel shifts (numbers of the camera pass's scramble key) of the Kronecker points that stratify the
#: first segment's next-event estimate over the passes; the surface's own numbers of that key are 0 .. 3 + 2 n²,
#: with n = --light-samples at most 64 (ESTIMATE_PARAMS), so these start past 3 + 2 * 64².
QMC_SEGMENT_DIM = 3 + 2 * 64 * 64 + 1
#: Bytes per pixel of the segment arrays (origin, direction, β, the two walls: 3 float64 each; length; medium;
#: vertices; count).
SEGMENT_BYTES = MEDIUM_SEGMENTS * (15 * 8 + 8 + 4 + 4) + 4




class CameraSegments(NamedTuple):
    """Each pixel's medium segments, MEDIUM_SEGMENTS slots a pixel (none in a scene without media)."""
    origin: np.ndarray      # float64[k, 3]
    direction: np.ndarray   # float64[k, 3]
    length: np.ndarray      # float64[k] (inf: the segment escapes)
    beta: np.ndarray        # float64[k, 3]: the path's throughput at the segment's origin
    medium: np.ndarray      # int32[k]
    vertices: np.ndarray    # int32[k]: the path's surface vertices before the segment (a point on it is that + 1
    #                         segments from the camera; null crossings are not vertices)
    start_wall: np.ndarray  # float64[k, 3]: the normal, turned into the medium, of the wall the segment starts at
    end_wall: np.ndarray    # float64[k, 3]: likewise where it ends; zero where there is none (the camera, an
    #                         escape, a null boundary with the same medium beyond): :func:`wall_normal`
    count: np.ndarray       # int32[pixels]: segments of each pixel's path


def allocate_segments(pixels: int, media: bool) -> CameraSegments:
    """Room for ``pixels`` paths' segments (every entry is written by the camera pass); empty without media."""
    k = pixels * MEDIUM_SEGMENTS if media else 0
    return CameraSegments(np.empty((k, 3)), np.empty((k, 3)), np.empty(k), np.empty((k, 3)), np.empty(k, np.int32),
                          np.empty(k, np.int32), np.empty((k, 3)), np.empty((k, 3)), np.zeros(pixels, np.int32))


@kernel(inline=True)
def store_segment(k, ray, path, start_wall, segments):
    """Write segment slot k: ``ray`` = (o, d, length s), ``path`` = (β, medium, the path's surface vertices before
    it), with no wall at its end yet (:func:`end_segment_at_wall` adds one)."""
    o, d, s = ray
    beta, medium, vertices = path
    vec.set_row(segments.origin, k, o)
    vec.set_row(segments.direction, k, d)
    vec.set_row(segments.beta, k, beta)
    segments.length[k] = s
    segments.medium[k] = medium
    segments.vertices[k] = vertices
    vec.set_row(segments.start_wall, k, vec.mul(start_wall, 1.0 if vec.dot(start_wall, d) >= 0.0 else -1.0))
    vec.set_row(segments.end_wall, k, (0.0, 0.0, 0.0))


@kernel(inline=True)
def end_segment_at_wall(k, ng, segments):
    """Segment slot k ends at a wall of normal ng (either side): kept turned back into the segment's medium."""
    d = (segments.direction[k, 0], segments.direction[k, 1], segments.direction[k, 2])
    vec.set_row(segments.end_wall, k, vec.mul(ng, -1.0 if vec.dot(ng, d) > 0.0 else 1.0))


@kernel(inline=True)
def wall_normal(ng, crossed, medium_before, medium_after):
    """The surface of geometric normal ng a camera path meets bounds the medium it was in — a wall for the volume
    estimate (:mod:`caustica.photons.beams`) — unless it is a null boundary with the same medium beyond: ng, or
    zero."""
    if crossed and medium_before == medium_after:
        return (0.0, 0.0, 0.0)
    return ng


@kernel(inline=True)
def emission_weighted(tables, o, d, medium, pdf_dir):
    """Emission reaching o from along d (past null boundaries, attenuated), each emitter weighted by MIS.

    d was sampled with solid-angle density pdf_dir (a phase function's, or a visible point's BSDF's); an area
    emitter met at distance r with cosine cos_l is weighted by the power heuristic against light sampling's density
    select_pdf r² / (area cos_l), as :func:`caustica.media.light_sample` samples it.
    pdf_dir < 0: no MIS (weight 1).  A ray that meets nothing sees the environment (weighted likewise against
    its light sampling).  Emitters on null surfaces crossed count, as in the path
    tracer (past a mask weighted by its chance of being off); the first other surface ends the ray (its emission
    counts if it is an emitter's front).
    """
    geom, mats, lights, media = tables
    L = (0.0, 0.0, 0.0)
    T = (1.0, 1.0, 1.0)
    dist = 0.0
    for _ in range(NULL_CROSSINGS_CAP):
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            if has(lights, ENV) and lights.env[0] >= 0:
                w = 1.0
                if pdf_dir >= 0.0:
                    w = power_heuristic(pdf_dir, lights.select_pdf[lights.env[0]] * env_pdf(lights, d))
                L = vec.madd(L, vec.hadamard(T, escaped_radiance(lights, media, (o, d), medium)), w)
            return L
        if medium >= 0:
            T = vec.hadamard(T, segment_attenuation(media, medium, (o, d), t))
        dist += t
        p, ng, _ = surface_at(geom, prim, o, d, t, b1, b2)
        e = geom.prim_emitter[prim]
        cos_l = -vec.dot(d, ng)
        if e >= 0 and cos_l > 0.0:
            w = 1.0
            if pdf_dir >= 0.0:
                pdf_light = lights.select_pdf[e] * dist * dist / (lights.area[e] * cos_l)
                w = power_heuristic(pdf_dir, pdf_light)
            L = vec.madd(L, vec.hadamard(T, radiance_at_hit(geom, lights, e, prim, (o, d, t, b1, b2))), w)
        if mats.kind[geom.prim_material[prim]] != NULL:
            passing = crossing(geom, mats, prim, (o, d, t, b1, b2))   # a mask: its chance of being off there
            if not (passing[0] > 0.0 or passing[1] > 0.0 or passing[2] > 0.0):
                return L
            T = vec.hadamard(T, passing)
        medium = medium_after(media, geom.prim_shape[prim], ng, d, medium)
        o = vec.offset_origin(p, ng, d)
    return L


@kernel
def escaped_radiance(lights, media, ray, medium):
    """The environment's radiance along a ray = (o, d) that meets nothing, attenuated by the ``medium`` it is in
    from o on (:func:`caustica.media.escape_attenuation`: an unbounded homogeneous medium leaves nothing, except in
    channels that do not attenuate; a heterogeneous one ends at its box)."""
    return vec.hadamard(env_radiance(lights, ray[1]), escape_attenuation(media, medium, ray))


@kernel(inline=True)
def emitted_along(tables, o, d, medium):
    """The radiance reaching o from along d from emitters, attenuated by the media and past null boundaries."""
    return emission_weighted(tables, o, d, medium, -1.0)


@kernel
def segment_inscatter(tables, o, d, s, m, beta, u):
    """β times one estimate of the direct light scattered towards o along the segment (o, d, s) in m.

    ``u`` = (u_channel, u_dist, u_light, u1, u2, u_ph1, u_ph2): one distance (u_channel, u_dist:
    :func:`caustica.media.sample_distance_within`, or in a heterogeneous medium
    :func:`caustica.media.tracked_within`); from there one light sample (u_light chooses the
    light, (u1, u2) the point on it) and one phase-function sample (u_ph1, u_ph2) that counts the
    emitter it sees, combined by MIS (power heuristic) for area lights.  Light sampling alone has unbounded variance where a segment passes close to an area
    light (its value grows as 1 / distance²); the phase sample takes over there.
    """
    media = tables[3]
    u_channel, u_dist, u_light, u1, u2, u_ph1, u_ph2 = u
    zero = (0.0, 0.0, 0.0)
    if has(media, HETEROGENEOUS) and media.kind[m] == HETEROGENEOUS:
        t, w = tracked_within(media, m, (o, d), s, u_channel, u_dist)
    else:
        t = sample_distance_within(media, m, s, u_channel, u_dist)
        w = within_weight(media, m, s, t)
    if w[0] == 0.0 and w[1] == 0.0 and w[2] == 0.0:
        return zero
    p = vec.madd(o, d, t)
    bw = vec.hadamard(beta, w)
    L = zero
    contrib, wi, pdf_light, _, is_area, ok, _ = light_sample(tables, in_medium(p, m), (u_light, u1, u2), False)
    if ok:
        mis = power_heuristic(pdf_light, phase_pdf(media, m, d, wi)) if is_area else 1.0
        L = vec.mul(vec.hadamard(bw, contrib), mis * phase_value(media, m, d, wi))
    wo, weight, pdf = phase_sample(media, m, d, u_ph1, u_ph2)
    if pdf > 0.0:
        Le = emission_weighted(tables, p, wo, m, pdf)
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
