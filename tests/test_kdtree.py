"""The kd-tree's k-nearest search against a brute-force numpy search."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numba import prange

from caustica.jit import parallel_kernel
from caustica.photons.kdtree import (EVERY_POINT, FACING_COS, LEAF_SIZE, NO_BOUNDS, KdTree, build_kdtree, knn,
                                     memory_bytes, normal_bounds)

SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# ----------------------------------------------------------------------------- helpers

def admitted_mask(n, admit):
    """Which of n points ``admit`` = (depths, max_depth, k) admits, written directly: depth + k <= max_depth."""
    depths, max_depth, k = admit
    return np.ones(n, bool) if max_depth is None else depths.astype(np.int64) + k <= max_depth


def brute(points, normals, qp, qn, k, r_max, admit=EVERY_POINT):
    """Candidates (indices, d2) sorted by d2, computed with the kernel's own formulas."""
    d = points - np.asarray(qp, dtype=np.float64)
    d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
    facing = normals[:, 0] * qn[0] + normals[:, 1] * qn[1] + normals[:, 2] * qn[2] > FACING_COS
    ok = np.nonzero((d2 <= r_max * r_max) & facing & admitted_mask(len(points), admit))[0]
    order = np.argsort(d2[ok], kind="stable")
    return ok[order], d2[ok][order]


# Every test runs twice: without and with the normal bounds that let knn skip subtrees
# whose normals all face away (the answer must not change).
_MODE = {"bounds": False}


@pytest.fixture(scope="module", autouse=True, params=[False, True], ids=["plain", "normal-bounds"])
def bounds_mode(request):
    _MODE["bounds"] = request.param
    yield request.param
    _MODE["bounds"] = False


def bounds_for(tree, normals):
    if _MODE["bounds"] and normals.shape[0] == tree.index.shape[0]:
        return normal_bounds(tree, normals)
    return NO_BOUNDS


def run_knn(tree, normals, qp, qn, k, r_max, admit=EVERY_POINT):
    out_idx = np.full(max(k, 1), -7, np.int64)
    out_d2 = np.full(max(k, 1), np.nan)
    count, r2 = knn(tree, (normals, bounds_for(tree, normals), admit), tuple(float(x) for x in qp),
                    tuple(float(x) for x in qn), k, r_max, (out_idx, out_d2))
    return count, r2, out_idx[:count].copy(), out_d2[:count].copy()


def check_query(points, normals, tree, qp, qn, k, r_max, admit=EVERY_POINT):
    count, r2, idx, d2 = run_knn(tree, normals, qp, qn, k, r_max, admit)
    cand, cd2 = brute(points, normals, qp, qn, k, r_max, admit)
    assert count == min(k, len(cand))
    # returned entries are distinct original indices with their true distances
    assert len(set(idx.tolist())) == count
    if count:
        dd = points[idx] - np.asarray(qp, dtype=np.float64)
        np.testing.assert_array_equal(d2, dd[:, 0] * dd[:, 0] + dd[:, 1] * dd[:, 1] + dd[:, 2] * dd[:, 2])
        assert np.all(normals[idx, 0] * qn[0] + normals[idx, 1] * qn[1] + normals[idx, 2] * qn[2] > FACING_COS)
        assert admitted_mask(len(points), admit)[idx].all()
        # heap property: slot 0 is the largest
        assert d2[0] == d2.max()
    if count == k and k > 0:
        kth = cd2[k - 1]
        assert r2 == kth
        # all strictly closer candidates are in; the others are ties at the boundary
        must = set(cand[cd2 < kth].tolist())
        assert must <= set(idx.tolist())
        assert np.all(d2 <= kth)
    else:
        assert r2 == r_max * r_max
        assert set(idx.tolist()) == set(cand.tolist())
    return count


def check_tree(points, tree):
    n = len(points)
    assert tree.points.shape == (n, 3) and tree.points.dtype == np.float64
    assert tree.index.dtype == np.int64 and tree.axis.dtype == np.int8
    assert sorted(tree.index.tolist()) == list(range(n))
    np.testing.assert_array_equal(tree.points, np.asarray(points, np.float64)[tree.index])
    # partition invariant of every internal node, iteratively
    stack = [(0, n)]
    depth = 0
    while stack:
        lo, hi = stack.pop()
        if hi - lo <= LEAF_SIZE:
            assert np.all(tree.axis[lo:hi] == -1)
            continue
        m = (lo + hi) // 2
        a = tree.axis[m]
        assert a in (0, 1, 2)
        assert np.all(tree.points[lo:m, a] <= tree.points[m, a])
        assert np.all(tree.points[m + 1:hi, a] >= tree.points[m, a])
        stack += [(lo, m), (m + 1, hi)]
        depth += 1


def unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def make_points(kind, n, rng):
    if kind == "uniform":
        return rng.random((n, 3)) * 10.0 - 5.0
    if kind == "duplicates":  # many identical points, a few distinct values
        base = rng.random((max(1, n // 50 + 1), 3))
        return base[rng.integers(0, len(base), n)]
    if kind == "all_same":
        return np.tile(rng.random(3), (n, 1))
    if kind == "plane":  # all on an axis plane
        p = rng.random((n, 3))
        p[:, int(rng.integers(3))] = 0.25
        return p
    if kind == "tilted_plane":
        u, v = rng.random((2, n, 1))
        return u * np.array([1.0, 2.0, 0.5]) + v * np.array([-0.3, 0.1, 1.0])
    if kind == "line":
        t = rng.random((n, 1))
        return np.array([0.1, -0.2, 0.3]) + t * np.array([1.0, 0.5, -2.0])
    if kind == "grid":  # lots of exactly tied distances
        return rng.integers(0, 4, (n, 3)).astype(np.float64)
    if kind == "clustered":
        centres = rng.random((4, 3)) * 20
        return centres[rng.integers(0, 4, n)] + rng.normal(scale=0.05, size=(n, 3))
    raise AssertionError(kind)


KINDS = ["uniform", "duplicates", "all_same", "plane", "tilted_plane", "line", "grid", "clustered"]


# ----------------------------------------------------------------------------- properties

@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(KINDS),
       n=st.one_of(st.integers(0, 3), st.integers(0, 40), st.integers(0, 3000)),
       k=st.sampled_from([1, 2, 3, 7, 8, 9, 50, 100]),
       r_scale=st.sampled_from([1e-9, 1e-3, 0.05, 0.3, 1.0, 1e3]),
       normals_kind=st.sampled_from(["facing", "random", "none_facing"]))
def test_knn_matches_brute_force(seed, kind, n, k, r_scale, normals_kind):
    rng = np.random.default_rng(seed)
    points = make_points(kind, n, rng)
    qn = tuple(unit_vectors(rng, 1)[0])
    if normals_kind == "facing":
        normals = np.tile(qn, (n, 1))
    elif normals_kind == "none_facing":
        normals = -np.tile(qn, (n, 1))
    else:  # about half face the query normal, the other half the other way
        normals = unit_vectors(rng, n)
        normals *= np.where(rng.random(n) < 0.5, 1.0, -1.0)[:, None]
        normals[normals @ np.asarray(qn) == 0.0] = qn
    tree = build_kdtree(points)
    check_tree(points, tree)
    ext = float(np.ptp(points, axis=0).max()) if n else 1.0
    r_max = r_scale * max(ext, 1e-3)
    for _ in range(5):
        if n and rng.random() < 0.5:  # query on a point, or next to one
            qp = points[rng.integers(n)] + (rng.normal(size=3) * 1e-3 if rng.random() < 0.5 else 0.0)
        else:
            qp = points.mean(axis=0) + rng.normal(size=3) * ext if n else rng.normal(size=3)
        count = check_query(points, normals, tree, qp, qn, k, r_max)
        if normals_kind == "none_facing":
            assert count == 0


@SETTINGS
@given(points=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=0, max_side=60)
                         .map(lambda s: (s[0], 3)),
                         elements=st.sampled_from([-1.0, 0.0, 0.5, 1.0, 2.0, 1e-300, -3.5e7])),
       q=st.tuples(*[st.sampled_from([-1.0, 0.0, 0.25, 0.5, 1.0, 3.0])] * 3),
       k=st.integers(1, 12), r_max=st.sampled_from([0.0, 0.5, 1.0, 1.5, 4.0, 1e9]),
       flip=st.lists(st.booleans(), min_size=60, max_size=60))
def test_knn_adversarial_values(points, q, k, r_max, flip):
    """Few distinct coordinate values: ties everywhere, zero-extent ranges, r_max = 0."""
    n = len(points)
    qn = (0.0, 0.0, 1.0)
    normals = np.zeros((n, 3))
    normals[:, 2] = np.where(np.array(flip[:n], dtype=bool), -1.0, 1.0)
    tree = build_kdtree(points)
    check_tree(points, tree)
    check_query(points, normals, tree, q, qn, k, r_max)


def test_small_n_and_edge_cases():
    rng = np.random.default_rng(0)
    for n in (0, 1, 2, LEAF_SIZE, LEAF_SIZE + 1, 2 * LEAF_SIZE + 1):
        points = rng.random((n, 3))
        normals = np.tile([0.0, 0.0, 1.0], (n, 1))
        tree = build_kdtree(points)
        check_tree(points, tree)
        for k in (1, n, n + 1, 100):
            if k > 0:
                check_query(points, normals, tree, (0.5, 0.5, 0.5), (0.0, 0.0, 1.0), k, 10.0)
                check_query(points, normals, tree, (0.5, 0.5, 0.5), (0.0, 0.0, 1.0), k, 1e-12)
    # n < k: everything in range is returned and r2 = r_max^2
    tree = build_kdtree(np.zeros((0, 3)))
    assert run_knn(tree, np.zeros((0, 3)), (0, 0, 0), (0, 0, 1), 5, 2.0)[:2] == (0, 4.0)
    # k = 0 finds nothing
    tree = build_kdtree(rng.random((30, 3)))
    assert run_knn(tree, np.ones((30, 3)), (0, 0, 0), (1, 1, 1), 0, 2.0)[:2] == (0, 4.0)
    # integer tuples and float32 input work
    tree = build_kdtree(rng.random((30, 3)).astype(np.float32))
    assert tree.points.dtype == np.float64
    assert run_knn(tree, np.ones((30, 3)), (0, 0, 0), (1, 1, 1), 3, 5.0)[0] == 3


def test_build_validates_and_does_not_modify_input():
    with pytest.raises(ValueError):
        build_kdtree(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        build_kdtree(np.array([[0.0, np.nan, 0.0]]))
    p = np.random.default_rng(1).random((100, 3))
    p0 = p.copy()
    tree = build_kdtree(p)
    np.testing.assert_array_equal(p, p0)
    assert isinstance(tree, KdTree)
    assert memory_bytes(tree) == 100 * (24 + 8 + 1)


def test_out_arrays_too_small():
    tree = build_kdtree(np.random.default_rng(2).random((50, 3)))
    with pytest.raises(ValueError):
        knn(tree, (np.ones((50, 3)), NO_BOUNDS, EVERY_POINT), (0.5, 0.5, 0.5), (1.0, 0.0, 0.0), 10, 1.0,
            (np.empty(5, np.int64), np.empty(10)))


def test_balanced_depth():
    """Median splits: depth is ceil(log2(n / LEAF_SIZE)) or so, even for duplicates."""
    for points in (np.zeros((5000, 3)), np.random.default_rng(3).random((5000, 3))):
        tree = build_kdtree(points)
        n = len(points)
        depth, stack = 0, [(0, n, 0)]
        while stack:
            lo, hi, d = stack.pop()
            depth = max(depth, d)
            if hi - lo > LEAF_SIZE:
                m = (lo + hi) // 2
                stack += [(lo, m, d + 1), (m + 1, hi, d + 1)]
        assert depth <= int(np.ceil(np.log2(n / LEAF_SIZE))) + 1


def test_big_case_against_brute_force():
    rng = np.random.default_rng(42)
    n = 200_000
    points = np.concatenate([rng.random((n - 20_000, 3)) * 100,
                             np.repeat(rng.random((200, 3)) * 100, 100, axis=0)])  # + duplicates
    normals = unit_vectors(rng, n)
    tree = build_kdtree(points)
    qps = np.concatenate([rng.random((200, 3)) * 100, points[rng.integers(0, n, 100)]])
    qns = unit_vectors(rng, len(qps))
    full = 0
    for qp, qn, r_max in zip(qps, qns, rng.choice([0.5, 3.0, 6.0, 200.0], len(qps))):
        full += check_query(points, normals, tree, qp, tuple(qn), 100, r_max) == 100
    assert 50 < full < len(qps)  # both regimes were exercised


@pytest.mark.parametrize("max_depth, k_camera", [(None, 0), (3, 1), (5, 1), (5, 3), (4, 3)])
def test_knn_admits_records_within_the_max_depth(max_depth, k_camera):
    """With (depths, max_depth, k) the search is the k-nearest search over the points of depth <= max_depth - k
    alone (a photon map's records that a camera path of k segments may gather), the same answer as brute force
    over those points; of depths 2 to 11, (3, 1) admits a tenth of them, (4, 3) none."""
    rng = np.random.default_rng(11)
    n = 20_000
    points = rng.random((n, 3)) * 10
    normals = unit_vectors(rng, n)
    depths = rng.integers(2, 12, n).astype(np.uint16)
    tree = build_kdtree(points)
    admit = (depths, max_depth, k_camera)
    admitted = {None: 1.0, 3: 0.1, 5: 0.3 if k_camera == 1 else 0.1, 4: 0.0}[max_depth]   # uniform depths 2..11
    assert abs(admitted_mask(n, admit).mean() - admitted) < 0.01
    qps = np.concatenate([rng.random((60, 3)) * 10, points[rng.integers(0, n, 40)]])
    full = 0
    for qp, qn, r_max in zip(qps, unit_vectors(rng, len(qps)), rng.choice([0.3, 1.5, 30.0], len(qps))):
        full += check_query(points, normals, tree, qp, tuple(qn), 50, r_max, admit) == 50
    assert (full == 0) == (max_depth == 4)


# ----------------------------------------------------------------------------- parallel use

@parallel_kernel
def _knn_prange(tree, normals, bounds, qps, qns, k, r_max, out_idx, out_d2, counts, r2s):
    for q in prange(qps.shape[0]):
        c, r2 = knn(tree, (normals, bounds, EVERY_POINT), (qps[q, 0], qps[q, 1], qps[q, 2]),
                    (qns[q, 0], qns[q, 1], qns[q, 2]), k, r_max, (out_idx[q], out_d2[q]))
        counts[q] = c
        r2s[q] = r2


def test_knn_inside_prange_matches_serial():
    rng = np.random.default_rng(7)
    n, nq, k = 50_000, 4000, 50
    points = rng.random((n, 3))
    normals = unit_vectors(rng, n)
    tree = build_kdtree(points)
    qps = rng.random((nq, 3))
    qns = unit_vectors(rng, nq)
    r_max = 0.1
    out_idx = np.full((nq, k), -1, np.int64)
    out_d2 = np.full((nq, k), np.nan)
    counts = np.empty(nq, np.int64)
    r2s = np.empty(nq)
    _knn_prange(tree, normals, bounds_for(tree, normals), qps, qns, k, r_max, out_idx, out_d2, counts, r2s)
    assert 0 < (counts == k).sum() < nq
    for q in range(nq):
        c, r2, idx, d2 = run_knn(tree, normals, qps[q], qns[q], k, r_max)
        assert counts[q] == c and r2s[q] == r2
        np.testing.assert_array_equal(out_idx[q, :c], idx)
        np.testing.assert_array_equal(out_d2[q, :c], d2)
