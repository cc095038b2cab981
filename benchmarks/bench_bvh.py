"""BVH build time and ray throughput of caustica's ray-tracing core.

    python benchmarks/bench_bvh.py [--rays 1000000] [--threads 2]

Prints the build time of a diacaustic-like Cornell box (5 walls + light as
rectangles, a glass sphere), a 16k and a 100k triangle soup, and rays/s of
``intersect`` for random rays (origins in the scene's box, uniform directions),
in one thread and with a ``prange`` over ``--threads`` threads.  Compile time is
excluded (each kernel is warmed up first).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np
import numba

from caustica.geometry.scene_geometry import build_geometry, intersect, intersect_rays
from caustica.jit import parallel_kernel
from caustica.scene import description as sd


@parallel_kernel
def intersect_rays_parallel(geom, origins, dirs, tmax):
    """``intersect_rays`` with a ``prange`` over rays (for this comparison only: renders use a thread pool)."""
    n = origins.shape[0]
    prim = np.empty(n, dtype=np.int64)
    tt = np.empty(n)
    for i in numba.prange(n):
        p, t, _, _ = intersect(geom, (origins[i, 0], origins[i, 1], origins[i, 2]),
                               (dirs[i, 0], dirs[i, 1], dirs[i, 2]), tmax)
        prim[i] = p
        tt[i] = t
    return prim, tt


def _rot_x(deg):
    a = math.radians(deg)
    m = np.eye(4)
    m[1:3, 1:3] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return m


def _rot_y(deg):
    a = math.radians(deg)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    return m


def _scale(s):
    return np.diag([s, s, s, 1.0])


def _translate(x=0.0, y=0.0, z=0.0):
    m = np.eye(4)
    m[:3, 3] = [x, y, z]
    return m


def _rectangle(m, emitter=None):
    p = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], dtype=float) @ m.T
    return sd.Shape(sd.MESH, 0, mesh=sd.Mesh(p[:, :3], np.array([[0, 1, 2], [2, 3, 0]])),
                    emitter_radiance=emitter)


def diacaustic_like() -> sd.SceneDescription:
    """The paper's diacaustic scene (shared/scenes/cornell-diacaustic.xml) built in code."""
    shapes = [
        _rectangle(_rot_x(-90) @ _scale(10)),                                  # floor
        _rectangle(_translate(y=20) @ _rot_x(90) @ _scale(10)),                # ceiling
        _rectangle(_translate(y=10, z=-10) @ _scale(10)),                      # back
        _rectangle(_translate(x=-10, y=10) @ _rot_y(90) @ _scale(10)),         # left
        _rectangle(_translate(x=10, y=10) @ _rot_y(-90) @ _scale(10)),         # right
        _rectangle(_translate(y=19.99) @ _rot_x(90) @ _scale(1.5), (40, 40, 40)),  # light
        sd.Shape(sd.SPHERE, 1, to_world=_translate(4, 4, 2) @ _scale(4)),     # glass sphere
    ]
    return sd.SceneDescription(camera=sd.Camera(np.eye(4), 34.0), shapes=shapes,
                               materials=[sd.Material(sd.DIFFUSE), sd.Material(sd.DIELECTRIC)])


def soup(n, seed=0) -> sd.SceneDescription:
    """n random triangles of size ~1 in a cube of side ~n^(1/3) * 2 (roughly constant density)."""
    rng = np.random.default_rng(seed)
    half = 2.0 * n ** (1.0 / 3.0)
    c = rng.uniform(-half, half, (n, 1, 3))
    pos = (c + rng.normal(0.0, 0.5, (n, 3, 3))).reshape(-1, 3)
    shape = sd.Shape(sd.MESH, 0, mesh=sd.Mesh(pos, np.arange(3 * n).reshape(n, 3)))
    return sd.SceneDescription(camera=sd.Camera(np.eye(4), 40.0), shapes=[shape],
                               materials=[sd.Material(sd.DIFFUSE)])


def rays_in_box(geom, n, seed=1):
    rng = np.random.default_rng(seed)
    lo, hi = geom.scene_box[:3], geom.scene_box[3:]
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.ascontiguousarray(o), np.ascontiguousarray(d)


def timed_build(desc, repeat=3):
    build_geometry(desc)  # warm-up (compile / cache load)
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        geom = build_geometry(desc)
        best = min(best, time.perf_counter() - t)
    return geom, best


def rays_per_second(fn, geom, o, d):
    fn(geom, o[:1000], d[:1000], np.inf)  # warm-up
    t = time.perf_counter()
    prim = fn(geom, o, d, np.inf)[0]
    dt = time.perf_counter() - t
    return len(o) / dt, float(np.mean(prim >= 0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()

    scenes = {"diacaustic-like": diacaustic_like(), "soup-16k": soup(16_000), "soup-100k": soup(100_000)}
    geoms = {}
    print("BVH build (best of 3, excluding compile):")
    for name, desc in scenes.items():
        geom, dt = timed_build(desc)
        geoms[name] = geom
        print(f"  {name:16s} {geom.n_prims:7d} prims {geom.bvh_node.shape[0]:7d} nodes  {dt * 1e3:8.2f} ms")

    threads = min(args.threads, numba.config.NUMBA_NUM_THREADS)
    print(f"intersect, {args.rays:,} random rays (origins in the scene box, uniform directions):")
    for name, geom in geoms.items():
        o, d = rays_in_box(geom, args.rays)
        numba.set_num_threads(1)
        r1, hit = rays_per_second(intersect_rays, geom, o, d)
        numba.set_num_threads(threads)
        rp, _ = rays_per_second(intersect_rays_parallel, geom, o, d)
        print(f"  {name:16s} 1 thread {r1 / 1e6:6.2f} Mrays/s   prange x{threads} {rp / 1e6:6.2f} Mrays/s"
              f"   (hit fraction {hit:.2f})")


if __name__ == "__main__":
    main()
