"""Method ``pt``: unidirectional path tracing, the unbiased reference.

Next-event estimation at every diffuse vertex with multiple importance sampling
(power heuristic) against BSDF sampling for area lights; mirrors and glass are
followed as Dirac deltas (glass chooses reflection or refraction with the Fresnel
probability); Russian roulette after ``rr_depth`` vertices, as in Mitsuba 3's
``path`` integrator, whose depth convention this follows: ``max_depth`` = 1 sees
only emitters, 2 adds direct light, -1 is unlimited (capped at 1024).

A scene with participating media or null-BSDF boundaries is rendered by the volumetric
kernel of :mod:`caustica.methods.pt_volume` instead (the same samples, keys and depth
convention; docs/media.md); every other scene by :func:`radiance` below, as before.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..bsdf import sample_surface, scattering_side
from ..camera import generate_ray
from ..geometry import vec
from ..geometry.scene_geometry import intersect, surface_at
from ..jit import borrowed, kernel, parallel_for
from ..lighting import direct_one_sample
from ..sampling.rng import STREAM_CAMERA, pass_stream, path_key, uniform
from ..scene.description import DIFFUSE
from . import register
from .independent import IndependentPasses
from .params import Param
from .pt_volume import render_pixels_media

INV_PI = 1.0 / math.pi
DEPTH_CAP = 1024


@kernel(hot=True)
def radiance(geom, mats, lights, o, d, key, max_depth, rr_depth):
    """Radiance arriving at o from direction -d, estimated along one random path.

    Returns (L, extension rays, shadow rays): the rays traced, counted where they are traced.
    """
    n_ext = 0
    n_shadow = 0
    L = (0.0, 0.0, 0.0)
    beta = (1.0, 1.0, 1.0)
    eta_scale = 1.0
    specular = True
    pdf_bsdf = 0.0
    dim = 2
    depth = 0
    while True:
        n_ext += 1
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim < 0:
            break
        p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
        front = vec.dot(d, ng) < 0.0
        e = geom.prim_emitter[prim]
        if e >= 0 and front:
            w = 1.0
            if not specular:
                cos_l = -vec.dot(d, ng)
                pdf_light = lights.select_pdf[e] * t * t / (lights.area[e] * cos_l)
                w = pdf_bsdf * pdf_bsdf / (pdf_bsdf * pdf_bsdf + pdf_light * pdf_light)
            L = vec.madd(L, vec.hadamard(beta, vec.row(lights.radiance, e)), w)
        depth += 1
        if depth >= max_depth:
            break
        m = geom.prim_material[prim]
        kind = mats.kind[m]
        rgb = vec.row(mats.rgb, m)
        scatters, ng, ns = scattering_side(mats, m, front, ng, ns)
        if not scatters:
            break
        if kind == DIFFUSE:
            contrib, pdf_light, cos_s, is_area, shadow = direct_one_sample(geom, lights, p, ng, ns, key, dim)
            n_shadow += shadow
            dim += 3
            if cos_s > 0.0:
                w = 1.0
                if is_area:
                    pdf_b = cos_s * INV_PI
                    w = pdf_light * pdf_light / (pdf_light * pdf_light + pdf_b * pdf_b)
                L = vec.madd(L, vec.hadamard(beta, vec.hadamard(rgb, contrib)), w * INV_PI)
        alive, wi, beta, eta_scale, pdf, specular, dim = sample_surface(kind, rgb, mats.eta[m], d, ng, ns, key,
                                                                        dim, beta, eta_scale)
        if not alive:
            break
        if not specular:
            pdf_bsdf = pdf
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
def render_pixels(geom, mats, lights, cam, seed, stream, spp, max_depth, rr_depth, image, rays, i0, i1):
    """Average ``spp`` jittered paths per pixel for pixels [i0, i1) in row-major order.

    Sample s of pixel i is random path (i * spp + s) of ``stream`` (the pass's camera stream).
    rays[i] receives pixel i's (extension, shadow) ray counts.
    """
    geom, mats, lights = borrowed(geom), borrowed(mats), borrowed(lights)
    width = cam.width
    for i in range(i0, i1):
        y = i // width
        x = i % width
        acc = (0.0, 0.0, 0.0)
        for s in range(spp):
            key = path_key(seed, stream, (y * width + x) * spp + s)
            o, d = generate_ray(cam, x, y, uniform(key, 0), uniform(key, 1))
            L, n_ext, n_shadow = radiance(geom, mats, lights, o, d, key, max_depth, rr_depth)
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
    params = (
        Param("max_depth", int, -1, "longest path in vertices (Mitsuba's convention); -1 = unlimited",
              lambda v: v == -1 or v >= 1, "-1 or >= 1", max=DEPTH_CAP),
        Param("rr_depth", int, 5, "vertices before Russian roulette starts", lambda v: v >= 1, ">= 1",
              max=DEPTH_CAP),
    )

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
        tables = (scene.geometry, scene.materials, scene.lights)
        kernel_args = (cam, settings["seed"], stream, settings["spp"], max_depth, settings["rr_depth"], image, rays)
        if scene.media is None:
            compile_s = parallel_for(render_pixels, n, tables + kernel_args, threads=settings["threads"], progress=bar)
        else:   # a volumetric path tracer (methods/pt_volume.py, docs/media.md)
            compile_s = parallel_for(render_pixels_media, n, tables + (scene.media,) + kernel_args,
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
