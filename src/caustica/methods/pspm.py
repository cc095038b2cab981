"""Method ``pspm``: progressive streamed photon mapping — the paper's "future work", SPEC §7.

Each pass is SPPM's (:mod:`caustica.methods.progressive`: visible points, a gather
within each pixel's own shrinking radius, the α update) with *streams* in place of
photons: ``streams`` streams of a leading and ``assoc`` associated photons are traced
as in SPM (:mod:`caustica.photons.streams`), keyed by (seed, stream phase, pass, index).
What the gather sees of a pass:

* ``--estimator stream`` (the paper's eq. 2): a stream record counts as one event
  of energy E_i at its leading position, and where a visible point evaluates its BSDF (pplastic, principled, any
  diffuse lobe under a normal or bump map) E_i is weighted by f at the leading photon's direction;
* ``--estimator photons``: the leading and each associated photon at its own position, each weighted at its own
  direction.

``--specular merge`` is the paper's rule: at a mirror or glass the associated photons
merge into the leading one, so every light → specular → diffuse event is one leading
photon carrying the whole stream.  With ``--specular split`` each associated photon
keeps its own path through the specular chain and is stored where it lands, so a
stream keeps n_fa + 1 samples of the caustic.

``--caustic-photons N`` (with ``merge``) is PSPM with a caustic map, as the paper sets SPM
beside PM+C: N photons per pass aimed at the mirrors and glass carry every
light → specular⁺ → diffuse path, in statistics of their own as sppm's, and the streams
leave those records out and carry the rest of the light.
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import ParameterError
from ..memory import check_budget
from ..photons.records import SLOT_BYTES, VOLUME_CAUSTIC, allocate_buffers
from ..photons.streams import StreamBuffers, trace_stream_pass
from ..photons.visible_points import max_depth_of
from ..sampling.rng import STREAM_SPM, pass_stream
from . import register
from .params import RADIUS_ALLOWED, Param, non_negative, positive, zero_or_in_radius_range
from .photon_common import DEPTH_PARAMS, MEDIUM_SCATTERING_PARAM, TERMINATIONS, StreamedBSDFs
from .progressive import (CAUSTIC_STATISTICS_PARAMS, PROGRESSIVE_PARAMS, VOLUME_RADIUS_PARAM,
                          ProgressivePhotonMethod,
                          caustic_event_kind, initial_radius, trace_caustic_pass)

ESTIMATORS = ("stream", "photons")
SPECULAR = ("merge", "split")


def streams_per_pass(settings) -> int:
    """Default: as many photons per pass as pixels, as sppm (n_fs (n_fa + 1) = pixels)."""
    return settings.streams or max(1, settings.width * settings.height // (settings.assoc + 1))


def stream_radius(scene, settings, radius) -> float:
    """This pass's stream radius: r_s scaled like the gather radii ``radius``, r_s · median(R_i) / R_0.

    Associated photons land within about r_s of where their stream's leading photon
    would have put them (and split photons leave through a disc of radius r_s), which
    blurs the light they carry at the scale r_s whatever the number of passes; shrinking
    r_s with the radii makes that blur vanish as the passes grow, as SPPM's own does.
    The median is over the pixels that have gathered (their R_i < R_0): a pixel that never
    gathers an event (it sees an emitter, the sky, or a black back) keeps R_0, and counting
    those held r_s at half its start while the gathering pixels' radii were at a fifth.
    The factor depends only on the state, so it is the same for any thread count.
    """
    r0 = initial_radius(scene, settings)
    shrunk = radius[radius < r0]
    return settings.stream_radius * (float(np.median(shrunk)) / r0 if shrunk.size else 1.0)


@register
class ProgressiveStreamedPhotonMapping(StreamedBSDFs, ProgressivePhotonMethod):
    name = "pspm"
    summary = "progressive streamed photon mapping: SPPM's per-pixel statistics over streams"
    params = (
        Param("streams", int, None, "streams traced per pass, n_fs (default: pixels / (assoc + 1))",
              positive, ">= 1"),
        Param("assoc", int, 10, "associated photons per stream (n_fa)", non_negative, ">= 0"),
        Param("stream_radius", float, 5.0, "stream radius r_s of the first pass (scene units); later passes "
                                           "scale it as the gather radii shrink", zero_or_in_radius_range,
              "0 or " + RADIUS_ALLOWED),
        Param("estimator", str, "stream", "stream: eq. 2 over stream records (the paper); "
                                          "photons: every photon at its own position", choices=ESTIMATORS),
        Param("specular", str, "merge", "merge: associated photons merge into the leading one at mirrors "
                                        "and glass (the paper); split: each keeps its own specular path",
              choices=SPECULAR),
        Param("caustic_photons", int, 0, "photons per pass aimed at the specular objects for light -> "
                                         "specular -> diffuse paths, which the streams then leave out "
                                         "(as PM's caustic map; 0: none, the streams carry the caustic too; "
                                         "needs --specular merge)", non_negative, ">= 0"),
        MEDIUM_SCATTERING_PARAM,
        VOLUME_RADIUS_PARAM,
        *DEPTH_PARAMS,
    ) + CAUSTIC_STATISTICS_PARAMS + PROGRESSIVE_PARAMS

    @classmethod
    def check(cls, scene, settings):
        if settings.caustic_photons > 0 and settings.specular == "split":
            raise ParameterError("--caustic-photons: pspm's aimed caustic photons need --specular merge "
                                 "(with split, the streams carry their own caustic photons)")
        if scene.has_media and settings.specular == "split":
            raise ParameterError("--specular split: not supported in a scene with media (docs/media.md)")
        super().check(scene, settings)

    pass_memory_hint = "lower --streams, --assoc, --caustic-photons or --max-bounces"

    @classmethod
    def auto_settings(cls, scene, settings) -> dict:
        return dict(super().auto_settings(scene, settings), streams=streams_per_pass(settings))

    @classmethod
    def emitted_per_pass(cls, scene, settings) -> int:
        """Streams, plus the aimed caustic photons (counted as paths emitted, as sppm's photons)."""
        return streams_per_pass(settings) + cls.caustic_photons_per_pass(scene, settings)

    @classmethod
    def pass_buffer_bytes(cls, scene, settings) -> int:
        """A pass's stream buffers and caustic photons' records, the grid's sorted copy of the events, and in a
        scene with media the camera's medium segments."""
        n = streams_per_pass(settings)
        streams = StreamBuffers.bytes_needed(n, settings.assoc, settings.max_bounces,
                                             settings.specular == "split")
        return 2 * (streams + cls.caustic_photons_per_pass(scene, settings) * SLOT_BYTES) + \
            cls.camera_pass_bytes(scene, settings)

    @classmethod
    def caustic_photons_per_pass(cls, scene, settings) -> int:
        specular = scene.specular_bounding_spheres().shape[0] > 0
        return settings.caustic_photons if specular else 0

    @classmethod
    def photon_events(cls, scene, settings, pass_index, radius, progress):
        n = streams_per_pass(settings)
        r_s = stream_radius(scene, settings, radius)
        n_fa, mr = settings.assoc, settings.max_bounces
        split = settings.specular == "split"
        check_budget(StreamBuffers.bytes_needed(n, n_fa, mr, split),
                     f"{n:,} streams x {n_fa} associated photons per pass",
                     "lower --streams, --assoc or --max-bounces")
        t0 = time.perf_counter()
        buf = StreamBuffers(n, n_fa, mr, split)
        bar = progress(total=n, desc="stream tracing", unit="stream")
        terminate = TERMINATIONS[settings.termination]
        compile_s = trace_stream_pass(scene, buf, settings.seed, pass_stream(STREAM_SPM, pass_index), n, n_fa, r_s,
                                      mr, terminate, spread=settings.medium_scattering == "spread",
                                      threads=settings.threads, progress=bar)
        bar.close()
        n_c = cls.caustic_photons_per_pass(scene, settings)
        if n_c > 0:   # the aimed caustic photons carry the light -> specular+ -> diffuse (or medium) paths
            cbuf = allocate_buffers(n_c, 1)
            compile_s += trace_caustic_pass(scene, settings, pass_index, n_c, cbuf)
        t1 = time.perf_counter()
        limited = max_depth_of(settings) is not None
        # depth: [each event's depth] under a finite max_depth, which the gather holds them against; else []
        pos, direction, power, normal, *depth = buf.events(settings.estimator, leave_caustics=n_c > 0,
                                                           depths=limited)
        valid = np.ones(pos.shape[0], np.int8)
        if n_c > 0:   # kind 2: the caustic photons' events
            kinds = np.empty(n_c, np.int8)
            caustic_event_kind(cbuf.kind, kinds)
            pos, power, normal, direction = (np.concatenate([a, b]) for a, b in (
                (pos, cbuf.position), (power, cbuf.power), (normal, cbuf.normal), (direction, cbuf.direction)))
            depth = [np.concatenate([a, cbuf.depth]) for a in depth]
            valid = np.concatenate([valid, kinds])
        stats = {"streams_emitted": n, "photons_emitted": n * (n_fa + 1) + n_c}
        if scene.has_media:
            # volume photons: the streams' volume records (without light -> specular+ -> medium ones when the
            # aimed caustic photons carry those), and the caustic photons' (docs/media.md)
            volume = buf.volume_events(settings.estimator, leave_caustics=n_c > 0)
            if n_c > 0:
                in_medium = cbuf.kind == VOLUME_CAUSTIC
                volume = tuple(np.concatenate([a, b[in_medium]])
                               for a, b in zip(volume, (cbuf.position, cbuf.direction, cbuf.power, cbuf.depth)))
            stats["volume_photons"] = volume
        stats["timings"] = {"compile_s": compile_s, "photon_trace_s": t1 - t0 - compile_s,
                            "map_build_s": time.perf_counter() - t1}
        return (pos, power, normal, valid, direction, *depth), n + n_c, stats

    @classmethod
    def final_stats(cls, scene, settings, state):
        out = super().final_stats(scene, settings, state)
        out["stream_radius_next_pass"] = stream_radius(scene, settings, cls.final_radius(scene, settings, state))
        return out
