"""PM's image-mean deficit at mr = 64 against Mitsuba's reference, as the gather radius changes (docs/experiments.md).

The radius of a k-nearest estimate scales as sqrt(k / photons): the configurations change it by k and by
the photon count separately.  Needs Mitsuba's references (``shared/refs`` or ``$CAUSTICA_SHARED/refs``).

    python benchmarks/pm_radius_ablation.py cornell-diacaustic
"""
from __future__ import annotations

import json
import sys

import numpy as np

import caustica
from caustica.experiments.convergence import shared_refs_dir
from caustica.imageio import read_exr

CONFIGS = [(100_000, 100), (100_000, 25), (100_000, 400), (25_000, 100), (400_000, 100)]
SEEDS = (0, 1, 2)


def main(scene_name: str = "cornell-diacaustic") -> None:
    refs = shared_refs_dir()
    if refs is None:
        sys.exit("no shared/refs folder (set CAUSTICA_SHARED)")
    ref = read_exr(refs / f"{scene_name}_256.exr").astype(np.float64)
    scene = caustica.load_scene(scene_name)
    for photons, k in CONFIGS:
        errs = [caustica.render(scene, "pm", res=256, seed=seed, photons=photons, caustic_photons=0, k=k,
                                max_bounces=64).image.astype(np.float64).mean() / ref.mean() - 1 for seed in SEEDS]
        print(json.dumps({"scene": scene_name, "photons": photons, "k": k, "mean_err": float(np.mean(errs)),
                          "sd": float(np.std(errs, ddof=1))}), flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
