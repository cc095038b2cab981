"""``roughplastic``: Mitsuba 3's rough plastic, a diffuse base under a rough dielectric coating (relative IOR eta =
int_ior / ext_ior, the microfacet distribution of :mod:`.microfacet`), with two lobes, in the frame of the shading
normal (wo = -d, the direction the path came from; wi the other; h = normalize(wo + wi)):

* **glossy reflection** off the coating: f = specular_reflectance · F(wo·h) D(h) G(wo, wi, h) / (4 cos θ_o cos θ_i),
  F the dielectric Fresnel reflectance;
* **diffuse**: f = ρ / (1 - Fdr) · T(cos θ_o) T(cos θ_i) / (π eta²) (ρ / (1 - ρ Fdr) per channel with
  ``nonlinear``),
  where T(μ) is the rough coating's transmittance from outside at incident cosine μ and Fdr its internal
  reflectance, both precomputed per material as Mitsuba 3 does (:func:`coating_tables`): T at 64 cosines
  (linearly interpolated; columns of the table's ``coating``, :mod:`.plastic`), Fdr = 2 · mean over those cosines
  of μ R(μ), R the coating's directional reflectance from inside.  Both are single-scattering Gauss-Legendre quadratures over the
  visible normals (32 x 32 nodes from outside, 128 x 128 from inside).

Sampling picks the glossy lobe with probability P = (1 - T(cos θ_o)) w / ((1 - T) w + T (1 - w)), w Mitsuba's
specular sampling weight (as :mod:`.plastic`), on the first number: a visible normal from wo and the reflection
about it, else a cosine-weighted direction, on the next two.  Its density is the mixture
P D G1(wo, h) / (4 cos θ_o) + (1 - P) cos θ_i / π, which :func:`eval_pdf` gives too, and its weight is the whole f
cos θ_i over that density, as in Mitsuba.  Directions below the shading or the geometric surface are refused.
Flags ``GLOSSY_REFLECTION | DIFFUSE_REFLECTION``: rendered by ``pt``, and by ``sppm`` with its lobes apart
(:func:`coat`, :func:`entry`, :func:`sample_coating`; :mod:`caustica.photons.visible_points`).
"""
from __future__ import annotations

import math

import numpy as np

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import ROUGHPLASTIC
from . import microfacet as mf
from .flags import ALL_LOBES, DIFFUSE_PART, DIFFUSE_REFLECTION, GLOSSY_PART, GLOSSY_REFLECTION
from .optics import fresnel_dielectric, refract
from .plastic import SPEC_WEIGHT, TABLE, TABLE_RES, base, specular

KIND = ROUGHPLASTIC
FLAGS = GLOSSY_REFLECTION | DIFFUSE_REFLECTION
INV_PI = 1.0 / math.pi


@kernel
def coating_quadrature(dist, alpha, eta, mu, nodes, weights, inside):
    """For each cosine mu[j], the rough interface's single-scattering quadrature over visible normals (u1, u2 on
    the Gauss-Legendre ``nodes`` mapped to [0, 1]): from outside (``inside`` False, relative IOR eta) the
    transmittance Σ (1 - F) G1(wt, h), from inside (relative IOR 1 / eta) the reflectance Σ F G1(wr, h)."""
    out = np.zeros(mu.shape[0])
    e = 1.0 / eta if inside else eta
    n = nodes.shape[0]
    for j in range(mu.shape[0]):
        wo = (math.sqrt(max(0.0, 1.0 - mu[j] * mu[j])), 0.0, mu[j])
        acc = 0.0
        for a in range(n):
            for b in range(n):
                h = mf.sample_visible(dist, alpha, wo, 0.5 * nodes[a] + 0.5, 0.5 * nodes[b] + 0.5)
                c = vec.dot(wo, h)
                F, cos_t = fresnel_dielectric(c, e) if c > 0.0 else (1.0, 0.0)
                if inside:
                    w = mf.reflect(wo, h, c)
                    g = F * mf.smith_g1(dist, alpha, w, h) if w[2] > 0.0 else 0.0
                elif F < 1.0:
                    w = refract(vec.neg(wo), h, e, c, cos_t)
                    g = (1.0 - F) * mf.smith_g1(dist, alpha, w, h) if w[2] < 0.0 else 0.0
                else:
                    g = 0.0
                acc += g * weights[a] * weights[b] * 0.25
        out[j] = acc
    return out


def coating_tables(dist: int, alpha: float, eta: float) -> tuple[np.ndarray, float]:
    """(T at the cosines max(1e-6, j / 63), Fdr) of a rough coating, as Mitsuba 3's roughplastic precomputes them."""
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_RES))
    out_nodes = np.polynomial.legendre.leggauss(32 if eta > 1.0 else 128)
    in_nodes = np.polynomial.legendre.leggauss(32 if 1.0 / eta > 1.0 else 128)
    T = coating_quadrature(dist, alpha, eta, mu, out_nodes[0], out_nodes[1], False)
    R = coating_quadrature(dist, alpha, eta, mu, in_nodes[0], in_nodes[1], True)
    return T, float(2.0 * np.mean(R * mu))


@kernel(inline=True)
def transmittance(mats, m, mu):
    """The coating's tabulated transmittance at cosine mu, linearly interpolated (Mitsuba's lerp_gather)."""
    x = mu * (TABLE_RES - 1)
    i = min(int(x), TABLE_RES - 2)
    t = x - i
    return (1.0 - t) * mats.coating[m, TABLE + i] + t * mats.coating[m, TABLE + i + 1]


@kernel(inline=True)
def choice(mats, m, t_o):
    """The probability of sampling the glossy lobe, given the transmittance t_o towards the path's direction."""
    w = mats.coating[m, SPEC_WEIGHT]
    ps = (1.0 - t_o) * w
    pd = t_o * (1.0 - w)
    return ps / (ps + pd) if ps + pd > 0.0 else 0.0


@kernel
def local_eval(mats, m, wo, wl, uv, part=ALL_LOBES):
    """f (RGB, both lobes) and the sampling density of the local direction wl from wo (both above the surface), the
    diffuse reflectance read at surface coordinates uv; ``part`` (:data:`.flags.ALL_LOBES`): one lobe alone, f and
    the density of picking it and sampling wl."""
    dist, alpha, eta = mats.distribution[m], mats.alpha[m], mats.eta[m]
    t_o = transmittance(mats, m, wo[2])
    P = choice(mats, m, t_o)
    h = vec.normalize(vec.add(wo, wl))
    dh = mf.D(dist, alpha, h)
    g1o = mf.smith_g1(dist, alpha, wo, h)
    F, _ = fresnel_dielectric(vec.dot(wo, h), eta)
    spec = F * dh * g1o * mf.smith_g1(dist, alpha, wl, h) / (4.0 * wo[2] * wl[2])
    diff = t_o * transmittance(mats, m, wl[2]) * INV_PI / (eta * eta)
    return lobe_sum(part, (vec.mul(specular(mats, m), spec), P * dh * g1o / (4.0 * wo[2])),
                    (vec.mul(base(mats, m, uv), diff), (1.0 - P) * wl[2] * INV_PI))


@kernel(inline=True)
def lobe_sum(part, glossy, diffuse):
    """(f, pdf) of the lobes ``part`` names (:data:`.flags.ALL_LOBES`, ``GLOSSY_PART``, ``DIFFUSE_PART``) from the
    glossy and the diffuse lobe's (f, pdf): both summed, the glossy first; shared with :mod:`.pplastic`."""
    if part == GLOSSY_PART:
        return glossy
    if part == DIFFUSE_PART:
        return diffuse
    return vec.add(glossy[0], diffuse[0]), glossy[1] + diffuse[1]


@kernel(inline=True)
def lobe_direction(mats, m, wo, P, key, dim):
    """(local direction, lobe): with probability P (number dim) the reflection of wo about a visible normal of material
    m's distribution, else a cosine-weighted direction (numbers dim + 1, dim + 2 for either); shared with
    :mod:`.pplastic`."""
    u1, u2 = uniform(key, dim + 1), uniform(key, dim + 2)
    if uniform(key, dim) < P:
        h = mf.sample_visible(mats.distribution[m], mats.alpha[m], wo, u1, u2)
        c = vec.dot(wo, h)
        return mf.reflect(wo, h, c), GLOSSY_REFLECTION
    return square_to_cosine_hemisphere(u1, u2), DIFFUSE_REFLECTION


@kernel(inline=True)
def glossy_probability(mats, m, wo):
    """The probability P of sampling the glossy lobe from wo (the transmittance's :func:`choice`)."""
    return choice(mats, m, transmittance(mats, m, wo[2]))


@kernel(inline=True)
def two_lobe_sample(probability, local_eval, mats, m, frame, uv, key, dim):
    """:func:`sample` for a glossy lobe beside a diffuse one, shared with :mod:`.pplastic`, whose sampling differs
    only in the kernels ``probability(mats, m, wo)`` (of the glossy lobe) and ``local_eval``; ``frame`` = (d, ng, ns).
    Passed as arguments, not in a tuple (which Numba would make a run-time function pointer): calls stay static."""
    d, ng, ns = frame
    zero = (0.0, 0.0, 0.0)
    s, t, wo = mf.local_frame(ns, d)
    if wo[2] <= 0.0:
        return False, zero, zero, 0.0, DIFFUSE_REFLECTION, 1.0, dim + 3
    wl, lobe = lobe_direction(mats, m, wo, probability(mats, m, wo), key, dim)
    wi = vec.from_local(s, t, ns, wl)
    if wl[2] <= 0.0 or vec.dot(wi, ng) <= 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    f, pdf = local_eval(mats, m, wo, wl, uv)
    if not pdf > 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    return True, wi, vec.mul(f, wl[2] / pdf), pdf, lobe, 1.0, dim + 3


@kernel(inline=True)
def two_lobe_eval_pdf(local_eval, mats, m, frame, uv, wi, part=ALL_LOBES):
    """:func:`eval_pdf` for a glossy lobe beside a diffuse one, shared with :mod:`.pplastic` (which differs only in
    ``local_eval``); ``frame`` = (d, ng, ns); ``part`` as :func:`caustica.bsdfs.eval_part`'s (pplastic's only)."""
    d, ng, ns = frame
    s, t, wo = mf.local_frame(ns, d)
    wl = mf.to_local(s, t, ns, wi)
    if wo[2] <= 0.0 or wl[2] <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    f, pdf = local_eval(mats, m, wo, wl, uv, part)
    return f, 1.0, pdf


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """The glossy lobe with probability P (number dim), else the diffuse one (numbers dim + 1, dim + 2 for either's
    direction): see :func:`caustica.bsdfs.sample` and the module's docstring (uv: where the diffuse reflectance's
    texture is read)."""
    return two_lobe_sample(glossy_probability, local_eval, mats, m, (d, ng, ns), uv, key, dim)


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f towards wi as (RGB f, 1), both lobes, and :func:`sample`'s density of wi (zero below either surface)."""
    return two_lobe_eval_pdf(local_eval, mats, m, (d, ng, ns), uv, wi)


# ---------------------------------------------------------------- the lobes apart, for the photon methods


@kernel
def coat(mats, m, d, ns, uv):
    """The two lobes apart (see :func:`caustica.bsdfs.rough_coat`): (P, A), P the probability that :func:`sample`
    picks the glossy lobe for a path arriving along d, A = base T(cos θ_o) / (π eta²) the diffuse lobe's factor on
    the path's side (its colour at uv); P = 0 and A = 0 seen from below."""
    zero = (0.0, 0.0, 0.0)
    cos_o = -vec.dot(d, ns)
    if cos_o <= 0.0:
        return 0.0, zero
    t_o = transmittance(mats, m, cos_o)
    eta = mats.eta[m]
    return choice(mats, m, t_o), vec.mul(base(mats, m, uv), t_o * INV_PI / (eta * eta))


@kernel
def entry(mats, m, cos_i):
    """The diffuse lobe's factor on the light's side, B = T(cos θ_i): f_diffuse = A B (:func:`coat`)."""
    if cos_i <= 0.0:
        return 0.0
    return transmittance(mats, m, cos_i)


@kernel
def sample_coating(mats, m, d, ng, ns, key, dim):
    """The glossy lobe alone, by a visible normal from wo and the reflection about it (numbers dim, dim + 1):
    (ok, wi, weight f_glossy cos θ_i / pdf_glossy = specular F(wo·h) G1(wi, h), pdf_glossy, dim + 2)."""
    zero = (0.0, 0.0, 0.0)
    s, t, wo = mf.local_frame(ns, d)
    if wo[2] <= 0.0:
        return False, zero, zero, 0.0, dim + 2
    dist, alpha = mats.distribution[m], mats.alpha[m]
    h = mf.sample_visible(dist, alpha, wo, uniform(key, dim), uniform(key, dim + 1))
    c = vec.dot(wo, h)
    wl = mf.reflect(wo, h, c)
    wi = vec.from_local(s, t, ns, wl)
    if wl[2] <= 0.0 or vec.dot(wi, ng) <= 0.0:
        return False, wi, zero, 0.0, dim + 2
    F, _ = fresnel_dielectric(c, mats.eta[m])
    pdf = mf.D(dist, alpha, h) * mf.smith_g1(dist, alpha, wo, h) / (4.0 * wo[2])
    return True, wi, vec.mul(specular(mats, m), F * mf.smith_g1(dist, alpha, wl, h)), pdf, dim + 2


@kernel
def eval_coating(mats, m, d, ng, ns, wi):
    """The glossy lobe alone towards wi: (f RGB, the density :func:`sample_coating` gives wi); zero below either
    surface."""
    zero = (0.0, 0.0, 0.0)
    s, t, wo = mf.local_frame(ns, d)
    wl = mf.to_local(s, t, ns, wi)
    if wo[2] <= 0.0 or wl[2] <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return zero, 0.0
    dist, alpha = mats.distribution[m], mats.alpha[m]
    h = vec.normalize(vec.add(wo, wl))
    dh = mf.D(dist, alpha, h)
    g1o = mf.smith_g1(dist, alpha, wo, h)
    F, _ = fresnel_dielectric(vec.dot(wo, h), mats.eta[m])
    f = F * dh * g1o * mf.smith_g1(dist, alpha, wl, h) / (4.0 * wo[2] * wl[2])
    return vec.mul(specular(mats, m), f), dh * g1o / (4.0 * wo[2])


@kernel
def split_record_weight(mats, m, d, ng, ns, wi, A):
    """What a caustic photon's record (its power times :func:`entry` B(wi), arriving from wi) is weighted by at a
    visible point that takes the diffuse lobe of the split (:func:`coat`: its factor A) but claims the glossy lobe's
    share of the caustic too (sppm's separate caustic statistics): A + f_glossy(d, wi) / B(wi), so the record gives
    the whole f times the photon's power.  A alone where B is 0 (the record then carries nothing)."""
    b = entry(mats, m, vec.dot(wi, ns))
    if b <= 0.0:
        return A
    f, _ = eval_coating(mats, m, d, ng, ns, wi)
    return vec.madd(A, f, 1.0 / b)
