"""``principled``: Mitsuba 3's principled BSDF (Burley's "Physically Based Shading at Disney", 2012 and 2015, as
Mitsuba 3 writes it in src/bsdfs/principled.cpp), in the shading frame (z the front shading normal; wo = -d, the
direction the path came from, Mitsuba's ``wi``; wi the other direction; h the half vector, turned up).

Its parameters (Mitsuba's names): roughness r, anisotropic, metallic, spec_trans, eta (or ``specular`` s, eta = 2 /
(1 - sqrt(0.08 s)) - 1), spec_tint, sheen, sheen_tint, clearcoat, clearcoat_gloss, flatness and three lobe-sampling
rates.  base_color and any of them but eta / specular and the rates may be given by a texture, as Mitsuba's: its value
at the surface point (``eval_1``, :func:`.textures.param` through the table's ``param_texture`` columns, as a rough
BSDF's textured alpha) is read by :func:`params`; a textured roughness or anisotropic makes α_u, α_v per point
(:func:`alphas`), a textured spec_trans makes the material an interface.  With brdf = (1 - metallic)(1 -
spec_trans) and bsdf = (1 - metallic) spec_trans, f is the sum of

* **specular reflection**, a GGX microfacet lobe with α = r² (anisotropic: α_u = r² / a, α_v = r² a,
  a = sqrt(1 - 0.9 anisotropic); each at least 0.001): F D G / (4 cos θ_o cos θ_i), F Disney's blend
  (1 - metallic)(1 - spec_tint) F_dielectric(wo·h) + metallic Schlick(base) + (1 - metallic) spec_tint
  Schlick(c_tint R0(eta)) (c_tint = base / luminance; Schlick at the refracted cosine inside), and from the back
  bsdf F_dielectric alone;
* **specular transmission** (spec_trans > 0: the surface is an interface, both sides scatter): sqrt(base) bsdf
  (1 - F_dielectric) D G eta_p² |wo·h| |wi·h| / (cos θ_o |cos θ_i| (wo·h + eta_p wi·h)²), eta_p the IOR across over
  the IOR on wo's side: the BSDF for importance, radiance is further scaled by 1 / eta_p² (:func:`camera_scale`);
* **clearcoat** (front only): Mitsuba's modified GTR1 lobe, 0.25 clearcoat Schlick_0.04(wo·h) D_GTR1(h) G_cc, with
  α = lerp(0.1, 0.001, clearcoat_gloss) and G_cc Smith's GGX shadowing at α = 0.25 — no 1 / (4 cos θ_o cos θ_i),
  as in Mitsuba (its value is f cos θ_i = that times cos θ_i);
* **diffuse** (front only): brdf base / π ((1 - F_o / 2)(1 - F_i / 2) + R_r (F_o + F_i + F_o F_i (R_r - 1))),
  F_x = (1 - cos θ_x)⁵ and R_r = 2 r (wi·h)² the retro-reflection; with flatness, lerp to Hanrahan-Krueger's
  fake subsurface 1.25 (F_ss (1 / (cos θ_o + cos θ_i) - 1/2) + 1/2), F_ss = lerp(1, R_r / 2, F_o) lerp(1, R_r / 2, F_i);
* **sheen** (front, with the diffuse lobe): sheen (1 - metallic) (1 - wi·h)⁵ lerp(1, c_tint, sheen_tint).

Sampling (numbers dim, dim + 1, dim + 2): a visible normal m of the specular lobe from wo is drawn first (dim + 1,
dim + 2), F_dielectric(wo·m) fixes the lobes' probabilities (front: specular srate (1 - bsdf (1 - F)), transmission
srate bsdf (1 - F), clearcoat 0.25 clearcoat srate, diffuse brdf srate; back: F and 1 - F), and number dim picks
one: reflection or refraction about m, a GTR1 normal (no visible-normal sampling, as Mitsuba) or a cosine-weighted
direction, each on the numbers dim + 1, dim + 2.  The density :func:`eval_pdf` returns is Mitsuba's: the mixture
with the lobes' probabilities taken at the half vector of wo and wi, which is the density of the procedure above
exactly where those probabilities do not depend on F (front side and spec_trans = 0); elsewhere it is Mitsuba's
approximation, kept so that images agree with Mitsuba's.  The weight is f |cos θ_i| over that density.

Directions on the wrong side of the geometric surface for their lobe are refused (as :mod:`.roughdielectric`).
Flags ``DIFFUSE_REFLECTION | GLOSSY_REFLECTION`` (and ``GLOSSY_TRANSMISSION`` for a material with spec_trans > 0
and metallic < 1, set per row by the material table; a material whose metallic or spec_trans is the number 1 has no
diffuse or sheen lobe, brdf = 0, and loses ``DIFFUSE_REFLECTION``: a principled glass or metal, which every photon
method passes by sampling as it passes roughdielectric and roughconductor).  Which photon methods render one beside
a diffuse lobe: api.check_bsdfs.
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import PRINCIPLED, PRINCIPLED_PARAMS
from . import microfacet as mf
from .flags import ALL_LOBES, DIFFUSE_PART, DIFFUSE_REFLECTION, GLOSSY_PART, GLOSSY_REFLECTION, GLOSSY_TRANSMISSION
from .optics import fresnel_dielectric
from . import textures
from .flags import TEXTURED
from .roughconductor import roughness
from .textures import colour
from ..features import has

KIND = PRINCIPLED
FLAGS = DIFFUSE_REFLECTION | GLOSSY_REFLECTION
INV_PI = 1.0 / math.pi
#: Mitsuba's luminance of linear sRGB.
LUM = (0.212671, 0.715160, 0.072169)

# The material table's ``coating`` columns of a principled row (its other parameters: rgb base_color, eta, alpha
# and alpha_v the specular lobe's roughness, GGX).
ROUGH, METALLIC, SPEC_TRANS, SPEC_TINT, SHEEN, SHEEN_TINT, CLEARCOAT, CC_ALPHA, FLATNESS, SPEC_RATE, CC_RATE, \
    DIFF_RATE = range(12)
#: anisotropic's column (read where a texture gives it or the roughness; the constant case is in alpha, alpha_v).
ANISO = textures.ANISO
#: Mitsuba's parameter names, in column order, and their defaults.
PARAMS = PRINCIPLED_PARAMS
#: Each parameter's column, by Mitsuba's name (textures.param_texture's columns PARAM + column).
COLUMN = {**{k: i for i, k in enumerate(PARAMS)}, "anisotropic": ANISO}


def row(params: dict) -> list[float]:
    """The ``coating`` columns of a principled material with Mitsuba's ``params`` (clearcoat_gloss as its GTR1 α)."""
    out = [float(params.get(k, v)) for k, v in PARAMS.items()] + [float(params.get("anisotropic", 0.0))]
    out[CC_ALPHA] = gloss_alpha(out[CC_ALPHA])
    return out


@kernel(inline=True)
def gloss_alpha(g):
    """The clearcoat's GTR1 α for clearcoat_gloss g (Mitsuba's lerp(0.1, 0.001, g))."""
    return 0.1 * (1.0 - g) + 0.001 * g


@kernel
def params(mats, m, uv):
    """Material m's scalar parameters at surface coordinates uv, a tuple by the ``coating`` columns (this module's
    and :mod:`.principledthin`'s): each its texture's eval_1 there (:func:`.textures.param`) or the constant."""
    c = mats.coating[m]
    if not has(mats, TEXTURED):
        return (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], c[13], c[14], c[15],
                c[16])
    cc = c[CC_ALPHA]
    if mats.param_texture[m, textures.PARAM + CC_ALPHA] >= 0:   # a texture gives clearcoat_gloss
        cc = gloss_alpha(textures.param(mats, m, CC_ALPHA, uv))
    q = textures.param
    return (q(mats, m, 0, uv), q(mats, m, 1, uv), q(mats, m, 2, uv), q(mats, m, 3, uv), q(mats, m, 4, uv),
            q(mats, m, 5, uv), q(mats, m, 6, uv), cc, q(mats, m, 8, uv), c[9], c[10], c[11], q(mats, m, 12, uv),
            q(mats, m, 13, uv), q(mats, m, 14, uv), c[15], c[16])


@kernel(inline=True)
def dist_params(roughness, anisotropic):
    """GGX's (α_u, α_v) for Disney's roughness and anisotropic (Mitsuba's ``calc_dist_params``; anisotropic 0 gives
    roughness² twice, as its isotropic case), each at least 0.001."""
    r2 = roughness * roughness
    a = math.sqrt(1.0 - 0.9 * anisotropic)
    return max(0.001, r2 / a), max(0.001, r2 * a)


@kernel(inline=True)
def alphas(mats, m, p, uv):
    """(distribution, α_u, α_v) of material m's specular lobe: from its roughness and anisotropic ``p`` where a texture
    gives either, else the table's constants."""
    if has(mats, TEXTURED) and (mats.param_texture[m, textures.PARAM + ROUGH] >= 0 or
                                mats.param_texture[m, textures.PARAM + ANISO] >= 0):
        au, av = dist_params(p[ROUGH], p[ANISO])
        return mats.distribution[m], au, av
    return roughness(mats, m, uv)


@kernel(inline=True)
def schlick_weight(c):
    """(1 - c)⁵, c clipped to [0, 1]."""
    x = min(max(1.0 - c, 0.0), 1.0)
    x2 = x * x
    return x2 * x2 * x


@kernel(inline=True)
def retro_diffuse(p, co, ci, cd):
    """Disney's diffuse shape with its retro-reflection, blended by ``flatness`` towards its fake subsurface term
    (Mitsuba's): the factor of base / π in the diffuse reflection of both principled BSDFs.  co, ci: the cosines of
    the two directions; cd = h · wi; ``p`` a row of the parameters (ROUGH, FLATNESS)."""
    fo = schlick_weight(ci)
    fi = schlick_weight(co)
    rr = 2.0 * p[ROUGH] * cd * cd
    lam = (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo) + rr * (fo + fi + fo * fi * (rr - 1.0))
    if p[FLATNESS] != 0.0:
        f90 = 0.5 * rr
        fss = (1.0 + (f90 - 1.0) * fo) * (1.0 + (f90 - 1.0) * fi)
        ss = 1.25 * (fss * (1.0 / (co + ci) - 0.5) + 0.5)
        lam = lam + p[FLATNESS] * (ss - lam)
    return lam


@kernel
def schlick(r0, c, eta):
    """Schlick's Fresnel with normal reflectance r0 at cosine c to the microfacet (negative: from inside), relative IOR
    eta, as Mitsuba's ``calc_schlick``: at |c| when the IOR across over the IOR on c's side exceeds 1, else at the
    refracted cosine (0 beyond the critical angle, so 1)."""
    eta_it = eta if c >= 0.0 else 1.0 / eta
    eta_ti = 1.0 / eta_it
    ct2 = 1.0 - (1.0 - c * c) * eta_ti * eta_ti
    ct = math.sqrt(max(ct2, 0.0))
    w = schlick_weight(abs(c)) if eta_it > 1.0 else schlick_weight(ct)
    return r0 + (1.0 - r0) * w


@kernel(inline=True)
def fresnel(c, eta):
    """The dielectric Fresnel reflectance at cosine c to the microfacet from either side (c < 0: from inside) and
    the signed cosine of the refracted direction (Mitsuba's ``fresnel``): (F, cos_t, eta crossed)."""
    if c >= 0.0:
        F, ct = fresnel_dielectric(c, eta)
        return F, -ct, eta
    F, ct = fresnel_dielectric(-c, 1.0 / eta)
    return F, ct, 1.0 / eta


@kernel(inline=True)
def tint(base):
    """(base / luminance, luminance): the colour of a tint, white where the base is black."""
    lum = vec.dot(base, LUM)
    if lum > 0.0:
        return vec.mul(base, 1.0 / lum), lum
    return (1.0, 1.0, 1.0), lum


@kernel
def spec_fresnel(p, base, F, c, front, eta):
    """Disney's Fresnel of the specular reflection (module docstring) at cosine c to the microfacet, RGB; ``p`` the
    row's columns."""
    metallic, spec_tint = p[METALLIC], p[SPEC_TINT]
    bsdf = (1.0 - metallic) * p[SPEC_TRANS]
    if not front:
        return (bsdf * F, bsdf * F, bsdf * F)
    out = (0.0, 0.0, 0.0)
    if metallic != 0.0:
        out = vec.mul((schlick(base[0], c, eta), schlick(base[1], c, eta), schlick(base[2], c, eta)), metallic)
    if spec_tint != 0.0:
        ct, _ = tint(base)
        e = eta if c >= 0.0 else 1.0 / eta
        r0 = (e - 1.0) / (e + 1.0)
        r0 = r0 * r0
        k = (1.0 - metallic) * spec_tint
        out = vec.add(out, vec.mul((schlick(ct[0] * r0, c, eta), schlick(ct[1] * r0, c, eta),
                                    schlick(ct[2] * r0, c, eta)), k))
    d = (1.0 - metallic) * (1.0 - spec_tint) * F
    return (out[0] + d, out[1] + d, out[2] + d)


@kernel(inline=True)
def gtr1(alpha, c):
    """Burley's GTR1 distribution at cos θ_h = c (0 where it is negligible, as Mitsuba)."""
    a2 = alpha * alpha
    r = (a2 - 1.0) / (math.pi * math.log(a2) * (1.0 + (a2 - 1.0) * c * c))
    return r if r * c > 1e-20 else 0.0


@kernel(inline=True)
def ggx_g1_fixed(v, h, alpha):
    """Smith's isotropic GGX shadowing of v for microfacet h at roughness alpha (the clearcoat's G_cc factors)."""
    if vec.dot(v, h) * v[2] <= 0.0:
        return 0.0
    if v[2] == 1.0:
        return 1.0
    c2 = v[2] * v[2]
    t2 = (1.0 - c2) / c2
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * t2))


@kernel(inline=True)
def compatible(h, wo, wi, front, reflection):
    """Mitsuba's macro-micro compatibility: wo on the microfacet's side (h turned to wo's side of the surface), wi on
    it for a reflection, on the other for a refraction."""
    s = 1.0 if front else -1.0
    a = vec.dot(wo, h) * s > 0.0
    b = vec.dot(wi, h) * s
    return a and (b > 0.0 if reflection else b < 0.0)


@kernel(inline=True)
def half_vector(wo, wi, eta):
    """(h turned up, reflect, eta_p): the generalised half vector of wo and wi (local), whether they are on one side."""
    reflect = wo[2] * wi[2] > 0.0
    eta_p = eta if wo[2] > 0.0 else 1.0 / eta
    e = 1.0 if reflect else eta_p
    h = vec.normalize((wo[0] + e * wi[0], wo[1] + e * wi[1], wo[2] + e * wi[2]))
    if h[2] < 0.0:
        h = vec.neg(h)
    return h, reflect, eta_p


@kernel
def probabilities(p, F, front):
    """The lobes' sampling probabilities (diffuse, clearcoat, transmission, specular) given F_dielectric."""
    bsdf = (1.0 - p[METALLIC]) * p[SPEC_TRANS]
    brdf = (1.0 - p[METALLIC]) * (1.0 - p[SPEC_TRANS])
    if front:
        ps = p[SPEC_RATE] * (1.0 - bsdf * (1.0 - F))
        pt = p[SPEC_RATE] * bsdf * (1.0 - F) if p[SPEC_TRANS] != 0.0 else 0.0
        pc = 0.25 * p[CLEARCOAT] * p[CC_RATE]
        pd = brdf * p[DIFF_RATE]
    else:
        ps = F
        pt = 1.0 - F if p[SPEC_TRANS] != 0.0 else 0.0
        pc = 0.0
        pd = 0.0
    inv = 1.0 / (ps + pt + pc + pd)
    return pd * inv, pc * inv, pt * inv, ps * inv


@kernel
def local_eval(mats, m, wo, wi, uv, part=ALL_LOBES):
    """(f RGB, density) towards the local direction wi from wo (cos θ_o != 0), Mitsuba's ``eval`` over |cos θ_i| and
    its ``pdf`` (module docstring); the base colour read at uv.  ``part`` (:data:`.flags.ALL_LOBES`): the diffuse
    lobes (diffuse and sheen) or the glossy ones (specular reflection and transmission, clearcoat) alone, f and the
    density of sampling one of them and wi."""
    p = params(mats, m, uv)
    dist, au, av = alphas(mats, m, p, uv)
    eta = mats.eta[m]
    base = colour(mats, m, uv)
    metallic, spec_trans = p[METALLIC], p[SPEC_TRANS]
    brdf = (1.0 - metallic) * (1.0 - spec_trans)
    bsdf = (1.0 - metallic) * spec_trans
    front = wo[2] > 0.0
    h, reflect, eta_p = half_vector(wo, wi, eta)
    co = abs(wo[2])
    ci = abs(wi[2])
    zero = (0.0, 0.0, 0.0)
    if wi[2] == 0.0 or co == 0.0:
        return zero, 0.0
    c = vec.dot(wo, h)
    F, _, _ = fresnel(c, eta)
    comp_r = reflect and compatible(h, wo, wi, front, True)
    comp_t = (not reflect) and compatible(h, wo, wi, front, False)
    wo_up = wo if front else vec.neg(wo)
    D = mf.D_uv(dist, au, av, h)
    G = mf.smith_g1_uv(dist, au, av, wo, h) * mf.smith_g1_uv(dist, au, av, wi, h)
    f = zero
    glossy, diffuse = part != DIFFUSE_PART, part != GLOSSY_PART
    if comp_r and F > 0.0 and glossy:
        f = vec.mul(spec_fresnel(p, base, F, c, front, eta), D * G / (4.0 * co * ci))
    if spec_trans != 0.0 and bsdf > 0.0 and comp_t and F < 1.0 and glossy:
        den = c + eta_p * vec.dot(wi, h)
        t = bsdf * abs((1.0 - F) * D * G * eta_p * eta_p * c * vec.dot(wi, h) / (wo[2] * den * den)) / ci
        f = vec.add(f, vec.mul((math.sqrt(base[0]), math.sqrt(base[1]), math.sqrt(base[2])), t))
    if p[CLEARCOAT] > 0.0 and comp_r and front and glossy:
        fcc = schlick(0.04, c, eta)
        g = ggx_g1_fixed(wo, h, 0.25) * ggx_g1_fixed(wi, h, 0.25)
        v = p[CLEARCOAT] * 0.25 * fcc * gtr1(p[CC_ALPHA], h[2]) * g
        f = vec.add(f, (v, v, v))
    if brdf > 0.0 and reflect and front and diffuse:
        cd = vec.dot(h, wi)
        lam = retro_diffuse(p, co, ci, cd)
        f = vec.add(f, vec.mul(base, brdf * INV_PI * lam))
        if p[SHEEN] > 0.0 and 1.0 - metallic > 0.0:
            k = p[SHEEN] * (1.0 - metallic) * schlick_weight(abs(cd))
            if p[SHEEN_TINT] != 0.0:
                ct, _ = tint(base)
                st = p[SHEEN_TINT]
                f = vec.add(f, vec.mul((1.0 + st * (ct[0] - 1.0), 1.0 + st * (ct[1] - 1.0), 1.0 + st * (ct[2] - 1.0)), k))
            else:
                f = vec.add(f, (k, k, k))
    # the density
    pd, pc, pt, ps = probabilities(p, F, front)
    wh = vec.dot(wi, h)
    if spec_trans != 0.0 and not reflect:
        den = c + eta_p * wh
        jac = abs(eta_p * eta_p * wh / (den * den))
    else:
        jac = abs(1.0 / (4.0 * wh))
    pm = D * mf.smith_g1_uv(dist, au, av, wo_up, h) * abs(vec.dot(wo_up, h)) / wo_up[2]
    pdf = 0.0
    if comp_r and glossy:
        pdf += ps * pm * jac
    if reflect and diffuse:
        pdf += pd * wi[2] * INV_PI
    if spec_trans != 0.0 and comp_t and glossy:
        pdf += pt * pm * jac
    if p[CLEARCOAT] != 0.0 and comp_r and glossy:
        pdf += pc * h[2] * gtr1(p[CC_ALPHA], h[2]) * jac
    return f, pdf


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """See :func:`caustica.bsdfs.sample` and the module's docstring: ``eta`` the relative IOR crossed by a
    refraction (1 otherwise); the weight leaves a refraction's 1 / eta² to the camera path."""
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
    s, t, wo = mf.shading_frame(ns, d, uv)   # about the front shading normal where the surface transmits
    zero = (0.0, 0.0, 0.0)
    p = params(mats, m, uv)
    front = wo[2] > 0.0
    bsdf = (1.0 - p[METALLIC]) * p[SPEC_TRANS]
    if wo[2] == 0.0 or not (front or bsdf > 0.0):
        return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, dim + 3
    dist, au, av = alphas(mats, m, p, uv)
    u0, u1, u2 = uniform(key, dim), uniform(key, dim + 1), uniform(key, dim + 2)
    sign = 1.0 if front else -1.0
    hm = mf.sample_visible_uv(dist, au, av, vec.mul(wo, sign), u1, u2)
    c = vec.dot(wo, hm)
    F, cos_t, eta_it = fresnel(c, mats.eta[m])
    pd, pc, pt, _ = probabilities(p, F, front)
    if u >= 0.0:   # the glossy lobes follow the diffuse one in the choice
        u0 = pd + u * (1.0 - pd)
    eta_out = 1.0
    if u0 < pd:
        wl = square_to_cosine_hemisphere(u1, u2)
        lobe = DIFFUSE_REFLECTION
        ok = wo[2] * wl[2] > 0.0
    elif u0 < pd + pc:
        phi = 2.0 * math.pi * u1
        a2 = p[CC_ALPHA] * p[CC_ALPHA]
        c2 = (1.0 - a2 ** (1.0 - u2)) / (1.0 - a2)
        st_ = math.sqrt(max(0.0, 1.0 - c2))
        hc = (math.cos(phi) * st_, math.sin(phi) * st_, math.sqrt(max(0.0, c2)))
        wl = mf.reflect(wo, hc, vec.dot(wo, hc))
        lobe = GLOSSY_REFLECTION
        ok = wo[2] * wl[2] > 0.0 and compatible(hc, wo, wl, front, True)
    elif u0 < pd + pc + pt:
        e = 1.0 / eta_it
        k = c * e + cos_t
        wl = (hm[0] * k - wo[0] * e, hm[1] * k - wo[1] * e, hm[2] * k - wo[2] * e)
        lobe = GLOSSY_TRANSMISSION
        eta_out = eta_it
        ok = wo[2] * wl[2] < 0.0 and compatible(hm, wo, wl, front, False)
    else:
        wl = mf.reflect(wo, hm, c)
        lobe = GLOSSY_REFLECTION
        ok = wo[2] * wl[2] > 0.0 and compatible(hm, wo, wl, front, True)
    wi = vec.from_local(s, t, ns, wl)
    # the geometric surface: a reflection leaves on wo's side of it, a refraction on the other
    across = vec.dot(wi, ng) * vec.dot(d, ng)
    if not (ok and (across > 0.0 if lobe == GLOSSY_TRANSMISSION else across < 0.0)):
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    f, pdf = local_eval(mats, m, wo, wl, uv)
    if not pdf > 0.0:
        return False, wi, zero, 0.0, lobe, 1.0, dim + 3
    return True, wi, vec.mul(f, abs(wl[2]) / pdf), pdf, lobe, eta_out, dim + 3


@kernel(inline=True)
def local_pair(d, ng, ns, uv, wi):
    """(valid, wo, wl): the camera-side direction -d and wi in the shading frame about ns (:func:`mf.shading_frame`),
    valid unless either is grazing or wi lies on the wrong side of the geometric surface for the lobe (reflection or
    transmission) its shading-frame side says; both principled BSDFs evaluate there."""
    s, t, wo = mf.shading_frame(ns, d, uv)   # about the front shading normal where the surface transmits
    wl = mf.to_local(s, t, ns, wi)
    if wo[2] == 0.0 or wl[2] == 0.0:
        return False, wo, wl
    return (vec.dot(wi, ng) * vec.dot(d, ng) < 0.0) == (wo[2] * wl[2] > 0.0), wo, wl


@kernel(inline=True)
def paired_eval(local_eval, mats, m, frame, uv, wi, part):
    """(RGB f, 1, density) of ``local_eval`` (this module's or :mod:`.principledthin`'s, lobes ``part``) at the pair of
    :func:`local_pair`, ``frame`` = (d, ng, ns); zero on the wrong side of the geometric surface for the lobe wi would
    come from."""
    d, ng, ns = frame
    ok, wo, wl = local_pair(d, ng, ns, uv, wi)
    if not ok:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    f, pdf = local_eval(mats, m, wo, wl, uv, part)
    return f, 1.0, pdf


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f towards wi as (RGB f, 1) and :func:`sample`'s density of wi (Mitsuba's ``pdf``); zero on the wrong side of
    the geometric surface for the lobe wi would come from."""
    return paired_eval(local_eval, mats, m, (d, ng, ns), uv, wi, ALL_LOBES)


@kernel
def eval_part(mats, m, d, ng, ns, uv, wi, part):
    """:func:`eval_pdf` of the lobes ``part`` names alone (:func:`local_eval`)."""
    return paired_eval(local_eval, mats, m, (d, ng, ns), uv, wi, part)


@kernel
def glossy_share(mats, m, d, ns, uv):
    """The probability that :func:`sample` picks a glossy lobe (specular reflection or transmission, clearcoat) from
    -d: 1 - the diffuse lobe's probability on the front, where it does not depend on the sampled microfacet; 1 from
    the back, which has no diffuse lobe."""
    if vec.dot(d, ns) >= 0.0:
        return 1.0
    pd, _, _, _ = probabilities(params(mats, m, uv), 0.0, True)
    return 1.0 - pd


@kernel
def glossy_albedo(mats, m, d, ns, uv):
    """(glossy, diffuse): about how much of the light from -d the glossy lobes and the diffuse one scatter, for
    :func:`caustica.bsdfs.glossy_pick`, luminances: the specular reflection's Fresnel at the macro-surface
    (:func:`spec_fresnel`), the transmission's (1 - metallic) spec_trans (1 - F), the clearcoat's 0.25 clearcoat F;
    the diffuse lobe's (1 - metallic) (1 - spec_trans) (1 - F) base.  Nothing from the back (no diffuse lobe)."""
    co = -vec.dot(d, ns)
    if co <= 0.0:
        return 1.0, 0.0
    p = params(mats, m, uv)
    base = colour(mats, m, uv)
    eta = mats.eta[m]
    F, _, _ = fresnel(co, eta)
    metallic, spec_trans = p[METALLIC], p[SPEC_TRANS]
    glossy = vec.dot(spec_fresnel(p, base, F, co, True, eta), LUM) + (1.0 - metallic) * spec_trans * (1.0 - F) + \
        0.25 * p[CLEARCOAT] * schlick(0.04, co, 1.5)
    return glossy, (1.0 - metallic) * (1.0 - spec_trans) * (1.0 - F) * vec.dot(base, LUM)


@kernel
def camera_scale(mats, m, d, ng, ns, wi):
    """1 / eta_p² towards a refracted wi (radiance's compression across the interface), else 1."""
    co = -vec.dot(d, ns)
    if co * vec.dot(wi, ns) >= 0.0:
        return 1.0
    eta = mats.eta[m] if co > 0.0 else 1.0 / mats.eta[m]
    return 1.0 / (eta * eta)
