"""``thindielectric``: a thin slab of glass (a window pane modelled as one sheet), Mitsuba 3's ``thindielectric``.

Light is reflected about the shading normal with the slab's reflectance R, or passes straight through with 1 - R:
no refraction (the two interfaces' bends cancel), no change of relative IOR (``eta`` 1, so no 1 / eta² scaling of
radiance).  R sums the internal reflections, R = F + (1 - F)² F (1 + F² + F⁴ + ...) = 2F / (1 + F), with F the
Fresnel reflectance at the angle of incidence and eta = int_ior / ext_ior whichever side the ray comes from (the
slab is symmetric), as Mitsuba's.  Both lobes are delta; both sides scatter.  Mitsuba flags the straight-on lobe
``Null``, which its ``volpath`` integrator does not count as a bounce and lets shadow rays through with
``eval_null_transmission`` = 1 - R (:func:`null_transmission`); ``pt`` does so for volpath scenes
(:data:`caustica.bsdfs.flags.NULL_TRANSMISSION`).  The medium beyond is the shape's
(its interior or exterior), as for any surface (:func:`caustica.media.medium_after`), as in Mitsuba.
"""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..scene.description import THINDIELECTRIC
from .flags import DELTA_REFLECTION, DELTA_TRANSMISSION
from .optics import fresnel_dielectric, reflect
from .dielectric import tints
from .plastic import specular
from .textures import colour

KIND = THINDIELECTRIC
FLAGS = DELTA_REFLECTION | DELTA_TRANSMISSION


@kernel(inline=True)
def slab(d, ng, ns, eta):
    """(reflected direction, the slab's reflectance R) for a ray along d.  The shading normal is turned to the
    incident side; where it disagrees with the geometry there, the geometric normal is used (as ``dielectric``)."""
    if vec.dot(d, ng) < 0.0:
        n, n_geo = ns, ng
    else:
        n, n_geo = vec.neg(ns), vec.neg(ng)
    cos_i = -vec.dot(d, n)
    if cos_i <= 0.0:
        n = n_geo
        cos_i = -vec.dot(d, n)
    F, _ = fresnel_dielectric(cos_i, eta)
    return reflect(d, n), 2.0 * F / (1.0 + F)


@kernel(inline=True)
def delta_branches(mats, m, d, ng, ns, uv):
    """Both branches (see :func:`caustica.bsdfs.delta_branches`): the reflection with R, straight on with 1 - R,
    eta 1.  Where R = 1 (int_ior < ext_ior at grazing angles) the transmitted direction repeats the reflected."""
    wr, R = slab(d, ng, ns, mats.eta[m])
    if R >= 1.0:
        return wr, wr, 1.0, 1.0, tints(mats, m, uv)
    return wr, d, R, 1.0, tints(mats, m, uv)


@kernel(inline=True)
def sample(mats, m, d, ng, ns, uv, key, dim):
    """Reflection with probability R, else straight through (number dim); the weight is the branch's tint
    (specular_reflectance or specular_transmittance, :func:`caustica.bsdfs.dielectric.tints`: the choice's
    probability cancels R or 1 - R), ``eta`` 1 on either lobe."""
    wr, R = slab(d, ng, ns, mats.eta[m])
    if uniform(key, dim) < R:
        return True, wr, specular(mats, m), 0.0, DELTA_REFLECTION, 1.0, dim + 1
    return True, d, colour(mats, m, uv), 0.0, DELTA_TRANSMISSION, 1.0, dim + 1


@kernel(inline=True)
def null_transmission(mats, m, d, ng, ns, uv):
    """The share of a shadow ray along d that passes straight on, (1 - R) times specular_transmittance: Mitsuba's
    ``eval_null_transmission``, with the R :func:`sample` reflects with (0 where R = 1)."""
    _, R = slab(d, ng, ns, mats.eta[m])
    return vec.mul(colour(mats, m, uv), max(0.0, 1.0 - R))
