"""Method ``pm``: classic photon mapping (Jensen 1996), optionally with a caustic map (PM+C).

1. Photon pass: ``photons`` photons leave the lights in proportion to power and
   are traced; every diffuse hit after the first scattering event leaves a record.
2. Caustic pass (when ``caustic_photons`` > 0): photons aimed at the specular
   objects' bounding spheres, storing only light -> specular+ -> diffuse records in
   a caustic map; the global map then leaves those paths out.
3. Maps: a kd-tree over each map's positions.
4. Camera pass (:mod:`caustica.methods.photon_common`): direct light by shadow rays,
   indirect light and caustics from the maps' k-nearest radiance estimates.  At a BSDF with glossy
   lobes beside its diffuse one (pplastic, principled, principledthin) each photon and shadow ray is weighted by the
   BSDF's f at its direction (:mod:`caustica.photons.gather`), as sppm's visible points do; where a glossy lobe is
   narrow or transmits the camera path first picks the glossy lobes or the diffuse ones (bsdfs.glossy_pick), follows
   the glossy ones, and weighs by the diffuse lobes alone where it picked those.

In a scene with media the photons scatter in them (:mod:`caustica.photons.trace`), their
volume photons (those of the aimed photons too) are gathered along the camera rays by the beam
radiance estimate within ``--volume-radius``, and the camera pass is the progressive one in media
(docs/media.md).
"""
from __future__ import annotations

import time

import numpy as np

from ..memory import check_budget
from ..photons.records import CAUSTIC, INDIRECT, SLOT_BYTES, VOLUME_CAUSTIC, VOLUME_INDIRECT, allocate_buffers, \
    empty_photon_map, map_from_buffers
from ..photons.trace import planned_records, trace_caustic_photon_pass, trace_photon_pass
from ..sampling.rng import STREAM_CAUSTIC_PHOTON, STREAM_PHOTON
from . import register
from .params import RADIUS_ALLOWED, Param, in_radius_range, non_negative, positive
from .photon_common import DEPTH_PARAMS, ESTIMATE_PARAMS, ONE_SHOT_VOLUME_PARAMS, TERMINATIONS, OneShot, \
    camera_pass, camera_pass_in_media, check_media_settings


def _map_stats(prefix, pmap, emitted):
    return {f"{prefix}_photons_emitted": emitted, f"{prefix}_photons_stored": pmap.count,
            f"{prefix}_map_bytes": pmap.memory_bytes()}


@register
class PhotonMapping(OneShot):
    name = "pm"
    summary = "photon mapping: a global map, plus a caustic map with --caustic-photons (PM+C)"
    renders_coated = True    # plastic: its lobes apart in gather_radiance, visible_point and trace_one (api.check_bsdfs)
    renders_rough_coated = True   # roughplastic: its glossy lobe sampled alone, as sppm's (gather_radiance)
    evaluates_bsdfs = True   # pplastic, principled(thin): photons and shadow rays weighted by f (diffuse_estimate)
    passes_glossy = True     # rough metal and glass: camera paths and photons sample them (api.check_bsdfs)
    renders_mixtures = True  # mask, blendbsdf: resolved at each hit (transport.surface_interaction; api.check_bsdfs)
    renders_normal_maps = True   # normalmap, bumpmap: visible points there evaluate f (trace.bounce: adjoint weights)
    default_spp = 1
    params = (
        Param("photons", int, 100_000, "photons emitted for the global map", positive, ">= 1"),
        Param("caustic_photons", int, 0, "photons aimed at specular objects for a caustic map "
                                         "(0: no caustic map; the paper's PM+C uses 100,000)",
              non_negative, ">= 0"),
        Param("caustic_k", int, None, "k of the caustic map (default: --k)", positive, ">= 1", scratch=16),
        Param("caustic_radius", float, None, "R of the caustic map (default: --radius)", in_radius_range,
              RADIUS_ALLOWED),
    ) + ONE_SHOT_VOLUME_PARAMS + ESTIMATE_PARAMS + DEPTH_PARAMS

    @staticmethod
    def build_maps(scene, settings, progress):
        """Photon pass(es) and kd-trees: (global map, caustic map, volume photons or None, stats with timings)."""
        n = settings.photons
        n_c = settings.caustic_photons
        mr = settings.max_bounces
        terminate = TERMINATIONS[settings.termination]
        planned = planned_records(n, mr, terminate)
        check_budget((planned + n_c) * SLOT_BYTES, f"{n:,} photons x {planned // max(n, 1)} record slots",
                     "lower --photons or --max-bounces")
        spheres = scene.specular_bounding_spheres()
        use_caustic = n_c > 0 and spheres.shape[0] > 0
        seed = settings.seed
        timings = {}

        threads = settings.threads
        t0 = time.perf_counter()
        bar = progress(total=n, desc="photon tracing", unit="photon")
        buf, _, compile_s = trace_photon_pass(scene, (seed, STREAM_PHOTON, n), (mr, terminate), threads=threads,
                                              progress=bar)
        bar.close()
        t1 = time.perf_counter()
        timings["photon_trace_s"] = t1 - t0 - compile_s
        cbuf = None
        if use_caustic:
            cbuf = allocate_buffers(n_c, 1)
            bar = progress(total=n_c, desc="caustic photons", unit="photon")
            c_s = trace_caustic_photon_pass(scene, cbuf, seed, STREAM_CAUSTIC_PHOTON, n_c, threads=threads,
                                            progress=bar)
            bar.close()
            compile_s += c_s
            timings["caustic_trace_s"] = time.perf_counter() - t1 - c_s

        t2 = time.perf_counter()
        global_map = map_from_buffers(buf, (INDIRECT,) if use_caustic else (INDIRECT, CAUSTIC))
        caustic_map = map_from_buffers(cbuf, (CAUSTIC,)) if use_caustic else empty_photon_map()
        volume = None
        if scene.has_media:
            # volume photons: as at surfaces, the aimed photons' light -> S+ -> medium ones replace the others'
            keep = buf.kind == VOLUME_INDIRECT if use_caustic else (buf.kind == VOLUME_INDIRECT) | \
                (buf.kind == VOLUME_CAUSTIC)
            volume = (buf.position[keep], buf.direction[keep], buf.power[keep], buf.depth[keep])
            if use_caustic:
                ck = cbuf.kind == VOLUME_CAUSTIC
                volume = tuple(np.concatenate([a, b[ck]]) for a, b in zip(volume, (cbuf.position, cbuf.direction,
                                                                                   cbuf.power, cbuf.depth)))
        timings["map_build_s"] = time.perf_counter() - t2
        del buf, cbuf
        timings["compile_s"] = compile_s
        stats = {"timings": timings,
                 **_map_stats("global", global_map, n),
                 "photons_emitted": n + (n_c if use_caustic else 0),
                 "photons_stored": global_map.count + caustic_map.count,
                 "map_bytes": global_map.memory_bytes() + caustic_map.memory_bytes()}
        if use_caustic:
            stats.update(_map_stats("caustic", caustic_map, n_c))
        stats["map_mb"] = stats["map_bytes"] / 1e6
        if n_c > 0 and not use_caustic:
            stats["note"] = "no specular objects in the scene: the caustic map was not built"
        return global_map, caustic_map, volume, stats

    @classmethod
    def render_once(cls, scene, settings, progress):
        check_media_settings(scene, settings)
        global_map, caustic_map, volume, stats = cls.build_maps(scene, settings, progress)
        k_c = settings.caustic_k or settings.k
        r_c = settings.caustic_radius or settings.radius
        if volume is None:
            image, cam_t, queries = camera_pass(scene, settings, global_map, caustic_map, k_c, r_c, progress)
        else:
            image, cam_t, queries, vstats = camera_pass_in_media(scene, settings, global_map, caustic_map, k_c, r_c,
                                                                  volume, progress)
            stats.update(vstats)
        cam_t["compile_s"] += stats["timings"].pop("compile_s")
        stats["timings"].update(cam_t)
        stats["knn_queries"] = queries
        return image, stats
