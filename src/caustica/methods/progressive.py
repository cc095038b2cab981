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

After P passes L_i = direct_i / P + τ_i / (π R_i² P) (+ τ_c,i / (π R_c,i² P) when the caustic
events keep statistics of their own: sppm's aimed caustic photons, docs/progressive.md).  Each event's power is already
divided by the photons of its pass (Φ / N), so pbrt's division by N is in it.
Everything persists as arrays of the pixel statistics, which are also the checkpoint.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ..arrays import require_array
from ..errors import ParameterError
from ..geometry import vec
from ..geometry.primitives import borrow
from ..jit import borrowed, kernel, parallel_for
from ..memory import check_budget
from ..photons.density_filters import FILTER_NONE, FILTERS
from ..photons.grid import build_grid, grid_compiled, grid_range_sum
from ..photons.beams import beam_gather, build_volume_grid, volume_grid_compiled
from ..photons.records import CAUSTIC, SLOT_BYTES, TraceBuffers
from ..photons.trace import trace_caustic_photon_pass
from ..photons.segments import MEDIUM_SEGMENTS
from ..photons.visible_points import BSDF_MATERIAL, VISIBLE_POINT_BYTES, bsdf_point, camera_pass, max_depth_of, \
    split_diffuse, split_point
from ..photons.visible_points import camera_pass_bytes as visible_camera_pass_bytes
from ..sampling.rng import STREAM_CAUSTIC_PHOTON, pass_stream
from .params import RADIUS_ALLOWED, RADIUS_MAX, Param, in_radius_range
from .independent import IndependentPasses
from .photon_common import ESTIMATE_PARAMS, GRID_LIMIT_HELP, SceneDepths, grid_limited, radius_setting

#: The default initial radius, as a fraction of the scene's bounding-box diagonal ...
RADIUS_FRACTION = 0.01
#: ... and at most this many pixel widths where the camera meets the scene (tables.Scene.pixel_footprint, the median
#: over a grid of the film): a camera that frames a small part of a scene (a material sample, a street in a city)
#: would blur it over tens of pixels (docs/progressive.md).  The paper's Cornell boxes at 256 px have 3.05.
FOOTPRINT_PIXELS = 4.0
#: The default initial radius of separate caustic statistics, as a fraction of R_0 (see docs/progressive.md).
CAUSTIC_RADIUS_SCALE = 0.6
#: The default initial radius of the volume estimate (scenes with media), as a fraction of R_0.
VOLUME_RADIUS_SCALE = 1.0
#: The least --alpha.  After a pixel's first photons its radius is R sqrt(alpha) while pixels without
#: photons keep R_0; the grid's cells follow the median radius, so a gather scans about alpha^-3/2
#: cells.  Measured (sppm, diacaustic 64x64, 100 passes): 0.03-0.1 s a pass for alpha 0.5 to 0.01,
#: 0.3-0.8 s at 1e-3, 2-6 s at 1e-4, and the second pass never ended at 1e-6 (issue 19, B2); radii
#: shrinking by sqrt(alpha) a pass also underflow to 0 (an image of NaN).
ALPHA_MIN = 0.01
#: Radius schedules: per pixel (SPPM's α update, sequential) or one per pass (independent passes).
SCHEDULES = ("pixel", "global")

_ESTIMATE = {p.name: p for p in ESTIMATE_PARAMS}

#: Parameters of the progressive gather and its camera pass.
PROGRESSIVE_PARAMS = (
    Param("radius", float, None, "initial gather radius R_0 in scene units "
                                 f"(default: {RADIUS_FRACTION} of the scene's bounding-box diagonal, at most "
                                 f"{FOOTPRINT_PIXELS:g} pixel widths where the camera meets the scene)",
          in_radius_range, RADIUS_ALLOWED),
    Param("alpha", float, 2.0 / 3.0, "fraction of new photons kept per pass (SPPM's α)",
          lambda a: ALPHA_MIN <= a < 1.0, f"at least {ALPHA_MIN:g} and below 1 (a smaller alpha makes a pass's "
                                          f"gather unbounded)"),
    Param("schedule", str, "pixel", "pixel: each pixel's radius shrinks with the photons it gathered "
                                    "(Hachisuka & Jensen 2009; passes run in order); global: pass p gathers "
                                    "within R_0 sqrt(prod_{i=1..p} (i + alpha) / (i + 1)) everywhere, so passes "
                                    "are independent and can run on a cluster (Knaus & Zwicker 2011)",
          choices=SCHEDULES),
    # the rest are the photon methods' own, with the progressive camera pass's defaults
    _ESTIMATE["max_bounces"],
    _ESTIMATE["termination"],
    replace(_ESTIMATE["light_samples"], default=1,
            help="n for n x n stratified shadow rays per area light, per pass"),
    replace(_ESTIMATE["fixed_light_grid"],
            help="use the n x n grid's cell centres instead of jittered samples (biased: never converges)"),
    _ESTIMATE["max_specular_depth"],
)

#: The volume estimate's radius (scenes with media; docs/media.md).
VOLUME_RADIUS_PARAM = Param("volume_radius", float, None,
                            "scenes with media: initial radius of the volume photons' spheres in the beam radiance "
                            "estimate; pass p uses it times sqrt(prod_{i=1..p} (i + alpha) / (i + 1)) "
                            f"(default: {VOLUME_RADIUS_SCALE} x the initial --radius{GRID_LIMIT_HELP})",
                            in_radius_range, RADIUS_ALLOWED)

#: How aimed caustic photons are gathered (sppm and pspm with --caustic-photons).
CAUSTIC_STATISTICS_PARAMS = (
    Param("caustic_statistics", str, "separate", "separate: with --caustic-photons, the caustic photons are "
                                                 "gathered into per-pixel statistics (N, R, tau) of their own, "
                                                 "so the other events keep their wider radius (pixel schedule); "
                                                 "shared: one set of statistics for all events",
          choices=("separate", "shared")),
    Param("caustic_radius", float, None, "initial radius of the separate caustic statistics "
                                         f"(default: {CAUSTIC_RADIUS_SCALE} x the initial --radius)",
          in_radius_range, RADIUS_ALLOWED),
    Param("caustic_filter", str, "epanechnikov",
          "the filter that weighs each caustic photon of the separate caustic statistics by its distance d from "
          "the visible point: epanechnikov 2 (1 - d^2/r^2), cone 3 (1 - d/r), gaussian (Jensen's), or none (the "
          "uniform disc of Hachisuka's PPM); at one radius the first three blur the caustic less and add noise "
          "(docs/progressive.md)",
          choices=tuple(FILTERS)),
)


def trace_caustic_pass(scene, settings, pass_index, n_caustic, out: TraceBuffers) -> float:
    """Trace the pass's ``n_caustic`` photons aimed at the caustic casters into ``out`` (one slot each).

    They carry every light -> (specular or glossy)+ -> diffuse path (as PM's caustic map, their power divided
    by the aiming pdf); the method's other photons or streams must then leave those paths out.
    Returns the compile seconds.
    """
    check_budget(n_caustic * SLOT_BYTES, f"{n_caustic:,} caustic photons per pass", "lower --caustic-photons")
    return trace_caustic_photon_pass(scene, out, settings.seed, pass_stream(STREAM_CAUSTIC_PHOTON, pass_index),
                                     n_caustic, threads=settings.threads)


def caustic_event_kind(kind: np.ndarray, out: np.ndarray) -> None:
    """Event kinds of caustic photons' slots into ``out`` (int8): 2 where a caustic event was stored, else 0."""
    np.equal(kind, CAUSTIC, out=out, casting="unsafe")
    out *= 2


class PixelStatistics(NamedTuple):
    """The per-pixel state of a progressive render after ``passes`` passes (flat, row-major)."""
    passes: int
    n_photons: np.ndarray   # float64[n]: N_i, the photon count kept
    radius: np.ndarray      # float64[n]: R_i
    tau: np.ndarray         # float64[n, 3]: τ_i, accumulated flux times W
    direct: np.ndarray      # float64[n, 3]: sum over passes of the directly seen radiance
    gathered: np.ndarray    # float64[n]: events gathered in all passes (before α), for --aov count
    emitted: int            # photons (or streams) emitted in all passes
    # the caustic events' own N_i, R_i and τ_i when the method keeps them apart (sppm's aimed caustic
    # photons, see ProgressivePhotonMethod.separate_caustics); otherwise N = τ = 0 and unused
    n_caustic: np.ndarray   # float64[n]
    radius_caustic: np.ndarray  # float64[n]
    tau_caustic: np.ndarray     # float64[n, 3]

    def to_arrays(self):
        return {k: np.asarray(v) for k, v in self._asdict().items()}


#: Grid cells are this many times the median gather radius of the pass (see :mod:`caustica.photons.grid`).
CELL_PER_RADIUS = 2.0


@kernel(inline=True)
def _point_sum(grid, query, limit, filt, row):
    """:func:`~caustica.photons.grid.grid_range_sum` at a visible point, ``query`` = (p, n, r), of ``row`` = (the
    material table, :attr:`VisiblePoints.bsdf`, i, the caustic grid or not): a plain sum without a BSDF row, or at a
    split point outside the caustic grid; weighted by the point's BSDF; at a split point in the caustic grid, each
    record by A + f_glossy / B."""
    p, n, r = query
    mats, rows, i, caustic = row
    split = split_point(mats, rows, i)
    if rows[i, BSDF_MATERIAL] < 0.0 and not (split and caustic):
        return grid_range_sum(grid, p, n, r, None, limit, filt)
    if not split:
        return grid_range_sum(grid, p, n, r, bsdf_point(mats, rows, i), limit, filt)
    return grid_range_sum(grid, p, n, r, bsdf_point(mats, rows, i), limit, filt, split_diffuse(mats, rows, i))


@kernel(inline=True)
def _gather_at(grid, points, radius, out, i, depth, filt=FILTER_NONE, caustic=False):
    """Σ Φ and the number of the grid's events within radius[i] of visible point i of ``points`` = (the pass's
    :class:`~caustica.photons.visible_points.VisiblePoints`, the material table), both borrowed, into ``out`` =
    (flux, count) at i.  Where the point's material is >= 0 each event's power is weighted by that BSDF at the
    event's direction (Σ f Φ; the visible point's weight is then β).  At a roughplastic's split point
    (:func:`~caustica.photons.visible_points.split_visible_point`) the sum is weighted by the diffuse lobe's A, or, for
    the ``caustic`` grid, each record by A + f_glossy / B (:func:`caustica.bsdfs.split_record_weight`).  Under a
    finite max_depth, ``depth`` = (max_depth, the grid's events' depths), the point takes those of depth max_depth -
    its segments at most; None: every one.  ``filt``: the filter that weighs each event
    (:func:`~caustica.photons.grid.grid_range_sum`)."""
    vps, mats = points
    vp_pos, vp_nrm, vp_found, rows = vps.position, vps.normal, vps.found, vps.bsdf
    flux, count = out
    if not vp_found[i]:
        count[i] = 0
        for c in range(3):
            flux[i, c] = 0.0
        return
    p = (vp_pos[i, 0], vp_pos[i, 1], vp_pos[i, 2])
    n = (vp_nrm[i, 0], vp_nrm[i, 1], vp_nrm[i, 2])
    row = (mats, rows, i, caustic)
    if depth is None:   # Numba compiles the two cases apart (the None one as before depths were kept)
        m, s = _point_sum(grid, (p, n, radius[i]), None, filt, row)
    else:
        m, s = _point_sum(grid, (p, n, radius[i]), (depth[0] - vps.segments[i], depth[1]), filt, row)
    if split_point(mats, rows, i) and not caustic:
        s = vec.hadamard(s, split_diffuse(mats, rows, i))
    count[i] = m
    for c in range(3):
        flux[i, c] = s[c]


@kernel
def gather_flux(grid, points, radius, out, depth, i0, i1):
    """Σ Φ and the number of this pass's events within radius[i] of visible point i, for i in [i0, i1) (0 without
    one): :func:`_gather_at` (``depth`` as it takes it)."""
    grid = borrowed(grid)
    points = (borrowed(points[0]), borrowed(points[1]))
    radius, out = borrow(radius), borrowed(out)   # no reference counts per pixel around the grid's sum
    for i in range(i0, i1):
        _gather_at(grid, points, radius, out, i, depth)


@kernel
def gather_flux_two(grids, points, radii, outs, depths, filt_c, i0, i1):
    """:func:`gather_flux` over two grids at once: ``grids`` = (grid, grid_c) within ``radii`` = (radius[i],
    radius_c[i]) into ``outs`` = ((flux, count), (flux_c, count_c)); ``depths``: None, or each grid's ``depth``
    as :func:`_gather_at` takes it; grid_c's events weighted by the filter ``filt_c``."""
    grid, grid_c = grids
    grid = borrowed(grid)
    grid_c = borrowed(grid_c)
    points = (borrowed(points[0]), borrowed(points[1]))
    radii, outs = borrowed(radii), borrowed(outs)   # no reference counts per pixel around the grids' sums
    if depths is None:
        for i in range(i0, i1):
            _gather_at(grid, points, radii[0], outs[0], i, None)
            _gather_at(grid_c, points, radii[1], outs[1], i, None, filt_c, True)
    else:
        for i in range(i0, i1):
            _gather_at(grid, points, radii[0], outs[0], i, depths[0])
            _gather_at(grid_c, points, radii[1], outs[1], i, depths[1], filt_c, True)


@kernel
def update_statistics(alpha, old, vp_found, vp_weight, gathered, new):
    """SPPM's update (step 4) of ``old`` = (N, R, tau) at every pixel, with this pass's ``gathered`` = (flux,
    count), into ``new`` = (N, R, tau) arrays (the old state stays whole).

    Per pixel with a visible point and M > 0 events: N <- N + alpha M, ratio = N_new / (N + M),
    R <- R sqrt(ratio), tau <- (tau + W Phi) ratio; the others keep N, R and tau.  The same
    operations, in the same order, as the NumPy expressions it replaced, so the same bits.
    """
    n_photons, radius, tau = old
    flux, count = gathered
    n_new, r_new, tau_new = new
    for i in range(n_photons.shape[0]):
        if vp_found[i] and count[i] > 0:
            m = float(count[i])
            nn = n_photons[i] + alpha * m
            ratio = nn / max(n_photons[i] + m, 1e-300)
            n_new[i] = nn
            r_new[i] = radius[i] * math.sqrt(ratio)
            for c in range(3):
                tau_new[i, c] = (tau[i, c] + vp_weight[i, c] * flux[i, c]) * ratio
        else:
            n_new[i] = n_photons[i]
            r_new[i] = radius[i]
            for c in range(3):
                tau_new[i, c] = tau[i, c]


def initial_radius(scene, settings) -> float:
    """R_0 of the surface estimate: ``radius``, else RADIUS_FRACTION of the scene's bounding-box diagonal, at most
    FOOTPRINT_PIXELS pixel widths where the camera meets the scene at the render's resolution."""
    r = radius_setting(scene, settings, "radius", RADIUS_FRACTION)
    if settings.radius is not None:
        return r
    return min(r, FOOTPRINT_PIXELS * scene.pixel_footprint(settings.width, settings.height))


def initial_volume_radius(scene, settings) -> float:
    """R_0 of the volume estimate: ``volume_radius`` when set, else VOLUME_RADIUS_SCALE R_0 limited by the scene's
    medium grids (:func:`~caustica.methods.photon_common.grid_limited`; docs/media.md)."""
    r = settings.volume_radius
    return grid_limited(scene.description, VOLUME_RADIUS_SCALE * initial_radius(scene, settings)) if r is None else r


def initial_caustic_radius(scene, settings) -> float:
    """R_0 of the separate caustic statistics: ``caustic_radius`` when set, else CAUSTIC_RADIUS_SCALE R_0."""
    r = settings.caustic_radius
    return CAUSTIC_RADIUS_SCALE * initial_radius(scene, settings) if r is None else r


def global_radius(r0: float, alpha: float, pass_index: int) -> float:
    """The ``global`` schedule's radius of pass p: R_0 sqrt(prod_{i=1..p} (i + α) / (i + 1)).

    Knaus & Zwicker (2011): with the variance of pass p's estimate growing as 1/R_p² and its
    bias falling as R_p², this product makes the mean of the passes consistent; it is
    R_0 sqrt(Γ(p + 1 + α) Γ(2) / (Γ(1 + α) Γ(p + 2))), written with lgamma so pass 10⁹ costs
    what pass 1 does.  It falls as p^((α - 1) / 2).
    """
    if pass_index == 0:
        return r0
    log_ratio = (math.lgamma(pass_index + 1 + alpha) - math.lgamma(1 + alpha)
                 - math.lgamma(pass_index + 2))
    return r0 * math.exp(0.5 * log_ratio)


class PassMeasurements(NamedTuple):
    """What one pass measured at each pixel: its visible point's weight, the flux and events within the radius."""
    vp_found: np.ndarray    # bool[n]
    vp_weight: np.ndarray   # float64[n, 3]: the path throughput W to the visible point
    flux: np.ndarray        # float64[n, 3]: Σ Φ of the events within the radius
    count: np.ndarray       # int64[n]: the events within the radius
    direct: np.ndarray      # float64[n, 3]: the radiance seen directly
    emitted: int            # photons (or streams) emitted
    flux_caustic: np.ndarray | None = None   # the same for the separate caustic events, within their radius
    count_caustic: np.ndarray | None = None


class ProgressivePhotonMethod(SceneDepths, IndependentPasses):
    """Shared pass of sppm and pspm; subclasses give ``photon_events(scene, settings, pass_index, radius, progress)``.

    ``photon_events`` returns ((position, power, normal, valid, direction[, depth]) of this pass's events (the
    direction of travel, which a visible point that evaluates its BSDF weighs with; the depth, which a finite
    ``max_depth`` limits, from a method that has one), paths emitted, stats); events with
    valid == 0 are empty slots, and when
    ``separate_caustics`` is true those with valid == 2 are the caustic events, gathered into
    the statistics n_caustic, radius_caustic, tau_caustic of their own; ``radius`` holds the
    pass's gather radii (float64[n]).  With ``--schedule pixel``
    the state is a :class:`PixelStatistics` and passes run in order; with ``global`` it
    is the film of independent passes (:class:`~caustica.methods.independent.IndependentPasses`).
    """
    progressive = True
    default_spp = 1
    aovs = ("radius", "count")
    #: Memory per pixel (api.resolve_settings checks it): the pixel statistics, old and new (with the
    #: caustic statistics' N, R and tau), and a pass's visible points, fluxes and counts (float64).
    #: Measured peak at 512 x 512: 265 bytes, 337 with separate caustic statistics.
    bytes_per_pixel = 340

    @classmethod
    def independent(cls, settings) -> bool:
        return settings.schedule == "global"

    #: What to lower when a pass's photon events would not fit in memory.
    pass_memory_hint = "lower --photons or --max-bounces"

    @classmethod
    def check(cls, scene, settings):
        """Settings the parameters' own ranges cannot refuse; and a pass's memory, before the first is traced."""
        if settings.spp != 1:
            raise ParameterError(f"--spp: {cls.name} takes one camera sample per pixel per pass "
                                 f"(got {settings.spp}); more passes give more samples")
        if scene.has_media and settings.fixed_light_grid:
            raise ParameterError("--fixed-light-grid: not supported in a scene with media (docs/media.md)")
        camera = " and the camera pass's BSDF rows or medium segments" if cls.camera_pass_bytes(scene, settings) else ""
        check_budget(cls.pass_buffer_bytes(scene, settings),
                     f"one {cls.name} pass of {cls.emitted_per_pass(scene, settings):,} paths (their records and "
                     f"the grid's copy{camera})", cls.pass_memory_hint + (" or --res" if camera else ""))

    @classmethod
    def auto_settings(cls, scene, settings) -> dict:
        """The values the settings left to their defaults (None) take in this scene (checkpoint messages)."""
        out = {"radius": initial_radius(scene, settings), "caustic_radius": initial_caustic_radius(scene, settings)}
        if scene.has_media:
            out["volume_radius"] = initial_volume_radius(scene, settings)
        return out

    @classmethod
    def new_state(cls, scene, settings):
        cls.check(scene, settings)
        if cls.independent(settings):
            return super().new_state(scene, settings)
        n = settings.width * settings.height
        r0 = initial_radius(scene, settings)
        return PixelStatistics(0, np.zeros(n), np.full(n, r0), np.zeros((n, 3)), np.zeros((n, 3)),
                               np.zeros(n), 0, np.zeros(n), np.full(n, initial_caustic_radius(scene, settings)),
                               np.zeros((n, 3)))

    @classmethod
    def state_from_arrays(cls, scene, settings, arrays):
        """The state a checkpoint holds, every array's dtype, shape and range checked (what a render writes)."""
        cls.check(scene, settings)
        if cls.independent(settings):
            return super().state_from_arrays(scene, settings, arrays)
        n = settings.width * settings.height
        radii = dict(above=0.0, high=RADIUS_MAX)
        spec = {"passes": ((), dict(low=0)), "emitted": ((), dict(low=0)), "n_photons": ((n,), dict(low=0)),
                "radius": ((n,), radii), "tau": ((n, 3), {}), "direct": ((n, 3), {}), "gathered": ((n,), dict(low=0)),
                "n_caustic": ((n,), dict(low=0)), "radius_caustic": ((n,), radii), "tau_caustic": ((n, 3), {})}
        got = {name: require_array(arrays, name, np.int64 if shape == () else np.float64, shape, **bounds)
               for name, (shape, bounds) in spec.items()}
        return PixelStatistics(**dict(got, passes=int(got["passes"]), emitted=int(got["emitted"])))

    @classmethod
    def caustic_photons_per_pass(cls, scene, settings) -> int:
        """Photons aimed at the mirrors and glass per pass (0: none, or no mirror or glass to aim at)."""
        return 0

    @classmethod
    def camera_pass_bytes(cls, scene, settings) -> int:
        """What a pass's camera pass holds beyond the one-column visible points :attr:`bytes_per_pixel` counts: the
        rest of each BSDF row where the gather evaluates BSDFs, and the medium segments in a scene with media."""
        claim = cls.separate_caustics(scene, settings) and not cls.independent(settings)
        return settings.width * settings.height * (visible_camera_pass_bytes(scene, claim) - VISIBLE_POINT_BYTES)

    @classmethod
    def separate_caustics(cls, scene, settings) -> bool:
        """Whether events of kind 2 are caustic events with their own statistics (the aimed caustic photons)."""
        return (settings.caustic_statistics == "separate"
                and cls.caustic_photons_per_pass(scene, settings) > 0)

    @classmethod
    def measure_pass(cls, scene, settings, pass_index, radius, progress, radius_caustic=None):
        """Camera pass, photon pass and gather within ``radius`` (float64[n]): (PassMeasurements, stats).

        With ``radius_caustic`` (float64[n]) the events of kind 2 go into a grid of their own and are
        gathered within it; the others (kind != 0) within ``radius``.  On :meth:`path_scene`'s scene.
        """
        scene = cls.path_scene(scene, settings)
        timings = {}
        n = settings.width * settings.height
        threads = settings.threads
        # 1. camera pass: visible points and direct light
        # every entry is written by the kernels (the camera pass for every pixel, the gather too)
        bar = progress(total=n, desc="visible points", unit="px")
        t0 = time.perf_counter()
        # in a scene with media, also the camera path's medium segments, for the volume estimate (docs/media.md)
        vps, segments, c0 = camera_pass(scene, settings, pass_index, bar, claim=radius_caustic is not None)
        vp_weight, vp_found, direct = vps.weight, vps.found, vps.direct
        max_depth = max_depth_of(settings)
        limited = max_depth is not None
        points = (vps, scene.materials)
        timings["camera_pass_s"] = time.perf_counter() - t0 - c0
        # 2. photon pass, and the grid over its events
        seen = radius[vp_found]
        typical = float(np.median(seen if seen.size else radius))
        events, emitted, stats = cls.photon_events(scene, settings, pass_index, radius, progress)
        timings.update(stats.pop("timings"))
        c1 = timings.pop("compile_s", 0.0)
        t1 = time.perf_counter()
        first_build = not grid_compiled()
        volume = stats.pop("volume_photons", None)
        (grid, depth), (grid_c, depth_c) = _event_grids(
            scene, events, radius_caustic, vp_found, typical,
            (bool(np.any(vps.bsdf[vp_found, BSDF_MATERIAL] != -1.0)), limited))
        if first_build:  # the grid's sort compiled (or loaded) just now: compile time, not work
            c1 += time.perf_counter() - t1
        else:
            timings["grid_build_s"] = time.perf_counter() - t1
        stats["events_stored"] = grid.count + (grid_c.count if grid_c is not None else 0)
        # 3. gather
        flux = np.empty((n, 3))
        count = np.empty(n, np.int64)
        t1 = time.perf_counter()
        flux_c = count_c = None
        if grid_c is None:
            c2 = parallel_for(gather_flux, n, (grid, points, radius, (flux, count),
                                               (max_depth, depth) if limited else None), threads=threads)
        else:
            flux_c = np.empty((n, 3))
            count_c = np.empty(n, np.int64)
            c2 = parallel_for(gather_flux_two, n, ((grid, grid_c), points, (radius, radius_caustic),
                                                   ((flux, count), (flux_c, count_c)),
                                                   ((max_depth, depth), (max_depth, depth_c)) if limited else None,
                                                   FILTERS[settings.caustic_filter]),
                              threads=threads)
        timings["gather_s"] = time.perf_counter() - t1 - c2
        c3 = 0.0
        if scene.has_media:   # 4. the volume: the beam radiance estimate along the camera segments
            vol, c3 = _volume_estimate(scene, settings, pass_index, volume, segments, timings, stats)
            direct += vol
        timings["compile_s"] = c0 + c1 + c2 + c3
        stats["events_gathered"] = int(count.sum()) + (int(count_c.sum()) if count_c is not None else 0)
        stats["timings"] = timings
        return PassMeasurements(vp_found, vp_weight, flux, count, direct, emitted, flux_c, count_c), stats

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        if cls.independent(settings):
            return super().run_pass(scene, settings, state, progress)
        separate = cls.separate_caustics(scene, settings)
        got, stats = cls.measure_pass(scene, settings, state.passes, state.radius, progress,
                                      state.radius_caustic if separate else None)
        # 4. the update, into new arrays: the old state stays whole until the pass is done
        alpha = settings.alpha
        first = not update_statistics.compiled_for_python()
        t0 = time.perf_counter()
        n_new, r_new, tau_new = cls.updated(alpha, state.n_photons, state.radius, state.tau, got, got.flux, got.count)
        if first:  # compiled (or loaded from the cache) just now: compile time, not work
            stats["timings"]["compile_s"] += time.perf_counter() - t0
        gathered_new = state.gathered + got.count
        nc_new, rc_new, tauc_new = state.n_caustic, state.radius_caustic, state.tau_caustic
        if separate:
            nc_new, rc_new, tauc_new = cls.updated(alpha, nc_new, rc_new, tauc_new, got, got.flux_caustic,
                                                   got.count_caustic)
            gathered_new += got.count_caustic
        new = PixelStatistics(state.passes + 1, n_new, r_new, tau_new, state.direct + got.direct, gathered_new,
                              state.emitted + got.emitted, nc_new, rc_new, tauc_new)
        return new, stats

    @staticmethod
    def updated(alpha, n_photons, radius, tau, got, flux, count):
        """(N, R, tau) after this pass's events (flux, count) at the visible points ``got`` found: new arrays."""
        n_new, r_new, tau_new = np.empty_like(n_photons), np.empty_like(radius), np.empty_like(tau)
        update_statistics(alpha, (n_photons, radius, tau), got.vp_found, got.vp_weight, (flux, count),
                          (n_new, r_new, tau_new))
        return n_new, r_new, tau_new

    @classmethod
    def pass_output(cls, scene, settings, pass_index, progress):
        """The ``global`` schedule's pass p: L = direct + W Σ Φ / (π R_p²) within the pass's own R_p."""
        n = settings.width * settings.height
        r = global_radius(initial_radius(scene, settings), settings.alpha, pass_index)
        got, stats = cls.measure_pass(scene, settings, pass_index, np.full(n, r), progress)
        radiance = got.direct + got.vp_weight * got.flux / (math.pi * r * r)
        image = radiance.reshape(settings.height, settings.width, 3).astype(np.float32)
        return image, got.count, stats

    @staticmethod
    def radiance(state) -> np.ndarray:
        """The ``pixel`` schedule's L_i = direct_i / P + τ_i / (π R_i² P), float64 (n, 3)."""
        p = max(state.passes, 1)
        out = state.direct / p + state.tau / (math.pi * state.radius[:, None] ** 2 * p)
        if np.any(state.n_caustic > 0):
            out += state.tau_caustic / (math.pi * state.radius_caustic[:, None] ** 2 * p)
        return out

    @classmethod
    def image(cls, scene, settings, state):
        if cls.independent(settings):
            return super().image(scene, settings, state)
        img = cls.radiance(state).reshape(settings.height, settings.width, 3)
        return img.astype(np.float32)

    @classmethod
    def final_radius(cls, scene, settings, state) -> np.ndarray:
        """The radius each pixel gathers within next (float64[n])."""
        if not cls.independent(settings):
            return state.radius
        r = global_radius(initial_radius(scene, settings), settings.alpha, state.passes)
        return np.full(settings.width * settings.height, r)

    @classmethod
    def aov(cls, scene, settings, state, name):
        shape = (settings.height, settings.width)
        if name == "radius":
            return cls.final_radius(scene, settings, state).reshape(shape).astype(np.float32)
        gathered = state.counts if cls.independent(settings) else state.gathered
        if gathered is None:
            return np.zeros(shape, np.float32)
        return gathered.reshape(shape).astype(np.float32)

    @classmethod
    def final_stats(cls, scene, settings, state):
        r = cls.final_radius(scene, settings, state)
        out = {"samples_per_pixel": state.passes, "emitted_all_passes": state.passes * cls.emitted_per_pass(scene, settings),
               "initial_radius": initial_radius(scene, settings), "schedule": settings.schedule,
               "radius_final": {"min": float(r.min()), "median": float(np.median(r)), "max": float(r.max())}}
        if scene.has_media:
            out["initial_volume_radius"] = initial_volume_radius(scene, settings)
            out["volume_radius_final"] = global_radius(out["initial_volume_radius"], settings.alpha, state.passes)
        if not cls.independent(settings):
            out["photons_kept_mean"] = float(state.n_photons.mean())
            if cls.separate_caustics(scene, settings):
                rc = state.radius_caustic
                out["caustic_statistics"] = "separate"
                out["initial_caustic_radius"] = initial_caustic_radius(scene, settings)
                out["radius_caustic_final"] = {"min": float(rc.min()), "median": float(np.median(rc)),
                                               "max": float(rc.max())}
                out["caustic_photons_kept_mean"] = float(state.n_caustic.mean())
        return out


def _event_grids(scene, events, radius_caustic, vp_found, typical, keep):
    """The hash grids over a pass's photon events: one for all (kind != 0), or with ``radius_caustic``
    the caustic events (kind 2) in a grid of their own, its cells sized by the caustic radii: ((grid, its events'
    depths), (grid_c, its depths) or (None, None)).  ``events`` = (position, power, normal, valid, direction,
    depth); ``keep`` = (directions, depths): the grids keep the directions when a visible point evaluates its BSDF,
    and their events' depths come back under a finite max_depth (None otherwise)."""
    position, power, normal, valid = events[:4]
    direction = events[4] if keep[0] else None
    depth = events[5] if keep[1] else None
    box = scene.geometry.scene_box
    if radius_caustic is None:
        return build_grid(position, power, normal, valid, box, CELL_PER_RADIUS * typical, direction, depth), \
            (None, None)
    others = build_grid(position, power, normal, (valid == 1).view(np.int8), box, CELL_PER_RADIUS * typical,
                        direction, depth)
    # the caustic radii shrink only where caustic events land: size the cells by those pixels
    seen_c = radius_caustic[vp_found & (radius_caustic < radius_caustic.max())]
    typical_c = float(np.median(seen_c)) if seen_c.size else typical
    caustic = build_grid(position, power, normal, (valid == 2).view(np.int8), box, CELL_PER_RADIUS * typical_c,
                         direction, depth)
    return others, caustic


def _volume_estimate(scene, settings, pass_index, volume, segments, timings, stats):
    """The beam radiance estimate of a pass's volume photons along the camera segments, within the
    pass's volume radius (docs/media.md): (radiance float64[n, 3], compile seconds)."""
    n = settings.width * settings.height
    r_v = global_radius(initial_volume_radius(scene, settings), settings.alpha, pass_index)
    compile_s = 0.0
    t1 = time.perf_counter()
    first_build = not volume_grid_compiled()
    position, direction, power, depth = volume
    vgrid = build_volume_grid(position, direction, power, r_v, depth)
    if first_build:
        compile_s += time.perf_counter() - t1
    else:
        timings["volume_grid_s"] = time.perf_counter() - t1
    vol = np.empty((n, 3))
    vfound = np.empty(n, np.int64)
    t1 = time.perf_counter()
    c = parallel_for(beam_gather, n, (vgrid, scene.media, (segments, MEDIUM_SEGMENTS, max_depth_of(settings)),
                                      (vol, vfound)), threads=settings.threads)
    timings["volume_gather_s"] = time.perf_counter() - t1 - c
    stats["volume_photons"] = vgrid.count
    stats["volume_grid_entries"] = vgrid.entries
    stats["volume_photons_gathered"] = int(vfound.sum())
    return vol, compile_s + c
