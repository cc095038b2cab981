"""Method ``pt``: unidirectional path tracing, the unbiased reference.

Next-event estimation at every vertex whose BSDF has a non-delta lobe, with multiple
importance sampling (power heuristic) against BSDF sampling for area lights; mirrors and
glass are followed as Dirac deltas (glass chooses reflection or refraction with the Fresnel
probability); the BSDFs are reached through :mod:`caustica.bsdfs` only; Russian roulette after ``rr_depth`` vertices, as in Mitsuba 3's
``path`` integrator, whose depth convention this follows: ``max_depth`` = 1 sees
only emitters, 2 adds direct light, -1 is unlimited (capped at 1024).

Through participating media it is a volumetric path tracer after Mitsuba 3's ``volpath``
(docs/media.md), in the same loop (vacuum is the case of no medium, with the same arithmetic):

* the current medium is tracked from the camera's through every boundary (a ray leaving a
  surface towards its front enters the shape's exterior medium, towards its back its interior;
  shapes without media leave it unchanged, :func:`caustica.media.medium_after`);
* in a medium a free-flight distance is sampled (:func:`caustica.media.free_flight`; delta tracking in a
  heterogeneous medium, :mod:`caustica.volumes`); if it ends before the next surface the path scatters there: next-event estimation with the phase function
  (MIS against phase sampling for area lights), then a phase-sampled direction;
* null-BSDF surfaces are crossed without scattering and without counting as a bounce (Mitsuba's
  depth), so a medium's boundary is invisible;
* next-event estimation from surfaces and medium points traces its shadow ray through null
  boundaries and media (exact transmittance, ratio tracked in a heterogeneous medium,
  :func:`caustica.media.light_sample`); glass blocks
  it, as in Mitsuba.

``max_depth`` counts scattering events (surface and medium) as Mitsuba does.

``thindielectric`` follows the scene's integrator (``null_thin_dielectric``, set for ``volpath`` and
``volpathmis``): Mitsuba flags its straight-on transmission ``Null``, and its ``volpath`` treats a pass as a
null crossing (not counted in the depth, the last real scattering kept for MIS, the medium switched; the
surface is sampled even at the last depth, where a reflection then ends the path) and lets shadow rays
through with ``eval_null_transmission`` = 1 - R; its ``path`` counts the pass as a bounce and blocks shadow
rays, as pt does without the setting.  The setting reaches the kernels as a copy of the material table
flagged ``NULL_TRANSMISSION`` there (:meth:`caustica.tables.Scene.with_null_thin_dielectric`); the scene's own
tables are not changed.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..bsdfs import DELTA, SMOOTH, TRANSMISSION, has_null_lobe, oriented, sample
from ..camera import generate_ray, pixel_of
from ..geometry import vec
from ..emitters import ENV, radiance_at_hit
from ..features import has
from ..scene.description import HETEROGENEOUS, NULL_THIN_INTEGRATORS, SCENE_INTEGRATORS
from ..jit import borrowed, kernel, parallel_for
from ..lighting import emission_mis, environment_mis, next_event
from ..media import cross_null, free_flight, in_a_medium, medium_after, phase_sample
from ..sampling.rng import STREAM_CAMERA, pass_stream, path_key, uniform
from ..transport import CROSSED, SCATTER, ShadingPoint, in_medium, surface_interaction
from . import register
from .independent import IndependentPasses
from .params import NULL_THIN_PARAM, Param

INV_PI = 1.0 / math.pi
DEPTH_CAP = 1024


@kernel(inline=True)
def medium_event(tables, at, d, acc, key, dim):
    """A scattering event in a medium at ``at`` (:func:`caustica.transport.in_medium`) on a path arriving along d
    with ``acc`` = (L, β, shadow rays so far): next-event estimation with the phase function (MIS against it for
    area lights), then a phase-sampled direction.  Returns (L, β, shadow rays, alive, wo, its pdf, dim)."""
    L, beta, n_shadow = acc
    ok, term, scale, shadow, dim = next_event(tables, at, 0, d, beta, key, dim)
    if ok:
        L = vec.madd(L, term, scale)
    wo, weight, pdf = phase_sample(tables[3], at.medium, d, uniform(key, dim), uniform(key, dim + 1))
    return L, vec.mul(beta, weight), n_shadow + shadow, pdf > 0.0, wo, pdf, dim + 2


@kernel(inline=True)
def surface_event(tables, at, m, d, acc, key, dim):
    """Scattering at surface point ``at`` of material m on a path arriving along d with ``acc`` = (L, β, shadow rays
    so far): next-event estimation where the BSDF has a smooth lobe, then a BSDF-sampled direction.  Returns
    (L, β times the sample's weight, shadow rays, (alive, wi, pdf, lobe, eta²), dim): β carries 1 / eta² when the
    lobe refracts (radiance is compressed into the denser medium), eta² is 1 otherwise."""
    L, beta, n_shadow = acc
    mats = tables[1]
    if mats.flags[m] & SMOOTH:
        ok, term, scale, shadow, dim = next_event(tables, at, m, d, beta, key, dim)
        n_shadow += shadow
        if ok:
            L = vec.madd(L, term, scale)
    alive, wi, weight, pdf, lobe, eta, dim = sample(mats, m, d, at.ng, at.ns, at.uv, key, dim)
    beta = vec.hadamard(beta, weight)
    eta2 = 1.0
    if lobe & TRANSMISSION:
        eta2 = eta * eta
        beta = vec.mul(beta, 1.0 / eta2)
    return L, beta, n_shadow, (alive, wi, pdf, lobe, eta2), dim


@kernel(inline=True)
def emitted(lights, emitter, acc, last, hit):
    """L plus β times the radiance Le of ``emitter`` = (e, Le) reached at ``hit`` = (p, cos_l, t, null crossings
    since the last scattering), MIS-weighted against light sampling from ``last`` = (specular, pdf_last, p_last)
    (:func:`caustica.lighting.emission_mis`); ``acc`` = (L, β)."""
    L, beta = acc
    e, Le = emitter
    p, cos_l, t, crossed = hit
    return vec.madd(L, vec.hadamard(beta, Le), emission_mis(lights, e, last, cos_l, t, crossed, p))


@kernel(inline=True)
def escaped_light(tables, acc, w, ray):
    """L plus β times the environment a path sees that escaped along ``ray`` = (d, medium, (specular, pdf_last),
    shown), MIS-weighted (:func:`caustica.lighting.environment_mis`); ``shown``: the environment counts (not hidden from the
    camera).  In a heterogeneous medium β first takes the tracked flight's weight w; ``acc`` = (L, β)."""
    L, beta = acc
    lights, media = tables[2], tables[3]
    d, medium, last, shown = ray
    if has(media, HETEROGENEOUS) and medium >= 0:
        beta = vec.hadamard(beta, w)   # the flight's null collisions (a homogeneous medium's escape weighs 1)
    if has(lights, ENV) and lights.env[0] >= 0 and shown:
        L = vec.add(L, vec.hadamard(beta, environment_mis(lights, media, d, medium, last)))
    return L


@kernel(inline=True)
def russian_roulette(beta, eta_scale, key, dim):
    """The path goes on with probability q = min(max β · eta_scale, 0.95) (number dim), then with β / q, as Mitsuba's.
    Returns (alive, β, dim)."""
    q = min(vec.max_component(beta) * eta_scale, 0.95)
    if uniform(key, dim) >= q:
        return False, beta, dim
    return True, vec.mul(beta, 1.0 / q), dim + 1


@kernel(inline=True)
def radiance(tables, o, d, key, depths):
    """Radiance arriving at o from direction -d along one random path (from the camera's medium), with ``depths`` =
    (max_depth, rr_depth, hide_emitters), Mitsuba's settings (hide_emitters: emitters and the environment the camera
    ray meets before any scattering add nothing).  Returns (L, extension rays, shadow rays traced)."""
    geom, mats, lights, media = tables
    max_depth, rr_depth, hide_emitters = depths
    n_ext = n_shadow = 0
    L, beta = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    eta_scale = 1.0      # the product of the refractions' eta² (Russian roulette's measure of β, as Mitsuba's)
    specular = True      # no scattering yet, or the last one was a delta: emission counts in full
    pdf_last = 0.0       # solid-angle density of the last scattering's sampled direction
    p_last = o           # where that scattering happened
    medium = media.camera[0]
    dim = 2
    depth = 0            # scattering events so far (Mitsuba's depth: null surfaces do not count)
    crossings = 0        # null surfaces crossed since the last scattering event
    while True:
        n_ext += 1
        prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
        if escaped:
            shown = not (hide_emitters and depth == 0)
            L = escaped_light(tables, (L, beta), w, (d, medium, (specular, pdf_last), shown))
            break
        if medium >= 0:
            beta = vec.hadamard(beta, w)
            if beta[0] == 0.0 and beta[1] == 0.0 and beta[2] == 0.0:
                break    # absorbed (albedo 0), or a flight no channel can take
        if in_a_medium(media, medium) and prim < 0:   # ---- a scattering event in the medium, at the flight's t
            p = vec.madd(o, d, t)
            depth += 1
            if depth >= max_depth:
                break
            L, beta, n_shadow, alive, d, pdf_last, dim = medium_event(tables, in_medium(p, medium), d,
                                                                       (L, beta, n_shadow), key, dim)
            if not alive:
                break
            o = p
            specular = False
        else:            # ---- a surface (an emitter on a null boundary shines too)
            crossed = crossings
            ray = (o, d, t, b1, b2)
            p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, nxt, dim = surface_interaction(
                tables, (prim, t, b1, b2), o, d, medium, crossings, key, dim)
            e = geom.prim_emitter[prim]
            if e >= 0 and front and not (hide_emitters and depth == 0):
                L = emitted(lights, (e, radiance_at_hit(geom, lights, e, prim, ray)), (L, beta),
                            (specular, pdf_last, p_last), (p, -vec.dot(d, ng), t, crossed))
            if nxt != SCATTER:
                if nxt == CROSSED:
                    continue
                break
            ng_front = ng
            scatters, ng, ns = oriented(mats, m, front, ng, ns)
            null_lobe = has_null_lobe(mats, m)   # sampled at the last depth too, as volpath does
            if not scatters or (depth + 1 >= max_depth and not null_lobe):
                break
            L, beta, n_shadow, (alive, wi, pdf, lobe, eta2), dim = surface_event(
                tables, ShadingPoint(p, ng, ns, ng_front, shape, medium, uv), m, d, (L, beta, n_shadow), key, dim)
            if not alive:
                break
            if null_lobe and lobe & TRANSMISSION:   # Mitsuba's Null lobe: crossed as a null boundary, no bounce
                medium, o, crossings, within = cross_null(media, shape, p, ng_front, d, medium, crossed)
                if within:
                    continue
                break
            depth += 1
            if depth >= max_depth:   # a Null lobe's surface reflecting at the last depth
                break
            eta_scale *= eta2
            specular = lobe & DELTA != 0
            if not specular:
                pdf_last = pdf
            o, d, medium = vec.offset_origin(p, ng, wi), wi, medium_after(media, shape, ng_front, wi, medium)
        p_last = p
        crossings = 0    # a real scattering event: null crossings are counted from here
        if depth >= rr_depth:
            alive, beta, dim = russian_roulette(beta, eta_scale, key, dim)
            if not alive:
                break
    return L, n_ext, n_shadow


@kernel
def render_pixels(tables, cam, keys, params, out, i0, i1):
    """Average ``spp`` jittered paths per pixel for pixels [i0, i1) in row-major order into ``out`` = (image, rays).

    Sample s of pixel i is random path (i * spp + s) of ``keys`` = (seed, the pass's camera stream);
    ``params`` = (spp, max_depth, rr_depth, hide_emitters).  rays[i] receives pixel i's (extension, shadow) ray counts.
    """
    tables, cam = borrowed(tables), borrowed(cam)
    seed, stream = keys
    spp, max_depth, rr_depth, hide_emitters = params
    image, rays = out
    for i in range(i0, i1):
        x, y = pixel_of(cam, i)
        acc = (0.0, 0.0, 0.0)
        for s in range(spp):
            key = path_key(seed, stream, i * spp + s)
            o, d = generate_ray(cam, x, y, uniform(key, 0), uniform(key, 1), key)
            L, n_ext, n_shadow = radiance(tables, o, d, key, (max_depth, rr_depth, hide_emitters))
            rays[i, 0] += n_ext
            rays[i, 1] += n_shadow
            if math.isfinite(L[0] + L[1] + L[2]):
                acc = vec.add(acc, L)
        inv = 1.0 / spp
        image[y, x, 0] = acc[0] * inv
        image[y, x, 1] = acc[1] * inv
        image[y, x, 2] = acc[2] * inv


@register
class PathTracer(IndependentPasses):
    name = "pt"
    summary = "path tracing with next-event estimation and MIS (the unbiased reference), through media too"
    progressive = True
    renders_glossy = True    # the BSDFs' glossy lobes through eval_pdf and sample (api.check_bsdfs)
    renders_mixtures = True  # mask, blendbsdf: resolved at each hit (transport.surface_interaction; api.check_bsdfs)
    renders_normal_maps = True   # normalmap, bumpmap: resolved at each hit to the nested BSDF, ns perturbed
    params = (
        Param("max_depth", int, -1, "longest path in vertices (Mitsuba's convention); -1 = unlimited; a scene's "
              "path/volpath integrator sets the default",
              lambda v: v == -1 or v >= 1, "-1 or >= 1", max=DEPTH_CAP),
        Param("rr_depth", int, 5, "vertices before Russian roulette starts (a scene's integrator sets the "
              "default)", lambda v: v >= 1, ">= 1",
              max=DEPTH_CAP),
        Param("hide_emitters", bool, False, "emitters (and the environment) seen directly by the camera render "
              "black, as Mitsuba's hide_emitters (a scene's integrator sets the default)"),
        NULL_THIN_PARAM,
    )

    @staticmethod
    def scene_defaults(description) -> dict:
        """The scene's ``<integrator>`` settings pt takes (Mitsuba's conventions, which pt's follow)."""
        s = description.integrator_settings
        if not description.integrator_source or s.type not in SCENE_INTEGRATORS:
            return {}
        if s.type == "direct":
            return {"max_depth": s.path_depth(), "hide_emitters": s.hide_emitters}
        return {"max_depth": s.path_depth(), "rr_depth": s.rr_depth, "hide_emitters": s.hide_emitters,
                "null_thin_dielectric": s.type in NULL_THIN_INTEGRATORS}

    @staticmethod
    def pass_output(scene, settings, pass_index, progress):
        """One pass: ``spp`` new samples per pixel, keyed by (seed, camera, pass, sample)."""
        cam = scene.camera(settings.width, settings.height)
        image = np.zeros((cam.height, cam.width, 3), np.float32)
        max_depth = DEPTH_CAP if settings.max_depth < 0 else settings.max_depth
        stream = pass_stream(STREAM_CAMERA, pass_index)

        n = cam.width * cam.height
        rays = np.zeros((n, 2), np.int64)
        bar = progress(total=n, desc="camera pass", unit="px")
        t0 = time.perf_counter()
        params = (settings.spp, max_depth, settings.rr_depth, settings.hide_emitters)
        tables = (scene.with_null_thin_dielectric() if settings.null_thin_dielectric else scene).tables
        compile_s = parallel_for(render_pixels, n, (tables, cam, (settings.seed, stream), params, (image, rays)),
                                 threads=settings.threads, progress=bar)
        bar.close()
        timings = {"compile_s": compile_s, "camera_pass_s": time.perf_counter() - t0 - compile_s}
        return image, None, {
            "timings": timings, "camera_rays": n * settings.spp,
            "extension_rays": int(rays[:, 0].sum()), "shadow_rays": int(rays[:, 1].sum())}

    @staticmethod
    def final_stats(scene, settings, state):
        # a path tracer stores no photons: reported so every sidecar has the same fields
        return {"samples_per_pixel": state.passes * settings.spp,
                "photons_emitted": 0, "photons_stored": 0, "map_bytes": 0, "map_mb": 0.0}
