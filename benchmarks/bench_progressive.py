"""Progressive photon methods: seconds per pass and where they go.

    python benchmarks/bench_progressive.py [--res 256] [--passes 20] [--threads N]

For sppm (defaults, and with aimed caustic photons) and pspm (merge; split with
r_s = 1) on cornell-diacaustic and cornell-catacaustic: one warm-up pass (compiles),
then ``--passes`` passes; prints passes per second and the mean per-pass time of
each phase the render reports (camera pass = visible points and direct light,
photon tracing, grid build, gather).  No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import caustica

CONFIGS = (
    ("sppm", {}),
    ("sppm", {"photons": 20_000, "caustic_photons": 20_000}),
    ("pspm", {}),
    ("pspm", {"specular": "split", "stream_radius": 1.0}),
)
PHASES = ("camera_pass_s", "photon_trace_s", "map_build_s", "grid_build_s", "gather_s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--passes", type=int, default=20)
    ap.add_argument("--threads", type=int)
    args = ap.parse_args()
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}, "
          f"load {os.getloadavg()[0]:.2f}; {args.res}x{args.res}, {args.passes} passes")
    print("| scene | method | parameters | passes/s | " + " | ".join(PHASES) + " |")
    print("| --- | --- | --- | ---: | " + " | ".join("---:" for _ in PHASES) + " |")
    for name in ("cornell-diacaustic", "cornell-catacaustic"):
        scene = caustica.load_scene(name)
        for method, params in CONFIGS:
            caustica.render(scene, method, res=args.res, passes=1, threads=args.threads, **params)
            t0 = time.perf_counter()
            r = caustica.render(scene, method, res=args.res, passes=args.passes, threads=args.threads, **params)
            wall = time.perf_counter() - t0
            t = r.stats["timings"]
            cells = " | ".join(f"{t.get(k, 0.0) / args.passes * 1e3:.1f} ms" for k in PHASES)
            desc = ", ".join(f"{k}={v}" for k, v in params.items()) or "defaults"
            print(f"| {name} | {method} | {desc} | {args.passes / wall:.2f} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
