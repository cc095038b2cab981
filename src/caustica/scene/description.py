"""The parsed scene: plain Python objects between the XML file and the kernels' arrays.

The XML loader (:mod:`caustica.scene.xml_loader`) produces a :class:`SceneDescription`;
:mod:`caustica.tables` flattens it into the structure-of-arrays form the
kernels read.  Everything here is in world space and in Mitsuba's units: radiance in
W/(m^2 sr) per RGB channel, intensity in W/sr, lengths in scene units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import ParameterError, shorten

# Material kinds (also the integer codes stored in the kernels' material table).
DIFFUSE = 0
CONDUCTOR = 1
DIELECTRIC = 2
NULL = 3  # Mitsuba's null BSDF: an invisible boundary (of a medium) that rays cross unchanged
ROUGHCONDUCTOR = 4   # Mitsuba's roughconductor: a microfacet metal (bsdfs/roughconductor.py)
ROUGHDIELECTRIC = 5  # Mitsuba's roughdielectric: microfacet glass, Walter et al. 2007 (bsdfs/roughdielectric.py)
PLASTIC = 6          # Mitsuba's plastic: a smooth dielectric coating over a diffuse base (bsdfs/plastic.py)
ROUGHPLASTIC = 7     # Mitsuba's roughplastic: a microfacet coating over a diffuse base (bsdfs/roughplastic.py)
THINDIELECTRIC = 8   # Mitsuba's thindielectric: a thin glass slab, light reflected or straight on (bsdfs/thindielectric.py)
MASK = 9             # Mitsuba's mask: its nested BSDF with probability opacity, else no surface (bsdfs/mixtures.py)
BLEND = 10           # Mitsuba's blendbsdf: (1 - weight) f0 + weight f1 of two nested BSDFs (bsdfs/mixtures.py)
NORMALMAP = 11       # Mitsuba's normalmap: its nested BSDF with a shading normal from a bitmap (bsdfs/perturb.py)
BUMPMAP = 12         # Mitsuba's bumpmap: its nested BSDF with a shading normal from a height field (bsdfs/perturb.py)
PPLASTIC = 13        # Mitsuba's pplastic (RGB): a microfacet reflection plus a Fresnel-weighted diffuse lobe (bsdfs/pplastic.py)
PRINCIPLED = 14      # Mitsuba's principled: Disney's BSDF as Mitsuba 3 writes it (bsdfs/principled.py)
PRINCIPLEDTHIN = 15  # Mitsuba's principledthin: Disney's thin-surface BSDF (bsdfs/principledthin.py)
MATERIAL_NAMES = {DIFFUSE: "diffuse", CONDUCTOR: "conductor", DIELECTRIC: "dielectric", NULL: "null",
                  ROUGHCONDUCTOR: "roughconductor", ROUGHDIELECTRIC: "roughdielectric", PLASTIC: "plastic",
                  ROUGHPLASTIC: "roughplastic", THINDIELECTRIC: "thindielectric", MASK: "mask", BLEND: "blendbsdf",
                  NORMALMAP: "normalmap", BUMPMAP: "bumpmap", PPLASTIC: "pplastic", PRINCIPLED: "principled",
                  PRINCIPLEDTHIN: "principledthin"}
#: A principled BSDF's scalar parameters (Mitsuba's names, in the order of its table columns: bsdfs/principled.py)
#: and their defaults; base_color, anisotropic and eta / specular are read apart.
PRINCIPLED_PARAMS = {"roughness": 0.5, "metallic": 0.0, "spec_trans": 0.0, "spec_tint": 0.0, "sheen": 0.0,
                     "sheen_tint": 0.0, "clearcoat": 0.0, "clearcoat_gloss": 0.0, "flatness": 0.0,
                     "main_specular_sampling_rate": 1.0, "clearcoat_sampling_rate": 1.0,
                     "diffuse_reflectance_sampling_rate": 1.0}
#: A principledthin BSDF's scalar parameters (Mitsuba's names) and their defaults; base_color, anisotropic and eta are
#: read apart (bsdfs/principledthin.py gives their table columns).
PRINCIPLEDTHIN_PARAMS = {"roughness": 0.5, "spec_trans": 0.0, "spec_tint": 0.0, "sheen": 0.0, "sheen_tint": 0.0,
                         "flatness": 0.0, "diff_trans": 0.0, "specular_reflectance_sampling_rate": 1.0,
                         "specular_transmittance_sampling_rate": 1.0, "diffuse_reflectance_sampling_rate": 1.0,
                         "diffuse_transmittance_sampling_rate": 1.0}
#: The mixtures: a hit on one of them is resolved to one of its nested BSDFs (or to no surface) with one random
#: number (bsdfs/mixtures.py), so that no loop ever scatters at a mixture itself.
MIXTURES = (MASK, BLEND)
#: The wrappers that perturb the shading normal: a hit on one is resolved to its nested BSDF with the perturbed
#: normal (bsdfs/perturb.py), so that no loop ever scatters at a wrapper itself.
WRAPPERS = (NORMALMAP, BUMPMAP)
#: Kinds with a glossy lobe: the photon methods do not render them yet (issue 20), only ``pt``.

# Microfacet distributions (Mitsuba's names; the codes the material table stores).
BECKMANN = 0
GGX = 1
DISTRIBUTIONS = {"beckmann": BECKMANN, "ggx": GGX}


@dataclass
class Material:
    """A BSDF of the supported subset.

    kind: DIFFUSE (``rgb`` = reflectance), CONDUCTOR (a perfect mirror, ``rgb`` =
    specular_reflectance), DIELECTRIC (smooth glass, ``int_ior`` / ``ext_ior``,
    ``rgb`` = specular_transmittance, ``specular`` = specular_reflectance, both 1 unless tinted) or NULL (no surface:
    rays cross it unchanged; the boundary of a medium, see :class:`Medium`).  THINDIELECTRIC: a thin glass
    slab (a pane as one sheet), ``int_ior`` / ``ext_ior`` and ``rgb`` as DIELECTRIC's, light reflected or
    passing straight on.
    ROUGHCONDUCTOR and ROUGHDIELECTRIC are the microfacet versions of CONDUCTOR and DIELECTRIC, with
    ``distribution`` (BECKMANN or GGX) and ``alpha`` (roughness; with ``alpha_v`` set and different, alpha is
    Mitsuba's alpha_u along dp/du and alpha_v the roughness across it: :attr:`anisotropic`).  A conductor (smooth or
    rough) with ``conductor_eta`` / ``conductor_k`` (RGB complex IOR) has their Fresnel reflectance;
    without them (Mitsuba's ``material="none"``) F = 1.
    PLASTIC and ROUGHPLASTIC: ``rgb`` = diffuse_reflectance, ``specular`` = specular_reflectance, the
    coating's ``int_ior`` / ``ext_ior`` (defaults polypropylene and air), ``nonlinear``; ROUGHPLASTIC also
    ``distribution`` and ``alpha``.
    PRINCIPLED: ``rgb`` = base_color (or ``texture``), ``principled`` its other parameters, ``distribution`` GGX and
    ``alpha``, ``alpha_v`` from its roughness and anisotropic, ``int_ior`` its eta.
    PRINCIPLEDTHIN: as PRINCIPLED with its own parameters (``principled``, eta among them; ``int_ior`` = ``ext_ior``:
    no refraction).  Either's scalar parameters may be given by textures instead, ``param_textures`` (by Mitsuba's
    names, read by their eval_1 at each surface point).
    PPLASTIC: ``rgb`` = diffuse_reflectance, ``specular`` = specular_reflectance, ``distribution``, ``alpha`` and the
    relative IOR ``int_ior`` / ``ext_ior`` (Mitsuba's ``eta`` is read as int_ior = eta, ext_ior = 1).
    texture: a :class:`Texture` that gives ``rgb`` at each surface point instead (diffuse ``reflectance``,
    a conductor's ``specular_reflectance``, a plastic's or pplastic's ``diffuse_reflectance``, glass's
    ``specular_transmittance``); ``rgb`` is then its mean.
    MASK and BLEND (the mixtures, :data:`MIXTURES`): ``nested`` holds the indices of the nested materials (one for
    a mask, two for a blend, f0 then f1) in the scene's material list; ``mix`` is the opacity (mask) or the weight
    of f1 (blend), in [0, 1], or ``mix_texture`` gives it at each surface point (the texture's luminance, clipped to
    [0, 1] as Mitsuba's ``eval_1``).
    NORMALMAP and BUMPMAP (the wrappers, :data:`WRAPPERS`): ``nested`` holds the one nested material, ``mix_texture``
    the map (a normal map's RGB, a bump map's heights as luminance), ``mix`` a bump map's ``scale``.  The nested
    row is the wrapper's own copy, with ``terminator`` set unless Mitsuba's ``use_shadowing_function`` is false:
    that row's f carries the shadowing factor for the bump terminator (bsdfs/perturb.py).
    twosided: a diffuse or conductor surface that scatters on both sides
    (Mitsuba's ``twosided`` wrapper); plain diffuse and conductor surfaces are
    black seen from the back, as in Mitsuba.
    """
    kind: int
    rgb: tuple[float, float, float] = (0.5, 0.5, 0.5)
    int_ior: float = 1.5046
    ext_ior: float = 1.000277
    twosided: bool = False
    name: str = ""
    distribution: int = BECKMANN
    alpha: float = 0.1                 # microfacet roughness (Mitsuba's default)
    conductor_eta: tuple[float, float, float] | None = None
    conductor_k: tuple[float, float, float] = (0.0, 0.0, 0.0)
    specular: tuple[float, float, float] = (1.0, 1.0, 1.0)   # a plastic's or glass's specular_reflectance
    nonlinear: bool = False            # a plastic's nonlinear colour shift (Mitsuba's ``nonlinear``)
    source: str = ""  # "file:line" for messages
    texture: "Texture | None" = None   # varies ``rgb`` over the surface (the diffuse or specular reflectance)
    nested: tuple[int, ...] = ()        # a mixture's nested materials (indices into the scene's materials)
    mix: float = 0.5                    # a mask's opacity, a blend's weight of nested[1]
    mix_texture: "Texture | None" = None   # gives ``mix`` at each surface point instead (its luminance); a
    #                                        wrapper's normal or height map
    terminator: bool = False            # the nested row of a wrapper with use_shadowing_function
    alpha_v: float | None = None        # anisotropic roughness across dp/du (``alpha`` is then alpha_u); None: alpha
    alpha_textures: tuple = (None, None)   # Textures giving alpha_u and alpha_v instead (their eval_1), or None each
    principled: dict | None = None      # a principled BSDF's parameters by Mitsuba's names (bsdfs/principled.py)
    param_textures: dict = field(default_factory=dict)   # Textures giving some of ``principled`` instead, by name

    @property
    def anisotropic(self) -> bool:
        """Whether the microfacet roughness differs along and across dp/du (the BSDF needs the shading frame)."""
        u, v = self.alpha_textures
        return (self.alpha_v is not None and self.alpha_v != self.alpha) or u is not v or \
            "anisotropic" in self.param_textures

    @property
    def is_specular(self) -> bool:
        return self.kind in (CONDUCTOR, DIELECTRIC, THINDIELECTRIC)


@dataclass
class Mesh:
    """A triangle mesh in world space.

    positions (n, 3) float64; triangles (m, 3) int64 vertex indices, counter-clockwise
    seen from the front (the side the geometric normal points to); normals (n, 3)
    float64 unit shading normals or None (then the geometric normal shades); uvs (n, 2)
    float64 texture coordinates as Mitsuba has them (an OBJ's v already flipped), or None
    (then a triangle's uv is its barycentric coordinates (b1, b2), as in Mitsuba).
    """
    positions: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    #: Mitsuba's mesh attributes by name: ``vertex_*`` (n, dim) or ``face_*`` (m, dim, one row per triangle) float32,
    #: dim 1 to 4 (a PLY file's extra properties, :func:`caustica.scene.meshes.ply_attributes`).
    attributes: dict | None = None


# Texture kinds (the codes of the material table's texture columns).
CHECKERBOARD = 0
BITMAP = 1
MESH_ATTRIBUTE = 2
TEXTURE_NAMES = {CHECKERBOARD: "checkerboard", BITMAP: "bitmap", MESH_ATTRIBUTE: "mesh_attribute"}
FILTER_TYPES = {"nearest": 0, "bilinear": 1}
WRAP_MODES = {"repeat": 0, "mirror": 1, "clamp": 2}


@dataclass
class Texture:
    """A ``<texture>``: Mitsuba 3's ``checkerboard`` or ``bitmap``, looked up at a surface point's (u, v).

    ``to_uv`` (2, 3): the affine map applied to (u, v) first (Mitsuba's ``to_uv``: a 4x4 transform's rows and
    columns x, y and translation).  CHECKERBOARD: ``color0`` where the fractional parts of u and v are both above
    1/2 or both not, ``color1`` elsewhere.  BITMAP: ``texels`` (height, width, 3) float32, linear RGB (sRGB
    already decoded), row 0 at v = 0 (the image's top row); ``filter`` and ``wrap`` are codes of
    :data:`FILTER_TYPES` and :data:`WRAP_MODES`.  MESH_ATTRIBUTE: the mesh's attribute ``attribute`` (a
    ``vertex_*`` one interpolated with the hit's barycentrics, a ``face_*`` one the triangle's) times ``scale``.
    """
    kind: int
    to_uv: np.ndarray = field(default_factory=lambda: np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    color0: tuple[float, float, float] = (0.4, 0.4, 0.4)
    color1: tuple[float, float, float] = (0.2, 0.2, 0.2)
    texels: np.ndarray | None = None
    filter: int = 1
    wrap: int = 0
    id: str = ""
    source: str = ""  # "file:line" for messages
    attribute: str = ""
    scale: float = 1.0
    #: Why this texture cannot be rendered, for one that is read and checked as Mitsuba 3 loads it (a ``volume``
    #: texture: its value at a surface point's world position) but may only stay unused: a shape whose BSDF or emitter
    #: reads it is refused (``xml_loader``'s ``check_textures_used``); it holds a 1 x 1 mid-grey BITMAP, never rendered.
    unrenderable: str = ""


# Phase functions of a medium.
ISOTROPIC = 0
HENYEY_GREENSTEIN = 1
PHASE_NAMES = {ISOTROPIC: "isotropic", HENYEY_GREENSTEIN: "hg"}

# Kinds of medium (the medium table's feature codes, caustica.features).
HOMOGENEOUS = 0     # Mitsuba's homogeneous: constant coefficients, free flights and transmittance in closed form
HETEROGENEOUS = 1   # Mitsuba's heterogeneous: coefficients from volumes (grids), null-collision tracking
MEDIUM_NAMES = {HOMOGENEOUS: "homogeneous", HETEROGENEOUS: "heterogeneous"}

# How a grid volume is read between its voxels (Mitsuba's filter_type), and beyond its unit cube (wrap_mode).
TRILINEAR = 0
NEAREST = 1
CLAMP = 0
REPEAT = 1


@dataclass(eq=False)
class Volume:
    """A heterogeneous medium's ``sigma_t`` or ``albedo``: Mitsuba's ``gridvolume`` or ``constvolume``.

    ``data``: float32 (nz, ny, nx, channels), channels 1 (grey) or 3 (RGB), voxel (x, y, z) at
    data[z, y, x] as in Mitsuba's .vol files; a constant is a grid of one voxel.  ``to_local``: 4 x 4, world to
    the grid's unit cube [0, 1]³ (the inverse of its ``to_world``, and of the file's bounding box with
    ``use_grid_bbox``); voxel i's value sits at (i + 1/2) / n, a point between voxel centres is ``filter``ed
    (TRILINEAR or NEAREST), and one beyond the outer centres takes the edge's value (``wrap`` CLAMP, Mitsuba's
    default) or the grid repeats (REPEAT).
    """
    data: np.ndarray
    to_local: np.ndarray
    filter: int = TRILINEAR
    wrap: int = CLAMP
    filename: str = ""
    source: str = ""   # "file:line" for messages

    @cached_property
    def voxel_edges(self) -> list[float]:
        """The world length of a voxel's edge along each local axis (x, y, z) on which the values change (a grid
        constant along an axis, one voxel thick included, has no voxel boundaries there).  Read once: the data are
        not changed after loading."""
        to_world = np.linalg.inv(self.to_local)
        edges = []
        for axis, n in enumerate(self.data.shape[2::-1]):   # data is (z, y, x, channels)
            along = np.moveaxis(self.data, 2 - axis, 0)
            if n > 1 and np.any(along != along[:1]):
                edges.append(float(np.linalg.norm(to_world[:3, axis])) / n)
        return edges

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the world box holding the unit cube mapped by ``to_world`` (Mitsuba's volume bbox)."""
        to_world = np.linalg.inv(self.to_local)
        corners = np.array([[x, y, z, 1.0] for x in (0, 1) for y in (0, 1) for z in (0, 1)]) @ to_world.T
        pts = corners[:, :3] / corners[:, 3:]
        return pts.min(axis=0), pts.max(axis=0)


@dataclass
class Medium:
    """A participating medium: Mitsuba's ``homogeneous`` or ``heterogeneous`` (``kind``).

    ``sigma_t``: extinction coefficient per scene unit per RGB channel, already multiplied
    by the file's ``scale``; ``albedo``: single-scattering albedo sigma_s / sigma_t per
    channel, in [0, 1]; ``phase``: ISOTROPIC or HENYEY_GREENSTEIN with asymmetry ``g`` in
    (-1, 1) (g > 0 scatters forwards).  A shape's ``interior`` / ``exterior`` and the
    camera's ``medium`` are indices into :attr:`SceneDescription.media` (-1: none).
    A heterogeneous medium's coefficients are ``sigma_t_volume`` (``scale`` applied to its data) and
    ``albedo_volume``; as in Mitsuba it exists only inside the world box of its ``sigma_t`` volume
    (:meth:`Volume.bounds`), and ``sigma_t`` / ``albedo`` hold zeros.  A homogeneous medium with a <volume> albedo
    (Mitsuba's homogeneous takes one) is such a medium too, with a constant sigma_t and ``bounded`` False: it fills
    its shapes, as every homogeneous medium does.
    """
    sigma_t: tuple[float, float, float] = (1.0, 1.0, 1.0)
    albedo: tuple[float, float, float] = (0.75, 0.75, 0.75)
    phase: int = ISOTROPIC
    g: float = 0.0
    id: str = ""
    source: str = ""  # "file:line" for messages
    kind: int = HOMOGENEOUS
    sigma_t_volume: Volume | None = None
    albedo_volume: Volume | None = None
    bounded: bool = True


# Shape kinds.
MESH = "mesh"
SPHERE = "sphere"
DISK = "disk"
CYLINDER = "cylinder"


@dataclass
class Shape:
    """One ``<shape>``.

    kind MESH holds ``mesh`` (rectangles, cubes, obj and ply become meshes).
    The analytic kinds are a canonical shape mapped by ``to_world`` (4x4):
    SPHERE the unit sphere at the origin, DISK the unit disk in the z = 0 plane
    facing +z, CYLINDER the open cylinder of radius 1 from z = 0 to z = 1 facing
    outwards.  ``flip_normals`` turns the front side around (for meshes it is
    already applied to the winding and normals).  ``emitter_radiance`` is the RGB
    radiance of an ``area`` emitter on the shape's front side, or None; ``emitter_texture`` the texture that
    radiance is multiplied by at each point's surface coordinates (Mitsuba's textured area emitter; the
    radiance is then (1, 1, 1)), or None.
    ``interior`` / ``exterior``: the media behind and in front of the surface (indices
    into :attr:`SceneDescription.media`, -1 for none).  As in Mitsuba, a ray that leaves
    a surface towards its front enters the exterior medium and towards its back the
    interior one, and a shape with neither leaves the ray's medium as it was.
    """
    kind: str
    material: int
    to_world: np.ndarray | None = None
    mesh: Mesh | None = None
    flip_normals: bool = False
    emitter_radiance: tuple[float, float, float] | None = None
    emitter_texture: Texture | None = None
    id: str = ""
    source: str = ""  # "file:line" for messages
    interior: int = -1
    exterior: int = -1


def signed_volume(mesh: Mesh, chunk: int = 1 << 18) -> tuple[float, float]:
    """(the volume a mesh's winding encloses, its area): positive where its faces point outwards, negative where
    they point inwards (a closed mesh; an open one's depends on where it is); flat, about 0 against area^1.5.  About
    the vertices' mean, in chunks of triangles (no array over the whole mesh)."""
    p = mesh.positions - mesh.positions.mean(axis=0)
    volume = area = 0.0
    for i in range(0, len(mesh.triangles), chunk):
        t = mesh.triangles[i:i + chunk]
        a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
        volume += float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0
        area += float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()) / 2.0
    return volume, area


@dataclass
class PointLight:
    """A point light (Mitsuba 3's ``point``), or a spot light (``spot``) when ``axis`` is given: then its
    intensity falls off with the angle θ from the axis as Mitsuba's does (1 within ``beam_width``, linearly in θ
    to 0 at ``cutoff_angle``, both in degrees; :func:`caustica.emitters.spot_falloff`)."""
    position: tuple[float, float, float]
    intensity: tuple[float, float, float]  # W/sr per channel (a spot's, on its axis)
    source: str = ""  # "file:line" for messages
    axis: tuple[float, float, float] | None = None   # a spot's unit beam direction in the world; None: a point light
    cutoff_angle: float = 180.0   # degrees
    beam_width: float = 180.0     # degrees, <= cutoff_angle
    #: a spot's projected ``texture`` (Mitsuba's): its intensity times the texture at
    #: uv = (1/2 + x / (2 z tan γ), 1/2 + y / (2 z tan γ)), (x, y, z) the direction in the spot's frame, γ its cutoff
    texture: "Texture | None" = None
    #: a textured spot's frame: 3x3, columns its unit x, y and z (= axis) in the world
    frame: np.ndarray | None = None


def fov_tangents(fov_deg: float, fov_axis: str, aspect: float) -> tuple[float, float]:
    """tan(fov_x / 2), tan(fov_y / 2) of an image of width / height ``aspect`` whose field of view is ``fov_deg``
    along ``fov_axis`` (x, y, diagonal, smaller or larger), as Mitsuba 3's parse_fov reads them (the perspective
    camera's and the projector's)."""
    axis = fov_axis
    if axis == "smaller":
        axis = "y" if aspect > 1 else "x"
    elif axis == "larger":
        axis = "x" if aspect > 1 else "y"
    t = math.tan(math.radians(fov_deg) / 2)
    if axis == "x":
        return t, t / aspect
    if axis == "y":
        return t * aspect, t
    if axis == "diagonal":
        tx = t / math.sqrt(1.0 + 1.0 / (aspect * aspect))
        return tx, tx / aspect
    raise ValueError(f"fov_axis '{fov_axis}' is not supported; supported: x, y, diagonal, smaller, larger")


@dataclass
class Projector:
    """A projection light (Mitsuba 3's ``projector``): a point light at ``position`` that projects an image through
    a pinhole, as a perspective camera at the same place would see it.  In its ``frame`` (3x3, columns its unit x,
    y, z in the world; it shines along +z) the direction (x, y, z) meets the image at
    uv = (1/2 − x / (2 z tan_x), 1/2 − y / (2 z tan_y)) (u along −x, as in Mitsuba's camera), and its intensity there
    is π ``scale`` E(uv) / cos³θ (W/sr; θ the angle from +z, E the irradiance ``texture`` or the constant
    ``irradiance``): a plane at distance z facing it receives π scale E / z² (Mitsuba's convention; 0 outside the
    image).  ``tan_x``, ``tan_y``: tangents of the half fields of view (tan_y = tan_x / aspect, the aspect the
    texture's width / height, 1 for a constant)."""
    position: tuple[float, float, float]
    frame: np.ndarray
    irradiance: tuple[float, float, float] = (1.0, 1.0, 1.0)   # the constant image (W/m² over π, per channel)
    texture: "Texture | None" = None                             # the image instead (a bitmap or checkerboard)
    scale: float = 1.0
    tan_x: float = 1.0
    tan_y: float = 1.0
    source: str = ""  # "file:line" for messages


@dataclass
class DirectionalLight:
    """A light at infinity shining along one direction (Mitsuba 3's ``directional``): ``irradiance`` (W/m² per
    channel) on a surface facing it, arriving from -``direction`` (unit, the way the light travels)."""
    direction: tuple[float, float, float]
    irradiance: tuple[float, float, float]
    source: str = ""  # "file:line" for messages


@dataclass
class Environment:
    """An environment emitter: light from infinitely far away, in every direction (Mitsuba 3's ``constant``
    and ``envmap``).

    ``kind`` "constant" (``radiance`` RGB from every direction) or "envmap": ``image`` float64 (H, W, 3) of
    linear RGB radiance, ``scale`` already applied, in Mitsuba's latitude-longitude layout, mapped to the
    world by the rotation ``to_world`` (3x3, the emitter's ``to_world`` without translation).
    """
    kind: str
    radiance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    image: np.ndarray | None = None
    to_world: np.ndarray | None = None
    filename: str = ""
    source: str = ""  # "file:line" for messages


@dataclass
class ReconstructionFilter:
    """The film's ``<rfilter>``: ``kind`` box, tent or gaussian (Mitsuba 3's definitions, see
    :mod:`caustica.sampling.filters`); ``radius`` the tent's radius in pixels (Mitsuba's default 1;
    unused by the others: the box's is 1/2, the gaussian's 4 ``stddev``); ``stddev`` the gaussian's
    standard deviation in pixels (Mitsuba's default 0.5).  A film without ``<rfilter>`` (and a sensor
    without a film) gets Mitsuba 3's default: a gaussian of ``stddev`` 0.5, cut off at radius 2."""
    kind: str = "gaussian"
    radius: float = 1.0
    stddev: float = 0.5


@dataclass
class Camera:
    """A perspective or orthographic camera in Mitsuba's convention.

    to_world maps camera space (looking along +z, +y up, +x towards the image's
    left) to the world; fov_deg is measured along ``fov_axis`` (x, y, diagonal, smaller or larger).
    ``medium``: the medium the camera sits in (an index into the scene's media, -1 for none).
    ``near_clip``: camera rays start on the plane at this depth (Mitsuba's near clip plane).
    ``far_clip``: Mitsuba's far clip plane (camera rays end at this depth).  caustica's camera rays do not
    stop there yet; the loader refuses a ``far_clip`` that any shape reaches beyond, so it changes nothing.
    ``rfilter``: the film's reconstruction filter; ``sample_border``: whether samples may land
    beyond the film's edge (Mitsuba's film ``sample_border``; off: a filter is truncated at the edge).
    ``projection``: "perspective", or "orthographic" (Mitsuba's: parallel rays along camera +z from the near
    plane's [-1, 1] x [-1/aspect, 1/aspect], which to_world's scale sizes; no fov).  ``aperture_radius`` > 0:
    Mitsuba's thin lens, rays from a uniform point of the lens disc through the point of the plane at depth
    ``focus_distance`` that the pinhole ray of the same film position meets.
    """
    to_world: np.ndarray
    fov_deg: float
    fov_axis: str = "x"
    width: int = 768
    height: int = 576
    near_clip: float = 1e-2
    far_clip: float = 1e4
    film_source: str = ""  # "file:line" of the <film> (of the <sensor> without one), for messages
    medium: int = -1
    rfilter: ReconstructionFilter = field(default_factory=ReconstructionFilter)
    sample_border: bool = False
    projection: str = "perspective"
    aperture_radius: float = 0.0   # a thin lens's radius (0: a pinhole)
    focus_distance: float = 1e4    # a thin lens's plane in focus, along camera +z (Mitsuba's default: far_clip)


#: Mitsuba integrators whose image pt renders: their ``max_depth`` and ``rr_depth`` are pt's defaults, and the
#: photon methods' max_depth (``direct``: paths of at most two segments, max_depth 2; ``ptracer`` traces from the
#: lights, to the same image; ``volpathmis`` is volpath with spectral MIS: the same image and settings).
SCENE_INTEGRATORS = ("path", "volpath", "volpathmis", "ptracer", "direct")
#: The integrators for which a thindielectric's straight-on transmission is a null event (Mitsuba's ``Null`` lobe,
#: which ``volpath`` does not count as a bounce and lets shadow rays through): ``null_thin_dielectric`` of pt and the
#: photon methods.
NULL_THIN_INTEGRATORS = ("volpath", "volpathmis")


@dataclass
class IntegratorSettings:
    """The scene file's ``<integrator>``, as the methods may read it (Mitsuba 3's defaults without one).

    ``type``: the integrator that renders the image ("path", "volpath", "direct", "ptracer", ... any name:
    the loader does not check it, caustica picks its own method); when the file wraps it in a ``moment``,
    ``aov`` or ``stokes`` integrator, ``type`` is the wrapped one and ``wrapper`` the wrapper's type.
    ``max_depth`` (-1: unbounded; Mitsuba counts the camera ray's first segment as depth 1, so 1 is only
    directly visible emitters), ``rr_depth`` (the depth from which Russian roulette starts) and
    ``hide_emitters`` (emitters seen directly by the camera render black) are Mitsuba's settings, checked
    as Mitsuba checks them (max_depth >= -1, rr_depth > 0).  ``props``: every property of the (wrapped)
    integrator as read, for settings of other types (``emitter_samples`` of ``direct``, ...).
    ``source`` / ``wrapper_source``: "file:line" of the elements, "" when absent.
    """
    type: str = "path"
    max_depth: int = -1
    rr_depth: int = 5
    hide_emitters: bool = False
    wrapper: str = ""
    props: dict = field(default_factory=dict)
    source: str = ""
    wrapper_source: str = ""

    @property
    def asked_depth(self) -> int:
        """The max_depth this integrator asks for: 2 for ``direct`` (direct light only), else its own (-1:
        unlimited)."""
        return 2 if self.type == "direct" else self.max_depth

    def path_depth(self) -> int:
        """:attr:`asked_depth`, the max_depth a method renders with; 0, an image with nothing in it, not even the
        emitters, is refused."""
        if self.asked_depth == 0:
            raise ParameterError(f"integrator '{self.type}' in {self.source}: max_depth 0 renders nothing (not even "
                                 f"the emitters); give -1 (unlimited) or a depth of at least 1")
        return self.asked_depth


#: The photon bounces that stand for an unlimited depth in :meth:`SceneDescription.integrator_note`.
UNLIMITED_BOUNCES = 64


@dataclass
class SceneDescription:
    """A whole scene.  ``integrator_settings`` is the file's ``<integrator>`` (:class:`IntegratorSettings`:
    type, max_depth, rr_depth, hide_emitters; Mitsuba's defaults when the file has none).
    ``integrator`` / ``integrator_props`` / ``integrator_source`` repeat its type, properties and "file:line"
    ("" when the file has none).  The method is chosen when rendering; ``pt`` takes the depths of the
    integrators whose image it renders (its ``scene_defaults``; :meth:`integrator_note` says what else is
    not read, docs/methods.md)."""
    camera: Camera
    shapes: list[Shape] = field(default_factory=list)
    materials: list[Material] = field(default_factory=list)
    point_lights: list[PointLight] = field(default_factory=list)
    spp: int = 4
    integrator: str = "path"
    integrator_props: dict = field(default_factory=dict)
    source: str = ""  # the file it came from, or the built-in name
    integrator_source: str = ""
    files: list = field(default_factory=list)  # the scene file and every mesh file it read (Paths)
    media: list[Medium] = field(default_factory=list)
    integrator_settings: IntegratorSettings = field(default_factory=IntegratorSettings)
    environment: Environment | None = None   # at most one (as in Mitsuba)
    directional_lights: list[DirectionalLight] = field(default_factory=list)
    projectors: list[Projector] = field(default_factory=list)
    #: What the loader accepted and renders otherwise than Mitsuba would, one sentence each, after the file (and the
    #: line) it concerns: the sensors past the first, a pixel format other than RGB.  Printed as notes, kept in the
    #: render's sidecar (``scene_notes``).
    loader_notes: list[str] = field(default_factory=list)

    @property
    def has_media(self) -> bool:
        """Whether rendering must follow rays through media: the camera or a shape has a medium,
        or a shape is a null-BSDF boundary (or a mask, which is one where it is off: :meth:`may_pass`).  A medium
        defined but never referenced does not count."""
        return (self.camera.medium >= 0
                or any(s.interior >= 0 or s.exterior >= 0 or self.may_pass(s.material) for s in self.shapes))

    @property
    def used_media(self) -> list[int]:
        """The media the camera or a shape refers to (a medium defined but never referenced is not among them)."""
        used = {self.camera.medium} | {m for s in self.shapes for m in (s.interior, s.exterior)}
        return sorted(m for m in used if m >= 0)

    @property
    def has_volumes(self) -> bool:
        """Whether the camera or a shape refers to a participating medium (null boundaries and masks alone do not
        count, unlike :attr:`has_media`)."""
        return self.camera.medium >= 0 or any(s.interior >= 0 or s.exterior >= 0 for s in self.shapes)

    def may_pass(self, m: int) -> bool:
        """Whether a ray may cross material m's surface unchanged: the null BSDF, a mask, or a blend with a null
        BSDF nested (such surfaces are crossed as a medium's boundary is, so the loops that handle media run)."""
        mat = self.materials[m]
        return mat.kind == NULL or mat.kind == MASK or any(self.may_pass(i) for i in mat.nested)

    @property
    def is_builtin(self) -> bool:
        """Whether this is one of the built-in scenes (the paper's: its photon methods keep the paper's cap on
        bounces without a note)."""
        from .builtin import builtin_scene_names
        return self.source in builtin_scene_names()

    @cached_property
    def inside_out_shapes(self) -> list[str]:
        """Where the shapes are that hold an interior medium and face inwards (:meth:`media_note`): a mesh whose
        signed volume is clearly negative, a sphere with flip_normals.  Computed once per scene (the command line's
        note and the render's sidecar both ask)."""
        inside_out = []
        for s in self.shapes:
            if s.interior >= 0 and s.kind == SPHERE and s.flip_normals:
                inside_out.append(s.source or s.id or "a sphere")
            if s.interior < 0 or s.mesh is None or len(s.mesh.triangles) == 0:
                continue
            volume, area = signed_volume(s.mesh)
            if volume < -1e-3 * area ** 1.5:   # clearly turned inside out, not a flat or open mesh's rounding
                inside_out.append(s.source or s.id or "a mesh")
        return inside_out

    def media_note(self, method: str) -> str | None:
        """For a photon method, one line naming the shapes that hold an interior medium and face inwards (a mesh whose
        volume, from its winding, comes out negative; a sphere with flip_normals): Mitsuba puts a shape's interior
        medium behind its faces, so outside such a shape, and a camera path (Mitsuba's, and pt's) that leaves the shape
        keeps that medium however far it goes, a state of the path that a photon estimate cannot share (a published
        scene, sapo17's texture-scanner cube: sppm 10 % darker than Mitsuba, -0.4 % with the faces turned).  None
        otherwise, and for pt, which follows Mitsuba's rule."""
        inside_out = self.inside_out_shapes
        if method == "pt" or not inside_out:
            return None
        return (f"the shape at {', '.join(inside_out[:3])}{' and others' if len(inside_out) > 3 else ''} "
                f"faces inwards, so its interior medium lies outside it; Mitsuba (and --method pt) keep that medium "
                f"on a path that has left the shape, which photons cannot follow: --method {method} will differ "
                f"there (flip_normals puts the medium inside)")

    def integrator_note(self, method: str, parameters: dict) -> str | None:
        """What a render with ``method`` and its ``parameters`` does with the scene's
        ``<integrator>``, when that differs from what the file asks; None otherwise.

        ``pt`` renders what Mitsuba's ``path`` and ``volpath`` (and ``volpathmis``) render, and takes their
        ``max_depth``, ``rr_depth`` and ``hide_emitters`` (a value given to pt wins: then a note);
        ``direct`` is pt with max_depth 2 and ``ptracer`` pt with its depths (a note says so).  ``path``
        on a scene with media gets a note (Mitsuba's ``path`` ignores them, ``pt`` does not).  A photon method
        gets a note for a max_depth or hide_emitters of ``path``, ``volpath``, ``direct`` or ``ptracer`` that its
        ``parameters`` do not carry (every photon method takes both) or that a value given replaced, and for a depth
        (unlimited too, but in the built-in scenes, which keep the paper's cap) that its ``max_bounces`` may cut
        short; any other
        integrator (``bdpt``, ...) gets a note, so a scene never renders differently from what it
        asks without the user being told.
        """
        if not self.integrator_source:
            return None
        kind, where = self.integrator, self.integrator_source
        if method != "pt":
            if kind not in SCENE_INTEGRATORS:
                return (f"integrator '{shorten(kind)}' in {where} is not used; the method is --method {method} "
                        f"('caustica methods' lists them)")
            st = self.integrator_settings
            depth = st.asked_depth
            asked = ([f"max_depth={depth}"] if depth != -1 and parameters.get("max_depth") != depth else []) + (
                ["hide_emitters"] if st.hide_emitters and not parameters.get("hide_emitters") else [])
            if asked:
                ran = [f"max_depth {parameters.get('max_depth', -1)}"] if asked[0].startswith("max_depth") else []
                ran += ["the emitters the camera sees shown"] if "hide_emitters" in asked else []
                why = "a value given wins over the file's" if "max_depth" in parameters else \
                    "the method does not read the file's"
                return (f"integrator '{kind}' in {where} asks for {' and '.join(asked)}; --method {method} renders "
                        f"with {' and '.join(ran)} ({why})")
            # unlimited: photons capped below 62 bounces may miss light (0.9 of it a bounce is 0.1 % after 64); the
            # built-in scenes keep the paper's cap (SPEC) without a note
            limit = UNLIMITED_BOUNCES if depth == -1 and not self.is_builtin else depth
            if limit != -1 and limit > parameters.get("max_bounces", limit) + 2:
                what = f"max_depth={depth}" if depth != -1 else "paths of any length (max_depth -1, Mitsuba's default)"
                return (f"integrator '{kind}' in {where} asks for {what}; --method {method}'s photons end "
                        f"after --max-bounces {parameters['max_bounces']} diffuse bounces, so its paths may be shorter "
                        f"(raise --max-bounces; with --termination roulette --max-bounces 1024 photons run until "
                        f"roulette ends them)")
            if kind == "path" and self.has_volumes:
                return (f"integrator 'path' in {where} would ignore the scene's media in Mitsuba; {method} renders "
                        f"them (as Mitsuba's volpath does)")
            if kind == "ptracer":
                return f"integrator 'ptracer' in {where}: {method} renders the same image its own way"
            return None if kind != "direct" else (
                f"integrator 'direct' in {where}: {method} renders the same image as paths of at most two segments "
                f"(max_depth 2)")
        if kind not in SCENE_INTEGRATORS:
            return (f"integrator '{shorten(kind)}' in {where} is not used; the method is --method {method} "
                    f"('caustica methods' lists them)")
        if kind == "path" and self.has_media:
            return (f"integrator 'path' in {where} would ignore the scene's media in Mitsuba; pt renders them "
                    f"(as Mitsuba's volpath does)")
        if kind == "direct":
            return (f"integrator 'direct' in {where}: pt renders the same image as paths of at most two segments "
                    f"(max_depth {parameters.get('max_depth')})")
        differ = {k: v for k, v in self.integrator_props.items() if parameters.get(k, object()) != v}
        if not differ:
            return None if kind != "ptracer" else (
                f"integrator 'ptracer' in {where}: pt renders the same image from the camera")
        asked = ", ".join(f"{k}={v}" for k, v in differ.items())
        ran = ", ".join(f"{k}={parameters[k]}" if k in parameters else f"no {k}" for k in differ)
        return (f"integrator '{kind}' in {where} asks for {asked}; pt runs with {ran} (a setting given to pt "
                f"wins over the scene's; pt has no other)")
