"""sppm on the diacaustic Cornell box with a rough plastic floor and back wall: the whole image's error at a fixed
number of passes, told apart into bias and spread over seeds, against Mitsuba 3's path tracer.

    python benchmarks/rough_plastic_box.py [--alpha 0.1] [--res 64] [--passes 256] [--seeds 0,1,2,3] [--ref-spp 32768]
                                           [--method sppm] [--set KEY=VALUE]

What it is for: a coating that reflects lit walls (indirect light) through a narrow lobe, where a photon estimate
weighted by the whole BSDF is noisier than a camera path that samples the lobe (docs/results.md, 2026-12-06).  The
scene is ../shared/scenes/cornell-diacaustic.xml with its floor and back wall made ``roughplastic`` (GGX,
``--alpha``), written to out/rough-plastic-box/; the reference (two halves of independent seeds) is cached there.
Spread and bias as benchmarks/caustic_filter_ablation.py solves them (:func:`bias_and_spread`).  No asserts: numbers to read.
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
from bench_caustic_goals import mitsuba_render  # noqa: E402  (Mitsuba's mean image in calls of 256 spp)
from caustic_filter_ablation import bias_and_spread  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED_SCENE = REPO.parent / "shared" / "scenes" / "cornell-diacaustic.xml"
COATED = ('<bsdf type="roughplastic" id="coated"><rgb name="diffuse_reflectance" value="0.75, 0.75, 0.75"/>'
          '<string name="distribution" value="ggx"/><float name="alpha" value="$alpha"/></bsdf>')


def scene_file(folder: Path) -> Path:
    """The box with its floor and back wall referring to a roughplastic ``coated`` (alpha a parameter)."""
    s = SHARED_SCENE.read_text()
    s = s.replace('<default name="max_depth" value="-1"/>',
                  '<default name="max_depth" value="-1"/>\n    <default name="alpha" value="0.1"/>')
    s = s.replace('<bsdf type="diffuse" id="blue">', COATED + '\n    <bsdf type="diffuse" id="blue">')
    for wall in ("floor", "back"):
        j = s.index('<ref id="white"/>', s.index(f'id="{wall}"'))
        s = s[:j] + '<ref id="coated"/>' + s[j + len('<ref id="white"/>'):]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "rough-plastic-box.xml"
    path.write_text(s)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--alpha", type=float, default=0.1)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--passes", type=int, default=256)
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--ref-spp", type=int, default=32768)
    ap.add_argument("--method", default="sppm", choices=("sppm", "pspm"))
    ap.add_argument("--set", type=method_setting, action="append", default=[], metavar="KEY=VALUE",
                    help="another parameter of the method, e.g. caustic_statistics=shared")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if len(seeds) < 2:
        ap.error("--seeds: at least two seeds (the bias and the spread are told apart by averaging them)")
    mi = mitsuba_module()
    if mi is None:
        raise SystemExit("Mitsuba 3 (scalar_rgb) is needed: pip install mitsuba")
    folder = REPO / "out" / "rough-plastic-box"
    path = scene_file(folder)
    cache = folder / f"ref-{args.alpha:g}-{args.res}-{args.ref_spp}.npz"
    if cache.is_file():
        z = np.load(cache)
        a, b = z["a"], z["b"]
    else:
        scene_mi = mi.load_file(str(path), res=args.res, alpha=args.alpha)
        t0 = time.perf_counter()
        a, b = (mitsuba_render(mi, scene_mi, args.ref_spp // 2, seed0) for seed0 in (0, 100_000))
        tmp = cache.with_suffix(".tmp.npz")
        np.savez(tmp, a=a, b=b)
        os.replace(tmp, cache)
        print(f"# reference: {args.ref_spp} spp in two halves, {time.perf_counter() - t0:.0f} s")
    ref = (a + b) / 2
    every = np.ones(ref.shape[:2], bool)
    noise2 = (rel_rmse(a, b, every) / 2) ** 2
    extra = dict(args.set)
    scene = caustica.load_scene(path, alpha=args.alpha)
    caustica.render(scene, args.method, res=args.res, passes=2, **extra)   # compile
    images, errors = [], []
    t0 = time.perf_counter()
    for seed in seeds:
        img = caustica.render(scene, args.method, res=args.res, seed=seed, passes=args.passes, **extra).image
        images.append(img.astype(np.float64))
        errors.append(max(rel_rmse(images[-1], ref, every) ** 2 - noise2, 0.0))
    m = max(rel_rmse(np.mean(images, axis=0), ref, every) ** 2 - noise2, 0.0)
    bias, spread = bias_and_spread(errors, m)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, alpha {args.alpha:g}, {args.method} {extra or 'defaults'}, "
          f"{args.res}², {args.passes} passes, seeds {seeds}, reference's own error {noise2 ** 0.5:.4f}")
    print(f"whole-image relRMSE per seed (noise out): {' '.join(f'{v ** 0.5:.4f}' for v in errors)}; "
          f"bias {bias:.4f}, spread per seed {spread:.4f}; mean / reference {np.mean(images) / ref.mean():.4f}; "
          f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
