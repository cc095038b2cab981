"""Method ``sppm``: stochastic progressive photon mapping (Hachisuka & Jensen 2009), SPEC §7.

A pass is (:mod:`caustica.methods.progressive`): a camera pass finding one visible
point per pixel (through mirrors and glass) with its direct light; ``photons``
photons traced as in PM (:mod:`caustica.photons.trace`: every diffuse hit after the
first scattering event is an event, caustic and indirect alike), keyed by
(seed, photon phase, pass, index); a grid over them; each visible point gathers
the events within its own radius; the per-pixel α update.  Its error goes to zero as
passes grow: the radius shrinks while the photon count it holds grows.
"""
from __future__ import annotations

import time

import numpy as np

from ..memory import check_budget
from ..photons.records import CAUSTIC, INDIRECT, SLOT_BYTES, VOLUME_CAUSTIC, VOLUME_INDIRECT, TraceBuffers
from ..photons.trace import planned_records, trace_photon_pass
from ..sampling.rng import STREAM_PHOTON, pass_stream
from . import register
from .params import Param, non_negative, positive
from .photon_common import DEPTH_PARAMS, TERMINATIONS
from .progressive import (CAUSTIC_STATISTICS_PARAMS, PROGRESSIVE_PARAMS, VOLUME_RADIUS_PARAM,
                          ProgressivePhotonMethod, caustic_event_kind, trace_caustic_pass)


def photon_counts(scene, settings) -> tuple[int, int]:
    """(photons, caustic photons) traced per pass; caustic photons only where there is a caustic caster (a mirror,
    glass or a glossy object: ``Scene.specular_shapes``) to aim at.

    Both left to their defaults in a scene with casters: one photon per pixel in all, as
    pbrt-v4, half of them aimed at those objects (docs/progressive.md has the measurements).  Otherwise
    ``--photons`` (default one per pixel) and ``--caustic-photons`` (default 0) as given.
    """
    pixels = settings.width * settings.height
    specular = scene.specular_bounding_spheres().shape[0] > 0
    n_c = settings.caustic_photons
    if n_c is None:
        if specular and settings.photons is None:
            return pixels - pixels // 2, pixels // 2
        n_c = 0
    return settings.photons or pixels, (n_c if specular else 0)


@register
class StochasticProgressivePhotonMapping(ProgressivePhotonMethod):
    name = "sppm"
    summary = "stochastic progressive photon mapping: per-pixel radii shrink pass by pass"
    renders_coated = True    # plastic: its lobes apart in visible_point and trace_one (api.check_bsdfs)
    renders_rough_coated = True   # roughplastic: the same, its glossy lobe sampled alone
    evaluates_bsdfs = True   # pplastic, principled(thin): visible points weight photons by f (bsdf_visible_point)
    passes_glossy = True     # rough metal and glass: camera paths and photons sample them (api.check_bsdfs)
    renders_mixtures = True  # mask, blendbsdf: resolved at each hit (transport.surface_interaction; api.check_bsdfs)
    renders_normal_maps = True   # normalmap, bumpmap: visible points there evaluate f (trace.bounce: adjoint weights)
    params = (
        Param("photons", int, None, "photons traced per pass (default: one per pixel, as pbrt-v4; half of them "
                                    "aimed at the mirrors, glass and glossy objects, if any, when --caustic-photons is not "
                                    "given)",
              positive, ">= 1"),
        Param("caustic_photons", int, None, "photons per pass aimed at the specular objects for light -> "
                                            "specular -> diffuse paths, which the other photons then leave out "
                                            "(as PM's caustic map; 0: none, plain SPPM; default: half of the "
                                            "default photons in a scene with mirrors or glass, else 0)",
              non_negative, ">= 0"),
        VOLUME_RADIUS_PARAM,
        *DEPTH_PARAMS,
    ) + CAUSTIC_STATISTICS_PARAMS + PROGRESSIVE_PARAMS

    pass_memory_hint = "lower --photons, --caustic-photons or --max-bounces"

    @classmethod
    def emitted_per_pass(cls, scene, settings) -> int:
        return sum(photon_counts(scene, settings))

    @classmethod
    def auto_settings(cls, scene, settings) -> dict:
        photons, caustic = photon_counts(scene, settings)
        return dict(super().auto_settings(scene, settings), photons=photons, caustic_photons=caustic)

    @classmethod
    def caustic_photons_per_pass(cls, scene, settings) -> int:
        return photon_counts(scene, settings)[1]

    @classmethod
    def pass_buffer_bytes(cls, scene, settings) -> int:
        """A pass's photon records (:func:`~caustica.photons.trace.planned_records`, one a caustic photon), the
        grid's sorted copy, and what the camera pass holds beyond the visible points (BSDF rows, medium segments)."""
        n, n_c = photon_counts(scene, settings)
        records = planned_records(n, settings.max_bounces, TERMINATIONS[settings.termination])
        return 2 * (records + n_c) * SLOT_BYTES + cls.camera_pass_bytes(scene, settings)

    @classmethod
    def photon_events(cls, scene, settings, pass_index, radius, progress):
        n, n_c = photon_counts(scene, settings)
        rules = (settings.max_bounces, TERMINATIONS[settings.termination])
        planned = planned_records(n, *rules)
        check_budget(planned * SLOT_BYTES, f"{n:,} photons x {planned // max(n, 1)} record slots per pass",
                     "lower --photons or --max-bounces")
        aimed = n_c > 0
        t0 = time.perf_counter()
        # one buffer: the photons' records, then the caustic photons' one slot each (the caustic photons write
        # into a view of its tail, so no copy joins the two)
        bar = progress(total=n, desc="photon tracing", unit="photon")
        buf, slots, compile_s = trace_photon_pass(scene, (settings.seed, pass_stream(STREAM_PHOTON, pass_index), n),
                                                  rules, reserve=n_c if aimed else 0, threads=settings.threads,
                                                  progress=bar)
        bar.close()
        head = TraceBuffers(*(a[:slots] for a in buf))
        if not aimed and not scene.has_media:
            # every record is an event (kind INDIRECT or CAUSTIC; EMPTY slots are 0)
            return (buf.position, buf.power, buf.normal, buf.kind, buf.direction, buf.depth), n, {
                "timings": {"compile_s": compile_s, "photon_trace_s": time.perf_counter() - t0 - compile_s},
                "photons_emitted": n}
        valid = np.empty(buf.kind.shape[0], np.int8)
        if aimed:
            # caustic photons carry the light -> specular+ -> diffuse (or medium) paths; the others leave them out
            tail = TraceBuffers(*(a[slots:] for a in buf))
            compile_s += trace_caustic_pass(scene, settings, pass_index, n_c, tail)
            np.equal(head.kind, INDIRECT, out=valid[:slots], casting="unsafe")
            # kind 2: the caustic events (their own statistics with --caustic-statistics separate)
            caustic_event_kind(tail.kind, valid[slots:])
        else:
            valid[:] = (buf.kind == INDIRECT) | (buf.kind == CAUSTIC)   # the surface records, not the volume's
        stats = {"timings": {"compile_s": compile_s, "photon_trace_s": time.perf_counter() - t0 - compile_s},
                 "photons_emitted": n + n_c}
        if scene.has_media:
            # volume photons: all of the unaimed ones', or, with caustic photons, the unaimed photons'
            # VOLUME_INDIRECT and the aimed ones' VOLUME_CAUSTIC (the same split as at surfaces)
            if aimed:
                keep = np.concatenate([head.kind == VOLUME_INDIRECT, tail.kind == VOLUME_CAUSTIC])
            else:
                keep = (buf.kind == VOLUME_INDIRECT) | (buf.kind == VOLUME_CAUSTIC)
            stats["volume_photons"] = (buf.position[keep], buf.direction[keep], buf.power[keep], buf.depth[keep])
        return (buf.position, buf.power, buf.normal, valid, buf.direction, buf.depth), n + n_c, stats
