"""What the photon-mapping methods (pm, spm) share: parameters, termination, the camera pass, one-shot passes; and
what every photon method (sppm and pspm too) takes from a scene's integrator: Mitsuba's max_depth and hide_emitters."""
from __future__ import annotations

import time

import numpy as np

from ..errors import ParameterError
from ..memory import check_budget
from ..jit import parallel_for
from ..photons.beams import beam_gather, build_volume_grid, volume_grid_compiled
from ..photons.density_filters import FILTERS
from ..photons.gather import gather_at_visible_points, gather_pixels
from ..photons.trace import TERMINATION_CAP, TERMINATION_ROULETTE
from ..photons.streams import MEDIUM_SCATTERING
from ..photons.segments import MEDIUM_SEGMENTS
from ..photons.visible_points import camera_pass_bytes, max_depth_of
from ..photons.visible_points import camera_pass as progressive_camera_pass
from ..scene.description import NULL_THIN_INTEGRATORS, SCENE_INTEGRATORS
from .params import NULL_THIN_PARAM, RADIUS_ALLOWED, Param, in_radius_range, non_negative, positive

TERMINATIONS = {"cap": TERMINATION_CAP, "roulette": TERMINATION_ROULETTE}

#: Parameters of the radiance estimate and the camera pass (SPEC §2-3), the paper's defaults.
ESTIMATE_PARAMS = (
    Param("max_bounces", int, 4, "diffuse bounces of a photon / leading photon (the paper's mr; in media, "
                                 "scattering events in a medium count too)",
          positive, ">= 1", max=1024),
    Param("k", int, 100, "photons (stream records) per radiance estimate", positive, ">= 1",
          scratch=16),  # the k-nearest search's index + distance arrays, per thread
    Param("radius", float, 3.0, "maximum search radius R (scene units)", in_radius_range, RADIUS_ALLOWED),
    Param("filter", str, "none", "radiance-estimate filter kernel", choices=tuple(FILTERS)),
    Param("termination", str, "cap",
          "cap: scale power by the albedo and stop after max_bounces (the paper); "
          "roulette: Russian roulette on each bounce's largest weight (a diffuse surface's albedo)",
          choices=tuple(TERMINATIONS)),
    Param("light_samples", int, 5, "n for n x n stratified shadow rays per area light",
          positive, ">= 1", max=64),
    Param("fixed_light_grid", bool, False,
          "use the n x n grid's cell centres (the paper's 25 point lights) instead of jittered samples"),
    Param("max_specular_depth", int, 64, "mirror, glass and glossy bounces of a camera ray (a photon's cap is "
          "the same 64)", non_negative, ">= 0", max=1024),
)

#: Mitsuba's max_depth and hide_emitters (docs/methods.md, "The scene's integrator"): a path is the camera's
#: segments to its diffuse point (sppm's and pspm's visible point) plus the segments of the photon (or stream
#: record) gathered there.
DEPTH_PARAMS = (
    Param("max_depth", int, -1, "longest path in segments, camera to light (Mitsuba's max_depth: 2 is direct "
                                "light only); -1 = unlimited; photons still end after --max-bounces diffuse "
                                "bounces either way; a scene's path, volpath, direct or ptracer integrator sets "
                                "the default",
          lambda v: v == -1 or v >= 1, "-1 or >= 1", max=1024),
    Param("hide_emitters", bool, False, "emitters (and the environment) seen directly by the camera render "
                                        "black, as Mitsuba's hide_emitters (a scene's integrator sets the "
                                        "default)"),
    NULL_THIN_PARAM,
)


class SceneDepths:
    """A photon method that takes the scene's ``<integrator>`` depths (:data:`DEPTH_PARAMS`)."""

    @classmethod
    def scene_defaults(cls, description) -> dict:
        """The scene's ``<integrator>`` settings the photon methods take: Mitsuba's max_depth (``direct``: 2),
        hide_emitters, and under volpath its thindielectric (``null_thin_dielectric``: :meth:`path_scene`)."""
        s = description.integrator_settings
        if not description.integrator_source or s.type not in SCENE_INTEGRATORS:   # pt's: the same images
            return {}
        return {"hide_emitters": s.hide_emitters, "null_thin_dielectric": s.type in NULL_THIN_INTEGRATORS,
                "max_depth": s.path_depth()}

    @staticmethod
    def path_scene(scene, settings):
        """The scene a pass traces: under ``null_thin_dielectric`` its copy where a thindielectric's straight-on lobe
        is volpath's null event (:meth:`~caustica.tables.Scene.with_null_thin_dielectric`), so that camera paths
        (:func:`~caustica.photons.gather.gather_radiance`, :func:`~caustica.photons.visible_points.visible_point`),
        photons (:func:`~caustica.photons.trace.trace_one`) and streams
        (:func:`~caustica.photons.streams.trace_stream`) cross it without a vertex and shadow rays pass it with
        1 - R: the light straight through it is direct light.  Else the scene itself."""
        return scene.with_null_thin_dielectric() if settings.null_thin_dielectric else scene


#: What a stream does at a scattering event in a medium (spm and pspm; docs/media.md).
MEDIUM_SCATTERING_PARAM = Param(
    "medium_scattering", str, "merge",
    "scenes with media: at a scattering event in a medium the associated photons merge into the leading photon "
    "(merge, as at a mirror or glass; the lower error at equal time in the fog box) or spread over the disc of "
    "radius r_s about it and go on with it as a beam (spread, as at a diffuse surface); under --estimator "
    "stream the two have the same expectation (the same image with --termination roulette; docs/media.md)",
    choices=MEDIUM_SCATTERING)

#: The default radius of the one-shot methods' volume estimate, as a fraction of the scene's diagonal.
VOLUME_RADIUS_FRACTION = 0.01

#: In a scene with grid media a default volume radius is at most this many of the grids' finest voxel edge (the
#: estimate blurs the photons' density over its radius, and a grid's coefficients change from voxel to voxel) ...
VOXEL_RADIUS_FRACTION = 0.5
#: ... and not below this fraction of the default it replaces (a fine grid need not be a sharp one; docs/media.md).
VOXEL_RADIUS_FLOOR = 0.25

#: How the default volume radius is limited in a scene with grid media, for the parameters' help.
GRID_LIMIT_HELP = (f"; with grid media at most {VOXEL_RADIUS_FRACTION} of their finest voxel, not below "
                   f"{VOXEL_RADIUS_FLOOR} of that default")

#: pm's and spm's volume estimate (scenes with media; docs/media.md).
ONE_SHOT_VOLUME_PARAMS = (
    Param("volume_radius", float, None, "scenes with media: radius of the volume photons' spheres in the beam "
                                        f"radiance estimate (default: {VOLUME_RADIUS_FRACTION} of the scene's "
                                        f"bounding-box diagonal{GRID_LIMIT_HELP})", in_radius_range, RADIUS_ALLOWED),
)


def radius_setting(scene, settings, name: str, fraction: float) -> float:
    """settings[name] when set, else ``fraction`` of the scene's bounding-box diagonal: the photon methods' radii
    default to a size relative to the scene."""
    if settings[name] is not None:
        return settings[name]
    box = scene.geometry.scene_box
    return fraction * float(np.linalg.norm(box[3:] - box[:3]))


def finest_voxel(description) -> float:
    """The shortest voxel edge (scene units) of the grids of the media the scene uses: each sigma_t and albedo
    volume's, along the axes on which its values change (:attr:`~caustica.scene.description.Volume.voxel_edges`);
    inf without such a grid."""
    edges = [np.inf]
    for m in description.used_media:
        medium = description.media[m]
        for volume in (medium.sigma_t_volume, medium.albedo_volume):
            if volume is not None:
                edges += volume.voxel_edges
    return min(edges)


def grid_limited(description, radius: float) -> float:
    """A default volume radius limited by the grids of the media the scene uses: at most VOXEL_RADIUS_FRACTION of
    their finest voxel (:func:`finest_voxel`), not below VOXEL_RADIUS_FLOOR of ``radius``.  The beam estimate takes
    the photons within the radius of a ray, so next to a voxel much denser than the ray's own it counts photons
    scattered there: in the corpus's test_hetero_sigmat_volpath (16³ voxels 0.094 wide) a row of pixels whose rays
    run along an empty layer under a dense one was 82 % too bright at the radius of the scene's size (0.125, 256
    passes), 25 % at 0.05 (docs/media.md)."""
    return max(min(radius, VOXEL_RADIUS_FRACTION * finest_voxel(description)), VOXEL_RADIUS_FLOOR * radius)


def one_shot_volume_radius(scene, settings) -> float:
    """The one-shot methods' volume radius: ``volume_radius``, else VOLUME_RADIUS_FRACTION of the diagonal, limited
    by the scene's medium grids (:func:`grid_limited`)."""
    if settings.volume_radius is not None:
        return settings.volume_radius
    return grid_limited(scene.description, radius_setting(scene, settings, "volume_radius", VOLUME_RADIUS_FRACTION))


#: Bytes a pixel of :func:`camera_pass_in_media` holds besides a sample's camera pass: the sum over the samples,
#: the sample's volume estimate and count (float64[3] + float64[3] + int64), its k-nearest searches (int64).
MEDIA_PASS_BYTES = 24 + 24 + 8 + 8


def check_media_settings(scene, settings) -> None:
    """Before any photon is traced: what the camera pass in media does not do (the fixed grid of light
    samples), and the memory of a sample's camera pass (:func:`camera_pass_in_media`: the visible points with their
    medium segments, and MEDIA_PASS_BYTES)."""
    if not scene.has_media:
        return
    if settings.fixed_light_grid:
        raise ParameterError("--fixed-light-grid: not supported in a scene with media (docs/media.md)")
    n = settings.width * settings.height
    claim = bool(settings.get("caustic_photons"))   # a caustic map (PM+C): split points keep whole BSDF rows
    check_budget(n * (camera_pass_bytes(scene, claim) + MEDIA_PASS_BYTES),
                 f"the camera pass of {n:,} pixels in media (visible points and {MEDIUM_SEGMENTS} medium segments "
                 f"each)", "lower the resolution")


def claims_caustics(caustic_map) -> bool:
    """Whether the camera pass gathers a caustic map of its own (PM+C), whose records then claim a roughplastic's
    glossy share of the caustic at its split points, as sppm's separate caustic statistics do
    (:func:`~caustica.photons.gather.gather_radiance`'s ``claim``)."""
    return caustic_map.count > 0


def camera_pass(scene, settings, global_map, caustic_map, k_caustic, r_caustic, progress):
    """Render the image from the maps; returns (image, timings, number of k-nearest searches)."""
    cam = scene.camera(settings.width, settings.height)
    image = np.zeros((cam.height, cam.width, 3), np.float32)
    filt = FILTERS[settings.filter]

    n = cam.width * cam.height
    knn_queries = np.zeros(n, np.int32)
    bar = progress(total=n, desc="camera pass", unit="px")
    t0 = time.perf_counter()
    estimate = (settings.k, settings.radius, k_caustic, r_caustic, filt)
    params = (settings.light_samples, settings.fixed_light_grid, settings.max_specular_depth,
              max_depth_of(settings), settings.hide_emitters, claims_caustics(caustic_map))
    compile_s = parallel_for(gather_pixels, n, (scene.tables, (cam, settings.seed, settings.spp),
                                                (global_map, caustic_map), estimate, params, (image, knn_queries)),
                             threads=settings.threads, progress=bar)
    bar.close()
    return image, {"compile_s": compile_s, "camera_pass_s": time.perf_counter() - t0 - compile_s}, \
        int(knn_queries.sum())


def _sample_in_media(scene, settings, s, lookup, out, bar):
    """Camera sample s of :func:`camera_pass_in_media`: its visible points' surface estimate and its segments' beam
    estimate added to ``out`` = (the sum over the samples, the k-nearest searches); ``lookup`` = ((global map,
    caustic map), their estimates' parameters, the volume grid).  Returns (volume photons gathered, compile seconds).
    The sample's arrays are freed when it returns, before the next sample's camera pass allocates its own."""
    maps, estimate, vgrid = lookup
    acc, knn_queries = out
    n = settings.width * settings.height
    max_depth = max_depth_of(settings)
    vps, segments, c = progressive_camera_pass(scene, settings, s, bar, claim=claims_caustics(maps[1]))
    vp_pos, vp_nrm, vp_weight, vp_found, radiance = vps[:5]
    # rows: BSDF-evaluating points; a max_depth limits the records by each point's segments
    points = (vp_pos, vp_nrm, vp_found, vp_weight, vps.bsdf, scene.materials, vps.segments, max_depth)
    c += parallel_for(gather_at_visible_points, n, (maps, estimate, points, (radiance, knn_queries)),
                      threads=settings.threads)
    vol = np.empty((n, 3))
    found = np.empty(n, np.int64)
    c += parallel_for(beam_gather, n, (vgrid, scene.media, (segments, MEDIUM_SEGMENTS, max_depth), (vol, found)),
                      threads=settings.threads)
    acc += radiance
    acc += vol
    return int(found.sum()), c


def camera_pass_in_media(scene, settings, global_map, caustic_map, k_caustic, r_caustic, volume, progress):
    """:func:`camera_pass` in a scene with media: (image, timings, k-nearest searches, stats of the volume estimate).

    ``settings.spp`` samples per pixel, each the progressive camera pass in media
    (:func:`caustica.photons.visible_points.camera_pass`, sample s keyed as pass s): a
    visible point with its direct light, the direct light scattered along the path's medium
    segments, then the maps' k-nearest estimates at the visible point and the beam radiance
    estimate of ``volume`` (position, direction, power, depth of the volume photons) along the segments,
    within :func:`one_shot_volume_radius`.
    """
    w, h, spp = settings.width, settings.height, settings.spp
    n = w * h
    filt = FILTERS[settings.filter]
    r_v = one_shot_volume_radius(scene, settings)
    first_build = not volume_grid_compiled()
    t0 = time.perf_counter()
    position, direction, power, depth = volume
    vgrid = build_volume_grid(position, direction, power, r_v, depth)
    grid_s = time.perf_counter() - t0
    acc = np.zeros((n, 3))
    knn_queries = np.zeros(n, np.int64)
    gathered = 0
    compile_s = 0.0
    bar = progress(total=n * spp, desc="camera pass", unit="px")
    t0 = time.perf_counter()
    estimate = (settings.k, settings.radius, k_caustic, r_caustic, filt)
    for s in range(spp):
        found, c = _sample_in_media(scene, settings, s, ((global_map, caustic_map), estimate, vgrid),
                                    (acc, knn_queries), bar)
        gathered += found
        compile_s += c
    bar.close()
    image = (acc / spp).reshape(h, w, 3).astype(np.float32)
    timings = {"compile_s": compile_s, "camera_pass_s": time.perf_counter() - t0 - compile_s}
    if first_build:   # the grid's kernels compiled (or loaded) just now: compile time, not work
        timings["compile_s"] += grid_s
    else:
        timings["volume_grid_s"] = grid_s
    stats = {"volume_photons": vgrid.count, "volume_radius": r_v, "volume_photons_gathered": gathered}
    return image, timings, int(knn_queries.sum()), stats


class StreamedBSDFs:
    """What the stream methods (spm, pspm) render beyond diffuse surfaces, mirrors and glass (api.check_bsdfs): their
    camera sides are pm's and sppm's, and the stream tracer (photons/streams.py) meets each of these as the photon
    tracer does."""
    passes_glossy = True     # rough metal and glass: cameras sample them, streams meet them as mirrors
    renders_coated = True    # plastic: a record carries the coating's factor B of each photon's direction
    renders_rough_coated = True   # roughplastic: the same (streams.stream_at_diffuse)
    renders_mixtures = True  # mask, blendbsdf: resolved at each hit, per associated photon too (associated_surface)
    evaluates_bsdfs = True   # pplastic, principled, principledthin: the estimate weights each record by f at its
    #                          direction (a stream record's: its leading photon's), as pm's and sppm's photons
    renders_normal_maps = True   # normalmap, bumpmap: the leading photon's wrapped bounce (trace.bounce_at), each
    #                              associated photon's own hit resolved (streams.unwrapped); visible points: pm's, sppm's


class OneShotState:
    """The state of a one-shot method: nothing before its one pass, the image after it."""

    def __init__(self, image=None):
        self.image = image

    @property
    def passes(self) -> int:
        return 0 if self.image is None else 1


class OneShot(SceneDepths):
    """A method whose whole render is one pass: ``render_once(scene, settings, progress) -> (image, stats)``."""
    progressive = False

    @staticmethod
    def new_state(scene, settings):
        return OneShotState()

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        image, stats = cls.render_once(cls.path_scene(scene, settings), settings, progress)
        return OneShotState(image), stats

    @staticmethod
    def image(scene, settings, state):
        return state.image

    @staticmethod
    def final_stats(scene, settings, state):
        return {}
