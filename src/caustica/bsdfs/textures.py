"""Textures in the material table: a material's colour looked up at the surface point's (u, v).

The table's texture columns (:func:`texture_columns`) hold every texture of the scene once: its kind, filter
and wrap mode, size and first texel, ``to_uv`` and a checkerboard's two colours; the bitmaps' texels are one
flat float32 array of RGB rows.  ``MaterialTable.texture[m]`` is the texture that gives material m's colour
(-1: none, the colour is ``rgb[m]``).  :func:`colour` is what every BSDF and loop reads; :func:`texture_rgb`, the
lookup, is one called kernel, compiled once.

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
from ..jit import kernel
from ..scene.description import CHECKERBOARD

NEAREST, BILINEAR = 0, 1
REPEAT, MIRROR, CLAMP = 0, 1, 2


def texture_columns(materials) -> tuple:
    """The material table's texture columns for a list of Materials: (texture, tex_kind, tex_mode, tex_size,
    tex_to_uv, tex_colours, texels); a texture shared by several materials is stored once."""
    index, textures = {}, []
    texture = np.full(max(1, len(materials)), -1, np.int32)
    for i, mat in enumerate(materials):
        tex = getattr(mat, "texture", None)
        if tex is None:
            continue
        if id(tex) not in index:
            index[id(tex)] = len(textures)
            textures.append(tex)
        texture[i] = index[id(tex)]
    x = max(1, len(textures))
    kind = np.zeros(x, np.int32)
    mode = np.zeros((x, 2), np.int32)
    size = np.zeros((x, 3), np.int64)      # width, height, first texel row in texels
    to_uv = np.zeros((x, 2, 3))
    colours = np.zeros((x, 2, 3))
    chunks, rows = [], 0
    for t, tex in enumerate(textures):
        kind[t] = tex.kind
        mode[t] = tex.filter, tex.wrap
        to_uv[t] = tex.to_uv
        colours[t] = tex.color0, tex.color1
        if tex.texels is not None:
            h, w = tex.texels.shape[:2]
            size[t] = w, h, rows
            chunks.append(tex.texels.reshape(-1, 3))
            rows += w * h
    texels = np.ascontiguousarray(np.concatenate(chunks) if chunks else np.zeros((1, 3)), dtype=np.float32)
    return texture, kind, mode, size, to_uv, colours, texels


@kernel(inline=True)
def wrap(i, n, mode):
    """Texel index i of a row or column of n texels, wrapped by ``mode`` into [0, n)."""
    if mode == CLAMP:
        return min(max(i, 0), n - 1)
    if mode == MIRROR:
        j = i % (2 * n)
        return 2 * n - 1 - j if j >= n else j
    return i % n


@kernel(inline=True)
def texel(mats, row0, w, h, mode, x, y):
    """The texel at column x, row y (wrapped) as a float64 RGB tuple."""
    r = row0 + wrap(y, h, mode) * w + wrap(x, w, mode)
    return float(mats.texels[r, 0]), float(mats.texels[r, 1]), float(mats.texels[r, 2])


@kernel
def texture_rgb(mats, t, uv):
    """Texture t's RGB at surface coordinates uv (see the module's docstring); black where uv is not finite."""
    a = mats.tex_to_uv
    u = a[t, 0, 0] * uv[0] + a[t, 0, 1] * uv[1] + a[t, 0, 2]
    v = a[t, 1, 0] * uv[0] + a[t, 1, 1] * uv[1] + a[t, 1, 2]
    if not (abs(u) < 1e15 and abs(v) < 1e15):
        return 0.0, 0.0, 0.0
    if mats.tex_kind[t] == CHECKERBOARD:
        k = 0 if (u - math.floor(u) > 0.5) == (v - math.floor(v) > 0.5) else 1
        return mats.tex_colours[t, k, 0], mats.tex_colours[t, k, 1], mats.tex_colours[t, k, 2]
    w = mats.tex_size[t, 0]
    h = mats.tex_size[t, 1]
    row0 = mats.tex_size[t, 2]
    mode = mats.tex_mode[t, 1]
    if mats.tex_mode[t, 0] == NEAREST:
        return texel(mats, row0, w, h, mode, np.int64(math.floor(u * w)), np.int64(math.floor(v * h)))
    px = u * w - 0.5
    py = v * h - 0.5
    fx = math.floor(px)
    fy = math.floor(py)
    x0 = np.int64(fx)
    y0 = np.int64(fy)
    ax = px - fx
    ay = py - fy
    c00 = texel(mats, row0, w, h, mode, x0, y0)
    c10 = texel(mats, row0, w, h, mode, x0 + 1, y0)
    c01 = texel(mats, row0, w, h, mode, x0, y0 + 1)
    c11 = texel(mats, row0, w, h, mode, x0 + 1, y0 + 1)
    top = vec.add(vec.mul(c00, 1.0 - ax), vec.mul(c10, ax))
    bottom = vec.add(vec.mul(c01, 1.0 - ax), vec.mul(c11, ax))
    return vec.add(vec.mul(top, 1.0 - ay), vec.mul(bottom, ay))


@kernel(inline=True)
def colour(mats, m, uv):
    """Material m's colour (its ``rgb``: reflectance, specular reflectance, glass scale) at surface coordinates uv:
    ``rgb[m]`` itself when untextured."""
    t = mats.texture[m]
    if t < 0:
        return vec.row(mats.rgb, m)
    return texture_rgb(mats, t, uv)


@kernel(inline=True)
def albedo_mean(mats, m, rgb):
    """The mean of material m's colour ``rgb`` (from :func:`colour`): photons' survival probability at a bounce."""
    if mats.texture[m] < 0:
        return mats.albedo_mean[m]
    return (rgb[0] + rgb[1] + rgb[2]) / 3.0
