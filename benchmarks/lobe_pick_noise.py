"""The noise of the camera path's pick between a narrow glossy lobe and a diffuse one (docs/results.md, "The camera
path's pick between glossy and diffuse lobes").

tests/scenes/plastic-caustic.xml with its floor made a ``pplastic`` of alpha 0.05 or a ``principled`` of roughness 0.2
(alpha 0.04): both narrow lobes beside a diffuse one, so ``sppm``'s camera paths take them apart
(``bsdfs.splits_lobes``, ``bsdfs.glossy_pick``).  For each floor: ``sppm`` at a fixed number of passes, several seeds,
and the per-pixel standard deviation over the seeds relative to the mean, over the image, outside its brightest 5 %
of pixels (the floor and its caustic) and inside them (the light's glossy highlight).  Noise at equal passes: the
pick changes no pass's cost measurably.

    python benchmarks/lobe_pick_noise.py [--passes 64] [--seeds 8] [--res 48]

To compare two trees, run it with each tree's ``src`` first on ``PYTHONPATH`` (and a kernel cache of its own,
``CAUSTICA_CACHE_DIR``).  No asserts.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import caustica

SCENE = Path(__file__).resolve().parent.parent / "tests" / "scenes" / "plastic-caustic.xml"
ROUGH_FLOOR = '<bsdf type="roughplastic">'
FLOORS = {
    "pplastic, alpha 0.05": lambda xml: xml.replace(ROUGH_FLOOR, '<bsdf type="pplastic">').replace(
        '<float name="alpha" value="0.15"/>', '<float name="alpha" value="0.05"/>'),
    "principled, roughness 0.2": lambda xml: xml.replace(
        xml[xml.index(ROUGH_FLOOR):xml.index("</bsdf>", xml.index(ROUGH_FLOOR)) + len("</bsdf>")],
        '<bsdf type="principled"><rgb name="base_color" value="0.6, 0.55, 0.5"/>'
        '<float name="roughness" value="0.2"/></bsdf>'),
}


def deviations(images: np.ndarray) -> tuple[float, float, float]:
    """Per-pixel standard deviation over the seeds relative to the mean: over the image, outside its brightest 5 %
    of pixels, inside them."""
    mean = images.mean(axis=0).mean(axis=-1)
    var = images.var(axis=0, ddof=1).mean(axis=-1)
    bright = mean > np.percentile(mean, 95)
    return (float(np.sqrt(var.mean()) / mean.mean()), float(np.sqrt(var[~bright].mean()) / mean[~bright].mean()),
            float(np.sqrt(var[bright].mean()) / mean[bright].mean()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--res", type=int, default=48)
    args = ap.parse_args()
    print(f"caustica {caustica.__version__} ({Path(caustica.__file__).parent}); sppm, {args.passes} passes, "
          f"{args.seeds} seeds, {args.res} px\n")
    print("| floor | image | outside the highlight | the highlight | mean | s a render |")
    print("| --- | ---: | ---: | ---: | --- | ---: |")
    xml = SCENE.read_text()
    with tempfile.TemporaryDirectory() as tmp:
        for name, make in FLOORS.items():
            path = Path(tmp) / "floor.xml"
            path.write_text(make(xml))
            scene = caustica.load_scene(path)
            caustica.render(scene, "sppm", res=args.res, passes=2, seed=99)   # compiled outside the timing
            t0 = time.perf_counter()
            images = np.array([caustica.render(scene, "sppm", res=args.res, passes=args.passes, seed=s)
                               .image.astype(np.float64) for s in range(args.seeds)])
            seconds = (time.perf_counter() - t0) / args.seeds
            means = images.mean(axis=(1, 2, 3))
            spread = means.std(ddof=1) / np.sqrt(args.seeds) / means.mean() * 100
            image, outside, inside = deviations(images)
            print(f"| {name} | {image:.3f} | {outside:.3f} | {inside:.3f} | {means.mean():.5f} ± {spread:.2f} % "
                  f"| {seconds:.2f} |")


if __name__ == "__main__":
    main()
