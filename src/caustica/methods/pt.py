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
* in a medium a free-flight distance is sampled (:func:`caustica.media.free_flight`); if it ends
  before the next surface the path scatters there: next-event estimation with the phase function
  (MIS against phase sampling for area lights), then a phase-sampled direction;
* null-BSDF surfaces are crossed without scattering and without counting as a bounce (Mitsuba's
  depth), so a medium's boundary is invisible;
* next-event estimation from surfaces and medium points traces its shadow ray through null
  boundaries and media (exact transmittance, :func:`caustica.media.light_sample`); glass blocks
  it, as in Mitsuba.

``max_depth`` counts scattering events (surface and medium) as Mitsuba does.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..bsdfs import DELTA, SMOOTH, TRANSMISSION, oriented, sample
from ..camera import generate_ray
from ..errors import ParameterError
from ..geometry import vec
from ..jit import kernel, parallel_for
from ..lighting import emission_mis, environment_mis, next_event
from ..media import free_flight, medium_after, phase_sample
from ..sampling.rng import STREAM_CAMERA, pass_stream, path_key, uniform
from ..transport import CROSSED, NO_UV, TRAPPED, ShadingPoint, borrow_tables, surface_interaction
from . import register
from .independent import IndependentPasses
from .params import Param

INV_PI = 1.0 / math.pi
DEPTH_CAP = 1024
#: Mitsuba integrators whose image pt renders: their ``max_depth`` and ``rr_depth`` are pt's defaults
#: (``direct``: paths of at most two segments, max_depth 2; ``ptracer`` traces from the lights, to
#: the same image; ``volpathmis`` is volpath with spectral MIS: the same image and settings).
SCENE_INTEGRATORS = ("path", "volpath", "volpathmis", "ptracer", "direct")


@kernel(hot=True)
def radiance(tables, o, d, key, depths):
    """Radiance arriving at o from direction -d, estimated along one random path (from the camera's medium).

    ``depths`` = (max_depth, rr_depth, hide_emitters): Mitsuba's settings (hide_emitters: emitters and the
    environment the camera ray meets before any scattering add nothing).

    Returns (L, extension rays, shadow rays): the rays traced, counted where they are traced.
    """
    geom, mats, lights, media = tables
    max_depth, rr_depth, hide_emitters = depths
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
        prim, t, b1, b2, w, dim, escaped = free_flight(geom, media, medium, o, d, key, dim)
        if escaped:
            if lights.env[0] >= 0 and not (hide_emitters and depth == 0):
                L = vec.add(L, vec.hadamard(beta, environment_mis(lights, media, d, medium, (specular, pdf_last))))
            break
        if medium >= 0:
            beta = vec.hadamard(beta, w)
            if beta[0] == 0.0 and beta[1] == 0.0 and beta[2] == 0.0:
                break    # absorbed (albedo 0), or a flight no channel can take
        if prim < 0:
            # ---- a scattering event in the medium, at t = the flight's distance
            p = vec.madd(o, d, t)
            depth += 1
            if depth >= max_depth:
                break
            ng = ns = ng_front = zero
            uv = NO_UV
            shape = -1
            m = 0
        else:
            # ---- a surface (an emitter on a null boundary shines too)
            crossed = crossings
            p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, nxt, dim = surface_interaction(
                tables, (prim, t, b1, b2), o, d, medium, crossings, key, dim)
            e = geom.prim_emitter[prim]
            if e >= 0 and front and not (hide_emitters and depth == 0):
                L = vec.madd(L, vec.hadamard(beta, vec.row(lights.radiance, e)),
                             emission_mis(lights, e, (specular, pdf_last, p_last), -vec.dot(d, ng), t, crossed, p))
            if nxt == CROSSED:
                continue
            if nxt == TRAPPED:
                break
            depth += 1
            if depth >= max_depth:
                break
            ng_front = ng
            scatters, ng, ns = oriented(mats, m, front, ng, ns)
            if not scatters:
                break
        in_medium = prim < 0
        if in_medium or mats.flags[m] & SMOOTH:
            ok, term, scale, shadow, dim = next_event(tables, ShadingPoint(p, ng, ns, ng_front, shape, medium, uv), m, d,
                                                      beta, key, dim)
            n_shadow += shadow
            if ok:
                L = vec.madd(L, term, scale)
        if in_medium:
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
            alive, wi, weight, pdf, lobe, eta, dim = sample(mats, m, d, ng, ns, uv, key, dim)
            if not alive:
                break
            beta = vec.hadamard(beta, weight)
            if lobe & TRANSMISSION:
                beta = vec.mul(beta, 1.0 / (eta * eta))   # radiance is compressed into the denser medium
                eta_scale *= eta * eta
            specular = lobe & DELTA != 0
            if not specular:
                pdf_last = pdf
            medium = medium_after(media, shape, ng_front, wi, medium)
            p_last = p
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
def render_pixels(tables, cam, keys, params, out, i0, i1):
    """Average ``spp`` jittered paths per pixel for pixels [i0, i1) in row-major order into ``out`` = (image, rays).

    Sample s of pixel i is random path (i * spp + s) of ``keys`` = (seed, the pass's camera stream);
    ``params`` = (spp, max_depth, rr_depth, hide_emitters).  rays[i] receives pixel i's (extension, shadow) ray counts.
    """
    tables = borrow_tables(tables)
    seed, stream = keys
    spp, max_depth, rr_depth, hide_emitters = params
    image, rays = out
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        acc = (0.0, 0.0, 0.0)
        for s in range(spp):
            key = path_key(seed, stream, (y * width + x) * spp + s)
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
    )

    @staticmethod
    def scene_defaults(description) -> dict:
        """The scene's ``<integrator>`` settings pt takes (Mitsuba's conventions, which pt's follow)."""
        s = description.integrator_settings
        if not description.integrator_source or s.type not in SCENE_INTEGRATORS:
            return {}
        if s.type == "direct":
            return {"max_depth": 2, "hide_emitters": s.hide_emitters}
        if s.max_depth == 0:
            raise ParameterError(f"integrator '{s.type}' in {s.source}: max_depth 0 renders nothing (not even the "
                                 f"emitters); give -1 (unlimited) or a depth of at least 1")
        return {"max_depth": s.max_depth, "rr_depth": s.rr_depth, "hide_emitters": s.hide_emitters}

    @staticmethod
    def pass_output(scene, settings, pass_index, progress):
        """One pass: ``spp`` new samples per pixel, keyed by (seed, camera, pass, sample)."""
        cam = scene.camera(settings["width"], settings["height"])
        image = np.zeros((cam.height, cam.width, 3), np.float32)
        max_depth = DEPTH_CAP if settings["max_depth"] < 0 else settings["max_depth"]
        stream = pass_stream(STREAM_CAMERA, pass_index)

        n = cam.width * cam.height
        rays = np.zeros((n, 2), np.int64)
        bar = progress(total=n, desc="camera pass", unit="px")
        t0 = time.perf_counter()
        params = (settings["spp"], max_depth, settings["rr_depth"], settings["hide_emitters"])
        compile_s = parallel_for(render_pixels, n, (scene.tables, cam, (settings["seed"], stream), params, (image, rays)),
                                 threads=settings["threads"], progress=bar)
        bar.close()
        timings = {"compile_s": compile_s, "camera_pass_s": time.perf_counter() - t0 - compile_s}
        return image, None, {
            "timings": timings, "camera_rays": n * settings["spp"],
            "extension_rays": int(rays[:, 0].sum()), "shadow_rays": int(rays[:, 1].sum())}

    @staticmethod
    def final_stats(scene, settings, state):
        # a path tracer stores no photons: reported so every sidecar has the same fields
        return {"samples_per_pixel": state.passes * settings["spp"],
                "photons_emitted": 0, "photons_stored": 0, "map_bytes": 0, "map_mb": 0.0}
