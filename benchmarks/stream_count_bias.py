"""spm's image-mean deficit on a small curved object, told apart: the streams, or the photons' count.

On ``benchmarks/scenes/cylinder-floor.xml`` (a cylinder of radius 0.3 on a floor), each configuration's image mean
over 4 seeds against caustica's own ``pt`` at 2 x 1,024 spp, with the standard error of the seeds' mean.  With the
base lifted off the floor (``lift=0.3``) the corner between them is gone.  If ``spm`` lost light in its streams, it
would be short with its associated photons and not without them; if the k-nearest estimate from few records is what
is short, ``pm`` with as few photons is short the same, and more streams or a smaller k take it away.

    python benchmarks/stream_count_bias.py
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import caustica

SCENE = Path(__file__).with_name("scenes") / "cylinder-floor.xml"
SEEDS = range(4)
CONFIGS = [
    ("spm 10,000 x 10 (the paper's)", "spm", {}),
    ("spm 10,000 x 0 (no associated photons)", "spm", {"assoc": 0}),
    ("spm 10,000 x 10, r_s 0.05", "spm", {"stream_radius": 0.05}),
    ("spm 10,000 x 10, --estimator photons", "spm", {"estimator": "photons"}),
    ("spm 10,000 x 10, k 25", "spm", {"k": 25}),
    ("spm 100,000 x 10", "spm", {"streams": 100_000}),
    ("pm 10,000 photons", "pm", {"photons": 10_000}),
    ("pm 100,000 photons (its default)", "pm", {}),
]


def main() -> None:
    print("| lift | configuration | mean against pt | ± (se of 4 seeds) |\n| --- | --- | ---: | ---: |")
    for lift in ("0", "0.3"):
        scene = caustica.load_scene(str(SCENE), lift=lift)
        ref = np.mean([caustica.render(scene, "pt", spp=1024, seed=s).image.astype(np.float64).mean()
                       for s in range(2)])
        for label, method, params in CONFIGS:
            means = np.array([caustica.render(scene, method, spp=16, seed=s, **params).image.astype(np.float64).mean()
                              for s in SEEDS]) / ref - 1.0
            se = means.std(ddof=1) / len(means) ** 0.5
            print(f"| {lift} | {label} | {100 * means.mean():+.2f} % | {100 * se:.2f} |", flush=True)


if __name__ == "__main__":
    main()
