"""What happens where a ray meets a surface: written once for every light path (camera, photon, stream,
visible point), with or without media.

A loop finds its next event with :func:`caustica.media.free_flight` (a surface, or a scattering
distance in the current medium) and, at a surface, asks :func:`surface_interaction` for the hit's
point, normals, material and shape.  A null-BSDF surface (a medium's invisible boundary) is crossed
there and then: the ray goes on from just past it in the medium beyond, and nothing else happens.  A mixture
(``mask``, ``blendbsdf``) is resolved there too, with one number (:func:`caustica.bsdfs.resolve`): the loop gets
the part chosen, or the surface is crossed as a null one where a mask is off.  A normal or bump map
(:mod:`caustica.bsdfs.perturb`) is resolved there to its nested BSDF, with the shading normal it perturbs:
the loop sees that BSDF at a point whose ``ns`` is the perturbed normal.
One offset rule (:func:`caustica.geometry.vec.offset_origin`) and one ``tmax`` convention
(``np.inf`` for an unbounded ray) hold in every loop.
"""
from __future__ import annotations

from typing import NamedTuple

from .geometry import vec
from .geometry.scene_geometry import NO_UV, surface_at, surface_tangents, surface_uv
from .features import has
from .jit import kernel
from .bsdfs.flags import ANISOTROPIC, TEXTURED
from .bsdfs.mixtures import resolve
from .bsdfs.perturb import both_normals, perturbed_normal
from .bsdfs.textures import needs_tangent, needs_uv
from .media import cross_null
from .scene.description import BLEND, BUMPMAP, MASK, NORMALMAP, NULL

class ShadingPoint(NamedTuple):
    """Where a path scatters, as next-event estimation needs it (built in kernels)."""
    p: tuple          # the point
    ng: tuple         # geometric normal on the side that scatters (zero in a medium)
    ns: tuple         # shading normal on that side (zero in a medium)
    ng_front: tuple   # the front geometric normal: which side leads to the exterior medium
    shape: int        # the shape, or -1 for a point in a medium
    medium: int       # the medium the path is in
    uv: tuple = NO_UV   # surface coordinates (u, v, triangle, b1, b2, dp/du) for the material's textures and an
    #                     anisotropic BSDF's frame (NO_UV: none)


@kernel(inline=True)
def in_medium(p, medium):
    """A :class:`ShadingPoint` at p inside ``medium``: no surface, no normals."""
    zero = (0.0, 0.0, 0.0)
    return ShadingPoint(p, zero, zero, zero, -1, medium, NO_UV)


#: What a loop does after :func:`surface_interaction`.
SCATTER = 0   # a real surface: the loop's own rules apply at p
CROSSED = 1   # a null boundary was crossed: go on from the returned origin, in the returned medium
TRAPPED = 2   # more null crossings in a row than NULL_CROSSINGS_CAP: the path ends


@kernel(inline=True)
def surface_interaction(tables, hit, o, d, medium, crossings, key, dim):
    """A ray from o along d (in ``medium``) meets ``hit`` = (primitive, t, barycentrics b1, b2).

    Returns (p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, next, dim): the hit point, its front
    geometric and shading normals (not turned towards the ray), its surface coordinates (u, v) when the
    material is textured ((0, 0) otherwise), whether the ray arrives on the front,
    the material and its kind, the shape; then the medium, origin and null crossings in a row for
    the ray's continuation, and ``next`` (SCATTER, CROSSED or TRAPPED).  At a real surface the
    crossings start again from 0 and medium and o are unchanged (the loop's scattering decides them).
    A mixture is resolved with number (key, dim) (:func:`caustica.bsdfs.resolve`): m is then the part chosen,
    and dim comes back past it; elsewhere dim comes back as it was.  A normal or bump map is resolved to its
    nested material, ns then the perturbed shading normal (:func:`caustica.bsdfs.perturb.perturbed_normal`).
    """
    geom, mats, _, media = tables
    prim, t, b1, b2 = hit
    p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
    front = vec.dot(d, ng) < 0.0
    m = geom.prim_material[prim]
    kind = mats.kind[m]
    shape = geom.prim_shape[prim]
    uv = NO_UV
    mixture = has(mats, MASK) and kind == MASK or has(mats, BLEND) and kind == BLEND
    if mixture:
        uv = surface_uv(geom, prim, o, d, t, b1, b2)
        m, dim = resolve(mats, m, uv, key, dim)
        kind = NULL if m < 0 else mats.kind[m]
        m = max(m, 0)
    if has(mats, NULL) and kind == NULL:
        medium, o, crossings, within = cross_null(media, shape, p, ng, d, medium, crossings)
        return p, ng, ns, uv, front, m, kind, shape, medium, o, crossings, CROSSED if within else TRAPPED, dim
    if has(mats, NORMALMAP) and kind == NORMALMAP or has(mats, BUMPMAP) and kind == BUMPMAP:
        m, ns, uv = unwrap(geom, mats, prim, (o, d, t, b1, b2), m, (ng, ns))
        kind = mats.kind[m]
        mixture = True   # uv is known
    if has(mats, TEXTURED) and needs_uv(mats, m) and not mixture:
        uv = surface_uv(geom, prim, o, d, t, b1, b2)
    if has(mats, ANISOTROPIC) and needs_tangent(mats, m):
        uv = with_tangent(geom, prim, (o, d, t, b1, b2), uv if mixture else surface_uv(geom, prim, o, d, t, b1, b2))
    return p, ng, ns, uv, front, m, kind, shape, medium, o, 0, SCATTER, dim


@kernel(inline=True)
def unwrap(geom, mats, prim, ray, m, normals):
    """Normal or bump map m where ``ray`` = (o, d, t, b1, b2) meets primitive prim, of front normals ``normals`` =
    (ng, ns): (its nested material, the perturbed shading normal, the surface coordinates)."""
    o, d, t, b1, b2 = ray
    ng, ns = normals
    uv = surface_uv(geom, prim, o, d, t, b1, b2)
    dp_du, dp_dv = surface_tangents(geom, prim, o, d, t)
    return mats.nested[m, 0], perturbed_normal(mats, m, d, ng, ns, uv, dp_du, dp_dv), uv


@kernel
def map_frames(geom, mats, prim, ray, uv):
    """Where ``ray`` = (o, d, t, b1, b2) meets primitive prim under a normal or bump map, at the surface coordinates
    uv :func:`surface_interaction` gave: (the map's normal, its mirror about the unperturbed shading normal, that
    normal), all on the front (:func:`caustica.bsdfs.perturb.both_normals`): what a photon needs to take Mitsuba's
    flip by the side it leaves towards."""
    o, d, t, b1, b2 = ray
    _, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
    dp_du, dp_dv = surface_tangents(geom, prim, o, d, t)
    n_map, n_mirror = both_normals(mats, geom.prim_material[prim], ng, ns, uv, dp_du, dp_dv)
    return n_map, n_mirror, ns


@kernel
def with_tangent(geom, prim, ray, uv):
    """The surface coordinates uv with the position partial dp/du of the hit of ``ray`` = (o, d, t, b1, b2) on prim
    (:func:`caustica.geometry.scene_geometry.surface_tangents`): an anisotropic BSDF's shading frame
    (:func:`caustica.bsdfs.microfacet.shading_frame`)."""
    o, d, t, _, _ = ray
    dp_du, _ = surface_tangents(geom, prim, o, d, t)
    return (uv[0], uv[1], uv[2], uv[3], uv[4], dp_du[0], dp_du[1], dp_du[2])
