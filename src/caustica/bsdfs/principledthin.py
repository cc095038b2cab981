"""``principledthin``: Mitsuba 3's thin principled BSDF (Burley's "Extending the Disney BRDF to a BSDF with Integrated
Subsurface Scattering", 2015, as Mitsuba 3 writes it in src/bsdfs/principledthin.cpp): a two-sided sheet with no
interior, so no refraction, both sides alike.

Seen from either side, the directions are first turned so that the camera's, wo = -d (Mitsuba's ``wi``), is above
the sheet (z > 0); wi, the other direction, is reflected (z > 0) or transmitted (z < 0); wi_r is wi mirrored above
the sheet and h = normalize(wo + wi_r).  Its parameters (Mitsuba's names; any of them but the sampling rates may be a
texture, read by its eval_1): base_color, roughness r, anisotropic, spec_trans s, eta (the sheet's IOR; no bending),
spec_tint, sheen, sheen_tint, flatness, diff_trans t (from 0 to 2, used as t / 2) and four lobe-sampling rates.
f |cos θ_i| is the sum of

* **specular reflection** (s > 0): s F_thin D G / (4 cos θ_o), GGX at (α_u, α_v) from r and anisotropic as
  :mod:`.principled`'s, F_thin = lerp(F_dielectric(wo·h, eta), Schlick(c_tint R0(eta)), spec_tint);
* **specular transmission** (s > 0): s base (1 - F_dielectric) D' G' / (4 cos θ_o), the same microfacet lobe mirrored
  through the sheet, at the roughness (0.65 eta - 0.35) r (Burley 2015, figure 15); G' takes wi where it is, below;
* **diffuse reflection** (s < 1, t / 2 < 1): (1 - s)(1 - t / 2) base / π cos θ_i times Disney's diffuse with
  retro-reflection (R_r = 2 r (wi·h)²), lerped to the fake subsurface with flatness, as :mod:`.principled`'s;
* **sheen**, with the diffuse reflection: sheen (1 - s)(1 - t / 2) (1 - wi·h)⁵ lerp(1, c_tint, sheen_tint) cos θ_i;
* **diffuse transmission**: (1 - s)(t / 2) base / π |cos θ_i|.

Sampling (numbers dim, dim + 1, dim + 2): number dim picks a lobe with probabilities proportional to s rate_r / 2,
s rate_t / 2, rate_dr (1 - s)(1 - t / 2) and rate_dt (1 - s) t / 2 — they do not depend on the direction, so the
density :func:`eval_pdf` returns (Mitsuba's ``pdf``) is the density of the procedure exactly — and the lobe's
direction from dim + 1, dim + 2: a visible normal of the lobe's GGX reflected about (and, to transmit, mirrored
through the sheet), or a cosine-weighted direction above (or below).  The weight is f |cos θ_i| / pdf.

Flags ``DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION`` (Mitsuba's lobes; its diffuse transmission is
smooth and transmits, which ``GLOSSY_TRANSMISSION`` covers for the loops: both sides scatter, lights behind the
sheet are sampled): rendered by every method, as a transmitting principled is (api.check_bsdfs).  No refraction:
``eta`` 1 and no 1 / eta² for a camera path.  Directions on the wrong side of the geometric surface for their lobe are
refused.
"""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import GGX, PRINCIPLEDTHIN, PRINCIPLEDTHIN_PARAMS
from . import microfacet as mf
from .flags import ALL_LOBES, DIFFUSE_PART, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GLOSSY_PART, GLOSSY_REFLECTION, \
    GLOSSY_TRANSMISSION
from .optics import fresnel_dielectric
from .principled import (ANISO, DIFF_RATE, FLATNESS, ROUGH, SHEEN, SHEEN_TINT, SPEC_RATE, SPEC_TINT, SPEC_TRANS,
                         INV_PI, dist_params, paired_eval, params, retro_diffuse, schlick, schlick_weight, tint)
from .textures import colour

KIND = PRINCIPLEDTHIN
FLAGS = DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION

#: The ``coating`` columns of a principledthin row beyond those it shares with :mod:`.principled` (ROUGH, SPEC_TRANS,
#: SPEC_TINT, SHEEN, SHEEN_TINT, FLATNESS, ANISO; SPEC_RATE its specular reflection's sampling rate, DIFF_RATE its
#: diffuse reflection's): diff_trans (as given, 0 to 2), eta, and the two transmissions' sampling rates.
DIFF_TRANS, ETA, TRANS_RATE, DIFF_TRANS_RATE = 13, 14, 15, 16
#: Each parameter's column, by Mitsuba's name (textures.param_texture's columns PARAM + column).
COLUMN = {"roughness": ROUGH, "spec_trans": SPEC_TRANS, "spec_tint": SPEC_TINT, "sheen": SHEEN,
          "sheen_tint": SHEEN_TINT, "flatness": FLATNESS, "diff_trans": DIFF_TRANS,
          "specular_reflectance_sampling_rate": SPEC_RATE, "specular_transmittance_sampling_rate": TRANS_RATE,
          "diffuse_reflectance_sampling_rate": DIFF_RATE, "diffuse_transmittance_sampling_rate": DIFF_TRANS_RATE,
          "anisotropic": ANISO, "eta": ETA}
PARAMS = PRINCIPLEDTHIN_PARAMS


def row(values: dict) -> list[float]:
    """The ``coating`` columns of a principledthin material with Mitsuba's parameters ``values`` (by name)."""
    out = [0.0] * (DIFF_TRANS_RATE + 1)
    defaults = {**PARAMS, "anisotropic": 0.0, "eta": 1.5}
    for k, column in COLUMN.items():
        out[column] = float(values.get(k, defaults[k]))
    return out


@kernel
def probabilities(p):
    """The lobes' sampling probabilities (specular reflection, specular transmission, diffuse reflection, diffuse
    transmission), normalised."""
    s = p[SPEC_TRANS]
    t = 0.5 * p[DIFF_TRANS]
    psr = s * p[SPEC_RATE] * 0.5
    pst = s * p[TRANS_RATE] * 0.5
    pdr = p[DIFF_RATE] * (1.0 - s) * (1.0 - t)
    pdt = p[DIFF_TRANS_RATE] * (1.0 - s) * t
    inv = 1.0 / (psr + pst + pdr + pdt)
    return psr * inv, pst * inv, pdr * inv, pdt * inv


@kernel(inline=True)
def lobe_alphas(p):
    """(α_u, α_v) of the specular reflection and of the specular transmission (roughness scaled by 0.65 eta - 0.35)."""
    au, av = dist_params(p[ROUGH], p[ANISO])
    tu, tv = dist_params((0.65 * p[ETA] - 0.35) * p[ROUGH], p[ANISO])
    return au, av, tu, tv


@kernel(inline=True)
def visible_pdf(au, av, wo, h):
    """GGX's density of visible normal h seen from wo (wo above)."""
    return mf.D_uv(GGX, au, av, h) * mf.smith_g1_uv(GGX, au, av, wo, h) * abs(vec.dot(wo, h)) / wo[2]


@kernel
def local_eval(mats, m, wo, wi, uv, part=ALL_LOBES):
    """(f RGB, density) towards the local direction wi from wo (wo[2] != 0), Mitsuba's ``eval`` over |cos θ_i| and
    its ``pdf`` (module docstring); the base colour read at uv.  ``part`` (:data:`.flags.ALL_LOBES`): the diffuse
    lobes (reflection with its sheen, transmission) or the glossy ones (specular reflection and transmission) alone,
    f and the density of sampling one of them and wi."""
    zero = (0.0, 0.0, 0.0)
    if wo[2] == 0.0 or wi[2] == 0.0:
        return zero, 0.0
    p = params(mats, m, uv)
    if wo[2] < 0.0:   # the sheet is symmetric: turn both to the camera's side
        wo = vec.neg(wo)
        wi = vec.neg(wi)
    co = wo[2]
    ci = abs(wi[2])
    reflect = wi[2] > 0.0
    wr = (wi[0], wi[1], ci)
    h = vec.normalize(vec.add(wo, wr))
    s = p[SPEC_TRANS]
    t = 0.5 * p[DIFF_TRANS]
    eta = p[ETA]
    au, av, tu, tv = lobe_alphas(p)
    base = colour(mats, m, uv)
    c = vec.dot(wo, h)
    wih = vec.dot(wi, h)
    comp_r = reflect and c > 0.0 and wih > 0.0
    comp_t = (not reflect) and c > 0.0 and wih < 0.0
    f = zero     # f |cos θ_i|, as Mitsuba's eval
    glossy, diffuse = part != DIFFUSE_PART, part != GLOSSY_PART
    if s > 0.0 and (comp_r or comp_t) and glossy:
        F, _ = fresnel_dielectric(c, eta)
        if comp_r:
            spec = (F, F, F)
            st = p[SPEC_TINT]
            if st != 0.0:
                ct, _ = tint(base)
                r0 = (eta - 1.0) / (eta + 1.0)
                r0 = r0 * r0
                spec = (F + st * (schlick(ct[0] * r0, c, eta) - F), F + st * (schlick(ct[1] * r0, c, eta) - F),
                        F + st * (schlick(ct[2] * r0, c, eta) - F))
            g = mf.smith_g1_uv(GGX, au, av, wo, h) * mf.smith_g1_uv(GGX, au, av, wi, h)
            f = vec.mul(spec, s * mf.D_uv(GGX, au, av, h) * g / (4.0 * co))
        else:
            g = mf.smith_g1_uv(GGX, tu, tv, wo, h) * mf.smith_g1_uv(GGX, tu, tv, wi, h)
            f = vec.mul(base, s * (1.0 - F) * mf.D_uv(GGX, tu, tv, h) * g / (4.0 * co))
    if reflect and s < 1.0 and t < 1.0 and diffuse:
        cd = vec.dot(h, wi)
        lam = retro_diffuse(p, co, ci, cd)
        f = vec.add(f, vec.mul(base, (1.0 - s) * ci * INV_PI * (1.0 - t) * lam))
        if p[SHEEN] > 0.0:
            k = p[SHEEN] * (1.0 - s) * schlick_weight(abs(cd)) * (1.0 - t) * ci
            st = p[SHEEN_TINT]
            if st != 0.0:
                ct, _ = tint(base)
                f = vec.add(f, vec.mul((1.0 + st * (ct[0] - 1.0), 1.0 + st * (ct[1] - 1.0), 1.0 + st * (ct[2] - 1.0)),
                                       k))
            else:
                f = vec.add(f, (k, k, k))
    if (not reflect) and s < 1.0 and t > 0.0 and diffuse:
        f = vec.add(f, vec.mul(base, (1.0 - s) * t * INV_PI * ci))
    # the density
    psr, pst, pdr, pdt = probabilities(p)
    pdf = 0.0
    if s > 0.0 and glossy:
        jac = abs(1.0 / (4.0 * vec.dot(wr, h)))
        if comp_r:
            pdf += psr * visible_pdf(au, av, wo, h) * jac
        if comp_t:
            pdf += pst * visible_pdf(tu, tv, wo, h) * jac
    if reflect and diffuse:
        pdf += pdr * ci * INV_PI
    elif diffuse:
        pdf += pdt * ci * INV_PI
    return vec.mul(f, 1.0 / ci), pdf


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """See :func:`caustica.bsdfs.sample` and the module's docstring: ``eta`` 1 (a thin sheet bends nothing)."""
    return sample_lobes(mats, m, d, ng, ns, uv, (key, dim), -1.0)


@kernel
def sample_glossy(mats, m, d, ng, ns, uv, numbers, u):
    """:func:`sample` of the glossy lobes alone (its density there is :func:`eval_part`'s over
    :func:`glossy_share`), u in [0, 1) picking one of them as :func:`sample`'s first number would."""
    return sample_lobes(mats, m, d, ng, ns, uv, numbers, u)


@kernel(inline=True)
def sample_lobes(mats, m, d, ng, ns, uv, numbers, u):
    """:func:`sample` (numbers = (key, dim)), or with u >= 0 :func:`sample_glossy`."""
    key, dim = numbers
    s_, t_, wo = mf.shading_frame(ns, d, uv)   # about the front shading normal (the sheet transmits)
    zero = (0.0, 0.0, 0.0)
    if wo[2] == 0.0:
        return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 3
    p = params(mats, m, uv)
    u0, u1, u2 = uniform(key, dim), uniform(key, dim + 1), uniform(key, dim + 2)
    sign = 1.0 if wo[2] > 0.0 else -1.0
    wu = vec.mul(wo, sign)     # wo turned above the sheet
    psr, pst, pdr, _ = probabilities(p)
    if u >= 0.0:   # the glossy lobes come first in the choice
        u0 = u * (psr + pst)
    if u0 < psr or u0 < psr + pst:
        au, av, tu, tv = lobe_alphas(p)
        refl = u0 < psr
        h = mf.sample_visible_uv(GGX, au if refl else tu, av if refl else tv, wu, u1, u2)
        wl = mf.reflect(wu, h, vec.dot(wu, h))
        if refl:
            lobe = GLOSSY_REFLECTION
        else:    # mirrored through the sheet
            wl = (wl[0], wl[1], -wl[2])
            lobe = GLOSSY_TRANSMISSION
        # Mitsuba's macro-micro compatibility: wo on the microfacet's front, wi on it (reflected) or behind it
        ok = vec.dot(wu, h) > 0.0 and (wl[2] > 0.0 and vec.dot(wl, h) > 0.0 if refl else
                                       wl[2] < 0.0 and vec.dot(wl, h) < 0.0)
    elif u0 < psr + pst + pdr:
        wl = square_to_cosine_hemisphere(u1, u2)
        lobe = DIFFUSE_REFLECTION
        ok = True
    else:
        wl = vec.neg(square_to_cosine_hemisphere(u1, u2))
        lobe = GLOSSY_TRANSMISSION | DIFFUSE_TRANSMISSION
        ok = True
    wl = vec.mul(wl, sign)
    wi = vec.from_local(s_, t_, ns, wl)
    # the geometric surface: a reflection leaves on wo's side of it, a transmission on the other
    across = vec.dot(wi, ng) * vec.dot(d, ng)
    if not (ok and wl[2] != 0.0 and (across > 0.0 if lobe & GLOSSY_TRANSMISSION else across < 0.0)):
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    f, pdf = local_eval(mats, m, wo, wl, uv)
    if not pdf > 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    return True, wi, vec.mul(f, abs(wl[2]) / pdf), pdf, lobe, 1.0, dim + 3


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """:func:`caustica.bsdfs.principled.eval_pdf` for the thin sheet (its :func:`local_eval`, its :func:`sample`)."""
    return eval_part(mats, m, d, ng, ns, uv, wi, ALL_LOBES)


@kernel
def eval_part(mats, m, d, ng, ns, uv, wi, part):
    """:func:`eval_pdf` of the lobes ``part`` names alone: :func:`.principled.paired_eval` with this module's
    :func:`local_eval`."""
    return paired_eval(local_eval, mats, m, (d, ng, ns), uv, wi, part)


@kernel
def glossy_share(mats, m, d, ns, uv):
    """The probability that :func:`sample` picks a glossy lobe (specular reflection or transmission), the same from
    either side and any direction."""
    psr, pst, _, _ = probabilities(params(mats, m, uv))
    return psr + pst


@kernel
def glossy_albedo(mats, m, d, ns, uv):
    """(glossy, diffuse): about how much of the light from -d the glossy lobes and the diffuse ones scatter, for
    :func:`caustica.bsdfs.glossy_pick`: spec_trans (F + (1 - F) base) and (1 - spec_trans) base, base's mean."""
    p = params(mats, m, uv)
    s = p[SPEC_TRANS]
    F, _ = fresnel_dielectric(abs(vec.dot(d, ns)), p[ETA])
    c = colour(mats, m, uv)
    base = (c[0] + c[1] + c[2]) / 3.0
    return s * (F + (1.0 - F) * base), (1.0 - s) * base
