"""Reads the supported subset of Mitsuba 3's XML scene format into a SceneDescription.

The subset is listed in SPEC §1 and in :data:`SUPPORTED`.  As in Mitsuba, every
property given to a plugin must be used: anything outside the subset (an unknown
element, plugin type or property name, a wrong property type, a bad number) raises
:class:`~caustica.errors.SceneError` as ``<file>:<line>: <element>: <what is wrong>;
supported: <list>`` rather than being silently ignored, so a scene never renders
differently from Mitsuba without the user knowing.

Parsing uses expat directly so that every element knows its line.  ``<default>``
values and the caller's (Mitsuba's ``-D``) values are substituted for ``$name`` in
every attribute before anything is interpreted; the caller's values win.
"""
from __future__ import annotations

import copy
import difflib
import math
import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CausticaError, SceneError, quoted, shorten
from ..imageio import read_radiance_image
from ..limits import MAX_PIXELS, MAX_SPP
from . import spectra
from . import transforms as tf
from .builtin import find_data_file
from .conductors import CONDUCTOR_IOR
from .description import (BITMAP, BLEND, CHECKERBOARD, MESH_ATTRIBUTE, CONDUCTOR, CYLINDER, DIELECTRIC, DIFFUSE, DISK, DISTRIBUTIONS,
                          FILTER_TYPES, HENYEY_GREENSTEIN, HETEROGENEOUS, ISOTROPIC, NEAREST, TRILINEAR, Volume,
                          CLAMP, REPEAT, MASK, MATERIAL_NAMES, MESH, MIXTURES, NULL,
                          BUMPMAP, NORMALMAP, WRAPPERS,
                          PLASTIC, PPLASTIC, PRINCIPLED, PRINCIPLED_PARAMS, PRINCIPLEDTHIN, PRINCIPLEDTHIN_PARAMS, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC, SPHERE, THINDIELECTRIC, WRAP_MODES,
                          GGX, Camera, Environment, DirectionalLight, IntegratorSettings, Material, Medium, PointLight,
                          Mesh, Projector, ReconstructionFilter, SceneDescription, Shape, Texture, fov_tangents)
from .meshes import cube_mesh, load_mesh_file, rectangle_mesh, to_world_mesh, vertex_normals_by_angle
from .curves import curve_mesh, read_curves
from .sdfgrid import NORMAL_MODES, check_grid, sdf_mesh
from .serialized import load_serialized
from .textures import read_texels
from .volume_files import read_grid

# ----------------------------------------------------------------------------- the subset

#: Property tags and plugin tags this loader knows.
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point", "vector", "transform")
TOP_LEVEL_TAGS = ("default", "include", "path", "alias", "integrator", "sensor", "bsdf", "texture", "shape", "emitter",
                  "medium", "film (with an id)", "sampler (with an id)")

FLOAT = ("float", "integer")
INT = ("integer",)
BOOL = ("boolean",)
STR = ("string",)
COLOR = ("rgb", "spectrum", "float", "integer")
POINT = ("point", "vector")
XFORM = ("transform",)

_SHAPE_COMMON = {"to_world": XFORM, "flip_normals": BOOL}
SHAPE_PROPS = {
    "rectangle": {},
    "cube": {},
    "sphere": {"center": POINT, "radius": FLOAT},
    "disk": {},
    "cylinder": {"p0": POINT, "p1": POINT, "radius": FLOAT},
    "obj": {"filename": STR, "face_normals": BOOL, "flip_tex_coords": BOOL},
    "ply": {"filename": STR, "face_normals": BOOL, "flip_tex_coords": BOOL},
    "serialized": {"filename": STR, "shape_index": INT, "face_normals": BOOL},
    "linearcurve": {"filename": STR},
    "bsplinecurve": {"filename": STR},
    "sdfgrid": {"filename": STR, "normals": STR},
    # shapes declared once and placed by instances (each instance becomes copies of them)
    "shapegroup": {},
    "instance": {},
}
BSDF_PROPS = {
    "diffuse": {"reflectance": COLOR},
    "conductor": {"material": STR, "eta": COLOR, "k": COLOR, "specular_reflectance": COLOR},
    "dielectric": {"int_ior": FLOAT + STR, "ext_ior": FLOAT + STR,
                   "specular_reflectance": COLOR, "specular_transmittance": COLOR},
    "thindielectric": {"int_ior": FLOAT + STR, "ext_ior": FLOAT + STR,
                       "specular_reflectance": COLOR, "specular_transmittance": COLOR},
    "roughconductor": {"material": STR, "eta": COLOR, "k": COLOR, "specular_reflectance": COLOR,
                       "distribution": STR, "alpha": FLOAT, "alpha_u": FLOAT, "alpha_v": FLOAT,
                       "sample_visible": BOOL},
    "roughdielectric": {"int_ior": FLOAT + STR, "ext_ior": FLOAT + STR,
                        "specular_reflectance": COLOR, "specular_transmittance": COLOR,
                        "distribution": STR, "alpha": FLOAT, "alpha_u": FLOAT, "alpha_v": FLOAT,
                        "sample_visible": BOOL},
    "plastic": {"diffuse_reflectance": COLOR, "specular_reflectance": COLOR, "int_ior": FLOAT + STR,
                "ext_ior": FLOAT + STR, "nonlinear": BOOL},
    "roughplastic": {"diffuse_reflectance": COLOR, "specular_reflectance": COLOR, "int_ior": FLOAT + STR,
                     "ext_ior": FLOAT + STR, "nonlinear": BOOL,
                     "distribution": STR, "alpha": FLOAT, "alpha_u": FLOAT, "alpha_v": FLOAT,
                     "sample_visible": BOOL},
    # Mitsuba's RGB pplastic (its polarization is not rendered): a relative IOR as eta or as int_ior / ext_ior
    "pplastic": {"diffuse_reflectance": COLOR, "specular_reflectance": COLOR, "int_ior": FLOAT + STR,
                 "ext_ior": FLOAT + STR, "eta": FLOAT,
                 "distribution": STR, "alpha": FLOAT, "alpha_u": FLOAT, "alpha_v": FLOAT, "sample_visible": BOOL},
    # Mitsuba's principled and principledthin (bsdfs/principled.py, principledthin.py): base_color and the scalar
    # parameters of TEXTURED_PARAMS may be textures
    "principled": {"base_color": COLOR, "roughness": FLOAT, "anisotropic": FLOAT, "metallic": FLOAT, "spec_trans": FLOAT,
                   "eta": FLOAT, "specular": FLOAT, "spec_tint": FLOAT, "sheen": FLOAT, "sheen_tint": FLOAT,
                   "clearcoat": FLOAT, "clearcoat_gloss": FLOAT, "flatness": FLOAT,
                   "main_specular_sampling_rate": FLOAT, "clearcoat_sampling_rate": FLOAT,
                   "diffuse_reflectance_sampling_rate": FLOAT},
    "principledthin": {"base_color": COLOR, "roughness": FLOAT, "anisotropic": FLOAT, "spec_trans": FLOAT,
                       "eta": FLOAT, "spec_tint": FLOAT, "sheen": FLOAT, "sheen_tint": FLOAT, "flatness": FLOAT,
                       "diff_trans": FLOAT, "specular_reflectance_sampling_rate": FLOAT,
                       "specular_transmittance_sampling_rate": FLOAT, "diffuse_reflectance_sampling_rate": FLOAT,
                       "diffuse_transmittance_sampling_rate": FLOAT},
    "twosided": {},
    "null": {},
    # Mitsuba's linear polarizer as its RGB variants render it: half the light straight on (a thindielectric of eta 1)
    "polarizer": {"theta": COLOR, "transmittance": COLOR, "polarizing": BOOL},
    # the mixtures (bsdfs/mixtures.py): a constant here, or a nested <texture name="opacity"/"weight">
    "mask": {"opacity": FLOAT},
    "blendbsdf": {"weight": FLOAT},
    # the wrappers (bsdfs/perturb.py): a nested <texture> (normalmap: name="normalmap", a bitmap) and <bsdf>
    "normalmap": {"flip_invalid_normals": BOOL, "use_shadowing_function": BOOL},
    "bumpmap": {"scale": FLOAT, "flip_invalid_normals": BOOL, "use_shadowing_function": BOOL},
}
#: Each mixture's parameter (given as a float or a texture), its default (None: required, as in Mitsuba) and how many
#: BSDFs it nests.
MIXTURE_PARAMS = {"mask": ("opacity", 0.5, 1), "blendbsdf": ("weight", None, 2)}
#: The wrappers that perturb the shading normal (bsdfs/perturb.py): one nested BSDF and one nested texture each.
WRAPPER_TYPES = ("normalmap", "bumpmap")
#: Mitsuba 3's textures (src/textures/): ``format`` and ``accel`` only choose how Mitsuba stores and filters the
#: texels on a GPU (the values are checked, the texels are float32 here).
TEXTURE_PROPS = {
    "checkerboard": {"color0": COLOR, "color1": COLOR, "to_uv": XFORM},
    "bitmap": {"filename": STR, "filter_type": STR, "wrap_mode": STR, "raw": BOOL, "to_uv": XFORM, "format": STR,
               "accel": BOOL},
    # a mesh's own per-vertex or per-face values (PLY properties), looked up at the hit's triangle
    "mesh_attribute": {"name": STR, "scale": FLOAT},
    # one value everywhere, as given (no colour conversion): a float, an rgb or a vector
    "rawconstant": {"value": COLOR + POINT},
    # a <volume name="volume"> looked up at the surface point's world position: read and checked, but only when no
    # shape uses it (Texture.unrenderable)
    "volume": {},
}
BITMAP_FORMATS = ("auto", "variant", "float16", "fp16", "uint8")
#: The BSDF parameters a texture may give (the colour each BSDF's ``rgb`` holds).
TEXTURED_PARAMS = {"diffuse": ("reflectance",), "conductor": ("specular_reflectance",),
                   "roughconductor": ("specular_reflectance", "alpha", "alpha_u", "alpha_v"),
                   "dielectric": ("specular_transmittance",), "thindielectric": ("specular_transmittance",),
                   "roughdielectric": ("specular_transmittance", "alpha", "alpha_u", "alpha_v"),
                   "plastic": ("diffuse_reflectance",),
                   "roughplastic": ("diffuse_reflectance",), "pplastic": ("diffuse_reflectance",),
                   # Mitsuba reads these with get_texture (eval_1 for the scalars); eta, specular and the sampling rates
                   # of principled, the sampling rates of principledthin, are plain numbers there
                   "principled": ("base_color", "roughness", "anisotropic", "metallic", "spec_trans", "spec_tint",
                                  "sheen", "sheen_tint", "clearcoat", "clearcoat_gloss", "flatness"),
                   "principledthin": ("base_color", "roughness", "anisotropic", "spec_trans", "eta", "spec_tint",
                                      "sheen", "sheen_tint", "flatness", "diff_trans")}
def principled_roughness(roughness: float, anisotropic: float) -> tuple[float, float]:
    """A principled BSDF's (alpha_u, alpha_v), as Mitsuba's ``calc_dist_params``: roughness², stretched by
    sqrt(1 - 0.9 anisotropic) along dp/du and shrunk by it across, each at least 0.001."""
    r2 = roughness * roughness
    if anisotropic == 0.0:
        return max(0.001, r2), max(0.001, r2)
    a = math.sqrt(1.0 - 0.9 * anisotropic)
    return max(0.001, r2 / a), max(0.001, r2 * a)


def principled_eta(specular: float | None, eta: float | None, spec_trans: float) -> float:
    """A principled BSDF's relative IOR from Mitsuba's ``eta`` or ``specular`` s (default 0.5; eta = 2 / (1 -
    sqrt(0.08 s)) - 1), with Mitsuba's guards where the surface transmits (eta 1 -> 1.001, s 0 -> 0.001)."""
    if eta is not None:
        return 1.001 if spec_trans != 0.0 and eta == 1.0 else eta
    s = 0.5 if specular is None else specular
    if spec_trans != 0.0 and s == 0.0:
        s = 1e-3
    return 2.0 / (1.0 - math.sqrt(0.08 * s)) - 1.0


EMITTER_PROPS = {
    "area": {"radiance": COLOR},
    "point": {"position": POINT, "to_world": XFORM, "intensity": COLOR},
    "spot": {"to_world": XFORM, "intensity": COLOR, "cutoff_angle": FLOAT, "beam_width": FLOAT},
    # a texture (bitmap or checkerboard) may give 'irradiance' instead of a colour
    "projector": {"irradiance": COLOR, "scale": FLOAT, "to_world": XFORM, "fov": FLOAT, "focal_length": STR + FLOAT,
                  "fov_axis": STR},
    "directional": {"direction": POINT, "to_world": XFORM, "irradiance": COLOR},
    "constant": {"radiance": COLOR},
    # mis_compensation only changes how Mitsuba samples the map (its noise), not the image it converges to
    "envmap": {"filename": STR, "scale": FLOAT, "to_world": XFORM, "mis_compensation": BOOL},
}
#: Environment emitters (at most one per scene, as in Mitsuba).
ENVIRONMENT_TYPES = ("constant", "envmap")
MEDIUM_PROPS = {kind: {"sigma_t": COLOR, "albedo": COLOR, "scale": FLOAT,
                        # how Mitsuba samples the medium (shadow rays from inside it, a spectral
                        # majorant): accepted, they change the noise, not the image's expectation
                        "sample_emitters": BOOL, "has_spectral_extinction": BOOL}
                for kind in ("homogeneous", "heterogeneous")}
#: A heterogeneous medium's sigma_t and albedo as volumes (Mitsuba 3's gridvolume and constvolume), and a homogeneous
#: medium's albedo; ``raw`` and ``accel`` change nothing in RGB (no spectral upsampling, no GPU texture).
VOLUME_PROPS = {"gridvolume": {"filename": STR, "to_world": XFORM, "filter_type": STR, "wrap_mode": STR, "raw": BOOL,
                               "use_grid_bbox": BOOL, "accel": BOOL},
                "constvolume": {"value": COLOR, "to_world": XFORM}}
VOLUME_FILTERS = {"trilinear": TRILINEAR, "nearest": NEAREST}
VOLUME_WRAPS = {"clamp": CLAMP, "repeat": REPEAT}
#: The properties of a heterogeneous medium a <volume> may give.
MEDIUM_VOLUMES = ("sigma_t", "albedo")
PHASE_PROPS = {"isotropic": {}, "hg": {"g": FLOAT}}
#: The names a medium takes inside a shape (Mitsuba's interior and exterior media).
SHAPE_MEDIUM_NAMES = ("interior", "exterior")
_PERSPECTIVE = {"fov": FLOAT, "focal_length": STR + FLOAT, "fov_axis": STR, "near_clip": FLOAT, "far_clip": FLOAT,
                "to_world": XFORM,
                # accepted, changing nothing in a pinhole camera's image of a static scene (docs/scenes.md):
                "focus_distance": FLOAT, "shutter_open": FLOAT, "shutter_close": FLOAT,
                # accepted when 0 (Mitsuba's default), refused otherwise
                "principal_point_offset_x": FLOAT, "principal_point_offset_y": FLOAT}
SENSOR_PROPS = {"perspective": _PERSPECTIVE,
                # a thin lens: depth of field through aperture_radius and focus_distance (0: a pinhole)
                "thinlens": {**_PERSPECTIVE, "aperture_radius": FLOAT},
                # parallel rays from the near plane's [-1, 1] x [-1/aspect, 1/aspect], placed by to_world
                "orthographic": {"near_clip": FLOAT, "far_clip": FLOAT, "to_world": XFORM,
                                 "shutter_open": FLOAT, "shutter_close": FLOAT}}
FILM_PROPS = {"hdrfilm": {"width": INT, "height": INT,
                           # samples beyond the film's edge reach its pixels through the filter (read)
                           "sample_border": BOOL,
                           # how Mitsuba would store the image: accepted and ignored (caustica writes linear RGB
                           # EXR + PNG), each checked against the values Mitsuba 3's hdrfilm takes
                           "file_format": STR, "pixel_format": STR, "component_format": STR,
                           "banner": BOOL, "compensate": BOOL,
                           # a crop window: accepted when it is the whole film
                           "crop_offset_x": INT, "crop_offset_y": INT, "crop_width": INT, "crop_height": INT}}
#: Mitsuba 3's hdrfilm values (src/films/hdrfilm.cpp); pixel formats other than RGB are refused (they change the
#: image's values), the rest only change how Mitsuba stores the file.
FILE_FORMATS = ("openexr", "exr", "rgbe", "pfm")
PIXEL_FORMATS = ("rgb", "rgba")
#: Pixel formats accepted with a note (caustica's images stay linear sRGB) and what Mitsuba writes for each.
OTHER_PIXEL_FORMATS = {"luminance": "luminance (Y)", "luminance_alpha": "luminance and alpha (Y, A)",
                       "xyz": "CIE XYZ (X, Y, Z)", "xyza": "CIE XYZ and alpha (X, Y, Z, A)"}
COMPONENT_FORMATS = ("float16", "float32", "uint32")
#: Mitsuba 3's samplers: each takes sample_count as the samples per pixel; which points it draws only changes the
#: noise, so caustica uses its own (seed, jitter and strength are accepted and do not change the expected image).
SAMPLER_TYPES = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
SAMPLER_PROPS = {t: {"sample_count": INT, "seed": INT,
                     **({"jitter": BOOL} if t in ("stratified", "multijitter", "orthogonal") else {}),
                     **({"strength": INT} if t == "orthogonal" else {})} for t in SAMPLER_TYPES}
RFILTER_PROPS = {"box": {}, "tent": {"radius": FLOAT}, "gaussian": {"stddev": FLOAT}}
FOV_AXES = ("x", "y", "diagonal", "smaller", "larger")
#: Mitsuba 3's sensor defaults (src/render/sensor.cpp): a 50 mm lens on 35 mm film (36 x 24 mm), whose
#: field of view is measured along the film's diagonal; the clip planes.
DEFAULT_FOCAL_LENGTH_MM = 50.0
FILM_DIAGONAL_MM = math.sqrt(36.0 ** 2 + 24.0 ** 2)
DEFAULT_NEAR_CLIP = 1e-2
DEFAULT_FAR_CLIP = 1e4

#: Integrators that wrap another (Mitsuba's moment, aov, stokes): the wrapped one renders the image.
INTEGRATOR_WRAPPERS = ("moment", "aov", "stokes")
#: The integrator settings the description carries: (Mitsuba's default, type, valid when).
INTEGRATOR_SETTINGS = {"max_depth": (-1, int, lambda v: v >= -1), "rr_depth": (5, int, lambda v: v > 0),
                       "hide_emitters": (False, bool, None)}

#: The largest ``sample_count`` a scene's sampler may ask for: 2**20 samples per pixel
#: (the kernels key each sample by pixel * spp + sample in 64 bits, which this and
#: MAX_FILM_PIXELS keep far from overflow).  The same bound as ``--spp`` (caustica.limits).
MAX_SAMPLE_COUNT = MAX_SPP
#: The most pixels a film may have: int32, which the kernels' pixel indices fit.
MAX_FILM_PIXELS = MAX_PIXELS

#: Indices of refraction of the materials Mitsuba knows by name (Mitsuba's ior.h).
IOR_TABLE = {
    "vacuum": 1.0, "helium": 1.000036, "hydrogen": 1.000132, "air": 1.000277,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}

#: Mitsuba's default BSDF for a shape without one: diffuse, reflectance 0.5, or 0 when the shape
#: is an emitter (Mitsuba 3's Shape constructor), so a bare area light reflects nothing.
DEFAULT_REFLECTANCE = (0.5, 0.5, 0.5)
DEFAULT_EMITTER_REFLECTANCE = (0.0, 0.0, 0.0)

#: The plugin tables and nested elements the one report checks in elements it cannot build.
LINT_CHILDREN = {"shape": ("bsdf", "ref", "emitter", "medium"), "sensor": ("film", "sampler", "medium", "ref"),
                 "film": ("rfilter",), "medium": ("phase", "volume"), "bsdf": ("texture", "ref", "bsdf"),
                 "texture": ("volume",)}

SUPPORTED = {"shape": SHAPE_PROPS, "bsdf": BSDF_PROPS, "emitter": EMITTER_PROPS,
             "sensor": SENSOR_PROPS, "film": FILM_PROPS, "sampler": SAMPLER_PROPS,
             "rfilter": RFILTER_PROPS, "medium": MEDIUM_PROPS, "phase": PHASE_PROPS, "texture": TEXTURE_PROPS,
             "volume": VOLUME_PROPS}


LINT_TABLES = SUPPORTED


def _names(items) -> str:
    return ", ".join(items) if items else "(none)"


# ----------------------------------------------------------------------------- XML -> nodes

@dataclass
class Node:
    """One XML element with its source line (attributes after $-substitution)."""
    tag: str
    attrs: dict[str, str]
    line: int
    children: list["Node"] = field(default_factory=list)
    source: str = ""              # the file it was read from (as errors name it)
    folder: Path | None = None    # that file's folder: relative file names start there

    def describe(self) -> str:
        keys = [k for k in ("type", "name", "id") if k in self.attrs]
        inner = " ".join(f'{k}="{shorten(self.attrs[k])}"' for k in keys)
        return f"<{shorten(self.tag)}{' ' + inner if inner else ''}>"


#: How deep elements may nest.  A Mitsuba scene needs a handful of levels (scene > shape >
#: bsdf > bsdf > rgb); the limit keeps the loader's recursive passes far from Python's
#: recursion limit, and it also bounds chains of twosided BSDFs through <ref>.
MAX_NESTING_DEPTH = 64
#: How deep <include>s may nest (a loop is refused before this is reached; this bounds long chains).
MAX_INCLUDE_DEPTH = 32

_XML_ENCODING = re.compile(rb"""\A\s*<\?xml[^>]*?encoding\s*=\s*["']([^"']*)["']""")


def _lenient_comments(text: str | bytes) -> str | bytes | None:
    """The text with each '--' inside a comment written '- ' and a '-' ending one written ' ' (lengths and lines
    kept), or None where no comment has either.  XML forbids both and expat refuses them; Mitsuba's parser (pugixml)
    takes them, and published scenes have them (a licence header of lines beginning '--').  One pass with find, up
    to a comment left open (an error either way): linear in the text's length."""
    opening, closing, dash, twice, mended = ("<!--", "-->", "-", "--", "- ") if isinstance(text, str) else \
        (b"<!--", b"-->", b"-", b"--", b"- ")
    parts, pos = [], 0
    while True:
        start = text.find(opening, pos)
        end = text.find(closing, start + 4) if start >= 0 else -1
        if end < 0:
            break
        inner = text[start + 4:end].replace(twice, mended)
        if inner.endswith(dash):
            inner = inner[:-1] + mended[1:]
        parts += [text[pos:start + 4], inner]
        pos = end
    out = text[:0].join(parts) + text[pos:]
    return None if out == text else out


def _parse_xml(text: str | bytes, source: str, folder: Path | None = None) -> Node:
    """Parse XML text into a Node tree; SceneError with file and line for malformed XML.

    Every node records ``source`` (the name errors use) and ``folder`` (where relative file
    names in it are looked up first)."""
    parser = xml.parsers.expat.ParserCreate()
    stack: list[Node] = []
    root: list[Node] = []

    def start(tag, attrs):
        node = Node(tag, dict(attrs), parser.CurrentLineNumber, source=source, folder=folder)
        if len(stack) >= MAX_NESTING_DEPTH:
            raise SceneError(f"{source}:{node.line}: {node.describe()}: elements are nested more than "
                             f"{MAX_NESTING_DEPTH} deep; a scene may nest at most {MAX_NESTING_DEPTH} levels")
        if stack:
            stack[-1].children.append(node)
        else:
            root.append(node)
        stack.append(node)

    def end(tag):
        stack.pop()

    def chars(data):
        if data.strip():
            line = parser.CurrentLineNumber
            where = stack[-1].describe() if stack else "document"
            raise SceneError(f"{source}:{line}: {where}: unexpected text {quoted(data.strip())}; "
                             f"Mitsuba scene elements hold only attributes and child elements")

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(text, True)
    except (LookupError, ValueError):
        # expat asks Python for an encoding it does not know itself: unknown names raise
        # LookupError, multi-byte codecs ValueError.
        found = _XML_ENCODING.match(text if isinstance(text, bytes) else text.encode("utf-8", "replace"))
        name = found.group(1).decode("ascii", "replace") if found else "?"
        raise SceneError(f"{source}:1: <?xml encoding={quoted(name)}?>: unknown or unsupported encoding; "
                         f"supported: UTF-8 (Mitsuba's), UTF-16, US-ASCII and single-byte encodings "
                         f"such as ISO-8859-1 or cp1252") from None
    except xml.parsers.expat.ExpatError as exc:
        lenient = _lenient_comments(text)
        if lenient is not None:
            return _parse_xml(lenient, source, folder)
        msg = xml.parsers.expat.errors.messages.get(exc.code, str(exc))
        raise SceneError(f"{source}:{exc.lineno}: malformed XML: {msg} (column {exc.offset + 1})") from None
    if not root:
        raise SceneError(f"{source}:1: malformed XML: no root element")
    return root[0]


_PARAM = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


# ----------------------------------------------------------------------------- properties

@dataclass
class Spectrum:
    """A ``<spectrum>`` property as read: a constant or (wavelengths, values); converted to RGB where it is
    used (an emitter's converts differently, as in Mitsuba: :mod:`caustica.scene.spectra`)."""
    constant: float | None = None
    wavelengths: list = field(default_factory=list)
    values: list = field(default_factory=list)

    def rgb(self, emitter: bool, unbounded: bool) -> tuple[float, float, float]:
        if self.constant is not None:
            return spectra.constant_to_rgb(self.constant, emitter)
        return spectra.pairs_to_rgb(self.wavelengths, self.values, emitter, unbounded)


@dataclass
class Prop:
    tag: str
    value: object
    node: Node


class _Abandon(Exception):
    """An element is left unbuilt because of problems already recorded (see ``_Loader.record``)."""


class Props:
    """The properties and nested objects of one plugin element, checked against a spec.

    Unknown names, wrong tags and bad values are each recorded (at the property's line) and the element is
    then abandoned (``_Abandon``), so one report lists every problem of an element; ``get`` returns a value,
    and no final check is needed because the spec already lists every name the plugin consumes.
    """

    def __init__(self, loader: "_Loader", node: Node, spec: dict, child_tags: tuple[str, ...]):
        self.node = node
        self.props: dict[str, Prop] = {}
        self.objects: list[Node] = []
        bad = False
        for child in node.children:
            try:
                self._read(loader, node, child, spec, child_tags)
            except SceneError as exc:
                loader.record(exc)
                bad = True
        if bad:
            raise _Abandon

    def _read(self, loader: "_Loader", node: Node, child: Node, spec: dict, child_tags: tuple[str, ...]) -> None:
        if child.tag in PROPERTY_TAGS:
            name = child.attrs.get("name")
            if name is None:
                loader.fail(child, "a property needs a name= attribute")
            if name not in spec:
                loader.fail(child, f"unknown property {quoted(name)} of {node.describe()}",
                            supported=list(spec))
            if child.tag not in spec[name]:
                loader.fail(child, f"property '{name}' must be given as "
                                   f"{' or '.join('<' + t + '>' for t in spec[name])}, not <{child.tag}>")
            if name in self.props:
                loader.fail(child, f"property '{name}' is given twice "
                                   f"(first on line {self.props[name].node.line})")
            self.props[name] = Prop(child.tag, loader.property_value(child), child)
        elif child.tag in child_tags or (child.tag == "ref" and "ref" in child_tags):
            self.objects.append(child)
        else:
            supported = [f"<{t}>" for t in child_tags] + (
                [f"properties {_names(list(spec))}"] if spec else [])
            loader.fail(child, f"unexpected element inside {node.describe()}", supported=supported)

    def has(self, name: str) -> bool:
        return name in self.props

    def get(self, name: str, default=None):
        p = self.props.get(name)
        return default if p is None else p.value

    def node_of(self, name: str) -> Node:
        return self.props[name].node if name in self.props else self.node


# ----------------------------------------------------------------------------- the loader

class _Loader:
    def __init__(self, source: str, base_dir: Path, params: dict[str, str]):
        self.source = source
        self.base_dir = base_dir
        self.params = params
        self.ids: dict[str, Node] = {}
        self.main_file: Path | None = None    # the scene file itself (resolved), for the include-loop check
        self.far_clip_node: Node | None = None
        self.top_level_area: dict[int, Node] = {}   # area emitters declared at the top level with an id
        self.groups: dict[int, list[Shape]] = {}     # each shapegroup's shapes, once built
        self.referenced_emitters: set[int] = set()
        self.materials: list[Material] = []
        self.material_of_node: dict[int, int] = {}
        self.texture_of_node: dict[int, Texture] = {}
        self.in_progress: set[int] = set()
        self.default_materials: dict[bool, int] = {}   # emitter or not -> index of Mitsuba's default BSDF
        self.media: list[Medium] = []
        self.medium_of_node: dict[int, int] = {}
        self.used_params: set[str] = set()
        self.errors: list[str] = []          # every problem found, for the one report
        self.loader_notes: list[str] = []    # what is accepted and rendered otherwise (SceneDescription.loader_notes)
        self.other_sensors: list[Node] = []  # the <sensor>s after the first (read, not rendered)
        self.error_keys: set = set()
        self.files: list[Path] = []  # every file read (meshes), so that no output overwrites one
        self.search_paths: list[Path] = []   # the <path> folders, in the order declared
        self.file_versions: dict[str, tuple | None] = {}   # each file's version= (Mitsuba upgrades < 2.0)
        self.declared: dict[str, Node] = {}  # every <default>, by name (the first of each name)
        self.environment_node: Node | None = None   # the scene's environment emitter, if any
        self.environment_emitter: Environment | None = None
        self.point_lights: list[PointLight] = []   # point and spot emitters
        self.directional_lights: list[DirectionalLight] = []
        self.projectors: list[Projector] = []

    # -- files ------------------------------------------------------------------------
    def lookup_dirs(self, node: Node) -> list[Path]:
        """Mitsuba's file resolver: the ``<path>`` folders, the last declared first (each is prepended), then the
        main scene's folder."""
        return self.search_paths[::-1] + [self.base_dir]

    def find_file(self, node: Node, filename: str, what: str = "mesh file") -> Path:
        """A file the scene names (a mesh, a spectrum), looked up as :func:`~caustica.scene.builtin.find_data_file`
        does: ``$CAUSTICA_DATA_PATH``, then Mitsuba's resolver (:meth:`lookup_dirs`), then the folder of the
        included file that names it (which Mitsuba does not search), then ``shared/data``."""
        return find_data_file(filename, None, self.lookup_dirs(node) + [node.folder or self.base_dir], what)

    # -- errors -----------------------------------------------------------------------
    def fail(self, node: Node, msg: str, supported=None, fatal: bool = False):
        """Raise the SceneError of a problem at node.  ``fatal``: reading on is not safe (a limit was hit), so
        the error is reported alone, at once, rather than collected for the one report."""
        text = f"{self.at(node)}: {node.describe()}: {msg}"
        if supported is not None:
            text += f"; supported: {_names(supported)}"
        exc = SceneError(text)
        exc.node = node
        exc.fatal = fatal
        raise exc

    def record(self, exc: SceneError) -> None:
        """Keep a problem for the one report (:meth:`raise_errors`): one per element, the first found.  A fatal
        one is raised alone at once."""
        if getattr(exc, "fatal", False):
            raise exc
        node = getattr(exc, "node", None)
        key = id(node) if node is not None else str(exc)
        if key not in self.error_keys and str(exc) not in self.errors:
            self.error_keys.add(key)
            self.errors.append(str(exc))

    def raise_errors(self) -> None:
        """One problem: its own one-line message, as ever; several: one message listing each on its line."""
        if len(self.errors) == 1:
            raise SceneError(self.errors[0])
        if self.errors:
            raise SceneError(f"{self.source}: {len(self.errors)} problems, each with its file and line (and what "
                             f"is supported there):\n" + "\n".join(f"  {e}" for e in self.errors))

    def lint(self, node: Node) -> None:
        """Record the problems of a plugin element that will not be built (its parent failed): its type and its
        properties, checked as building it would, then its nested elements."""
        table = LINT_TABLES.get(node.tag)
        if table is None:
            return
        try:
            if node.tag == "bsdf" and node.attrs.get("type") == "twosided":
                children = ("bsdf", "ref")
            elif node.tag == "shape" and node.attrs.get("type") in ("shapegroup", "instance"):
                self.plugin(node, {"shapegroup": {}, "instance": {"to_world": XFORM}},
                            ("shape",) if node.attrs["type"] == "shapegroup" else ("ref",))
                self.lint_children(node)
                return
            else:
                children = LINT_CHILDREN.get(node.tag, ())
            self.plugin(node, table, children, extra=_SHAPE_COMMON if node.tag == "shape" else None)
        except SceneError as exc:
            self.record(exc)
        except _Abandon:
            pass
        self.lint_children(node)

    def lint_children(self, node: Node) -> None:
        for c in node.children:
            if c.tag not in PROPERTY_TAGS:
                self.lint(c)

    def at(self, node: Node) -> str:
        """"file:line" of a node (its own file, which may be an included one)."""
        return f"{node.source or self.source}:{node.line}"

    # -- substitution and ids -----------------------------------------------------------
    def substitute(self, node: Node) -> None:
        """Replace $name in every attribute (except inside <default>) and collect ids; every problem is
        recorded (none is interpreted yet, so all can be listed)."""
        try:
            self._substitute_one(node)
        except SceneError as exc:
            self.record(exc)
        for c in node.children:
            self.substitute(c)

    def _substitute_one(self, node: Node) -> None:
        if node.tag != "default":
            for k, v in node.attrs.items():
                if "$" in v:
                    def repl(m, node=node, k=k):
                        self.used_params.add(m.group(1))
                        if m.group(1) not in self.params:
                            name = shorten(m.group(1))
                            self.fail(node, f"attribute {k}={quoted(v)} uses ${name}, which is not "
                                            f"defined; add <default name=\"{name}\" value=\"...\"/> "
                                            f"or pass a value for it",
                                      supported=sorted(self.params) or None)
                        return self.params[m.group(1)]
                    node.attrs[k] = _PARAM.sub(repl, v)
        if "id" in node.attrs and node.tag not in PROPERTY_TAGS and node.tag not in ("ref", "default", "alias"):
            i = node.attrs["id"]
            if i in self.ids:
                first = self.ids[i]
                where = f"line {first.line}" if first.source == node.source else self.at(first)
                self.fail(node, f"id {quoted(i)} is already used on {where}")
            self.ids[i] = node

    def aliases(self, node: Node) -> None:
        """Mitsuba's <alias id="a" as="b"/>: b names what a names (a must exist, b must be new); the elements
        are then removed from the tree.  Problems are recorded."""
        kept = []
        for c in node.children:
            if c.tag != "alias":
                self.aliases(c)
                kept.append(c)
                continue
            try:
                self.check_attrs(c, ("id", "as"), ("id", "as"))
                src, dst = c.attrs["id"], c.attrs["as"]
                if src not in self.ids:
                    self.fail(c, f"no element has id {quoted(src)}", supported=sorted(self.ids) or None)
                if dst in self.ids:
                    self.fail(c, f"id {quoted(dst)} is already used on {self.at(self.ids[dst])}")
                self.ids[dst] = self.ids[src]
            except SceneError as exc:
                self.record(exc)
        node.children = kept

    def substitute_attrs(self, node: Node) -> None:
        """$name substitution in the attributes of one node (for <include> and <path>, which are read
        before the rest of the tree is substituted)."""
        children, node.children = node.children, []
        try:
            self.substitute(node)
        finally:
            node.children = children
        self.raise_errors()

    def read_defaults(self, root: Node) -> None:
        """The <default>s among root's children: a name not yet defined gets its value (the caller's -D
        values and earlier defaults win, as in Mitsuba, where an included file's defaults only fill gaps);
        the same name twice in one file is an error."""
        local: dict[str, Node] = {}
        for node in root.children:
            if node.tag != "default":
                continue
            self.check_attrs(node, ("name", "value"), ("name", "value"))
            if node.children:
                self.fail(node.children[0], "<default> takes no child elements")
            name = node.attrs["name"]
            if not _PARAM_NAME.fullmatch(name):
                self.fail(node, f"name={quoted(name)} cannot be used as $name: a parameter name is letters, "
                                f"digits and _, not starting with a digit")
            if name in local:
                self.fail(node, f"default {quoted(name)} is given twice (first on line {local[name].line})")
            local[name] = node
            self.declared.setdefault(name, node)
            self.params.setdefault(name, node.attrs["value"])

    def expand(self, node: Node, chain: tuple[tuple[Path, Node], ...], top: bool) -> None:
        """Replace every <include> below node by what the included file holds and read every <path>
        (both in document order, as Mitsuba does).  ``chain``: the includes being expanded, outermost
        first (for the loop check); ``top``: node is a scene's root (where <path> may appear)."""
        out: list[Node] = []
        for child in node.children:
            if child.tag == "path":
                if not top:
                    self.fail(child, "<path> must be a child of <scene> (Mitsuba's rule)")
                self.check_attrs(child, ("value",), ("value",))
                self.substitute_attrs(child)
                self.add_search_path(child)
            elif child.tag == "include":
                self.check_attrs(child, ("filename", "name"), ("filename",))
                self.substitute_attrs(child)
                out += self.include(child, chain)
            else:
                if child.tag != "default":
                    self.expand(child, chain, False)
                out.append(child)
        node.children = out

    def candidates(self, node: Node, p: Path) -> list[Path]:
        """Where a relative <include> or <path> named in node may be: its own file's folder (Mitsuba prepends
        it while reading the file), then Mitsuba's resolver (:meth:`lookup_dirs`)."""
        if p.is_absolute():
            return [p]
        return [(node.folder or self.base_dir) / p] + [d / p for d in self.lookup_dirs(node)]

    def add_search_path(self, node: Node) -> None:
        value = node.attrs["value"]
        p = Path(value)
        cands = self.candidates(node, p)
        for c in cands:
            if c.is_dir():
                self.search_paths.append(c)
                return
        self.fail(node, f"folder {quoted(value)} not found (searched: {', '.join(str(c) for c in cands)}); "
                        f"a <path> names a folder, absolute or relative to the scene file")

    def include(self, node: Node, chain: tuple[tuple[Path, Node], ...]) -> list[Node]:
        """The nodes an <include> stands for: the children of an included <scene> (its <default>s read),
        or the included file's root element itself (a file holding one <bsdf>, say)."""
        filename = node.attrs["filename"]
        p = Path(filename)
        cands = self.candidates(node, p)
        path = next((c for c in cands if c.is_file()), None)
        if path is None:
            self.fail(node, f"included file {quoted(filename)} not found; searched: "
                            f"{', '.join(str(c.parent) for c in cands)}; add its folder with <path value=\"...\"/>")
        key = path.resolve()
        if any(k == key for k, _ in chain) or key == self.main_file:
            steps = [f"{self.at(n)} includes {n.attrs['filename']}" for _, n in chain] + \
                    [f"{self.at(node)} includes {filename}"]
            self.fail(node, f"include loop: {'; '.join(steps)}, which is already being read; "
                            f"an included file must not include itself, directly or through others")
        if len(chain) >= MAX_INCLUDE_DEPTH:
            self.fail(node, f"includes nest more than {MAX_INCLUDE_DEPTH} deep; at most {MAX_INCLUDE_DEPTH} "
                            f"levels are allowed")
        try:
            data = path.read_bytes()
        except OSError as exc:
            self.fail(node, f"cannot read the included file {quoted(filename)}: {exc.strerror}")
        root = _parse_xml(data, str(path), path.parent)
        self.files.append(path)
        self.file_versions[str(path)] = _version(root.attrs.get("version"))
        inner = chain + ((key, node),)
        if root.tag == "scene":
            self.check_attrs(root, ("version",))
            self.read_defaults(root)
            self.expand(root, inner, True)
            return [c for c in root.children if c.tag != "default"]
        self.expand(root, inner, False)
        return [root]

    def check_attrs(self, node: Node, allowed: tuple[str, ...], required: tuple[str, ...] = ()):
        for k in node.attrs:
            if k not in allowed:
                self.fail(node, f"unknown attribute {quoted(k)}", supported=list(allowed))
        for k in required:
            if k not in node.attrs:
                self.fail(node, f"missing attribute '{k}'")

    # -- property values ----------------------------------------------------------------
    def property_value(self, node: Node):
        """The Python value of a property element: float, int, bool, str, RGB tuple, 3-vector or 4x4."""
        tag = node.tag
        try:
            if tag == "transform":
                self.check_attrs(node, ("name",), ("name",))
                ops = []
                for c in node.children:
                    try:
                        ops.append(tf.op_matrix(c.tag, c.attrs))
                    except ValueError as exc:
                        self.fail(c, str(exc))
                return tf.check_transform(tf.compose(ops))
            if node.children:
                self.fail(node.children[0], f"<{tag}> takes no child elements")
            if tag == "spectrum":
                return self.spectrum_value(node)
            if tag in ("point", "vector"):
                self.check_attrs(node, ("name", "value", "x", "y", "z"), ("name",))
                return tf.xyz_from_attrs({k: v for k, v in node.attrs.items() if k != "name"}, 0.0)
            self.check_attrs(node, ("name", "value"), ("name", "value"))
            v = node.attrs["value"]
            if tag == "float":
                return tf.parse_float(v)
            if tag == "integer":
                return tf.parse_int(v)
            if tag == "boolean":
                if v.strip().lower() not in ("true", "false"):
                    raise ValueError(f"value={quoted(v)} is not a boolean; use true or false")
                return v.strip().lower() == "true"
            if tag == "string":
                return v
            if tag == "rgb":
                vals = tf.parse_floats(v)
                if len(vals) == 1:
                    vals = vals * 3
                if len(vals) != 3:
                    raise ValueError(f"value={quoted(v)} must have 3 components (or 1)")
                return tuple(vals)
        except ValueError as exc:
            self.fail(node, str(exc))
        raise AssertionError(tag)

    def spectrum_value(self, node: Node) -> Spectrum:
        """A <spectrum value="..."/> (one number, or wavelength:value pairs) or <spectrum filename="x.spd"/>."""
        if "type" in node.attrs:
            self.fail(node, f"a spectrum plugin (<spectrum type={quoted(node.attrs['type'])}>) is not supported",
                      supported=['<spectrum value="0.5"/>', '<spectrum value="400:0.1, 700:0.9"/>',
                                 '<spectrum filename="x.spd"/>'])
        self.check_attrs(node, ("name", "value", "filename"), ("name",))
        if ("value" in node.attrs) == ("filename" in node.attrs):
            self.fail(node, "a <spectrum> needs either value= or filename=, not both (as in Mitsuba)")
        try:
            if "value" in node.attrs:
                parsed = spectra.parse_spectrum(node.attrs["value"])
                if isinstance(parsed, float):
                    return Spectrum(constant=tf.parse_float(node.attrs["value"].strip().rstrip(",")))
            else:
                path = self.find_file(node, node.attrs["filename"], "spectrum file")
                self.files.append(Path(path))
                parsed = spectra.read_spd(path)
        except (ValueError, SceneError) as exc:
            self.fail(node, str(exc))
        except OSError as exc:
            self.fail(node, f"cannot read the spectrum file {quoted(node.attrs['filename'])}: {exc.strerror}")
        for v in parsed[1]:
            if abs(v) > tf.MAX_ABS_FLOAT:
                self.fail(node, f"spectrum value {v:g} is out of range (beyond {tf.MAX_ABS_FLOAT:.3g}, float32)")
        return Spectrum(wavelengths=parsed[0], values=parsed[1])

    def color(self, props: Props, name: str, default: tuple, nonneg: bool = True, *, emitter: bool = False,
              unbounded: bool = False) -> tuple:
        """A colour property as RGB (an <rgb>, a number, or a <spectrum> converted as Mitsuba's RGB variants do:
        ``emitter`` for radiance and intensity, ``unbounded`` for quantities not limited to [0, 1])."""
        v = props.get(name)
        if v is None:
            return default
        if isinstance(v, Spectrum):
            rgb = v.rgb(emitter, unbounded)
        else:
            rgb = (float(v),) * 3 if not isinstance(v, tuple) else tuple(float(c) for c in v)
        if nonneg and min(rgb) < 0:
            self.fail(props.node_of(name), f"'{name}' must not be negative, got {rgb}")
        return rgb

    def number(self, props: Props, name: str, default, *, positive=False, nonneg=False):
        v = props.get(name, default)
        if v is None:
            return None
        if positive and not v > 0:
            self.fail(props.node_of(name), f"'{name}' must be positive, got {v}")
        if nonneg and not v >= 0:
            self.fail(props.node_of(name), f"'{name}' must not be negative, got {v}")
        return v

    def plugin(self, node: Node, table: dict, child_tags: tuple[str, ...] = (), extra=None) -> Props:
        """Check the type= of a plugin element against table and read its properties."""
        self.check_attrs(node, ("type", "id", "name"), ("type",))
        kind = node.attrs["type"]
        if kind not in table:
            self.fail(node, f"unknown {node.tag} type {quoted(kind)}", supported=list(table))
        spec = dict(table[kind])
        if extra:
            spec.update(extra)
        return Props(self, node, spec, child_tags)

    # -- BSDFs -----------------------------------------------------------------------
    def resolve(self, node: Node, expected: str) -> Node:
        """A <ref id=...> to the element it names (which must be a <expected>), or node itself."""
        if node.tag != "ref":
            return node
        self.check_attrs(node, ("id", "name"), ("id",))
        target = self.ids.get(node.attrs["id"])
        if target is None:
            known = sorted(k for k, n in self.ids.items() if n.tag == expected)
            self.fail(node, f"no element has id {quoted(node.attrs['id'])}", supported=known or None)
        if target.tag != expected:
            self.fail(node, f"id {quoted(node.attrs['id'])} is a <{target.tag}> (line {target.line}), "
                            f"a <{expected}> is needed here")
        return target

    def build_material(self, node: Node) -> Material:
        key = id(node)
        if key in self.in_progress:
            self.fail(node, "the BSDF refers to itself (a reference cycle)")
        if len(self.in_progress) >= MAX_NESTING_DEPTH:
            self.fail(node, f"BSDFs wrap each other (through twosided and <ref>) more than "
                            f"{MAX_NESTING_DEPTH} deep; at most {MAX_NESTING_DEPTH} levels are allowed", fatal=True)
        self.in_progress.add(key)
        try:
            return self._build_material(node)
        finally:
            self.in_progress.discard(key)

    def _build_material(self, node: Node) -> Material:
        props = self.plugin(node, BSDF_PROPS, ("bsdf", "ref") if node.attrs.get("type") == "twosided"
                            else ("texture", "ref", "bsdf") if node.attrs.get("type") in MIXTURE_PARAMS
                            or node.attrs.get("type") in WRAPPER_TYPES
                            else ("texture", "ref"))
        kind = node.attrs["type"]
        name = node.attrs.get("id", "")
        if kind in MIXTURE_PARAMS:
            return self.mixture(node, props, kind, name)
        if kind in WRAPPER_TYPES:
            return self.wrapper(node, props, kind, name)
        textures = {} if kind == "twosided" else self.bsdf_textures(props, kind)
        if kind == "diffuse":
            tex = textures.get("reflectance")
            return Material(DIFFUSE, self.color(props, "reflectance", DEFAULT_REFLECTANCE) if tex is None
                            else texture_mean(tex), name=name, texture=tex)
        if kind in ("conductor", "roughconductor"):
            eta, k = self.conductor_ior(props)
            tex = textures.get("specular_reflectance")
            mat = Material(CONDUCTOR, self.color(props, "specular_reflectance", (1.0, 1.0, 1.0)) if tex is None
                           else texture_mean(tex), name=name, conductor_eta=eta, conductor_k=k, texture=tex)
            if kind == "roughconductor":
                mat.kind, mat.source = ROUGHCONDUCTOR, self.at(node)
                mat.distribution, mat.alpha, mat.alpha_v = self.microfacet(props, anisotropic=True, textures=textures)
                mat.alpha_textures = self.roughness_textures(textures)
            return mat
        if kind == "null":
            return Material(NULL, (1.0, 1.0, 1.0), name=name)
        if kind == "polarizer":
            return self.polarizer(node, props, name)
        if kind in ("dielectric", "roughdielectric", "thindielectric"):
            int_ior, ext_ior = self.dielectric_iors(props)
            tex = textures.get("specular_transmittance")    # tinted glass: bsdfs/dielectric.py's tints
            mat = Material(DIELECTRIC, self.color(props, "specular_transmittance", (1.0, 1.0, 1.0)) if tex is None
                           else texture_mean(tex), int_ior=int_ior, ext_ior=ext_ior, name=name, texture=tex,
                           specular=self.color(props, "specular_reflectance", (1.0, 1.0, 1.0)))
            if kind == "thindielectric":
                mat.kind, mat.source = THINDIELECTRIC, self.at(node)
            if kind == "roughdielectric":
                if int_ior == ext_ior:
                    self.fail(node, f"roughdielectric: int_ior and ext_ior are both {int_ior:g}; they must differ, "
                                    f"as Mitsuba 3 requires (an interface between equal media scatters nothing)")
                mat.kind, mat.source = ROUGHDIELECTRIC, self.at(node)
                mat.distribution, mat.alpha, mat.alpha_v = self.microfacet(props, anisotropic=True, textures=textures)
                mat.alpha_textures = self.roughness_textures(textures)
            return mat
        if kind == "pplastic":
            return self.pplastic(node, props, textures.get("diffuse_reflectance"), name)
        if kind == "principled":
            return self.principled(node, props, textures, name)
        if kind == "principledthin":
            return self.principledthin(node, props, textures, name)
        if kind in ("plastic", "roughplastic"):
            int_ior, ext_ior = self.dielectric_iors(props, "polypropylene")
            tex = textures.get("diffuse_reflectance")
            if tex is not None and tex.kind == MESH_ATTRIBUTE:
                self.fail(node, f"a {kind}'s diffuse_reflectance cannot be a mesh_attribute (Mitsuba's {kind} needs "
                                f"the texture's mean, which a mesh_attribute has not)",
                          supported=["a bitmap or checkerboard diffuse_reflectance"])
            mat = Material(PLASTIC, self.color(props, "diffuse_reflectance", DEFAULT_REFLECTANCE) if tex is None
                           else texture_mean(tex), int_ior=int_ior, ext_ior=ext_ior, name=name,
                           specular=self.color(props, "specular_reflectance", (1.0,) * 3),
                           nonlinear=bool(props.get("nonlinear", False)), source=self.at(node), texture=tex)
            if kind == "roughplastic":
                if int_ior == ext_ior:
                    self.fail(node, f"roughplastic: int_ior and ext_ior are both {int_ior:g}; they must differ, "
                                    f"as Mitsuba 3 requires")
                mat.kind = ROUGHPLASTIC
                mat.distribution, mat.alpha, _ = self.microfacet(props)
            return mat
        # twosided
        if len(props.objects) != 1:
            self.fail(node, f"twosided must wrap exactly one BSDF, found {len(props.objects)} "
                            f"(different front and back BSDFs are not supported)")
        inner_node = self.resolve(props.objects[0], "bsdf")
        inner = self.build_material(inner_node)
        if inner.kind in WRAPPERS:
            self.fail(props.objects[0], f"twosided around a {MATERIAL_NAMES[inner.kind]} is not supported; put "
                                        f"twosided inside it, around its nested BSDF",
                      supported=["diffuse", "conductor", "roughconductor", "plastic", "roughplastic", "pplastic"])
        if inner.kind == BLEND:
            self.fail(props.objects[0], "twosided around a blendbsdf is not supported; put twosided around each of "
                                        "its nested BSDFs instead (the same BSDF)",
                      supported=["diffuse", "conductor", "roughconductor", "plastic", "roughplastic", "pplastic"])
        if inner.kind in (DIELECTRIC, ROUGHDIELECTRIC, THINDIELECTRIC, NULL, MASK, PRINCIPLEDTHIN) or (
                inner.kind == PRINCIPLED and (inner.principled.get("spec_trans", 0.0) != 0.0
                                              or "spec_trans" in inner.param_textures)):
            self.fail(props.objects[0], f"twosided cannot wrap a {inner_node.attrs.get('type', '?')} "
                                        f"BSDF (Mitsuba forbids transmissive BSDFs inside twosided)",
                      supported=["diffuse", "conductor", "roughconductor", "plastic", "roughplastic", "pplastic"])
        out = copy.copy(inner)
        out.twosided = True
        out.name = name or inner.name
        return out

    def mixture(self, node: Node, props: Props, kind: str, name: str) -> Material:
        """A ``mask`` (``opacity``, default 0.5, and one nested BSDF) or a ``blendbsdf`` (``weight``, required, and two
        nested BSDFs, f0 then f1): the parameter a float in [0, 1] or a nested texture (``<texture name=...>`` or
        ``<ref name=... id=...>``, its luminance clipped to [0, 1] as Mitsuba's); the nested BSDFs inline or by
        ``<ref>``, each a material of its own, not themselves a mask or blendbsdf."""
        param, default, count = MIXTURE_PARAMS[kind]
        nested, texture = [], None
        for obj in props.objects:
            target = self.ids.get(obj.attrs.get("id", "")) if obj.tag == "ref" else obj
            if obj.tag == "texture" or (target is not None and target.tag == "texture"):
                if obj.attrs.get("name") != param:
                    self.fail(obj, f"a texture inside a {kind} gives its '{param}' (name=\"{param}\"), got "
                                   f"name={quoted(obj.attrs.get('name', ''))}", supported=[f'name="{param}"'])
                if texture is not None or props.has(param):
                    self.fail(obj, f"'{param}' is given twice")
                texture = self.texture(obj)
            else:
                nested.append(obj)
        if len(nested) != count:
            self.fail(node, f"a {kind} nests exactly {count} BSDF{'s' if count > 1 else ''}, found {len(nested)}",
                      supported=[f"{count} nested <bsdf> or <ref id=...> element{'s' if count > 1 else ''}"])
        indices = []
        for obj in nested:
            i = self.material_index(obj)
            if self.materials[i].kind in MIXTURES + WRAPPERS:
                self.fail(obj, f"a {MATERIAL_NAMES[self.materials[i].kind]} nested in a {kind} is not supported "
                               f"(one level of mask or blendbsdf, normalmap and bumpmap not inside one)",
                          supported=[t for t in BSDF_PROPS if t not in MIXTURE_PARAMS and t != "twosided"
                                     and t not in WRAPPER_TYPES] + ["twosided"])
            indices.append(i)
        if texture is None and default is None and not props.has(param):
            self.fail(node, f"a {kind} needs its '{param}' (a <float> or a nested <texture name=\"{param}\">), as "
                            f"in Mitsuba")
        mix = float(self.number(props, param, 0.0 if default is None else default))
        if not 0.0 <= mix <= 1.0:
            self.fail(props.node_of(param), f"'{param}' must be within [0, 1], got {mix:g}", supported=["[0, 1]"])
        return Material(MASK if kind == "mask" else BLEND, (1.0, 1.0, 1.0), name=name, nested=tuple(indices),
                        mix=mix, mix_texture=texture, source=self.at(node))

    def wrapper(self, node: Node, props: Props, kind: str, name: str) -> Material:
        """A ``normalmap`` (a bitmap texture named "normalmap" of tangent-space normals) or a ``bumpmap`` (a texture
        of heights, any name, and ``scale``, default 1) around one nested BSDF (inline or by ``<ref>``; not a mask,
        blendbsdf, null or another wrapper).  The nested BSDF becomes a row of the wrapper's own, with
        ``terminator`` set unless ``use_shadowing_function`` is false (bsdfs/perturb.py)."""
        nested, texture = [], None
        for obj in props.objects:
            target = self.ids.get(obj.attrs.get("id", "")) if obj.tag == "ref" else obj
            if obj.tag == "texture" or (target is not None and target.tag == "texture"):
                if kind == "normalmap" and obj.attrs.get("name") != "normalmap":
                    self.fail(obj, f"a texture inside a normalmap gives its 'normalmap' (name=\"normalmap\"), got "
                                   f"name={quoted(obj.attrs.get('name', ''))}", supported=['name="normalmap"'])
                if texture is not None:
                    self.fail(obj, f"a {kind} takes one texture, found a second")
                texture = self.texture(obj)
                if texture.kind != BITMAP:
                    self.fail(obj, f"a {kind}'s texture must be a bitmap (an image of "
                                   f"{'normals' if kind == 'normalmap' else 'heights'})", supported=["bitmap"])
            else:
                nested.append(obj)
        if texture is None:
            self.fail(node, f"a {kind} needs a nested <texture type=\"bitmap\"> (its "
                            f"{'normals' if kind == 'normalmap' else 'heights'}), as in Mitsuba")
        if len(nested) != 1:
            self.fail(node, f"a {kind} nests exactly 1 BSDF, found {len(nested)}",
                      supported=["1 nested <bsdf> or <ref id=...> element"])
        if not props.get("flip_invalid_normals", True):
            self.fail(props.node_of("flip_invalid_normals"), "flip_invalid_normals=false is not supported",
                      supported=["true (the default)"])
        i = self.material_index(nested[0])
        inner = self.materials[i]
        if inner.kind in MIXTURES + WRAPPERS + (NULL,):
            self.fail(nested[0], f"a {MATERIAL_NAMES[inner.kind]} nested in a {kind} is not supported",
                      supported=[t for t in BSDF_PROPS if t not in MIXTURE_PARAMS and t not in WRAPPER_TYPES
                                 and t != "null"])
        row = copy.copy(inner)   # the wrapper's own row: its f carries the terminator's shadowing
        row.terminator = bool(props.get("use_shadowing_function", True))
        self.materials.append(row)
        scale = float(self.number(props, "scale", 1.0)) if kind == "bumpmap" else 1.0
        return Material(NORMALMAP if kind == "normalmap" else BUMPMAP, inner.rgb, name=name,
                        nested=(len(self.materials) - 1,), mix=scale, mix_texture=texture, source=self.at(node))

    def bsdf_textures(self, props: Props, kind: str) -> dict[str, Texture]:
        """The textures among a BSDF's children (nested ``<texture name=...>`` or ``<ref name=... id=...>``), by the
        parameter each gives; only the colours of :data:`TEXTURED_PARAMS` may be textured."""
        out: dict[str, Texture] = {}
        allowed = TEXTURED_PARAMS.get(kind, ())
        for obj in props.objects:
            name = obj.attrs.get("name")
            if name is None:
                self.fail(obj, "a texture inside a BSDF needs name= (the parameter it gives)",
                          supported=[f"name=\"{p}\"" for p in allowed] or None)
            if name not in allowed:
                self.fail(obj, f"a texture for '{name}' of a {kind} BSDF is not supported",
                          supported=[f"a texture for '{p}'" for p in allowed] + [f"a constant '{name}'"])
            if name in props.props or name in out:
                self.fail(obj, f"'{name}' is given twice")
            out[name] = self.texture(obj)
        return out

    def texture(self, node: Node) -> Texture:
        """The Texture of a <texture> (or a <ref> to one), built once per element."""
        node = self.resolve(node, "texture")
        if id(node) not in self.texture_of_node:
            self.texture_of_node[id(node)] = self.build_texture(node)
        return self.texture_of_node[id(node)]

    def build_texture(self, node: Node) -> Texture:
        """A <texture type="checkerboard">, "bitmap", "mesh_attribute" or "rawconstant", with Mitsuba's defaults."""
        props = self.plugin(node, TEXTURE_PROPS, ("texture", "ref", "volume"))
        if node.attrs["type"] == "volume":
            return self.volume_texture(node, props)
        if props.objects:
            self.fail(props.objects[0], "a texture inside a texture is not supported",
                      supported=["<rgb>, <float> or <spectrum> colours"])
        m = props.get("to_uv")
        to_uv = np.eye(4)[np.ix_([0, 1], [0, 1, 3])] if m is None else np.asarray(m)[np.ix_([0, 1], [0, 1, 3])]
        common = dict(to_uv=np.ascontiguousarray(to_uv, dtype=np.float64), id=node.attrs.get("id", ""),
                      source=self.at(node))
        if node.attrs["type"] == "mesh_attribute":
            attr = props.get("name")
            if attr is None:
                self.fail(node, "a mesh_attribute texture needs <string name=\"name\" .../> (the attribute)")
            if not attr.startswith(("vertex_", "face_")):
                self.fail(props.node_of("name"), f"a mesh_attribute's name must start with \"vertex_\" or \"face_\" "
                                                 f"(as in Mitsuba), got {quoted(attr)}")
            common["to_uv"] = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
            return Texture(MESH_ATTRIBUTE, attribute=attr, scale=self.number(props, "scale", 1.0), **common)
        if node.attrs["type"] == "rawconstant":   # a 1 x 1 image of the value: every lookup and eval_1 reads it
            if not props.has("value"):
                self.fail(node, "a rawconstant texture needs its <float>, <rgb> or <vector name=\"value\" .../>")
            v = props.get("value")
            value = tuple(float(x) for x in np.ravel(v)) if not isinstance(v, (int, float)) else (float(v),) * 3
            if len(value) != 3 or not all(math.isfinite(x) for x in value):
                self.fail(props.node_of("value"), f"a rawconstant's value must be one or three finite numbers, "
                                                  f"got {quoted(v)}")
            return Texture(BITMAP, texels=np.array(value, np.float32).reshape(1, 1, 3), filter=FILTER_TYPES["nearest"],
                           wrap=WRAP_MODES["repeat"], **common)
        if node.attrs["type"] == "checkerboard":
            return Texture(CHECKERBOARD, color0=self.color(props, "color0", (0.4, 0.4, 0.4)),
                           color1=self.color(props, "color1", (0.2, 0.2, 0.2)), **common)
        modes = {}
        for p, table, default in (("filter_type", FILTER_TYPES, "bilinear"), ("wrap_mode", WRAP_MODES, "repeat"),
                                  ("format", dict.fromkeys(BITMAP_FORMATS), "auto")):
            v = props.get(p, default)
            if v not in table:
                self.fail(props.node_of(p), f"unknown {p} {quoted(v)}", supported=list(table))
            modes[p] = table[v]
        if not props.has("filename"):
            self.fail(node, "a bitmap texture needs <string name=\"filename\" .../>")
        where = props.node_of("filename")
        try:
            path = self.find_file(where, props.get("filename"), "texture file")
            self.files.append(Path(path))
            texels = read_texels(path, bool(props.get("raw", False)))
        except SceneError as exc:
            self.fail(where, str(exc))
        return Texture(BITMAP, texels=texels, filter=modes["filter_type"], wrap=modes["wrap_mode"], **common)

    def volume_texture(self, node: Node, props: Props) -> Texture:
        """A <texture type="volume">: its <volume name="volume"> read and checked (a gridvolume's file too) as Mitsuba
        loads it, kept as unrenderable (:attr:`Texture.unrenderable`): caustica's textures are looked up at a surface
        point's (u, v), and this one at its world position."""
        volumes = [obj for obj in props.objects if obj.tag == "volume"]
        if len(volumes) != len(props.objects) or len(volumes) > 1 or \
                any(v.attrs.get("name", "volume") != "volume" for v in volumes):
            self.fail(node, "a volume texture holds at most one <volume name=\"volume\">",
                      supported=['<volume type="gridvolume" name="volume">', '<volume type="constvolume">'])
        # none: Mitsuba's constant 0.75 (it takes no number or colour there)
        self.medium_volume(props, volumes[0] if volumes else None, "volume", 0.75, 1.0)
        # a placeholder of no weight (never rendered); mid-grey passes the parameters' range checks
        return Texture(BITMAP, texels=np.full((1, 1, 3), 0.5, np.float32), id=node.attrs.get("id", ""),
                       source=self.at(node), unrenderable="a volume texture (looked up at the surface point's world "
                                                          "position, not at its (u, v))")

    def material_textures(self, m: int, seen: tuple = ()):
        """(texture, role) of every texture material m and its parts (a mixture's, a wrapper's) read: role "colour"
        (``texture``), "weight" (``mix_texture``: a mixture's weight, a map) or "parameter" (roughness, principled's
        scalars), in that order, each material's before its parts'."""
        mat = self.materials[m]
        for tex, role in ((mat.texture, "colour"), (mat.mix_texture, "weight"),
                          *((t, "parameter") for t in (*mat.alpha_textures, *(mat.param_textures or {}).values()))):
            if tex is not None:
                yield tex, role
        for j in getattr(mat, "nested", ()) or ():
            if j >= 0 and j not in seen:
                yield from self.material_textures(j, seen + (m,))

    def check_textures_used(self, shapes: list[Shape]) -> None:
        """Each shape's BSDF (its parts too) and area emitter read only textures caustica renders: an unrenderable one
        (:attr:`Texture.unrenderable`) is an error where a shape uses it, as the one report's."""
        users: dict[int, tuple[Texture, list[Shape]]] = {}
        for shape in shapes:
            used = [t for t, _ in self.material_textures(shape.material)] \
                if 0 <= shape.material < len(self.materials) else []
            for tex in used + [shape.emitter_texture]:
                if tex is not None and tex.unrenderable:
                    users.setdefault(id(tex), (tex, []))[1].append(shape)
        for tex, by in users.values():   # one error a texture, naming its first user
            named = f" {by[0].id!r}" if by[0].id else ""
            others = f" and {len(by) - 1} other shape{'s' if len(by) > 2 else ''}" if len(by) > 1 else ""
            self.errors.append(f"{tex.source}: {tex.unrenderable} is not supported where a shape uses it (here the "
                               f"{by[0].kind}{named} at {by[0].source}{others}); it may be declared unused, as "
                               f"Mitsuba loads it; supported: checkerboard, bitmap, mesh_attribute, rawconstant")

    def check_mesh_attributes(self, shapes: list[Shape]) -> None:
        """Each shape whose BSDF (or a mixture's part) reads a mesh_attribute texture is a mesh holding that attribute,
        of 3 or 1 channels for a colour (Mitsuba's eval: 1 is grey) and 1 for a mixture's weight (its eval_1)."""
        needs = {"colour": ((1, 3), "a colour"), "weight": ((1,), "a mixture's weight")}
        for shape in shapes:
            if not 0 <= shape.material < len(self.materials):
                continue
            for tex, role in self.material_textures(shape.material):
                if tex.kind != MESH_ATTRIBUTE or role not in needs:
                    continue
                dims, what = needs[role]
                attrs = (shape.mesh.attributes or {}) if shape.mesh is not None else None
                if attrs is None:
                    self.errors.append(f"{tex.source}: mesh_attribute {quoted(tex.attribute)} is on the {shape.kind} "
                                       f"{shape.id!r} ({shape.source}), which is no mesh: only a mesh has attributes")
                elif tex.attribute not in attrs:
                    have = ", ".join(sorted(attrs)) or "none"
                    self.errors.append(f"{tex.source}: the mesh {shape.id!r} ({shape.source}) has no attribute "
                                       f"{quoted(tex.attribute)} (its attributes: {have})")
                elif attrs[tex.attribute].shape[1] not in dims:
                    self.errors.append(f"{tex.source}: attribute {quoted(tex.attribute)} of the mesh {shape.id!r} has "
                                       f"{attrs[tex.attribute].shape[1]} channels; as {what} it needs "
                                       + " or ".join(map(str, dims[::-1])) + " (as Mitsuba's mesh_attribute)")
                else:
                    rows = len(shape.mesh.positions) if tex.attribute.startswith("vertex_") else len(shape.mesh.triangles)
                    if len(attrs[tex.attribute]) != rows:
                        self.errors.append(f"{tex.source}: attribute {quoted(tex.attribute)} of the mesh {shape.id!r} "
                                           f"has {len(attrs[tex.attribute])} rows, expected {rows} (one per "
                                           + ("vertex" if tex.attribute.startswith("vertex_") else "face") + ")")

    def dielectric_iors(self, props: Props, interior: str = "bk7") -> tuple[float, float]:
        """(int_ior, ext_ior) of a (rough) dielectric or plastic: numbers or Mitsuba's names, defaults ``interior``
        (bk7 for glass, polypropylene for plastic, as Mitsuba) and air."""
        iors = []
        for p, default in (("int_ior", interior), ("ext_ior", "air")):
            v = props.get(p, default)
            if isinstance(v, str):
                key = v.strip().lower()
                if key not in IOR_TABLE:
                    self.fail(props.node_of(p), f"unknown material name {quoted(v)} for {p}",
                              supported=list(IOR_TABLE))
                v = IOR_TABLE[key]
            v = float(v)
            if not v > 0:
                self.fail(props.node_of(p), f"'{p}' must be positive, got {v}")
            iors.append(v)
        return iors[0], iors[1]

    def conductor_ior(self, props: Props):
        """A (rough) conductor's complex IOR as (eta, k) RGB, or (None, 0) for material="none" (F = 1).

        As Mitsuba 3: ``eta`` / ``k`` (defaults 0 and 1) or a named ``material``, not both; neither means
        "none" (Mitsuba 3's default, a perfect reflector)."""
        mat = props.get("material")
        if props.has("eta") or props.has("k"):
            if mat is not None:
                self.fail(props.node_of("material"), "give either eta and k or a material, not both (as Mitsuba)")
            eta = self.color(props, "eta", (0.0, 0.0, 0.0), unbounded=True)
            k = self.color(props, "k", (1.0, 1.0, 1.0), unbounded=True)
            if max(eta) == 0.0 and min(k) == 1.0 and max(k) == 1.0:
                return None, (0.0, 0.0, 0.0)     # Mitsuba's own "none": eta 0, k 1 reflects everything
            return eta, k
        if mat is None or mat.strip() == "none":
            return None, (0.0, 0.0, 0.0)
        if mat.strip() not in CONDUCTOR_IOR:
            self.fail(props.node_of("material"), f"unknown conductor material {quoted(mat)}",
                      supported=["none"] + list(CONDUCTOR_IOR))
        return CONDUCTOR_IOR[mat.strip()]

    def principled_params(self, props: Props, textures: dict, kind: str, defaults: dict) -> tuple[dict, dict]:
        """(numbers, textures) of a principled or principledthin BSDF's scalar parameters (Mitsuba's names, with
        ``defaults`` and anisotropic): a constant must be finite and in [0, 1] (diff_trans [0, 2]; a sampling rate not
        negative), a texture (a checkerboard, bitmap or rawconstant, read by its eval_1) within the same range."""
        params, given = {}, {}
        for p, default in {**defaults, "anisotropic": 0.0}.items():
            top = None if p.endswith("_rate") else 2.0 if p == "diff_trans" else 1.0
            if p in textures:
                tex = textures[p]
                node = next(o for o in props.objects if o.attrs.get("name") == p)
                if tex.kind == MESH_ATTRIBUTE:
                    self.fail(node, f"{kind}: a mesh_attribute for '{p}' is not supported",
                              supported=["a checkerboard, bitmap or rawconstant texture", f"a constant '{p}'"])
                low, high = scalar_range(tex)
                if not (low >= 0.0 and high <= top):
                    self.fail(node, f"{kind}: the texture for '{p}' has values from {low:g} to {high:g}; they must "
                                    f"be in [0, {top:g}]", supported=[f"values from 0 to {top:g}"])
                params[p], given[p] = float(default), tex
                continue
            v = self.number(props, p, default, nonneg=True)
            if not math.isfinite(v) or (top is not None and v > top):
                self.fail(props.node_of(p), f"{kind}: '{p}' must be in [0, {top:g}], got {v}" if top is not None else
                          f"{kind}: '{p}' must be finite, got {v}",
                          supported=[f"a number from 0 to {top:g}"] if top is not None else None)
            params[p] = float(v)
        return params, given

    def principled(self, node: Node, props: Props, textures: dict, name: str) -> Material:
        """Mitsuba's ``principled`` (bsdfs/principled.py): base_color (default 0.5, or a texture), its other parameters
        with Mitsuba's defaults, each weight in [0, 1], a constant or a texture (:meth:`principled_params`); ``eta`` or
        ``specular`` (not both, as Mitsuba; numbers)."""
        tex = textures.get("base_color")
        params, given = self.principled_params(props, textures, "principled", PRINCIPLED_PARAMS)
        anisotropic = params["anisotropic"]
        if props.has("eta") and props.has("specular"):
            self.fail(props.node_of("specular"), "principled: give either eta or specular, not both (as Mitsuba)")
        eta = self.number(props, "eta", None, positive=True)
        if eta is not None and not math.isfinite(eta):
            self.fail(props.node_of("eta"), f"principled: 'eta' must be finite, got {eta}")
        specular = self.number(props, "specular", None, nonneg=True)
        if specular is not None and not specular <= 1.0:
            self.fail(props.node_of("specular"), f"principled: 'specular' must be in [0, 1], got {specular}")
        eta = principled_eta(specular, eta, 1.0 if "spec_trans" in given else params["spec_trans"])
        if eta == 1.0:
            self.fail(props.node_of("eta") if props.has("eta") else node,
                      "principled: eta 1 (or specular 0) makes no interface to reflect from", supported=["eta != 1"])
        au, av = principled_roughness(params["roughness"], float(anisotropic))
        return Material(PRINCIPLED, self.color(props, "base_color", DEFAULT_REFLECTANCE) if tex is None
                        else texture_mean(tex), int_ior=eta, ext_ior=1.0, name=name, distribution=GGX, alpha=au,
                        alpha_v=av if av != au else None, principled=params, source=self.at(node), texture=tex,
                        param_textures={p: t for p, t in given.items() if p != "base_color"})

    def principledthin(self, node: Node, props: Props, textures: dict, name: str) -> Material:
        """Mitsuba's ``principledthin`` (bsdfs/principledthin.py): base_color (default 0.5, or a texture), its scalar
        parameters as :meth:`principled`'s (diff_trans in [0, 2]), ``eta`` (default 1.5, positive; a number or a
        texture).  A thin sheet: no refraction, so the material's int_ior and ext_ior are both 1."""
        tex = textures.get("base_color")
        params, given = self.principled_params(props, textures, "principledthin", PRINCIPLEDTHIN_PARAMS)
        if "eta" in textures:
            node_eta = next(o for o in props.objects if o.attrs.get("name") == "eta")
            if textures["eta"].kind == MESH_ATTRIBUTE:
                self.fail(node_eta, "principledthin: a mesh_attribute for 'eta' is not supported",
                          supported=["a checkerboard, bitmap or rawconstant texture", "a constant 'eta'"])
            low, high = scalar_range(textures["eta"])
            if not (low > 0.0 and math.isfinite(high)):
                self.fail(node_eta, f"principledthin: the texture for 'eta' has values from {low:g} to {high:g}; "
                                    f"they must be positive and finite", supported=["positive values"])
            given["eta"], params["eta"] = textures["eta"], 1.5
        else:
            eta = self.number(props, "eta", 1.5, positive=True)
            if not math.isfinite(eta):
                self.fail(props.node_of("eta"), f"principledthin: 'eta' must be finite, got {eta}")
            params["eta"] = float(eta)
        au, av = principled_roughness(params["roughness"], params["anisotropic"])
        return Material(PRINCIPLEDTHIN, self.color(props, "base_color", DEFAULT_REFLECTANCE) if tex is None
                        else texture_mean(tex), int_ior=1.0, ext_ior=1.0, name=name, distribution=GGX, alpha=au,
                        alpha_v=av if av != au else None, principled=params, source=self.at(node), texture=tex,
                        param_textures={p: t for p, t in given.items() if p != "base_color"})

    def pplastic(self, node: Node, props: Props, tex, name: str) -> Material:
        """Mitsuba's ``pplastic`` (its RGB branch, bsdfs/pplastic.py): diffuse_reflectance (default 0.5, a texture
        allowed), specular_reflectance (default 1), the microfacet distribution and roughness, and the relative IOR:
        ``eta`` (positive), or int_ior / ext_ior (defaults polypropylene and air, differing), not both, as Mitsuba."""
        if tex is not None and tex.kind == MESH_ATTRIBUTE:
            self.fail(node, "a pplastic's diffuse_reflectance cannot be a mesh_attribute (Mitsuba's pplastic needs the "
                            "texture's mean, which a mesh_attribute has not)",
                      supported=["a bitmap or checkerboard diffuse_reflectance"])
        if props.has("eta"):
            for p in ("int_ior", "ext_ior"):
                if props.has(p):
                    self.fail(props.node_of(p), "pplastic: give either eta or int_ior and ext_ior, not both "
                                                "(as Mitsuba)")
            int_ior, ext_ior = float(self.number(props, "eta", None, positive=True)), 1.0
            if not math.isfinite(int_ior):
                self.fail(props.node_of("eta"), f"'eta' must be finite, got {int_ior}")
        else:
            int_ior, ext_ior = self.dielectric_iors(props, "polypropylene")
            if int_ior == ext_ior:
                self.fail(node, f"pplastic: int_ior and ext_ior are both {int_ior:g}; they must differ, as Mitsuba 3 "
                                f"requires")
        mat = Material(PPLASTIC, self.color(props, "diffuse_reflectance", DEFAULT_REFLECTANCE) if tex is None
                       else texture_mean(tex), int_ior=int_ior, ext_ior=ext_ior, name=name,
                       specular=self.color(props, "specular_reflectance", (1.0,) * 3), source=self.at(node),
                       texture=tex)
        mat.distribution, mat.alpha, _ = self.microfacet(props)
        return mat

    def needs_tangent(self, i: int) -> bool:
        """Whether material i (or a BSDF it nests) is anisotropic: its shading frame needs dp/du."""
        mat = self.materials[i]
        return mat.anisotropic or any(self.needs_tangent(j) for j in mat.nested)

    def microfacet(self, props: Props, anisotropic: bool = False, textures: dict | None = None) \
            -> tuple[int, float, float | None]:
        """(distribution code, alpha, alpha_v) of a rough BSDF: Mitsuba's distribution (default beckmann) and roughness
        ``alpha`` (default 0.1), or ``alpha_u`` and ``alpha_v`` (alpha_v None where they are equal; a BSDF that is not
        ``anisotropic`` refuses them different), clamped to 1e-4 as Mitsuba does.  A roughness given by one of
        ``textures`` (:meth:`roughness_textures`) counts as given; its number here is the default, unused."""
        dist = props.get("distribution", "beckmann")
        if dist not in DISTRIBUTIONS:
            self.fail(props.node_of("distribution"), f"unknown microfacet distribution {quoted(dist)}",
                      supported=list(DISTRIBUTIONS))
        textures = textures or {}
        given = {p: props.has(p) or p in textures for p in ("alpha", "alpha_u", "alpha_v")}
        def where(p):   # the element that gives p: a property, or a texture
            return props.node_of(p) if props.has(p) else next(o for o in props.objects if o.attrs.get("name") == p)
        if given["alpha"] and (given["alpha_u"] or given["alpha_v"]):
            self.fail(where("alpha"), "give either alpha or alpha_u and alpha_v, not both (as Mitsuba)")
        if given["alpha_u"] != given["alpha_v"]:
            self.fail(where("alpha_u" if given["alpha_u"] else "alpha_v"),
                      "alpha_u and alpha_v must be given together (as Mitsuba)")
        names = ("alpha_u", "alpha_v") if given["alpha_u"] else ("alpha",)
        values = [self.number(props, p, 0.1, nonneg=True) for p in names]
        for p, v in zip(names, values):
            if not math.isfinite(v):
                self.fail(props.node_of(p), f"'{p}' must be finite, got {v}")
        if values[0] != values[-1] and not anisotropic:
            self.fail(props.node_of("alpha_v"), f"anisotropic roughness (alpha_u {values[0]} != alpha_v "
                                                f"{values[-1]}) is not supported here (roughconductor and "
                                                f"roughdielectric take it)", supported=["alpha_u = alpha_v"])
        au, av = max(float(values[0]), 1e-4), max(float(values[-1]), 1e-4)
        return DISTRIBUTIONS[dist], au, (av if av != au else None)

    @staticmethod
    def roughness_textures(textures: dict) -> tuple:
        """The Textures that give a rough BSDF's (alpha_u, alpha_v) over its surface, or None each: ``alpha`` both."""
        if "alpha" in textures:
            return textures["alpha"], textures["alpha"]
        return textures.get("alpha_u"), textures.get("alpha_v")

    def element_index(self, node: Node, tag: str, index_of_node: dict[int, int], entries: list, build) -> int:
        """Index in ``entries`` of what ``build`` makes of a <tag> element (or <ref> to one): built once per
        element, so that every reference to it shares the entry (appended after building: nested ones come first)."""
        node = self.resolve(node, tag)
        key = id(node)
        if key not in index_of_node:
            entry = build(node)
            index_of_node[key] = len(entries)
            entries.append(entry)
        return index_of_node[key]

    def material_index(self, node: Node) -> int:
        """Index of the Material of a <bsdf> (or <ref> to one); each element becomes one entry."""
        return self.element_index(node, "bsdf", self.material_of_node, self.materials, self.build_material)

    def default_material_index(self, emitter: bool) -> int:
        """The default BSDF of a shape without one (created once): black for an emitter, as in Mitsuba 3."""
        if emitter not in self.default_materials:
            self.default_materials[emitter] = len(self.materials)
            self.materials.append(Material(DIFFUSE, DEFAULT_EMITTER_REFLECTANCE if emitter else DEFAULT_REFLECTANCE,
                                           name="default emitter" if emitter else "default"))
        return self.default_materials[emitter]

    # -- media ------------------------------------------------------------------------
    def medium_index(self, node: Node) -> int:
        """Index of the Medium of a <medium> (or <ref> to one); each element becomes one entry."""
        return self.element_index(node, "medium", self.medium_of_node, self.media, self.build_medium)

    def build_medium(self, node: Node) -> Medium:
        """A <medium type="homogeneous">: sigma_t x scale, albedo and its <phase> (Mitsuba's defaults); or
        "heterogeneous", or homogeneous with a <volume> albedo (:meth:`heterogeneous_medium`)."""
        heterogeneous = node.attrs.get("type") == "heterogeneous"
        props = self.plugin(node, MEDIUM_PROPS, ("phase", "volume"))
        scale = float(self.number(props, "scale", 1.0, nonneg=True))
        if heterogeneous or any(obj.tag == "volume" for obj in props.objects):
            return self.heterogeneous_medium(node, props, scale, bounded=heterogeneous)
        sigma_t = self.color(props, "sigma_t", (1.0, 1.0, 1.0), unbounded=True)
        albedo = self.color(props, "albedo", (0.75, 0.75, 0.75), unbounded=True)
        if max(albedo) > 1.0:
            self.fail(props.node_of("albedo"), f"'albedo' is sigma_s / sigma_t and must lie in [0, 1], got {albedo}")
        sigma = tuple(c * scale for c in sigma_t)
        if not all(math.isfinite(c) and c <= tf.MAX_ABS_FLOAT for c in sigma):
            self.fail(props.node_of("scale" if props.has("scale") else "sigma_t"),
                      f"sigma_t x scale = {max(sigma_t)} x {scale} is beyond {tf.MAX_ABS_FLOAT:.3g} (float32)")
        phase, g = self.phase_function(props.objects)
        return Medium(sigma, albedo, phase, g, id=node.attrs.get("id", ""), source=self.at(node))

    def phase_function(self, objects: list[Node]) -> tuple[int, float]:
        """(phase, g) of a medium's <phase> among its nested ``objects`` (isotropic without one, as Mitsuba)."""
        phases = [o for o in objects if o.tag == "phase"]
        phase, g = ISOTROPIC, 0.0
        if len(phases) > 1:
            self.fail(phases[1], "a medium takes only one <phase>")
        for obj in phases:
            pprops = self.plugin(obj, PHASE_PROPS)
            if obj.attrs["type"] == "hg":
                phase, g = HENYEY_GREENSTEIN, float(pprops.get("g", 0.8))   # Mitsuba's default g
                if not -1.0 < g < 1.0:
                    self.fail(pprops.node_of("g"), f"'g' must lie strictly between -1 and 1, got {g}")
        return phase, g

    def heterogeneous_medium(self, node: Node, props: Props, scale: float, bounded: bool = True) -> Medium:
        """A <medium type="heterogeneous">: its sigma_t (times scale) and albedo, each a number, an <rgb> or a
        <volume> (:meth:`medium_volume`), and its <phase>.  Not ``bounded``: a homogeneous medium whose albedo is a
        <volume>, which fills its shapes (no box) and whose sigma_t must be constant."""
        given: dict[str, Node] = {}
        for obj in props.objects:
            if obj.tag != "volume":
                continue
            name = obj.attrs.get("name")
            if name not in MEDIUM_VOLUMES:
                self.fail(obj, "a medium's <volume> needs name=\"sigma_t\" or name=\"albedo\"",
                          supported=list(MEDIUM_VOLUMES))
            if name in given or props.has(name):
                self.fail(obj, f"the medium's {name} is given twice")
            if name == "sigma_t" and not bounded and obj.attrs.get("type") != "constvolume":
                self.fail(obj, "a homogeneous medium's sigma_t is constant (a number, an <rgb> or a constvolume); "
                               "a grid of sigma_t needs <medium type=\"heterogeneous\">")
            given[name] = obj
        sigma_t = self.medium_volume(props, given.get("sigma_t"), "sigma_t", 1.0, scale)
        albedo = self.medium_volume(props, given.get("albedo"), "albedo", 0.75, 1.0)
        phase, g = self.phase_function(props.objects)
        return Medium((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), phase, g, id=node.attrs.get("id", ""), source=self.at(node),
                      kind=HETEROGENEOUS, sigma_t_volume=sigma_t, albedo_volume=albedo, bounded=bounded)

    def medium_volume(self, props: Props, vnode: Node | None, name: str, default: float, scale: float) -> Volume:
        """A heterogeneous medium's ``name`` (sigma_t or albedo) as a :class:`Volume` with ``scale`` applied: a
        <volume> (gridvolume, constvolume), or a number or <rgb>, which is Mitsuba's constvolume over the unit cube
        [0, 1]³ (so a medium whose sigma_t is a number exists only there, as in Mitsuba)."""
        to_world, filt, wrap, filename = np.eye(4), TRILINEAR, CLAMP, ""
        if vnode is None:
            where = props.node_of(name)
            rgb = self.color(props, name, (default,) * 3, unbounded=True)
            if name == "albedo" and max(rgb) > 1.0:
                self.fail(where, f"'albedo' is sigma_s / sigma_t and must lie in [0, 1], got {rgb}")
            data = np.asarray(rgb, np.float32).reshape(1, 1, 1, 3)
        else:
            where = vnode
            vprops = self.plugin(vnode, VOLUME_PROPS)
            if vprops.has("to_world"):
                to_world = np.asarray(vprops.get("to_world"), np.float64)
            if vnode.attrs["type"] == "constvolume":
                data = np.asarray(self.color(vprops, "value", (1.0,) * 3, unbounded=True), np.float32).reshape(1, 1, 1, 3)
            else:
                data, (filt, wrap), filename, to_world = self.grid_volume(vnode, vprops, to_world)
        if not data.min() >= 0.0:
            what = f"grid volume {quoted(filename)}" if filename else "the value"
            self.fail(where, f"{name}: {what} holds a negative value ({float(data.min()):g}); a medium's sigma_t and "
                             f"albedo must not be negative")
        if abs(np.linalg.det(to_world[:3, :3])) < 1e-300 or not np.all(np.isfinite(to_world)):
            self.fail(where, f"{name}: the volume's to_world is singular (it maps the unit cube to nothing)")
        data = data.astype(np.float64) * scale
        if not np.all(data <= tf.MAX_ABS_FLOAT):
            self.fail(where, f"{name} x scale = {float(data.max() / max(scale, 1e-300)):g} x {scale:g} is beyond "
                             f"{tf.MAX_ABS_FLOAT:.3g} (float32)")
        return Volume(data.astype(np.float32), np.linalg.inv(to_world), filt, wrap, filename, source=self.at(where))

    def grid_volume(self, vnode: Node, vprops: Props, to_world: np.ndarray):
        """(data, (filter, wrap), filename, to_world) of a <volume type="gridvolume">: its .vol file read
        (:func:`~caustica.scene.volume_files.read_grid`), with ``use_grid_bbox`` the file's box mapped to the unit
        cube first (Mitsuba's default ignores that box: the grid fills the unit cube, placed by ``to_world``)."""
        filt = vprops.get("filter_type", "trilinear")
        if filt not in VOLUME_FILTERS:
            self.fail(vprops.node_of("filter_type"), f"unknown filter_type {quoted(filt)}",
                      supported=list(VOLUME_FILTERS))
        wrap = vprops.get("wrap_mode", "clamp")
        if wrap not in VOLUME_WRAPS:
            self.fail(vprops.node_of("wrap_mode"), f"wrap_mode {quoted(wrap)} is not supported",
                      supported=list(VOLUME_WRAPS))
        if not vprops.has("filename"):
            self.fail(vnode, "a gridvolume needs <string name=\"filename\" .../> (a Mitsuba .vol file)")
        filename = vprops.get("filename")
        where = vprops.node_of("filename")
        try:
            path = self.find_file(where, filename, "grid volume")
            self.files.append(Path(path))
            data, bbox = read_grid(path)
        except SceneError as exc:
            self.fail(where, str(exc))
        if vprops.get("use_grid_bbox", False):
            extent = bbox[1] - bbox[0]
            if not np.all(extent > 0.0):
                self.fail(vprops.node_of("use_grid_bbox"), f"grid volume {quoted(filename)}'s bounding box "
                                                           f"{bbox.tolist()} is empty; use_grid_bbox needs a box")
            to_world = to_world @ _translation(bbox[0]) @ np.diag([*extent, 1.0])
        return data, (VOLUME_FILTERS[filt], VOLUME_WRAPS[wrap]), filename, to_world

    def is_medium(self, obj: Node) -> bool:
        """Whether a shape's or sensor's child is a medium: a <medium>, or a <ref> named like one or
        naming one (a <ref> naming a BSDF is the shape's BSDF, as before)."""
        if obj.tag == "medium":
            return True
        target = self.ids.get(obj.attrs.get("id", ""))
        return obj.tag == "ref" and (obj.attrs.get("name") in SHAPE_MEDIUM_NAMES
                                     or (target is not None and target.tag == "medium"))

    # -- shapes ----------------------------------------------------------------------
    def shape_group(self, node: Node) -> list[Shape]:
        """The shapes of a <shape type="shapegroup"> in its own space, built once (Mitsuba forbids emitters,
        nested groups and instances in a group)."""
        key = id(node)
        if key not in self.groups:
            self.plugin(node, {"shapegroup": {}}, ("shape",))
            built = []
            for child in node.children:
                kind = child.attrs.get("type")
                if kind in ("shapegroup", "instance"):
                    self.fail(child, f"a shapegroup cannot hold a {kind} (nested instancing is not permitted, as in "
                                     f"Mitsuba)")
                if any(c.tag == "emitter" or (c.tag == "ref" and self.ids.get(c.attrs.get("id", ""), c).tag
                                              == "emitter") for c in child.children):
                    self.fail(child, "a shape in a shapegroup cannot be an emitter (Mitsuba does not instance "
                                     "emitters)")
                built.append(self.shape(child))
            self.groups[key] = built
        return self.groups[key]

    def instance(self, node: Node) -> list[Shape]:
        """A <shape type="instance">: a copy of its shapegroup's shapes placed by its to_world (Mitsuba's instance:
        shading normals through the inverse transpose, so a mirroring to_world keeps each surface's front)."""
        props = self.plugin(node, {"instance": {"to_world": XFORM}}, ("ref",))
        if len(props.objects) != 1:
            self.fail(node, f"an instance takes exactly one <ref> to a shapegroup, found {len(props.objects)}")
        ref = props.objects[0]
        target = self.ids.get(ref.attrs.get("id", ""))
        if target is None or target.tag != "shape" or target.attrs.get("type") != "shapegroup":
            known = sorted(k for k, n in self.ids.items() if n.tag == "shape" and n.attrs.get("type") == "shapegroup")
            self.fail(ref, f"an instance needs a <ref> to a <shape type=\"shapegroup\">; "
                           f"{quoted(ref.attrs.get('id', ''))} is not one", supported=known or None)
        m = props.get("to_world")
        m = np.eye(4) if m is None else m
        out = []
        for s in self.shape_group(target):
            placed = copy.copy(s)
            placed.source = f"{s.source} (instanced at {self.at(node)})"
            if s.mesh is not None:
                try:
                    mesh = to_world_mesh(s.mesh, m)
                except SceneError as exc:
                    self.fail(node, str(exc))
                if np.linalg.det(m[:3, :3]) < 0 and mesh.normals is None:
                    # keep the front side where Mitsuba's instance keeps it (with vertex normals to_world_mesh has
                    # put it on their side already, where Mitsuba's shading frame keeps it)
                    mesh.triangles = np.ascontiguousarray(mesh.triangles[:, ::-1])
                placed.mesh = mesh
                placed.to_world = m @ s.to_world
            else:
                placed.to_world = self.placement(node, m @ s.to_world, "the instance's to_world with the shape's")
                if s.kind == SPHERE:
                    lin = placed.to_world[:3, :3]
                    gram = lin.T @ lin
                    s2 = np.trace(gram) / 3.0
                    if np.abs(gram - s2 * np.eye(3)).max() > 1e-6 * s2:
                        self.fail(props.node_of("to_world"), "an instanced sphere must stay round: the instance's "
                                                             "to_world must not shear or scale non-uniformly")
            out.append(placed)
        return out

    def shape(self, node: Node) -> Shape:
        if node.attrs.get("type") in ("shapegroup", "instance"):
            self.fail(node, f"a {node.attrs['type']} belongs at the top level of the scene")
        props = self.plugin(node, SHAPE_PROPS, ("bsdf", "ref", "emitter", "medium"), extra=_SHAPE_COMMON)
        kind = node.attrs["type"]
        to_world = props.get("to_world")
        to_world = np.eye(4) if to_world is None else to_world
        flip = bool(props.get("flip_normals", False))

        material, radiance, emitter_texture, held_light = None, None, None, None
        media = {}
        for obj in props.objects:
            target = self.ids.get(obj.attrs.get("id", "")) if obj.tag == "ref" else None
            if target is not None and target.tag == "emitter":   # an area emitter declared at the top level
                if target.attrs.get("type") != "area":   # (any other is read where it is declared)
                    self.fail(obj, f"a shape can refer only to an area emitter; '{obj.attrs.get('id')}' (line "
                                   f"{target.line}) is a {target.attrs.get('type')} emitter, read at the top level")
                self.referenced_emitters.add(id(target))
                obj = target
            if self.is_medium(obj):
                name = obj.attrs.get("name")
                if name not in SHAPE_MEDIUM_NAMES:
                    self.fail(obj, "a medium inside a shape needs name=\"interior\" or name=\"exterior\" "
                                   "(the side of the surface it fills)", supported=list(SHAPE_MEDIUM_NAMES))
                if name in media:
                    self.fail(obj, f"the shape's {name} medium is given twice")
                media[name] = self.medium_index(obj)
            elif obj.tag in ("bsdf", "ref"):
                if material is not None:
                    self.fail(obj, "a shape takes only one BSDF")
                material = self.material_index(obj)
            else:  # emitter
                if radiance is not None or held_light is not None:
                    self.fail(obj, "a shape takes only one emitter")
                if obj.attrs.get("type") in ENVIRONMENT_TYPES:   # Mitsuba would sample it but not see it: refused
                    self.fail(obj, f"a {obj.attrs['type']} emitter belongs at the top level of the scene")
                if obj.attrs.get("type") != "area":
                    held_light = obj   # read after the shape, which has no part in it (see placed_emitter)
                    continue
                eprops = self.plugin(obj, {"area": EMITTER_PROPS["area"]}, ("texture", "ref"))
                emitter_texture = self.emitter_textures(eprops, "radiance", "area").get("radiance")
                radiance = ((1.0, 1.0, 1.0) if emitter_texture is not None
                            else self.color(eprops, "radiance", (1.0, 1.0, 1.0), emitter=True))
        if material is None:
            material = self.default_material_index(emitter=radiance is not None or held_light is not None)
        if held_light is not None:
            self.placed_emitter(held_light)

        src = self.at(node)
        common = dict(material=material, flip_normals=flip, emitter_radiance=radiance, emitter_texture=emitter_texture,
                      id=node.attrs.get("id", ""), source=src,
                      interior=media.get("interior", -1), exterior=media.get("exterior", -1))
        # Under a mirroring to_world Mitsuba 3 keeps a rectangle's and a cube's front where the inverse transpose takes
        # their normals (the shading frame, by which they emit and scatter; their winding turns), and turns a sphere
        # inside out (sphere.cpp flips its normals); a disk, a cylinder and a mesh file keep theirs.  Checked against
        # Mitsuba 3.9.1 in tests/test_scene_loader.py.
        mirrored = bool(np.linalg.det(to_world[:3, :3]) < 0)
        if kind in ("rectangle", "cube", "obj", "ply", "serialized"):
            if kind == "rectangle":
                local = rectangle_mesh()
            elif kind == "cube":
                local = cube_mesh()
            else:
                if not props.has("filename"):
                    self.fail(node, f"a {kind} shape needs <string name=\"filename\" .../>")
                index = int(self.number(props, "shape_index", 0, nonneg=True))
                try:
                    path = self.find_file(props.node_of("filename"), props.get("filename"))
                    self.files.append(Path(path))
                    if kind == "serialized":
                        local = load_serialized(path, index)
                    else:
                        local = load_mesh_file(path, kind, props.get("flip_tex_coords", kind == "obj"))
                except SceneError as exc:
                    self.fail(props.node_of("filename"), str(exc))
                if props.get("face_normals", False):
                    local.normals = None
            try:
                mesh = to_world_mesh(local, to_world, flip != (mirrored and kind in ("rectangle", "cube")))
            except SceneError as exc:
                self.fail(node, str(exc))
            if kind in ("obj", "ply", "serialized") and mesh.normals is None and not props.get("face_normals", False):
                # A file without vertex normals shades smoothly in Mitsuba 3: it computes them (in world space)
                mesh.normals = vertex_normals_by_angle(mesh.positions, mesh.triangles)
            return Shape(MESH, mesh=mesh, to_world=to_world, **common)
        if kind in ("linearcurve", "bsplinecurve"):
            return Shape(MESH, mesh=self.curve(node, props, kind, to_world), to_world=to_world, **common)
        if kind == "sdfgrid":
            return Shape(MESH, mesh=self.sdf_grid(node, props, to_world, material, radiance), to_world=to_world,
                         **common)
        if kind == "sphere":
            radius = self.number(props, "radius", 1.0, positive=True)
            center = props.get("center", np.zeros(3))
            m = self.placement(node, to_world @ tf.translate(center) @ tf.scale(radius),
                               "to_world with the center and radius")
            lin = m[:3, :3]
            gram = lin.T @ lin
            s2 = np.trace(gram) / 3.0
            if np.abs(gram - s2 * np.eye(3)).max() > 1e-6 * s2:
                self.fail(props.node_of("to_world"), "a sphere's to_world must not shear or scale "
                                                     "non-uniformly (Mitsuba's sphere stays round)")
            return Shape(SPHERE, to_world=m, **{**common, "flip_normals": flip != mirrored})
        if self.materials[material].kind in WRAPPERS or self.needs_tangent(material):
            what = (MATERIAL_NAMES[self.materials[material].kind] if self.materials[material].kind in WRAPPERS
                    else f"BSDF with anisotropic roughness ({MATERIAL_NAMES[self.materials[material].kind]})")
            self.fail(node, f"a {what} on a {kind} is not supported (its "
                            f"position partials dp/du, dp/dv are not implemented)",
                      supported=["rectangle", "cube", "obj", "ply", "serialized", "linearcurve", "bsplinecurve",
                                 "sphere"])
        if kind == "disk":
            return Shape(DISK, to_world=to_world, **common)
        # cylinder (Mitsuba: to_world @ translate(p0) @ to_frame(dir) @ scale(r, r, length))
        radius = self.number(props, "radius", 1.0, positive=True)
        p0 = props.get("p0", np.zeros(3))
        p1 = props.get("p1", np.array([0.0, 0.0, 1.0]))
        d = p1 - p0
        length = float(np.linalg.norm(d))
        if length == 0.0:
            self.fail(props.node_of("p1"), "the cylinder's p0 and p1 coincide")
        m = self.placement(node, to_world @ tf.translate(p0) @ tf.to_frame(d / length)
                           @ tf.scale([radius, radius, length]), "to_world with p0, p1 and the radius")
        c0, c1, c2 = m[:3, 0], m[:3, 1], m[:3, 2]
        tol = 1e-6 * max(np.dot(c0, c0), np.dot(c1, c1))
        if (abs(np.dot(c0, c0) - np.dot(c1, c1)) > tol or abs(np.dot(c0, c1)) > tol
                or abs(np.dot(c0, c2)) > 1e-6 * np.linalg.norm(c0) * np.linalg.norm(c2)
                or abs(np.dot(c1, c2)) > 1e-6 * np.linalg.norm(c1) * np.linalg.norm(c2)):
            self.fail(props.node_of("to_world"), "a cylinder's to_world must keep its cross-section "
                                                 "circular (no shear or non-uniform scaling across the axis)")
        return Shape(CYLINDER, to_world=m, **common)

    def curve(self, node: Node, props, kind: str, to_world: np.ndarray) -> Mesh:
        """A curve shape's tessellation in world space (:mod:`.curves`)."""
        if not props.has("filename"):
            self.fail(node, f"a {kind} shape needs <string name=\"filename\" .../>")
        try:
            path = self.find_file(props.node_of("filename"), props.get("filename"))
            self.files.append(Path(path))
            return curve_mesh(read_curves(path, kind), kind, to_world)
        except SceneError as exc:
            self.fail(props.node_of("filename"), str(exc))

    def sdf_grid(self, node: Node, props, to_world: np.ndarray, material: int, radiance) -> Mesh:
        """An sdfgrid shape's tessellation in world space (:mod:`.sdfgrid`), refusing what Mitsuba's sdfgrid
        does not do (an area emitter, flipped normals, a BSDF that needs dp/du: it has no surface coordinates)."""
        if radiance is not None:
            self.fail(node, "an sdfgrid cannot be an area emitter (Mitsuba's sdfgrid cannot be sampled)")
        if props.has("flip_normals"):
            self.fail(props.node_of("flip_normals"), "an sdfgrid takes no flip_normals (Mitsuba's sdfgrid has none)")
        if self.materials[material].kind in WRAPPERS or self.needs_tangent(material):
            what = (MATERIAL_NAMES[self.materials[material].kind] if self.materials[material].kind in WRAPPERS
                    else f"BSDF with anisotropic roughness ({MATERIAL_NAMES[self.materials[material].kind]})")
            self.fail(node, f"a {what} on an sdfgrid is not supported (Mitsuba's sdfgrid has no surface "
                            f"coordinates: its dp/du is zero)")
        mode = props.get("normals", "smooth")
        if mode not in NORMAL_MODES:
            self.fail(props.node_of("normals"), f"unknown normals mode {quoted(mode)}", supported=list(NORMAL_MODES))
        if not props.has("filename"):
            self.fail(node, "an sdfgrid needs <string name=\"filename\" .../> (a one-channel Mitsuba .vol file; "
                            "Mitsuba's inline 'grid' tensor cannot be given in XML)")
        where = props.node_of("filename")
        try:
            path = self.find_file(where, props.get("filename"), "sdf grid")
            self.files.append(Path(path))
            data, _ = read_grid(path, channels=(1,), purpose="an sdfgrid's distances take 1")
            f = check_grid(data)
            local = sdf_mesh(f, mode, what=f"sdf grid {quoted(str(props.get('filename')))}")
            return to_world_mesh(local, to_world)
        except SceneError as exc:
            self.fail(where, f"sdf grid {quoted(str(props.get('filename')))}: {exc}"
                      if not str(exc).startswith(("grid volume", "sdf grid")) else str(exc))

    def placement(self, node: Node, m: np.ndarray, what: str) -> np.ndarray:
        """The matrix placing an analytic shape, checked like every transform (SceneError at node)."""
        try:
            return tf.check_transform(m)
        except ValueError as exc:
            self.fail(node, f"{what}: {exc}")

    # -- sensor -----------------------------------------------------------------------
    def other_sensor(self, node: Node) -> None:
        """A <sensor> after the first: read and checked as the first is (so that its faults are reported), then
        dropped with what reading it left behind (its far_clip, an inline medium, its film's notes), since only the
        first is rendered."""
        far_clip_node, n_media, n_notes = self.far_clip_node, len(self.media), len(self.loader_notes)
        try:
            self.sensor(node)
        finally:
            self.far_clip_node = far_clip_node
            del self.media[n_media:], self.loader_notes[n_notes:]
            for key in [k for k, i in self.medium_of_node.items() if i >= n_media]:
                del self.medium_of_node[key]
        self.other_sensors.append(node)

    def sensor(self, node: Node) -> tuple[Camera, int]:
        props = self.plugin(node, SENSOR_PROPS, ("film", "sampler", "medium", "ref"))
        projection = "orthographic" if node.attrs["type"] == "orthographic" else "perspective"
        fov, axis = self.field_of_view(node, props) if projection == "perspective" else (0.0, "x")
        near = float(self.number(props, "near_clip", DEFAULT_NEAR_CLIP, positive=True))
        far = float(self.number(props, "far_clip", DEFAULT_FAR_CLIP, positive=True))
        if not near < far:
            self.fail(props.node_of("far_clip" if props.has("far_clip") else "near_clip"),
                      f"near_clip ({near:g}) must be smaller than far_clip ({far:g}), as in Mitsuba")
        for p in ("principal_point_offset_x", "principal_point_offset_y"):
            if props.get(p, 0.0) != 0.0:
                self.fail(props.node_of(p), f"'{p}' other than 0 (an off-centre image) is not supported",
                          supported=["0"])
        to_world = props.get("to_world")
        to_world = np.eye(4) if to_world is None else to_world
        if projection == "perspective" and np.any(np.abs(np.diag(to_world[:3, :3].T @ to_world[:3, :3]) - 1.0) > 1e-3):
            # Mitsuba 3's perspective and thinlens: "Scale factors in the camera-to-world transformation are not
            # allowed!" (a scale would stretch the view, which fov and fov_axis give)
            self.fail(props.node_of("to_world"), "a perspective sensor's to_world must not scale (as in Mitsuba 3, "
                                                 "which refuses it: the view's size is its fov)",
                      supported=["lookat, rotate, translate, a mirror (scale -1)"])
        radius, focus = 0.0, far
        if node.attrs["type"] == "thinlens":
            if not props.has("aperture_radius"):
                self.fail(node, "a thinlens sensor needs <float name=\"aperture_radius\" .../> (as in Mitsuba)")
            radius = float(self.number(props, "aperture_radius", 0.0, nonneg=True))
            focus = float(self.number(props, "focus_distance", far, positive=True))
            if radius > 0.0 and not np.allclose(to_world[:3, :3].T @ to_world[:3, :3], np.eye(3), atol=1e-5):
                self.fail(props.node_of("to_world"), "a thin lens's to_world must not scale (as in Mitsuba: the "
                                                     "lens and the focus distance are in world units)")
        width, height, spp = 768, 576, 4
        film_where = self.at(node)
        rfilter = ReconstructionFilter()   # Mitsuba's default: a gaussian, stddev 0.5 (docs/usage.md)
        sample_border = False
        medium = -1
        seen = set()
        for obj in props.objects:
            if obj.tag == "ref":   # a film or sampler declared at the top level, or a medium
                target = self.ids.get(obj.attrs.get("id", ""))
                if target is not None and target.tag in ("film", "sampler"):
                    obj = target
            tag = "medium" if obj.tag == "ref" else obj.tag
            if tag in seen:
                self.fail(obj, f"the sensor takes only one <{tag}>")
            seen.add(tag)
            if tag == "medium":   # the medium the camera sits in
                medium = self.medium_index(obj)
            elif obj.tag == "film":
                film_where = self.at(obj)
                fprops = self.plugin(obj, FILM_PROPS, ("rfilter",))
                width = int(self.number(fprops, "width", width, positive=True))
                height = int(self.number(fprops, "height", height, positive=True))
                sample_border = bool(fprops.get("sample_border", False))
                self.film_settings(fprops, width, height)
                if width * height > MAX_FILM_PIXELS:
                    self.fail(obj, f"a {width:,} x {height:,} film has {width * height:,} pixels, more than "
                                   f"the {MAX_FILM_PIXELS:,} (int32) caustica's kernels can index; "
                                   f"lower width or height")
                if len(fprops.objects) > 1:
                    self.fail(fprops.objects[1], "the film takes only one <rfilter>")
                for rf in fprops.objects:
                    rfilter = self.rfilter(rf)
            else:
                sprops = self.plugin(obj, SAMPLER_PROPS)
                spp = mitsuba_sample_count(obj.attrs["type"], int(self.number(sprops, "sample_count", spp,
                                                                                positive=True)))
                if spp > MAX_SAMPLE_COUNT:
                    self.fail(sprops.node_of("sample_count"), f"sample_count={spp:,} is more than "
                                                              f"{MAX_SAMPLE_COUNT:,} (2^20), the most samples "
                                                              f"per pixel caustica takes")
        cam = Camera(to_world=to_world, fov_deg=fov, fov_axis=axis, width=width, height=height,
                     near_clip=near, far_clip=far, film_source=film_where, medium=medium, rfilter=rfilter,
                     sample_border=sample_border, projection=projection, aperture_radius=radius,
                     focus_distance=focus)
        self.far_clip_node = props.node_of("far_clip") if props.has("far_clip") else None
        return cam, spp

    def rfilter(self, node: Node) -> ReconstructionFilter:
        """A film's <rfilter>: box, tent (radius) or gaussian (stddev), Mitsuba's defaults."""
        props = self.plugin(node, RFILTER_PROPS)
        kind = node.attrs["type"]
        radius = float(self.number(props, "radius", 1.0, positive=True))
        stddev = float(self.number(props, "stddev", 0.5, positive=True))
        for name, v in (("radius", radius), ("stddev", stddev)):
            if not math.isfinite(v):
                self.fail(props.node_of(name), f"'{name}' must be finite, got {v}")
        return ReconstructionFilter(kind, radius, stddev)

    def film_settings(self, fprops: Props, width: int, height: int) -> None:
        """Check hdrfilm's settings that change nothing in caustica's image (they are then ignored) and refuse
        the ones that would: a pixel format other than RGB, a crop window smaller than the film."""
        for name, allowed, other in (("file_format", FILE_FORMATS, ()), ("component_format", COMPONENT_FORMATS, ()),
                                     ("pixel_format", PIXEL_FORMATS, OTHER_PIXEL_FORMATS)):
            if not fprops.has(name):
                continue
            v = fprops.get(name).strip().lower()
            if v in other:   # the same light in other channels: the issue's "accepted", with a note
                at = fprops.node_of(name)
                self.loader_notes.append(f"{self.at(at)}: {name}={quoted(v)}: caustica writes linear sRGB "
                                         f"(R, G, B), where Mitsuba would write {OTHER_PIXEL_FORMATS[v]}")
                continue
            if v not in allowed:
                self.fail(fprops.node_of(name), f"unknown {name} {quoted(v)}", supported=list(allowed) + list(other))
        crop = {}
        for name, default in (("crop_offset_x", 0), ("crop_offset_y", 0), ("crop_width", width),
                              ("crop_height", height)):
            crop[name] = int(self.number(fprops, name, default, nonneg=True))
        for off, size, full in (("crop_offset_x", "crop_width", width), ("crop_offset_y", "crop_height", height)):
            if crop[off] + crop[size] > full or crop[size] == 0:
                self.fail(fprops.node_of(size if fprops.has(size) else off),
                          f"the crop window ({off}={crop[off]}, {size}={crop[size]}) must lie inside the "
                          f"{width} x {height} film and not be empty")
        if tuple(crop.values()) != (0, 0, width, height):
            given = [n for n in crop if fprops.has(n)]
            window = ", ".join(f"{n}={crop[n]}" for n in crop)
            self.fail(fprops.node_of(given[0]),
                      f"a crop window ({window}) smaller than the {width} x {height} "
                      f"film is not supported: caustica renders the whole film; remove the crop_* settings",
                      supported=["a crop window covering the whole film"])

    def field_of_view(self, node: Node, props: Props) -> tuple[float, str]:
        """(fov in degrees, fov_axis) as Mitsuba 3's parse_fov reads them: ``fov`` along ``fov_axis`` (x by
        default), or a ``focal_length`` ("<x>mm", 50mm by default) on 35 mm film, along the diagonal."""
        if props.has("fov") and props.has("focal_length"):
            self.fail(props.node_of("focal_length"), "give either 'fov' or 'focal_length', not both (as in Mitsuba)")
        if props.has("fov"):
            fov = float(props.get("fov"))
            if not 0.0 < fov < 180.0:
                self.fail(props.node_of("fov"), f"fov must be between 0 and 180 degrees, got {fov}")
            axis = props.get("fov_axis", "x").strip().lower()
            if axis not in FOV_AXES:
                self.fail(props.node_of("fov_axis"), f"unknown fov_axis {quoted(axis)}", supported=list(FOV_AXES))
            return fov, axis
        if props.has("fov_axis"):   # Mitsuba reads it only with fov; check it all the same
            axis = props.get("fov_axis").strip().lower()
            if axis not in FOV_AXES:
                self.fail(props.node_of("fov_axis"), f"unknown fov_axis {quoted(axis)}", supported=list(FOV_AXES))
        f = props.get("focal_length", f"{DEFAULT_FOCAL_LENGTH_MM:g}mm")
        text = str(f).strip()
        text = text[:-2] if text.endswith("mm") else text
        try:
            mm = tf.parse_float(text)
        except ValueError:
            mm = float("nan")
        if not mm > 0:
            self.fail(props.node_of("focal_length"), f"focal_length={quoted(f)} is not a positive length in "
                                                     f"millimetres; write it as \"<x>mm\", e.g. \"50mm\"")
        return math.degrees(2.0 * math.atan(FILM_DIAGONAL_MM / (2.0 * mm))), "diagonal"

    def check_far_clip(self, camera: Camera, shapes: list[Shape]) -> None:
        """caustica's camera rays do not stop at far_clip: accept a far_clip no shape reaches (then it changes
        nothing), refuse one that would hide part of the scene.  Only a far_clip the file gives is checked
        (Mitsuba's default, 1e4, cuts only scenes larger than that, which loaded before).  The test is the
        camera-space depth (the distance along the view axis, where Mitsuba's far plane lies) of each shape's
        bounds."""
        if self.far_clip_node is None:
            return   # Mitsuba's default 1e4: not checked, so that scenes of any size load as before
        m = np.asarray(camera.to_world, dtype=np.float64)
        axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
        depth = _farthest_depth(shapes, m[:3, 3], axis)
        if depth is not None and depth > camera.far_clip:
            self.fail(self.far_clip_node,
                      f"far_clip={camera.far_clip:g} would hide the parts of the scene beyond it (they reach "
                      f"{depth:.4g} along the view axis), and caustica does not clip camera rays at far_clip; "
                      f"raise far_clip to at least {depth:.4g} or remove it")

    # -- integrator -------------------------------------------------------------------
    def integrator(self, node: Node) -> IntegratorSettings:
        """The scene's <integrator>, recorded for the methods (not checked against a list: caustica picks its own
        method).  A wrapper (``moment``, ``aov``, ``stokes``) stands for the integrator it wraps, whose
        max_depth, rr_depth and hide_emitters are checked as Mitsuba checks them."""
        self.check_attrs(node, ("type", "id", "name"), ("type",))
        wrapper, wrapper_node = "", None
        inner = [c for c in node.children if c.tag == "integrator"]
        if node.attrs["type"] in INTEGRATOR_WRAPPERS and inner:
            wrapper, wrapper_node = node.attrs["type"], node
            node = inner[0]
            self.check_attrs(node, ("type", "id", "name"), ("type",))
        props = self.generic_props(node)
        values = {}
        for name, (default, kind, rule) in INTEGRATOR_SETTINGS.items():
            v = props.get(name, default)
            child = next((c for c in node.children if c.tag in PROPERTY_TAGS and c.attrs.get("name") == name), node)
            ok = isinstance(v, bool) if kind is bool else (isinstance(v, int) and not isinstance(v, bool))
            if not ok:
                self.fail(child, f"'{name}' must be given as <{'boolean' if kind is bool else 'integer'}>")
            if kind is int and not rule(v):
                self.fail(child, f"'{name}' must be {'at least -1' if name == 'max_depth' else 'positive'}, got {v} "
                                 f"(as in Mitsuba)")
            values[name] = v
        return IntegratorSettings(type=node.attrs["type"], **values, wrapper=wrapper, props=props,
                                  source=self.at(node), wrapper_source="" if wrapper_node is None
                                  else self.at(wrapper_node))

    def generic_props(self, node: Node) -> dict:
        """Any properties and nested plugins, for the integrator (recorded, not checked)."""
        out = {}
        for c in node.children:
            if c.tag in PROPERTY_TAGS:
                if "name" not in c.attrs:
                    self.fail(c, "a property needs a name= attribute")
                out[c.attrs["name"]] = self.property_value(c)
            else:
                key = c.attrs.get("name") or c.tag
                out[key] = {"type": c.attrs.get("type", ""), **self.generic_props(c)}
        return out

    # -- the scene ----------------------------------------------------------------------
    def scene(self, root: Node) -> SceneDescription:
        camera, spp = None, 4
        settings, integrator_node = IntegratorSettings(), None
        shapes: list[Shape] = []
        sensor_seen = False
        for node in root.children:
            if node.tag == "sensor":
                sensor_seen = True
            try:
                camera, spp, settings, integrator_node = self.top_level(node, camera, spp, settings, integrator_node,
                                                                        shapes)
            except SceneError as exc:
                self.record(exc)
                self.lint_children(node)
            except _Abandon:
                self.lint_children(node)
        named = {c.attrs.get("id") for n in root.children if n.tag == "shape" for c in n.children if c.tag == "ref"}
        for n in self.top_level_area.values():
            # unused, and not because the shape that names it failed (that shape's problem is reported)
            if id(n) not in self.referenced_emitters and n.attrs["id"] not in named:
                self.errors.append(f"{self.at(n)}: {n.describe()}: an area emitter must be nested inside a <shape> "
                                   f"or given to one by <ref id=\"{n.attrs['id']}\"/>; no shape refers to it")
        if camera is None and not sensor_seen:
            self.errors.append(f"{self.source}:{root.line}: <scene>: the scene has no <sensor>; "
                               f"add <sensor type=\"perspective\">")
        if camera is not None:
            try:
                self.check_far_clip(camera, shapes)
            except SceneError as exc:
                self.record(exc)
        self.check_mesh_attributes(shapes)
        self.check_textures_used(shapes)
        self.raise_errors()
        if self.other_sensors:
            n = len(self.other_sensors)
            lines = ", ".join(f"line {s.line}" if s.source in ("", self.source) else self.at(s)
                              for s in self.other_sensors)
            self.loader_notes.append(f"{self.source}: the scene has {n + 1} <sensor>s: caustica renders the first, "
                                     f"as Mitsuba's render() does by default; "
                                     f"{'the other' if n == 1 else f'the other {n}'} "
                                     f"({lines}) {'is' if n == 1 else 'are'} read, not rendered")
        return SceneDescription(camera=camera, shapes=shapes, materials=self.materials,
                                point_lights=self.point_lights, spp=spp, integrator=settings.type, media=self.media,
                                integrator_props=settings.props, source=self.source,
                                integrator_source=settings.source, integrator_settings=settings,
                                environment=self.environment_emitter, directional_lights=self.directional_lights,
                                projectors=self.projectors, loader_notes=self.loader_notes)

    def environment(self, node: Node) -> Environment:
        """A ``constant`` or ``envmap`` emitter (Mitsuba 3's): uniform radiance, or a latitude-longitude image."""
        kind = node.attrs["type"]
        props = self.plugin(node, {kind: EMITTER_PROPS[kind]})
        if kind == "constant":
            return Environment("constant", radiance=self.color(props, "radiance", (1.0, 1.0, 1.0), emitter=True),
                               source=self.at(node))
        if not props.has("filename"):
            self.fail(node, "an envmap needs a 'filename' (a latitude-longitude image)")
        scale = self.number(props, "scale", 1.0, nonneg=True)
        filename = props.get("filename")
        where = props.node_of("filename")
        try:
            path = self.find_file(where, filename, "environment map")
            self.files.append(Path(path))
            image = read_radiance_image(path)
        except CausticaError as exc:   # SceneError too
            self.fail(where, str(exc))
        if not np.all(np.isfinite(image)):
            self.fail(where, f"environment map {quoted(filename)} has NaN or infinite pixels")
        if image.min() < 0.0:
            self.fail(where, f"environment map {quoted(filename)} has negative pixels (down to {image.min():g}); "
                             f"radiance must not be negative")
        # Mitsuba pads a map to at least 2 x 3 pixels, repeating its last column and row (Bitmap::pad_to)
        h, w = image.shape[:2]
        image = np.pad(image, ((0, max(0, 3 - h)), (0, max(0, 2 - w)), (0, 0)), mode="edge")
        image = image * scale
        if image.max() > tf.MAX_ABS_FLOAT:
            self.fail(node, f"environment map radiance up to {image.max():.3g} (with scale {scale:g}) is beyond "
                            f"{tf.MAX_ABS_FLOAT:.3g} (float32)")
        rot = np.eye(3)
        if props.has("to_world"):
            m = np.asarray(props.get("to_world"), dtype=np.float64)[:3, :3]
            # directions only: the rotation part (Mitsuba applies the linear part to unit directions)
            u, _, vt = np.linalg.svd(m)
            rot = u @ vt
            # a rotation to the precision scene files write matrices in (Mitsuba's exporters: 6 digits)
            if not np.allclose(m, rot, rtol=0.0, atol=1e-5) or np.linalg.det(rot) < 0:
                self.fail(props.node_of("to_world"), "an envmap's to_world must be a rotation (its 3x3 part "
                                                     "orthonormal, determinant 1)", supported=["rotate", "lookat",
                                                                                              "matrix of a rotation"])
        return Environment("envmap", image=np.ascontiguousarray(image), to_world=rot, filename=filename,
                           source=self.at(node))

    def point_light(self, node: Node) -> PointLight:
        """A ``point`` emitter: ``position`` or ``to_world``'s translation, ``intensity`` (W/sr)."""
        props = self.plugin(node, {"point": EMITTER_PROPS["point"]})
        if props.has("position") and props.has("to_world"):
            self.fail(node, "give either 'position' or 'to_world', not both")
        if props.has("to_world"):
            pos = props.get("to_world")[:3, 3]
        else:
            pos = props.get("position", np.zeros(3))
        intensity = self.color(props, "intensity", (1.0, 1.0, 1.0), emitter=True)
        return PointLight(tuple(float(c) for c in pos), intensity, source=self.at(node))

    def spot(self, node: Node) -> PointLight:
        """A ``spot`` emitter (Mitsuba 3's): at ``to_world``'s origin, shining along its +z; ``intensity`` (W/sr on
        the axis), ``cutoff_angle`` (degrees, default 20), ``beam_width`` (default 3/4 of the cutoff) and an optional
        projected ``texture`` (a bitmap or checkerboard, multiplying the intensity; the cutoff then below 90 degrees,
        as Mitsuba maps it through tan(cutoff)).  A ``to_world`` that is not a rotation with a uniform scale is
        refused (Mitsuba would tilt the falloff's cone)."""
        props = self.plugin(node, {"spot": EMITTER_PROPS["spot"]}, ("texture", "ref"))
        textures = self.emitter_textures(props, "texture", "spot")
        cutoff = float(self.number(props, "cutoff_angle", 20.0))
        if not 0.0 <= cutoff <= 180.0:
            self.fail(props.node_of("cutoff_angle"), f"'cutoff_angle' must be within [0, 180] degrees, got {cutoff:g}")
        beam = float(self.number(props, "beam_width", cutoff * 3.0 / 4.0))
        if not 0.0 <= beam <= cutoff:
            self.fail(props.node_of("beam_width"), f"'beam_width' must be within [0, cutoff_angle = {cutoff:g}] "
                                                   f"degrees, got {beam:g}")
        texture = textures.get("texture")
        if texture is not None and not 0.0 < cutoff < 90.0:
            self.fail(props.node_of("cutoff_angle"), f"a spot with a projected 'texture' needs a 'cutoff_angle' "
                                                     f"within (0, 90) degrees (Mitsuba maps the texture through "
                                                     f"tan(cutoff_angle)), got {cutoff:g}")
        m = np.asarray(props.get("to_world", np.eye(4)), dtype=np.float64)
        lin = m[:3, :3]
        scale2 = np.trace(lin.T @ lin) / 3.0
        if not (scale2 > 0.0 and np.allclose(lin.T @ lin, scale2 * np.eye(3), rtol=0.0, atol=1e-5 * scale2)):
            self.fail(props.node_of("to_world"), "a spot's to_world must be a rotation with a uniform scale (its "
                                                 "3x3 part a multiple of an orthonormal matrix)",
                      supported=["lookat", "rotate", "translate", "uniform scale"])
        frame = lin / np.linalg.norm(lin, axis=0)
        axis = frame[:, 2]
        intensity = self.color(props, "intensity", (1.0, 1.0, 1.0), emitter=True)
        return PointLight(tuple(float(c) for c in m[:3, 3]), intensity, source=self.at(node),
                          axis=tuple(float(c) for c in axis), cutoff_angle=cutoff, beam_width=beam,
                          texture=texture, frame=None if texture is None else np.ascontiguousarray(frame))

    def emitter_textures(self, props: Props, name: str, kind: str) -> dict[str, Texture]:
        """The texture an emitter takes for its parameter ``name`` (a nested ``<texture name=...>`` or a ``<ref>``),
        as {name: Texture}; the texture's colours must not be negative."""
        out: dict[str, Texture] = {}
        for obj in props.objects:
            given = obj.attrs.get("name")
            if given != name:
                self.fail(obj, f"a {kind} emitter takes a texture only for '{name}'"
                               + (f", not for {quoted(given)}" if given else " (give it name=\"" + name + "\")"),
                          supported=[f"<texture name=\"{name}\">"])
            if name in props.props or name in out:
                self.fail(obj, f"'{name}' is given twice")
            tex = self.texture(obj)
            if tex.unrenderable and kind != "area":   # a spot's or projector's texture is always used
                self.fail(obj, f"a {kind} emitter's texture cannot be {tex.unrenderable}",
                          supported=["bitmap", "checkerboard"])
            if tex.kind == MESH_ATTRIBUTE:
                self.fail(obj, f"a {kind} emitter's texture cannot be a mesh_attribute"
                               + (" (not supported)" if kind == "area" else " (an emitter has no mesh)"),
                          supported=["bitmap", "checkerboard"])
            low = min(min(tex.color0), min(tex.color1)) if tex.kind == CHECKERBOARD else float(tex.texels.min())
            if not low >= 0.0:
                self.fail(obj, f"the {kind}'s '{name}' texture has negative values (down to {low:g}); an emitter's "
                               f"texture must not be negative")
            out[name] = tex
        return out

    def polarizer(self, node: Node, props: Props, name: str) -> Material:
        """Mitsuba 3's ``polarizer`` as its RGB (unpolarised) variants render it: light passes straight on with half
        its power times ``transmittance`` and is never reflected (a Null lobe: volpath's shadow rays pass it); its
        ``theta`` and ``polarizing`` change only polarised renders and are read for their syntax alone.  That is a
        thindielectric slab of eta 1 (Fresnel reflectance 0) and colour transmittance / 2."""
        transmittance = self.color(props, "transmittance", (1.0, 1.0, 1.0))
        mat = Material(THINDIELECTRIC, tuple(0.5 * t for t in transmittance), int_ior=1.0, ext_ior=1.0, name=name)
        mat.source = self.at(node)
        return mat

    def projector(self, node: Node) -> Projector:
        """A ``projector`` emitter (Mitsuba 3's): a point light at ``to_world``'s origin projecting its ``irradiance``
        (a bitmap or checkerboard texture, or a constant colour; default 1) times ``scale`` along its +z through a
        pinhole of field of view ``fov`` along ``fov_axis`` (or a ``focal_length``), as Mitsuba's perspective
        camera: the aspect is the texture's width / height.  ``to_world`` must be a rigid motion."""
        props = self.plugin(node, {"projector": EMITTER_PROPS["projector"]}, ("texture", "ref"))
        texture = self.emitter_textures(props, "irradiance", "projector").get("irradiance")
        if texture is not None and not np.allclose(texture.to_uv, np.eye(3)[:2], rtol=0.0, atol=1e-12):
            self.fail(props.objects[0], "a projector's texture with a 'to_uv' is not supported (the projector "
                                        "samples the image's texels where they fall)", supported=["no to_uv"])
        irradiance = self.color(props, "irradiance", (1.0, 1.0, 1.0), emitter=True)
        scale = float(self.number(props, "scale", 1.0, nonneg=True))
        if not math.isfinite(scale):
            self.fail(props.node_of("scale"), f"'scale' must be finite, got {scale}")
        aspect = 1.0
        if texture is not None and texture.kind == BITMAP:
            aspect = texture.texels.shape[1] / texture.texels.shape[0]
        fov, fov_axis = self.field_of_view(node, props)
        tan_x, tan_y = fov_tangents(fov, fov_axis, aspect)
        if not (0.0 < tan_x < 1e15 and 0.0 < tan_y < 1e15):
            self.fail(props.node_of("fov"), f"the projector's field of view ({fov:g} degrees along {fov_axis}) is "
                                             f"too close to 0 or 180 degrees along one of its axes")
        m = np.asarray(props.get("to_world", np.eye(4)), dtype=np.float64)
        lin = m[:3, :3]
        if not np.allclose(lin.T @ lin, np.eye(3), rtol=0.0, atol=1e-5):
            self.fail(props.node_of("to_world"), "a projector's to_world must be a rigid motion (its 3x3 part "
                                                 "orthonormal: Mitsuba scales a projector's light by a scale in it in "
                                                 "direct lighting but not in its emitted rays)",
                      supported=["lookat", "rotate", "translate"])
        frame = lin / np.linalg.norm(lin, axis=0)
        return Projector(tuple(float(c) for c in m[:3, 3]), np.ascontiguousarray(frame), irradiance=irradiance,
                         texture=texture, scale=scale, tan_x=float(tan_x), tan_y=float(tan_y),
                         source=self.at(node))

    def directional(self, node: Node) -> DirectionalLight:
        """A ``directional`` emitter (Mitsuba 3's): ``irradiance`` (W/m²) travelling along ``direction`` or
        ``to_world``'s +z (default +z), normalised."""
        props = self.plugin(node, {"directional": EMITTER_PROPS["directional"]})
        if props.has("direction") and props.has("to_world"):
            self.fail(node, "give either 'direction' or 'to_world', not both")
        if props.has("to_world"):
            d, where = np.asarray(props.get("to_world"), dtype=np.float64)[:3, 2], props.node_of("to_world")
        else:
            d, where = np.asarray(props.get("direction", (0.0, 0.0, 1.0)), dtype=np.float64), \
                props.node_of("direction")
        norm = float(np.linalg.norm(d))
        if not (norm > 0.0 and math.isfinite(norm)):
            self.fail(where, f"a directional light needs a non-zero finite direction, got {tuple(float(c) for c in d)}")
        irradiance = self.color(props, "irradiance", (1.0, 1.0, 1.0), emitter=True)
        return DirectionalLight(tuple(float(c) for c in d / norm), irradiance, source=self.at(node))

    def placed_emitter(self, node: Node) -> None:
        """A point, spot, projector or directional emitter: placed by its own parameters, wherever it is declared.

        Mitsuba 3 lets a shape hold such an emitter as its one emitter child.  The shape neither moves it nor emits:
        the image is the same, bit for bit, as with the emitter at the top level (checked with Mitsuba 3.9.1), except
        that a shape without a BSDF gets an emitter's black default."""
        kind = node.attrs.get("type")
        if kind == "directional":
            self.directional_lights.append(self.directional(node))
        elif kind == "spot":
            self.point_lights.append(self.spot(node))
        elif kind == "projector":
            self.projectors.append(self.projector(node))
        elif kind in (None, "point"):
            self.point_lights.append(self.point_light(node))
        else:
            self.fail(node, f"unknown emitter type {quoted(node.attrs['type'])}",
                      supported=["point", "spot", "projector", "directional", "area (inside a <shape>)",
                                 "constant (top level)", "envmap (top level)"])

    def top_level(self, node: Node, camera, spp, settings, integrator_node, shapes):
        """Read one element at the top of the scene (what it defines goes into the arguments)."""
        tag = node.tag
        if tag == "default":
            return camera, spp, settings, integrator_node
        if tag == "integrator":
            if integrator_node is not None:
                self.fail(node, f"only one <integrator> is allowed (first on line {integrator_node.line})")
            integrator_node = node
            settings = self.integrator(node)
        elif tag == "sensor":
            if camera is None:
                camera, spp = self.sensor(node)
            else:   # read and checked as Mitsuba loads it; its render() takes the first sensor unless told
                self.other_sensor(node)
        elif tag == "bsdf":
            self.material_index(node)
        elif tag == "texture":   # declared for a BSDF's <ref>; read (and checked) here
            self.texture(node)
        elif tag in ("film", "sampler"):   # declared for a <ref> from the sensor, read there
            if "id" not in node.attrs:
                self.fail(node, f"a <{tag}> at the top level needs an id= for the sensor's <ref>",
                          supported=[f"<{tag}> inside the <sensor>",
                                     f"<{tag} id=...> with <ref id=.../> in the sensor"])
        elif tag == "medium":
            self.medium_index(node)
        elif tag == "shape" and node.attrs.get("type") == "shapegroup":
            self.check_attrs(node, ("type", "id", "name"), ("type",))
            if "id" not in node.attrs:
                self.fail(node, "a shapegroup needs an id= for its instances' <ref>")
        elif tag == "shape" and node.attrs.get("type") == "instance":
            shapes.extend(self.instance(node))
        elif tag == "shape":
            shapes.append(self.shape(node))
        elif tag == "emitter":
            if node.attrs.get("type") == "area":
                if "id" in node.attrs:   # Mitsuba's area emitter declared once and given to a shape by <ref>
                    self.top_level_area[id(node)] = node
                    return camera, spp, settings, integrator_node
                self.fail(node, "an area emitter must be nested inside a <shape>")
            if node.attrs.get("type") in ENVIRONMENT_TYPES:
                env = self.environment(node)
                if self.environment_node is not None:
                    self.fail(node, f"only one environment emitter is allowed (as in Mitsuba; the first is on line "
                                    f"{self.environment_node.line})")
                self.environment_node = node
                self.environment_emitter = env
                return camera, spp, settings, integrator_node
            self.placed_emitter(node)
        else:
            self.fail(node, "unknown element at the top level of the scene",
                      supported=[f"<{t}>" for t in TOP_LEVEL_TAGS])
        return camera, spp, settings, integrator_node


def scalar_range(tex: Texture) -> tuple[float, float]:
    """The lowest and highest value a checkerboard, bitmap or rawconstant texture gives where a BSDF reads a number
    (its eval_1: a checkerboard colour's mean, a texel's luminance; bsdfs/textures.texture_value)."""
    if tex.kind == CHECKERBOARD:
        values = [sum(tex.color0) / 3.0, sum(tex.color1) / 3.0]
    else:
        values = tex.texels.reshape(-1, 3).astype(np.float64) @ np.array([0.212671, 0.715160, 0.072169])
    return float(np.min(values)), float(np.max(values))


def texture_mean(tex: Texture) -> tuple[float, float, float]:
    """A texture's mean colour (its checkerboard colours' or its texels' mean): the material's ``rgb`` for what
    reads one colour per material."""
    if tex.kind == CHECKERBOARD:
        return tuple(0.5 * (a + b) for a, b in zip(tex.color0, tex.color1))
    if tex.kind == MESH_ATTRIBUTE:
        return (0.5, 0.5, 0.5)   # unused: every reader of a mesh_attribute's colour looks it up per hit
    return tuple(float(c) for c in tex.texels.reshape(-1, 3).astype(np.float64).mean(axis=0))


def mitsuba_sample_count(kind: str, spp: int) -> int:
    """The samples per pixel a Mitsuba 3 sampler of this kind takes for ``sample_count`` spp: stratified and
    ldsampler round up to a square (ldsampler: of a power of two), orthogonal to the square of a prime,
    multijitter to a near-square product (Mitsuba's set_sample_count, src/samplers/)."""
    if spp > MAX_SAMPLE_COUNT:
        return spp   # refused by the caller with the bound
    if kind == "stratified":
        r = math.isqrt(spp - 1) + 1 if spp > 1 else 1
        return r * r
    if kind == "multijitter":
        ry = max(1, math.isqrt(spp))
        return -(-spp // ry) * ry
    if kind == "orthogonal":
        r = 2
        while r * r < spp or any(r % k == 0 for k in range(2, math.isqrt(r) + 1)):
            r += 1
        return r * r
    if kind == "ldsampler":
        r = 2
        while r * r < spp:
            r = 1 << (r).bit_length()   # round_to_power_of_two(r + 1) for r >= 2
        return r * r
    return spp


def _farthest_depth(shapes: list[Shape], origin: np.ndarray, axis: np.ndarray) -> float | None:
    """The largest depth (distance along ``axis`` from ``origin``) any shape reaches, an upper bound for
    disks and cylinders (their bounding boxes' corners); None without shapes."""
    best = None
    for s in shapes:
        if s.mesh is not None:
            d = float(np.max((s.mesh.positions - origin) @ axis)) if len(s.mesh.positions) else None
        elif s.kind == SPHERE:
            m = s.to_world
            d = float((m[:3, 3] - origin) @ axis + np.linalg.norm(m[:3, 0]))
        else:
            zs = (0.0, 1.0) if s.kind == CYLINDER else (0.0,)
            corners = np.array([[x, y, z, 1.0] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in zs])
            d = float(np.max(((corners @ s.to_world.T)[:, :3] - origin) @ axis))
        if d is not None and (best is None or d > best):
            best = d
    return best


# ----------------------------------------------------------------------------- entry points

def parse_scene_string(text: str | bytes, base_dir: str | Path = ".", defaults: dict | None = None,
                       source_name: str = "<string>", main_file: Path | None = None) -> SceneDescription:
    """Parse Mitsuba XML text; mesh filenames and <include>s are relative to base_dir.

    defaults: values for ``$name`` (Mitsuba's ``-D``), overriding the file's ``<default>``s.
    source_name: the name used in error messages and as ``SceneDescription.source``.
    """
    root = _parse_xml(text, source_name, Path(base_dir))
    loader = _Loader(source_name, Path(base_dir), {})
    loader.main_file = main_file
    if root.tag != "scene":
        loader.fail(root, "the root element must be <scene>", supported=["<scene>"])
    loader.check_attrs(root, ("version",))
    given = {str(k): _param_str(v) for k, v in (defaults or {}).items()}
    loader.params = dict(given)
    loader.read_defaults(root)
    loader.file_versions[source_name] = _version(root.attrs.get("version"))
    loader.expand(root, (), True)
    loader.substitute(root)
    loader.aliases(root)
    loader.raise_errors()    # stop here: nothing can be read with a value missing
    old = {src for src, v in loader.file_versions.items() if v is not None and v < (2,)}
    if old:
        _upgrade_from_v1(root, old)
    _check_defines(source_name, given, loader.declared, loader.used_params)
    desc = loader.scene(root)
    desc.files = loader.files
    return desc


_PARAM_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def camel_to_snake(name: str) -> str:
    """Mitsuba 3's camel_to_underscore_case (parser.cpp): "toWorld" -> "to_world", "intIOR" -> "int_ior"."""
    out, i = [], 0
    while i < len(name):
        c = name[i]
        if i > 0 and name[i - 1].islower() and c.isupper():
            out += ["_", c.lower()]
            while i + 1 < len(name) and name[i + 1].isupper():
                i += 1
                out.append(name[i].lower())
        else:
            out.append(c)
        i += 1
    return "".join(out)


def _version(text: str | None) -> tuple[int, ...] | None:
    """A file's version="x.y.z" as numbers, None when absent or not numbers."""
    if text is None:
        return None
    try:
        return tuple(int(p) for p in text.strip().split("."))
    except ValueError:
        return None


def _upgrade_from_v1(node: Node, old: set[str]) -> None:
    """Mitsuba 3's upgrade of files older than version 2.0 (parser.cpp, upgrade_from_v1): property names in
    camelCase become snake_case (toWorld, sampleCount, intIOR, fovAxis...), and a diffuse BSDF's
    diffuse_reflectance becomes reflectance.  ``old``: the files (sources) whose version is below 2."""
    if node.source in old:
        if "name" in node.attrs and (node.tag in PROPERTY_TAGS or node.tag in ("ref",) or node.tag in SUPPORTED):
            node.attrs["name"] = camel_to_snake(node.attrs["name"])
        if node.tag == "bsdf" and node.attrs.get("type") == "diffuse":
            for c in node.children:
                if c.tag in PROPERTY_TAGS and c.source in old and \
                        camel_to_snake(c.attrs.get("name", "")) == "diffuse_reflectance":
                    c.attrs["name"] = "reflectance"
    for c in node.children:
        _upgrade_from_v1(c, old)


def _check_defines(source: str, given: dict[str, str], declared: dict[str, Node], used: set[str]) -> None:
    """Every caller's value (``-D name=value``) must reach a ``$name`` the scene uses, as every
    method parameter must be a known one: a misspelt or empty name is an error, not ignored."""
    names = sorted(used)
    for k, v in given.items():
        if k in used:
            continue
        what = f"{source}: -D {shorten(k)}={shorten(v)}"
        if not k:
            problem = "a define needs a name (-D name=value)"
        elif k in declared:
            problem = (f"the scene declares <default name=\"{k}\"> (line {declared[k].line}) but never uses ${k}, "
                       f"so the value would change nothing")
        else:
            close = difflib.get_close_matches(k, names, n=1)
            problem = f"the scene has no parameter ${shorten(k)}" + (f" (did you mean '{close[0]}'?)" if close else "")
        raise SceneError(f"{what}: {problem}; the scene's parameters: {_names(names)}")


def _param_str(v) -> str:
    """A -D value as the XML text Mitsuba would see (booleans as true/false)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def load_scene_file(path: str | Path, defaults: dict[str, str] | None = None) -> SceneDescription:
    """Load a Mitsuba XML scene file (the supported subset); SceneError on any problem."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: scene file not found" if not path.exists()
                         else f"{path}: not a file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the scene file: {exc.strerror}") from None
    desc = parse_scene_string(data, path.parent, defaults, str(path), main_file=path.resolve())
    desc.files.insert(0, path)
    return desc


def _translation(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m
