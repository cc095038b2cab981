"""``roughdielectric``: Mitsuba 3's rough glass, Walter et al. 2007's microfacet BSDF (:mod:`.microfacet`) between two
media of relative IOR ``eta`` = int_ior / ext_ior.  Both sides scatter.

In the frame of the shading normal turned to the side the path comes from (wo = -d above it; eta the IOR across
over the IOR on wo's side; the geometric normal where the shading normal disagrees, as the smooth ``dielectric``),
with h the microfacet normal (above the surface) and F = F_dielectric(wo·h):

* reflection (wi above): f = F D G / (4 cos θ_o cos θ_i), h = normalize(wo + wi);
* transmission (wi below): f = (1 - F) D G eta² |wo·h| |wi·h| / (cos θ_o |cos θ_i| (wo·h + eta wi·h)²),
  h = ±normalize(wo + eta wi) — the BSDF for importance (Mitsuba's ``TransportMode::Importance``); radiance is
  further scaled by 1 / eta² across the refraction, which camera paths apply (:func:`camera_scale`,
  :mod:`caustica.bsdfs`).

Sampling draws a visible normal from wo (numbers dim, dim + 1), then reflection with probability F, else
refraction (number dim + 2), so both weights f |cos θ_i| / pdf are G1(wi, h), times the lobe's tint: Mitsuba's
specular_reflectance or specular_transmittance (both 1 by default; :func:`caustica.bsdfs.dielectric.tints`).
Anisotropic roughness as :mod:`.roughconductor`'s (the frame's s from dp/du on either side: D and G1 are even in each
slope).
"""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..scene.description import ROUGHDIELECTRIC
from . import microfacet as mf
from .roughconductor import roughness
from .flags import GLOSSY_REFLECTION, GLOSSY_TRANSMISSION
from .optics import fresnel_dielectric, refract
from .plastic import specular
from .textures import colour

KIND = ROUGHDIELECTRIC
FLAGS = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION


#: |wo + eta wi| below this is the degenerate refraction straight through an interface of eta ~ 1, whose
#: density is unbounded (the loader refuses int_ior == ext_ior, as Mitsuba does; this guards the rest).
DEGENERATE_HALF_VECTOR = 1e-7


@kernel(inline=True)
def side(d, ng, ns, eta_int_over_ext):
    """(n, n_geo, eta): the shading normal on -d's side (the geometric one where they disagree), the geometric
    normal on that side, and the relative IOR crossed (transmitted over incident), as
    :func:`caustica.bsdfs.dielectric.interface` decides them."""
    if vec.dot(d, ng) < 0.0:
        n, n_geo, eta = ns, ng, eta_int_over_ext
    else:
        n, n_geo, eta = vec.neg(ns), vec.neg(ng), 1.0 / eta_int_over_ext
    if -vec.dot(d, n) <= 0.0:
        n = n_geo
    return n, n_geo, eta


@kernel(inline=True)
def same_side(wi, n_geo, reflect):
    """Whether wi leaves by the side of the geometric surface its lobe says (above it for a reflection, below
    for a refraction): where shading and geometric normals disagree, the shading frame alone would send a
    reflection through the surface, and light sampling (which tests both normals) could not meet it."""
    c = vec.dot(wi, n_geo)
    return c > 0.0 if reflect else c < 0.0


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """See :func:`caustica.bsdfs.sample`: ``eta`` is the relative IOR crossed (1 when reflecting)."""
    dist, au, av = roughness(mats, m, uv)
    n, n_geo, eta = side(d, ng, ns, mats.eta[m])
    s, t, wo = mf.shading_frame(n, d, uv)
    zero = (0.0, 0.0, 0.0)
    if wo[2] <= 0.0:
        return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 3
    h, c = mf.sample_half_uv(dist, au, av, wo, key, dim)
    if c <= 0.0:
        return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 3
    F, cos_t = fresnel_dielectric(c, eta)
    p_h = mf.D_uv(dist, au, av, h) * mf.smith_g1_uv(dist, au, av, wo, h) * c / wo[2]
    if uniform(key, dim + 2) < F:
        wl = mf.reflect(wo, h, c)
        pdf = F * p_h / (4.0 * c)
        lobe, eta_out = GLOSSY_REFLECTION, 1.0
        ok = wl[2] > 0.0
    else:
        wl = refract(vec.neg(wo), h, eta, c, cos_t)
        ci = vec.dot(wl, h)
        den = c + eta * ci
        pdf = (1.0 - F) * p_h * eta * eta * abs(ci) / (den * den)
        lobe, eta_out = GLOSSY_TRANSMISSION, eta
        ok = wl[2] < 0.0 and abs(den) > DEGENERATE_HALF_VECTOR
    g1 = mf.smith_g1_uv(dist, au, av, wl, h)
    wi = vec.from_local(s, t, n, wl)
    ok = ok and same_side(wi, n_geo, lobe == GLOSSY_REFLECTION)
    tint = specular(mats, m) if lobe == GLOSSY_REFLECTION else colour(mats, m, uv)
    return ok and pdf > 0.0 and g1 > 0.0, wi, vec.mul(tint, g1), pdf, lobe, eta_out, dim + 3


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f towards wi (the lobe's tint, and the scale above) and :func:`sample`'s density of wi."""
    dist, au, av = roughness(mats, m, uv)
    n, n_geo, eta = side(d, ng, ns, mats.eta[m])
    s, t, wo = mf.shading_frame(n, d, uv)
    wl = mf.to_local(s, t, n, wi)
    zero = (0.0, 0.0, 0.0)
    reflect = wl[2] > 0.0
    e = 1.0 if reflect else eta
    hv = (wo[0] + e * wl[0], wo[1] + e * wl[1], wo[2] + e * wl[2])
    hl = vec.length(hv)
    if wo[2] <= 0.0 or wl[2] == 0.0 or not hl > DEGENERATE_HALF_VECTOR or not same_side(wi, n_geo, reflect):
        return zero, 0.0, 0.0
    h = vec.mul(hv, (1.0 if hv[2] >= 0.0 else -1.0) / hl)
    dh = mf.D_uv(dist, au, av, h)
    g1o = mf.smith_g1_uv(dist, au, av, wo, h)
    g = g1o * mf.smith_g1_uv(dist, au, av, wl, h)
    if dh * g == 0.0:
        return zero, 0.0, 0.0
    c = vec.dot(wo, h)
    F, _ = fresnel_dielectric(c, eta)
    if reflect:
        return specular(mats, m), F * dh * g / (4.0 * wo[2] * wl[2]), F * dh * g1o / (4.0 * wo[2])
    ci = vec.dot(wl, h)
    den = c + eta * ci
    jac = eta * eta * abs(ci) / (den * den)
    scale = (1.0 - F) * dh * g * c * jac / (wo[2] * abs(wl[2]))
    return colour(mats, m, uv), scale, (1.0 - F) * dh * g1o * c / wo[2] * jac


@kernel
def camera_scale(mats, m, d, ng, ns, wi):
    """1 / eta² when wi is refracted (radiance's compression into the denser medium), else 1."""
    n, _, eta = side(d, ng, ns, mats.eta[m])
    if vec.dot(wi, n) < 0.0:
        return 1.0 / (eta * eta)
    return 1.0
