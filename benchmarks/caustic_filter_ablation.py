"""The caustic statistics' filter at a fixed number of passes: how much of the caustic error is bias, how much spread.

    python benchmarks/caustic_filter_ablation.py [--scene glossy|envmap|plastic] [--method sppm|pspm]
                                                 [--passes 800] [--seeds 0,1,2,3] [--filters none,epanechnikov]
                                                 [--ref-spp 32768] [--ptracer-spp 16384] [--res 96] [--set KEY=VALUE]

For each ``--caustic-filter``: the method at a fixed pass count (so the machine's load does not change an image) for
each seed, and the caustic-region relative RMSE (bench_caustic_goals.py's region and Mitsuba 3 references, cached in
out/refs/ by that script: run it first with ``--scene S --ref-spp 32768 --ptracer-spp 16384 --reference-only``, or
this script renders them itself) of each seed's image and of the seeds' mean image.  ``pspm`` keeps separate caustic
statistics only with caustic photons: give ``--set caustic_photons=N``.
Averaging S seeds divides the variance by S and leaves the bias, so with e the mean squared per-seed error and m the
mean image's squared error (each with the reference's own noise taken out):

    bias² ≈ (S m - e) / (S - 1),    spread² (per seed) ≈ S (e - m) / (S - 1).

Few seeds give both roughly (a difference of two close numbers).  No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

import caustica
from caustica.experiments.config import method_setting
from caustica.experiments.convergence import rel_rmse
from caustica.experiments.mitsuba import mitsuba_module

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_caustic_goals as goals  # noqa: E402  (the references and the caustic region)


def bias_and_spread(errors, m):
    """(bias, spread per seed) from the seeds' squared errors ``errors`` and the squared error m of their mean image,
    both with the reference's noise taken out (the module's formulas)."""
    s, e = len(errors), float(np.mean(errors))
    return max((s * m - e) / (s - 1), 0.0) ** 0.5, max(s * (e - m) / (s - 1), 0.0) ** 0.5


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="glossy", choices=sorted(goals.SCENES))
    ap.add_argument("--method", default="sppm", choices=("sppm", "pspm"))
    ap.add_argument("--passes", type=int, default=800)
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--filters", default="none,epanechnikov")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--ref-spp", type=int, default=32768)
    ap.add_argument("--ptracer-spp", type=int, default=16384)
    ap.add_argument("--dist", default="ggx")
    ap.add_argument("--alpha", default="0.1")
    ap.add_argument("--set", type=method_setting, action="append", default=[], metavar="KEY=VALUE",
                    help="another parameter of the method (a number or a string), e.g. caustic_photons=4608")
    args = ap.parse_args()
    extra = dict(args.set)
    seeds = [int(s) for s in args.seeds.split(",")]
    s = len(seeds)
    if s < 2:
        ap.error("--seeds: at least two seeds (the bias and the spread are told apart by averaging them)")
    if args.method == "pspm" and not extra.get("caustic_photons"):
        ap.error("--method pspm: give --set caustic_photons=N (without caustic photons pspm keeps no caustic "
                 "statistics to filter)")
    mi = mitsuba_module()
    if mi is None:
        raise SystemExit("Mitsuba 3 (scalar_rgb) is needed: pip install mitsuba")
    params = {"dist": args.dist, "alpha": args.alpha} if args.scene == "glossy" else {}
    path = goals.scene_file(args)
    _, _, _, direct = goals.reference(mi, args, path, params)
    ref_p, a_p, b_p = goals.particle_reference(mi, args, path, params)
    region = goals.caustic_region(ref_p, direct, goals.floor_pixels(mi, args, path, params))
    noise2 = (rel_rmse(a_p, b_p, region) / 2) ** 2
    scene = caustica.load_scene(path, **params)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {args.scene}, {args.method}, {args.passes} passes, seeds {seeds}, "
          f"{args.res}x{args.res}, caustic region {int(region.sum())} pixels, reference's own caustic error "
          f"{noise2 ** 0.5:.4f}, {extra or 'defaults'}")
    print("| filter | per-seed caustic relRMSE (noise out) | mean image's | bias | spread per seed | s / pass |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for name in args.filters.split(","):
        caustica.render(scene, args.method, res=args.res, passes=2, caustic_filter=name, **extra)   # compile
        images, errors, seconds = [], [], 0.0
        for seed in seeds:
            t0 = time.perf_counter()
            r = caustica.render(scene, args.method, res=args.res, seed=seed, passes=args.passes,
                                caustic_filter=name, **extra)
            seconds += time.perf_counter() - t0
            images.append(r.image.astype(np.float64))
            errors.append(max(rel_rmse(images[-1], ref_p, region) ** 2 - noise2, 0.0))
        m = max(rel_rmse(np.mean(images, axis=0), ref_p, region) ** 2 - noise2, 0.0)
        bias, spread = bias_and_spread(errors, m)
        per_seed = " ".join(f"{v ** 0.5:.4f}" for v in errors)
        print(f"| {name} | {per_seed} | {m ** 0.5:.4f} | {bias:.4f} | {spread:.4f} | "
              f"{seconds / (s * args.passes):.4f} |", flush=True)
    print(f"# load {os.getloadavg()[0]:.2f} at the end (the images do not depend on it; the s / pass column does)")


if __name__ == "__main__":
    main()
