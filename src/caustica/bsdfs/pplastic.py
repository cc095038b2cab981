"""``pplastic``: Mitsuba 3's polarized plastic as its RGB variants render it (``src/bsdfs/pplastic.cpp``, the
non-polarized branch): a rough specular reflection and a diffuse lobe added side by side, not a coating over a base
(so, unlike :mod:`.roughplastic`, no internal reflections, no 1 / eta² and no precomputed tables).  In the frame of
the shading normal (wo = -d, the direction the path came from; wi the other; h = normalize(wo + wi)):

* **glossy reflection**: f = specular_reflectance · F(wo·h, eta) D(h) G(wo, wi, h) / (4 cos θ_o cos θ_i), F the
  dielectric Fresnel reflectance, D and G the distribution of :mod:`.microfacet`;
* **diffuse**: f = diffuse_reflectance · (1 - F(cos θ_o, eta)) (1 - F(cos θ_i, eta)) / π, the light refracted in and
  out through a smooth interface (Mitsuba: "where conceptually some subsurface scattering occurs").

eta is the relative IOR int_ior / ext_ior (Mitsuba's defaults polypropylene, 1.49, and air, 1.000277), or Mitsuba's
``eta`` given directly.  Only the front scatters (Mitsuba's ``FrontSide``), the back is black unless ``twosided``.

Sampling picks the glossy lobe with probability w = mean(specular_reflectance) / (mean(diffuse_reflectance) +
mean(specular_reflectance)), Mitsuba's fixed specular sampling weight (no Fresnel term in it, unlike the plastics;
the ``spec_weight`` column of :mod:`.plastic`), on the first number, then a visible normal and the reflection about
it or a cosine-weighted direction on the next two (:func:`.roughplastic.lobe_direction`).  The density is the
mixture w D(h) G1(wo, h) / (4 cos θ_o) + (1 - w) cos θ_i / π, which :func:`eval_pdf` gives too, and the weight the
whole f cos θ_i over it, as Mitsuba's.  Directions below the shading or the geometric surface are refused.
Flags ``GLOSSY_REFLECTION | DIFFUSE_REFLECTION``: rendered by ``pt``; the photon methods refuse it as they refuse
roughplastic (``api.check_bsdfs``).
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..scene.description import PPLASTIC
from . import microfacet as mf
from .flags import DIFFUSE_REFLECTION, GLOSSY_REFLECTION
from .optics import fresnel_dielectric
from .plastic import SPEC_WEIGHT, specular
from .roughplastic import lobe_direction
from .textures import colour

KIND = PPLASTIC
FLAGS = GLOSSY_REFLECTION | DIFFUSE_REFLECTION
INV_PI = 1.0 / math.pi


@kernel
def local_eval(mats, m, wo, wl, uv):
    """f (RGB, both lobes) and the sampling density of the local direction wl from wo (both above the surface), the
    diffuse reflectance read at surface coordinates uv."""
    dist, alpha, eta = mats.distribution[m], mats.alpha[m], mats.eta[m]
    w = mats.coating[m, SPEC_WEIGHT]
    h = vec.normalize(vec.add(wo, wl))
    dh = mf.D(dist, alpha, h)
    g1o = mf.smith_g1(dist, alpha, wo, h)
    F, _ = fresnel_dielectric(vec.dot(wo, h), eta)
    spec = F * dh * g1o * mf.smith_g1(dist, alpha, wl, h) / (4.0 * wo[2] * wl[2])
    F_o, _ = fresnel_dielectric(wo[2], eta)
    F_i, _ = fresnel_dielectric(wl[2], eta)
    diff = (1.0 - F_o) * (1.0 - F_i) * INV_PI
    f = vec.add(vec.mul(specular(mats, m), spec), vec.mul(colour(mats, m, uv), diff))
    pdf = w * dh * g1o / (4.0 * wo[2]) + (1.0 - w) * wl[2] * INV_PI
    return f, pdf


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """The glossy lobe with probability w (number dim), else the diffuse one (numbers dim + 1, dim + 2 for either's
    direction): see :func:`caustica.bsdfs.sample` and the module's docstring (uv: where the diffuse reflectance's
    texture is read)."""
    zero = (0.0, 0.0, 0.0)
    s, t, wo = mf.local_frame(ns, d)
    if wo[2] <= 0.0:
        return False, zero, zero, 0.0, DIFFUSE_REFLECTION, 1.0, dim + 3
    wl, lobe = lobe_direction(mats, m, wo, mats.coating[m, SPEC_WEIGHT], key, dim)
    wi = vec.from_local(s, t, ns, wl)
    if wl[2] <= 0.0 or vec.dot(wi, ng) <= 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    f, pdf = local_eval(mats, m, wo, wl, uv)
    if not pdf > 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    return True, wi, vec.mul(f, wl[2] / pdf), pdf, lobe, 1.0, dim + 3


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f towards wi as (RGB f, 1), both lobes, and :func:`sample`'s density of wi (zero below either surface)."""
    s, t, wo = mf.local_frame(ns, d)
    wl = mf.to_local(s, t, ns, wi)
    if wo[2] <= 0.0 or wl[2] <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    f, pdf = local_eval(mats, m, wo, wl, uv)
    return f, 1.0, pdf
