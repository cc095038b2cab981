"""``conductor``: a smooth mirror, f a Dirac delta about the shading normal, scaled by ``specular_reflectance``
and, given the complex IOR (``conductor_eta`` / ``conductor_k``), by the conductor's Fresnel reflectance at the
angle of incidence; Mitsuba's ``material="none"`` is F = 1 (then the weight is the colour exactly)."""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..scene.description import CONDUCTOR
from .flags import DELTA_REFLECTION
from .optics import fresnel_conductor, mirror_reflect
from .textures import colour

KIND = CONDUCTOR
FLAGS = DELTA_REFLECTION


@kernel(inline=True)
def reflectance(mats, m, uv, d, wr):
    """specular_reflectance (at surface coordinates uv), times the Fresnel reflectance of the reflection d -> wr
    when the IOR is given."""
    rgb = colour(mats, m, uv)
    if mats.fresnel[m] == 0:
        return rgb
    h = vec.normalize(vec.sub(wr, d))
    c = vec.dot(wr, h)
    return (rgb[0] * fresnel_conductor(c, mats.cond_eta[m, 0], mats.cond_k[m, 0]),
            rgb[1] * fresnel_conductor(c, mats.cond_eta[m, 1], mats.cond_k[m, 1]),
            rgb[2] * fresnel_conductor(c, mats.cond_eta[m, 2], mats.cond_k[m, 2]))


@kernel(inline=True)
def delta_branches(mats, m, d, ng, ns, uv):
    """The one reflected direction, as both branches with F = 1 (see :func:`caustica.bsdfs.delta_branches`)."""
    wr = mirror_reflect(d, ng, ns)
    tint = reflectance(mats, m, uv, d, wr)
    return wr, wr, 1.0, 1.0, (tint, tint)


@kernel(inline=True)
def sample(mats, m, d, ng, ns, uv, key, dim):
    """The reflection, weight ``specular_reflectance`` (times F).  Like every delta BSDF it takes one number (its
    lobe choice, of one lobe here), so a mirror and a glass advance a path's numbers alike."""
    wr = mirror_reflect(d, ng, ns)
    return True, wr, reflectance(mats, m, uv, d, wr), 0.0, DELTA_REFLECTION, 1.0, dim + 1
