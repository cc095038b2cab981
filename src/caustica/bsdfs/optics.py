"""Reflection and refraction at a smooth interface: the geometric optics the BSDFs share.

Directions follow the transport loops' convention: ``d`` is the incident direction of travel
(pointing towards the surface), normals are unit vectors, and the returned directions leave
the surface.
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel


@kernel
def reflect(d, n):
    """Mirror direction of the incident direction d (pointing towards the surface) about n."""
    c = 2.0 * vec.dot(d, n)
    return (d[0] - c * n[0], d[1] - c * n[1], d[2] - c * n[2])


@kernel(inline=True)
def mirror_reflect(d, ng, ns):
    """The perfect mirror's direction about the shading normal; about the geometric normal
    when the shading normal would send the ray into the surface.  Normals on the incident side."""
    wi = reflect(d, ns)
    if vec.dot(wi, ng) <= 0.0:
        wi = reflect(d, ng)
    return wi


@kernel
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of a smooth dielectric interface.

    cos_i: cosine between the incident direction and the normal on the incident
    side (> 0); eta: relative IOR (transmitted side over incident side).
    Returns (F, cos_t); F = 1 for total internal reflection.
    """
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@kernel
def refract(d, n, eta, cos_i, cos_t):
    """Refracted direction of d through a surface with normal n on the incident side."""
    inv = 1.0 / eta
    k = inv * cos_i - cos_t
    return vec.normalize((d[0] * inv + n[0] * k, d[1] * inv + n[1] * k, d[2] * inv + n[2] * k))


@kernel
def fresnel_conductor(cos_i, eta, k):
    """Unpolarised Fresnel reflectance of a conductor of complex relative IOR eta + i k (one channel).

    cos_i: cosine of the incident angle (> 0).  The exact formula for an absorbing medium (Born & Wolf;
    as Mitsuba 3's ``fresnel_conductor`` and pbrt's ``FrConductor``): with a² + b² the modulus of
    (eta + i k)² - sin² θ and a its real square root, r_s = (a²+b² + cos² - 2a cos) / (a²+b² + cos² + 2a cos)
    and r_p = r_s (cos² (a²+b²) + sin⁴ - 2a cos sin²) / (cos² (a²+b²) + sin⁴ + 2a cos sin²).
    """
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    a2b2 = math.sqrt(t * t + 4.0 * eta * eta * k * k)
    a = math.sqrt(max(0.5 * (a2b2 + t), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * a * cos_i
    rs = (t1 - t2) / (t1 + t2)
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / (t3 + t4)
    return 0.5 * (rs + rp)
