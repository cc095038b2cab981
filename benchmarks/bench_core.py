"""The transport core's speed, for a before/after comparison of two trees in one run.

    python benchmarks/bench_core.py [--label NAME] [--threads N] [--budget 10] [--json FILE]
    benchmarks/before_after.sh OLD_SRC NEW_SRC     # both trees, interleaved, on one machine

Only the public API (``caustica.load_scene``, ``caustica.render`` and the sidecar stats) is used, so
the same script measures an older tree (``PYTHONPATH=old/src``).  Printed, each after a warm-up render
(kernels compiled or loaded):

* ``pt`` samples per second: cornell-diacaustic and cornell-catacaustic at 256 x 256, 16 spp, the
  camera pass's own seconds (``camera_pass_s``, compile excluded), best of three;
* ``sppm`` at ``--budget`` seconds on both caustic scenes (256 x 256, seed 0): passes run and the
  caustic-mask and whole-image relative RMSE against Mitsuba's converged reference in shared/refs
  (skipped without it);
* the fog box (``cornell-diacaustic-fog``, 128 x 128): seconds per pass of ``pt`` (4 spp), ``sppm`` and
  ``pspm``, mean of 6 passes after 2 warm-up passes;
* the cold first render: ``caustica render cornell-diacaustic --method spm`` (what ``make render``
  runs) in a subprocess with ``CAUSTICA_NO_CACHE=1`` (every kernel compiled), wall and CPU seconds.

The machine's load changes wall times: run the trees interleaved and compare them within the run.
No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

import caustica

CAUSTIC_SCENES = ("cornell-diacaustic", "cornell-catacaustic")


def pt_samples_per_second(threads):
    out = {}
    for name in CAUSTIC_SCENES:
        scene = caustica.load_scene(name)
        caustica.render(scene, "pt", res=32, spp=1, threads=threads)   # warm-up
        best = min(caustica.render(scene, "pt", res=256, spp=16, seed=s, threads=threads).stats["timings"]
                   ["camera_pass_s"] for s in range(3))
        out[name] = 256 * 256 * 16 / best
    return out


def sppm_at_budget(threads, budget):
    try:
        from caustica.experiments.convergence import rel_rmse, shared_refs_dir
        from caustica.imageio import read_exr, read_png_mask
    except ImportError:
        return {}
    refs = shared_refs_dir()
    if refs is None:
        return {}
    out = {}
    for name in CAUSTIC_SCENES:
        ref = read_exr(refs / f"{name}_256.exr")[..., :3]
        mask = read_png_mask(refs / f"{name}_256_caustic_mask.png")
        scene = caustica.load_scene(name)
        caustica.render(scene, "sppm", res=256, passes=2, threads=threads)   # warm-up
        r = caustica.render(scene, "sppm", res=256, seed=0, time_s=budget, threads=threads)
        out[name] = {"passes": r.stats["passes"], "caustic": rel_rmse(r.image, ref, mask),
                     "whole": rel_rmse(r.image, ref)}
    return out


def fog_seconds_per_pass(threads):
    scene = caustica.load_scene("cornell-diacaustic-fog")
    out = {}
    for method, kw in (("pt", {"spp": 4}), ("sppm", {}), ("pspm", {})):
        caustica.render(scene, method, res=128, passes=2, threads=threads, **kw)   # warm-up
        t0 = time.perf_counter()
        caustica.render(scene, method, res=128, passes=6, threads=threads, **kw)
        out[method] = (time.perf_counter() - t0) / 6
    return out


def cold_first_render():
    env = dict(os.environ, CAUSTICA_NO_CACHE="1")
    code = ("import sys, caustica.cli; sys.exit(caustica.cli.main(['render', 'cornell-diacaustic', '--method', "
            "'spm', '-o', '/tmp/bench_core_cold.exr', '--quiet']))")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"wall_s": wall, "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--label", default=os.path.dirname(os.path.dirname(os.path.abspath(caustica.__file__))))
    ap.add_argument("--threads", type=int)
    ap.add_argument("--budget", type=float, default=10.0)
    ap.add_argument("--skip", default="", help="comma-separated parts to skip: pt,sppm,fog,cold")
    ap.add_argument("--json", help="append the results as one JSON line to this file")
    args = ap.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    res = {"label": args.label, "time": time.strftime("%Y-%m-%d %H:%M"), "load": os.getloadavg()[0]}
    if "cold" not in skip:
        res["cold"] = cold_first_render()
    if "pt" not in skip:
        res["pt_samples_per_s"] = pt_samples_per_second(args.threads)
    if "fog" not in skip:
        res["fog_s_per_pass"] = fog_seconds_per_pass(args.threads)
    if "sppm" not in skip:
        res["sppm"] = sppm_at_budget(args.threads, args.budget)
    print(json.dumps(res, default=lambda x: float(x) if isinstance(x, np.floating) else str(x)))
    if args.json:
        with open(args.json, "a") as f:
            f.write(json.dumps(res, default=float) + "\n")


if __name__ == "__main__":
    main()
