"""The wrappers that perturb the shading normal, Mitsuba 3's ``normalmap`` and ``bumpmap`` (src/bsdfs/normalmap.cpp,
bumpmap.cpp): resolved where a ray meets them, in :func:`caustica.transport.surface_interaction`, to their nested
BSDF with a new shading normal, so the loops see an ordinary BSDF at a point whose ``ns`` is the perturbed normal.

Both work in the shading frame (s, t, n) of the hit: n the shading normal, s the position partial dp/du made
orthogonal to n (Gram-Schmidt; Duff et al.'s basis where that vanishes), t = n x s
(:func:`caustica.geometry.scene_geometry.surface_tangents` gives dp/du and dp/dv).

* ``normalmap``: the bitmap's RGB at (u, v) (filtered, ``raw``), mapped to 2 rgb - 1, is the normal in (s, t, n).
* ``bumpmap``: the texture's luminance is a height h; with its gradient g = scale (dh/du, dh/dv) (the bilinear
  cell's exact derivative, zero for a nearest lookup: Mitsuba's ``eval_1_grad``), dp/du' = dp/du + n (g_u - n.dp/du)
  and dp/dv' likewise; the normal is dp/du' x dp/dv' normalised, turned to the geometric normal's side.

Then, as Mitsuba's ``flip_invalid_normals``: where the incoming direction wi = -d lies on one side of the shading
normal and the perturbed normal's other, the perturbed normal's (s, t) components are negated (mirrored about n).

Mitsuba's ``use_shadowing_function`` (default on) multiplies f by the shadowing term of Estevez et al. 2019, for the
bump terminator: G(wo) = 2 / (1 + sqrt(1 + a² tan² θ_o)), a² = min(tan² θ_p / 8, 1), θ_p the perturbed normal's
angle to the unperturbed one and θ_o that of the direction towards the light (a camera path's sampled or
next-event direction).  The loops no longer know the unperturbed normal, so
:func:`terminator` measures both angles from the geometric normal: exact on flat triangles, rectangles and spheres,
an approximation on meshes with vertex normals.
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..features import guarded_by, has
from ..scene.description import BUMPMAP, NORMALMAP
from .textures import FILTER, HEIGHT, LUMINANCE, NEAREST, ROW0, TO_UV, WIDTH, WRAP, texel, texture_rgb


@kernel
def height_gradient(table, t, uv):
    """(dh/du, dh/dv) of texture t's luminance h at surface coordinates uv (a bitmap, bilinear: the cell's exact
    derivative; nearest: zero), ``table`` = (tex_int, tex_float, texels), as Mitsuba's ``eval_1_grad``."""
    ints, a, texels = table
    if ints[t, FILTER] == NEAREST:
        return 0.0, 0.0
    u = a[t, TO_UV] * uv[0] + a[t, TO_UV + 1] * uv[1] + a[t, TO_UV + 2]
    v = a[t, TO_UV + 3] * uv[0] + a[t, TO_UV + 4] * uv[1] + a[t, TO_UV + 5]
    if not (abs(u) < 1e15 and abs(v) < 1e15):
        return 0.0, 0.0
    w = ints[t, WIDTH]
    h = ints[t, HEIGHT]
    row0 = ints[t, ROW0]
    mode = ints[t, WRAP]
    px = u * w - 0.5
    py = v * h - 0.5
    fx = math.floor(px)
    fy = math.floor(py)
    x0 = int(fx)
    y0 = int(fy)
    ax = px - fx
    ay = py - fy
    f00 = vec.dot(texel(texels, row0, w, h, mode, x0, y0), LUMINANCE)
    f10 = vec.dot(texel(texels, row0, w, h, mode, x0 + 1, y0), LUMINANCE)
    f01 = vec.dot(texel(texels, row0, w, h, mode, x0, y0 + 1), LUMINANCE)
    f11 = vec.dot(texel(texels, row0, w, h, mode, x0 + 1, y0 + 1), LUMINANCE)
    dx = (1.0 - ay) * (f10 - f00) + ay * (f11 - f01)
    dy = (1.0 - ax) * (f01 - f00) + ax * (f11 - f10)
    return ((a[t, TO_UV] * dx + a[t, TO_UV + 3] * dy) * w, (a[t, TO_UV + 1] * dx + a[t, TO_UV + 4] * dy) * h)


@kernel(inline=True)
def map_normal(mats, m, ng, ns, uv, dp_du, dp_dv):
    """Wrapper m's normal before Mitsuba's flip, in the shading frame (s, t, ns) of a surface with front normals
    ng, ns, surface coordinates uv and position partials dp_du, dp_dv: (s, t, its (s, t, n) components)."""
    s = vec.sub(dp_du, vec.mul(ns, vec.dot(ns, dp_du)))
    if vec.dot(s, s) > 0.0:
        s = vec.normalize(s)
        t = vec.cross(ns, s)
    else:
        s, t = vec.orthonormal_basis(ns)
    table = (mats.tex_int, mats.tex_float, mats.texels)
    x = mats.mix_texture[m]
    if mats.kind[m] == BUMPMAP:
        gu, gv = height_gradient(table, x, uv)
        scale = mats.mix[m]
        du = vec.madd(dp_du, ns, scale * gu - vec.dot(ns, dp_du))
        dv = vec.madd(dp_dv, ns, scale * gv - vec.dot(ns, dp_dv))
        n = vec.normalize(vec.cross(du, dv))
        if vec.dot(ng, n) < 0.0:
            n = vec.neg(n)
        local = (vec.dot(n, s), vec.dot(n, t), vec.dot(n, ns))
    else:
        c = texture_rgb(table, x, (uv[0], uv[1]))
        local = (2.0 * c[0] - 1.0, 2.0 * c[1] - 1.0, 2.0 * c[2] - 1.0)
    return s, t, local


@kernel
def perturbed_normal(mats, m, d, ng, ns, uv, dp_du, dp_dv):
    """Wrapper m's shading normal (world space) for a ray along d meeting a surface with front normals ng, ns,
    surface coordinates uv and position partials dp_du, dp_dv (see the module's docstring)."""
    s, t, local = map_normal(mats, m, ng, ns, uv, dp_du, dp_dv)
    wi = vec.neg(d)
    if vec.dot(wi, ns) * vec.dot(wi, vec.from_local(s, t, ns, local)) <= 0.0:
        local = (-local[0], -local[1], local[2])
    return vec.normalize(vec.from_local(s, t, ns, vec.normalize(local)))


@kernel
def both_normals(mats, m, ng, ns, uv, dp_du, dp_dv):
    """Wrapper m's two possible shading normals (world space): the map's, and the map's mirrored about ns (its
    (s, t) components negated), one of which Mitsuba's flip picks by the camera's side (:func:`flip_side`)."""
    s, t, local = map_normal(mats, m, ng, ns, uv, dp_du, dp_dv)
    mirrored = (-local[0], -local[1], local[2])
    return (vec.normalize(vec.from_local(s, t, ns, vec.normalize(local))),
            vec.normalize(vec.from_local(s, t, ns, vec.normalize(mirrored))))


@kernel(inline=True)
def flip_side(n_map, ns, w):
    """Which of :func:`both_normals` Mitsuba's flip gives a camera path arriving from w (towards the camera): 0 the
    map's normal n_map, 1 its mirror, where w lies on different sides of ns and n_map."""
    return 1 if vec.dot(w, ns) * vec.dot(w, n_map) <= 0.0 else 0


@kernel(inline=True)
def terminator(ng, ns, wo):
    """Mitsuba's shadowing term for bump and normal maps towards wo, both angles from ng (module docstring)."""
    c = vec.dot(ng, ns)
    c2 = c * c
    a2 = min(0.125 * (1.0 - c2) / c2, 1.0) if c2 > 0.0 else 1.0
    co = vec.dot(ng, wo)
    co2 = co * co
    if co2 <= 0.0:
        return 0.0
    return 2.0 / (1.0 + math.sqrt(1.0 + a2 * max(1.0 - co2, 0.0) / co2))


@guarded_by(NORMALMAP, BUMPMAP)
@kernel(inline=True)
def wrapped(mats, m):
    """Whether material row m is a wrapper's nested row: its shading normal is perturbed where a ray meets it."""
    return (has(mats, NORMALMAP) or has(mats, BUMPMAP)) and mats.wrapped[m] != 0


@kernel(inline=True)
def photon_shading(mats, m, ng, ns, wo, wi):
    """What a photon's weight f cos / pdf from wrapper's nested row m (sampled as a camera path samples it, without
    the terminator's shadowing: :func:`caustica.bsdfs.sample_kind`; shading normal ns, the one Mitsuba's flip gives
    wi: :func:`caustica.photons.trace.wrapped_bounce` sees to that) is multiplied by when the photon arrives from wo
    (towards the light) and leaves along wi.

    Mitsuba's BSDF f_M(wi, wo) = f cos_s(wo) G(wo) holds the shading cosine and the terminator's shadowing G on the
    light's side, wo (:func:`terminator`, where the row has it); a photon carries flux, whose density on a surface
    is per geometric area.  Leaving along wi sampled with density p, its weight must be f_M |cos_g(wi)| /
    (p |cos_g(wo)|) (Veach 1997, §5.3: the adjoint of a BSDF with shading normals), that is the sample's weight
    f |cos_s(wi)| / p times G(wo) |cos_s(wo)| |cos_g(wi)| / (|cos_s(wi)| |cos_g(wo)|).  The same factor holds for
    a delta lobe (refraction's Jacobian takes its cosines about ns)."""
    cs_i = abs(vec.dot(ns, wi))
    cg_o = abs(vec.dot(ng, wo))
    if cs_i <= 0.0 or cg_o <= 0.0:
        return 0.0
    g = terminator(ng, ns, wo) if mats.terminator[m] else 1.0
    return g * abs(vec.dot(ns, wo)) * abs(vec.dot(ng, wi)) / (cs_i * cg_o)


@kernel(inline=True)
def gather_shading(ng, ns, wo):
    """What a photon arriving from wo (towards the light) is weighted by, beside f, at a visible point on a
    wrapper's nested row: |cos_s(wo)| / |cos_g(wo)|, the shading cosine Mitsuba's f_M holds over the geometric one
    the photons' density already holds (:func:`photon_shading`)."""
    cg = abs(vec.dot(ng, wo))
    return abs(vec.dot(ns, wo)) / cg if cg > 0.0 else 0.0
