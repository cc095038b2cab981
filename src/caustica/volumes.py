"""Heterogeneous media: their grid volumes in the medium table, and free flights and transmittance through them
by null collisions (docs/media.md#heterogeneous-media).

A heterogeneous medium (Mitsuba 3's ``heterogeneous``) takes its extinction sigma_t(x) and its albedo(x) from
volumes, grids of voxels or constants (:class:`caustica.scene.description.Volume`), and, as in Mitsuba, exists
only inside the world box of its sigma_t volume: outside it a ray crosses vacuum.  Inside, a coarse *majorant
grid* over the sigma_t volume's unit cube (at most :data:`MAJORANT_CELLS` cells an axis) bounds sigma_t: each cell
holds the largest sigma_t of any channel of any voxel a point of the cell may read (:func:`majorant_grid`), and a ray
walks the cells it crosses (:func:`advance`: the majorant is constant in each, so its exponential distances are
drawn cell by cell).  With the majorant of the cell a tentative collision falls in,

* a free flight is *delta tracked*: tentative collisions at the majorant's exponential distances; at each, the
  path scatters with probability P_s = mean(sigma_s) / (mean(sigma_s) + mean(sigma_n)) (the channels' means;
  sigma_n = majorant - sigma_t, the null coefficient) and goes on otherwise, its throughput multiplied per channel
  by sigma_s,c / (majorant P_s) or by sigma_n,c / (majorant (1 - P_s)).  Every channel's expectation is that of
  its own collision density, so each stays unbiased for RGB coefficients, with weights bounded where the channels
  are alike (a grey medium: 1 - sigma_a / majorant per event; a constant grid: the albedo, the homogeneous case);
* a shadow ray's transmittance is *ratio tracked*: the product of sigma_n,c / majorant over the same tentative
  collisions, an unbiased estimate of exp(-integral of sigma_t,c).  Its random numbers come from a key hashed from
  the shadow ray's origin and direction (:func:`ray_key`), so that the callers of
  :func:`caustica.media.transmittance` keep their signatures and homogeneous scenes their numbers.

The grids live in columns of :class:`caustica.media.MediumTable` (:func:`grid_columns`): ``volumes`` (each
medium's sigma_t and albedo volume), ``grid_shape`` (nx, ny, nz, channels, first value, filter, wrap), ``grid_to_local``
(world to the unit cube, 3 x 4), ``voxels`` (every grid's float32 values, one after another), and each medium's
majorant grid: ``cells`` (cells along x, y, z, first value) and ``cell_majorant``.
"""
from __future__ import annotations

import math

import numpy as np

from .geometry import vec
from .jit import kernel
from .sampling.rng import mix64, uniform
from .scene.description import HETEROGENEOUS, NEAREST, REPEAT, Medium, Volume

#: Tentative collisions one tracked flight or shadow ray may take before it is given up (weight 0): a guard
#: against a majorant so large that a ray would never finish; 2**20 collisions is a majorant times distance of
#: about a million, optical depths no scene file means.
TRACKING_CAP = 1 << 20
#: The majorant grid's cells along an axis, at most (fewer for a grid of fewer voxels; one for a constant or a
#: repeated grid).  16³ cells: a 4 KB table per medium, whose walk costs a few cell steps a flight.
MAJORANT_CELLS = 16


def majorant_grid(vol: Volume) -> np.ndarray:
    """(cz, cy, cx): per cell of the unit cube split in at most MAJORANT_CELLS along each axis, the largest value of
    any channel of any voxel that a point of the cell reads (trilinear: voxels floor(x n - 1/2) and the next, which
    covers nearest's floor(x n); a point beyond the cube reads the edge's voxels, as the edge cells do)."""
    v = vol.data.max(axis=3)
    if vol.wrap == REPEAT:
        return np.full((1, 1, 1), v.max())
    for axis in range(3):
        n = v.shape[axis]
        cells = min(MAJORANT_CELLS, n)
        parts = []
        for i in range(cells):
            lo = max(math.floor(i * n / cells - 0.5), 0)
            hi = min(math.floor((i + 1) * n / cells - 0.5) + 1, n - 1)
            parts.append(np.take(v, np.arange(lo, hi + 1), axis=axis).max(axis=axis))
        v = np.stack(parts, axis=axis)
    return v


def grid_columns(media: list[Medium], k: int) -> dict:
    """The medium table's columns of the heterogeneous media among ``media`` (a scene's, ``k`` rows): kind, volumes,
    bounds, the grids and the majorant grids.  Homogeneous rows have volumes -1, no grid and one cell of majorant 0."""
    kind = np.zeros(k, np.int32)
    volumes = np.full((k, 2), -1, np.int32)
    bounds = np.zeros((k, 6))
    cells = np.tile(np.array([1, 1, 1, 0], np.int64), (k, 1))   # one cell, value 0: the rows of no grid
    majorants = [np.zeros(1)]
    grids: list[Volume] = []
    for i, m in enumerate(media):
        if m.kind != HETEROGENEOUS:
            continue
        cells[i, 3] = sum(a.size for a in majorants)
        kind[i] = HETEROGENEOUS
        for j, vol in enumerate((m.sigma_t_volume, m.albedo_volume)):
            volumes[i, j] = len(grids)
            grids.append(vol)
        maj = majorant_grid(m.sigma_t_volume)
        cells[i, :3] = maj.shape[::-1]
        majorants.append(maj.reshape(-1).astype(np.float64))
        lo, hi = m.sigma_t_volume.bounds() if m.bounded else ((-np.inf,) * 3, (np.inf,) * 3)
        bounds[i] = (*lo, *hi)
    shape = np.zeros((max(1, len(grids)), 7), np.int64)
    to_local = np.zeros((max(1, len(grids)), 12))
    first = 0
    for g, vol in enumerate(grids):
        nz, ny, nx, channels = vol.data.shape
        shape[g] = (nx, ny, nz, channels, first, vol.filter, vol.wrap)
        to_local[g] = np.asarray(vol.to_local, np.float64)[:3].reshape(12)
        first += vol.data.size
    voxels = np.concatenate([v.data.reshape(-1) for v in grids]) if grids else np.zeros(1, np.float32)
    return dict(kind=kind, volumes=volumes, bounds=bounds, grid_shape=shape, grid_to_local=to_local,
                voxels=np.ascontiguousarray(voxels, np.float32), cells=cells,
                cell_majorant=np.concatenate(majorants))


# ----------------------------------------------------------------------------- looking a volume up

@kernel(inline=True)
def _cell(f, n):
    """The voxel index of unit-cube coordinate times resolution f, clamped to [0, n - 1] (Mitsuba's clamp)."""
    return min(max(int(math.floor(min(max(f, -1.0), n + 1.0))), 0), n - 1)


@kernel(inline=True)
def _index(i, n, repeat):
    """Voxel index i (which may lie one beyond either end) of a row of n: wrapped round (repeat) or clamped."""
    if repeat:
        return (i + n) % n
    return min(max(i, 0), n - 1)


@kernel(inline=True)
def _voxel(media, g, ix, iy, iz):
    """Grid g's value at voxel (ix, iy, iz), as RGB (a grey grid's one channel three times)."""
    nx, ny, channels, first = media.grid_shape[g, 0], media.grid_shape[g, 1], media.grid_shape[g, 3], \
        media.grid_shape[g, 4]
    i = first + ((iz * ny + iy) * nx + ix) * channels
    v = media.voxels
    if channels == 3:
        return (float(v[i]), float(v[i + 1]), float(v[i + 2]))
    return (float(v[i]), float(v[i]), float(v[i]))


@kernel(inline=True)
def volume_at(media, g, p):
    """Grid volume g's value at world point p, RGB: voxel i's value sits at (i + 1/2) / n of the unit cube;
    trilinear between those centres, or the nearest voxel; beyond them the edge's value, or the grid repeated."""
    M = media.grid_to_local
    x = M[g, 0] * p[0] + M[g, 1] * p[1] + M[g, 2] * p[2] + M[g, 3]
    y = M[g, 4] * p[0] + M[g, 5] * p[1] + M[g, 6] * p[2] + M[g, 7]
    z = M[g, 8] * p[0] + M[g, 9] * p[1] + M[g, 10] * p[2] + M[g, 11]
    nx, ny, nz = media.grid_shape[g, 0], media.grid_shape[g, 1], media.grid_shape[g, 2]
    repeat = media.grid_shape[g, 6] == REPEAT
    if repeat:   # into [0, 1): the corners' indices then wrap round
        x, y, z = x - math.floor(x), y - math.floor(y), z - math.floor(z)
    if media.grid_shape[g, 5] == NEAREST:
        return _voxel(media, g, _cell(x * nx, nx), _cell(y * ny, ny), _cell(z * nz, nz))
    fx = min(max(x * nx - 0.5, -1.0), nx + 1.0)
    fy = min(max(y * ny - 0.5, -1.0), ny + 1.0)
    fz = min(max(z * nz - 0.5, -1.0), nz + 1.0)
    x0, y0, z0 = math.floor(fx), math.floor(fy), math.floor(fz)
    wx, wy, wz = fx - x0, fy - y0, fz - z0
    out = (0.0, 0.0, 0.0)
    for k in range(8):
        w = (wx if k & 1 else 1.0 - wx) * (wy if k & 2 else 1.0 - wy) * (wz if k & 4 else 1.0 - wz)
        if w > 0.0:
            c = _voxel(media, g, _index(int(x0) + (k & 1), nx, repeat), _index(int(y0) + (k >> 1 & 1), ny, repeat),
                       _index(int(z0) + (k >> 2 & 1), nz, repeat))
            out = vec.madd(out, c, w)
    return out


@kernel(inline=True)
def coefficients(media, m, p):
    """(sigma_t, sigma_s) per channel of heterogeneous medium m at world point p (scale applied)."""
    st = volume_at(media, media.volumes[m, 0], p)
    return st, vec.hadamard(st, volume_at(media, media.volumes[m, 1], p))


@kernel(inline=True)
def clip(media, m, o, d, t_max):
    """(t0, t1): the part of the ray o + t d, 0 <= t <= t_max, inside medium m's box (t0 >= t1: none)."""
    t0, t1 = 0.0, t_max
    for a in range(3):
        lo, hi = media.bounds[m, a], media.bounds[m, a + 3]
        if d[a] != 0.0:
            ta, tb = (lo - o[a]) / d[a], (hi - o[a]) / d[a]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        elif not lo <= o[a] <= hi:
            return 0.0, -1.0
    return t0, t1


# ----------------------------------------------------------------------------- the majorant grid's walk

@kernel(inline=True)
def _axis_exit(x0, dx, i, cells):
    """Where (in t) the ray x0 + t dx leaves cell i of ``cells`` along one axis of the unit cube: at the plane between
    it and the next cell it moves towards, never at the cube's faces (beyond them the edge cell goes on); inf if the
    ray does not move towards another cell."""
    if dx > 0.0 and i < cells - 1:
        return ((i + 1) / cells - x0) / dx
    if dx < 0.0 and i > 0:
        return (i / cells - x0) / dx
    return np.inf


@kernel(inline=True)
def walk_start(media, m, ray, t):
    """The walk of ``ray`` = (o, d) through medium m's majorant cells from t: (local ray, state), the local ray the
    sigma_t grid's unit-cube coordinates o' + t d' (an affine map keeps t), the state (t, ix, iy, iz, tx, ty, tz),
    the cell and the t where the ray leaves it along each axis."""
    o, d = ray
    M, g = media.grid_to_local, media.volumes[m, 0]
    ol = (M[g, 0] * o[0] + M[g, 1] * o[1] + M[g, 2] * o[2] + M[g, 3],
          M[g, 4] * o[0] + M[g, 5] * o[1] + M[g, 6] * o[2] + M[g, 7],
          M[g, 8] * o[0] + M[g, 9] * o[1] + M[g, 10] * o[2] + M[g, 11])
    dl = (M[g, 0] * d[0] + M[g, 1] * d[1] + M[g, 2] * d[2], M[g, 4] * d[0] + M[g, 5] * d[1] + M[g, 6] * d[2],
          M[g, 8] * d[0] + M[g, 9] * d[1] + M[g, 10] * d[2])
    cx, cy, cz = media.cells[m, 0], media.cells[m, 1], media.cells[m, 2]
    ix = _cell((ol[0] + t * dl[0]) * cx, cx)
    iy = _cell((ol[1] + t * dl[1]) * cy, cy)
    iz = _cell((ol[2] + t * dl[2]) * cz, cz)
    return (ol, dl), (t, ix, iy, iz, _axis_exit(ol[0], dl[0], ix, cx), _axis_exit(ol[1], dl[1], iy, cy),
                      _axis_exit(ol[2], dl[2], iz, cz))


@kernel
def advance(media, m, local, state, tau, t1):
    """The next tentative collision: the walk ``state`` (:func:`walk_start`) moved on by optical depth tau of the
    majorant, cell by cell.  Returns (state, the majorant there, True) at a collision before t1, else (state at t1,
    0, False)."""
    ol, dl = local
    t, ix, iy, iz, tx, ty, tz = state
    cx, cy, cz, first = media.cells[m, 0], media.cells[m, 1], media.cells[m, 2], media.cells[m, 3]
    for _ in range(cx + cy + cz + 3):   # a straight ray crosses at most cx + cy + cz cells
        mu = media.cell_majorant[first + (iz * cy + iy) * cx + ix]
        t_exit = min(min(tx, ty), min(tz, t1))
        if mu > 0.0:
            if mu * (t_exit - t) > tau:
                return (t + tau / mu, ix, iy, iz, tx, ty, tz), mu, True
            tau -= mu * max(t_exit - t, 0.0)
        t = max(t, t_exit)
        if t_exit >= t1:
            break
        if tx <= ty and tx <= tz:
            ix += 1 if dl[0] > 0.0 else -1
            tx = _axis_exit(ol[0], dl[0], ix, cx)
        elif ty <= tz:
            iy += 1 if dl[1] > 0.0 else -1
            ty = _axis_exit(ol[1], dl[1], iy, cy)
        else:
            iz += 1 if dl[2] > 0.0 else -1
            tz = _axis_exit(ol[2], dl[2], iz, cz)
    return (t1, ix, iy, iz, tx, ty, tz), 0.0, False


# ----------------------------------------------------------------------------- tracking

@kernel
def delta_tracking(media, m, ray, t_max, key, dim):
    """A free flight in heterogeneous medium m along ``ray`` = (o, d) up to t_max (the next surface, or inf):
    (t, scattered, weight per channel, dim past the numbers used).  Scattered: a real collision at t, the weight
    sigma_s,c / (mu P_s) times the null collisions' before it (mu: the majorant of the cell); otherwise the flight
    passed t_max (or left the medium's box for good) with the null collisions' weight, t = t_max.  Numbers dim,
    dim + 1, ... of key, two per tentative collision."""
    w = (1.0, 1.0, 1.0)
    t, t1 = clip(media, m, ray[0], ray[1], t_max)
    if not t < t1:
        return t_max, False, w, dim
    local, state = walk_start(media, m, ray, t)
    for _ in range(TRACKING_CAP):
        state, mu, hit = advance(media, m, local, state, -math.log(1.0 - uniform(key, dim)), t1)
        if not hit:
            return t_max, False, w, dim + 1
        t = state[0]
        st, ss = coefficients(media, m, vec.madd(ray[0], ray[1], t))
        sn = (max(mu - st[0], 0.0), max(mu - st[1], 0.0), max(mu - st[2], 0.0))
        ms, mn = vec.mean(ss), vec.mean(sn)
        if not ms + mn > 0.0:   # all absorption: the path ends here
            return t, False, (0.0, 0.0, 0.0), dim + 1
        p_s = ms / (ms + mn)
        if uniform(key, dim + 1) < p_s:
            return t, True, vec.hadamard(w, vec.mul(ss, 1.0 / (mu * p_s))), dim + 2
        w = vec.hadamard(w, vec.mul(sn, 1.0 / (mu * (1.0 - p_s))))
        dim += 2
    return t, False, (0.0, 0.0, 0.0), dim


@kernel(inline=True)
def _null_factors(media, m, ray, t, mu, T):
    """T times, per channel, the factor sigma_n / mu = max(mu - sigma_t, 0) / mu of a tentative collision at t of
    ``ray`` in heterogeneous medium m (mu: the majorant there): ratio tracking's step."""
    st = volume_at(media, media.volumes[m, 0], vec.madd(ray[0], ray[1], t))
    return T[0] * max(mu - st[0], 0.0) / mu, T[1] * max(mu - st[1], 0.0) / mu, T[2] * max(mu - st[2], 0.0) / mu


@kernel
def ratio_tracking(media, m, ray, s, key):
    """Per channel, an unbiased estimate of exp(-integral of sigma_t over [0, s]) along ``ray`` = (o, d) in
    heterogeneous medium m: the product of sigma_n,c / mu at the majorant's tentative collisions (mu: the majorant
    of the cell; numbers 0, 1, ... of key)."""
    T = (1.0, 1.0, 1.0)
    t, t1 = clip(media, m, ray[0], ray[1], s)
    if not t < t1:
        return T
    local, state = walk_start(media, m, ray, t)
    for i in range(TRACKING_CAP):
        state, mu, hit = advance(media, m, local, state, -math.log(1.0 - uniform(key, i)), t1)
        if not hit:
            return T
        T = _null_factors(media, m, ray, state[0], mu, T)
        if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
            return T
    return (0.0, 0.0, 0.0)


@kernel
def ratio_tracking_steps(media, m, ray, s, key, out):
    """:func:`ratio_tracking` over [0, s] walked once, for many distances along the ray: ``out`` = (t, T) arrays,
    t[j] the j-th tentative collision and T[j] (RGB) the product of the factors up to it (:func:`_null_factors`); so
    ratio_tracking(media, m, ray, x, key) for x <= s is T[j - 1] with j the collisions before x (1 for none), the same
    collisions from the same numbers.  Returns (n, ended): the collisions written, and whether the walk reached s (or T fell to 0, where
    every later estimate is 0); with ``ended`` False the arrays filled up first, and a distance past t[n - 1] needs
    ratio_tracking itself."""
    out_t, out_T = out
    T = (1.0, 1.0, 1.0)
    t, t1 = clip(media, m, ray[0], ray[1], s)
    if not t < t1:
        return 0, True
    local, state = walk_start(media, m, ray, t)
    for i in range(out_t.shape[0]):
        state, mu, hit = advance(media, m, local, state, -math.log(1.0 - uniform(key, i)), t1)
        if not hit:
            return i, True
        T = _null_factors(media, m, ray, state[0], mu, T)
        out_t[i] = state[0]
        out_T[i, 0] = T[0]
        out_T[i, 1] = T[1]
        out_T[i, 2] = T[2]
        if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
            return i + 1, True
    return out_t.shape[0], False


@kernel(inline=True)
def _mix_float(k, x):
    """Key k mixed with every bit of float x (its mantissa and exponent, by frexp)."""
    f, e = math.frexp(x)
    k = mix64(k ^ np.uint64(int(abs(f) * 9007199254740992.0)))
    return mix64(k ^ np.uint64(e + 4096 + (8192 if f < 0.0 else 0)))


@kernel(inline=True)
def ray_key(o, d):
    """The key of a shadow ray's ratio-tracking numbers: a hash of its origin's and direction's bits (a point
    sampled by the path's own numbers, so a stream of its own for each shadow ray, the same for any thread)."""
    k = np.uint64(0x5851F42D4C957F2D)
    for x in (o[0], o[1], o[2], d[0], d[1], d[2]):
        k = _mix_float(k, x)
    return k

