"""The tables stage: a scene description flattened into the arrays the kernels read.

:func:`compile_scene` turns a :class:`SceneDescription` into a :class:`Scene`
holding the geometry (primitives + BVH), the material table, the light table and
the camera, and the medium table (trivial for a scene without media: no shape bounds a
medium and the camera is in none, so every kernel runs the vacuum case).  It is what
:func:`caustica.load_scene` returns.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .bsdfs import DELTA, DIFFUSE_REFLECTION, GLOSSY, MaterialTable, build_material_table, material_features, \
    null_transmitting
from .camera import CameraParams, camera_params, pixel_footprints
from .emitters import AREA, POINT, TEX_OF, TEXTURED_AREA, LightTable, build_light_table
from .errors import SceneError
from .features import ALL, bits, features_of, specialised
from .geometry.bounds import shape_bounding_sphere
from .geometry.scene_geometry import Geometry, build_geometry
from .media import MediumTable, build_medium_table, light_media, medium_features
from .scene.description import CONDUCTOR, DIELECTRIC, DIFFUSE, HETEROGENEOUS, HOMOGENEOUS, NULL, SceneDescription
from .scene.transforms import MAX_ABS_FLOAT


@dataclass
class Scene:
    description: SceneDescription
    geometry: Geometry
    materials: MaterialTable
    lights: LightTable
    timings: dict = field(default_factory=dict)
    media: MediumTable | None = None   # always built by compile_scene: trivial (no medium anywhere) without media
    _specular_spheres: np.ndarray | None = field(default=None, repr=False, compare=False)
    _null_thin: Scene | None = field(default=None, repr=False, compare=False)
    _light_media: np.ndarray | None = field(default=None, repr=False, compare=False)

    _footprints: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def name(self) -> str:
        return self.description.source

    def pixel_footprint(self, width: int, height: int) -> float:
        """The median width of a pixel (scene units) where the camera's rays through a 16 x 16 grid of the film first
        meet a surface that may hold a visible point (a diffuse reflection lobe, as the camera passes make them:
        :func:`caustica.photons.visible_points.camera_vertex`; straight on through the others, mirrors and rough metal
        too: :func:`caustica.camera.pixel_footprints`) at this resolution; inf where none does.  Computed once a
        resolution."""
        if (width, height) not in self._footprints:
            n = 16
            out = np.empty(n * n)
            stops = np.ascontiguousarray((self.materials.flags & DIFFUSE_REFLECTION) != 0)
            pixel_footprints(self.camera(width, height), self.geometry, stops, n, out)
            hits = out[np.isfinite(out)]
            self._footprints[(width, height)] = float(np.median(hits)) if hits.size else np.inf
        return self._footprints[(width, height)]

    @property
    def has_media(self) -> bool:
        """Whether the scene has media or null-BSDF boundaries (the volume estimates and media outputs run)."""
        return self.description.has_media

    @property
    def tables(self) -> tuple:
        """(geometry, materials, lights, media): what the kernels take as ``tables``."""
        return self.geometry, self.materials, self.lights, self.media

    def with_null_thin_dielectric(self) -> Scene:
        """This scene with a thindielectric's straight-on lobe made Mitsuba volpath's null event: a copy of the
        material table flagged ``NULL_TRANSMISSION`` there (:func:`caustica.bsdfs.null_transmitting`) and of the media
        table saying shadow rays may cross surfaces, so that they reach :func:`caustica.media.crossing`.  What a
        method that follows ``volpath``'s depths renders with (``null_thin_dielectric``); this scene stays as it is.
        Itself without a thindielectric.  Built once (every pass of sppm asks for it)."""
        if self._null_thin is None:
            flagged = null_transmitting(self.materials)
            self._null_thin = self if flagged is None else replace(
                self, materials=flagged, media=self._crossable_media(), _null_thin=None)
        return self._null_thin

    def _crossable_media(self) -> MediumTable:
        """The media table saying shadow rays may cross surfaces (``null_surfaces``), its features re-rounded
        (:func:`caustica.media.medium_features`) so that :func:`caustica.media.shadow_transmittance` keeps that code."""
        held = features_of(self.media)
        features = medium_features(held & bits(HETEROGENEOUS) != 0, held & bits(HOMOGENEOUS) != 0, True)
        return specialised(MediumTable, features)(*self.media._replace(null_surfaces=np.ones(1, np.int8)))

    def light_media(self) -> np.ndarray:
        """int32[L]: the medium each light emits into (:func:`caustica.media.light_media`); probed once, as every
        photon pass asks for it."""
        if self._light_media is None:
            self._light_media = light_media(self)
        return self._light_media

    @property
    def width(self) -> int:
        return self.description.camera.width

    @property
    def height(self) -> int:
        return self.description.camera.height

    @property
    def spp(self) -> int:
        return self.description.spp

    def camera(self, width: int | None = None, height: int | None = None) -> CameraParams:
        return camera_params(self.description.camera, width, height)

    def specular_shapes(self) -> list[int]:
        """Indices of the shapes that cast caustics: a BSDF with delta or glossy lobes and no diffuse one (mirror,
        glass, rough metal, rough glass; the aimed caustic photons' targets)."""
        flags = self.materials.flags
        return [i for i, s in enumerate(self.description.shapes)
                if flags[s.material] & (DELTA | GLOSSY) and not flags[s.material] & DIFFUSE_REFLECTION]

    def specular_bounding_spheres(self) -> np.ndarray:
        """(n, 4) centre + radius of a tight sphere containing each specular shape (the caustic map's targets).

        Analytic shapes get their own sphere (radius 4 for the diacaustic scene's glass
        sphere), meshes a near-minimal sphere about their vertices
        (:mod:`caustica.geometry.bounds`); computed once per scene.
        """
        if self._specular_spheres is None:
            out = []
            for s in self.specular_shapes():
                centre, radius = shape_bounding_sphere(self.geometry, s)
                out.append([*centre, radius])
            self._specular_spheres = np.asarray(out, dtype=np.float64).reshape(-1, 4)
        return self._specular_spheres.copy()

    def __repr__(self) -> str:
        d = self.description
        return (f"Scene({d.source!r}, {len(d.shapes)} shapes, {self.geometry.prim_kind.shape[0]} primitives, "
                f"{self.lights.kind.shape[0]} lights, {self.width}x{self.height}, spp {self.spp})")


def compile_scene(desc: SceneDescription) -> Scene:
    t0 = time.perf_counter()
    geom = build_geometry(desc)
    t1 = time.perf_counter()
    lights = build_light_table(desc, geom)
    if lights.kind.shape[0] == 0:
        raise SceneError(f"{desc.source}: the scene has no emitter; add an <emitter type=\"area\"> "
                         f"inside a shape, an <emitter type=\"point\">, \"spot\", \"projector\", \"directional\", \"constant\" or "
                         f"\"envmap\"")
    _check_light_power(desc, lights)
    mats, lights = specialise(build_material_table(desc), lights)
    media = build_medium_table(desc)
    return Scene(desc, geom, mats, lights, {"geometry_build_s": t1 - t0}, media)


#: The feature sets kernels are compiled for (:mod:`caustica.features`): a scene whose materials and lights all lie
#: in these (the paper's scenes: diffuse walls, mirrors, glass, media behind null boundaries, area and point lights)
#: gets kernels with the code of these kinds alone; any other scene gets every kind's code.  Two sets, so a kernel
#: compiles at most twice (each set once, then cached).  The diacaustic scene's spm render compiled in 53 CPU s with
#: the core set, 80 s with every kind (docs/results.md, 2026-12-04).
CORE_MATERIALS = bits(DIFFUSE, CONDUCTOR, DIELECTRIC, NULL)
CORE_LIGHTS = bits(AREA, POINT)


def specialise(mats: MaterialTable, lights: LightTable) -> tuple[MaterialTable, LightTable]:
    """The material and light tables as instances of the classes of their feature set (CORE_*, or ALL)."""
    textured = np.any((lights.kind == AREA) & (lights.tex_int[:, TEX_OF] != 0))
    light_features = bits(*np.unique(lights.kind)) | (bits(TEXTURED_AREA) if textured else 0)
    core = material_features(mats) & ~CORE_MATERIALS == 0 and light_features & ~CORE_LIGHTS == 0
    return (specialised(MaterialTable, CORE_MATERIALS if core else ALL)(*mats),
            specialised(LightTable, CORE_LIGHTS if core else ALL)(*lights))


def _check_light_power(desc: SceneDescription, lights: LightTable) -> None:
    """The emitted power must stay within float32, in which photon powers are stored.

    Radiance and sizes are each checked when read, but their product (pi x radiance x
    area) is not: a radiance of 1e30 on a shape of area 1e20 would make every photon's
    power infinite.  The lights table lists the area emitters in shape order, then the
    point and spot lights, the projectors, the directional lights and the environment.
    """
    rows = ([(s.source, "pi x radiance x area") for s in desc.shapes if s.emitter_radiance is not None]
            + [(p.source, "4 pi x intensity" if p.axis is None else "2 pi x intensity x the falloff's integral"
                if p.texture is None else "intensity x the integral of the falloff times the texture")
               for p in desc.point_lights]
            + [(p.source, "pi x scale x the image's area at distance 1 x its mean irradiance") for p in desc.projectors]
            + [(d.source, "pi R^2 x irradiance, R the scene's bounding radius") for d in desc.directional_lights]
            + ([(desc.environment.source, "pi R^2 x the radiance's integral over the sphere, R the scene's "
                                          "bounding radius")] if desc.environment is not None else []))
    total = lights.power.sum(axis=0)
    if np.all(total <= MAX_ABS_FLOAT):
        return
    i = int(np.argmax(lights.power.max(axis=1)))
    source, what = rows[i]
    raise SceneError(f"{source or desc.source}: the emitter's power ({what}) is "
                     f"{float(lights.power[i].max()):.3g} W, and the scene's lights emit "
                     f"{float(total.max()):.3g} W in all, beyond {MAX_ABS_FLOAT:.3g} (float32, in which photon "
                     f"powers are stored); lower the radiance or the emitter's size")
