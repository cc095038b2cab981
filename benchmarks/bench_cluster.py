"""Rendering on a Dask cluster against the local thread pool: throughput and the cost of each task.

    python benchmarks/bench_cluster.py [--res 256] [--seconds 30] [--workers 2]

For pt and sppm (``--schedule global``, the schedule a cluster can take apart) on
cornell-diacaustic: a render of ``--seconds`` on ``--workers`` threads of this process,
then the same budget on a local cluster of ``--workers`` single-threaded worker
processes (started and warmed up before the clock starts).  Prints passes per second
of each and their ratio, then what each task cost beyond its work:

* overhead per task: the time from sending a task to holding its result, less the
  work the worker measured (scheduling, moving the part of the film, unpickling);
* bytes per task: the part of the film it sent back;

and from those, the workers a 1 Gbit/s client link can keep busy (the client takes in
every part: N workers send N · bytes / task seconds).  Last, how long ``caustica render
--workers N`` takes to exit after Ctrl-C (SIGINT to its process group once passes are being
merged): the local cluster's workers are stopped at once, not closed in turn (1.9-2.9 s for
two before).  No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import caustica
from caustica import cluster

CONFIGS = (("pt", {}), ("sppm", {"schedule": "global"}))
LINK_BYTES_PER_S = 1e9 / 8


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}, "
          f"load {os.getloadavg()[0]:.2f}; cornell-diacaustic {args.res}x{args.res}, {args.seconds:g} s per render")
    scene = caustica.load_scene("cornell-diacaustic")
    rows = []
    with cluster.connect(workers=args.workers) as cl:
        for method, params in CONFIGS:
            kw = dict(res=args.res, **params)
            caustica.render(scene, method, passes=2, threads=args.workers, **kw)          # compiled here
            caustica.render(scene, method, passes=2 * args.workers, dask=cl.client, **kw)  # and on the workers
            t0 = time.perf_counter()
            local = caustica.render(scene, method, time_s=args.seconds, threads=args.workers, **kw)
            t_local = time.perf_counter() - t0
            t0 = time.perf_counter()
            far = caustica.render(scene, method, time_s=args.seconds, dask=cl.client, **kw)
            t_far = time.perf_counter() - t0
            c = far.stats["cluster"]
            overhead = [w - s for w, s in zip(c["task_wall_seconds"], c["task_seconds"])]
            per_task_bytes = c["result_bytes"] / c["tasks"]
            task_s = statistics.median(c["task_seconds"])
            rows.append((method, local.stats["passes"] / t_local, far.stats["passes"] / t_far, c["tasks"],
                         statistics.median(c["task_passes"]), task_s, statistics.median(overhead) * 1e3,
                         per_task_bytes / 1e6, LINK_BYTES_PER_S * task_s / per_task_bytes,
                         c["scene_transfer_s"] * 1e3))
    print(f"| method | local {args.workers} threads, passes/s | {args.workers} workers, passes/s | ratio | tasks "
          f"| passes per task | s per task | overhead per task | MB per task | workers a 1 Gbit/s link feeds "
          f"| scene to workers |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for m, pl, pf, tasks, ppt, ts, ov, mb, feed, sc in rows:
        print(f"| {m} | {pl:.2f} | {pf:.2f} | {pf / pl:.3f} | {tasks} | {ppt:g} | {ts:.2f} | {ov:.1f} ms | "
              f"{mb:.2f} | {feed:.0f} | {sc:.1f} ms |")
    print(f"\nCtrl-C to `caustica render --workers {args.workers}`: exits {ctrl_c_seconds(args.workers):.2f} s after the "
          f"signal")


def ctrl_c_seconds(workers: int) -> float:
    """Seconds from SIGINT (to the process group, as a terminal sends it) to the exit of a render on a local
    cluster, once its checkpoint shows passes are being merged."""
    with tempfile.TemporaryDirectory() as tmp:
        ck = Path(tmp, "state.npz")
        proc = subprocess.Popen([sys.executable, "-m", "caustica", "render", "cornell-diacaustic", "--res", "16",
                                 "--time", "600", "--workers", str(workers), "--checkpoint", str(ck),
                                 "-o", str(Path(tmp, "x.exr")), "-q"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            while not ck.is_file() and proc.poll() is None:
                time.sleep(0.05)
            t0 = time.monotonic()
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=60)
            return time.monotonic() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


if __name__ == "__main__":
    main()
