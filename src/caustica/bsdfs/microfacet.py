"""Mitsuba 3's microfacet distribution: the normal distribution D, Smith's shadowing G1 and G, and the sampling of
visible normals with its density; isotropic (one alpha) or anisotropic (alpha_u along the tangent s, alpha_v along
t = n x s: the ``*_uv`` kernels, which call the isotropic ones where alpha_u = alpha_v, so those keep their bits).

The definitions are those of Mitsuba 3 (``include/mitsuba/render/microfacet.h``, after Walter et al. 2007
and Heitz 2014), written here independently:

* ``BECKMANN``: D(m) = exp(-tan²θ_m / α²) / (π α² cos⁴θ_m);
  ``GGX`` (Trowbridge-Reitz): D(m) = 1 / (π α² ((m_x² + m_y²) / α² + m_z²)²); both 0 below the horizon
  and, as in Mitsuba, where D cos θ_m <= 1e-20.
* Smith's G1(v, m) = 1 / (1 + Λ(v)), 0 where v sees the back of the microfacet (v·m and cos θ_v of
  different sign), 1 at normal incidence; G(wi, wo, m) = G1(wi, m) G1(wo, m) (separable).  GGX:
  2 / (1 + sqrt(1 + α² tan²θ_v)).  Beckmann: the exact Λ = (e^(-a²) / (a √π) - erfc(a)) / 2 with
  a = 1 / (α tan θ_v); Mitsuba uses a rational approximation of it (Walter et al.'s, < 0.35 % error),
  here the exact form so that the density below is exactly the one :func:`sample_visible` draws from.
* Visible normals (Mitsuba's ``sample_visible=true``, its default): m drawn with density
  D_wi(m) = G1(wi, m) max(0, wi·m) D(m) / cos θ_wi, by stretching wi to α = 1, drawing the slopes of the
  visible normals there and unstretching.  GGX: Heitz 2018's exact construction (a point on a
  hemisphere's projected disc); Beckmann: the slope along wi by inverting its CDF
  (1 + erf(x) + tan θ e^(-x²) / √π, normalised at x = cot θ) with safeguarded Newton steps to
  convergence (Mitsuba does three), the other slope a normal deviate with variance 1/2.

Anisotropic (Mitsuba's ``alpha_u``, ``alpha_v``): the same forms with the slopes scaled per axis, m_x / α_u and
m_y / α_v in D (and α_u α_v for α² in its normalisation), α_u² v_x² + α_v² v_y² for α² (v_x² + v_y²) in G1, and
wi stretched to (α_u wi_x, α_v wi_y, wi_z) before the α = 1 sampling and the normal unstretched the same way.

Vectors are in the local frame of the macro-surface (z the normal).  An isotropic BSDF's frame is any frame about the
normal (:func:`local_frame`); an anisotropic one's is Mitsuba's shading frame (:func:`shading_frame`): s the position
partial dp/du made orthogonal to the normal (Gram-Schmidt), t = n x s.  Mitsuba's ``sample_visible=false``
(sampling D cos θ_m) is not implemented: the loader accepts it and samples visible normals all the same,
which changes how an image converges, not what it converges to.
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..scene.description import BECKMANN, GGX  # noqa: F401  (the distribution codes)

INV_PI = 1.0 / math.pi
INV_SQRT_PI = 1.0 / math.sqrt(math.pi)
#: Mitsuba clamps the roughness to at least this (a smooth surface needs the smooth BSDF).
ALPHA_MIN = 1e-4
#: The slope interval searched: the Beckmann CDF of a slope beyond ±SLOPE_MAX is below 1e-30.
SLOPE_MAX = 8.5


@kernel
def D(dist, alpha, m):
    """The microfacet distribution at the unit normal m (local frame)."""
    c = m[2]
    if c <= 0.0:
        return 0.0
    c2 = c * c
    a2 = alpha * alpha
    xy2 = m[0] * m[0] + m[1] * m[1]
    if dist == BECKMANN:
        r = math.exp(-xy2 / (a2 * c2)) / (math.pi * a2 * c2 * c2)
    else:
        t = xy2 / a2 + c2
        r = 1.0 / (math.pi * a2 * t * t)
    return r if r * c > 1e-20 else 0.0


@kernel
def smith_g1(dist, alpha, v, m):
    """Smith's masking of direction v (unit, local frame) for microfacet normal m."""
    if vec.dot(v, m) * v[2] <= 0.0:
        return 0.0
    xy2 = alpha * alpha * (v[0] * v[0] + v[1] * v[1])
    if xy2 == 0.0:
        return 1.0
    return g1_of(dist, xy2 / (v[2] * v[2]))      # α² tan²θ_v


@kernel(inline=True)
def g1_of(dist, t2):
    """Smith's masking from t2 = α² tan²θ_v (the roughness projected on v's azimuth, where it is anisotropic)."""
    if dist == BECKMANN:
        a = 1.0 / math.sqrt(t2)
        lam = 0.5 * (math.exp(-a * a) * INV_SQRT_PI / a - math.erfc(a))
        return 1.0 / (1.0 + lam)
    return 2.0 / (1.0 + math.sqrt(1.0 + t2))


@kernel
def beckmann_slope(u, tan_t):
    """The slope x < cot θ with CDF u of the visible Beckmann slopes along wi at α = 1 (tan_t = tan θ_wi);
    with tan_t = 0 a normal deviate of variance 1/2 (erf⁻¹(2u - 1))."""
    hi = SLOPE_MAX
    if tan_t > 0.0:
        hi = min(hi, 1.0 / tan_t)
    lo = -SLOPE_MAX
    # the CDF's numerator 1 + erf(x) + tan θ e^(-x²)/√π, and its value at hi (the normalisation)
    z = 1.0 + math.erf(hi) + tan_t * math.exp(-hi * hi) * INV_SQRT_PI
    target = u * z
    x = 0.0 if hi > 0.0 else 0.5 * (lo + hi)
    for _ in range(100):
        e = math.exp(-x * x) * INV_SQRT_PI
        f = math.erfc(-x) + tan_t * e - target
        if f > 0.0:
            hi = x
        else:
            lo = x
        if abs(f) <= 1e-14 * z or hi - lo <= 1e-14:
            break
        deriv = 2.0 * (1.0 - x * tan_t) * e
        nx = x - f / deriv if deriv > 0.0 else lo - 1.0
        x = nx if lo < nx < hi else 0.5 * (lo + hi)
    return x


@kernel
def sample_ggx_11(wi, u1, u2):
    """Heitz 2018: a visible normal of the α = 1 GGX distribution for the (stretched, unit) wi."""
    lensq = wi[0] * wi[0] + wi[1] * wi[1]
    if lensq > 0.0:
        inv = 1.0 / math.sqrt(lensq)
        t1v = (-wi[1] * inv, wi[0] * inv, 0.0)
    else:
        t1v = (1.0, 0.0, 0.0)
    t2v = vec.cross(wi, t1v)
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    p1 = r * math.cos(phi)
    p2 = r * math.sin(phi)
    s = 0.5 * (1.0 + wi[2])
    p2 = (1.0 - s) * math.sqrt(max(0.0, 1.0 - p1 * p1)) + s * p2
    pz = math.sqrt(max(0.0, 1.0 - p1 * p1 - p2 * p2))
    return (p1 * t1v[0] + p2 * t2v[0] + pz * wi[0],
            p1 * t1v[1] + p2 * t2v[1] + pz * wi[1],
            p1 * t1v[2] + p2 * t2v[2] + pz * wi[2])


@kernel
def sample_visible(dist, alpha, wi, u1, u2):
    """A microfacet normal m seen from wi (local, cos θ_wi > 0), with density (per solid angle of m)
    G1(wi, m) |wi·m| D(m) / cos θ_wi, which the BSDFs write out where they need it."""
    return sample_visible_uv(dist, alpha, alpha, wi, u1, u2)


@kernel
def to_local(s, t, n, v):
    """World to local (the s, t, n frame)."""
    return (vec.dot(v, s), vec.dot(v, t), vec.dot(v, n))


@kernel
def local_frame(n, d):
    """The frame (s, t) about the normal n and, in it, wo = -d (towards where the ray came from): (s, t, wo)."""
    s, t = vec.orthonormal_basis(n)
    return s, t, to_local(s, t, n, vec.neg(d))


@kernel
def reflect(wo, h, c):
    """wo mirrored about the microfacet normal h, c = wo · h (local frame)."""
    return (2.0 * c * h[0] - wo[0], 2.0 * c * h[1] - wo[1], 2.0 * c * h[2] - wo[2])


@kernel
def D_uv(dist, au, av, m):
    """:func:`D` with roughness au along the frame's s axis and av along t (anisotropic)."""
    if au == av:
        return D(dist, au, m)
    c = m[2]
    if c <= 0.0:
        return 0.0
    c2 = c * c
    x = m[0] / au
    y = m[1] / av
    xy2 = x * x + y * y
    if dist == BECKMANN:
        r = math.exp(-xy2 / c2) / (math.pi * au * av * c2 * c2)
    else:
        t = xy2 + c2
        r = 1.0 / (math.pi * au * av * t * t)
    return r if r * c > 1e-20 else 0.0


@kernel
def smith_g1_uv(dist, au, av, v, m):
    """:func:`smith_g1` with roughness au along s and av along t (anisotropic)."""
    if au == av:
        return smith_g1(dist, au, v, m)
    if vec.dot(v, m) * v[2] <= 0.0:
        return 0.0
    x = au * v[0]
    y = av * v[1]
    xy2 = x * x + y * y
    if xy2 == 0.0:
        return 1.0
    return g1_of(dist, xy2 / (v[2] * v[2]))      # the projected roughness squared times tan²θ_v


@kernel
def sample_visible_uv(dist, au, av, wi, u1, u2):
    """:func:`sample_visible` with roughness au along s and av along t: the density is G1 |wi·m| D / cos θ_wi with
    :func:`D_uv` and :func:`smith_g1_uv` (with au = av the isotropic one's, with the same arithmetic)."""
    st = vec.normalize((au * wi[0], av * wi[1], wi[2]))   # stretched to α = 1
    if dist == GGX:
        n = sample_ggx_11(st, u1, u2)
        return vec.normalize((au * n[0], av * n[1], max(n[2], 1e-30)))
    sin_t = math.sqrt(max(0.0, 1.0 - st[2] * st[2]))
    tan_t = sin_t / st[2]
    sx = beckmann_slope(u1, tan_t)
    sy = beckmann_slope(u2, 0.0)
    if sin_t > 0.0:
        cp = st[0] / sin_t
        sp = st[1] / sin_t
    else:
        cp = 1.0
        sp = 0.0
    # rotate the slopes to wi's azimuth, unstretch; the normal of slope (x, y) is (-x, -y, 1)
    x = (cp * sx - sp * sy) * au
    y = (sp * sx + cp * sy) * av
    return vec.normalize((-x, -y, 1.0))


@kernel
def sample_half_uv(dist, au, av, wo, key, dim):
    """A visible microfacet normal h seen from wo, of roughness au along s and av along t (numbers dim, dim + 1;
    :func:`sample_visible_uv`), and c = wo · h."""
    h = sample_visible_uv(dist, au, av, wo, uniform(key, dim), uniform(key, dim + 1))
    return h, vec.dot(wo, h)


@kernel(inline=True)
def tangent(uv):
    """The position partial dp/du that :func:`caustica.transport.surface_interaction` puts in the surface
    coordinates of an anisotropic material's hit (zero elsewhere)."""
    return (uv[5], uv[6], uv[7])


@kernel
def shading_frame(n, d, uv):
    """Mitsuba's shading frame about the normal n: s = dp/du (from uv, :func:`tangent`) made orthogonal to n, t = n x s,
    and wo = -d in it: (s, t, wo).  Without a tangent (an isotropic material's hit, or dp/du along n) the frame of
    :func:`local_frame`, so isotropic BSDFs keep their numbers."""
    dp = tangent(uv)
    s = vec.sub(dp, vec.mul(n, vec.dot(n, dp)))
    if vec.dot(s, s) > 0.0:
        s = vec.normalize(s)
        t = vec.cross(n, s)
        return s, t, to_local(s, t, n, vec.neg(d))
    return local_frame(n, d)
