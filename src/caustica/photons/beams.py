"""The beam radiance estimate along camera segments (Jarosz, Zwicker & Jensen 2008), over one pass's volume photons.

Every volume photon of the pass is a sphere of radius r (the pass's volume radius).  A camera
segment (origin o, unit direction d, length s, in medium m, throughput β at o) gathers every
photon whose sphere it pierces with its projection t_i = (x_i − o)·d inside [0, s]:

    L_m ≈ β Σ_i T(t_i) p(ω_i → −d) Φ_i / (π r²)

T(t) = exp(−σt t) per channel, p the medium's phase function, ω_i the photon's direction of
travel and Φ_i its stored power, which already holds σs / σt and the transmittance of its
flight (:mod:`caustica.photons.trace`): with photons stored at scattering events, Σ Φ_i
δ(x − x_i) δ(ω − ω_i) estimates σs L, and the 2-D kernel 1 / (π r²) across the segment
turns the integral of T σs p L along it into that sum.  Where the segment starts or ends at a wall of its
medium (:class:`~caustica.photons.segments.CameraSegments`), the disc is cut there: photons beyond the wall's
plane are left out and the others weighted by 1 / the part of the disc inside (:func:`_walls_weight`), so the
empty part past the medium is not read as a density of zero.  The kernel is 2-D (across the beam),
so its progressive radius follows the 2-D rule of Knaus & Zwicker 2011: r_p² ∝ ∏ (i + α) / (i + 1),
the surfaces' global schedule (docs/media.md).

**The grid.**  One radius for every photon of a pass makes a uniform grid natural: cells of
side c ≥ 2 r, each photon entered in every cell its sphere's bounding box overlaps (at most 8).
A segment then only visits the cells it passes through (3-D DDA, Amanatides & Woo 1987), and
every photon whose sphere it pierces is entered in the cell that holds the segment's point
nearest to it — the point at t_i, within r of the photon.  A photon found in a visited cell
is counted there only if t_i lies in that cell's stretch [t_enter, t_exit) of the segment, so a
photon entered in several visited cells counts once.  The cells are folded into a power of two
of buckets (cell key mod buckets), as in :mod:`caustica.photons.grid`, so building is a counting
sort in O(entries) however small r gets; an entry stores its cell key and the photon's index.
A pixel-parallel gather needs no atomics: the same bits for any thread count.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..features import has
from ..geometry import vec
from ..jit import borrowed, kernel
from ..media import phase_value
from ..memory import check_budget
from ..scene.description import HETEROGENEOUS
from ..volumes import ratio_tracking, ratio_tracking_steps, ray_key
from .grid import MAX_DIM, bucket_count
from .kdtree import depth_left

#: Cells are this many photon radii across (>= 2, so a sphere overlaps at most 2 cells a side).
CELL_PER_RADIUS = 2.0


class VolumeGrid(NamedTuple):
    lo: np.ndarray         # float64[3]: low corner of the grid's box
    cell: np.ndarray       # float64[1]: side of a cell
    radius: np.ndarray     # float64[1]: the photons' radius r
    dims: np.ndarray       # int64[3]
    start: np.ndarray      # int64[buckets + 1]: entries of bucket b are start[b] .. start[b + 1]
    key: np.ndarray        # int64[entries]: each entry's cell key
    photon: np.ndarray     # int32[entries]: each entry's photon
    position: np.ndarray   # float32[n, 3]
    direction: np.ndarray  # float32[n, 3]: direction of travel at the event
    power: np.ndarray      # float32[n, 3]
    depth: np.ndarray      # uint16[n]: segments from the light to the event (a render's max_depth limits them)

    @property
    def count(self) -> int:
        return self.position.shape[0]

    @property
    def entries(self) -> int:
        return self.key.shape[0]


@kernel(inline=True)
def _index(x, lo, inv, dim):
    return min(max(int(math.floor((x - lo) * inv)), 0), dim - 1)


@kernel
def _count_entries(position, r, lo, inv, dims):
    n = 0
    for i in range(position.shape[0]):
        nx = _index(position[i, 0] + r, lo[0], inv, dims[0]) - _index(position[i, 0] - r, lo[0], inv, dims[0]) + 1
        ny = _index(position[i, 1] + r, lo[1], inv, dims[1]) - _index(position[i, 1] - r, lo[1], inv, dims[1]) + 1
        nz = _index(position[i, 2] + r, lo[2], inv, dims[2]) - _index(position[i, 2] - r, lo[2], inv, dims[2]) + 1
        n += nx * ny * nz
    return n


@kernel
def _fill(position, r, lo, inv, dims, start, out_key, out_photon):
    """Counting sort of the (photon, cell) entries by bucket: counts, prefix sum, placement from the back."""
    n_buckets = start.shape[0] - 1
    mask = n_buckets - 1
    for rnd in range(2):
        if rnd == 1:
            for b in range(n_buckets):
                start[b + 1] += start[b]
        for ii in range(position.shape[0]):
            i = ii if rnd == 0 else position.shape[0] - 1 - ii
            x0 = _index(position[i, 0] - r, lo[0], inv, dims[0])
            x1 = _index(position[i, 0] + r, lo[0], inv, dims[0])
            y0 = _index(position[i, 1] - r, lo[1], inv, dims[1])
            y1 = _index(position[i, 1] + r, lo[1], inv, dims[1])
            z0 = _index(position[i, 2] - r, lo[2], inv, dims[2])
            z1 = _index(position[i, 2] + r, lo[2], inv, dims[2])
            for ix in range(x1, x0 - 1, -1):
                for iy in range(y1, y0 - 1, -1):
                    for iz in range(z1, z0 - 1, -1):
                        k = (ix * dims[1] + iy) * dims[2] + iz
                        b = k & mask
                        if rnd == 0:
                            start[b + 1] += 1
                        else:
                            j = start[b + 1] - 1
                            start[b + 1] = j
                            out_key[j] = k
                            out_photon[j] = i
    for b in range(n_buckets):
        start[b] = start[b + 1]
    start[n_buckets] = out_key.shape[0]


def volume_grid_compiled() -> bool:
    """Whether the grid's kernels are compiled (or loaded) in this process: the first build's time is compile time."""
    return _fill.compiled_for_python()


def build_volume_grid(position, direction, power, radius: float, depth=None) -> VolumeGrid:
    """The grid over these volume photons (float32 arrays, already compacted) as spheres of ``radius``; ``depth``:
    each one's segments from its light (None: photons made without a path, a test's, which every max_depth
    admits)."""
    position = np.ascontiguousarray(position, np.float32)
    n = position.shape[0]
    r = float(radius)
    if n:
        lo = position.min(axis=0).astype(np.float64) - 2.0 * r
        hi = position.max(axis=0).astype(np.float64) + 2.0 * r
    else:
        lo, hi = np.zeros(3), np.ones(3)
    ext = np.maximum(hi - lo, 1e-9)
    cell = max(CELL_PER_RADIUS * r, float(ext.max()) / MAX_DIM, 1e-9)
    dims = np.minimum(MAX_DIM, np.maximum(1, np.ceil(ext / cell).astype(np.int64)))
    inv = 1.0 / cell
    entries = _count_entries(position, r, lo, inv, dims) if n else 0
    # each photon is in the cells its sphere overlaps (at most 8: cells are >= 2 r); its key and index
    check_budget(entries * 12 + 8 * bucket_count(entries, int(np.prod(dims))),
                 f"the volume photons' grid ({n:,} photons, {entries:,} cell entries)",
                 "lower the photons (or streams) per pass")
    start = np.zeros(bucket_count(entries, int(np.prod(dims))) + 1, np.int64)
    key = np.empty(entries, np.int64)
    photon = np.empty(entries, np.int32)
    if n:
        _fill(position, r, lo, inv, dims, start, key, photon)
    return VolumeGrid(lo, np.array([cell]), np.array([r]), dims, start, key, photon, position,
                      np.ascontiguousarray(direction, np.float32), np.ascontiguousarray(power, np.float32),
                      np.zeros(n, np.uint16) if depth is None else np.ascontiguousarray(depth, np.uint16))


@kernel(inline=True)
def _clip_to_grid(vg, o, d, s):
    """The part (t0, t1) of the segment (o, d, [0, s]) inside the grid's box; none when not t0 < t1."""
    c = vg.cell[0]
    lo = vg.lo
    dims = vg.dims
    t0 = 0.0
    t1 = s
    for k in range(3):
        hi = lo[k] + dims[k] * c
        if d[k] != 0.0:
            ta = (lo[k] - o[k]) / d[k]
            tb = (hi - o[k]) / d[k]
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
        elif o[k] < lo[k] or o[k] > hi:
            return 0.0, -1.0
    return t0, t1


@kernel(inline=True)
def _dda_start(vg, o, d, t0):
    """A 3-D DDA from the point at t0 (Amanatides & Woo): per axis the cell, the step, the t of the
    next cell boundary and the t between boundaries."""
    c = vg.cell[0]
    lo = vg.lo
    dims = vg.dims
    inv = 1.0 / c
    ix = _index(o[0] + d[0] * t0, lo[0], inv, dims[0])   # the cell where the clipped segment starts
    iy = _index(o[1] + d[1] * t0, lo[1], inv, dims[1])
    iz = _index(o[2] + d[2] * t0, lo[2], inv, dims[2])
    sx = 1 if d[0] > 0.0 else -1
    sy = 1 if d[1] > 0.0 else -1
    sz = 1 if d[2] > 0.0 else -1
    nx = (lo[0] + (ix + (1 if sx > 0 else 0)) * c - o[0]) / d[0] if d[0] != 0.0 else np.inf
    ny = (lo[1] + (iy + (1 if sy > 0 else 0)) * c - o[1]) / d[1] if d[1] != 0.0 else np.inf
    nz = (lo[2] + (iz + (1 if sz > 0 else 0)) * c - o[2]) / d[2] if d[2] != 0.0 else np.inf
    dx = c / abs(d[0]) if d[0] != 0.0 else np.inf
    dy = c / abs(d[1]) if d[1] != 0.0 else np.inf
    dz = c / abs(d[2]) if d[2] != 0.0 else np.inf
    return (ix, iy, iz), (sx, sy, sz), (nx, ny, nz), (dx, dy, dz)


@kernel(inline=True)
def _wall(n, d, s, r):
    """A wall of normal n (turned into the medium; zero: none) through the point at s of a segment along d, as
    :func:`_add_cell` cuts the disc with it: (n, h0, n·d, 1 / (r sin θ), e) — a photon at v from the segment's origin
    is beyond it where v·n < h0; the disc at t has its centre (t n·d - h0) in front of the wall, a distance x of
    r sin θ, and the disc's part beyond lies towards -e (e: n across the segment, a unit vector).  1 / (r sin θ) is 0
    where nothing is cut: no wall, or one across the segment."""
    nd = vec.dot(n, d)
    sin_t = math.sqrt(max(1.0 - nd * nd, 0.0))
    if sin_t * r <= 0.0 or not vec.dot(n, n) > 0.0:
        return n, 0.0, nd, 0.0, n
    return n, s * nd, nd, 1.0 / (sin_t * r), vec.mul(vec.madd(n, d, -nd), 1.0 / sin_t)


@kernel(inline=True)
def _disc_inside(x):
    """The fraction of a unit disc on the near side of a line at distance x >= 0 beyond its centre."""
    if x >= 1.0:
        return 1.0
    return 1.0 - (math.acos(x) - x * math.sqrt(1.0 - x * x)) / math.pi


#: Points of the quadrature of :func:`_disc_inside_two` in each of its (at most three) smooth pieces.
TWO_CUT_POINTS = 16


@kernel(inline=True)
def _chords_inside(phi, x1, a, b):
    """The part of the chord y = cos φ e0 + τ f (|τ| <= sin φ) of the unit disc with y·e1 >= -x1, e1 = a e0 + b f, times
    sin φ (the chords' measure ds = sin φ dφ)."""
    c = math.cos(phi)
    w = math.sin(phi)
    lo, hi = -w, w
    bound = -x1 - c * a   # τ b >= bound
    if abs(b) < 1e-12:
        if bound > 0.0:
            hi = lo
    elif b > 0.0:
        lo = max(lo, bound / b)
    else:
        hi = min(hi, bound / b)
    return (hi - lo) * w if hi > lo else 0.0


@kernel(inline=True)
def _disc_inside_two(x0, x1, a, b):
    """The fraction of a unit disc on the near side of two lines: {y·e0 >= -x0} ∩ {y·e1 >= -x1}, x0, x1 >= 0, with
    e1 = a e0 + b f (f ⊥ e0 in the disc's plane).  Over the chords y = cos φ e0 + τ f, φ from 0 to acos(-x0), of the
    part of each on the near side of the second line (:func:`_chords_inside`): smooth in φ between the points where
    the second line meets the circle, so the midpoint rule in each piece between them."""
    phi_max = math.acos(-min(x0, 1.0))
    # the second line meets the circle at s = y·e0 = -x1 a -+ b sqrt(1 - x1²)
    root = b * math.sqrt(max(1.0 - x1 * x1, 0.0))
    p1 = math.acos(min(max(-x1 * a - root, -1.0), 1.0))
    p2 = math.acos(min(max(-x1 * a + root, -1.0), 1.0))
    if p1 > p2:
        p1, p2 = p2, p1
    area = 0.0
    lo = 0.0
    for piece in range(3):
        hi = min(p1, phi_max) if piece == 0 else (min(p2, phi_max) if piece == 1 else phi_max)
        if hi > lo:
            h = (hi - lo) / TWO_CUT_POINTS
            for j in range(TWO_CUT_POINTS):
                area += _chords_inside(lo + (j + 0.5) * h, x1, a, b) * h
            lo = hi
    return area / math.pi


@kernel(inline=True)
def _walls_weight(walls, v, t):
    """1 / the fraction of the disc at t inside both walls (:func:`_wall`) for a photon at v from the segment's
    origin; 0 for a photon beyond either wall.  ``walls`` = (start wall, end wall, (a, b): the end wall's e in the
    start wall's frame, :func:`_disc_inside_two`)."""
    start, end, (a, b) = walls
    x0 = x1 = 1.0
    for k in range(2):
        n, h0, nd, inv, _ = start if k == 0 else end
        if inv > 0.0:
            if v[0] * n[0] + v[1] * n[1] + v[2] * n[2] < h0:
                return 0.0
            x = (t * nd - h0) * inv
            if k == 0:
                x0 = x
            else:
                x1 = x
    if x0 >= 1.0 and x1 >= 1.0:
        return 1.0
    if x1 >= 1.0:
        return 1.0 / _disc_inside(x0)
    if x0 >= 1.0:
        return 1.0 / _disc_inside(x1)
    return 1.0 / _disc_inside_two(x0, x1, a, b)


#: The collisions of a segment's ratio-tracking walk kept for its photons (:func:`segment_estimate`); a photon past
#: the last of a walk that fills them is tracked on its own.
TRACKING_STEPS = 1024


@kernel(inline=True)
def _add_cell(vg, media, seg, k, span, acc, limit):
    """Add to ``acc`` = (a0, a1, a2, found) the photons of grid cell k whose spheres the segment pierces
    with its closest approach t in ``span`` = [t_enter, t_exit); ``seg`` = (o, d, m, r2, walls).  Photons deeper than
    ``limit`` are left out, unless it is None (Numba prunes the test then: a compilation of its own).  At a wall
    (:func:`_wall`) the disc across the segment is cut: photons beyond it are left out and the others weighted by
    1 / the fraction of the disc left (:func:`_walls_weight`), so a disc that reaches past the medium does not
    count the empty part as a density of zero.  In a heterogeneous medium each photon's T(t) is ratio tracked, with
    the numbers of the segment's own transmittance (:func:`caustica.media.segment_attenuation`: one estimate of T
    along the segment, read at each photon): read from the segment's walk, ``seg[5]`` = (key, (t, T) of its
    collisions, their count, whether the walk ended: :func:`caustica.volumes.ratio_tracking_steps`), or tracked
    again past a walk that filled its arrays."""
    o, d, m, r2, walls, (key, (step_t, step_T), n_steps, ended) = seg
    t_enter, t_exit = span
    a0, a1, a2, found = acc
    tracked = has(media, HETEROGENEOUS) and media.kind[m] == HETEROGENEOUS
    st0 = media.sigma_t[m, 0]
    st1 = media.sigma_t[m, 1]
    st2 = media.sigma_t[m, 2]
    grey = st0 == st1 and st1 == st2   # one exponential per photon (the same bits as three)
    wo = (-d[0], -d[1], -d[2])
    b = k & (vg.start.shape[0] - 2)
    for j in range(vg.start[b], vg.start[b + 1]):
        if vg.key[j] != k:
            continue
        i = vg.photon[j]
        if limit is not None:
            if vg.depth[i] > limit:
                continue
        vx = vg.position[i, 0] - o[0]
        vy = vg.position[i, 1] - o[1]
        vz = vg.position[i, 2] - o[2]
        ti = vx * d[0] + vy * d[1] + vz * d[2]
        if ti < t_enter or ti >= t_exit:
            continue
        d2 = vx * vx + vy * vy + vz * vz - ti * ti
        if d2 > r2:
            continue
        cut = _walls_weight(walls, (vx, vy, vz), ti)
        if cut == 0.0:
            continue
        wi = (float(vg.direction[i, 0]), float(vg.direction[i, 1]), float(vg.direction[i, 2]))
        ph = phase_value(media, m, wi, wo) * cut
        if tracked:
            j = np.searchsorted(step_t[:n_steps], ti)   # the collisions before ti
            if j == n_steps and not ended:
                T = ratio_tracking(media, m, (o, d), ti, key)
            elif j == 0:
                T = (1.0, 1.0, 1.0)
            else:
                T = (step_T[j - 1, 0], step_T[j - 1, 1], step_T[j - 1, 2])
            a0 += T[0] * ph * vg.power[i, 0]
            a1 += T[1] * ph * vg.power[i, 1]
            a2 += T[2] * ph * vg.power[i, 2]
        elif grey:
            w = math.exp(-st0 * ti) * ph
            a0 += w * vg.power[i, 0]
            a1 += w * vg.power[i, 1]
            a2 += w * vg.power[i, 2]
        else:
            a0 += math.exp(-st0 * ti) * ph * vg.power[i, 0]
            a1 += math.exp(-st1 * ti) * ph * vg.power[i, 1]
            a2 += math.exp(-st2 * ti) * ph * vg.power[i, 2]
        found += 1
    return a0, a1, a2, found


@kernel
def segment_estimate(vg, media, segment, m, limit, steps):
    """Σ_i T(t_i) p(ω_i → −d) Φ_i over the photons whose spheres the segment (o, d, [0, s]) in m pierces (those of
    depth ``limit`` at most; every one for None); ``segment`` = (o, d, s, (the normals of the walls at its start and
    end, turned into the medium; zero: none)), each photon weighted as :func:`_walls_weight` says.  ``steps``:
    scratch (t, T) arrays for the segment's ratio-tracking walk in a heterogeneous medium, walked once for all its
    photons.

    Without β and the 1 / (π r²): :func:`beam_gather` applies both.  Also returns the photons counted.
    The segment walks the grid's cells in order (a DDA), each photon counted in the cell of its
    closest approach.
    """
    o, d, s, (start_wall, end_wall) = segment
    acc = (0.0, 0.0, 0.0, 0)
    if vg.position.shape[0] == 0:
        return (0.0, 0.0, 0.0), 0
    t0, t1 = _clip_to_grid(vg, o, d, s)
    if not t0 < t1:
        return (0.0, 0.0, 0.0), 0
    dims = vg.dims
    cell, step, nxt, delta = _dda_start(vg, o, d, t0)
    ix, iy, iz = cell
    sx, sy, sz = step
    nx, ny, nz = nxt
    dx, dy, dz = delta
    r = vg.radius[0]
    start, end = _wall(start_wall, d, 0.0, r), _wall(end_wall, d, s, r)
    e0, e1 = start[4], end[4]
    walls = (start, end, (vec.dot(e1, e0), vec.dot(e1, vec.cross(d, e0))))
    tracked = has(media, HETEROGENEOUS) and media.kind[m] == HETEROGENEOUS
    key = np.uint64(0)
    n_steps, ended = 0, True
    if tracked:
        key = ray_key(o, d)   # the segment's ratio-tracking numbers, the same for each photon
        n_steps, ended = ratio_tracking_steps(media, m, (o, d), s, key, steps)
    seg = (o, d, m, r * r, walls, (key, steps, n_steps, ended))
    t_enter = t0
    while t_enter < t1:
        t_exit = min(min(nx, ny), min(nz, t1))
        acc = _add_cell(vg, media, seg, (ix * dims[1] + iy) * dims[2] + iz, (t_enter, t_exit), acc, limit)
        if t_exit >= t1:
            break
        if nx <= ny and nx <= nz:
            ix += sx
            if ix < 0 or ix >= dims[0]:
                break
            nx += dx
        elif ny <= nz:
            iy += sy
            if iy < 0 or iy >= dims[1]:
                break
            ny += dy
        else:
            iz += sz
            if iz < 0 or iz >= dims[2]:
                break
            nz += dz
        t_enter = t_exit
    return (acc[0], acc[1], acc[2]), acc[3]


@kernel
def beam_gather(vg, media, camera, out, i0, i1):
    """Pixels [i0, i1) of ``camera`` = (segments, per_pixel, max_depth): the camera's segments
    (:class:`~caustica.photons.segments.CameraSegments`, per_pixel slots a pixel) into ``out`` = (radiance, found),
    radiance[i] = Σ over its segments of β Σ_i T p Φ_i / (π r²), found[i] the photons counted.  Under a max_depth
    (None: none) a segment after k surface vertices takes the photons of depth max_depth - k - 1 at most."""
    vg, media = borrowed(vg), borrowed(media)
    segments, per_pixel, max_depth = camera
    seg_o, seg_d, seg_len, seg_beta, seg_medium, seg_vertices, seg_start, seg_end, seg_count = segments
    out, found = out
    norm = 1.0 / (math.pi * vg.radius[0] * vg.radius[0])
    steps = (np.empty(TRACKING_STEPS), np.empty((TRACKING_STEPS, 3)))
    for i in range(i0, i1):
        acc0 = 0.0
        acc1 = 0.0
        acc2 = 0.0
        nf = 0
        for j in range(seg_count[i]):
            k = i * per_pixel + j
            o = (seg_o[k, 0], seg_o[k, 1], seg_o[k, 2])
            d = (seg_d[k, 0], seg_d[k, 1], seg_d[k, 2])
            walls = ((seg_start[k, 0], seg_start[k, 1], seg_start[k, 2]), (seg_end[k, 0], seg_end[k, 1], seg_end[k, 2]))
            a, f = segment_estimate(vg, media, (o, d, seg_len[k], walls), seg_medium[k],
                                    depth_left(max_depth, seg_vertices[k] + 1), steps)   # camera -> k vertices -> it
            acc0 += seg_beta[k, 0] * a[0]
            acc1 += seg_beta[k, 1] * a[1]
            acc2 += seg_beta[k, 2] * a[2]
            nf += f
        out[i, 0] = acc0 * norm
        out[i, 1] = acc1 * norm
        out[i, 2] = acc2 * norm
        found[i] = nf
