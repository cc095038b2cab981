"""Emitting photons from the lights: everywhere (global map) or towards specular objects (caustic map).

A light is chosen in proportion to its power; an area light emits from a point
uniform by area in a cosine-weighted direction about its front normal, a point
light uniformly over the sphere, a spot light uniformly within its cutoff cone, a projector through a point
of its image drawn by the image's luminance (as Mitsuba 3's ``sample_ray``).  The photon's power is the Monte Carlo weight of
its emission sample divided by the number of paths, so that the sum of emitted
power equals the scene's total power Φ (SPEC §3):

    area:  Φ_p = L cosθ / (pdf_area · pdf_dir · p_select · N) = π L A / (p_select N)
    point: Φ_p = I / (pdf_dir · p_select · N)                  = 4 π I / (p_select N)
    spot:  Φ_p = I f(θ) / (pdf_dir · p_select · N)             = 2 π (1 − cos γ) I f(θ) / (p_select N)

(f the spot's falloff, γ its cutoff angle: the mean of Φ_p is the spot's power over p_select N; a projected
texture T multiplies it, T(uv) at the direction drawn, which stays uniform in the cone, as Mitsuba 3's.)
A projector (image E, scale s, image area A on its plane z = 1) draws a point uv of its image by the image's
luminance, density p(uv) (uniform for a constant image; Mitsuba 3's ``sample_ray``), and sends the photon
through it:

    projector: Φ_p = π s A E(uv) / (p(uv) · p_select · N)

Caustic photons are aimed at bounding spheres of the specular shapes: the
direction is drawn from the mixture (uniform over spheres) of uniform cones that
the spheres subtend, and the photon's power divides by that mixture pdf, so the
estimate stays unbiased wherever cones overlap.

The environment emits parallel rays: a direction d by its importance sampling (density p(ω) towards
-d) and an origin uniform on the disc of the scene's bounding sphere (radius R) perpendicular to d, on
the sphere's far side from where the light goes (Mitsuba 3's ``sample_ray``):

    env:   Φ_p = L(ω) π R² / (p(ω) · p_select · N)

Its caustic photons take the origin on the disc of one specular sphere's radius instead (chosen
uniformly), and divide by the mixture of those discs' area densities.  A directional light of irradiance E
emits as the environment does along its one direction d (a delta: no direction density):

    directional: Φ_p = E π R² / (p_select · N)

and its caustic photons as the environment's, along d.  A spot's caustic photons are a point light's (aimed
at the spheres' cones), their power times the falloff f in the direction drawn (a projector's and a textured
spot's times their intensity's profile there, :func:`caustica.emitters.profile`).
"""
from __future__ import annotations

import math

from ..emitters import AREA, DIRECTIONAL, ENV, PROJECTOR, SPOT, TEX_OF, choose_light, env_sample, light_texture, \
    emitter_point, profile, profiled, projector_sample_uv, spot_falloff
from ..geometry import vec
from ..features import has
from ..jit import kernel
from ..media import holds_media, photon_medium
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere, square_to_uniform_cone, square_to_uniform_disk, \
    square_to_uniform_sphere

FOUR_PI = 4.0 * math.pi


@kernel(inline=True)
def emit_photon(geom, lights, key, n_paths):
    """A photon leaving a light: (origin, unit direction, power RGB in W, front normal or zero)."""
    li, sel_pdf, _ = choose_light(lights, uniform(key, 0))
    if has(lights, ENV) and lights.kind[li] == ENV:
        return emit_env_photon(lights, sel_pdf, key, n_paths)
    if has(lights, DIRECTIONAL) and lights.kind[li] == DIRECTIONAL:
        return emit_directional_photon(lights, li, sel_pdf, key, n_paths)
    if has(lights, SPOT) and lights.kind[li] == SPOT:
        return emit_spot_photon(lights, li, sel_pdf, key, n_paths)
    if has(lights, PROJECTOR) and lights.kind[li] == PROJECTOR:
        return emit_projector_photon(lights, li, sel_pdf, key, n_paths)
    if lights.kind[li] == AREA:
        p, n, Le = emitter_point(lights, geom, li, uniform(key, 1), uniform(key, 2))
        local = square_to_cosine_hemisphere(uniform(key, 3), uniform(key, 4))
        s, t = vec.orthonormal_basis(n)
        d = vec.normalize(vec.from_local(s, t, n, local))
        w = math.pi * lights.area[li] / (sel_pdf * n_paths)
        return vec.offset_origin(p, n, d), d, (Le[0] * w, Le[1] * w, Le[2] * w), n
    p = vec.row(lights.position, li)
    d = square_to_uniform_sphere(uniform(key, 1), uniform(key, 2))
    w = FOUR_PI / (sel_pdf * n_paths)
    power = (lights.radiance[li, 0] * w, lights.radiance[li, 1] * w, lights.radiance[li, 2] * w)
    return p, d, power, (0.0, 0.0, 0.0)


@kernel(inline=True)
def start_medium(tables, light_medium, key, ray):
    """The medium photon (or stream) ``key`` starts in, leaving its light along ``ray`` = (o, d):
    :func:`caustica.media.photon_medium` of the light that :func:`emit_photon` and :func:`emit_caustic_photon` chose
    with the photon's number 0 (``light_medium`` as :meth:`caustica.tables.Scene.light_media` gives it)."""
    geom, _, lights, media = tables
    if not holds_media(media):
        return -1   # a scene without media (its code not compiled)
    li, _, _ = choose_light(lights, uniform(key, 0))
    return photon_medium(geom, media, light_medium, li, ray[0], ray[1])


@kernel
def _cone_pdf(p, d, spheres):
    """Mixture pdf (per steradian) of direction d from p over the spheres' cones."""
    n = spheres.shape[0]
    total = 0.0
    for j in range(n):
        c = (spheres[j, 0] - p[0], spheres[j, 1] - p[1], spheres[j, 2] - p[2])
        dist2 = vec.dot(c, c)
        r2 = spheres[j, 3] * spheres[j, 3]
        if dist2 <= r2:
            total += 1.0 / FOUR_PI  # inside the sphere: the whole sphere of directions
            continue
        cos_max = math.sqrt(max(0.0, 1.0 - r2 / dist2))
        if vec.dot(c, d) >= cos_max * math.sqrt(dist2):
            total += 1.0 / (2.0 * math.pi * (1.0 - cos_max))
    return total / n


@kernel
def emit_caustic_photon(geom, lights, spheres, key, n_paths):
    """A photon aimed at a caustic caster (mirror, glass or glossy object): (origin, direction, power, ok).

    ok is False when the sampled direction leaves the light's back side (a
    one-sided emitter sends nothing there); such a photon still counts in n_paths.
    """
    li, sel_pdf, _ = choose_light(lights, uniform(key, 0))
    if has(lights, ENV) and lights.kind[li] == ENV:
        return emit_env_caustic_photon(lights, spheres, sel_pdf, key, n_paths)
    if has(lights, DIRECTIONAL) and lights.kind[li] == DIRECTIONAL:
        return emit_directional_caustic_photon(lights, li, spheres, sel_pdf, key, n_paths)
    is_area = lights.kind[li] == AREA
    if is_area:
        p, n, Le = emitter_point(lights, geom, li, uniform(key, 1), uniform(key, 2))
    else:
        p = vec.row(lights.position, li)
        n = (0.0, 0.0, 0.0)
        Le = vec.row(lights.radiance, li)
    m = spheres.shape[0]
    j = min(int(uniform(key, 3) * m), m - 1)
    c = (spheres[j, 0] - p[0], spheres[j, 1] - p[1], spheres[j, 2] - p[2])
    dist2 = vec.dot(c, c)
    r2 = spheres[j, 3] * spheres[j, 3]
    if dist2 <= r2:
        d = square_to_uniform_sphere(uniform(key, 4), uniform(key, 5))
    else:
        cos_max = math.sqrt(max(0.0, 1.0 - r2 / dist2))
        axis = vec.mul(c, 1.0 / math.sqrt(dist2))
        s, t = vec.orthonormal_basis(axis)
        local = square_to_uniform_cone(uniform(key, 4), uniform(key, 5), cos_max)
        d = vec.normalize(vec.from_local(s, t, axis, local))
    pdf_dir = _cone_pdf(p, d, spheres)
    zero = (0.0, 0.0, 0.0)
    if pdf_dir <= 0.0:
        return p, d, zero, False
    if is_area:
        cos_e = vec.dot(n, d)
        if cos_e <= 0.0:
            return p, d, zero, False
        w = cos_e * lights.area[li] / (pdf_dir * sel_pdf * n_paths)
        return vec.offset_origin(p, n, d), d, (Le[0] * w, Le[1] * w, Le[2] * w), True
    w = 1.0 / (pdf_dir * sel_pdf * n_paths)
    if profiled(lights, li):
        power = vec.hadamard(vec.mul(vec.row(lights.radiance, li), w), profile(lights, li, d))
        return p, d, power, power[0] > 0.0 or power[1] > 0.0 or power[2] > 0.0
    if has(lights, SPOT) and lights.kind[li] == SPOT:
        w *= spot_falloff(lights, li, d)
        if not w > 0.0:
            return p, d, zero, False
    return p, d, (lights.radiance[li, 0] * w, lights.radiance[li, 1] * w, lights.radiance[li, 2] * w), True


@kernel
def emit_spot_photon(lights, li, sel_pdf, key, n_paths):
    """A photon from spot li (chosen with probability sel_pdf): a direction uniform in its cutoff cone (numbers 1,
    2), power I f / (pdf_dir p_select N); as :func:`emit_photon` returns it, with no normal."""
    p = vec.row(lights.position, li)
    cos_max = lights.cone[li, 0]
    axis = vec.row(lights.normal, li)
    s, t = vec.orthonormal_basis(axis)
    d = vec.normalize(vec.from_local(s, t, axis, square_to_uniform_cone(uniform(key, 1), uniform(key, 2), cos_max)))
    zero = (0.0, 0.0, 0.0)
    solid_angle = 2.0 * math.pi * (1.0 - cos_max)
    if not solid_angle > 0.0:
        return p, d, zero, zero
    w = solid_angle * spot_falloff(lights, li, d) / (sel_pdf * n_paths)
    if lights.tex_int[li, TEX_OF] == 1:   # a projected texture: T at the direction's uv (profile / f)
        return p, d, vec.mul(vec.hadamard(vec.row(lights.radiance, li), profile(lights, li, d)),
                             solid_angle / (sel_pdf * n_paths)), zero
    return p, d, vec.mul(vec.row(lights.radiance, li), w), zero


@kernel
def emit_projector_photon(lights, li, sel_pdf, key, n_paths):
    """A photon from projector li (chosen with probability sel_pdf): a point uv of its image by
    :func:`caustica.emitters.projector_sample_uv` (numbers 1, 2), through which it leaves; power
    π s A E(uv) / (p(uv) p_select N) (π s in its radiance, A = 4 tan_x tan_y); as :func:`emit_photon` returns it."""
    p = vec.row(lights.position, li)
    u, v, pdf = projector_sample_uv(lights, li, uniform(key, 1), uniform(key, 2))
    local = ((1.0 - 2.0 * u) * lights.cone[li, 0], (1.0 - 2.0 * v) * lights.cone[li, 1], 1.0)
    d = vec.normalize(vec.from_local(vec.row(lights.edge1, li), vec.row(lights.edge2, li),
                                     vec.row(lights.normal, li), local))
    zero = (0.0, 0.0, 0.0)
    if not pdf > 0.0:
        return p, d, zero, zero
    w = lights.cone[li, 2] / (pdf * sel_pdf * n_paths)
    E = light_texture(lights, li, (u, v)) if lights.tex_int[li, TEX_OF] == 1 else (1.0, 1.0, 1.0)
    return p, d, vec.mul(vec.hadamard(vec.row(lights.radiance, li), E), w), zero


@kernel
def emit_directional_photon(lights, li, sel_pdf, key, n_paths):
    """A photon from directional light li (chosen with probability sel_pdf): along its direction d, from a point
    uniform on the disc of the scene's bounding sphere (centre c, radius R) across d, on the sphere's far side
    (numbers 1, 2, as the environment's); power E π R² / (p_select N)."""
    d = vec.row(lights.normal, li)
    c = (lights.env_data[0], lights.env_data[1], lights.env_data[2])
    r = lights.env_data[3]
    s, t = vec.orthonormal_basis(d)
    x, y = square_to_uniform_disk(uniform(key, 1), uniform(key, 2))
    o = vec.madd(vec.madd(vec.madd(c, s, x * r), t, y * r), d, -r)
    w = math.pi * r * r / (sel_pdf * n_paths)
    return o, d, vec.mul(vec.row(lights.radiance, li), w), (0.0, 0.0, 0.0)


@kernel
def emit_env_photon(lights, sel_pdf, key, n_paths):
    """A photon from the environment (chosen with probability sel_pdf): as :func:`emit_photon` returns it,
    with no normal.  Direction from numbers 3, 4; the disc point from 1, 2."""
    towards, pdf, Le = env_sample(lights, uniform(key, 3), uniform(key, 4))
    d = vec.neg(towards)
    c = (lights.env_data[0], lights.env_data[1], lights.env_data[2])
    r = lights.env_data[3]
    zero = (0.0, 0.0, 0.0)
    if not pdf > 0.0:
        return c, (0.0, 0.0, 1.0), zero, zero
    s, t = vec.orthonormal_basis(d)
    x, y = square_to_uniform_disk(uniform(key, 1), uniform(key, 2))
    o = vec.madd(vec.madd(vec.madd(c, s, x * r), t, y * r), d, -r)
    w = math.pi * r * r / (pdf * sel_pdf * n_paths)
    return o, d, vec.mul(Le, w), zero


@kernel
def emit_env_caustic_photon(lights, spheres, sel_pdf, key, n_paths):
    """A photon from the environment aimed at a specular sphere: (origin, direction, power, ok).

    Direction by the environment's importance (numbers 1, 2); the origin by :func:`aim_parallel_ray`
    (numbers 3, 4, 5).  Its power divides by the direction's density and the origin's.
    """
    towards, pdf, Le = env_sample(lights, uniform(key, 1), uniform(key, 2))
    d = vec.neg(towards)
    zero = (0.0, 0.0, 0.0)
    if not pdf > 0.0:
        return zero, (0.0, 0.0, 1.0), zero, False
    o, density = aim_parallel_ray(lights, spheres, d, key)
    if not density > 0.0:
        return o, d, zero, False
    return o, d, vec.mul(Le, 1.0 / (pdf * density * sel_pdf * n_paths)), True


@kernel
def emit_directional_caustic_photon(lights, li, spheres, sel_pdf, key, n_paths):
    """A photon from directional light li aimed at a specular sphere: (origin, direction, power, ok); the origin by
    :func:`aim_parallel_ray` (numbers 3, 4, 5), power E / (density p_select N)."""
    d = vec.row(lights.normal, li)
    o, density = aim_parallel_ray(lights, spheres, d, key)
    if not density > 0.0:
        return o, d, (0.0, 0.0, 0.0), False
    return o, d, vec.mul(vec.row(lights.radiance, li), 1.0 / (density * sel_pdf * n_paths)), True


@kernel
def aim_parallel_ray(lights, spheres, d, key):
    """The origin of a ray along d from outside the scene aimed at a specular sphere, and its area density across d.

    Sphere j uniformly (number 3); a point q uniform on the disc of sphere j's radius about its centre, across
    d (numbers 4, 5), moved back to the plane that touches the scene's bounding sphere behind it.  The density
    (per m² across d) is the mixture over the spheres of their discs' uniform densities at that line.
    """
    m = spheres.shape[0]
    j = min(int(uniform(key, 3) * m), m - 1)
    s, t = vec.orthonormal_basis(d)
    x, y = square_to_uniform_disk(uniform(key, 4), uniform(key, 5))
    cj = (spheres[j, 0], spheres[j, 1], spheres[j, 2])
    q = vec.madd(vec.madd(cj, s, x * spheres[j, 3]), t, y * spheres[j, 3])
    density = 0.0
    for k in range(m):
        to_k = (spheres[k, 0] - q[0], spheres[k, 1] - q[1], spheres[k, 2] - q[2])
        across = vec.madd(to_k, d, -vec.dot(to_k, d))
        r2 = spheres[k, 3] * spheres[k, 3]
        if vec.dot(across, across) <= r2 and r2 > 0.0:
            density += 1.0 / (math.pi * r2)
    density /= m
    if not density > 0.0:
        return q, 0.0
    c = (lights.env_data[0], lights.env_data[1], lights.env_data[2])
    return vec.madd(q, d, -(vec.dot(vec.sub(q, c), d) + lights.env_data[3])), density
