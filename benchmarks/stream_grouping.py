"""What grouping photons into streams costs pspm when aimed photons carry the caustic: an ablation.

    python benchmarks/stream_grouping.py [--passes 100] [--seeds 0,1,2] [--assoc 0 3 10]

pspm --caustic-photons 32768 (merge, stream estimator) on cornell-diacaustic and
cornell-catacaustic at 256 x 256, with the same 32,768 photons per pass outside the
caustic grouped into streams of n_fa + 1: n_fa = 0 is one photon per stream (the stream
tracer then draws PM's photons, bit for bit), so it is sppm's default pass with another
key for its random numbers; n_fa > 0 groups them.  Equal passes, so the errors do not
depend on the machine's load; the seconds per pass (the median pass) do, and the
1-minute load average is printed.  Errors: relative RMSE against Mitsuba's references in
shared/refs over the caustic mask and the whole image, mean and spread over the seeds.
sppm's default (32,768 + 32,768 aimed photons) is the last row.  Numbers to read.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import caustica
from caustica.experiments.convergence import rel_rmse, shared_refs_dir
from caustica.imageio import read_exr, read_png_mask

PHOTONS = 32_768


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=100)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--assoc", type=int, nargs="+", default=[0, 3, 10])
    args = ap.parse_args()
    refs = shared_refs_dir()
    if refs is None:
        raise SystemExit("no shared/refs beside the checkout (or $CAUSTICA_SHARED)")
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = [(f"pspm n_fa={a}, {PHOTONS // (a + 1):,} streams + {PHOTONS:,} caustic", "pspm",
                {"assoc": a, "streams": PHOTONS // (a + 1), "caustic_photons": PHOTONS}) for a in args.assoc]
    configs.append(("sppm defaults (32,768 + 32,768 aimed)", "sppm", {}))
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, 256x256, {args.passes} passes, "
          f"seeds {seeds}")
    print("| scene | configuration | caustic relRMSE | whole relRMSE | s / pass | load |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for name in ("cornell-diacaustic", "cornell-catacaustic"):
        ref = read_exr(refs / f"{name}_256.exr")[..., :3]
        mask = read_png_mask(refs / f"{name}_256_caustic_mask.png")
        scene = caustica.load_scene(name)
        for label, method, params in configs:
            caustica.render(scene, method, res=256, passes=1, **params)   # kernels compiled or loaded
            caustic, whole, per_pass = [], [], []
            load = os.getloadavg()[0]
            for seed in seeds:
                r = caustica.render(scene, method, res=256, seed=seed, passes=args.passes, **params)
                caustic.append(rel_rmse(r.image, ref, mask))
                whole.append(rel_rmse(r.image, ref))
                per_pass.append(statistics.median(r.stats["pass_seconds"]))
            sd = (lambda v: statistics.stdev(v) if len(v) > 1 else 0.0)
            print(f"| {name} | {label} | {statistics.mean(caustic):.4f} ± {sd(caustic):.4f} | "
                  f"{statistics.mean(whole):.4f} ± {sd(whole):.4f} | {statistics.mean(per_pass):.3f} | {load:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
