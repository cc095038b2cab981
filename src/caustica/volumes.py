"""Heterogeneous media: their grid volumes in the medium table, and free flights and transmittance through them
by null collisions (docs/media.md#heterogeneous-media).

A heterogeneous medium (Mitsuba 3's ``heterogeneous``) takes its extinction sigma_t(x) and its albedo(x) from
volumes, grids of voxels or constants (:class:`caustica.scene.description.Volume`), and, as in Mitsuba, exists
only inside the world box of its sigma_t volume: outside it a ray crosses vacuum.  Inside, each medium has one
scalar majorant, the largest sigma_t of any voxel and channel (scale applied), and

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

The grids live in four columns of :class:`caustica.media.MediumTable` (:func:`grid_columns`): ``volumes`` (each
medium's sigma_t and albedo volume), ``grid_shape`` (nx, ny, nz, channels, first value, filter, wrap), ``grid_to_local``
(world to the unit cube, 3 x 4) and ``voxels`` (every grid's float32 values, one after another).
"""
from __future__ import annotations

import math

import numpy as np

from .geometry import vec
from .jit import kernel
from .sampling.rng import mix64, uniform
from .scene.description import HETEROGENEOUS, NEAREST, REPEAT, SceneDescription, Volume

#: Tentative collisions one tracked flight or shadow ray may take before it is given up (weight 0): a guard
#: against a majorant so large that a ray would never finish; 2**20 collisions is a majorant times distance of
#: about a million, optical depths no scene file means.
TRACKING_CAP = 1 << 20


def grid_columns(desc: SceneDescription, k: int) -> dict:
    """The medium table's columns of the heterogeneous media among ``desc.media`` (``k`` rows): kind, volumes,
    majorant, bounds and the grids.  Homogeneous rows have volumes -1 and no grid."""
    kind = np.zeros(k, np.int32)
    volumes = np.full((k, 2), -1, np.int32)
    majorant = np.zeros(k)
    bounds = np.zeros((k, 6))
    grids: list[Volume] = []
    for i, m in enumerate(desc.media):
        if m.kind != HETEROGENEOUS:
            continue
        kind[i] = HETEROGENEOUS
        for j, vol in enumerate((m.sigma_t_volume, m.albedo_volume)):
            volumes[i, j] = len(grids)
            grids.append(vol)
        majorant[i] = float(m.sigma_t_volume.data.max())
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
    return dict(kind=kind, volumes=volumes, majorant=majorant, bounds=bounds, grid_shape=shape,
                grid_to_local=to_local, voxels=np.ascontiguousarray(voxels, np.float32))


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


# ----------------------------------------------------------------------------- tracking

@kernel
def delta_tracking(media, m, ray, t_max, key, dim):
    """A free flight in heterogeneous medium m along ``ray`` = (o, d) up to t_max (the next surface, or inf):
    (t, scattered, weight per channel, dim past the numbers used).  Scattered: a real collision at t, the weight
    sigma_s,c / (majorant P_s) times the null collisions' before it; otherwise the flight passed t_max (or left
    the medium's box for good) with the null collisions' weight, t = t_max.  Numbers dim, dim + 1, ... of key,
    two per tentative collision."""
    o, d = ray
    w = (1.0, 1.0, 1.0)
    mu = media.majorant[m]
    t, t1 = clip(media, m, o, d, t_max)
    if not (t < t1 and mu > 0.0):
        return t_max, False, w, dim
    for _ in range(TRACKING_CAP):
        t -= math.log(1.0 - uniform(key, dim)) / mu
        if t >= t1:
            return t_max, False, w, dim + 1
        st, ss = coefficients(media, m, vec.madd(o, d, t))
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


@kernel
def ratio_tracking(media, m, ray, s, key):
    """Per channel, an unbiased estimate of exp(-integral of sigma_t over [0, s]) along ``ray`` = (o, d) in
    heterogeneous medium m: the product of sigma_n,c / majorant at the majorant's tentative collisions (numbers
    0, 1, ... of key)."""
    o, d = ray
    T = (1.0, 1.0, 1.0)
    mu = media.majorant[m]
    t, t1 = clip(media, m, o, d, s)
    if not (t < t1 and mu > 0.0):
        return T
    for i in range(TRACKING_CAP):
        t -= math.log(1.0 - uniform(key, i)) / mu
        if t >= t1:
            return T
        st = volume_at(media, media.volumes[m, 0], vec.madd(o, d, t))
        T = (T[0] * max(mu - st[0], 0.0) / mu, T[1] * max(mu - st[1], 0.0) / mu, T[2] * max(mu - st[2], 0.0) / mu)
        if T[0] == 0.0 and T[1] == 0.0 and T[2] == 0.0:
            return T
    return (0.0, 0.0, 0.0)


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

