"""``roughconductor``: Mitsuba 3's rough metal, a microfacet BRDF (:mod:`.microfacet`) with the conductor's Fresnel
reflectance, f = specular_reflectance · F(wo·h) D(h) G(wo, wi, h) / (4 cos θ_o cos θ_i), h the half vector.

``wo`` = -d is the direction the path came from (Mitsuba's ``wi``).  F is the Fresnel reflectance of the RGB complex
IOR ``conductor_eta`` + i ``conductor_k`` at the microfacet, or 1 for ``material="none"``.  Sampling draws a visible
normal from wo and reflects about it, so the weight f cos θ_i / pdf is specular_reflectance · F · G1(wi, h).
Directions below the shading or the geometric surface are refused (zero f).  With anisotropic roughness (Mitsuba's
``alpha_u`` along dp/du, ``alpha_v`` across it) the distribution's ``*_uv`` forms in Mitsuba's shading frame
(:func:`.microfacet.shading_frame`).
"""
from __future__ import annotations

from ..geometry import vec
from ..features import has
from ..jit import kernel
from ..scene.description import ROUGHCONDUCTOR
from . import microfacet as mf
from .flags import ANISOTROPIC, GLOSSY_REFLECTION, TEXTURED
from .optics import fresnel_conductor
from .textures import ALPHA_U, ALPHA_V, colour, texture_value

KIND = ROUGHCONDUCTOR
FLAGS = GLOSSY_REFLECTION


@kernel(inline=True)
def fresnel_rgb(mats, m, cos_i):
    """The conductor's Fresnel reflectance per channel at incident cosine cos_i: (1, 1, 1) for material "none"."""
    if mats.fresnel[m] == 0:
        return (1.0, 1.0, 1.0)
    return (fresnel_conductor(cos_i, mats.cond_eta[m, 0], mats.cond_k[m, 0]),
            fresnel_conductor(cos_i, mats.cond_eta[m, 1], mats.cond_k[m, 1]),
            fresnel_conductor(cos_i, mats.cond_eta[m, 2], mats.cond_k[m, 2]))


@kernel(inline=True)
def roughness(mats, m, uv):
    """(distribution, alpha_u, alpha_v) of material m at surface coordinates uv (alpha_v = alpha_u unless the scene
    has anisotropic rows): its textures' values there (at least ALPHA_MIN, as Mitsuba clamps), or its constants."""
    au = mats.alpha[m]
    av = mats.alpha_v[m] if has(mats, ANISOTROPIC) else au
    if has(mats, TEXTURED):
        tu, tv = mats.param_texture[m, ALPHA_U], mats.param_texture[m, ALPHA_V]
        if tu >= 0:
            au = max(texture_value(mats, tu, uv), mf.ALPHA_MIN)
        if tv == tu and tu >= 0:   # one texture gives both ("alpha")
            av = au
        elif tv >= 0:
            av = max(texture_value(mats, tv, uv), mf.ALPHA_MIN)
    return mats.distribution[m], au, av


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """A visible microfacet normal from -d (numbers dim, dim + 1) and the reflection about it: see
    :func:`caustica.bsdfs.sample`."""
    dist, au, av = roughness(mats, m, uv)
    s, t, wo = mf.shading_frame(ns, d, uv)
    zero = (0.0, 0.0, 0.0)
    if wo[2] <= 0.0:
        return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 2
    h, c = mf.sample_half_uv(dist, au, av, wo, key, dim)
    wl = mf.reflect(wo, h, c)
    wi = vec.from_local(s, t, ns, wl)
    if wl[2] <= 0.0 or c <= 0.0 or vec.dot(wi, ng) <= 0.0:
        return False, wi, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 2
    pdf = mf.D_uv(dist, au, av, h) * mf.smith_g1_uv(dist, au, av, wo, h) / (4.0 * wo[2])
    g1 = mf.smith_g1_uv(dist, au, av, wl, h)
    weight = vec.mul(vec.hadamard(colour(mats, m, uv), fresnel_rgb(mats, m, c)), g1)
    return pdf > 0.0, wi, weight, pdf, GLOSSY_REFLECTION, 1.0, dim + 2


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f towards wi as (specular_reflectance · F, D G / (4 cos θ_o cos θ_i)) and :func:`sample`'s density of wi."""
    dist, au, av = roughness(mats, m, uv)
    s, t, wo = mf.shading_frame(ns, d, uv)
    wl = mf.to_local(s, t, ns, wi)
    if wo[2] <= 0.0 or wl[2] <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    h = vec.normalize(vec.add(wo, wl))
    dh = mf.D_uv(dist, au, av, h)
    g1o = mf.smith_g1_uv(dist, au, av, wo, h)
    scale = dh * g1o * mf.smith_g1_uv(dist, au, av, wl, h) / (4.0 * wo[2] * wl[2])
    pdf = dh * g1o / (4.0 * wo[2])
    return vec.hadamard(colour(mats, m, uv), fresnel_rgb(mats, m, vec.dot(wo, h))), scale, pdf
