"""A balanced kd-tree over photon (or stream-record) positions, and k-nearest search.

Layout
------
The tree is *implicit*: no node records, no child pointers.  ``build_kdtree``
permutes the points so that every node is a contiguous range ``[lo, hi)`` of
``KdTree.points``:

* a range with at most ``LEAF_SIZE`` points is a leaf (scanned linearly);
* otherwise the node holds the point ``m = (lo + hi) // 2``, its split axis is
  ``a = KdTree.axis[m]`` (the axis of largest extent of the range), and the points
  are partitioned (nth-element) so that
  ``points[lo:m, a] <= points[m, a] <= points[m+1:hi, a]``.
  The children are ``[lo, m)`` and ``[m + 1, hi)``.

Each point is the node point of at most one internal node, so one ``int8`` per
point is all the node data there is.  Depth is below ``log2(n)``, so < 64.

The build is Numba code: an explicit stack of ranges, a Hoare quickselect
(median-of-three pivot; equal keys are swapped, so many identical points still
split in half) per node, O(n log n) expected.

Search
------
``knn`` keeps a max-heap of the k best candidates in caller-provided arrays and
walks the tree with a small explicit stack, pruning a subtree when the squared
distance to its splitting planes is larger than the current search radius
(``r_max**2`` until k points are found, then the heap maximum).  Points whose
normal faces away from the query normal are skipped *before* they reach the heap,
so they neither take a slot nor shrink the radius (SPEC §3).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..jit import kernel

#: Largest number of points in a leaf (a range that is scanned, not split).
#: 4, 8 and 16 measured within 5% of each other for k = 100 (16 slightly ahead).
LEAF_SIZE = 16
#: ``knn``'s admission of every point (no depths, no max_depth).
EVERY_POINT = (np.zeros(0, np.uint16), None, 0)
#: Entries of the traversal and build stacks; the depth of any tree is < 64.
STACK_SIZE = 64
#: A point faces the query when dot(normal, query normal) > FACING_COS: normals more
#: than 89.1 degrees apart never count.  Not 0: a photon on a perpendicular surface
#: (the floor, for a query on the wall in the corner) has a dot product of about
#: +-1e-16 from rounding, and would be counted or not by chance.  1/64 is also
#: coarser than the normal bounds' 1/127 quantisation, so those can prune such subtrees.
FACING_COS = 1.0 / 64.0


class KdTree(NamedTuple):
    """An implicit balanced kd-tree (see the module doc).  Plain arrays, so it can
    be passed to Numba kernels as it is."""

    #: (n, 3) float64, the positions in tree order.
    points: np.ndarray
    #: (n,) int64, ``index[j]`` is the original index of ``points[j]``.
    index: np.ndarray
    #: (n,) int8, split axis of the internal node whose point is j
    #: (-1 where points[j] is in a leaf).
    axis: np.ndarray


# ----------------------------------------------------------------------------- build

@kernel(inline=True)
def _swap(pts, idx, i, j):
    for c in range(3):
        t = pts[i, c]
        pts[i, c] = pts[j, c]
        pts[j, c] = t
    ti = idx[i]
    idx[i] = idx[j]
    idx[j] = ti


@kernel
def _select(pts, idx, lo, hi, kth, ax):
    """Partially sort rows [lo, hi) of pts (and idx) on column ax so that row kth
    holds the value it would hold if sorted, nothing before it is larger and
    nothing after it is smaller (nth_element)."""
    left = lo
    right = hi - 1
    while right > left:
        a = pts[left, ax]
        b = pts[(left + right) >> 1, ax]
        c = pts[right, ax]
        # median of three: a value present in the range, so the scans below
        # cannot run off its ends
        if a < b:
            if b < c:
                pivot = b
            elif a < c:
                pivot = c
            else:
                pivot = a
        else:
            if a < c:
                pivot = a
            elif b < c:
                pivot = c
            else:
                pivot = b
        i = left
        j = right
        while i <= j:
            while pts[i, ax] < pivot:
                i += 1
            while pts[j, ax] > pivot:
                j -= 1
            if i <= j:
                _swap(pts, idx, i, j)
                i += 1
                j -= 1
        # now rows [left, j] <= pivot, rows [i, right] >= pivot, rows (j, i) == pivot
        if kth <= j:
            right = j
        elif kth >= i:
            left = i
        else:
            break


@kernel(inline=True)
def _push_children(stk_lo, stk_hi, sp, split, leaf_size):
    """Push the children of node m = split[1] over [lo, hi) that are not leaves; returns the new sp.

    The tree is implicit: node m of range [lo, hi) is its median, its children are [lo, m)
    and [m + 1, hi), and a range of at most ``leaf_size`` points is a leaf.
    """
    lo, m, hi = split
    if hi - (m + 1) > leaf_size:
        stk_lo[sp] = m + 1
        stk_hi[sp] = hi
        sp += 1
    if m - lo > leaf_size:
        stk_lo[sp] = lo
        stk_hi[sp] = m
        sp += 1
    return sp


@kernel(inline=True)
def _range_stack(n, leaf_size):
    """The builds' work stack of index ranges [lo, hi), holding the whole range [0, n) unless that is one leaf:
    (stk_lo, stk_hi, sp)."""
    stk_lo = np.empty(2 * STACK_SIZE, dtype=np.int64)
    stk_hi = np.empty(2 * STACK_SIZE, dtype=np.int64)
    stk_lo[0] = 0
    stk_hi[0] = n
    return stk_lo, stk_hi, (1 if n > leaf_size else 0)


@kernel(inline=True)
def _pop_node(stk_lo, stk_hi, sp):
    """Pop the builds' next range [lo, hi) with its node m = (lo + hi) >> 1, the median that
    :func:`_push_children` splits it at: (lo, m, hi, sp)."""
    sp -= 1
    lo, hi = stk_lo[sp], stk_hi[sp]
    return lo, (lo + hi) >> 1, hi, sp


@kernel
def _build(pts, idx, axis, leaf_size):
    stk_lo, stk_hi, sp = _range_stack(pts.shape[0], leaf_size)
    while sp > 0:
        lo, m, hi, sp = _pop_node(stk_lo, stk_hi, sp)
        # axis of largest extent
        mn0 = mx0 = pts[lo, 0]
        mn1 = mx1 = pts[lo, 1]
        mn2 = mx2 = pts[lo, 2]
        for j in range(lo + 1, hi):
            x = pts[j, 0]
            y = pts[j, 1]
            z = pts[j, 2]
            if x < mn0:
                mn0 = x
            elif x > mx0:
                mx0 = x
            if y < mn1:
                mn1 = y
            elif y > mx1:
                mx1 = y
            if z < mn2:
                mn2 = z
            elif z > mx2:
                mx2 = z
        e0 = mx0 - mn0
        e1 = mx1 - mn1
        e2 = mx2 - mn2
        ax = 0
        if e1 > e0:
            ax = 1
            if e2 > e1:
                ax = 2
        elif e2 > e0:
            ax = 2
        _select(pts, idx, lo, hi, m, ax)
        axis[m] = ax
        sp = _push_children(stk_lo, stk_hi, sp, (lo, m, hi), leaf_size)


def build_kdtree(points: np.ndarray) -> KdTree:
    """Build the tree of ``points`` ((n, 3), any real dtype, n >= 0, all finite).

    The input is not modified.  Raises ValueError on a wrong shape or a
    non-finite coordinate.
    """
    pts = np.array(points, dtype=np.float64, order="C", copy=True)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"build_kdtree needs an (n, 3) array of points, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise ValueError("build_kdtree: a point has a non-finite coordinate")
    n = pts.shape[0]
    idx = np.arange(n, dtype=np.int64)
    axis = np.full(n, -1, dtype=np.int8)
    _build(pts, idx, axis, LEAF_SIZE)
    return KdTree(points=pts, index=idx, axis=axis)


@kernel
def _normal_bounds(index, normals, leaf_size, out):
    stk_lo, stk_hi, sp = _range_stack(index.shape[0], leaf_size)
    while sp > 0:
        lo, m, hi, sp = _pop_node(stk_lo, stk_hi, sp)
        for a in range(3):
            mn = 1.0
            mx = -1.0
            for j in range(lo, hi):
                v = normals[index[j], a]
                mn = min(mn, v)
                mx = max(mx, v)
            # quantised outwards, so the box of normals only ever grows
            out[m, a] = max(-127, int(np.floor(mn * 127.0)))
            out[m, 3 + a] = min(127, int(np.ceil(mx * 127.0)))
        sp = _push_children(stk_lo, stk_hi, sp, (lo, m, hi), leaf_size)


def normal_bounds(tree: KdTree, normals: np.ndarray) -> np.ndarray:
    """Per internal node m, the box of the unit normals of its range: int8 (n, 6), min xyz then max xyz, x127.

    With it :func:`knn` skips a whole subtree whose normals all face away from the
    query's (they could neither be counted nor shrink r), e.g. the floor's photons
    for a query on the wall just above them.  6 bytes per point.
    """
    n = tree.index.shape[0]
    out = np.zeros((n, 6), np.int8)
    if n:
        _normal_bounds(tree.index, np.ascontiguousarray(normals, dtype=np.float64), LEAF_SIZE, out)
    return out


NO_BOUNDS = np.zeros((0, 6), np.int8)


def memory_bytes(tree: KdTree) -> int:
    """Bytes held by the tree's arrays."""
    return int(sum(a.nbytes for a in tree))


# ----------------------------------------------------------------------------- search

@kernel(inline=True)
def _heap_set(out_idx, out_d2, c, i, d2):
    """Write the entry (i, d2) to heap slot c: the heap is the two arrays side by side, moved in step."""
    out_d2[c] = d2
    out_idx[c] = i


@kernel(inline=True)
def _heap_push(out_idx, out_d2, count, i, d2):
    """Insert into the max-heap out_d2[:count] (count < capacity); returns count + 1."""
    c = count
    while c > 0:
        p = (c - 1) >> 1
        if out_d2[p] >= d2:
            break
        _heap_set(out_idx, out_d2, c, out_idx[p], out_d2[p])
        c = p
    _heap_set(out_idx, out_d2, c, i, d2)
    return count + 1


@kernel(inline=True)
def _heap_replace_top(out_idx, out_d2, count, i, d2):
    """Replace the maximum of the max-heap out_d2[:count] by (i, d2), d2 <= max."""
    c = 0
    while True:
        ch = 2 * c + 1
        if ch >= count:
            break
        if ch + 1 < count and out_d2[ch + 1] > out_d2[ch]:
            ch += 1
        if out_d2[ch] <= d2:
            break
        _heap_set(out_idx, out_d2, c, out_idx[ch], out_d2[ch])
        c = ch
    _heap_set(out_idx, out_d2, c, i, d2)


@kernel(inline=True)
def depth_left(max_depth, segments):
    """max_depth - segments: the deepest record (photon) a camera path of that many segments may take, here and in
    the beam estimate (:mod:`caustica.photons.beams`); None (max_depth itself, so that an int max_depth gives an int
    in both branches, never an optional) when max_depth is None."""
    if max_depth is None:
        return max_depth
    return max_depth - segments


@kernel(inline=True)
def _offer(arrays, j, query, heap, out, limit):
    """Consider tree point j for the heap; returns the new heap (count, bound).

    ``arrays`` = (points, index, normals, depths), ``query`` = (qx, qy, qz, nx, ny, nz, k),
    ``heap`` = (count, bound), ``out`` = (out_idx, out_d2); a point of depth > ``limit`` is no candidate, unless
    ``limit`` is None (then Numba prunes the test: a compilation of its own, the search as it was; the test in a
    helper of its own cost a fifth of the search's speed).
    """
    pts, index, normals, depths = arrays
    qx, qy, qz, nx, ny, nz, k = query
    count, bound = heap
    out_idx, out_d2 = out
    dx = pts[j, 0] - qx
    dy = pts[j, 1] - qy
    dz = pts[j, 2] - qz
    d2 = dx * dx + dy * dy + dz * dz
    if count < k:
        if d2 <= bound:
            i = index[j]
            if normals[i, 0] * nx + normals[i, 1] * ny + normals[i, 2] * nz > FACING_COS:
                if limit is not None:
                    if depths[i] > limit:
                        return count, bound
                count = _heap_push(out_idx, out_d2, count, i, d2)
                if count == k:
                    bound = out_d2[0]
    elif d2 < bound:
        i = index[j]
        if normals[i, 0] * nx + normals[i, 1] * ny + normals[i, 2] * nz > FACING_COS:
            if limit is not None:
                if depths[i] > limit:
                    return count, bound
            _heap_replace_top(out_idx, out_d2, count, i, d2)
            bound = out_d2[0]
    return count, bound


@kernel(inline=True)
def _faces_away(bounds, m, query):
    """Whether every normal below node m faces away from the query's (the largest dot over its box, x127)."""
    nx, ny, nz = query[3], query[4], query[5]
    facing = (max(nx * bounds[m, 0], nx * bounds[m, 3])
              + max(ny * bounds[m, 1], ny * bounds[m, 4])
              + max(nz * bounds[m, 2], nz * bounds[m, 5]))
    return facing <= FACING_COS * 127.0


@kernel(inline=True)
def _split(pts, axis, m, query, cell):
    """Where the query lies against node m's splitting plane: (diff, the far child's cell).

    ``cell`` = (nb, o0, o1, o2): the squared distance bound of node m's cell and its offsets from
    the query along x, y, z (Arya & Mount's incremental distance); the far child's cell differs
    along the splitting axis only.
    """
    nb, o0, o1, o2 = cell
    ax = axis[m]
    if ax == 0:
        diff = query[0] - pts[m, 0]
        old = o0
    elif ax == 1:
        diff = query[1] - pts[m, 1]
        old = o1
    else:
        diff = query[2] - pts[m, 2]
        old = o2
    fb = nb - old * old + diff * diff
    ad = abs(diff)
    if ax == 0:
        return diff, (fb, ad, o1, o2)
    if ax == 1:
        return diff, (fb, o0, ad, o2)
    return diff, (fb, o0, o1, ad)


@kernel(inline=True)
def _push(stk, sp, lo, hi, cell):
    """Push the range [lo, hi) with its cell (nb, o0, o1, o2); returns sp + 1."""
    e = 6 * sp
    stk[e] = lo
    stk[e + 1] = hi
    stk[e + 2] = cell[0]
    stk[e + 3] = cell[1]
    stk[e + 4] = cell[2]
    stk[e + 5] = cell[3]
    return sp + 1


@kernel(inline=True)
def _pop(stk, sp):
    """The range and cell at stack entry sp: (lo, hi, cell)."""
    e = 6 * sp
    return int(stk[e]), int(stk[e + 1]), (stk[e + 2], stk[e + 3], stk[e + 4], stk[e + 5])


@kernel
def knn(tree, candidates, qp, qn, k, r_max, out):
    """The k nearest points to qp within distance r_max whose normal faces qn (and that ``admit`` admits).

    tree       -- a KdTree
    candidates -- (normals, bounds, admit):
                  normals, an (n, 3) array indexed by ORIGINAL point index: point i is a
                  candidate only if dot(normals[i], qn) > FACING_COS;
                  bounds, :func:`normal_bounds` of these normals, or :data:`NO_BOUNDS`:
                  subtrees whose normals all face away are skipped;
                  admit, (depths, max_depth, k): point i is a candidate only if
                  depths[i] + k <= max_depth (a photon map's records that a camera path of k segments
                  may take under a render's max_depth); max_depth None admits every point
                  (:data:`EVERY_POINT`)
    qp, qn  -- query position and normal, 3-tuples of floats
    k       -- heap capacity (out_idx and out_d2 need at least k entries, else
               ValueError)
    r_max   -- maximum search distance, >= 0 (points with d^2 <= r_max^2 qualify)
    out     -- (out_idx, out_d2): an int64 array that receives the ORIGINAL indices
               of the found points, a float64 array their squared distances

    Returns (count, r2): count <= k points are in out_idx[:count] / out_d2[:count]
    (in heap order, not sorted; out_d2[0] is the largest when count > 0), and r2 is
    the squared radius of the estimate: max(out_d2[:count]) when count == k, else
    r_max**2.  The only allocation is the traversal stack, one 3 KiB array
    (64 entries of (lo, hi, bound, three axis offsets); indices stored as float64, exact below 2**53).
    """
    r2max = r_max * r_max
    pts = tree.points
    n = pts.shape[0]
    out_idx, out_d2 = out
    if k > out_idx.shape[0] or k > out_d2.shape[0]:
        raise ValueError("knn: out_idx and out_d2 need at least k entries")
    if k <= 0 or n == 0:
        return 0, r2max
    normals, bounds, (depths, max_depth, k_camera) = candidates
    arrays = (pts, tree.index, normals, depths)
    axis = tree.axis
    query = (float(qp[0]), float(qp[1]), float(qp[2]), float(qn[0]), float(qn[1]), float(qn[2]), k)
    limit = depth_left(max_depth, k_camera)
    use_bounds = bounds.shape[0] == n
    # Stack entries: (lo, hi, and the cell: lower bound, offsets to the cell along x, y, z).
    stk = np.empty(6 * STACK_SIZE, dtype=np.float64)
    sp = 0
    heap = (0, r2max)  # (count, squared search radius: r_max^2 until the heap is full)
    lo = 0
    hi = n
    cell = (0.0, 0.0, 0.0, 0.0)  # the root's cell holds the query: distance bound 0
    while True:
        if cell[0] <= heap[1]:
            if hi - lo <= LEAF_SIZE:
                for j in range(lo, hi):
                    heap = _offer(arrays, j, query, heap, out, limit)
            else:
                m = (lo + hi) >> 1
                if use_bounds and _faces_away(bounds, m, query):
                    lo = hi  # an empty range: the loop goes on to the stack
                    continue
                heap = _offer(arrays, m, query, heap, out, limit)
                diff, far = _split(pts, axis, m, query, cell)
                if far[0] <= heap[1]:
                    if diff < 0.0:  # near child [lo, m), far child [m + 1, hi)
                        sp = _push(stk, sp, m + 1, hi, far)
                    else:
                        sp = _push(stk, sp, lo, m, far)
                if diff < 0.0:
                    hi = m
                else:
                    lo = m + 1
                continue
        if sp == 0:
            break
        sp -= 1
        lo, hi, cell = _pop(stk, sp)

    count = heap[0]
    if count == k:
        return count, out_d2[0]
    return count, r2max

