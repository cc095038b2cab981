"""The issue's 10-second goal: caustica's progressive methods against Mitsuba 3 at equal wall time.

    python benchmarks/bench_ten_seconds.py [--budget 10] [--seeds 0] [--res 256] [--ref-res 256] [--threads N]
                                           [--only LABEL] [--set KEY=VALUE]

For cornell-diacaustic and cornell-catacaustic: each configuration below renders once
untimed (a warm-up: kernels compiled or loaded), then with ``time_s=BUDGET``; Mitsuba 3's
path tracer (``scalar_rgb``) gets the same budget in the same run
(:func:`caustica.experiments.convergence.mitsuba_equal_time`: passes of 4 spp after its
own warm-up, until the next would cross the budget).  Every image is measured against
Mitsuba's converged reference in ``shared/refs`` over the caustic mask and the whole
image (relative RMSE, :func:`caustica.experiments.convergence.rel_rmse`), and the ratios
Mitsuba / caustica are printed.  The 1-minute load average is printed before each
render: on this project's 2-core machine, read the numbers of a loaded machine as such.
No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import caustica
from caustica.experiments.convergence import mitsuba_equal_time, mitsuba_module, rel_rmse, shared_refs_dir
from caustica.imageio import read_exr, read_png_mask

SCENES = ("cornell-diacaustic", "cornell-catacaustic")
#: (label, method, parameters).  sppm's defaults in these scenes: 32,768 + 32,768 aimed photons per
#: pass; with caustic photons it keeps separate caustic statistics (R_c = 0.6 R_0, the Epanechnikov filter) unless told
#: "shared" -- the README's best configuration of 2026-12-01 (now with this branch's camera pass).
CONFIGS = (
    ("sppm defaults", "sppm", {}),
    ("sppm, uniform caustic disc", "sppm", {"caustic_filter": "none"}),
    ("sppm 20k + 20k caustic, shared", "sppm", {"photons": 20_000, "caustic_photons": 20_000,
                                                "caustic_statistics": "shared"}),
    ("sppm 20k + 20k caustic", "sppm", {"photons": 20_000, "caustic_photons": 20_000}),
    ("sppm 20k + 20k caustic, R0 0.5, Rc 0.2", "sppm", {"photons": 20_000, "caustic_photons": 20_000,
                                                        "radius": 0.5, "caustic_radius": 0.2}),
    ("sppm 20k + 40k caustic", "sppm", {"photons": 20_000, "caustic_photons": 40_000}),
    # pspm with a caustic map: streams for the rest of the light, aimed photons for the caustic
    ("pspm + 32k caustic", "pspm", {"caustic_photons": 32_768}),
    ("pspm 2979 streams + 32k caustic", "pspm", {"streams": 2_979, "caustic_photons": 32_768}),
    # pspm as the paper's method (streams carry everything): merge at mirrors and glass, or split there
    ("pspm merge", "pspm", {}),
    ("pspm split", "pspm", {"specular": "split"}),
)

def load() -> float:
    return os.getloadavg()[0]


def _setting(item: str) -> tuple:
    """KEY=VALUE of ``--set``: the value as an int, a float or the text."""
    key, _, text = item.partition("=")
    for kind in (int, float):
        try:
            return key, kind(text)
        except ValueError:
            pass
    return key, text


def box_average(image, k: int):
    """``image`` averaged over k x k blocks of pixels (k = 1: itself)."""
    if k == 1:
        return image
    h, w = image.shape[0] // k, image.shape[1] // k
    return image[:h * k, :w * k].reshape(h, k, w, k, -1).mean(axis=(1, 3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=10.0, help="seconds per render (default 10)")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds (default 0)")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--threads", type=int)
    ap.add_argument("--refs", type=Path, help="folder of <scene>_<res>.exr and masks (default: shared/refs)")
    ap.add_argument("--only", action="append", help="run only the configurations whose label contains this "
                                                    "text (may be given more than once)")
    ap.add_argument("--json", type=Path, help="also write the rows to this file")
    ap.add_argument("--ref-res", type=int, help="the references' size (default: --res); a larger --res, a multiple of "
                                                "it, is box-averaged down to it (the scenes' box filter makes that the "
                                                "same pixel integrals)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a parameter added to every configuration run (its label says so); repeatable")
    args = ap.parse_args()
    ref_res = args.ref_res or args.res
    if args.res % ref_res:
        raise SystemExit(f"--res {args.res} is not a multiple of --ref-res {ref_res}")
    extra = dict(_setting(item) for item in args.set)
    refs = args.refs or shared_refs_dir()
    if refs is None:
        raise SystemExit("no reference folder: pass --refs or set CAUSTICA_SHARED")
    mi = mitsuba_module()
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = [(label + (f" [{', '.join(args.set)}]" if extra else ""), method, {**params, **extra})
               for label, method, params in CONFIGS if args.only is None or any(o in label for o in args.only)]
    down = args.res // ref_res
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}, "
          f"{args.res}x{args.res}{f' averaged to {ref_res}' if down > 1 else ''}, budget {args.budget:g} s, "
          f"seeds {seeds}, "
          f"Mitsuba {'yes' if mi is not None else 'not installed'}")
    print("| scene | seed | renderer | passes / spp | wall s | caustic relRMSE | whole relRMSE | load |")
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: |")
    rows = []
    for name in SCENES:
        ref = read_exr(refs / f"{name}_{ref_res}.exr")[..., :3]
        ref_spp = json.loads((refs / f"{name}_{ref_res}.json").read_text())["spp"]
        mask = read_png_mask(refs / f"{name}_{ref_res}_caustic_mask.png")
        scene = caustica.load_scene(name)
        for label, method, params in configs:   # warm-up: compile or load the kernels
            caustica.render(scene, method, res=args.res, passes=2, threads=args.threads, **params)
        for seed in seeds:
            got = []
            for label, method, params in configs:
                before = load()
                t0 = time.perf_counter()
                r = caustica.render(scene, method, res=args.res, seed=seed, time_s=args.budget,
                                    threads=args.threads, **params)
                wall = time.perf_counter() - t0
                image = box_average(r.image, down)
                row = {"scene": name, "seed": seed, "label": label, "passes": r.stats["passes"], "wall_s": wall,
                       "caustic": rel_rmse(image, ref, mask), "whole": rel_rmse(image, ref), "load": before}
                got.append(row)
            if mi is not None:
                before = load()
                image, wall, spp = mitsuba_equal_time(mi, name, args.res, args.budget, seed)
                image = box_average(image, down)
                got.append({"scene": name, "seed": seed, "label": "Mitsuba 3 path (scalar_rgb)", "passes": spp,
                            "wall_s": wall, "caustic": rel_rmse(image, ref, mask), "whole": rel_rmse(image, ref),
                            "load": before})
            for row in got:
                print(f"| {name} | {seed} | {row['label']} | {row['passes']} | {row['wall_s']:.2f} | "
                      f"{row['caustic']:.4f} | {row['whole']:.4f} | {row['load']:.2f} |", flush=True)
            if mi is not None:
                peer = got[-1]
                best = min(got[:-1], key=lambda r: r["caustic"])
                print(f"|  |  | **ratio Mitsuba / best ({best['label']})** |  |  | "
                      f"**{peer['caustic'] / best['caustic']:.1f}x** | {peer['whole'] / best['whole']:.2f}x |  |",
                      flush=True)
                # The reference is a Mitsuba render too, of ref_spp samples: its own error in the same
                # measure is about the peer's scaled by sqrt(spp / ref_spp) (the peer's error is nearly
                # all its variance), and every error above includes it in quadrature.
                noise = {k: peer[k] * (peer["passes"] / ref_spp) ** 0.5 for k in ("caustic", "whole")}
                print(f"|  |  | reference's own noise (est. {ref_spp:,} spp) |  |  | {noise['caustic']:.4f} | "
                      f"{noise['whole']:.4f} |  |", flush=True)
            rows += got
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
