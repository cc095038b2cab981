"""A binned-SAH bounding volume hierarchy in a flat array (pbrt's ``LinearBVHNode``).

Layout (all C-contiguous numpy arrays, ``M`` nodes, depth-first order):

* ``box``   (M, 6) float64: ``xmin, ymin, zmin, xmax, ymax, zmax`` of the node.
* ``node``  (M, 3) int32:   ``[a, count, axis]``.  A leaf has ``count > 0`` and its
  primitives are ``order[a : a + count]``; an interior node has ``count == 0``, its
  first child is the next node (``index + 1``) and its second child is node ``a``;
  ``axis`` is the split axis, used to visit the nearer child first.
* ``order`` (N,) int32: primitive ids in leaf order.

The build (:func:`build_bvh`) runs entirely in Numba: at each node the primitive
centroids are binned (``N_BINS`` bins on each of the three axes) and the split of
lowest surface-area-heuristic cost is taken; nodes with at most ``MAX_LEAF``
primitives become leaves when that is cheaper.  Degenerate nodes (all centroids
equal) and nodes deeper than ``MEDIAN_DEPTH`` are split at the object median, so the
tree depth stays below ``STACK_SIZE`` and traversal can use a fixed-size stack that
lives in the kernel's stack frame (no heap allocation per ray).

Traversal (:func:`bvh_closest_hit`, :func:`bvh_any_hit`) is pbrt's: the nearer child
(by the sign of the ray direction on the node's split axis) is visited first,
the farther one pushed; closest-hit shrinks ``tmax`` as it finds hits, any-hit
returns at the first.
"""
from __future__ import annotations

import math

import numpy as np
from numba import carray, types
from numba.core import cgutils
from numba.extending import intrinsic

from ..jit import kernel
from .primitives import INF, borrow, intersect_primitive_arrays

N_BINS = 16
MAX_LEAF = 4
STACK_SIZE = 128
MEDIAN_DEPTH = 64  # beyond this depth split at the median: depth <= 64 + log2(N) < STACK_SIZE
TRAVERSAL_COST = 0.5  # relative to one primitive test (pbrt-v4's value)
# Box tests widen the far distances (slab exits and the current closest t) by this
# factor.  pbrt uses 1 + 2 gamma(3) for the slab's own rounding; we take more so
# that a primitive whose own test gives t a few ulps below the box entry (coplanar,
# overlapping triangles) is never culled and the BVH returns exactly the brute-force
# closest hit.
_BOX_WIDEN = 1.0 + 1e-10


# ---------------------------------------------------------------------------
# A fixed-size int32 array on the stack frame
# ---------------------------------------------------------------------------

@intrinsic
def _alloca_int32(typingctx, size):
    """Pointer to ``size`` (a compile-time literal) int32s allocated in the function's entry block."""
    if not isinstance(size, types.IntegerLiteral):
        return None
    n = size.literal_value

    def codegen(context, builder, signature, args):
        ty = context.get_value_type(types.int32)
        return cgutils.alloca_once(builder, ty, size=n)

    return types.CPointer(types.int32)(size), codegen


@kernel(inline=True)
def _traversal_stack():
    return carray(_alloca_int32(128), (128,))  # literal == STACK_SIZE


# ---------------------------------------------------------------------------
# Build
# ---------------------------------------------------------------------------

@kernel
def _area(lx, ly, lz, hx, hy, hz):
    dx = hx - lx
    dy = hy - ly
    dz = hz - lz
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@kernel
def _less(a, b):
    """a < b in numpy's sort order (NaN after every number)."""
    return a < b or (b != b and a == a)


@kernel
def _stable_sort(keys, order, lo, hi, tmp_keys, tmp_order):
    """Sort ``order[lo:hi]`` by ``keys[lo:hi]`` (both permuted), keeping equal keys in order.

    A bottom-up merge sort: the same permutation as ``np.argsort(kind="mergesort")``
    (a stable sort's result is unique), for a fraction of its compile time.
    """
    n = hi - lo
    width = 1
    in_tmp = False  # where the current runs are: keys/order, or tmp_keys/tmp_order
    while width < n:
        for left in range(lo, hi, 2 * width):
            mid = min(left + width, hi)
            right = min(left + 2 * width, hi)
            i = left
            j = mid
            for k in range(left, right):
                if in_tmp:
                    take_right = j < right and (i >= mid or _less(tmp_keys[j], tmp_keys[i]))
                    src = j if take_right else i
                    keys[k] = tmp_keys[src]
                    order[k] = tmp_order[src]
                else:
                    take_right = j < right and (i >= mid or _less(keys[j], keys[i]))
                    src = j if take_right else i
                    tmp_keys[k] = keys[src]
                    tmp_order[k] = order[src]
                if take_right:
                    j += 1
                else:
                    i += 1
        in_tmp = not in_tmp
        width *= 2
    if in_tmp:
        for k in range(lo, hi):
            keys[k] = tmp_keys[k]
            order[k] = tmp_order[k]


@kernel(inline=True)
def _grow(lo, hi, arr, p, h):
    """Bounds (lo, hi) grown by row p of ``arr``: its low corner in columns 0..2, its high one from column h."""
    return ((min(lo[0], arr[p, 0]), min(lo[1], arr[p, 1]), min(lo[2], arr[p, 2])),
            (max(hi[0], arr[p, h]), max(hi[1], arr[p, h + 1]), max(hi[2], arr[p, h + 2])))


@kernel(inline=True)
def _node_bounds(prim_box, cen, order, start, end):
    """The bounds of primitives order[start:end] and of their centroids: (lo, hi, centroid lo, centroid hi)."""
    lo = c_lo = (INF, INF, INF)
    hi = c_hi = (-INF, -INF, -INF)
    for k in range(start, end):
        p = order[k]
        lo, hi = _grow(lo, hi, prim_box, p, 3)
        c_lo, c_hi = _grow(c_lo, c_hi, cen, p, 0)
    return lo, hi, c_lo, c_hi


@kernel(inline=True)
def _bin_of(cen, p, axis, lo, scale):
    """The SAH bin of primitive p's centroid along ``axis`` (from the centroid bounds' ``lo``), below N_BINS."""
    b = int((cen[p, axis] - lo) * scale)
    if b >= N_BINS:
        b = N_BINS - 1
    return b


@kernel(inline=True)
def _fill_bins(prim_box, cen, order, span, axis, lo, scale, bins):
    """Count primitives order[start:end] (``span``) into the bins along ``axis`` and grow each bin's bounds;
    ``bins`` = (counts, bounds)."""
    start, end = span
    bin_cnt, bin_box = bins
    bin_cnt[:] = 0
    for b in range(N_BINS):
        for c in range(3):
            bin_box[b, c] = INF
            bin_box[b, c + 3] = -INF
    for k in range(start, end):
        p = order[k]
        b = max(_bin_of(cen, p, axis, lo, scale), 0)
        bin_cnt[b] += 1
        for c in range(3):
            if prim_box[p, c] < bin_box[b, c]:
                bin_box[b, c] = prim_box[p, c]
            if prim_box[p, c + 3] > bin_box[b, c + 3]:
                bin_box[b, c + 3] = prim_box[p, c + 3]


@kernel(inline=True)
def _sweep(bin_box, b, bounds):
    """``bounds`` (lx, ly, lz, hx, hy, hz) grown by bin b's."""
    lx, ly, lz, hx, hy, hz = bounds
    return (min(lx, bin_box[b, 0]), min(ly, bin_box[b, 1]), min(lz, bin_box[b, 2]),
            max(hx, bin_box[b, 3]), max(hy, bin_box[b, 4]), max(hz, bin_box[b, 5]))


@kernel(inline=True)
def _best_bin(bins, right):
    """The SAH's cheapest split of the filled ``bins`` = (counts, bounds): (cost, b), left = bins < b, b = -1 if no
    split leaves both sides non-empty.  ``right`` = (areas, counts) scratch of the sweep from the right."""
    bin_cnt, bin_box = bins
    right_area, right_cnt = right
    empty = (INF, INF, INF, -INF, -INF, -INF)
    r = empty
    rc = 0
    for b in range(N_BINS - 1, 0, -1):   # area and count of bins b..N_BINS-1
        r = _sweep(bin_box, b, r)
        rc += bin_cnt[b]
        right_area[b] = _area(r[0], r[1], r[2], r[3], r[4], r[5])
        right_cnt[b] = rc
    best_cost = INF
    best_bin = -1
    lb = empty
    lc = 0
    for b in range(1, N_BINS):           # split after bin b - 1
        lb = _sweep(bin_box, b - 1, lb)
        lc += bin_cnt[b - 1]
        if lc == 0 or right_cnt[b] == 0:
            continue
        cost = lc * _area(lb[0], lb[1], lb[2], lb[3], lb[4], lb[5]) + right_cnt[b] * right_area[b]
        if cost < best_cost:
            best_cost = cost
            best_bin = b
    return best_cost, best_bin


@kernel(inline=True)
def _sah_split(prim_box, cen, order, span, centroids, bins, right):
    """The cheapest SAH split of order[start:end] (``span``) over the three axes, ``centroids`` = (their lower
    bound, extent): (cost, axis, bin), axis -1 if none."""
    clo, ext = centroids
    best_cost = INF
    best_axis = -1
    best_bin = -1
    for axis in range(3):
        if ext[axis] <= 0.0:
            continue
        _fill_bins(prim_box, cen, order, span, axis, clo[axis], N_BINS / ext[axis], bins)
        cost, b = _best_bin(bins, right)
        if b >= 0 and cost < best_cost:
            best_cost = cost
            best_axis = axis
            best_bin = b
    return best_cost, best_axis, best_bin


@kernel(inline=True)
def _partition(cen, order, span, axis, centroids, best_bin):
    """Partition order[start:end] (``span``) by centroid bin < best_bin along ``axis``; the first index of the
    second part."""
    start, end = span
    clo, ext = centroids
    scale = N_BINS / ext[axis]
    i = start
    j = end - 1
    while i <= j:
        p = order[i]
        if _bin_of(cen, p, axis, clo[axis], scale) < best_bin:
            i += 1
        else:
            order[i] = order[j]
            order[j] = p
            j -= 1
    return i


@kernel(inline=True)
def _choose_split(prim_box, cen, order, span, bounds, depth, scratch):
    """Where the node of primitives order[start:end] (``span``) splits: (mid, axis), mid = -1 for a leaf.

    ``bounds`` = (lo, hi, centroid lo, centroid hi) of :func:`_node_bounds`.  Above MEDIAN_DEPTH the binned SAH
    (a leaf where it is cheaper and small enough); where it finds no split, the object median along the widest
    centroid axis (a stable sort of order[start:end]).  ``scratch`` = (bins, right, keys, tmp_keys, tmp_order).
    """
    start, end = span
    lo, hi, clo, chi = bounds
    bins, right, keys, tmp_keys, tmp_order = scratch
    cnt = end - start
    if cnt == 1:
        return -1, 0
    ext = (chi[0] - clo[0], chi[1] - clo[1], chi[2] - clo[2])
    big_axis = 0
    if ext[1] > ext[big_axis]:
        big_axis = 1
    if ext[2] > ext[big_axis]:
        big_axis = 2
    if ext[big_axis] > 0.0 and depth < MEDIAN_DEPTH:
        parent_area = _area(lo[0], lo[1], lo[2], hi[0], hi[1], hi[2])
        best_cost, best_axis, best_bin = _sah_split(prim_box, cen, order, span, (clo, ext), bins, right)
        if best_axis >= 0:
            split_cost = TRAVERSAL_COST + (best_cost / parent_area if parent_area > 0.0 else cnt)
            if cnt <= MAX_LEAF and cnt <= split_cost:
                return -1, 0
            mid = _partition(cen, order, span, best_axis, (clo, ext), best_bin)
            if mid != start and mid != end:
                return mid, best_axis
    if cnt <= MAX_LEAF:
        return -1, 0
    for k in range(start, end):
        keys[k] = cen[order[k], big_axis]
    _stable_sort(keys, order, start, end, tmp_keys, tmp_order)
    return start + cnt // 2, big_axis


@kernel
def build_bvh(prim_box):
    """Build the BVH over primitives with bounds ``prim_box`` (N, 6).

    Returns ``(box, node, order)`` as described in the module docstring.  Runs in
    O(N log N); all allocations happen here, once per scene.
    """
    n = prim_box.shape[0]
    order = np.empty(n, dtype=np.int32)
    for i in range(n):
        order[i] = i
    max_nodes = max(1, 2 * n - 1)
    box = np.empty((max_nodes, 6), dtype=np.float64)
    node = np.zeros((max_nodes, 3), dtype=np.int32)
    if n == 0:
        return box[:0].copy(), node[:0].copy(), order
    cen = np.empty((n, 3), dtype=np.float64)
    for i in range(n):
        for a in range(3):
            cen[i, a] = 0.5 * (prim_box[i, a] + prim_box[i, a + 3])
    scratch = ((np.zeros(N_BINS, dtype=np.int64), np.empty((N_BINS, 6), dtype=np.float64)),
               (np.empty(N_BINS, dtype=np.float64), np.empty(N_BINS, dtype=np.int64)),
               np.empty(n, dtype=np.float64), np.empty(n, dtype=np.float64), np.empty(n, dtype=np.int32))

    # DFS work stack: (start, end, parent-to-patch or -1, depth).
    st = np.empty((2 * (MEDIAN_DEPTH + 64) + 8, 4), dtype=np.int64)
    st[0, 0] = 0
    st[0, 1] = n
    st[0, 2] = -1
    st[0, 3] = 0
    sp = 1
    n_nodes = 0
    while sp > 0:
        sp -= 1
        start, end, parent, depth = st[sp, 0], st[sp, 1], st[sp, 2], st[sp, 3]
        idx = n_nodes
        n_nodes += 1
        if parent >= 0:
            node[parent, 0] = idx
        bounds = _node_bounds(prim_box, cen, order, start, end)
        for c in range(3):
            box[idx, c] = bounds[0][c]
            box[idx, c + 3] = bounds[1][c]
        mid, split_axis = _choose_split(prim_box, cen, order, (start, end), bounds, depth, scratch)
        if mid < 0:
            node[idx, 0] = start
            node[idx, 1] = end - start
            continue
        node[idx, 1] = 0
        node[idx, 2] = split_axis
        # Push the second (right) child first so the first child gets index idx + 1.
        st[sp, 0] = mid
        st[sp, 1] = end
        st[sp, 2] = idx
        st[sp, 3] = depth + 1
        st[sp + 1, 0] = start
        st[sp + 1, 1] = mid
        st[sp + 1, 2] = -1
        st[sp + 1, 3] = depth + 1
        sp += 2
    return box[:n_nodes].copy(), node[:n_nodes].copy(), order


@kernel
def bvh_depth(node):
    """Depth of the tree (a single leaf has depth 1); for tests and statistics."""
    m = node.shape[0]
    if m == 0:
        return 0
    depth = np.zeros(m, dtype=np.int64)
    depth[0] = 1
    best = 1
    for k in range(m):
        if node[k, 1] == 0:
            depth[k + 1] = depth[k] + 1
            depth[node[k, 0]] = depth[k] + 1
        best = max(best, depth[k])
    return best


# ---------------------------------------------------------------------------
# Traversal
# ---------------------------------------------------------------------------

@kernel
def _safe_inv(x):
    """1 / x, with +-inf for a zero component.

    A ray lying exactly in a slab's plane then gives ``0 * inf = NaN``, which the
    comparisons in :func:`_hit_box` ignore: the ray counts as inside that slab.
    """
    if x == 0.0:
        return math.copysign(INF, x)
    return 1.0 / x


@kernel(inline=True)
def _slab(lo, hi, o, inv, t0, t1):
    """The ray's span (t0, t1) narrowed to one axis's slab [lo, hi] (origin o and 1 / direction inv on that axis;
    the exit widened by _BOX_WIDEN).  A NaN distance leaves the span as it is."""
    tn = (lo - o) * inv
    tf = (hi - o) * inv
    if tn > tf:
        tn, tf = tf, tn
    tf *= _BOX_WIDEN
    return (tn if tn > t0 else t0), (tf if tf < t1 else t1)


@kernel(inline=True)
def _hit_box(box, k, o, inv, tmax):
    """Slab test of node ``k`` against the ray ``o + t d``, ``t`` in [0, tmax].

    Written so that NaN slab distances (ray in a slab plane) never reject a box.
    """
    t0, t1 = _slab(box[k, 0], box[k, 3], o[0], inv[0], 0.0, tmax * _BOX_WIDEN)
    if t0 > t1:
        return False
    t0, t1 = _slab(box[k, 1], box[k, 4], o[1], inv[1], t0, t1)
    if t0 > t1:
        return False
    t0, t1 = _slab(box[k, 2], box[k, 5], o[2], inv[2], t0, t1)
    return t0 <= t1


@kernel(inline=True)
def _arrays(geom):
    """Borrowed views of the arrays a traversal reads (no reference counts touched per ray)."""
    return (borrow(geom.bvh_box), borrow(geom.bvh_node), borrow(geom.bvh_order), borrow(geom.prim_kind),
            borrow(geom.prim_index), borrow(geom.tri_p0), borrow(geom.tri_e1), borrow(geom.tri_e2),
            borrow(geom.ana_to_local))


@kernel(inline=True)
def bvh_closest_hit(geom, o, d, tmax):
    """Closest primitive hit with ``t`` in (0, tmax): ``(prim, t, b1, b2)``; ``prim = -1``, ``t = tmax`` on a miss.

    ``geom`` is a :class:`~caustica.geometry.scene_geometry.Geometry` (its
    ``bvh_box``, ``bvh_node``, ``bvh_order`` and primitive tables).  Inlined: it
    only hands borrowed views of the arrays it needs to the (compiled once,
    cached) traversal.
    """
    return _traverse(_arrays(geom), o, d, tmax, False)


@kernel(inline=True)
def bvh_any_hit(geom, o, d, tmax):
    """True when some primitive is hit with ``t`` in (0, tmax) (shadow rays; stops at the first hit)."""
    return _traverse(_arrays(geom), o, d, tmax, True)[0] >= 0


@kernel
def _near_first(axis, d):
    """True when the ray direction is negative along ``axis`` (visit the second child first)."""
    if axis == 0:
        return d[0] < 0.0
    if axis == 1:
        return d[1] < 0.0
    return d[2] < 0.0


@kernel(inline=True)
def _traverse(arrays, o, d, tmax, any_hit):
    """The BVH walk for both queries: the closest hit ``(prim, t, b1, b2)`` in (0, tmax), or with
    ``any_hit`` the first hit found (its ``prim`` >= 0; a miss is ``prim = -1``, ``t = tmax``).

    ``arrays`` as :func:`_arrays` gives them.  Compiled once by Numba; LLVM inlines it into each
    caller (``inline``), where the constant ``any_hit`` folds away.
    """
    box, node, order, prim_kind, prim_index, tri_p0, tri_e1, tri_e2, ana_to_local = arrays
    prims = (prim_kind, prim_index, tri_p0, tri_e1, tri_e2, ana_to_local)
    best_prim = -1
    best_t = tmax
    best_b1 = 0.0
    best_b2 = 0.0
    if node.shape[0] == 0:
        return best_prim, best_t, best_b1, best_b2
    inv = (_safe_inv(d[0]), _safe_inv(d[1]), _safe_inv(d[2]))
    stack = _traversal_stack()
    sp = 0
    k = 0
    while True:
        if _hit_box(box, k, o, inv, best_t):
            cnt = node[k, 1]
            if cnt > 0:
                first = node[k, 0]
                for s in range(first, first + cnt):
                    prim = order[s]
                    t, b1, b2 = intersect_primitive_arrays(prims, prim, o, d, best_t)
                    if t < best_t:
                        best_t = t
                        best_prim = prim
                        best_b1 = b1
                        best_b2 = b2
                        if any_hit:
                            return best_prim, best_t, best_b1, best_b2
                if sp == 0:
                    break
                sp -= 1
                k = stack[sp]
            else:
                if _near_first(node[k, 2], d):
                    stack[sp] = k + 1
                    k = node[k, 0]
                else:
                    stack[sp] = node[k, 0]
                    k = k + 1
                sp += 1
        else:
            if sp == 0:
                break
            sp -= 1
            k = stack[sp]
    return best_prim, best_t, best_b1, best_b2
