"""What the global radius schedule costs: error at equal passes, --schedule pixel against global.

    python benchmarks/schedule_cost.py [--passes 32 160] [--seeds 2]

sppm (defaults, and 20k + 20k aimed caustic photons) and pspm (defaults) on
cornell-diacaustic and cornell-catacaustic at 256 x 256 against the Mitsuba references
in ../shared/refs: relative RMSE over the caustic mask and the whole image, mean over
seeds, for each schedule.  Equal passes, not equal time (a pass of either schedule does
the same tracing; how long the gather takes differs a little).  Numbers to read.
"""
from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import caustica
from caustica.experiments.convergence import rel_rmse
from caustica.imageio import read_exr, read_png_mask

REFS = Path(__file__).resolve().parents[2] / "shared" / "refs"
CONFIGS = (("sppm", "sppm", {}), ("sppm 20k + 20k caustic", "sppm", {"photons": 20_000, "caustic_photons": 20_000}),
           ("pspm", "pspm", {}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, nargs="+", default=[32, 160])
    ap.add_argument("--seeds", type=int, default=2)
    args = ap.parse_args()
    print("| scene | method | passes | caustic relRMSE, pixel | global | global / pixel | whole image, pixel | global |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in ("cornell-diacaustic", "cornell-catacaustic"):
        ref = read_exr(REFS / f"{name}_256.exr")
        mask = read_png_mask(REFS / f"{name}_256_caustic_mask.png")
        scene = caustica.load_scene(name)
        for label, method, params in CONFIGS:
            for passes in args.passes:
                err = {}
                for schedule in ("pixel", "global"):
                    images = [caustica.render(scene, method, res=256, seed=s, passes=passes, schedule=schedule,
                                              **params).image for s in range(args.seeds)]
                    err[schedule] = (statistics.mean(rel_rmse(im, ref, mask) for im in images),
                                     statistics.mean(rel_rmse(im, ref) for im in images))
                (cp, wp), (cg, wg) = err["pixel"], err["global"]
                print(f"| {name} | {label} | {passes} | {cp:.4f} | {cg:.4f} | {cg / cp:.2f} | {wp:.4f} | {wg:.4f} |",
                      flush=True)


if __name__ == "__main__":
    main()
