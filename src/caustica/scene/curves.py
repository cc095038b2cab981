"""Mitsuba 3's curve shapes (``linearcurve``, ``bsplinecurve``) as triangle meshes.

A curve file holds one control point per line, ``x y z radius``; a blank line starts a new curve.
Mitsuba moves the points by the shape's ``to_world`` and keeps the radii as they are, then sweeps a
sphere of the interpolated radius along each curve:

* ``linearcurve``: straight segments between consecutive points (two or more per curve), with a sphere
  at every point, so segments join smoothly and the ends are round;
* ``bsplinecurve``: a uniform cubic B-spline through each run of four consecutive points (four or more
  per curve), with no caps: the tube is open at its ends.

Here each sweep becomes a tube of triangles: rings of :data:`SIDES` vertices around the centre line,
:data:`STEPS` rings per B-spline segment.  A ring lies on the *characteristic circle* of the swept
sphere (where the sweep's envelope touches it), so the tube is the sweep's surface up to the facets:
for a sphere of radius r(s) centred at c(s), the circle's points p satisfy |p - c| = r and
(p - c) . c' = -r r', which moves the circle back along the tangent by r r' / |c'| and shrinks it to
r sqrt(1 - (r' / |c'|)^2); the normal there is (p - c) / r.

Surface coordinates are Mitsuba's: u the angle about the centre line over 2 pi, from the frame its curve
shapes build about the tangent t (the rotation axis the part of +z across t, then the radial axis
that axis times t); v the global curve parameter, (segment index + local parameter) / segments, over all
segments of the shape.  A texture on a curve therefore lands where Mitsuba puts it.

What differs from Mitsuba's curves, by construction: the facets (a ring of 32 sides falls 0.5 % inside
the round tube at the middle of each side), and Mitsuba culls a curve's back faces, so it sees through
an open B-spline end where this mesh shows the tube's inside.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SceneError, quoted
from .description import Mesh
from .transforms import transform_points

#: Vertices around a ring (the tube's facets).
SIDES = 32
#: Rings per B-spline segment (a linear segment needs two: its ends).
STEPS = 16
#: Latitude bands of a linear curve's joint and end spheres.
SPHERE_BANDS = 16
#: Refused above this many triangles (about 200 bytes each in the scene's tables and BVH).
MAX_TRIANGLES = 1 << 26
MIN_POINTS = {"linearcurve": 2, "bsplinecurve": 4}


def read_curves(path: str | Path, kind: str) -> list[np.ndarray]:
    """The curves of a curve file: one (k, 4) float64 array (x, y, z, radius) per curve.

    SceneError (naming the file and line) for a line that is not four numbers, a non-finite value, a
    negative radius, a curve with fewer points than ``kind`` needs, or a file without points."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"curve file '{path}': cannot read it ({exc.__class__.__name__}: {exc})") \
            from None
    curves, current, first_line = [], [], 0

    def finish():
        if current:
            if len(current) < MIN_POINTS[kind]:
                raise SceneError(f"curve file '{path}', line {first_line}: a {kind} needs at least "
                                 f"{MIN_POINTS[kind]} control points per curve; this curve has {len(current)}")
            curves.append(np.array(current, np.float64))
            current.clear()

    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        if not fields:
            finish()
            continue
        if not current:
            first_line = number
        try:
            values = [float(f) for f in fields]
        except ValueError:
            values = []
        if len(values) != 4:
            raise SceneError(f"curve file '{path}', line {number}: a control point is four numbers, "
                             f"'x y z radius'; found {quoted(line.strip()[:60])}")
        if not all(np.isfinite(values)):
            raise SceneError(f"curve file '{path}', line {number}: a control point must be finite")
        if values[3] < 0.0:
            raise SceneError(f"curve file '{path}', line {number}: a radius must be >= 0 (found {values[3]:g})")
        current.append(values)
    finish()
    if not curves:
        raise SceneError(f"curve file '{path}' holds no control points")
    return curves


def _frame(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's frame about unit tangents t (n, 3): (rotation axis, radial axis), each (n, 3)."""
    guide = np.array([0.0, 0.0, 1.0])
    rot = guide - t * (t @ guide)[:, None]
    length = np.linalg.norm(rot, axis=1)
    singular = length < 1e-12
    rot = np.where(singular[:, None], np.array([0.0, 1.0, 0.0]), rot / np.where(singular, 1.0, length)[:, None])
    return rot, np.cross(rot, t)


def _rings(c, dc, r, dr, v) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The characteristic circles of spheres (c, r) moving at (dc, dr) per unit v: positions, normals and
    uvs of SIDES + 1 vertices per ring (the last repeats the first at u = 1), each (n, SIDES + 1, .)."""
    speed = np.linalg.norm(dc, axis=1)
    t = dc / np.maximum(speed, 1e-300)[:, None]
    rot, rad = _frame(t)
    slope = np.clip(dr / np.maximum(speed, 1e-300), -1.0, 1.0)       # r' / |c'|: how fast the sphere grows
    along = -(r * slope)[:, None] * t                                  # the circle's centre, back from c
    ring_r = r * np.sqrt(1.0 - slope * slope)
    u = np.arange(SIDES + 1) / SIDES
    cos, sin = np.cos(2 * np.pi * u), np.sin(2 * np.pi * u)
    cos[-1], sin[-1] = 1.0, 0.0
    across = cos[None, :, None] * rad[:, None, :] + sin[None, :, None] * rot[:, None, :]
    offset = along[:, None, :] + ring_r[:, None, None] * across
    positions = c[:, None, :] + offset
    tip = r < 1e-12                                                     # a point: its normal along the curve
    normals = np.where(tip[:, None, None], -np.sign(slope + (slope == 0))[:, None, None] * t[:, None, :],
                       offset / np.where(tip, 1.0, r)[:, None, None])
    uvs = np.stack(np.broadcast_arrays(u[None, :], v[:, None]), axis=-1)
    return positions, normals, uvs


def _tube(positions, normals, uvs) -> tuple[np.ndarray, ...]:
    """Triangles joining consecutive rings (n rings of SIDES + 1 vertices), counter-clockwise from outside."""
    n = positions.shape[0]
    ring = SIDES + 1
    i = np.arange(n - 1)[:, None] * ring + np.arange(SIDES)[None, :]
    a, b, c, d = i, i + 1, i + ring, i + ring + 1
    tris = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return positions.reshape(-1, 3), normals.reshape(-1, 3), uvs.reshape(-1, 2), tris


def _bspline(points: np.ndarray, first_segment: int, segments: int):
    """One B-spline curve's tube: its rings at STEPS + 1 parameters per segment."""
    k = points.shape[0] - 3
    s = np.concatenate([np.linspace(0.0, 1.0, STEPS + 1)[:-1] + j for j in range(k)] + [np.array([float(k)])])
    j = np.minimum(s.astype(np.int64), k - 1)
    x = s - j
    # the uniform cubic B-spline basis and its derivative in the local parameter x
    w = np.stack([(1 - x) ** 3, 3 * x ** 3 - 6 * x ** 2 + 4, -3 * x ** 3 + 3 * x ** 2 + 3 * x + 1, x ** 3], -1) / 6
    dw = np.stack([-3 * (1 - x) ** 2, 9 * x ** 2 - 12 * x, -9 * x ** 2 + 6 * x + 3, 3 * x ** 2], -1) / 6
    cp = points[j[:, None] + np.arange(4)[None, :]]                    # (n, 4, 4)
    value = np.einsum("nk,nkd->nd", w, cp)
    slope = np.einsum("nk,nkd->nd", dw, cp)
    v = (first_segment + s) / segments
    return _tube(*_rings(value[:, :3], slope[:, :3], value[:, 3], slope[:, 3], v))


def _sphere(centre, radius, v, rot, rad, axis):
    """A sphere's tessellation in the frame (rad, rot, axis) of the segment it joins; uv (angle about the axis, v)."""
    lat = np.linspace(np.pi, 0.0, SPHERE_BANDS + 1)                  # from -axis to +axis: outward winding
    u = np.arange(SIDES + 1) / SIDES
    phi = 2 * np.pi * u
    d = (np.sin(lat)[:, None, None] * (np.cos(phi)[None, :, None] * rad + np.sin(phi)[None, :, None] * rot)
         + np.cos(lat)[:, None, None] * axis)
    uvs = np.stack(np.broadcast_arrays(u[None, :], np.full((SPHERE_BANDS + 1, 1), v)), axis=-1)
    return _tube(centre + radius * d, d, uvs)


def _linear(points: np.ndarray, first_segment: int, segments: int):
    """One linear curve's pieces: a tube per segment and a sphere at every control point."""
    k = points.shape[0] - 1
    p, r = points[:, :3], points[:, 3]
    parts = []
    for j in range(k):
        ends = np.array([0.0, 1.0])
        c = p[j] + ends[:, None] * (p[j + 1] - p[j])
        dc = np.repeat((p[j + 1] - p[j])[None, :], 2, axis=0)
        if np.linalg.norm(dc[0]) == 0.0:
            continue                                                    # coincident points: the sphere covers it
        parts.append(_tube(*_rings(c, dc, r[j] + ends * (r[j + 1] - r[j]), np.full(2, r[j + 1] - r[j]),
                                   (first_segment + j + ends) / segments)))
    for i in range(k + 1):
        j = min(i, k - 1)                                               # the segment whose frame the sphere takes
        axis = p[j + 1] - p[j]
        axis = axis / max(np.linalg.norm(axis), 1e-300)
        rot, rad = _frame(axis[None, :])
        if r[i] > 0.0:
            parts.append(_sphere(p[i], r[i], (first_segment + j + (i > j)) / segments, rot[0], rad[0], axis))
    return parts


def curve_mesh(curves: list[np.ndarray], kind: str, to_world: np.ndarray | None) -> Mesh:
    """The world-space mesh of ``curves`` (from :func:`read_curves`) as a ``kind`` shape placed by ``to_world``
    (the points moved, the radii kept, as Mitsuba does).  SceneError above MAX_TRIANGLES."""
    per_segment = 2 * SIDES * (STEPS if kind == "bsplinecurve" else 1)
    segments = sum(len(c) - (3 if kind == "bsplinecurve" else 1) for c in curves)
    estimate = segments * per_segment + (0 if kind == "bsplinecurve" else
                                         sum(len(c) for c in curves) * 2 * SIDES * SPHERE_BANDS)
    if estimate > MAX_TRIANGLES:
        raise SceneError(f"the {kind}'s {segments} segments would make {estimate:,} triangles (about "
                         f"{estimate * 200 / 2**30:.1f} GiB), more than the {MAX_TRIANGLES:,} allowed")
    parts, first = [], 0
    for points in curves:
        world = points.copy()
        if to_world is not None:
            world[:, :3] = transform_points(to_world, points[:, :3])
        if kind == "bsplinecurve":
            parts.append(_bspline(world, first, segments))
            first += len(points) - 3
        else:
            parts.extend(_linear(world, first, segments))
            first += len(points) - 1
    positions, normals, uvs, tris, offset = [], [], [], [], 0
    for pos, nrm, uv, tri in parts:
        positions.append(pos)
        normals.append(nrm)
        uvs.append(uv)
        tris.append(tri + offset)
        offset += pos.shape[0]
    return Mesh(positions=np.concatenate(positions), triangles=np.concatenate(tris).astype(np.int64),
                normals=np.concatenate(normals), uvs=np.concatenate(uvs))
