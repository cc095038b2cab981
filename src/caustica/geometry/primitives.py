"""Ray intersection, surface evaluation and area sampling of single primitives.

Two families:

* **Triangles**, stored as ``p0``, ``e1 = p1 - p0``, ``e2 = p2 - p0`` (world space,
  float64) and intersected with Möller–Trumbore.  Barycentrics are tested with a
  tiny *inclusive* tolerance (``BARY_EPS``) so a ray through a shared edge or vertex
  of a mesh always hits one of the triangles (no cracks); ``t`` must be strictly
  positive.  Rays leaving a surface are expected to start at
  :func:`caustica.geometry.vec.offset_origin`, which puts them on the correct side
  of the plane by far more than the float64 error of ``t``.
* **Analytic shapes** in a canonical object space, mapped to the world by a 3x4
  affine ``to_world`` (``to_local`` is its inverse):

  - ``SPHERE``   the unit sphere at the origin, front side outward;
  - ``DISK``     the unit disk in ``z = 0``, front side ``+z``;
  - ``CYLINDER`` the open cylinder of radius 1 from ``z = 0`` to ``z = 1``, front
    side outward (Mitsuba 3's conventions).

  The ray is moved into object space *without* normalising its direction, so the
  ray parameter ``t`` is the same in both spaces.  Normals go back to the world
  with the inverse transpose (the transpose of ``to_local``'s linear part), which
  keeps "outward" outward for any invertible map.  Both quadric roots are tried, so
  a ray starting inside a sphere or cylinder hits the far side.

All functions are Numba device functions; nothing is allocated.  A miss is
reported as ``t = inf``.  Functions that take arrays are ``@kernel(inline=True)``:
a non-inlined Numba call increfs and decrefs every array argument (atomic NRT
calls, ~10 ns each), which dominated the cost of a ray before they were inlined.
Functions on tuples and scalars are left to LLVM's inliner.
"""
from __future__ import annotations

import math

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ..jit import kernel
from .vec import cross, dot, normalize

# Primitive kinds (the ``prim_kind`` column of :class:`~caustica.geometry.scene_geometry.Geometry`).
TRIANGLE = 0
SPHERE = 1
DISK = 2
CYLINDER = 3

INF = math.inf

# Inclusive tolerance on barycentrics, relative to the triangle (closes cracks
# between neighbouring triangles whose edges round differently).
BARY_EPS = 1e-12


# ---------------------------------------------------------------------------
# Triangles
# ---------------------------------------------------------------------------

@kernel
def intersect_triangle(p0, e1, e2, o, d, tmax):
    """Möller–Trumbore: returns ``(t, b1, b2)`` with hit ``p0 + b1 e1 + b2 e2``.

    ``t`` is in units of ``d`` (world units for unit ``d``); ``t = inf`` on a miss
    or when the hit is not in ``(0, tmax)``.  Both sides are hit (no culling).
    """
    pv = cross(d, e2)
    det = dot(e1, pv)
    if det == 0.0:
        return INF, 0.0, 0.0
    inv = 1.0 / det
    s = (o[0] - p0[0], o[1] - p0[1], o[2] - p0[2])
    b1 = dot(s, pv) * inv
    if b1 < -BARY_EPS or b1 > 1.0 + BARY_EPS:
        return INF, 0.0, 0.0
    qv = cross(s, e1)
    b2 = dot(d, qv) * inv
    if b2 < -BARY_EPS or b1 + b2 > 1.0 + BARY_EPS:
        return INF, 0.0, 0.0
    t = dot(e2, qv) * inv
    if not (t > 0.0 and t < tmax):
        return INF, 0.0, 0.0
    return t, b1, b2


@kernel
def sample_triangle(p0, e1, e2, u1, u2):
    """Uniform point by area: ``p0 + b1 e1 + b2 e2`` (square-root warp); pdf = 1 / area."""
    s = math.sqrt(u1)
    b1 = 1.0 - s
    b2 = u2 * s
    return (p0[0] + b1 * e1[0] + b2 * e2[0],
            p0[1] + b1 * e1[1] + b2 * e2[1],
            p0[2] + b1 * e1[2] + b2 * e2[2])


# ---------------------------------------------------------------------------
# Affine transforms stored as (n, 3, 4) arrays
# ---------------------------------------------------------------------------

@kernel(inline=True)
def xform_point(m, i, p):
    """Affine ``m[i]`` (3x4) applied to point ``p``."""
    return (m[i, 0, 0] * p[0] + m[i, 0, 1] * p[1] + m[i, 0, 2] * p[2] + m[i, 0, 3],
            m[i, 1, 0] * p[0] + m[i, 1, 1] * p[1] + m[i, 1, 2] * p[2] + m[i, 1, 3],
            m[i, 2, 0] * p[0] + m[i, 2, 1] * p[1] + m[i, 2, 2] * p[2] + m[i, 2, 3])


@kernel(inline=True)
def xform_vector(m, i, v):
    """Linear part of ``m[i]`` applied to direction ``v`` (no normalisation)."""
    return (m[i, 0, 0] * v[0] + m[i, 0, 1] * v[1] + m[i, 0, 2] * v[2],
            m[i, 1, 0] * v[0] + m[i, 1, 1] * v[1] + m[i, 1, 2] * v[2],
            m[i, 2, 0] * v[0] + m[i, 2, 1] * v[1] + m[i, 2, 2] * v[2])


@kernel(inline=True)
def xform_normal(to_local, i, n):
    """Object-space normal to world (inverse transpose of to_world = transpose of to_local), unit length."""
    m = to_local
    return normalize((m[i, 0, 0] * n[0] + m[i, 1, 0] * n[1] + m[i, 2, 0] * n[2],
                      m[i, 0, 1] * n[0] + m[i, 1, 1] * n[1] + m[i, 2, 1] * n[2],
                      m[i, 0, 2] * n[0] + m[i, 1, 2] * n[1] + m[i, 2, 2] * n[2]))


# ---------------------------------------------------------------------------
# Analytic shapes in object space
# ---------------------------------------------------------------------------

@kernel
def _pick_root(t0, t1, tmax):
    """Smallest of two roots (t0 <= t1) in (0, tmax), else inf."""
    if t0 > 0.0 and t0 < tmax:
        return t0
    if t1 > 0.0 and t1 < tmax:
        return t1
    return INF


@kernel
def _quadric_roots(a, b, c, disc):
    """Both roots of ``a t^2 + b t + c`` (sorted) from a precomputed discriminant,
    using the cancellation-free form ``q = -(b + sign(b) sqrt(disc)) / 2``."""
    rd = math.sqrt(disc)
    if b < 0.0:
        q = -0.5 * (b - rd)
    else:
        q = -0.5 * (b + rd)
    if q == 0.0:
        return INF, INF
    t0 = q / a
    t1 = c / q
    if t0 > t1:
        return t1, t0
    return t0, t1


@kernel
def intersect_unit_sphere(o, d, tmax):
    """Unit sphere at the origin; ``o``, ``d`` in object space (``d`` not unit).

    The discriminant is computed as ``4a (1 - |o - (b / 2a) d|^2)`` (pbrt-v4), which
    stays accurate for rays far from the sphere.  Returns ``t`` or inf.
    """
    a = dot(d, d)
    if a == 0.0:
        return INF
    b = 2.0 * dot(d, o)
    c = dot(o, o) - 1.0
    k = b / (2.0 * a)
    v = (o[0] - k * d[0], o[1] - k * d[1], o[2] - k * d[2])
    lv = math.sqrt(dot(v, v))
    disc = 4.0 * a * (1.0 - lv) * (1.0 + lv)
    if disc < 0.0:
        return INF
    t0, t1 = _quadric_roots(a, b, c, disc)
    return _pick_root(t0, t1, tmax)


@kernel
def intersect_unit_cylinder(o, d, tmax):
    """Open cylinder ``x^2 + y^2 = 1``, ``0 <= z <= 1`` in object space.  Returns ``t`` or inf."""
    a = d[0] * d[0] + d[1] * d[1]
    if a == 0.0:
        return INF
    b = 2.0 * (d[0] * o[0] + d[1] * o[1])
    c = o[0] * o[0] + o[1] * o[1] - 1.0
    k = b / (2.0 * a)
    vx = o[0] - k * d[0]
    vy = o[1] - k * d[1]
    lv = math.sqrt(vx * vx + vy * vy)
    disc = 4.0 * a * (1.0 - lv) * (1.0 + lv)
    if disc < 0.0:
        return INF
    t0, t1 = _quadric_roots(a, b, c, disc)
    if t0 > 0.0 and t0 < tmax:
        z = o[2] + t0 * d[2]
        if z >= 0.0 and z <= 1.0:
            return t0
    if t1 > 0.0 and t1 < tmax:
        z = o[2] + t1 * d[2]
        if z >= 0.0 and z <= 1.0:
            return t1
    return INF


@kernel
def intersect_unit_disk(o, d, tmax):
    """Unit disk in ``z = 0`` in object space.  Returns ``t`` or inf."""
    if d[2] == 0.0:
        return INF
    t = -o[2] / d[2]
    if not (t > 0.0 and t < tmax):
        return INF
    x = o[0] + t * d[0]
    y = o[1] + t * d[1]
    if x * x + y * y > 1.0:
        return INF
    return t


@kernel(inline=True)
def intersect_analytic(kind, to_local, i, o, d, tmax):
    """World ray against analytic record ``i`` of kind SPHERE/DISK/CYLINDER; ``t`` or inf."""
    ol = xform_point(to_local, i, o)
    dl = xform_vector(to_local, i, d)
    if kind == SPHERE:
        return intersect_unit_sphere(ol, dl, tmax)
    if kind == DISK:
        return intersect_unit_disk(ol, dl, tmax)
    if kind == CYLINDER:
        return intersect_unit_cylinder(ol, dl, tmax)
    return INF


@kernel(inline=True)
def analytic_surface(kind, to_world, to_local, i, o, d, t):
    """Hit point and unit front-side (unflipped) normal of analytic record ``i`` at ray parameter ``t``.

    The object-space hit is re-projected onto the exact surface before it is
    mapped back, which removes most of the error of ``o + t d``.
    """
    ol = xform_point(to_local, i, o)
    dl = xform_vector(to_local, i, d)
    x = ol[0] + t * dl[0]
    y = ol[1] + t * dl[1]
    z = ol[2] + t * dl[2]
    if kind == SPHERE:
        r = math.sqrt(x * x + y * y + z * z)
        if r > 0.0:
            x /= r
            y /= r
            z /= r
        n_loc = (x, y, z)
    elif kind == CYLINDER:
        r = math.sqrt(x * x + y * y)
        if r > 0.0:
            x /= r
            y /= r
        n_loc = (x, y, 0.0)
    else:  # DISK
        z = 0.0
        n_loc = (0.0, 0.0, 1.0)
    p = xform_point(to_world, i, (x, y, z))
    return p, xform_normal(to_local, i, n_loc)


@kernel(inline=True)
def analytic_uv(kind, to_local, i, o, d, t):
    """Mitsuba 3's surface coordinates (u, v) of analytic record ``i`` at ray parameter ``t``: for the sphere
    (azimuth / 2 pi, polar angle from +z / pi), the disk (radius, azimuth / 2 pi), the cylinder (azimuth / 2 pi,
    height), azimuths in [0, 2 pi) from the local +x axis (src/shapes/sphere.cpp, disk.cpp, cylinder.cpp)."""
    ol = xform_point(to_local, i, o)
    dl = xform_vector(to_local, i, d)
    x = ol[0] + t * dl[0]
    y = ol[1] + t * dl[1]
    z = ol[2] + t * dl[2]
    phi = math.atan2(y, x)
    if phi < 0.0:
        phi += 2.0 * math.pi
    if kind == SPHERE:
        r = math.sqrt(x * x + y * y + z * z)
        c = z / r if r > 0.0 else 1.0
        return phi / (2.0 * math.pi), math.acos(min(1.0, max(-1.0, c))) / math.pi
    if kind == CYLINDER:
        return phi / (2.0 * math.pi), z
    return math.sqrt(x * x + y * y), phi / (2.0 * math.pi)


@kernel(inline=True)
def sample_analytic(kind, to_world, to_local, i, u1, u2):
    """Point and unit front-side (unflipped) normal, uniform by object-space area.

    Uniform by *world* area whenever ``to_world`` is a similarity (any affine map
    for the planar disk); :func:`~caustica.geometry.scene_geometry.build_geometry`
    rejects emitters for which this does not hold.
    """
    if kind == SPHERE:
        z = 1.0 - 2.0 * u1
        r = math.sqrt(max(0.0, 1.0 - z * z))
        phi = 2.0 * math.pi * u2
        pl = (r * math.cos(phi), r * math.sin(phi), z)
        n_loc = pl
    elif kind == CYLINDER:
        phi = 2.0 * math.pi * u2
        c = math.cos(phi)
        s = math.sin(phi)
        pl = (c, s, u1)
        n_loc = (c, s, 0.0)
    else:  # DISK: polar map, uniform in the unit disk
        r = math.sqrt(u1)
        phi = 2.0 * math.pi * u2
        pl = (r * math.cos(phi), r * math.sin(phi), 0.0)
        n_loc = (0.0, 0.0, 1.0)
    return xform_point(to_world, i, pl), xform_normal(to_local, i, n_loc)


# ---------------------------------------------------------------------------
# Dispatch on a primitive of the scene's tables
# ---------------------------------------------------------------------------

@intrinsic
def borrow(typingctx, arr):
    """The same array view without its reference count (``meminfo = NULL``).

    Numba increfs/decrefs every array a variable holds when the variable is
    copied (argument binding, inlining) and cannot prune the pairs around loops;
    with :class:`Geometry`'s ~27 arrays that cost hundreds of ns per ray and made
    threads contend on the shared counters.  A borrowed view's refcount
    operations are null checks.  Only for views that do not outlive the call in
    which the owner (``geom``) is alive -- never return or store one.
    """
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, signature, args):
        view = cgutils.create_struct_proxy(arr)(context, builder, value=args[0])
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        view.parent = cgutils.get_null_value(view.parent.type)
        return view._getvalue()

    return arr(arr), codegen


@kernel(inline=True)
def intersect_primitive_arrays(prims, prim, o, d, tmax):
    """:func:`intersect_primitive` on the individual columns, ``prims`` = (prim_kind, prim_index, tri_p0, tri_e1,
    tri_e2, ana_to_local) (the BVH's inner loop, on borrowed views)."""
    prim_kind, prim_index, tri_p0, tri_e1, tri_e2, ana_to_local = prims
    kind = prim_kind[prim]
    j = prim_index[prim]
    if kind == TRIANGLE:
        p0 = (tri_p0[j, 0], tri_p0[j, 1], tri_p0[j, 2])
        e1 = (tri_e1[j, 0], tri_e1[j, 1], tri_e1[j, 2])
        e2 = (tri_e2[j, 0], tri_e2[j, 1], tri_e2[j, 2])
        return intersect_triangle(p0, e1, e2, o, d, tmax)
    t = intersect_analytic(kind, ana_to_local, j, o, d, tmax)
    return t, 0.0, 0.0


@kernel(inline=True)
def intersect_primitive(geom, prim, o, d, tmax):
    """Ray against primitive ``prim`` of a :class:`Geometry`: ``(t, b1, b2)``, ``t = inf`` on a miss.

    ``b1, b2`` are the barycentrics of ``p1, p2`` for triangles and 0 for analytic shapes.
    """
    return intersect_primitive_arrays((geom.prim_kind, geom.prim_index, geom.tri_p0, geom.tri_e1, geom.tri_e2,
                                       geom.ana_to_local), prim, o, d, tmax)
