"""``dielectric``: a smooth glass interface between two media, reflection or refraction chosen with
the Fresnel probability.  Both sides scatter; ``eta`` is int_ior / ext_ior.  As in Mitsuba, the reflected branch's
weight is ``specular_reflectance`` and the refracted branch's ``specular_transmittance`` (tinted glass; both 1 by
default): they scale the weights, not the choice (:func:`tints`)."""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..scene.description import DIELECTRIC
from .flags import DELTA_REFLECTION, DELTA_TRANSMISSION
from .optics import fresnel_dielectric, reflect, refract
from .plastic import specular
from .textures import colour

KIND = DIELECTRIC
FLAGS = DELTA_REFLECTION | DELTA_TRANSMISSION


@kernel
def interface(d, ng, ns, eta_int_over_ext):
    """At a dielectric hit: (incident-side shading normal n, relative IOR eta, cos_i, Fresnel reflectance F, cos_t).

    Both normals are turned to the side the ray comes from and eta = n_transmitted / n_incident;
    where the shading normal disagrees with the geometry (cos_i <= 0) the geometric normal is used.
    """
    if vec.dot(d, ng) < 0.0:  # entering through the front (outside -> inside)
        n, n_geo, eta = ns, ng, eta_int_over_ext
    else:
        n, n_geo, eta = vec.neg(ns), vec.neg(ng), 1.0 / eta_int_over_ext
    cos_i = -vec.dot(d, n)
    if cos_i <= 0.0:
        n = n_geo
        cos_i = -vec.dot(d, n)
    F, cos_t = fresnel_dielectric(cos_i, eta)
    return n, eta, cos_i, F, cos_t


@kernel(inline=True)
def tints(mats, m, uv):
    """(specular_reflectance, specular_transmittance) of glass m at surface coordinates uv: the factors of its
    reflected and its transmitted branch (the transmittance may be a texture, the reflectance is a constant).  Every
    glass kind (dielectric, thindielectric, roughdielectric) keeps them in the same two places."""
    return specular(mats, m), colour(mats, m, uv)


@kernel(inline=True)
def delta_branches(mats, m, d, ng, ns, uv):
    """Both branches (see :func:`caustica.bsdfs.delta_branches`): the refracted direction is meaningless
    under total internal reflection (F = 1), where it repeats the reflected one."""
    n, eta, cos_i, F, cos_t = interface(d, ng, ns, mats.eta[m])
    wr = reflect(d, n)
    if F >= 1.0:
        return wr, wr, 1.0, eta, tints(mats, m, uv)
    return wr, refract(d, n, eta, cos_i, cos_t), F, eta, tints(mats, m, uv)


@kernel(inline=True)
def sample(mats, m, d, ng, ns, uv, key, dim):
    """Reflection with probability F, else refraction (number dim); the weight is the branch's tint
    (:func:`tints`), as the choice's probability cancels the Fresnel factor.  ``eta`` is the relative IOR crossed (1
    when reflecting)."""
    n, eta, cos_i, F, cos_t = interface(d, ng, ns, mats.eta[m])
    if uniform(key, dim) < F:
        return True, reflect(d, n), specular(mats, m), 0.0, DELTA_REFLECTION, 1.0, dim + 1
    return True, refract(d, n, eta, cos_i, cos_t), colour(mats, m, uv), 0.0, DELTA_TRANSMISSION, eta, dim + 1
