"""A uniform grid over one pass's photon events, for the progressive methods' fixed-radius gather.

SPPM asks, every pass and for every pixel, "which of this pass's photons lie within
R_i of my visible point?".  A kd-tree answers in O(log n + found) but costs a
median-split build per pass (O(n log n), the largest part of a pass in measurements);
a uniform grid with cells about as large as the radii is built by one counting sort
(O(n + cells)) and answers by scanning the few cells the query's sphere overlaps.

Layout: cells of side ``cell`` cover the box ``[lo, lo + dims * cell)``; cell
(ix, iy, iz) is number ``(ix * dims[1] + iy) * dims[2] + iz``, and its events are
entries ``start[c] .. start[c + 1]`` of the sorted arrays (position, power, normal:
structure of arrays, float32 like the photon records).  Points outside the box are
clamped into its border cells (the distance test stays exact).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import kernel
from .kdtree import FACING_COS

#: Most cells a grid may have (its ``start`` array is int64: 8 bytes a cell).
MAX_CELLS = 1 << 22


class PhotonGrid(NamedTuple):
    lo: np.ndarray        # float64[3], the box's low corner
    cell: np.ndarray      # float64[1], the side of a cell
    dims: np.ndarray      # int64[3], cells along x, y, z
    start: np.ndarray     # int64[cells + 1]
    position: np.ndarray  # float32[n, 3], sorted by cell
    power: np.ndarray     # float32[n, 3]
    normal: np.ndarray    # float32[n, 3]

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def memory_bytes(self) -> int:
        return int(sum(a.nbytes for a in self))


def grid_shape(box: np.ndarray, cell: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(low corner, cell side, dims) for cells of about ``cell`` over ``box`` (lo, hi), at most MAX_CELLS."""
    lo = np.asarray(box[:3], np.float64)
    ext = np.maximum(np.asarray(box[3:], np.float64) - lo, 1e-9)
    cell = max(float(cell), 1e-9)
    while True:
        dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
        if int(np.prod(dims)) <= MAX_CELLS:
            return lo, cell, dims
        cell *= 1.25


@kernel
def _cell_of(px, py, pz, lo, inv, dims):
    ix = min(max(int(math.floor((px - lo[0]) * inv)), 0), dims[0] - 1)
    iy = min(max(int(math.floor((py - lo[1]) * inv)), 0), dims[1] - 1)
    iz = min(max(int(math.floor((pz - lo[2]) * inv)), 0), dims[2] - 1)
    return ix, iy, iz


@kernel
def _counting_sort(position, power, normal, valid, lo, cell, dims, start, out_pos, out_pow, out_nrm):
    """Sort the valid events by cell into out_*; start receives the cells' offsets."""
    inv = 1.0 / cell
    n = position.shape[0]
    n_cells = start.shape[0] - 1
    cells = np.empty(n, np.int64)
    for i in range(n):
        if valid[i] == 0:
            cells[i] = -1
            continue
        ix, iy, iz = _cell_of(position[i, 0], position[i, 1], position[i, 2], lo, inv, dims)
        c = (ix * dims[1] + iy) * dims[2] + iz
        cells[i] = c
        start[c + 1] += 1
    for c in range(n_cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    for i in range(n):  # in input order: the same sorted arrays for any thread count
        c = cells[i]
        if c < 0:
            continue
        j = fill[c]
        fill[c] += 1
        for k in range(3):
            out_pos[j, k] = position[i, k]
            out_pow[j, k] = power[i, k]
            out_nrm[j, k] = normal[i, k]


def grid_compiled() -> bool:
    """Whether the grid's sort has been compiled (or loaded from the cache) in this process."""
    return _counting_sort.compiled_for_python()


def build_grid(position, power, normal, valid, box, cell) -> PhotonGrid:
    """The grid of the events with ``valid`` != 0, cells of about ``cell`` over ``box`` (lo, hi)."""
    lo, cell, dims = grid_shape(box, cell)
    n = int(np.count_nonzero(valid))
    start = np.zeros(int(np.prod(dims)) + 1, np.int64)
    out = [np.empty((n, 3), np.float32) for _ in range(3)]
    _counting_sort(position, power, normal, np.ascontiguousarray(valid, np.int8), lo, cell, dims, start, *out)
    return PhotonGrid(lo, np.array([cell]), dims, start, *out)


@kernel
def grid_range_sum(grid, qp, qn, r):
    """Σ power over the events within r of qp whose normal faces qn (dot > FACING_COS), and their count.

    The same sidedness rule as the kd-tree's searches.  Returns (count, (Σ_0, Σ_1, Σ_2)), float64 sums.
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
    x0, y0, z0 = _cell_of(qp[0] - r, qp[1] - r, qp[2] - r, lo, inv, dims)
    x1, y1, z1 = _cell_of(qp[0] + r, qp[1] + r, qp[2] + r, lo, inv, dims)
    r2 = r * r
    pos = grid.position
    pw = grid.power
    nrm = grid.normal
    for ix in range(x0, x1 + 1):
        for iy in range(y0, y1 + 1):
            base = (ix * dims[1] + iy) * dims[2]
            a = grid.start[base + z0]
            b = grid.start[base + z1 + 1]   # cells z0..z1 of this column are contiguous
            for j in range(a, b):
                dx = pos[j, 0] - qp[0]
                dy = pos[j, 1] - qp[1]
                dz = pos[j, 2] - qp[2]
                if dx * dx + dy * dy + dz * dz <= r2:
                    if nrm[j, 0] * qn[0] + nrm[j, 1] * qn[1] + nrm[j, 2] * qn[2] > FACING_COS:
                        count += 1
                        s0 += pw[j, 0]
                        s1 += pw[j, 1]
                        s2 += pw[j, 2]
    return count, (s0, s1, s2)
