"""The mixtures, Mitsuba 3's ``mask`` and ``blendbsdf``: resolved where a ray meets them, with one random number.

A mask is f = o · f_nested plus, with probability 1 - o, no surface at all (the ray goes straight on, as across
Mitsuba's ``null``); a blend is f = (1 - w) f0 + w f1 (src/bsdfs/mask.cpp, blendbsdf.cpp).  Both are linear in
their parts, so choosing one part with the mixture's probability (the nested BSDF with probability o, else no
surface; f1 with probability w, else f0) and going on as if the surface were that part alone is unbiased for every
estimator that is unbiased for the parts: the path tracer's next-event estimate and MIS, photon paths, visible
points, whatever a loop does at a surface.  :func:`resolve` does it in
:func:`caustica.transport.surface_interaction`, so no loop ever scatters at a mixture: the material it is given is
the part chosen (or the surface is crossed as a null one).  A mixture takes its one number only where a ray meets
it, so a scene without one keeps its numbers, and its bits.

The opacity or weight is ``mix[m]``, or texture ``mix_texture[m]`` at the hit's (u, v) as one number, clipped to
[0, 1] (Mitsuba's ``eval_1``, then ``clip``): a bitmap's luminance; a checkerboard's colour's channel mean, with its two
colours the other way round from its ``eval`` (src/textures/checkerboard.cpp), as :func:`weight` follows. Shadow
rays take a mixture's chance of passing, the expected value (:func:`pass_probability`: 1 - o for a mask, as
Mitsuba's ``eval_null_transmission``), so they need no number. Mixtures do not nest (the loader refuses a mixture
inside a mixture).
"""
from __future__ import annotations


import numpy as np

from ..features import has
from ..jit import kernel
from ..sampling.rng import uniform
from ..scene.description import BLEND, MASK, MIXTURES, NULL, WRAPPERS
from .flags import TEXTURED
from .textures import texture_value


def mixture_columns(materials) -> tuple:
    """The material table's mixture columns for a list of Materials: (mix, nested): a mask's opacity or a blend's
    weight, and the nested materials' indices (-1: none)."""
    m = max(1, len(materials))
    mix = np.zeros(m)
    nested = np.full((m, 2), -1, np.int32)
    for i, mat in enumerate(materials):
        if mat.kind in MIXTURES + WRAPPERS:   # a wrapper's nested BSDF, and a bump map's scale
            mix[i] = mat.mix
            nested[i, :len(mat.nested)] = mat.nested
    return mix, nested


@kernel(inline=True)
def weight(mats, m, uv):
    """Mixture m's opacity (mask) or weight of its second part (blend) at surface coordinates uv, in [0, 1]."""
    t = mats.mix_texture[m] if has(mats, TEXTURED) else -1
    if t < 0:
        return mats.mix[m]
    return min(max(texture_value(mats, t, uv), 0.0), 1.0)


@kernel(inline=True)
def resolve(mats, m, uv, key, dim):
    """The part of mixture m a ray meeting it at uv takes, with number (key, dim): (material, dim + 1); material
    -1 for no surface (a mask where it is off).  Any other material is returned as it is, no number used."""
    kind = mats.kind[m]
    if not (has(mats, MASK) and kind == MASK or has(mats, BLEND) and kind == BLEND):
        return m, dim
    w = weight(mats, m, uv)
    u = uniform(key, dim)
    if kind == MASK:
        return (mats.nested[m, 0] if u < w else -1), dim + 1
    return (mats.nested[m, 1] if u < w else mats.nested[m, 0]), dim + 1


@kernel(inline=True)
def pass_probability(mats, m, uv):
    """The probability that a ray crosses material m's surface unchanged: 1 for the null BSDF, 1 - o for a mask
    (o its opacity; 1 where its nested BSDF is null), (1 - w) P0 + w P1 for a blend, 0 for any other BSDF."""
    kind = mats.kind[m]
    if kind == NULL:
        return 1.0
    if has(mats, MASK) and kind == MASK:
        o = weight(mats, m, uv)
        return 1.0 if mats.kind[mats.nested[m, 0]] == NULL else 1.0 - o
    if has(mats, BLEND) and kind == BLEND:
        w = weight(mats, m, uv)
        p0 = 1.0 if mats.kind[mats.nested[m, 0]] == NULL else 0.0
        p1 = 1.0 if mats.kind[mats.nested[m, 1]] == NULL else 0.0
        return (1.0 - w) * p0 + w * p1
    return 0.0
