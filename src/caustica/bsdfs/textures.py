"""Textures in the material table: a material's colour looked up at the surface point's (u, v).

The table's texture columns (:func:`texture_columns`) hold every texture of the scene once: ``tex_int`` its
kind, filter and wrap mode, a bitmap's width, height and first texel row; ``tex_float`` its ``to_uv`` and a
checkerboard's two colours; the bitmaps' texels are one flat float32 array of RGB rows, ``texels``.
``MaterialTable.texture[m]`` is the texture that gives material m's colour (-1: none, the colour is ``rgb[m]``), and
``MaterialTable.mix_texture[m]`` the one that gives a mixture's opacity or weight (its luminance, :mod:`.mixtures`).
A ``mesh_attribute`` texture reads no (u, v): its values are per triangle corner in ``MaterialTable.attr`` (one slot
per attribute name, :func:`attribute_table`), weighted by the hit's barycentrics, which the surface coordinates
carry with the triangle: uv = (u, v, triangle, b1, b2).
:func:`colour` is what every BSDF and loop reads; :func:`texture_rgb`, the lookup, is one called kernel, compiled
once.

The lookups follow Mitsuba 3 (src/textures/checkerboard.cpp, bitmap.cpp and Dr.Jit's texture): (u, v) goes
through ``to_uv`` first.  A checkerboard is ``color0`` where the fractional parts of u and v are both above 1/2
or both not, else ``color1``.  A bitmap of w x h texels has texel (i, j) (column, row; row 0 the image's top)
centred at ((i + 1/2) / w, (j + 1/2) / h): ``nearest`` takes the texel holding (u w, v h), ``bilinear``
interpolates the four texels around (u w - 1/2, v h - 1/2).  Texel indices beyond the image wrap (``repeat``:
modulo the size), reflect (``mirror``: -1 -> 0, w -> w - 1, period 2w) or ``clamp`` to the edge.
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import vec
from ..features import guarded_by, has
from ..jit import kernel
from ..scene.description import CHECKERBOARD, MESH, MESH_ATTRIBUTE
from .flags import TEXTURED

NEAREST, BILINEAR = 0, 1
REPEAT, MIRROR, CLAMP = 0, 1, 2


#: Columns of ``MaterialTable.param_texture``: a rough BSDF's alpha_u and alpha_v, then PARAM_COLUMNS columns for the
#: scalar parameters of ``MaterialTable.coating`` (column k's texture at PARAM + k; a principled's).
ALPHA_U, ALPHA_V, PARAM = 0, 1, 2
PARAM_COLUMNS = 17
#: The parameter column of a principled's (and principledthin's) anisotropic (bsdfs/principled.py).
ANISO = 12

#: Columns of ``tex_int`` and ``tex_float``.
KIND, FILTER, WRAP, WIDTH, HEIGHT, ROW0 = range(6)
TO_UV, COLOR0, COLOR1 = 0, 6, 9


def texture_columns(materials, params=None) -> tuple:
    """The material table's texture columns for a list of Materials: (texture, tex_int, tex_float, texels,
    mix_texture, param_texture); a texture shared by several materials (or giving a colour and a mixture's weight, or
    both roughnesses) is stored once.  ``params[i]``, if given, maps columns k of material i's scalar parameters
    (``MaterialTable.coating``: a principled's) to the textures giving them (``param_texture[i, PARAM + k]``)."""
    index, textures = {}, []
    texture = np.full(max(1, len(materials)), -1, np.int32)
    mix_texture = np.full(max(1, len(materials)), -1, np.int32)
    param_texture = np.full((max(1, len(materials)), PARAM + PARAM_COLUMNS), -1, np.int32)
    for i, mat in enumerate(materials):
        alphas = getattr(mat, "alpha_textures", (None, None))
        scalars = [(param_texture[i, PARAM + k:PARAM + k + 1], tex) for k, tex in (params[i] if params else {}).items()]
        for column, tex in [(texture[i:i + 1], getattr(mat, "texture", None)),
                            (mix_texture[i:i + 1], getattr(mat, "mix_texture", None)),
                            (param_texture[i, ALPHA_U:ALPHA_U + 1], alphas[0]),
                            (param_texture[i, ALPHA_V:ALPHA_V + 1], alphas[1])] + scalars:
            if tex is None:
                continue
            if id(tex) not in index:
                index[id(tex)] = len(textures)
                textures.append(tex)
            column[0] = index[id(tex)]
    x = max(1, len(textures))
    ints = np.zeros((x, 6), np.int64)
    floats = np.zeros((x, 12))
    chunks, rows = [], 0
    slots = attribute_slots(textures)
    for t, tex in enumerate(textures):
        ints[t, KIND], ints[t, FILTER], ints[t, WRAP] = tex.kind, tex.filter, tex.wrap
        floats[t, TO_UV:TO_UV + 6] = np.asarray(tex.to_uv, dtype=np.float64).reshape(6)
        floats[t, COLOR0:COLOR0 + 3] = tex.color0
        floats[t, COLOR1:COLOR1 + 3] = tex.color1
        if tex.kind == MESH_ATTRIBUTE:   # its slot in MaterialTable.attr and its scale
            ints[t, ROW0] = slots[tex.attribute]
            floats[t, COLOR0] = tex.scale
        if tex.texels is not None:
            h, w = tex.texels.shape[:2]
            ints[t, WIDTH], ints[t, HEIGHT], ints[t, ROW0] = w, h, rows
            chunks.append(tex.texels.reshape(-1, 3))
            rows += w * h
    texels = np.ascontiguousarray(np.concatenate(chunks) if chunks else np.zeros((1, 3)), dtype=np.float32)
    return texture, ints, floats, texels, mix_texture, param_texture


def attribute_slots(textures) -> dict:
    """The mesh attributes the textures name, each with its slot in ``MaterialTable.attr`` (in order of first use)."""
    slots = {}
    for tex in textures:
        if tex is not None and tex.kind == MESH_ATTRIBUTE and tex.attribute not in slots:
            slots[tex.attribute] = len(slots)
    return slots


def attribute_table(desc) -> np.ndarray:
    """``MaterialTable.attr``: float32 (K, T, 9), for each of the K attributes mesh_attribute textures name and each
    triangle of the scene (primitive order: the meshes' triangles shape by shape), the attribute's RGB at the
    triangle's three corners (a face attribute the same at all three, a 1-channel one grey); zero where a mesh has
    no such attribute (the loader refuses a mesh_attribute on it).  (1, 1, 9) zeros without any."""
    textures = [getattr(m, k, None) for m in desc.materials for k in ("texture", "mix_texture")]
    slots = attribute_slots(textures)
    if not slots:   # (before the shapes are read: a table of materials alone has none)
        return np.zeros((1, 1, 9), np.float32)
    meshes = [s.mesh for s in desc.shapes if s.kind == MESH and s.mesh is not None]
    n = sum(len(m.triangles) for m in meshes)
    if n == 0:
        return np.zeros((1, 1, 9), np.float32)
    out = np.zeros((len(slots), n, 9), np.float32)
    row = 0
    for mesh in meshes:
        tri = np.asarray(mesh.triangles, dtype=np.int64)
        for name, k in slots.items():
            a = (mesh.attributes or {}).get(name)
            if a is None or a.shape[1] not in (1, 3):
                continue
            a = np.repeat(a, 3, axis=1) if a.shape[1] == 1 else a
            corners = a[tri] if name.startswith("vertex_") else np.repeat(a[:, None, :], 3, axis=1)
            out[k, row:row + len(tri)] = corners.reshape(len(tri), 9)
        row += len(tri)
    return out


#: Rec. 709 luminance weights of linear RGB (Mitsuba's ``luminance``).
LUMINANCE = (0.212671, 0.715160, 0.072169)


def mitsuba_mean(tex) -> float:
    """The one number Mitsuba 3's RGB variants give as a texture's ``mean()`` (what a plastic's specular sampling
    weight reads): a checkerboard's is the mean of its two colours' channel means, a bitmap's the mean luminance
    of its (linear) texels."""
    if tex.kind == CHECKERBOARD:
        return 0.5 * (sum(tex.color0) + sum(tex.color1)) / 3.0
    t = np.asarray(tex.texels, dtype=np.float64).reshape(-1, 3)
    return float(np.mean(t @ np.array(LUMINANCE)))


@kernel(inline=True)
def wrap(i, n, mode):
    """Texel index i of a row or column of n texels, wrapped by ``mode`` into [0, n)."""
    if mode == CLAMP:
        return min(max(i, 0), n - 1)
    if mode == MIRROR:
        j = i % (2 * n)
        return 2 * n - 1 - j if j >= n else j
    return i % n


@kernel
def texel(texels, row0, w, h, mode, x, y):
    """The texel at column x, row y (wrapped) as a float64 RGB tuple (called, not inlined: a bilinear lookup reads
    four; inlined, they cost texture_rgb ~3 s of compile time)."""
    r = row0 + wrap(y, h, mode) * w + wrap(x, w, mode)
    return float(texels[r, 0]), float(texels[r, 1]), float(texels[r, 2])


@kernel
def texture_rgb(table, t, uv):
    """Texture t's RGB at surface coordinates uv (see the module's docstring); black where uv is not finite.
    ``table`` = (tex_int, tex_float, texels) of the material table: these three arrays, not the whole table, so
    that each call site passes little."""
    ints, a, texels = table
    u = a[t, TO_UV] * uv[0] + a[t, TO_UV + 1] * uv[1] + a[t, TO_UV + 2]
    v = a[t, TO_UV + 3] * uv[0] + a[t, TO_UV + 4] * uv[1] + a[t, TO_UV + 5]
    if not (abs(u) < 1e15 and abs(v) < 1e15):
        return 0.0, 0.0, 0.0
    if ints[t, KIND] == CHECKERBOARD:
        c = COLOR0 if (u - math.floor(u) > 0.5) == (v - math.floor(v) > 0.5) else COLOR1
        return a[t, c], a[t, c + 1], a[t, c + 2]
    w = ints[t, WIDTH]
    h = ints[t, HEIGHT]
    row0 = ints[t, ROW0]
    mode = ints[t, WRAP]
    if ints[t, FILTER] == NEAREST:
        return texel(texels, row0, w, h, mode, np.int64(math.floor(u * w)), np.int64(math.floor(v * h)))
    px = u * w - 0.5
    py = v * h - 0.5
    fx = math.floor(px)
    fy = math.floor(py)
    x0 = np.int64(fx)
    y0 = np.int64(fy)
    ax = px - fx
    ay = py - fy
    c00 = texel(texels, row0, w, h, mode, x0, y0)
    c10 = texel(texels, row0, w, h, mode, x0 + 1, y0)
    c01 = texel(texels, row0, w, h, mode, x0, y0 + 1)
    c11 = texel(texels, row0, w, h, mode, x0 + 1, y0 + 1)
    top = vec.add(vec.mul(c00, 1.0 - ax), vec.mul(c10, ax))
    bottom = vec.add(vec.mul(c01, 1.0 - ax), vec.mul(c11, ax))
    return vec.add(vec.mul(top, 1.0 - ay), vec.mul(bottom, ay))


@kernel
def attribute_rgb(attr, slot, scale, hit):
    """A mesh attribute (slot ``slot`` of ``MaterialTable.attr``) times ``scale`` at ``hit`` = (u, v, triangle, b1,
    b2) (:func:`caustica.geometry.scene_geometry.surface_uv`): the corners' values weighted by the barycentrics
    (Mitsuba's mesh_attribute eval); black off a triangle."""
    j = np.int64(hit[2])
    if j < 0:
        return 0.0, 0.0, 0.0
    b1 = hit[3]
    b2 = hit[4]
    b0 = 1.0 - b1 - b2
    r = (b0 * attr[slot, j, 0] + b1 * attr[slot, j, 3] + b2 * attr[slot, j, 6]) * scale
    g = (b0 * attr[slot, j, 1] + b1 * attr[slot, j, 4] + b2 * attr[slot, j, 7]) * scale
    b = (b0 * attr[slot, j, 2] + b1 * attr[slot, j, 5] + b2 * attr[slot, j, 8]) * scale
    return r, g, b


@kernel(inline=True)
def colour(mats, m, uv):
    """Material m's colour (its ``rgb``: reflectance, specular reflectance, glass scale) at the hit's surface
    coordinates uv = (u, v, triangle, b1, b2): ``rgb[m]`` itself when untextured."""
    t = mats.texture[m] if has(mats, TEXTURED) else -1
    if t < 0:
        return vec.row(mats.rgb, m)
    if mats.tex_int[t, KIND] == MESH_ATTRIBUTE:
        return attribute_rgb(mats.attr, mats.tex_int[t, ROW0], mats.tex_float[t, COLOR0], uv)
    return texture_rgb((mats.tex_int, mats.tex_float, mats.texels), t, (uv[0], uv[1]))


@kernel(inline=True)
def albedo_mean(mats, m, rgb):
    """The mean of material m's colour ``rgb`` (from :func:`colour`).  No kernel reads it since photon roulette takes the
    bounce's sampled weight (:func:`caustica.photons.trace.survive`)."""
    if not has(mats, TEXTURED) or mats.texture[m] < 0:
        return mats.albedo_mean[m]
    return (rgb[0] + rgb[1] + rgb[2]) / 3.0


@kernel
def texture_value(mats, t, uv):
    """Texture t's value where a BSDF reads a number (Mitsuba's ``eval_1``) at surface coordinates uv: a
    ``mesh_attribute``'s first channel; a checkerboard's colour mean, with color0 and color1 the other way round from
    its colour lookup (Mitsuba's checkerboard.cpp compares with != in eval_1 where eval has ==); a bitmap's luminance."""
    if mats.tex_int[t, KIND] == MESH_ATTRIBUTE:   # a 1-channel attribute (the loader checks)
        return attribute_rgb(mats.attr, mats.tex_int[t, ROW0], mats.tex_float[t, COLOR0], uv)[0]
    if mats.tex_int[t, KIND] == CHECKERBOARD:
        a = mats.tex_float
        u = a[t, TO_UV] * uv[0] + a[t, TO_UV + 1] * uv[1] + a[t, TO_UV + 2]
        v = a[t, TO_UV + 3] * uv[0] + a[t, TO_UV + 4] * uv[1] + a[t, TO_UV + 5]
        if not (abs(u) < 1e15 and abs(v) < 1e15):
            return 0.0
        k = COLOR1 if (u - math.floor(u) > 0.5) == (v - math.floor(v) > 0.5) else COLOR0
        return (a[t, k] + a[t, k + 1] + a[t, k + 2]) / 3.0   # a colour's eval_1: the mean (Mitsuba's srgb mean())
    c = texture_rgb((mats.tex_int, mats.tex_float, mats.texels), t, (uv[0], uv[1]))
    return LUMINANCE[0] * c[0] + LUMINANCE[1] * c[1] + LUMINANCE[2] * c[2]


@guarded_by(TEXTURED)
@kernel(inline=True)
def needs_uv(mats, m):
    """Whether a texture gives material m's colour, roughness or another scalar parameter: its hits need their
    surface coordinates (never in a table without the TEXTURED feature: no code in its kernels)."""
    if not has(mats, TEXTURED):
        return False
    if mats.texture[m] >= 0:
        return True
    for k in range(mats.param_texture.shape[1]):
        if mats.param_texture[m, k] >= 0:
            return True
    return False


@kernel(inline=True)
def needs_tangent(mats, m):
    """Whether material m's roughness may differ along and across dp/du (its shading frame needs the tangent): a
    principled's anisotropic given by a texture (column ``aniso`` of its parameters) too."""
    return mats.alpha_v[m] != mats.alpha[m] or mats.param_texture[m, ALPHA_U] != mats.param_texture[m, ALPHA_V] or \
        mats.param_texture[m, PARAM + ANISO] >= 0


@kernel
def param(mats, m, k, uv):
    """Material m's scalar parameter k (column k of ``MaterialTable.coating``) at surface coordinates uv: its
    texture's value there (:func:`texture_value`) where one gives it, else the column."""
    if has(mats, TEXTURED):
        t = mats.param_texture[m, PARAM + k]
        if t >= 0:
            return texture_value(mats, t, uv)
    return mats.coating[m, k]
