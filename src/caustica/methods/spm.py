"""Method ``spm``: streamed photon mapping (Guzek & Napieralski), as pinned down in SPEC §4.

One pass: trace ``streams`` streams (:mod:`caustica.photons.streams`: emission,
merging at mirrors and glass, associated photons in a disc of radius r_s, stream
records, stream decay), build the kd-tree over the leading photons, then the camera
pass (:mod:`caustica.methods.photon_common`).  The radiance estimate (eq. 2) takes
the k nearest stream records within R: L = f_r Σ W E_i (the ``stream`` estimator,
the paper's).  The ``photons`` estimator instead counts every photon at its own
position (an option, never the default).

In a scene with media the streams go through them (:mod:`caustica.photons.streams`,
``--medium-scattering``); their volume records are gathered along the camera rays by the beam
radiance estimate within ``--volume-radius`` (under either estimator, as at surfaces), and the
camera pass is the progressive one in media (docs/media.md).
"""
from __future__ import annotations

import time

from ..memory import check_budget
from ..photons.records import empty_photon_map
from ..photons.streams import StreamBuffers, StreamMap, trace_stream_pass
from ..sampling.rng import STREAM_SPM
from . import register
from .params import RADIUS_ALLOWED, Param, non_negative, positive, zero_or_in_radius_range
from .photon_common import DEPTH_PARAMS, ESTIMATE_PARAMS, MEDIUM_SCATTERING_PARAM, ONE_SHOT_VOLUME_PARAMS, \
    TERMINATIONS, OneShot, StreamedBSDFs, camera_pass, camera_pass_in_media, check_media_settings

ESTIMATORS = ("stream", "photons")


@register
class StreamedPhotonMapping(StreamedBSDFs, OneShot):
    name = "spm"
    summary = "streamed photon mapping (the paper's method): streams of a leading + associated photons"
    default_spp = 1
    params = (
        Param("streams", int, 10_000, "streams emitted (n_fs)", positive, ">= 1"),
        Param("assoc", int, 10, "associated photons per stream (n_fa)", non_negative, ">= 0"),
        Param("stream_radius", float, 5.0, "stream radius r_s (scene units)", zero_or_in_radius_range,
              "0 or " + RADIUS_ALLOWED),
        Param("estimator", str, "stream", "stream: eq. 2 over stream records (the paper); "
                                          "photons: every photon at its own position", choices=ESTIMATORS),
        MEDIUM_SCATTERING_PARAM,
    ) + ONE_SHOT_VOLUME_PARAMS + ESTIMATE_PARAMS + DEPTH_PARAMS

    @staticmethod
    def build_stream_map(scene, settings, progress):
        """Stream tracing and the kd-tree over leading photons: (StreamMap, stats with timings)."""
        n, n_fa, mr = settings.streams, settings.assoc, settings.max_bounces
        check_budget(StreamBuffers.bytes_needed(n, n_fa, mr), f"{n:,} streams x {n_fa} associated photons",
                     "lower --streams, --assoc or --max-bounces")
        timings = {}
        t0 = time.perf_counter()
        buf = StreamBuffers(n, n_fa, mr)
        bar = progress(total=n, desc="stream tracing", unit="stream")
        terminate = TERMINATIONS[settings.termination]
        compile_s = trace_stream_pass(scene, buf, settings.seed, STREAM_SPM, n, n_fa, settings.stream_radius, mr,
                                      terminate, spread=settings.medium_scattering == "spread",
                                      threads=settings.threads, progress=bar)
        bar.close()
        t1 = time.perf_counter()
        timings["compile_s"] = compile_s
        timings["photon_trace_s"] = t1 - t0 - compile_s
        smap = StreamMap(buf)
        smap.volume = buf.volume_events(settings.estimator) if scene.has_media else None
        timings["map_build_s"] = time.perf_counter() - t1
        stats = {"timings": timings,
                 "streams_emitted": n,
                 "stream_records_stored": smap.n_records,
                 "associated_photons_stored": smap.n_associated,
                 "photons_emitted": n * (n_fa + 1),
                 "photons_stored": smap.n_records + smap.n_associated,
                 "map_bytes": smap.memory_bytes()}
        stats["map_mb"] = stats["map_bytes"] / 1e6
        return smap, stats

    @classmethod
    def render_once(cls, scene, settings, progress):
        check_media_settings(scene, settings)
        smap, stats = cls.build_stream_map(scene, settings, progress)
        t0 = time.perf_counter()
        pmap = smap.records if settings.estimator == "stream" else smap.photon_map()
        stats["timings"]["map_build_s"] += time.perf_counter() - t0
        if smap.volume is None:
            image, cam_t, queries = camera_pass(scene, settings, pmap, empty_photon_map(), 0, 1.0, progress)
        else:
            image, cam_t, queries, vstats = camera_pass_in_media(scene, settings, pmap, empty_photon_map(), 0, 1.0,
                                                                  smap.volume, progress)
            stats.update(vstats)
        cam_t["compile_s"] += stats["timings"].pop("compile_s")
        stats["timings"].update(cam_t)
        stats["knn_queries"] = queries
        return image, stats
