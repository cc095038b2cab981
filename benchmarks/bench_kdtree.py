"""Benchmark of the photon kd-tree: build time and k-nearest queries per second.

Run:  .venv/bin/python benchmarks/bench_kdtree.py [--n 100000 1000000] [--k 100]

Compile times are measured first (on a tiny tree) and reported separately; the
timed runs below never include JIT compilation.  Queries are random positions in
the bounding box of uniformly random points with uniformly random unit normals
(so about half of the photons are filtered out by the normal test), r_max chosen
so that about 2k unfiltered points lie in the ball, i.e. the heap usually fills.
"""
from __future__ import annotations

import argparse
import math
import time

import numba
import numpy as np
from numba import prange

from caustica.jit import parallel_kernel
from caustica.photons.kdtree import EVERY_POINT, NO_BOUNDS, build_kdtree, knn, memory_bytes


@parallel_kernel
def knn_many(tree, normals, qps, qns, k, r_max, out_idx, out_d2, counts, r2s):
    for q in prange(qps.shape[0]):
        c, r2 = knn(tree, (normals, NO_BOUNDS, EVERY_POINT), (qps[q, 0], qps[q, 1], qps[q, 2]),
                    (qns[q, 0], qns[q, 1], qns[q, 2]), k, r_max, (out_idx[q], out_d2[q]))
        counts[q] = c
        r2s[q] = r2


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def _serial(tree, normals, qps, qns, k, r_max, out_idx, out_d2):
    # a Python loop calling the compiled kernel: includes dispatch overhead,
    # so the serial figure is measured with the prange kernel on 1 thread instead
    for q in range(qps.shape[0]):
        knn(tree, (normals, NO_BOUNDS, EVERY_POINT), tuple(qps[q]), tuple(qns[q]), k, r_max, (out_idx[q], out_d2[q]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--k", type=int, default=100)
    ap.add_argument("--queries", type=int, default=50_000)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    rng = np.random.default_rng(12345)
    k = args.k

    # --- compile times (tiny inputs)
    p = rng.random((64, 3))
    t0 = time.perf_counter()
    tiny = build_kdtree(p)
    t_build_c = time.perf_counter() - t0
    nrm = _unit(rng, 64)
    oi = np.empty((1, k), np.int64)
    od = np.empty((1, k), np.float64)
    t0 = time.perf_counter()
    knn(tiny, (nrm, NO_BOUNDS, EVERY_POINT), (0.5, 0.5, 0.5), (0.0, 0.0, 1.0), k, 0.1, (oi[0], od[0]))
    t_knn_c = time.perf_counter() - t0
    t0 = time.perf_counter()
    knn_many(tiny, nrm, p[:1], nrm[:1], k, 0.1, oi, od, np.empty(1, np.int64), np.empty(1))
    t_par_c = time.perf_counter() - t0
    print(f"compile (or cache load): build_kdtree {t_build_c:.2f} s, knn {t_knn_c:.2f} s, "
          f"prange wrapper {t_par_c:.2f} s   [numba {numba.__version__}, "
          f"{numba.config.NUMBA_NUM_THREADS} threads available]")

    for n in args.n:
        pts = rng.random((n, 3))
        normals = _unit(rng, n)
        best = math.inf
        for _ in range(3):
            t0 = time.perf_counter()
            tree = build_kdtree(pts)
            best = min(best, time.perf_counter() - t0)
        # ball volume holding ~2k of n uniform points in the unit cube
        r_max = (2 * k / n * 3 / (4 * math.pi)) ** (1 / 3)
        nq = args.queries
        qps = rng.random((nq, 3))
        qns = _unit(rng, nq)
        out_idx = np.empty((nq, k), np.int64)
        out_d2 = np.empty((nq, k), np.float64)
        counts = np.empty(nq, np.int64)
        r2s = np.empty(nq)
        print(f"n = {n:>9,}: build {best * 1e3:8.1f} ms (best of 3), tree {memory_bytes(tree) / 2**20:.1f} MiB, "
              f"r_max {r_max:.4f}")
        for threads in (1, args.threads):
            numba.set_num_threads(threads)
            knn_many(tree, normals, qps[:100], qns[:100], k, r_max, out_idx, out_d2, counts, r2s)
            best = math.inf
            for _ in range(3):
                t0 = time.perf_counter()
                knn_many(tree, normals, qps, qns, k, r_max, out_idx, out_d2, counts, r2s)
                best = min(best, time.perf_counter() - t0)
            print(f"    k={k} queries, prange on {threads} thread(s): {nq / best:12,.0f} queries/s  "
                  f"(mean count {counts.mean():.1f})")
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        nq_py = min(nq, 5000)
        t0 = time.perf_counter()
        _serial(tree, normals, qps[:nq_py], qns[:nq_py], k, r_max, out_idx, out_d2)
        dt = time.perf_counter() - t0
        print(f"    k={k} queries, one Python call per query:  {nq_py / dt:12,.0f} queries/s")


if __name__ == "__main__":
    main()
