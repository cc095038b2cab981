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
it or a cosine-weighted direction on the next two (:func:`.roughplastic.two_lobe_sample`, with this module's
lobe probability and :func:`local_eval`).  The density is the mixture w D(h) G1(wo, h) / (4 cos θ_o) + (1 - w)
cos θ_i / π, which :func:`eval_pdf` gives too, and the weight the whole f cos θ_i over it, as Mitsuba's.
Directions below the shading or the geometric surface are refused.
Flags ``GLOSSY_REFLECTION | DIFFUSE_REFLECTION``: rendered by every method, the photon methods' estimates weighting
each photon by f at its direction (``api.check_bsdfs``).
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..scene.description import PPLASTIC
from . import microfacet as mf
from .flags import ALL_LOBES, DIFFUSE_REFLECTION, GLOSSY_REFLECTION
from .optics import fresnel_dielectric
from .plastic import SPEC_WEIGHT, specular
from .roughplastic import lobe_sum, two_lobe_eval_pdf, two_lobe_sample
from .textures import colour

KIND = PPLASTIC
FLAGS = GLOSSY_REFLECTION | DIFFUSE_REFLECTION
INV_PI = 1.0 / math.pi


@kernel
def local_eval(mats, m, wo, wl, uv, part=ALL_LOBES):
    """f (RGB, both lobes) and the sampling density of the local direction wl from wo (both above the surface), the
    diffuse reflectance read at surface coordinates uv; ``part`` (:data:`.flags.ALL_LOBES`): one lobe alone, f and
    the density of picking it and sampling wl."""
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
    return lobe_sum(part, (vec.mul(specular(mats, m), spec), w * dh * g1o / (4.0 * wo[2])),
                    (vec.mul(colour(mats, m, uv), diff), (1.0 - w) * wl[2] * INV_PI))


@kernel(inline=True)
def glossy_probability(mats, m, wo):
    """The probability w of sampling the glossy lobe: Mitsuba's fixed specular sampling weight, whatever wo."""
    return mats.coating[m, SPEC_WEIGHT]


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """:func:`caustica.bsdfs.sample`: :func:`.roughplastic.two_lobe_sample` with the fixed glossy probability w."""
    return two_lobe_sample(glossy_probability, local_eval, mats, m, (d, ng, ns), uv, key, dim)


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """:func:`caustica.bsdfs.eval_pdf`: :func:`.roughplastic.two_lobe_eval_pdf` with this module's local_eval."""
    return two_lobe_eval_pdf(local_eval, mats, m, (d, ng, ns), uv, wi)


@kernel
def eval_part(mats, m, d, ng, ns, uv, wi, part):
    """:func:`eval_pdf` of one lobe alone (``part``, :func:`local_eval`)."""
    return two_lobe_eval_pdf(local_eval, mats, m, (d, ng, ns), uv, wi, part)


@kernel
def glossy_share(mats, m, d, ns, uv):
    """The probability that :func:`sample` picks the glossy lobe: w, whatever the direction."""
    return mats.coating[m, SPEC_WEIGHT]


@kernel
def glossy_albedo(mats, m, d, ns, uv):
    """(glossy, diffuse): about how much of the light from -d each lobe reflects (the channels' means), for
    :func:`caustica.bsdfs.glossy_pick`: F(cos θ_o) specular_reflectance and (1 - F(cos θ_o))² diffuse_reflectance
    (the light refracted in and, about as much, out)."""
    co = -vec.dot(d, ns)
    if co <= 0.0:
        return 0.0, 0.0
    F, _ = fresnel_dielectric(co, mats.eta[m])
    s, c = specular(mats, m), colour(mats, m, uv)
    return F * (s[0] + s[1] + s[2]) / 3.0, (1.0 - F) * (1.0 - F) * (c[0] + c[1] + c[2]) / 3.0


@kernel(inline=True)
def glossy_only(mats, m, wo):
    """The glossy lobe's probability in :func:`sample_glossy`: 1."""
    return 1.0


@kernel
def sample_glossy(mats, m, d, ng, ns, uv, numbers, u):
    """:func:`sample` of the glossy lobe alone, numbers = (key, dim) (its density there is :func:`eval_part`'s over
    w); u, the number that would pick the lobe, is not needed."""
    return two_lobe_sample(glossy_only, local_eval, mats, m, (d, ng, ns), uv, numbers[0], numbers[1])
