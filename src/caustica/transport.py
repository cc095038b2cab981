"""What happens where a ray meets a surface: written once for every light path (camera, photon, stream,
visible point), with or without media.

A loop finds its next event with :func:`caustica.media.free_flight` (a surface, or a scattering
distance in the current medium) and, at a surface, asks :func:`surface_interaction` for the hit's
point, normals, material and shape.  A null-BSDF surface (a medium's invisible boundary) is crossed
there and then: the ray goes on from just past it in the medium beyond, and nothing else happens.
One offset rule (:func:`caustica.geometry.vec.offset_origin`) and one ``tmax`` convention
(``np.inf`` for an unbounded ray) hold in every loop.
"""
from __future__ import annotations

from .geometry import vec
from .geometry.scene_geometry import surface_at
from .jit import kernel
from .media import cross_null
from .scene.description import NULL

#: What a loop does after :func:`surface_interaction`.
SCATTER = 0   # a real surface: the loop's own rules apply at p
CROSSED = 1   # a null boundary was crossed: go on from the returned origin, in the returned medium
TRAPPED = 2   # more null crossings in a row than NULL_CROSSINGS_CAP: the path ends


@kernel(inline=True)
def surface_interaction(geom, mats, media, prim, o, d, t, b1, b2, medium, crossings):
    """A ray from o along d (in ``medium``) meets primitive ``prim`` at t (barycentrics b1, b2).

    Returns (p, ng, ns, front, m, kind, shape, medium, o, crossings, next): the hit point, its front
    geometric and shading normals (not turned towards the ray), whether the ray arrives on the front,
    the material and its kind, the shape; then the medium, origin and null crossings in a row for
    the ray's continuation, and ``next`` (SCATTER, CROSSED or TRAPPED).  At a real surface the
    crossings start again from 0 and medium and o are unchanged (the loop's scattering decides them).
    """
    p, ng, ns = surface_at(geom, prim, o, d, t, b1, b2)
    front = vec.dot(d, ng) < 0.0
    m = geom.prim_material[prim]
    kind = mats.kind[m]
    shape = geom.prim_shape[prim]
    if kind == NULL:
        medium, o, crossings, within = cross_null(media, shape, p, ng, d, medium, crossings)
        return p, ng, ns, front, m, kind, shape, medium, o, crossings, CROSSED if within else TRAPPED
    return p, ng, ns, front, m, kind, shape, medium, o, 0, SCATTER
