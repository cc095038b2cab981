"""A uniform grid over one pass's photon events, folded into buckets, for the progressive methods' gather.

SPPM asks, every pass and for every pixel, "which of this pass's photons lie within
R_i of my visible point?".  A kd-tree answers in O(log n + found) but costs a
median-split build per pass (O(n log n), the largest part of a pass in measurements);
a uniform grid with cells about as large as the radii is built by one counting sort
and answers by scanning the few cells the query's sphere overlaps.

Cells of side ``cell`` cover the box ``[lo, lo + dims * cell)``; cell (ix, iy, iz) has the
key ``(ix * dims[1] + iy) * dims[2] + iz``.  The events lie on surfaces, so most cells of
the box are empty: once the radii have shrunk, a dense table of every cell (a million
or more for 10^5 events) cost more to clear and to sum per pass than the sort itself.
So the cells are *folded* into a power of two of buckets, at least twice the events
(and no more than the cells): cell ``key`` lives in bucket ``key mod buckets``.  The
build is then O(events) whatever the radius, and a z-column's cells z0..z1 are still
consecutive buckets (one run, or two where the buckets wrap), so a query reads memory
as the dense grid did.  A bucket's events are entries ``start[b] .. start[b + 1]`` of
the sorted arrays (position, power, normal: structure of arrays, float32 like the
photon records) with their cells' keys: a query takes an event only if its key is one
of the cells it scans, so the cells that share a bucket never mix.  Points outside the
box are clamped into its border cells (the distance test stays exact).

A visible point on a BSDF that is not Lambertian (the diffuse lobes beside a glossy one, a diffuse lobe under a map)
weights each event by the lobes it holds at the event's direction (:func:`grid_range_sum`'s ``bsdf``), so the
grid then keeps the events' directions too (``direction``; empty otherwise).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..bsdfs import eval_photon, split_record_weight
from ..jit import kernel
from .density_filters import FILTER_NONE, filter_shape
from .kdtree import FACING_COS

#: Most cells along one axis (keys stay far inside int64).
MAX_DIM = 1 << 20


class PhotonGrid(NamedTuple):
    lo: np.ndarray        # float64[3], the box's low corner
    cell: np.ndarray      # float64[1], the side of a cell
    dims: np.ndarray      # int64[3], cells along x, y, z
    start: np.ndarray     # int64[buckets + 1]
    key: np.ndarray       # int64[n], each sorted event's cell key
    position: np.ndarray  # float32[n, 3], sorted by bucket
    power: np.ndarray     # float32[n, 3]
    normal: np.ndarray    # float32[n, 3]
    direction: np.ndarray  # float32[n, 3] (direction of travel) or float32[0, 3] when no visible point reads it
    # (The events' depths, when a finite max_depth needs them, are an array beside the grid, not a field: a tenth
    # array here made SPPM's two-grid gather 30 % slower with no depth read, measured 2026-12-05.)

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def memory_bytes(self) -> int:
        return int(sum(a.nbytes for a in self))


def grid_shape(box: np.ndarray, cell: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(low corner, cell side, dims) for cells of about ``cell`` over ``box`` (lo, hi), at most MAX_DIM a side."""
    lo = np.asarray(box[:3], np.float64)
    ext = np.maximum(np.asarray(box[3:], np.float64) - lo, 1e-9)
    cell = max(float(cell), float(ext.max()) / MAX_DIM, 1e-9)
    dims = np.minimum(MAX_DIM, np.maximum(1, np.ceil(ext / cell).astype(np.int64)))
    return lo, cell, dims


def bucket_count(n_events: int, n_cells: int) -> int:
    """Buckets: the least power of two >= 2 n_events (at least 1), and no more than needed for n_cells."""
    want = max(1, min(2 * n_events, n_cells))
    return 1 << (want - 1).bit_length()


@kernel
def _cell_of(px, py, pz, lo, inv, dims):
    ix = min(max(int(math.floor((px - lo[0]) * inv)), 0), dims[0] - 1)
    iy = min(max(int(math.floor((py - lo[1]) * inv)), 0), dims[1] - 1)
    iz = min(max(int(math.floor((pz - lo[2]) * inv)), 0), dims[2] - 1)
    return ix, iy, iz


@kernel(inline=True)
def _bucket(key, mask):
    return key & mask


@kernel
def _counting_sort(events, shape, out):
    """Sort the valid events, ``events`` = (position, power, normal, valid, direction, depth), by bucket of the grid
    ``shape`` = (lo, cell, dims) into ``out`` = (start, key, position, power, normal, direction, depth), stably
    (the directions, the depths, only when ``out``'s have rows); start receives the buckets' offsets.

    Counts, a prefix sum, then the events placed from the last one back, each at the end of its
    bucket's free part (a bucket's key is recomputed rather than stored: no temporary arrays).
    """
    position, power, normal, valid, direction, depth = events
    lo, cell, dims = shape
    start, out_key, out_pos, out_pow, out_nrm, out_dir, out_depth = out
    with_direction = out_dir.shape[0] > 0
    with_depth = out_depth.shape[0] > 0
    inv = 1.0 / cell
    n = position.shape[0]
    n_buckets = start.shape[0] - 1
    mask = n_buckets - 1
    for i in range(n):
        if valid[i] != 0:
            ix, iy, iz = _cell_of(position[i, 0], position[i, 1], position[i, 2], lo, inv, dims)
            start[_bucket((ix * dims[1] + iy) * dims[2] + iz, mask) + 1] += 1
    for b in range(n_buckets):
        start[b + 1] += start[b]
    # start[b + 1] is now the end of bucket b; filling from the back moves it to the bucket's beginning
    for i in range(n - 1, -1, -1):  # the same sorted arrays for any thread count
        if valid[i] == 0:
            continue
        ix, iy, iz = _cell_of(position[i, 0], position[i, 1], position[i, 2], lo, inv, dims)
        k = (ix * dims[1] + iy) * dims[2] + iz
        b = _bucket(k, mask)
        j = start[b + 1] - 1
        start[b + 1] = j
        out_key[j] = k
        for c in range(3):
            out_pos[j, c] = position[i, c]
            out_pow[j, c] = power[i, c]
            out_nrm[j, c] = normal[i, c]
        if with_direction:
            for c in range(3):
                out_dir[j, c] = direction[i, c]
        if with_depth:
            out_depth[j] = depth[i]
    # start[b + 1] holds bucket b's beginning: shift down by one, and close with the total
    for b in range(n_buckets):
        start[b] = start[b + 1]
    start[n_buckets] = out_key.shape[0]


def grid_compiled() -> bool:
    """Whether the grid's sort has been compiled (or loaded from the cache) in this process."""
    return _counting_sort.compiled_for_python()


def build_grid(position, power, normal, valid, box, cell, direction=None, depth=None):
    """(The grid of the events with ``valid`` != 0, cells of about ``cell`` over ``box`` (lo, hi), with their
    ``direction`` when given; their ``depth`` in the grid's order, or None when not given)."""
    lo, cell, dims = grid_shape(box, cell)
    valid = np.ascontiguousarray(valid, np.int8)
    n = int(np.count_nonzero(valid))
    start = np.zeros(bucket_count(n, int(np.prod(dims))) + 1, np.int64)
    key = np.empty(n, np.int64)
    out = [np.empty((n, 3), np.float32) for _ in range(3)]
    out_dir = np.empty((n if direction is not None else 0, 3), np.float32)
    if direction is None:
        direction = out_dir
    out_depth = np.empty(n if depth is not None else 0, np.uint16)
    given = depth is not None
    if not given:
        depth = out_depth
    _counting_sort((position, power, normal, valid, direction, depth), (lo, cell, dims),
                   (start, key, *out, out_dir, out_depth))
    return PhotonGrid(lo, np.array([cell]), dims, start, key, *out, out_dir), (out_depth if given else None)


@kernel
def grid_range_sum(grid, qp, qn, r, bsdf, limit, filt=FILTER_NONE, split=None):
    """Σ power over the events within r of qp whose normal faces qn (dot > FACING_COS), and their count.
    With ``limit`` = (deepest, the events' depths in the grid's order, :func:`build_grid`'s) only events of depth <=
    deepest count (a scene's max_depth: the segments the camera path took to qp leave the photon's path the rest);
    with None, every one (a separate compilation, as ``bsdf``'s).

    The same sidedness rule as the kd-tree's searches.  Returns (count, (Σ_0, Σ_1, Σ_2)), float64 sums.
    With a filter ``filt`` other than none (:mod:`~caustica.photons.density_filters`) each term is also weighted by
    its shape π r² W(d, r) (mean 1 over the disc), so the sums stay on the uniform disc's scale.
    With ``bsdf`` = (mats, m, d, ng, ns, uv) each event's power is weighted by material m's BSDF value
    f(d, -event direction) at a point of normals ng, ns (:func:`caustica.bsdfs.eval_photon`: the visible point's own,
    the camera path arriving along d); with ``bsdf`` None, plain sums (a separate compilation: Numba prunes the
    ``bsdf is not None`` branch, so the plain sum's code is what it was before BSDFs were weighed here).  With
    ``split`` = the diffuse lobe's factor A of a roughplastic's split point (m's), the events are caustic records
    carrying its factor B: each is weighted by :func:`caustica.bsdfs.split_record_weight` instead.
    """
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    count = 0
    if grid.position.shape[0] == 0 or r <= 0.0:
        return count, (s0, s1, s2)
    lo = grid.lo
    dims = grid.dims
    inv = 1.0 / grid.cell[0]
    mask = grid.start.shape[0] - 2
    x0, y0, z0 = _cell_of(qp[0] - r, qp[1] - r, qp[2] - r, lo, inv, dims)
    x1, y1, z1 = _cell_of(qp[0] + r, qp[1] + r, qp[2] + r, lo, inv, dims)
    r2 = r * r
    pos = grid.position
    nrm = grid.normal
    keys = grid.key
    for ix in range(x0, x1 + 1):
        for iy in range(y0, y1 + 1):
            # cells z0..z1 of this column are consecutive keys: consecutive buckets, in at most two runs
            # when the buckets wrap (or all of them, when the column is longer than the buckets)
            k0 = (ix * dims[1] + iy) * dims[2] + z0
            k1 = k0 + (z1 - z0)
            b0 = k0 & mask
            b1 = k1 & mask
            if k1 - k0 >= mask:
                b0 = 0
                b1 = mask
            runs = 1 if b1 >= b0 else 2
            for run in range(runs):
                if runs == 1:
                    a, e = grid.start[b0], grid.start[b1 + 1]
                elif run == 0:
                    a, e = grid.start[b0], grid.start[mask + 1]
                else:
                    a, e = grid.start[0], grid.start[b1 + 1]
                for j in range(a, e):
                    kj = keys[j]
                    if kj < k0 or kj > k1:
                        continue
                    dx = pos[j, 0] - qp[0]
                    dy = pos[j, 1] - qp[1]
                    dz = pos[j, 2] - qp[2]
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 <= r2:
                        if limit is not None and limit[1][j] > limit[0]:
                            continue
                        if nrm[j, 0] * qn[0] + nrm[j, 1] * qn[1] + nrm[j, 2] * qn[2] > FACING_COS:
                            count += 1
                            e0, e1, e2 = _gathered_power(grid, j, bsdf, filt, d2, r2, split)
                            s0 += e0
                            s1 += e1
                            s2 += e2
    return count, (s0, s1, s2)


@kernel(inline=True)
def _gathered_power(grid, j, bsdf, filt, d2, r2, split):
    """Event j's power as :func:`grid_range_sum` adds it, d² from the query within r²: times the filter's shape
    (exactly 1 for none, so the plain power's bits) and, with ``bsdf``, the BSDF's value at its direction (at a split
    point, ``split`` its factor A: :func:`caustica.bsdfs.split_record_weight`)."""
    pw = grid.power
    w = filter_shape(filt, d2, r2)
    if bsdf is not None:
        wi = (-float(grid.direction[j, 0]), -float(grid.direction[j, 1]), -float(grid.direction[j, 2]))
        if split is not None:
            f, f_scale = split_record_weight(bsdf[0], bsdf[1], bsdf[2], bsdf[3], bsdf[4], wi, split), 1.0
        else:
            f, f_scale = eval_photon(bsdf[0], bsdf[1], bsdf[2], bsdf[3], bsdf[4], bsdf[5], wi)
        f_scale *= w
        return pw[j, 0] * f[0] * f_scale, pw[j, 1] * f[1] * f_scale, pw[j, 2] * f[2] * f_scale
    return pw[j, 0] * w, pw[j, 1] * w, pw[j, 2] * w
