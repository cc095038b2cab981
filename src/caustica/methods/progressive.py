"""What the progressive photon methods (sppm, pspm) share: per-pixel statistics and their update.

Stochastic progressive photon mapping (Hachisuka & Jensen 2009, as pbrt-v4's
``SPPMIntegrator``), SPEC §7.  Every pass:

1. camera pass (:mod:`caustica.photons.visible_points`): one visible point per pixel
   and the light it sees directly (emitters, and direct light by shadow rays);
2. photon pass (the method's own): this pass's photon events — photons for sppm,
   stream records or photons for pspm — in a uniform grid (:mod:`caustica.photons.grid`);
3. gather: each visible point sums the flux Φ and counts the events M within its
   current radius R_i (same side of the surface only, as in PM) — a pixel-parallel
   query, so no atomics and the same bits for any thread count;
4. update, per pixel with M > 0 (α ∈ (0, 1)):
       N_i ← N_i + α M,   R_i ← R_i √((N_i + α M) / (N_i + M)),
       τ_i ← (τ_i + W_i Φ) · R_i,new² / R_i²;
   every pixel adds its direct radiance to a running sum.

After P passes L_i = direct_i / P + τ_i / (π R_i² P).  Each event's power is already
divided by the photons of its pass (Φ / N), so pbrt's division by N is in it.
Everything persists as arrays of the pixel statistics, which are also the checkpoint.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ..errors import ParameterError
from ..jit import borrowed, kernel, parallel_for
from ..photons.grid import build_grid, grid_compiled, grid_range_sum
from ..photons.visible_points import visible_points
from ..sampling.rng import STREAM_CAMERA, pass_stream
from .params import Param, positive
from .photon_common import ESTIMATE_PARAMS

#: The default initial radius, as a fraction of the scene's bounding-box diagonal.
RADIUS_FRACTION = 0.01

_ESTIMATE = {p.name: p for p in ESTIMATE_PARAMS}

#: Parameters of the progressive gather and its camera pass.
PROGRESSIVE_PARAMS = (
    Param("radius", float, None, "initial gather radius R_0 in scene units "
                                 f"(default: {RADIUS_FRACTION} of the scene's bounding-box diagonal)",
          positive, "> 0"),
    Param("alpha", float, 2.0 / 3.0, "fraction of new photons kept per pass (SPPM's α)",
          lambda a: 0.0 < a < 1.0, "between 0 and 1, exclusive"),
    # the rest are the photon methods' own, with the progressive camera pass's defaults
    _ESTIMATE["max_bounces"],
    _ESTIMATE["termination"],
    replace(_ESTIMATE["light_samples"], default=1,
            help="n for n x n stratified shadow rays per area light, per pass"),
    replace(_ESTIMATE["fixed_light_grid"],
            help="use the n x n grid's cell centres instead of jittered samples (biased: never converges)"),
    _ESTIMATE["max_specular_depth"],
)


class PixelStatistics(NamedTuple):
    """The per-pixel state of a progressive render after ``passes`` passes (flat, row-major)."""
    passes: int
    n_photons: np.ndarray   # float64[n]: N_i, the photon count kept
    radius: np.ndarray      # float64[n]: R_i
    tau: np.ndarray         # float64[n, 3]: τ_i, accumulated flux times W
    direct: np.ndarray      # float64[n, 3]: sum over passes of the directly seen radiance
    gathered: np.ndarray    # float64[n]: events gathered in all passes (before α), for --aov count
    emitted: int            # photons (or streams) emitted in all passes

    def to_arrays(self):
        return {k: np.asarray(v) for k, v in self._asdict().items()}


#: Grid cells are this many times the median gather radius of the pass (see :mod:`caustica.photons.grid`).
CELL_PER_RADIUS = 2.0


@kernel
def gather_flux(grid, vp_pos, vp_nrm, vp_found, radius, flux, count, i0, i1):
    """Σ Φ and the number of this pass's events within radius[i] of visible point i, for i in [i0, i1)."""
    grid = borrowed(grid)
    for i in range(i0, i1):
        if not vp_found[i]:
            continue
        p = (vp_pos[i, 0], vp_pos[i, 1], vp_pos[i, 2])
        n = (vp_nrm[i, 0], vp_nrm[i, 1], vp_nrm[i, 2])
        m, s = grid_range_sum(grid, p, n, radius[i])
        count[i] = m
        flux[i, 0] = s[0]
        flux[i, 1] = s[1]
        flux[i, 2] = s[2]


def initial_radius(scene, settings) -> float:
    if settings["radius"] is not None:
        return settings["radius"]
    box = scene.geometry.scene_box
    return RADIUS_FRACTION * float(np.linalg.norm(box[3:] - box[:3]))


class ProgressivePhotonMethod:
    """Shared pass of sppm and pspm; subclasses give ``photon_events(scene, settings, state, progress)``.

    ``photon_events`` returns ((position, power, normal, valid) of this pass's events,
    paths emitted, stats); events with valid == 0 are empty slots.
    """
    progressive = True
    default_spp = 1
    aovs = ("radius", "count")
    #: Memory per pixel (api.resolve_settings checks it): the pixel statistics, old and new,
    #: and a pass's visible points, flux and counts (float64); measured about 231 bytes.
    bytes_per_pixel = 240

    @classmethod
    def check(cls, scene, settings):
        if settings["spp"] != 1:
            raise ParameterError(f"--spp: {cls.name} takes one camera sample per pixel per pass "
                                 f"(got {settings['spp']}); more passes give more samples")

    @classmethod
    def new_state(cls, scene, settings):
        cls.check(scene, settings)
        n = settings["width"] * settings["height"]
        r0 = initial_radius(scene, settings)
        return PixelStatistics(0, np.zeros(n), np.full(n, r0), np.zeros((n, 3)), np.zeros((n, 3)),
                               np.zeros(n), 0)

    @classmethod
    def state_from_arrays(cls, scene, settings, arrays):
        n = settings["width"] * settings["height"]
        try:
            st = PixelStatistics(**{k: arrays[k] for k in PixelStatistics._fields})
        except (KeyError, TypeError) as exc:
            raise ParameterError(f"checkpoint: missing pixel statistics ({exc})") from None
        st = st._replace(passes=int(st.passes), emitted=int(st.emitted))
        shapes = {"n_photons": (n,), "radius": (n,), "tau": (n, 3), "direct": (n, 3), "gathered": (n,)}
        for name, shape in shapes.items():
            if np.shape(getattr(st, name)) != shape:
                raise ParameterError(f"checkpoint: its {name} has shape {np.shape(getattr(st, name))}, "
                                     f"this {settings['width']}x{settings['height']} render needs {shape}")
        return st

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        timings = {}
        n = settings["width"] * settings["height"]
        cam = scene.camera(settings["width"], settings["height"])
        threads = settings["threads"]
        # 1. camera pass: visible points and direct light
        vp_pos = np.zeros((n, 3))
        vp_nrm = np.zeros((n, 3))
        vp_weight = np.zeros((n, 3))
        vp_found = np.zeros(n, np.bool_)
        direct = np.zeros((n, 3))
        bar = progress(total=n, desc="visible points", unit="px")
        t0 = time.perf_counter()
        c0 = parallel_for(visible_points, n, (scene.geometry, scene.materials, scene.lights, cam, settings["seed"],
                                              pass_stream(STREAM_CAMERA, state.passes), settings["light_samples"],
                                              settings["fixed_light_grid"], settings["max_specular_depth"],
                                              vp_pos, vp_nrm, vp_weight, vp_found, direct),
                          threads=threads, progress=bar)
        bar.close()
        timings["camera_pass_s"] = time.perf_counter() - t0 - c0
        # 2. photon pass, and the grid over its events
        events, emitted, stats = cls.photon_events(scene, settings, state, progress)
        timings.update(stats.pop("timings"))
        c1 = timings.pop("compile_s", 0.0)
        t1 = time.perf_counter()
        seen = state.radius[vp_found]
        cell = CELL_PER_RADIUS * float(np.median(seen if seen.size else state.radius))
        first_build = not grid_compiled()
        grid = build_grid(*events, scene.geometry.scene_box, cell)
        if first_build:  # the grid's sort compiled (or loaded) just now: compile time, not work
            c1 += time.perf_counter() - t1
        else:
            timings["grid_build_s"] = time.perf_counter() - t1
        stats["events_stored"] = grid.count
        # 3. gather
        flux = np.zeros((n, 3))
        count = np.zeros(n, np.int64)
        t1 = time.perf_counter()
        c2 = parallel_for(gather_flux, n, (grid, vp_pos, vp_nrm, vp_found, state.radius, flux, count),
                          threads=threads)
        timings["gather_s"] = time.perf_counter() - t1 - c2
        timings["compile_s"] = c0 + c1 + c2
        # 4. the update, into new arrays: the old state stays whole until the pass is done
        alpha = settings["alpha"]
        m = count.astype(np.float64)
        has = vp_found & (count > 0)
        n_new = np.where(has, state.n_photons + alpha * m, state.n_photons)
        ratio = np.where(has, n_new / np.maximum(state.n_photons + m, 1e-300), 1.0)
        r_new = state.radius * np.sqrt(ratio)
        tau_new = np.where(has[:, None], (state.tau + vp_weight * flux) * ratio[:, None], state.tau)
        new = PixelStatistics(state.passes + 1, n_new, r_new, tau_new, state.direct + direct,
                              state.gathered + m, state.emitted + emitted)
        stats["events_gathered"] = int(count.sum())
        stats["timings"] = timings
        return new, stats

    @staticmethod
    def radiance(state) -> np.ndarray:
        """L_i = direct_i / P + τ_i / (π R_i² P), float64 (n, 3)."""
        p = max(state.passes, 1)
        return state.direct / p + state.tau / (math.pi * state.radius[:, None] ** 2 * p)

    @classmethod
    def image(cls, scene, settings, state):
        img = cls.radiance(state).reshape(settings["height"], settings["width"], 3)
        return img.astype(np.float32)

    @classmethod
    def aov(cls, scene, settings, state, name):
        shape = (settings["height"], settings["width"])
        if name == "radius":
            return state.radius.reshape(shape).astype(np.float32)
        return state.gathered.reshape(shape).astype(np.float32)

    @classmethod
    def final_stats(cls, scene, settings, state):
        r = state.radius
        return {"samples_per_pixel": state.passes, "emitted_all_passes": state.emitted,
                "initial_radius": initial_radius(scene, settings),
                "radius_final": {"min": float(r.min()), "median": float(np.median(r)), "max": float(r.max())},
                "photons_kept_mean": float(state.n_photons.mean())}
