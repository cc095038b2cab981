"""Emitters: area lights (one-sided Lambertian, on any shape), point and spot lights, directional lights and an
environment.

A :class:`LightTable` lists every emitter once: area emitters first (one per
emissive shape, in scene order, matching ``Geometry.prim_emitter``), then point and spot
lights (in scene order), then directional lights, then the environment if the scene has one (``env[0]`` its
index, else -1).  Lights are chosen in proportion to their power (mean over RGB), both for
next-event estimation and for photon emission.

Power of a one-sided Lambertian area emitter of radiance L and area A is
Φ = π L A; of a point light of intensity I it is Φ = 4 π I (watts per channel).

A spot light (Mitsuba 3's ``spot``) is a point light whose intensity is I f(θ), θ the angle from its axis:
f = 1 within the beam width β, (γ − θ) / (γ − β) between β and the cutoff angle γ, 0 beyond
(:func:`spot_falloff`).  Its power is Φ = 2π I ∫₀^γ f(θ) sin θ dθ = 2π I (1 − (sin γ − sin β) / (γ − β))
(2π I (1 − cos γ) when β = γ; :func:`spot_power_factor`).

A spot may project a ``texture`` (Mitsuba's): its intensity times T(uv), uv = (1/2 + x / (2 z tan γ),
1/2 + y / (2 z tan γ)) for the direction (x, y, z) in the spot's frame; its power is then a quadrature of
I ∫ f T dω (:func:`profile_power`).

A projector (Mitsuba 3's ``projector``) is a point light projecting an image E through a pinhole of half-angle
tangents (tan_x, tan_y) along its +z: the direction (x, y, z) in its frame meets the image at
uv = (1/2 − x / (2 z tan_x), 1/2 − y / (2 z tan_y)), and its intensity there is π s E(uv) / cos³θ (s its
``scale``), so a plane at distance z across its axis receives π s E / z².  Its power is
Φ = π s A ∫ E du dv, A = 4 tan_x tan_y the image's area on the plane z = 1; a bitmap's ∫ E du dv is its texels'
mean (bilinear or nearest, with any wrap mode).  Its photons take uv by the texels' luminance as Mitsuba's
bitmap ``sample_position`` does (:func:`projector_sample_uv`).

A directional light (Mitsuba 3's ``directional``) of irradiance E shines along one direction from infinitely far
away; like the environment its power is taken over the disc of the scene's bounding sphere (radius R) across
the beam: Φ = π R² E (Mitsuba's convention).

The environment (Mitsuba 3's ``constant`` or ``envmap``) is light from infinitely far away.  Its power is
Φ = π R² ∫ L dω, R the radius of the scene's bounding sphere (Mitsuba's convention; for a map the integral
is the sum over its bilinear patches of their mean radiance times their solid angle).  A map is looked up
as Mitsuba 3 does (:func:`env_lookup`) and sampled by luminance (:func:`env_sample`); a constant one
uniformly over the sphere.

An area emitter's radiance may be a texture (Mitsuba's ``<texture name="radiance">``): radiance[e] x T(uv) at the
point's surface coordinates (:func:`area_radiance`).  Its points are still sampled uniformly by area, each weighted
by the texture there (Mitsuba samples the texture's image instead: the same expectation), and its power is
π ∫ T dA by a quadrature over that sampling (:func:`texture_area_mean`), which only chooses between lights.

Points on an area emitter are sampled uniformly by area.  A rectangle (a
parallelogram of two triangles) is sampled through its own (u, v) parametrisation,
so a regular grid of (u, v) lands on a regular grid on the light (the paper's
"25 point lights distributed evenly"); other shapes pick a primitive by area and
sample it uniformly.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .bsdfs.textures import NEAREST, REPEAT, texture_columns, texture_rgb, wrap
from .geometry import vec
from .geometry.scene_geometry import Geometry, hit_uv, sample_on_primitive, surface_uv
from .features import guarded_by, has, specialisable
from .jit import kernel
from .sampling.warps import square_to_uniform_sphere
from .scene.description import BITMAP, CHECKERBOARD, SceneDescription

AREA = 0
POINT = 1
ENV = 2
SPOT = 3          # a point light with an angular falloff (its axis in LightTable.normal, its cone in .cone)
DIRECTIONAL = 4   # a delta light at infinity (its direction of travel in LightTable.normal)
PROJECTOR = 5     # a point light projecting an image (its frame in edge1, edge2, normal; its image in .cone)
TEXTURED_AREA = 6  # not a kind: the feature code of a LightTable holding an area emitter with a texture
ENV_TO_WORLD = 4   # offsets into LightTable.env_data
TEX_OF, TEX_CDF = 6, 7   # columns of LightTable.tex_int past the texture's own: 1 if the light has a texture;
#                          the offset of its sampling tables in tex_cdf (-1: none)
ENV_CDF = 13
INV_4PI = 1.0 / (4.0 * math.pi)

#: Mitsuba 3's luminance of linear sRGB (its sampling weight for an envmap's texels).
LUMINANCE = (0.212671, 0.715160, 0.072169)


@specialisable
class LightTable(NamedTuple):
    kind: np.ndarray          # int32[L]: AREA, POINT, SPOT, DIRECTIONAL or ENV
    radiance: np.ndarray      # float64[L, 3]: radiance (area), intensity W/sr (point, spot: on its axis),
    #                           irradiance W/m² (directional)
    position: np.ndarray      # float64[L, 3]: point and spot lights' position
    area: np.ndarray          # float64[L]: total area of an area emitter
    power: np.ndarray         # float64[L, 3]: emitted power per channel (W)
    select_pdf: np.ndarray    # float64[L]: probability of choosing the light
    select_cdf: np.ndarray    # float64[L]: running sum of select_pdf (last = 1)
    prim_first: np.ndarray    # int32[L]: first index into prims / prim_cdf
    prim_count: np.ndarray    # int32[L]
    prims: np.ndarray         # int32[*]: the emitters' primitives (Geometry.emitter_prim_ids)
    prim_cdf: np.ndarray      # float64[*]: area CDF within each emitter (Geometry.emitter_cdf)
    is_parallelogram: np.ndarray  # int8[L]: 1 when sampled through corner + u e1 + v e2
    corner: np.ndarray        # float64[L, 3]
    edge1: np.ndarray         # float64[L, 3]: a parallelogram's edges; a projector's or textured spot's unit x
    edge2: np.ndarray         # float64[L, 3]: ... and unit y
    normal: np.ndarray        # float64[L, 3]: the parallelogram's front normal; a spot's axis; the direction a
    #                           directional light's light travels (unit); a projector's axis (its +z)
    cone: np.ndarray          # float64[L, 4]: a spot's (cos γ, cos β, γ in rad, 1 / (γ − β) in 1/rad or 0 when
    #                           β = γ), γ its cutoff angle, β its beam width; a projector's (tan_x, tan_y, A, 0):
    #                           its half-angle tangents and image area 4 tan_x tan_y on the plane z = 1
    # the environment (one entry of kind ENV, or none; arrays of size 1 without one)
    # (few arrays: every call that passes the tables passes each array's fields)
    # The scene's bounding sphere is env_data[0..3] whenever the scene has an environment or a directional light.
    env: np.ndarray           # int32[2]: its index (-1 without one), 1 if constant (radiance[env] everywhere)
    env_image: np.ndarray     # float64[H, W, 3]: a map's radiance (scale applied), Mitsuba's lat-long layout
    env_data: np.ndarray      # float64[*]: the scene's bounding sphere (centre, radius R) at 0..3, then a map's
    #                           rotation to the world (3 x 3, row-major) at ENV_TO_WORLD, then from ENV_CDF
    #                           its CDF over rows of bilinear patches (H - 1), each row's CDF over its patches
    #                           ((H - 1) W) and each patch's density in (u, v) (probability x W (H - 1))
    # The textures of spots and projectors, one row per light (bsdfs/textures.py's columns, read by texture_rgb
    # with the light's index): a light without one has tex_int[e, TEX_OF] = 0.
    tex_int: np.ndarray       # int64[L, 8]: kind, filter, wrap, width, height, first texel row, TEX_OF, TEX_CDF
    tex_float: np.ndarray     # float64[L, 12]: to_uv, a checkerboard's colours
    texels: np.ndarray        # float32[N, 3]: the bitmaps' texels
    tex_cdf: np.ndarray       # float64[*]: a projector's bitmap's sampling tables from tex_int[e, TEX_CDF] (-1:
    #                           none, uniform in uv): its row CDF (H), each row's column CDF (H W), each texel's
    #                           probability x W H (H W)


def _parallelogram(shape):
    """(corner, e1, e2, normal) if the emissive shape is one planar quad of two triangles."""
    mesh = shape.mesh
    if mesh is None or len(mesh.triangles) != 2 or len(mesh.positions) != 4:
        return None
    p = mesh.positions
    # A parallelogram has one corner c with neighbours a, b such that the fourth = a + b - c.
    for c in range(4):
        others = [i for i in range(4) if i != c]
        for far in others:
            a, b = [i for i in others if i != far]
            if np.allclose(p[a] + p[b] - p[c], p[far], atol=1e-9 * (1 + np.abs(p).max())):
                e1, e2 = p[a] - p[c], p[b] - p[c]
                t = mesh.triangles[0]
                n = np.cross(p[t[1]] - p[t[0]], p[t[2]] - p[t[0]])
                return p[c], e1, e2, n / np.linalg.norm(n)
    return None


def _light_columns(n: int) -> dict:
    """The per-light columns of :class:`LightTable` for ``n`` lights, zero (the selection's come last)."""
    c = {k: np.zeros((n, 3)) for k in ("radiance", "position", "power", "corner", "edge1", "edge2", "normal")}
    c.update(kind=np.zeros(n, np.int32), area=np.zeros(n), prim_first=np.zeros(n, np.int32),
             prim_count=np.zeros(n, np.int32), is_parallelogram=np.zeros(n, np.int8), cone=np.zeros((n, 4)))
    return c


def _area_rows(c: dict, emissive: list, geom: Geometry) -> None:
    """Rows 0.. of the area emitters: the geometry lists each one's primitives with their area CDF (CSR)."""
    for e, shape in enumerate(emissive):
        c["prim_first"][e] = geom.emitter_offset[e]
        c["prim_count"][e] = geom.emitter_offset[e + 1] - geom.emitter_offset[e]
        c["kind"][e] = AREA
        c["radiance"][e] = shape.emitter_radiance
        c["area"][e] = geom.emitter_area[e]
        c["power"][e] = math.pi * c["area"][e] * np.asarray(shape.emitter_radiance)
        quad = _parallelogram(shape) if shape.emitter_texture is None else None   # textured: uv from the mesh
        if quad is not None:
            c["is_parallelogram"][e] = 1
            c["corner"][e], c["edge1"][e], c["edge2"][e], c["normal"][e] = quad


def _point_rows(c: dict, desc: SceneDescription, i0: int) -> None:
    """Rows i0.. of the point lights and spots, then of the projectors."""
    kind, radiance, power, edge1, edge2, normal, cone = (c[k] for k in ("kind", "radiance", "power", "edge1",
                                                                        "edge2", "normal", "cone"))
    for j, light in enumerate(desc.point_lights):
        i = i0 + j
        kind[i] = POINT
        radiance[i] = light.intensity
        c["position"][i] = light.position
        power[i] = 4.0 * math.pi * np.asarray(light.intensity)
        if light.axis is not None:
            kind[i] = SPOT
            normal[i] = light.axis
            gamma, beta = math.radians(light.cutoff_angle), math.radians(light.beam_width)
            cone[i] = (math.cos(gamma), math.cos(beta), gamma, 1.0 / (gamma - beta) if gamma > beta else 0.0)
            power[i] = 2.0 * math.pi * spot_power_factor(gamma, beta) * np.asarray(light.intensity)
            if light.frame is not None:
                edge1[i], edge2[i] = light.frame[:, 0], light.frame[:, 1]
    for j, proj in enumerate(desc.projectors):
        i = i0 + len(desc.point_lights) + j
        kind[i] = PROJECTOR
        radiance[i] = math.pi * proj.scale * np.asarray(proj.irradiance if proj.texture is None else (1.0,) * 3)
        c["position"][i] = proj.position
        edge1[i], edge2[i], normal[i] = proj.frame[:, 0], proj.frame[:, 1], proj.frame[:, 2]
        cone[i] = (proj.tan_x, proj.tan_y, 4.0 * proj.tan_x * proj.tan_y, 0.0)
        power[i] = cone[i, 2] * radiance[i] * _image_mean(proj.texture)


def _append_environment(c: dict, env: dict, textures: dict) -> None:
    """One more row, of kind ENV, for the environment: its radiance and power from ``env`` (taken out of it)."""
    c["kind"] = np.append(c["kind"], np.int32(ENV))
    c["radiance"] = np.vstack([c["radiance"], env.pop("radiance")])
    c["power"] = np.vstack([c["power"], env.pop("power")])
    for k in ("position", "edge1", "edge2", "corner", "normal"):
        c[k] = np.vstack([c[k], np.zeros((1, 3))])
    c["cone"] = np.vstack([c["cone"], np.zeros((1, 4))])
    c["area"] = np.append(c["area"], 0.0)
    c["prim_first"] = np.append(c["prim_first"], np.int32(0))
    c["prim_count"] = np.append(c["prim_count"], np.int32(0))
    c["is_parallelogram"] = np.append(c["is_parallelogram"], np.int8(0))
    textures["tex_int"] = np.vstack([textures["tex_int"], _no_texture_row()])
    textures["tex_float"] = np.vstack([textures["tex_float"], np.zeros((1, 12))])


def build_light_table(desc: SceneDescription, geom: Geometry) -> LightTable:
    """The scene's lights in one table: area emitters, point lights and spots, projectors, directional lights,
    then the environment; each chosen in proportion to its mean power (``select_pdf``, ``select_cdf``)."""
    emissive = [s for s in desc.shapes if s.emitter_radiance is not None]
    n_area = len(emissive)
    n_point = n_area + len(desc.point_lights) + len(desc.projectors)
    n = n_point + len(desc.directional_lights)
    c = _light_columns(n)
    _area_rows(c, emissive, geom)
    _point_rows(c, desc, n_area)
    textures = _light_textures(desc, emissive, n)
    env = _environment_tables(desc, geom)
    disc = math.pi * env["env_data"][3] ** 2
    for j, light in enumerate(desc.directional_lights):
        i = n_point + j
        c["kind"][i] = DIRECTIONAL
        c["radiance"][i] = light.irradiance
        c["normal"][i] = light.direction
        c["power"][i] = disc * np.asarray(light.irradiance)
    if desc.environment is not None:
        _append_environment(c, env, textures)
        n += 1
    else:
        env.pop("radiance")
        env.pop("power")
    table = LightTable(**c, select_pdf=np.zeros(n), select_cdf=np.zeros(n),
                       prims=geom.emitter_prim_ids.astype(np.int32), prim_cdf=geom.emitter_cdf.astype(np.float64),
                       **env, **textures)
    power, radiance = c["power"], c["radiance"]
    for e, shape in enumerate(emissive):
        if shape.emitter_texture is not None:   # π A x the mean radiance over the emitter
            power[e] = math.pi * c["area"][e] * np.asarray(texture_area_mean(table, geom, e, 256))
    for j, light in enumerate(desc.point_lights):
        if light.texture is not None:   # a textured spot: I ∫ f T dω by quadrature
            i = n_area + j
            power[i] = radiance[i] * np.asarray(profile_power(table, i, 1024, 2048))
    scalar = power.mean(axis=1)
    total_power = scalar.sum()
    select_pdf = scalar / total_power if total_power > 0 else np.zeros(n)
    select_cdf = np.cumsum(select_pdf)
    if n:
        select_cdf[-1] = 1.0
    return table._replace(power=power, select_pdf=select_pdf, select_cdf=select_cdf)


def _no_texture_row() -> np.ndarray:
    row = np.zeros((1, 8), np.int64)
    row[0, TEX_CDF] = -1
    return row


def _image_mean(tex) -> np.ndarray:
    """∫ E du dv over the unit square of a projector's image (1 for a constant one, whose colour is in its
    radiance): a bitmap's texel mean per channel (bilinear or nearest, any wrap mode: each texel's weight
    integrates to one texel's area), a checkerboard's two colours' mean (to_uv is the identity)."""
    if tex is None:
        return np.ones(3)
    if tex.kind == CHECKERBOARD:
        return 0.5 * (np.asarray(tex.color0) + np.asarray(tex.color1))
    return tex.texels.reshape(-1, 3).astype(np.float64).mean(axis=0)


def discrete_2d(prob: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 2D discrete distribution over the cells of ``prob`` (H x W, summing to 1), sampled row first: the rows'
    CDF (H) and each row's CDF over its columns (H x W), each ending at exactly 1 (an environment map's and a
    projector's image, sampled by luminance)."""
    rows = prob.sum(axis=1)
    row_cdf = np.cumsum(rows)
    row_cdf[-1] = 1.0
    col_cdf = np.cumsum(prob, axis=1) / np.where(rows > 0, rows, 1.0)[:, None]
    col_cdf[:, -1] = 1.0
    return row_cdf, col_cdf


def _light_textures(desc: SceneDescription, emissive: list, n: int) -> dict:
    """The LightTable's texture columns: one row per light (rows of the untextured area emitters and of the
    directional lights empty), and a projector's bitmap's sampling tables (Mitsuba's DiscreteDistribution2D over the
    texels' luminance)."""
    n_area = len(emissive)
    textures = ([s.emitter_texture for s in emissive] + [x.texture for x in desc.point_lights]
                + [x.texture for x in desc.projectors])
    index, ints, floats, texels, _, _ = texture_columns([_Textured(t) for t in textures])
    tex_int = np.zeros((n, 8), np.int64)
    tex_int[:, TEX_CDF] = -1
    tex_float = np.zeros((n, 12))
    chunks, offset = [], 0
    for i, tex in enumerate(textures):
        if tex is None:
            continue
        tex_int[i, :6] = ints[index[i]]
        tex_float[i] = floats[index[i]]
        tex_int[i, TEX_OF] = 1
        if i >= n_area + len(desc.point_lights) and tex.kind == BITMAP:
            lum = tex.texels.astype(np.float64) @ np.asarray(LUMINANCE)
            total = lum.sum()
            if not total > 0.0:
                continue   # a black image: no photons (its power is 0, it is never chosen)
            h, w = lum.shape
            prob = lum / total
            row_cdf, col_cdf = discrete_2d(prob)
            chunks.append(np.concatenate([row_cdf, col_cdf.reshape(-1), (prob * w * h).reshape(-1)]))
            tex_int[i, TEX_CDF] = offset
            offset += chunks[-1].size
    tex_cdf = np.concatenate(chunks) if chunks else np.zeros(1)
    return dict(tex_int=tex_int, tex_float=tex_float, texels=texels, tex_cdf=tex_cdf)


class _Textured(NamedTuple):
    texture: object


def spot_power_factor(gamma: float, beta: float) -> float:
    """∫₀^γ f(θ) sin θ dθ of Mitsuba's spot falloff f (cutoff γ, beam width β, radians; β ≤ γ): the spot's power
    over 2π I.  1 − cos β from the beam, cos β − (sin γ − sin β) / (γ − β) from the linear ramp; the quotient
    is written 2 cos((γ + β) / 2) sin((γ − β) / 2) / (γ − β), which tends to cos γ as β → γ."""
    half = 0.5 * (gamma - beta)
    ramp_mean_cos = math.cos(0.5 * (gamma + beta)) * (math.sin(half) / half if half > 0.0 else 1.0)
    return 1.0 - ramp_mean_cos


def scene_bounding_sphere(geom: Geometry) -> tuple[np.ndarray, float]:
    """(centre, radius) of the sphere about the scene's bounding box, as Mitsuba 3 takes it for an environment."""
    box = geom.scene_box
    centre = 0.5 * (box[:3] + box[3:])
    radius = float(np.linalg.norm(box[3:] - centre))
    return centre, max(radius * (1.0 + 1e-4), 1e-4)


def _environment_tables(desc: SceneDescription, geom: Geometry) -> dict:
    """The LightTable columns of the environment (with its radiance and power rows): a map's patch CDFs.

    A map of H x W texels is looked up bilinearly between texel centres (columns periodic, rows from pole to
    pole, :func:`env_lookup`), so its radiance is bilinear on (H - 1) x W patches: patch (i, j) spans rows
    i, i + 1 and columns j, j + 1 (mod W).  Each is sampled with probability ∝ the mean luminance of its four
    corners times its solid angle, and uniformly in (u, v) within it; a patch of zero weight has zero radiance.
    """
    envd = desc.environment
    out = dict(env=np.array([-1, 0], np.int32), env_image=np.zeros((1, 1, 3)), env_data=np.zeros(ENV_CDF),
               radiance=np.zeros(3), power=np.zeros(3))
    if envd is None and not desc.directional_lights:
        return out
    centre, radius = scene_bounding_sphere(geom)
    out["env_data"] = np.concatenate([centre, [radius], np.eye(3).reshape(-1)])
    if envd is None:
        return out
    n_lights = (sum(1 for s in desc.shapes if s.emitter_radiance is not None) + len(desc.point_lights)
                + len(desc.projectors) + len(desc.directional_lights))
    out["env"] = np.array([n_lights, 1 if envd.kind == "constant" else 0], np.int32)
    disc = math.pi * radius * radius
    if envd.kind == "constant":
        out["radiance"] = np.asarray(envd.radiance, np.float64)
        out["power"] = disc * 4.0 * math.pi * out["radiance"]
        return out
    img = np.ascontiguousarray(envd.image, dtype=np.float64)
    h, w = img.shape[:2]
    theta = np.linspace(0.0, math.pi, h)
    band = np.cos(theta[:-1]) - np.cos(theta[1:])           # ∫ sin θ dθ over each row of patches
    corners = 0.25 * (img[:-1] + img[1:] + np.roll(img[:-1], -1, axis=1) + np.roll(img[1:], -1, axis=1))
    lum = corners @ np.asarray(LUMINANCE)
    weight = lum * band[:, None]
    total = weight.sum()
    if not total > 0.0:
        weight = np.ones_like(weight) * band[:, None]
        total = weight.sum()
    prob = weight / total
    row_cdf, col_cdf = discrete_2d(prob)
    rot = np.asarray(envd.to_world, np.float64).reshape(-1)
    out.update(env_image=img, env_data=np.concatenate([centre, [radius], rot, row_cdf, col_cdf.reshape(-1),
                                                       (prob * w * (h - 1)).reshape(-1)]))
    out["power"] = disc * (corners * (band[:, None, None] * 2.0 * math.pi / w)).sum(axis=(0, 1))
    out["radiance"] = out["power"] / (disc * 4.0 * math.pi)   # the mean radiance (for messages)
    return out


@kernel
def find_cdf(cdf, first, count, u):
    """Index in [first, first + count) of the first cdf entry above u (binary search)."""
    lo = first
    hi = first + count - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= u:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel(inline=True)
def choose_light(lights, u):
    """A light chosen in proportion to power: (index, probability, u rescaled to [0,1))."""
    n = lights.kind.shape[0]
    i = find_cdf(lights.select_cdf, 0, n, u)
    lo = lights.select_cdf[i - 1] if i > 0 else 0.0
    p = lights.select_pdf[i]
    u_rest = (u - lo) / p if p > 0.0 else 0.0
    return i, p, min(max(u_rest, 0.0), 0.99999999)


@kernel(inline=True)
def spot_falloff(lights, e, d):
    """Mitsuba 3's falloff f of spot e towards unit world direction d (leaving the light), in [0, 1]: 1 within
    the beam width β, (γ − θ) / (γ − β) beyond it, 0 from the cutoff angle γ on (θ the angle from the axis)."""
    cos_t = vec.dot(vec.row(lights.normal, e), d)
    if not cos_t > lights.cone[e, 0]:
        return 0.0
    if cos_t >= lights.cone[e, 1]:
        return 1.0
    return (lights.cone[e, 2] - math.acos(min(cos_t, 1.0))) * lights.cone[e, 3]


@kernel
def light_texture(lights, e, uv):
    """Light e's texture (a spot's projected texture, a projector's image) at uv, RGB."""
    return texture_rgb((lights.tex_int, lights.tex_float, lights.texels), e, uv)


@kernel
def profile(lights, e, d):
    """The intensity of textured spot or projector e towards unit world direction d (leaving it) over its
    ``radiance`` row, per channel: a spot's falloff f times its texture at uv = (1/2 + x / (2 z tan γ),
    1/2 + y / (2 z tan γ)); a projector's image E at uv = (1/2 − x / (2 z tan_x), 1/2 − y / (2 z tan_y)) over
    cos³θ = z³, 0 outside the image ((x, y, z) = d in the light's frame; Mitsuba 3's spot and projector)."""
    zero = (0.0, 0.0, 0.0)
    x = vec.dot(vec.row(lights.edge1, e), d)
    y = vec.dot(vec.row(lights.edge2, e), d)
    z = vec.dot(vec.row(lights.normal, e), d)
    if has(lights, SPOT) and lights.kind[e] == SPOT:
        f = spot_falloff(lights, e, d)
        if not (f > 0.0 and z > 0.0):
            return zero
        c = lights.cone[e, 0]
        k = 0.5 * c / (z * math.sqrt(max(0.0, 1.0 - c * c)))   # 1 / (2 z tan γ)
        return vec.mul(light_texture(lights, e, (0.5 + x * k, 0.5 + y * k)), f)
    if not z > 0.0:
        return zero
    u = 0.5 - 0.5 * x / (z * lights.cone[e, 0])
    v = 0.5 - 0.5 * y / (z * lights.cone[e, 1])
    if not (0.0 <= u <= 1.0 and 0.0 <= v <= 1.0):
        return zero
    inv_cos3 = 1.0 / (z * z * z)
    if lights.tex_int[e, TEX_OF] == 0:
        return (inv_cos3, inv_cos3, inv_cos3)
    return vec.mul(light_texture(lights, e, (u, v)), inv_cos3)


@guarded_by(PROJECTOR, SPOT)
@kernel(inline=True)
def profiled(lights, e):
    """Whether light e's intensity varies by :func:`profile` (a projector, a textured spot)."""
    return (has(lights, PROJECTOR) and lights.kind[e] == PROJECTOR
            or has(lights, SPOT) and lights.kind[e] == SPOT and lights.tex_int[e, TEX_OF] == 1)


@kernel
def profile_power(lights, e, n_theta, n_phi):
    """∫ profile dω over spot e's cone (per channel; its power over its intensity) by the midpoint rule on an
    n_theta x n_phi grid of (θ, φ) within its cutoff angle."""
    gamma = lights.cone[e, 2]
    axis = vec.row(lights.normal, e)
    ex = vec.row(lights.edge1, e)
    ey = vec.row(lights.edge2, e)
    acc0 = 0.0
    acc1 = 0.0
    acc2 = 0.0
    d_theta = gamma / n_theta
    d_phi = 2.0 * math.pi / n_phi
    for i in range(n_theta):
        theta = (i + 0.5) * d_theta
        st = math.sin(theta)
        ct = math.cos(theta)
        for j in range(n_phi):
            phi = (j + 0.5) * d_phi
            d = vec.madd(vec.madd(vec.mul(axis, ct), ex, st * math.cos(phi)), ey, st * math.sin(phi))
            p = profile(lights, e, d)
            acc0 += p[0] * st
            acc1 += p[1] * st
            acc2 += p[2] * st
    w = d_theta * d_phi
    return (acc0 * w, acc1 * w, acc2 * w)


@kernel
def projector_uv_pdf(lights, e, u, v):
    """The density in (u, v) with which :func:`projector_sample_uv` gives (u, v) on projector e's image: 1 without
    a bitmap; a bitmap's texel probabilities x W H, interpolated as its filter interpolates texels (Mitsuba's
    ``pdf_position``)."""
    o = lights.tex_int[e, TEX_CDF]
    if o < 0:
        return 1.0
    w = lights.tex_int[e, 3]
    h = lights.tex_int[e, 4]
    mode = lights.tex_int[e, 2]
    dens = o + h + h * w
    if lights.tex_int[e, 1] == NEAREST:
        j = min(max(np.int64(math.floor(u * w)), 0), w - 1)
        i = min(max(np.int64(math.floor(v * h)), 0), h - 1)
        return lights.tex_cdf[dens + i * w + j]
    px = u * w - 0.5
    py = v * h - 0.5
    fx = math.floor(px)
    fy = math.floor(py)
    ax = px - fx
    ay = py - fy
    x0 = wrap(np.int64(fx), w, mode)
    x1 = wrap(np.int64(fx) + 1, w, mode)
    y0 = wrap(np.int64(fy), h, mode)
    y1 = wrap(np.int64(fy) + 1, h, mode)
    p = lights.tex_cdf
    top = (1.0 - ax) * p[dens + y0 * w + x0] + ax * p[dens + y0 * w + x1]
    bottom = (1.0 - ax) * p[dens + y1 * w + x0] + ax * p[dens + y1 * w + x1]
    return (1.0 - ay) * top + ay * bottom


@kernel
def projector_sample_uv(lights, e, u1, u2):
    """A point (u, v) on projector e's image and its density: uniform without a bitmap; with one, a texel by its
    luminance (row by u1, column by u2), then uniform in it (nearest) or a tent about its centre one texel wide
    each way, wrapped or reflected back into [0, 1] by its wrap mode (bilinear): Mitsuba 3's bitmap
    ``sample_position``, whose density :func:`projector_uv_pdf` is."""
    o = lights.tex_int[e, TEX_CDF]
    if o < 0:
        return u1, u2, 1.0
    w = lights.tex_int[e, 3]
    h = lights.tex_int[e, 4]
    cdf = lights.tex_cdf
    i = find_cdf(cdf, o, h, u1) - o
    lo = cdf[o + i - 1] if i > 0 else 0.0
    width = cdf[o + i] - lo
    u1 = min(max((u1 - lo) / width if width > 0.0 else 0.0, 0.0), 0.99999999)
    cols = o + h + i * w
    j = find_cdf(cdf, cols, w, u2) - cols
    lo = cdf[cols + j - 1] if j > 0 else 0.0
    width = cdf[cols + j] - lo
    u2 = min(max((u2 - lo) / width if width > 0.0 else 0.0, 0.0), 0.99999999)
    if lights.tex_int[e, 1] == NEAREST:
        u = (j + u2) / w
        v = (i + u1) / h
    else:
        u = wrap_unit((j + 0.5 + tent(u2)) / w, lights.tex_int[e, 2])
        v = wrap_unit((i + 0.5 + tent(u1)) / h, lights.tex_int[e, 2])
    return u, v, projector_uv_pdf(lights, e, u, v)


@kernel(inline=True)
def tent(u):
    """u in [0, 1) to [-1, 1] with the tent density 1 - |x| (Mitsuba's square_to_tent)."""
    if u < 0.5:
        return math.sqrt(2.0 * u) - 1.0
    return 1.0 - math.sqrt(2.0 - 2.0 * u)


@kernel(inline=True)
def wrap_unit(x, mode):
    """x within a texel of [0, 1] moved into it: periodically (repeat), else reflected at the edge."""
    if mode == REPEAT:
        if x < 0.0:
            return x + 1.0
        if x > 1.0:
            return x - 1.0
        return x
    if x < 0.0:
        return -x
    if x > 1.0:
        return 2.0 - x
    return x


@kernel(inline=True)
def parallelogram_point(lights, e, u1, u2):
    """corner + u1 edge1 + u2 edge2 on rectangle emitter e: (position, front normal)."""
    c = vec.row(lights.corner, e)
    p = vec.madd(vec.madd(c, vec.row(lights.edge1, e), u1), vec.row(lights.edge2, e), u2)
    return p, vec.row(lights.normal, e)


@kernel(inline=True)
def sample_emitter_primitives(lights, geom, e, u1, u2):
    """A point uniformly by area on emitter e via its primitives' area CDF: (position, front normal)."""
    prim, u1r = emitter_primitive(lights, e, u1)
    return sample_on_primitive(geom, prim, u1r, u2)


@kernel(inline=True)
def emitter_primitive(lights, e, u1):
    """The primitive of area emitter e that number u1 picks in proportion to area, and u1 rescaled to [0, 1) within
    its share of the CDF (the number that places the point on it): (primitive, u1r)."""
    first = lights.prim_first[e]
    count = lights.prim_count[e]
    j = find_cdf(lights.prim_cdf, first, count, u1)
    lo = lights.prim_cdf[j - 1] if j > first else 0.0
    width = lights.prim_cdf[j] - lo
    u1r = (u1 - lo) / width if width > 0.0 else 0.0
    return lights.prims[j], min(max(u1r, 0.0), 0.99999999)


@kernel(inline=True)
def sample_area_emitter(lights, geom, e, u1, u2):
    """A point uniformly by area on area emitter e: (position, front normal); pdf = 1 / area[e].

    Rectangles take the fast path through their (u, v) parametrisation; the general
    path is a separate call so that the common case never touches ``geom``
    (binding Geometry's many arrays costs reference-count updates per call).
    """
    if lights.is_parallelogram[e] == 1:
        return parallelogram_point(lights, e, u1, u2)
    return sample_emitter_primitives(lights, geom, e, u1, u2)


@kernel(inline=True)
def area_radiance(lights, e, uv):
    """Area emitter e's radiance at surface coordinates uv (its radiance row, times its texture there if it has
    one; uv is read only then)."""
    if has(lights, TEXTURED_AREA) and lights.tex_int[e, TEX_OF] != 0:
        return vec.hadamard(vec.row(lights.radiance, e),
                            texture_rgb((lights.tex_int, lights.tex_float, lights.texels), e, uv))
    return vec.row(lights.radiance, e)


@kernel(inline=True)
def radiance_at_hit(geom, lights, e, prim, ray):
    """The radiance area emitter e sends back along the ray that meets its primitive prim at ``ray`` = (o, d, t,
    b1, b2) (on its front side: the caller checks); the surface coordinates are looked up only for a textured
    emitter."""
    if has(lights, TEXTURED_AREA) and lights.tex_int[e, TEX_OF] != 0:
        o, d, t, b1, b2 = ray
        return area_radiance(lights, e, surface_uv(geom, prim, o, d, t, b1, b2))
    return vec.row(lights.radiance, e)


@kernel
def textured_emitter_point(lights, geom, e, u1, u2):
    """:func:`sample_emitter_primitives`' point on textured area emitter e with the radiance leaving it there:
    (position, front normal, radiance)."""
    prim, u1r = emitter_primitive(lights, e, u1)
    p, n = sample_on_primitive(geom, prim, u1r, u2)
    s = math.sqrt(u1r)   # the barycentrics primitives.sample_triangle gives the point
    uv = hit_uv((geom.prim_kind, geom.prim_index, geom.tri_uv, geom.ana_to_local), prim, (p, (0.0, 0.0, 0.0), 0.0),
                (1.0 - s, u2 * s))
    return p, n, area_radiance(lights, e, uv)


@kernel(inline=True)
def emitter_point(lights, geom, e, u1, u2):
    """:func:`sample_area_emitter`'s point on area emitter e with the radiance leaving it: (position, front normal,
    radiance); pdf = 1 / area[e]."""
    if has(lights, TEXTURED_AREA) and lights.tex_int[e, TEX_OF] != 0:
        return textured_emitter_point(lights, geom, e, u1, u2)
    p, n = sample_area_emitter(lights, geom, e, u1, u2)
    return p, n, vec.row(lights.radiance, e)


@kernel
def texture_area_mean(lights, geom, e, n):
    """The mean radiance over textured area emitter e (per channel): the points of an n x n grid of cell centres
    mapped by :func:`textured_emitter_point` (uniform by area), averaged; its power is π area x this."""
    acc = (0.0, 0.0, 0.0)
    for i in range(n):
        for j in range(n):
            _, _, L = textured_emitter_point(lights, geom, e, (i + 0.5) / n, (j + 0.5) / n)
            acc = vec.add(acc, L)
    return vec.mul(acc, 1.0 / (n * n))


@kernel
def total_power(lights):
    """Sum of all lights' power per channel (W)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for i in range(lights.kind.shape[0]):
        s0 += lights.power[i, 0]
        s1 += lights.power[i, 1]
        s2 += lights.power[i, 2]
    return (s0, s1, s2)


# ----------------------------------------------------------------------------- the environment

@kernel
def env_lookup(lights, u, v):
    """A map's radiance at (u, v) as Mitsuba 3 looks it up: bilinear, texel centres at u = (j + 1/2) / W
    (periodic in u), rows at v = i / (H - 1) (pole to pole)."""
    img = lights.env_image
    h = img.shape[0]
    w = img.shape[1]
    u = u - math.floor(u)
    v = min(max(v, 0.0), 1.0)
    x = u * w - 0.5
    x0f = math.floor(x)
    fx = x - x0f
    x0 = int(x0f) % w
    x1 = (x0 + 1) % w
    y = v * (h - 1)
    y0 = min(int(y), h - 2)
    fy = y - y0
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for c in range(3):
        top = (1.0 - fx) * img[y0, x0, c] + fx * img[y0, x1, c]
        bottom = (1.0 - fx) * img[y0 + 1, x0, c] + fx * img[y0 + 1, x1, c]
        val = (1.0 - fy) * top + fy * bottom
        if c == 0:
            out0 = val
        elif c == 1:
            out1 = val
        else:
            out2 = val
    return (out0, out1, out2)


@kernel
def env_uv(lights, d):
    """Mitsuba 3's (u, v) of world direction d on the map, and sin θ: u = atan2(x, -z) / 2π, v = acos(y) / π in
    the map's frame (y up)."""
    m = lights.env_data   # the rotation m[ENV_TO_WORLD + 3 i + j]; its inverse is its transpose
    x = m[ENV_TO_WORLD] * d[0] + m[ENV_TO_WORLD + 3] * d[1] + m[ENV_TO_WORLD + 6] * d[2]
    y = m[ENV_TO_WORLD + 1] * d[0] + m[ENV_TO_WORLD + 4] * d[1] + m[ENV_TO_WORLD + 7] * d[2]
    z = m[ENV_TO_WORLD + 2] * d[0] + m[ENV_TO_WORLD + 5] * d[1] + m[ENV_TO_WORLD + 8] * d[2]
    u = math.atan2(x, -z) / (2.0 * math.pi)
    return u - math.floor(u), math.acos(min(max(y, -1.0), 1.0)) / math.pi, math.sqrt(x * x + z * z)


@kernel
def env_radiance(lights, d):
    """The environment's radiance arriving from world direction d (unit, pointing away from the scene)."""
    if lights.env[1] == 1:
        return vec.row(lights.radiance, lights.env[0])
    u, v, _ = env_uv(lights, d)
    return env_lookup(lights, u, v)


@kernel
def env_pdf(lights, d):
    """The solid-angle density with which :func:`env_sample` gives direction d (light choice excluded)."""
    if lights.env[1] == 1:
        return INV_4PI
    u, v, sin_t = env_uv(lights, d)
    h = lights.env_image.shape[0]
    w = lights.env_image.shape[1]
    up = u - 0.5 / w
    up -= math.floor(up)
    j = min(int(up * w), w - 1)
    i = min(int(v * (h - 1)), h - 2)
    if not sin_t > 0.0:
        return 0.0
    return lights.env_data[ENV_CDF + h - 1 + (h - 1) * w + i * w + j] / (2.0 * math.pi * math.pi * sin_t)


@kernel
def env_sample(lights, u1, u2):
    """A direction towards the environment: (world unit direction, its solid-angle density, radiance).

    A map: a patch by its CDFs (u1 the row, u2 the column), uniform in (u, v) within it; density
    p(u, v) / (2 π² sin θ).  A constant environment: uniform over the sphere.  Density 0: no sample.
    """
    if lights.env[1] == 1:
        return square_to_uniform_sphere(u1, u2), INV_4PI, vec.row(lights.radiance, lights.env[0])
    h = lights.env_image.shape[0]
    w = lights.env_image.shape[1]
    cdf = lights.env_data
    i = find_cdf(cdf, ENV_CDF, h - 1, u1) - ENV_CDF
    lo = cdf[ENV_CDF + i - 1] if i > 0 else 0.0
    width = cdf[ENV_CDF + i] - lo
    u1 = min(max((u1 - lo) / width if width > 0.0 else 0.0, 0.0), 0.99999999)
    cols = ENV_CDF + h - 1      # row i's column CDF at cols + i w .. cols + i w + w - 1
    k = find_cdf(cdf, cols + i * w, w, u2) - cols
    lo = cdf[cols + k - 1] if k > i * w else 0.0
    width = cdf[cols + k] - lo
    u2 = min(max((u2 - lo) / width if width > 0.0 else 0.0, 0.0), 0.99999999)
    v = (i + u1) / (h - 1)
    u = (k - i * w + u2 + 0.5) / w
    theta = v * math.pi
    phi = 2.0 * math.pi * u
    sin_t = math.sin(theta)
    zero = (0.0, 0.0, 0.0)
    if not sin_t > 0.0:
        return zero, 0.0, zero
    local = (math.sin(phi) * sin_t, math.cos(theta), -math.cos(phi) * sin_t)
    m = lights.env_data
    r = ENV_TO_WORLD
    d = (m[r] * local[0] + m[r + 1] * local[1] + m[r + 2] * local[2],
         m[r + 3] * local[0] + m[r + 4] * local[1] + m[r + 5] * local[2],
         m[r + 6] * local[0] + m[r + 7] * local[1] + m[r + 8] * local[2])
    return d, m[ENV_CDF + h - 1 + (h - 1) * w + k] / (2.0 * math.pi * math.pi * sin_t), env_lookup(lights, u, v)
