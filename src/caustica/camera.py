"""The perspective and orthographic cameras, in Mitsuba 3's conventions (same XML, same framing).

Camera space looks along +z with +y up and +x towards the image's *left* (that is
what Mitsuba's ``lookat`` builds: its first column is ``cross(up, dir)``).  The
field of view is given along one axis (``fov_axis`` x, y, smaller or larger) and
converted to the half-angle tangents of both axes.  The orthographic camera sends
parallel rays along camera +z from the near plane's [-1, 1] x [-1/aspect, 1/aspect]
(to_world's scale sizes the view: Mitsuba 3's orthographic sensor).  Pixels integrate the film's
reconstruction filter (box, tent or gaussian, as Mitsuba 3 defines them): each sample's
sub-pixel position is drawn from the filter by :func:`caustica.sampling.filters.film_position`
from the two uniform numbers the caller passes (box: uniform inside the pixel).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .errors import SceneError
from .geometry import vec
from .geometry.scene_geometry import intersect
from .jit import borrowed, kernel
from .sampling.filters import FILTER_KINDS, GAUSSIAN, film_position, filter_radius
from .sampling.rng import lens_key, uniform
from .sampling.warps import square_to_uniform_disk
from .scene.description import Camera, fov_tangents


class CameraParams(NamedTuple):
    origin: np.ndarray     # float64[3]
    basis: np.ndarray      # float64[3, 3]: columns are camera x, y, z in world space
    tan_half_x: float
    tan_half_y: float
    width: int
    height: int
    near_clip: float
    filter_kind: int       # caustica.sampling.filters: BOX, TENT or GAUSSIAN
    filter_radius: float   # the filter's support radius in pixels
    filter_stddev: float   # the gaussian's standard deviation in pixels (0 for the others)
    sample_border: bool    # sample beyond the film's edge (Mitsuba's film sample_border)
    orthographic: bool     # parallel rays; tan_half_x / tan_half_y are then the view's half-extents
    inv_basis: np.ndarray  # float64[3, 3]: the inverse of basis (world to camera space, for projecting)
    aperture_radius: float  # a thin lens's radius, 0 for a pinhole
    focus_distance: float   # a thin lens's plane in focus (camera-space depth)


def tan_half_angles(fov_deg: float, fov_axis: str, width: int, height: int) -> tuple[float, float]:
    """tan(fov_x / 2), tan(fov_y / 2) for Mitsuba's fov / fov_axis (as Mitsuba 3's parse_fov)."""
    try:
        return fov_tangents(fov_deg, fov_axis, width / height)
    except ValueError as exc:
        raise SceneError(str(exc)) from None


def camera_params(cam: Camera, width: int | None = None, height: int | None = None) -> CameraParams:
    w = int(width or cam.width)
    h = int(height or cam.height)
    ortho = cam.projection == "orthographic"
    tx, ty = (1.0, h / w) if ortho else tan_half_angles(cam.fov_deg, cam.fov_axis, w, h)
    m = np.asarray(cam.to_world, dtype=np.float64)
    rf = cam.rfilter
    kind = FILTER_KINDS[rf.kind]
    return CameraParams(m[:3, 3].copy(), m[:3, :3].copy(), tx, ty, w, h, float(cam.near_clip),
                        kind, float(filter_radius(kind, rf.radius, rf.stddev)),
                        float(rf.stddev) if kind == GAUSSIAN else 0.0,
                        bool(cam.sample_border), ortho, np.linalg.inv(m[:3, :3]), float(cam.aperture_radius),
                        float(cam.focus_distance))


@kernel(inline=True)
def pixel_of(cam, i):
    """The pixel (px, py) of index i in row-major order, the order of the camera passes' ranges of pixels."""
    return i % cam.width, i // cam.width


@kernel
def generate_ray(cam, px, py, u1, u2, key):
    """The primary ray of a sample of pixel (px, py) drawn with the uniform numbers (u1, u2): (origin, unit direction).

    The sample's film position comes from the film's reconstruction filter centred on the pixel (box:
    (px + u1, py + u2), uniform inside the pixel).  Pixel (0, 0) is the top-left corner of the image.
    A thin lens takes its point on the lens from the sample's ``key`` (:func:`caustica.sampling.rng.lens_key`:
    numbers of their own, so a pinhole camera reads nothing from it).
    """
    sx = film_position(cam.filter_kind, cam.filter_radius, cam.filter_stddev, cam.sample_border,
                       px, cam.width, u1) / cam.width
    sy = film_position(cam.filter_kind, cam.filter_radius, cam.filter_stddev, cam.sample_border,
                       py, cam.height, u2) / cam.height
    if cam.orthographic:
        return _orthographic_ray(cam, sx, sy)
    local = (cam.tan_half_x * (1.0 - 2.0 * sx), cam.tan_half_y * (1.0 - 2.0 * sy), 1.0)
    if cam.aperture_radius > 0.0:
        return _thin_lens_ray(cam, local, key)
    return _pinhole_ray(cam, local)


@kernel(inline=True)
def _pinhole_ray(cam, local):
    """The pinhole ray through the camera-space point ``local`` (z = 1): (origin on the near plane, unit direction)."""
    d = vec.normalize(_to_world(cam.basis, local))
    # Start on the near plane (Mitsuba ignores geometry closer than near_clip).
    zlen = vec.length(local)
    o = (cam.origin[0], cam.origin[1], cam.origin[2])
    o = vec.madd(o, d, cam.near_clip * zlen)
    return o, d


@kernel(inline=True)
def _to_world(b, v):
    """The camera-space vector v in world space: basis b (columns: camera x, y, z) times v."""
    return (b[0, 0] * v[0] + b[0, 1] * v[1] + b[0, 2] * v[2],
            b[1, 0] * v[0] + b[1, 1] * v[1] + b[1, 2] * v[2],
            b[2, 0] * v[0] + b[2, 1] * v[1] + b[2, 2] * v[2])


@kernel
def _orthographic_ray(cam, sx, sy):
    """The ray of film position (sx, sy) in [0, 1)^2: from the near plane's point, along camera +z."""
    local = (cam.tan_half_x * (1.0 - 2.0 * sx), cam.tan_half_y * (1.0 - 2.0 * sy), cam.near_clip)
    origin = (cam.origin[0], cam.origin[1], cam.origin[2])
    return vec.add(origin, _to_world(cam.basis, local)), vec.normalize(_to_world(cam.basis, (0.0, 0.0, 1.0)))


@kernel
def _thin_lens_ray(cam, local, key):
    """Mitsuba's thin lens: from a uniform point a of the lens disc (camera z = 0) through the point f where the
    pinhole ray ``local`` (camera space, z = 1) meets the plane in focus; starting at the near plane."""
    lk = lens_key(key)
    dx, dy = square_to_uniform_disk(uniform(lk, 0), uniform(lk, 1))
    a = (cam.aperture_radius * dx, cam.aperture_radius * dy, 0.0)
    f = vec.mul(local, cam.focus_distance)
    dc = vec.normalize(vec.sub(f, a))
    d = vec.normalize(_to_world(cam.basis, dc))
    o = vec.add((cam.origin[0], cam.origin[1], cam.origin[2]), _to_world(cam.basis, a))
    return vec.madd(o, d, cam.near_clip / dc[2]), d


@kernel
def pixel_footprints(cam, geom, stops, n, out):
    """The width of a pixel (scene units) where the rays through an n x n grid of film points (pixel-centre spaced)
    first meet a surface of a material with ``stops[m]`` (one a visible point may lie on), going straight on through
    the others (glass, mirrors, rough metal, media's boundaries: a guide, not a ray differential): out[i] = that
    point's depth along the view axis times a pixel's width at unit depth, or an orthographic pixel's width; inf
    where the ray meets none (caustica.tables.Scene.pixel_footprint)."""
    geom = borrowed(geom)
    view = vec.normalize(_to_world(cam.basis, (0.0, 0.0, 1.0)))
    origin = (cam.origin[0], cam.origin[1], cam.origin[2])
    for k in range(n * n):
        sx, sy = (k % n + 0.5) / n, (k // n + 0.5) / n
        if cam.orthographic:
            o, d = _orthographic_ray(cam, sx, sy)
        else:
            o, d = _pinhole_ray(cam, (cam.tan_half_x * (1.0 - 2.0 * sx), cam.tan_half_y * (1.0 - 2.0 * sy), 1.0))
        out[k] = np.inf
        for _ in range(64):
            prim, t, _, _ = intersect(geom, o, d, 1e30)
            if prim < 0:
                break
            o = vec.madd(o, d, t)
            if stops[geom.prim_material[prim]]:
                if cam.orthographic:
                    out[k] = 2.0 * cam.tan_half_x / cam.width * vec.length(_to_world(cam.basis, (1.0, 0.0, 0.0)))
                else:
                    out[k] = vec.dot(vec.sub(o, origin), view) * 2.0 * cam.tan_half_x / cam.width
                break
            o = vec.offset_origin(o, d, d)   # straight on, past the surface along d

