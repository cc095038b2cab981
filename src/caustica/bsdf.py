"""The supported BSDFs: diffuse, perfect mirror (conductor) and smooth dielectric.

Materials live in a :class:`MaterialTable` (structure of arrays, indexed by the
primitive's material id).  The diffuse BSDF is sampled by cosine weighting; the
mirror and the dielectric are Dirac deltas, handled by returning the one (or,
for glass, the Fresnel-chosen) outgoing direction and its weight.

Sidedness follows Mitsuba 3: a diffuse or conductor surface seen from the back is
black unless wrapped in ``twosided``; a dielectric is an interface between two
media, so both sides are active.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .geometry import vec
from .jit import kernel
from .sampling.rng import uniform
from .sampling.warps import square_to_cosine_hemisphere
from .scene.description import CONDUCTOR, DIELECTRIC, DIFFUSE, SceneDescription  # noqa: F401


class MaterialTable(NamedTuple):
    kind: np.ndarray       # int32[M]: DIFFUSE, CONDUCTOR or DIELECTRIC
    rgb: np.ndarray        # float64[M, 3]: reflectance (diffuse), specular reflectance (conductor), scale (glass)
    eta: np.ndarray        # float64[M]: int_ior / ext_ior (dielectric only)
    twosided: np.ndarray   # int8[M]: 1 when both sides scatter
    albedo_mean: np.ndarray  # float64[M]: mean of rgb, the survival probability of associated photons


def build_material_table(desc: SceneDescription) -> MaterialTable:
    m = max(1, len(desc.materials))
    kind = np.zeros(m, np.int32)
    rgb = np.full((m, 3), 0.5)
    eta = np.ones(m)
    twosided = np.zeros(m, np.int8)
    for i, mat in enumerate(desc.materials):
        kind[i] = mat.kind
        rgb[i] = mat.rgb
        eta[i] = mat.int_ior / mat.ext_ior
        twosided[i] = 1 if mat.twosided else 0
    return MaterialTable(kind, rgb, eta, twosided, rgb.mean(axis=1))


@kernel(inline=True)
def scattering_side(mats, m, front, ng, ns):
    """(scatters, ng, ns) for a ray arriving on the front (``front``) or back of material m.

    Diffuse and conductor normals are turned to the side the ray came from; their
    back is black (``scatters`` False) unless the material is two-sided, as in
    Mitsuba.  Dielectric normals stay on the front side (both sides are active).
    """
    if front or mats.kind[m] == DIELECTRIC:
        return True, ng, ns
    if mats.twosided[m] == 0:
        return False, ng, ns
    return True, vec.neg(ng), vec.neg(ns)


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
def dielectric_interface(d, ng, ns, eta_int_over_ext):
    """The incident-side normals and relative IOR at a dielectric hit.

    Returns (n_shading, n_geometric, eta) with both normals flipped to the side
    the ray comes from and eta = n_transmitted / n_incident.
    """
    if vec.dot(d, ng) < 0.0:  # entering through the front (outside -> inside)
        return ns, ng, eta_int_over_ext
    return vec.neg(ns), vec.neg(ng), 1.0 / eta_int_over_ext


@kernel
def dielectric_fresnel(d, ng, ns, eta_int_over_ext):
    """At a dielectric hit: (incident-side normal n, relative IOR eta, cos_i, Fresnel reflectance F, cos_t)."""
    n, n_geo, eta = dielectric_interface(d, ng, ns, eta_int_over_ext)
    cos_i = -vec.dot(d, n)
    if cos_i <= 0.0:  # the shading normal disagrees with the geometry: use the geometric normal
        n = n_geo
        cos_i = -vec.dot(d, n)
    F, cos_t = fresnel_dielectric(cos_i, eta)
    return n, eta, cos_i, F, cos_t


@kernel
def sample_dielectric(d, ng, ns, eta_int_over_ext, u):
    """Choose reflection or refraction at glass with probability F (Fresnel).

    Returns (direction, is_reflection, eta) where eta is the relative IOR crossed
    (1 for reflection).  Since the choice is made with probability F, the
    throughput weight is just the material's scale colour; radiance carried by a
    refracted camera ray is additionally scaled by 1 / eta^2 (solid-angle
    compression), which callers apply in radiance mode only.
    """
    n, eta, cos_i, F, cos_t = dielectric_fresnel(d, ng, ns, eta_int_over_ext)
    if u < F:
        return reflect(d, n), True, 1.0
    return refract(d, n, eta, cos_i, cos_t), False, eta


@kernel
def dielectric_branches(d, ng, ns, eta_int_over_ext):
    """Both branches at glass, as :func:`sample_dielectric` would choose between them.

    Returns (reflected direction, refracted direction, F, eta): F is the probability
    sample_dielectric gives reflection (1 under total internal reflection, when the
    refracted direction is meaningless) and eta the relative IOR of the refraction.
    ``u < F`` picks reflection exactly as sample_dielectric(d, ng, ns, eta, u) does.
    """
    n, eta, cos_i, F, cos_t = dielectric_fresnel(d, ng, ns, eta_int_over_ext)
    wr = reflect(d, n)
    if F >= 1.0:
        return wr, wr, 1.0, eta
    return wr, refract(d, n, eta, cos_i, cos_t), F, eta


@kernel(inline=True)
def sample_surface(kind, rgb, eta, d, ng, ns, key, dim, beta, eta_scale):
    """Continue a path at a surface: sample its BSDF and weight the throughput.

    Diffuse: a cosine-weighted direction (``pdf`` its density; ``alive`` is False when it
    falls below the geometric surface); mirror: the reflection; glass: reflection or
    refraction with the Fresnel probability (β /= η² when refracting, ``eta_scale`` *= η²,
    for Russian roulette).  Returns (alive, wi, β, eta_scale, pdf, specular, dim), ``dim``
    past the random numbers used; ``pdf`` is 0 for the Dirac lobes (specular).
    """
    if kind == DIFFUSE:
        local = square_to_cosine_hemisphere(uniform(key, dim), uniform(key, dim + 1))
        dim += 2
        s, t = vec.orthonormal_basis(ns)
        wi = vec.from_local(s, t, ns, local)
        if vec.dot(wi, ng) <= 0.0 or local[2] <= 0.0:
            return False, wi, beta, eta_scale, 0.0, False, dim
        return True, wi, vec.hadamard(beta, rgb), eta_scale, local[2] * (1.0 / math.pi), False, dim
    if kind == CONDUCTOR:
        return True, mirror_reflect(d, ng, ns), vec.hadamard(beta, rgb), eta_scale, 0.0, True, dim
    wi, is_reflection, eta_t = sample_dielectric(d, ng, ns, eta, uniform(key, dim))
    dim += 1
    beta = vec.hadamard(beta, rgb)
    if not is_reflection:
        beta = vec.mul(beta, 1.0 / (eta_t * eta_t))
        eta_scale *= eta_t * eta_t
    return True, wi, beta, eta_scale, 0.0, True, dim
