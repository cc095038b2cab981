"""The scattering interface: every BSDF behind the same four functions, chosen by the material's kind.

A BSDF is one module here (``diffuse``, ``conductor``, ``dielectric``, ``thindielectric``, ``roughconductor``,
``roughdielectric``, ``plastic``, ``roughplastic``, ``pplastic``, ``principled``; the microfacet distribution the rough ones share is :mod:`.microfacet`) with its
``KIND`` (the code the loader writes into :class:`~caustica.scene.description.Material`), its ``FLAGS``
(:mod:`.flags`) and its kernels; the transport loops call only the functions below, and decide by flags, never by name:

* :func:`oriented` — which side of the surface scatters, and its normals turned towards the ray;
* :func:`sample` — a direction, the weight f |cos| / pdf, its density, the lobe it came from and the
  relative IOR crossed, and the path's dimension past the random numbers it used (no caller counts);
* :func:`eval_pdf` — f towards a given direction (a colour times a scalar, so next-event estimation
  keeps one multiplication order) and the density :func:`sample` would give it;
* :func:`splits_lobes`, :func:`glossy_share`, :func:`glossy_pick`, :func:`sample_glossy`, :func:`eval_part` — a BSDF's
  glossy lobes beside its diffuse ones taken
  apart, for the photon methods' camera paths (which follow a glossy lobe and gather photons on the diffuse ones);
* :func:`colour` — material m's colour at surface coordinates uv (its texture's, or ``rgb[m]``), which every
  BSDF and loop reads rather than ``rgb`` (:mod:`.textures`);
* :func:`resolve` — a mixture (``mask``, ``blendbsdf``: :mod:`.mixtures`) met by a ray becomes one of its parts (or
  no surface) with one random number, in :func:`caustica.transport.surface_interaction`, so the functions above
  never see one; :func:`pass_probability` is a surface's chance of letting a shadow ray through;
* :func:`null_transmission` — what passes straight on through a BSDF whose transmission is Mitsuba's ``Null`` lobe
  (``NULL_TRANSMISSION``, set on a copy of the table by :func:`null_transmitting`), for shadow rays;
* :func:`delta_branches` — for a BSDF with only delta lobes: both directions and the reflection
  probability, for the loops that follow both branches of glass (the photon-map gather) or add what
  each branch sees in expectation (the visible-point pass).

Adding a BSDF: write its module (``KIND``, ``FLAGS``, ``sample``, and ``eval_pdf`` for a smooth one or
``delta_branches`` for a delta one; with glossy lobes beside a diffuse one also ``glossy_share``,
``glossy_albedo``, ``sample_glossy`` and ``eval_part``, for :func:`splits_lobes`), add it to :data:`BSDFS` and one
line to each dispatch function below (``if has(mats, FOO) and kind == FOO:``, so scenes without it compile none of
its code: :mod:`caustica.features`), and read its parameters in the scene loader (``scene/xml_loader.py``);
docs/architecture.md walks through it.  ``sample`` returns ``(ok, wi, weight, pdf, lobe, eta, dim)``: ``pdf`` is 0 for a
delta lobe, ``eta`` 1 unless the lobe transmits.  Radiance carried through a refraction is further
scaled by 1 / eta² (solid-angle compression); camera paths apply it, photons (importance) do not; for
:func:`eval_pdf`'s f towards a refracted direction :func:`camera_scale` gives that factor.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry import vec
from ..features import bits, guarded_by, has, specialisable
from ..jit import kernel
from ..scene.description import CONDUCTOR, DIELECTRIC, DIFFUSE, MIXTURES, PLASTIC, PPLASTIC, PRINCIPLED, \
    PRINCIPLEDTHIN, ROUGHCONDUCTOR, ROUGHDIELECTRIC, ROUGHPLASTIC, THINDIELECTRIC, WRAPPERS, SceneDescription
from . import conductor, dielectric, diffuse, microfacet, plastic, pplastic, principled, principledthin, \
    roughconductor, roughdielectric, roughplastic, thindielectric
from .textures import albedo_mean, attribute_table, colour, mitsuba_mean, texture_columns  # noqa: F401  (part of the interface)
from .textures import ALPHA_U, ALPHA_V, ANISO, PARAM
from .mixtures import mixture_columns, pass_probability, resolve  # noqa: F401  (part of the interface)
from .perturb import gather_shading, perturbed_normal, photon_shading, terminator, wrapped  # noqa: F401  (part of the interface)
from ..scene.description import BLEND, BUMPMAP, MASK, NORMALMAP
from .flags import ALL_LOBES, ANISOTROPIC, DELTA, DELTA_REFLECTION, DELTA_TRANSMISSION, DIFFUSE_LOBES, DIFFUSE_PART, \
    DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GLOSSY, GLOSSY_PART, GLOSSY_REFLECTION, GLOSSY_LOBES, \
    GLOSSY_TRANSMISSION, NARROW_ALPHA, NARROW_GLOSSY, NULL_TRANSMISSION, SMOOTH, TEXTURED, TRANSMISSION  # noqa: F401

#: kind code -> module; a kind not listed here (NULL) has no BSDF: rays cross it (caustica.transport).
BSDFS = {DIFFUSE: diffuse, CONDUCTOR: conductor, DIELECTRIC: dielectric, ROUGHCONDUCTOR: roughconductor,
         ROUGHDIELECTRIC: roughdielectric, PLASTIC: plastic, ROUGHPLASTIC: roughplastic, THINDIELECTRIC: thindielectric,
         PPLASTIC: pplastic, PRINCIPLED: principled, PRINCIPLEDTHIN: principledthin}


@specialisable
class MaterialTable(NamedTuple):
    kind: np.ndarray       # int32[M]: the BSDF's KIND (or NULL)
    flags: np.ndarray      # int32[M]: its FLAGS (0 for NULL)
    rgb: np.ndarray        # float64[M, 3]: reflectance (diffuse, a plastic's base), specular reflectance
    #                        (conductor), specular transmittance (glass; its specular reflectance is in ``coating``)
    eta: np.ndarray        # float64[M]: int_ior / ext_ior (dielectric, thindielectric, roughdielectric, a plastic's
    #                        coating)
    twosided: np.ndarray   # int8[M]: 1 when both sides scatter
    albedo_mean: np.ndarray  # float64[M]: mean of rgb (read by no kernel since photon roulette takes the weight)
    distribution: np.ndarray  # int32[M]: microfacet distribution (BECKMANN, GGX; rough BSDFs)
    alpha: np.ndarray      # float64[M]: microfacet roughness (rough BSDFs); alpha_u where anisotropic
    alpha_v: np.ndarray    # float64[M]: the roughness across dp/du (= alpha where isotropic; microfacet.shading_frame)
    fresnel: np.ndarray    # int8[M]: 1 when a conductor has a complex IOR (cond_eta + i cond_k), 0: F = 1
    cond_eta: np.ndarray   # float64[M, 3]: a conductor's IOR, real part (RGB)
    cond_k: np.ndarray     # float64[M, 3]: a conductor's IOR, imaginary part (RGB)
    coating: np.ndarray    # float64[M, plastic.COATING_COLUMNS]: a plastic's parameters (specular_reflectance,
    #                        sampling weight, Fdr, nonlinear, a rough coating's transmittance table; plastic.py);
    #                        a pplastic's specular_reflectance and sampling weight; a principled's parameters
    #                        (principled.py)
    # Textures (bsdfs/textures.py), X of them: the one giving material m's rgb, and each texture's columns.
    texture: np.ndarray    # int32[M]: the texture that gives rgb at each surface point, -1 for none
    tex_int: np.ndarray    # int64[X, 6]: kind, filter, wrap mode, a bitmap's width, height, first row in texels
    tex_float: np.ndarray  # float64[X, 12]: to_uv (2 x 3, row by row), a checkerboard's color0, color1
    texels: np.ndarray     # float32[N, 3]: every bitmap's linear RGB texels, row by row
    # Mixtures (mask, blendbsdf; bsdfs/mixtures.py): resolved at the hit to one of their nested materials.
    mix_texture: np.ndarray   # int32[M]: the texture giving a mixture's opacity or weight (mixtures.weight), -1: none
    param_texture: np.ndarray  # int32[M, 2 + P]: the textures giving a rough BSDF's alpha_u, alpha_v (their eval_1 at
    #                            the surface point, at least ALPHA_MIN; microfacet roughness), -1: alpha, alpha_v above;
    #                            then those giving the scalar parameters in ``coating`` (a principled's; textures.param)
    mix: np.ndarray        # float64[M]: a mask's opacity, a blend's weight of nested[m, 1]
    nested: np.ndarray     # int32[M, 2]: a mixture's or wrapper's nested materials (-1: none)
    # Wrappers (normalmap, bumpmap; bsdfs/perturb.py): resolved at the hit to nested[m, 0] with a perturbed ns; their
    # map is mix_texture[m], a bump map's scale mix[m].
    terminator: np.ndarray  # int8[M]: 1 on a wrapper's nested row: f carries Mitsuba's bump-terminator shadowing
    wrapped: np.ndarray    # int8[M]: 1 on a wrapper's nested row (its ns perturbed), with the shadowing or without
    attr: np.ndarray       # float32[K, T, 9]: mesh attributes at each triangle's corners (textures.attribute_table)


def build_material_table(desc: SceneDescription) -> MaterialTable:
    m = max(1, len(desc.materials))
    kind = np.zeros(m, np.int32)
    flags = np.full(m, diffuse.FLAGS, np.int32)
    rgb = np.full((m, 3), 0.5)
    eta = np.ones(m)
    twosided = np.zeros(m, np.int8)
    distribution, alpha, alpha_v = np.zeros(m, np.int32), np.zeros(m), np.zeros(m)
    fresnel, cond_eta, cond_k = np.zeros(m, np.int8), np.ones((m, 3)), np.zeros((m, 3))
    coating = np.zeros((m, plastic.COATING_COLUMNS))
    coatings = {}    # (distribution, alpha, eta) -> a rough coating's tables, computed once
    params = [{} for _ in range(m)]   # per material: coating column -> the texture giving it (a principled's)
    for i, mat in enumerate(desc.materials):
        kind[i] = mat.kind
        flags[i] = BSDFS[mat.kind].FLAGS if mat.kind in BSDFS else 0   # a mixture's or wrapper's: below
        rgb[i] = mat.rgb
        eta[i] = mat.int_ior / mat.ext_ior
        twosided[i] = 1 if mat.twosided else 0
        distribution[i], alpha[i] = mat.distribution, max(mat.alpha, microfacet.ALPHA_MIN)
        alpha_v[i] = max(mat.alpha_v, microfacet.ALPHA_MIN) if mat.alpha_v is not None else alpha[i]
        if mat.conductor_eta is not None:
            fresnel[i], cond_eta[i], cond_k[i] = 1, mat.conductor_eta, mat.conductor_k
        if mat.kind in (PRINCIPLED, PRINCIPLEDTHIN):
            module = principled if mat.kind == PRINCIPLED else principledthin
            values = module.row(mat.principled)
            coating[i, :len(values)] = values
            params[i] = {module.COLUMN[p]: tex for p, tex in mat.param_textures.items()}
            textured = {principled.COLUMN[p] for p in mat.param_textures} if mat.kind == PRINCIPLED else set()
            if (coating[i, principled.SPEC_TRANS] != 0.0 or principled.SPEC_TRANS in textured) and \
                    (coating[i, principled.METALLIC] < 1.0 or principled.METALLIC in textured):
                flags[i] |= GLOSSY_TRANSMISSION   # an interface: both sides scatter
            if mat.kind == PRINCIPLED and any(c not in textured and coating[i, c] == 1.0
                                              for c in (principled.METALLIC, principled.SPEC_TRANS)):
                flags[i] &= ~DIFFUSE_REFLECTION   # metallic or spec_trans 1: no diffuse or sheen lobe (glossy only)
            if narrowest_glossy_alpha(mat, float(alpha[i]), float(alpha_v[i])) < NARROW_ALPHA or \
                    flags[i] & GLOSSY_TRANSMISSION and flags[i] & DIFFUSE_REFLECTION and transmits_glossily(mat):
                flags[i] |= NARROW_GLOSSY   # (a glossy transmission: taken apart however broad; flags.NARROW_GLOSSY)
        if mat.kind == PPLASTIC and alpha[i] < NARROW_ALPHA:
            flags[i] |= NARROW_GLOSSY
        if mat.kind in (DIELECTRIC, ROUGHDIELECTRIC, THINDIELECTRIC):   # specular_reflectance (dielectric.tints)
            coating[i, plastic.SPEC:plastic.SPEC + 3] = mat.specular
        if mat.kind in (PLASTIC, ROUGHPLASTIC, PPLASTIC):
            row = coating[i]
            row[plastic.SPEC:plastic.SPEC + 3] = mat.specular
            row[plastic.SPEC_WEIGHT] = plastic.specular_sampling_weight(
                mat.rgb, mat.specular, None if mat.texture is None else mitsuba_mean(mat.texture))
            row[plastic.NONLINEAR] = 1.0 if mat.nonlinear else 0.0
            if mat.kind == PLASTIC:
                row[plastic.INTERNAL] = plastic.fresnel_diffuse_reflectance(1.0 / eta[i])
            elif mat.kind == ROUGHPLASTIC:     # (a pplastic has no coating: no Fdr, no table)
                c = (int(distribution[i]), float(alpha[i]), float(eta[i]))
                if c not in coatings:
                    coatings[c] = roughplastic.coating_tables(*c)
                row[plastic.TABLE:], row[plastic.INTERNAL] = coatings[c]
    for i, mat in enumerate(desc.materials):   # a mixture's or wrapper's lobes are its parts' own rows' (a principled's
        if mat.kind in MIXTURES + WRAPPERS:    # set per row above; a mask's absence is no lobe: the loops never see it)
            flags[i] = 0
            for j in mat.nested:
                flags[i] |= flags[j] if desc.materials[j].kind in BSDFS else 0
    return MaterialTable(kind, flags, rgb, eta, twosided, rgb.mean(axis=1), distribution, alpha, alpha_v, fresnel,
                         cond_eta,
                         cond_k, coating, *texture_columns(desc.materials, params), *mixture_columns(desc.materials),
                         np.array([1 if m.terminator else 0 for m in desc.materials] or [0], np.int8),
                         wrapped_rows(desc, m), attribute_table(desc))


def narrowest_glossy_alpha(mat, alpha_u: float, alpha_v: float) -> float:
    """The smallest microfacet roughness a principled or principledthin material's reflecting glossy lobes may have:
    its (alpha_u, alpha_v) from roughness and anisotropic, principled's clearcoat lobe (alpha from 0.1 down to 0.001 as
    clearcoat_gloss goes to 1); 0 where roughness, anisotropic or clearcoat_gloss comes from a texture (any value may
    occur).  (A glossy transmission is taken apart whatever its roughness: :func:`transmits_glossily`.)"""
    p, textured = mat.principled, mat.param_textures
    if {"roughness", "anisotropic", "clearcoat_gloss"} & set(textured):
        return 0.0
    a = min(alpha_u, alpha_v)
    if mat.kind == PRINCIPLED and (p.get("clearcoat", 0.0) > 0.0 or "clearcoat" in textured):
        a = min(a, 0.1 + (0.001 - 0.1) * p.get("clearcoat_gloss", 0.0))
    return a


def transmits_glossily(mat) -> bool:
    """Whether a principled or principledthin material has a glossy transmission lobe: ``spec_trans`` above 0, or
    from a texture (principled's is also weighted by 1 - metallic: its flags say whether it transmits at all)."""
    return mat.principled.get("spec_trans", 0.0) > 0.0 or "spec_trans" in mat.param_textures


def wrapped_rows(desc: SceneDescription, m: int) -> np.ndarray:
    """int8[m]: 1 on each wrapper's nested row (the wrapper's own copy of its nested BSDF), 0 elsewhere."""
    out = np.zeros(m, np.int8)
    for mat in desc.materials:
        if mat.kind in WRAPPERS:
            out[mat.nested[0]] = 1
    return out


def material_features(mats: MaterialTable) -> int:
    """The feature bits (:mod:`caustica.features`) of table ``mats``: its kinds, TEXTURED, GLOSSY_LOBES, ANISOTROPIC."""
    textured = (mats.texture >= 0).any() or (mats.mix_texture >= 0).any() or (mats.param_texture >= 0).any()
    anisotropic = (mats.alpha_v != mats.alpha).any() or (mats.param_texture[:, ALPHA_U] !=
                                                         mats.param_texture[:, ALPHA_V]).any() or \
        (mats.param_texture[:, PARAM + ANISO] >= 0).any()
    return bits(*np.unique(mats.kind), *([TEXTURED] if textured else []),
                *([GLOSSY_LOBES] if (mats.flags & GLOSSY).any() else []),
                *([ANISOTROPIC] if anisotropic else []))


def null_transmitting(mats: MaterialTable) -> MaterialTable | None:
    """A copy of ``mats`` whose thindielectric rows carry ``NULL_TRANSMISSION`` (their straight-on lobe is Mitsuba's
    ``Null`` one, as its ``volpath`` integrator treats it), or None when no row is a thindielectric.  The scene's
    own table stays as it is (Mitsuba's ``path``: a crossing is a bounce).  A thindielectric
    inside a mask or blendbsdf is left as it is (a bounce, blocking shadow rays): :func:`pass_probability` does not
    add Mitsuba's share of its null transmission, and the camera paths and shadow rays must agree."""
    thin = mats.kind == THINDIELECTRIC
    mixtures = (mats.kind == MASK) | (mats.kind == BLEND)
    thin[mats.nested[mixtures][mats.nested[mixtures] >= 0]] = False
    if not thin.any():
        return None
    flags = mats.flags.copy()
    flags[thin] |= NULL_TRANSMISSION
    return mats._replace(flags=flags)


@guarded_by(THINDIELECTRIC)
@kernel(inline=True)
def has_null_lobe(mats, m):
    """Whether material m's straight-on lobe is a null event (a thindielectric flagged ``NULL_TRANSMISSION`` by
    :func:`null_transmitting`, volpath's): a path crosses it without a vertex and shadow rays pass it with 1 - R.
    Compiled away in a scene without a thindielectric."""
    return has(mats, THINDIELECTRIC) and mats.flags[m] & NULL_TRANSMISSION != 0


@kernel(inline=True)
def null_transmission(mats, m, d, ng, ns, uv):
    """Per channel, the share of a shadow ray along d (front normals ng, ns at the hit) that passes material m
    unscattered: :func:`caustica.bsdfs.thindielectric.null_transmission` (the only BSDF with such a lobe)."""
    return thindielectric.null_transmission(mats, m, d, ng, ns, uv)


@kernel(inline=True)
def oriented(mats, m, front, ng, ns):
    """(scatters, ng, ns) for a ray arriving on the front (``front``) or back of material m.

    A BSDF that transmits is an interface: both sides scatter and its normals stay on the front.
    The others reflect on the side the ray came from, normals turned to it; their back is black
    (``scatters`` False) unless the material is two-sided, as in Mitsuba.
    """
    if front or mats.flags[m] & TRANSMISSION:
        return True, ng, ns
    if mats.twosided[m] == 0:
        return False, ng, ns
    return True, vec.neg(ng), vec.neg(ns)


@kernel(inline=True)
def sample(mats, m, d, ng, ns, uv, key, dim):
    """Sample material m's BSDF for a ray travelling along d (normals from :func:`oriented`, surface coordinates
    uv for its textures), with numbers (key, dim, ...): (ok, wi, weight, pdf, lobe, eta, dim past the numbers
    used).  On a wrapper's nested row the weight carries the bump terminator's shadowing (:mod:`.perturb`)."""
    ok, wi, weight, pdf, lobe, eta, dim = sample_kind(mats, m, d, ng, ns, uv, key, dim)
    if (has(mats, NORMALMAP) or has(mats, BUMPMAP)) and mats.terminator[m]:
        weight = vec.mul(weight, terminator(ng, ns, wi))
    return ok, wi, weight, pdf, lobe, eta, dim


@kernel(inline=True)
def sample_kind(mats, m, d, ng, ns, uv, key, dim):
    """:func:`sample` by material m's kind."""
    kind = mats.kind[m]
    if has(mats, DIFFUSE) and kind == DIFFUSE:
        return diffuse.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, CONDUCTOR) and kind == CONDUCTOR:
        return conductor.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, ROUGHCONDUCTOR) and kind == ROUGHCONDUCTOR:
        return roughconductor.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, ROUGHDIELECTRIC) and kind == ROUGHDIELECTRIC:
        return roughdielectric.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, PLASTIC) and kind == PLASTIC:
        return plastic.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, ROUGHPLASTIC) and kind == ROUGHPLASTIC:
        return roughplastic.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        return pplastic.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, PRINCIPLED) and kind == PRINCIPLED:
        return principled.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, PRINCIPLEDTHIN) and kind == PRINCIPLEDTHIN:
        return principledthin.sample(mats, m, d, ng, ns, uv, key, dim)
    if has(mats, THINDIELECTRIC) and kind == THINDIELECTRIC:
        return thindielectric.sample(mats, m, d, ng, ns, uv, key, dim)
    return dielectric.sample(mats, m, d, ng, ns, uv, key, dim)


@kernel(inline=True)
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """Material m's BSDF from direction d towards wi: (colour, scale, pdf), f = colour · scale of its smooth lobes
    (0 for a delta lobe, which no direction given in advance can meet), pdf the solid-angle density with which
    :func:`sample` returns wi (its lobe choice included).  On a wrapper's nested row the scale carries the bump
    terminator's shadowing (:mod:`.perturb`)."""
    c, scale, pdf = eval_pdf_kind(mats, m, d, ng, ns, uv, wi)
    if (has(mats, NORMALMAP) or has(mats, BUMPMAP)) and mats.terminator[m]:
        scale *= terminator(ng, ns, wi)
    return c, scale, pdf


@kernel(inline=True)
def eval_radiance(mats, m, d, ng, ns, uv, wi):
    """(colour, scale): material m's f = colour · scale from d towards wi as a camera path (radiance) weighs what
    arrives from wi at a visible point that evaluates its BSDF: :func:`eval_pdf`'s f (the diffuse lobes' alone where
    glossy ones are beside them, :func:`splits_lobes`), times :func:`camera_scale` on the other side of a glossy
    transmission lobe (principled's spec_trans; 1 for principledthin, which does not refract), as pbrt-v4's SPPM
    evaluates f in radiance mode."""
    if splits_lobes(mats, m):
        c, scale, _ = eval_part(mats, m, d, ng, ns, uv, wi, DIFFUSE_PART)
    else:
        c, scale, _ = eval_pdf(mats, m, d, ng, ns, uv, wi)
    if mats.flags[m] & GLOSSY_TRANSMISSION:
        scale *= camera_scale(mats, m, d, ng, ns, wi)
    return c, scale


@kernel(inline=True)
def eval_photon(mats, m, d, ng, ns, uv, wi):
    """(colour, scale): material m's f = colour · scale from d towards wi as a visible point that evaluates its BSDF
    weighs a photon arriving from wi (:func:`eval_radiance`); on a wrapper's nested row the scale also carries
    |cos_s(wi)| / |cos_g(wi)| (:func:`caustica.bsdfs.perturb.gather_shading`), the shading cosine of Mitsuba's f."""
    c, scale = eval_radiance(mats, m, d, ng, ns, uv, wi)
    if wrapped(mats, m):
        scale *= gather_shading(ng, ns, wi)
    return c, scale


@kernel(inline=True)
def eval_pdf_kind(mats, m, d, ng, ns, uv, wi):
    """:func:`eval_pdf` by material m's kind."""
    kind = mats.kind[m]
    if has(mats, DIFFUSE) and kind == DIFFUSE:
        return diffuse.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, ROUGHCONDUCTOR) and kind == ROUGHCONDUCTOR:
        return roughconductor.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, ROUGHDIELECTRIC) and kind == ROUGHDIELECTRIC:
        return roughdielectric.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, PLASTIC) and kind == PLASTIC:
        return plastic.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, ROUGHPLASTIC) and kind == ROUGHPLASTIC:
        return roughplastic.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        return pplastic.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, PRINCIPLED) and kind == PRINCIPLED:
        return principled.eval_pdf(mats, m, d, ng, ns, uv, wi)
    if has(mats, PRINCIPLEDTHIN) and kind == PRINCIPLEDTHIN:
        return principledthin.eval_pdf(mats, m, d, ng, ns, uv, wi)
    return (0.0, 0.0, 0.0), 0.0, 0.0


@guarded_by(PPLASTIC, PRINCIPLED, PRINCIPLEDTHIN)
@kernel(inline=True)
def splits_lobes(mats, m):
    """Whether material m has glossy lobes beside diffuse ones that a camera path takes apart (pplastic, principledthin,
    and principled where metallic and spec_trans leave it a diffuse lobe; ``NARROW_GLOSSY``: some glossy lobe may be
    narrower than :data:`.flags.NARROW_ALPHA`, or transmits): it picks its glossy or its diffuse lobes
    (:func:`glossy_pick`), goes on by the glossy ones (:func:`sample_glossy`) and makes its visible point on a diffuse
    one, which then holds the diffuse lobes alone (:func:`eval_radiance`), so that no photon estimate goes through a
    narrow glossy lobe or across the surface (caustica.photons.visible_points).  Broader reflections stay in the
    visible point's estimate, weighed with the photons: the choice costs noise there.  Never in a scene without those
    kinds."""
    if not (has(mats, PPLASTIC) or has(mats, PRINCIPLED) or has(mats, PRINCIPLEDTHIN)):
        return False
    kind = mats.kind[m]
    flags = mats.flags[m]
    return (kind == PPLASTIC or kind == PRINCIPLED or kind == PRINCIPLEDTHIN) and flags & NARROW_GLOSSY != 0 and \
        flags & GLOSSY != 0 and flags & DIFFUSE_REFLECTION != 0


@kernel(inline=True)
def glossy_share(mats, m, d, ns, uv):
    """For a material that :func:`splits_lobes`, the probability P_G that :func:`sample` picks a glossy lobe for a ray
    along d: it does not depend on the numbers that make the direction, so a camera path that goes on only by a
    glossy lobe's sample takes that branch with probability P_G."""
    kind = mats.kind[m]
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        return pplastic.glossy_share(mats, m, d, ns, uv)
    if has(mats, PRINCIPLED) and kind == PRINCIPLED:
        return principled.glossy_share(mats, m, d, ns, uv)
    if has(mats, PRINCIPLEDTHIN):
        return principledthin.glossy_share(mats, m, d, ns, uv)
    return 0.0


@kernel(inline=True)
def glossy_pick(mats, m, d, ns, uv, P):
    """For a material that :func:`splits_lobes`, the probability Q with which a camera path takes its glossy lobes
    (:func:`caustica.photons.visible_points.lobe_choice`), P being :func:`glossy_share`: the mean of P and the glossy
    lobes' share of the light the BSDF scatters from -d (each module's ``glossy_albedo``).  A sampling rate alone
    (Mitsuba's: a plastic's by its reflectances, a principled's one half) sends most camera paths along a glossy lobe
    that carries a few per cent of the light, and the diffuse visible point's photons are then weighed by 1 / (1 - P);
    the share alone starves a narrow highlight (docs/results.md measures the three).  The mean keeps 1 / Q within
    2 / P and 1 / (1 - Q) within 2 / (1 - P); Q is P where P is 0 or 1."""
    if not (P > 0.0 and P < 1.0):
        return P
    kind = mats.kind[m]
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        g, dif = pplastic.glossy_albedo(mats, m, d, ns, uv)
    elif has(mats, PRINCIPLED) and kind == PRINCIPLED:
        g, dif = principled.glossy_albedo(mats, m, d, ns, uv)
    elif has(mats, PRINCIPLEDTHIN):
        g, dif = principledthin.glossy_albedo(mats, m, d, ns, uv)
    else:
        g, dif = 0.0, 0.0
    if not g + dif > 0.0:
        return P
    return 0.5 * (P + g / (g + dif))


@kernel(inline=True)
def sample_glossy(mats, m, d, ng, ns, uv, numbers, u):
    """:func:`sample` of the glossy lobes alone of a material that :func:`splits_lobes`: its density is
    :func:`eval_part`'s (``GLOSSY_PART``) over :func:`glossy_share`; u in [0, 1) picks among them as :func:`sample`'s
    first number would, the direction from numbers = (key, dim) on, as :func:`sample`'s."""
    kind = mats.kind[m]
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        return pplastic.sample_glossy(mats, m, d, ng, ns, uv, numbers, u)
    if has(mats, PRINCIPLED) and kind == PRINCIPLED:
        return principled.sample_glossy(mats, m, d, ng, ns, uv, numbers, u)
    if has(mats, PRINCIPLEDTHIN):
        return principledthin.sample_glossy(mats, m, d, ng, ns, uv, numbers, u)
    zero = (0.0, 0.0, 0.0)
    return False, zero, zero, 0.0, GLOSSY_REFLECTION, 1.0, numbers[1] + 3


@kernel(inline=True)
def held_lobes_transmit(mats, m):
    """Whether the lobes a visible point holds at material m (:func:`eval_radiance`'s) transmit, so that lights behind
    the surface light it: a transmitting BSDF's, but where it :func:`splits_lobes` only principledthin's (its diffuse
    transmission; a principled's diffuse lobe reflects only)."""
    if splits_lobes(mats, m):
        return has(mats, PRINCIPLEDTHIN) and mats.kind[m] == PRINCIPLEDTHIN
    return mats.flags[m] & GLOSSY_TRANSMISSION != 0


@kernel(inline=True)
def eval_part(mats, m, d, ng, ns, uv, wi, part):
    """:func:`eval_pdf` of a material that :func:`splits_lobes`, its diffuse or glossy lobes alone (``part``,
    :data:`.flags.DIFFUSE_PART` or :data:`.flags.GLOSSY_PART`): f and the density with which :func:`sample` picks
    one of those lobes and returns wi (so the two parts' densities add up to :func:`eval_pdf`'s)."""
    kind = mats.kind[m]
    if has(mats, PPLASTIC) and kind == PPLASTIC:
        c, scale, pdf = pplastic.eval_part(mats, m, d, ng, ns, uv, wi, part)
    elif has(mats, PRINCIPLED) and kind == PRINCIPLED:
        c, scale, pdf = principled.eval_part(mats, m, d, ng, ns, uv, wi, part)
    elif has(mats, PRINCIPLEDTHIN):
        c, scale, pdf = principledthin.eval_part(mats, m, d, ng, ns, uv, wi, part)
    else:
        c, scale, pdf = (0.0, 0.0, 0.0), 0.0, 0.0
    if (has(mats, NORMALMAP) or has(mats, BUMPMAP)) and mats.terminator[m]:
        scale *= terminator(ng, ns, wi)
    return c, scale, pdf


@kernel(inline=True)
def camera_scale(mats, m, d, ng, ns, wi):
    """The factor a camera path (radiance) applies to :func:`eval_pdf`'s f towards wi: 1 / eta² when wi is
    refracted by a glossy transmission lobe, else 1 (:func:`sample`'s weight leaves it to the caller too)."""
    if has(mats, ROUGHDIELECTRIC) and mats.kind[m] == ROUGHDIELECTRIC:
        return roughdielectric.camera_scale(mats, m, d, ng, ns, wi)
    if has(mats, PRINCIPLED) and mats.kind[m] == PRINCIPLED:
        return principled.camera_scale(mats, m, d, ng, ns, wi)
    return 1.0


@kernel(inline=True)
def coat(mats, m, d, ng, ns, uv):
    """For a BSDF with a delta reflection over a diffuse lobe (``plastic``; flags with both ``DELTA`` and ``SMOOTH``),
    the lobes apart: (reflected direction, P, weight, A).  :func:`sample` picks the reflection with probability P
    (``u < P`` with its first number u), with that weight (f cos / pdf); the diffuse lobe is separable,
    f = A(d) · :func:`entry` (wi), which lets the photon methods weight a photon (or a light sample) by B where it
    arrives and a visible point by A, A with the diffuse colour at surface coordinates uv."""
    return plastic.coat(mats, m, d, ng, ns, uv)


@kernel(inline=True)
def entry(mats, m, cos_o):
    """The factor B of :func:`coat`'s (or :func:`rough_coat`'s) separable diffuse lobe for light arriving at cosine
    cos_o (shading normal)."""
    if has(mats, ROUGHPLASTIC) and mats.kind[m] == ROUGHPLASTIC:
        return roughplastic.entry(mats, m, cos_o)
    return plastic.entry(mats, m, cos_o)


@kernel(inline=True)
def rough_coat(mats, m, d, ns, uv):
    """For a glossy coating over a diffuse lobe (``roughplastic``), the lobes apart: (P, A), P the probability that
    :func:`sample` picks the glossy lobe, A the diffuse lobe's factor on the path's side, f_diffuse = A(d) ·
    :func:`entry` (wi), as :func:`coat`'s; :func:`sample_coating` samples the glossy lobe alone."""
    return roughplastic.coat(mats, m, d, ns, uv)


@kernel(inline=True)
def sample_coating(mats, m, d, ng, ns, key, dim):
    """:func:`rough_coat`'s glossy lobe alone: (ok, wi, weight f cos / pdf of that lobe, that pdf, dim past its two
    numbers)."""
    return roughplastic.sample_coating(mats, m, d, ng, ns, key, dim)


@kernel(inline=True)
def eval_coating(mats, m, d, ng, ns, wi):
    """:func:`rough_coat`'s glossy lobe alone towards wi: (f RGB, the density :func:`sample_coating` gives wi)."""
    return roughplastic.eval_coating(mats, m, d, ng, ns, wi)


@kernel(inline=True)
def split_record_weight(mats, m, d, ng, ns, wi, A):
    """:func:`rough_coat`'s split point (its diffuse lobe's factor A) weighing a caustic record (power times B)
    arriving from wi: A plus the glossy lobe's f / B (:func:`caustica.bsdfs.roughplastic.split_record_weight`).  No
    code in a scene without roughplastic."""
    if has(mats, ROUGHPLASTIC):
        return roughplastic.split_record_weight(mats, m, d, ng, ns, wi, A)
    return (0.0, 0.0, 0.0)


@kernel(inline=True)
def delta_branches(mats, m, d, ng, ns, uv):
    """A delta BSDF's two branches: (reflected, transmitted direction, F, eta, (reflected tint, transmitted tint)).

    F is the probability :func:`sample` reflects (1 for a mirror, and under total internal reflection,
    when the transmitted direction repeats the reflected one); eta the relative IOR of the
    transmission; each tint scales its branch (glass's specular_reflectance and specular_transmittance,
    :func:`caustica.bsdfs.dielectric.tints`; a mirror's reflectance twice).  ``u < F`` picks reflection as
    :func:`sample` does with number u.
    """
    kind = mats.kind[m]
    if has(mats, CONDUCTOR) and kind == CONDUCTOR:
        return conductor.delta_branches(mats, m, d, ng, ns, uv)
    if has(mats, THINDIELECTRIC) and kind == THINDIELECTRIC:
        return thindielectric.delta_branches(mats, m, d, ng, ns, uv)
    return dielectric.delta_branches(mats, m, d, ng, ns, uv)
