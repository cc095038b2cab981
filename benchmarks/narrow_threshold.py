"""Where a glossy lobe is narrow enough for the photon methods' camera paths to take it apart: ``bsdfs.NARROW_ALPHA``.

Three scenes (``--scene``): ``pplastic``, tests/scenes/plastic-caustic.xml with a ``pplastic`` floor of microfacet
alpha a (GGX; ``--values`` are alphas): a glass ball's caustic and a small light's highlight on it; ``panel``,
tests/scenes/principled-sharp-panel.xml, a frosted ``principled`` panel (``spec_trans`` 0.9) in front of a lit wall,
seen through the panel's glossy transmission (``--values`` are roughnesses r; alpha r²); ``box``, the paper's
diacaustic Cornell box with its floor a GGX ``pplastic`` of alpha a, which reflects the lit walls and the caustic.
For each value, ``sppm`` at a fixed number of passes and several seeds, twice: with the glossy lobe taken apart
(``split``: a camera path picks the glossy or the diffuse lobes, :func:`caustica.bsdfs.glossy_pick`) and with the whole
BSDF at the visible point (``whole``: photons weighted by the BSDF).  The choice is set for the run by assigning
``caustica.bsdfs.NARROW_ALPHA`` (1: every lobe split, 0: none) and, for ``whole``, ``caustica.bsdfs.transmits_glossily``
(a glossy transmission is split at any alpha otherwise) before the scene's tables are built.  Against Mitsuba 3's path
tracer (``scalar_rgb``, two halves of ``--ref-spp`` each, cached in out/refs/), printed per value and variant: one
render's relative RMSE, and with the reference's own noise taken out; the seeds' mean image's error (what is left is
mostly bias); the image mean against the reference's; seconds per render.

    python benchmarks/narrow_threshold.py [--scene pplastic|panel|box] [--values 0.05,0.09,0.1,0.12,0.15] [--passes 128]
                                          [--seeds 8] [--res 48] [--ref-spp 32768]

No asserts: numbers to read.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import caustica
import caustica.bsdfs
from caustica.experiments.convergence import rel_rmse
from caustica.experiments.mitsuba import mitsuba_module

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_caustic_goals import mitsuba_render  # noqa: E402  (Mitsuba's mean image in calls of 256 spp)

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "tests" / "scenes"
REFS = ROOT / "out" / "refs"
DEFAULT_VALUES = {"pplastic": "0.05,0.09,0.1,0.12,0.15", "panel": "0.1,0.2,0.25,0.3,0.35", "box": "0.05,0.1,0.2,0.4"}
BOX = ROOT / "src" / "caustica" / "scene" / "builtin" / "cornell-diacaustic.xml"
BOX_FLOOR = '<rotate x="1" angle="-90"/></transform>\n        <ref id="white"/>'


def scene_file(scene: str, value: float, folder: Path) -> tuple[Path, dict, float]:
    """(the XML file, its ``<default>`` values, the glossy lobe's alpha) of ``scene`` at ``value``."""
    if scene == "panel":
        return SCENES / "principled-sharp-panel.xml", {"rough": f"{value:g}"}, value * value
    if scene == "box":
        xml = BOX.read_text()
        assert BOX_FLOOR in xml
        path = folder / f"box-{value:g}.xml"
        path.write_text(xml.replace(BOX_FLOOR, BOX_FLOOR.replace(
            '<ref id="white"/>', '<bsdf type="pplastic"><rgb name="diffuse_reflectance" value="0.75, 0.75, 0.75"/>'
            f'<string name="distribution" value="ggx"/><float name="alpha" value="{value:g}"/></bsdf>')))
        return path, {}, value
    xml = (SCENES / "plastic-caustic.xml").read_text()
    path = folder / f"pplastic-{value:g}.xml"
    path.write_text(xml.replace('<bsdf type="roughplastic">', '<bsdf type="pplastic">').replace(
        '<float name="alpha" value="0.15"/>', f'<float name="alpha" value="{value:g}"/>'))
    return path, {}, value


def reference(mi, path: Path, defaults: dict, res: int, spp: int, label: str) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba's path tracer in two halves of ``spp`` each, of independent seeds (cached in out/refs/)."""
    cache = REFS / f"narrow-threshold-{label}-{res}-{spp}.npz"
    if cache.exists():
        z = np.load(cache)
        return z["a"], z["b"]
    scene = mi.load_file(str(path), res=res, **defaults)
    a, b = mitsuba_render(mi, scene, spp, 0), mitsuba_render(mi, scene, spp, 100_000)
    REFS.mkdir(parents=True, exist_ok=True)
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, a=a, b=b)
    os.replace(tmp, cache)
    return a, b


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=sorted(DEFAULT_VALUES), default="pplastic")
    ap.add_argument("--values", help="alphas (pplastic, box) or roughnesses (panel); default: "
                    + "; ".join(f"{k} {v}" for k, v in DEFAULT_VALUES.items()))
    ap.add_argument("--passes", type=int, default=128)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--ref-spp", type=int, default=32768, help="samples per pixel of each reference half")
    args = ap.parse_args()
    mi = mitsuba_module()
    if mi is None:
        raise SystemExit("needs Mitsuba 3 (pip install mitsuba)")
    print(f"# {platform.machine()}, {time.strftime('%Y-%m-%d %H:%M')}, {args.scene}, sppm {args.passes} passes x "
          f"{args.seeds} seeds, {args.res} px; Mitsuba path tracer 2 x {args.ref_spp} spp")
    print("| value | alpha | variant | one render's relRMSE (noise out) | the seeds' mean's relRMSE (noise out) "
          "| mean / ref | s a render |\n| ---: | ---: | --- | ---: | ---: | ---: | ---: |")
    # transmits_glossily exists since 90ad41d; before it a glossy transmission followed NARROW_ALPHA alone
    default = caustica.bsdfs.NARROW_ALPHA, getattr(caustica.bsdfs, "transmits_glossily", None)
    with tempfile.TemporaryDirectory() as tmp:
        for value in (float(v) for v in (args.values or DEFAULT_VALUES[args.scene]).split(",")):
            path, defaults, alpha = scene_file(args.scene, value, Path(tmp))
            ref_a, ref_b = reference(mi, path, defaults, args.res, args.ref_spp, f"{args.scene}-{value:g}")
            ref = 0.5 * (ref_a + ref_b)
            ref_noise = 0.5 * rel_rmse(ref_a, ref_b)   # the two halves' mean's own error
            for variant, threshold in (("split", 1.0), ("whole", 0.0)):
                caustica.bsdfs.NARROW_ALPHA = threshold
                if variant == "whole" and default[1] is not None:
                    caustica.bsdfs.transmits_glossily = lambda mat: False
                try:
                    scene = caustica.load_scene(str(path), res=str(args.res), **defaults)
                    caustica.render(scene, "sppm", passes=2, seed=999)   # warm-up: kernels compiled or loaded
                    t0 = time.perf_counter()
                    images = np.stack([caustica.render(scene, "sppm", passes=args.passes, seed=s).image
                                       for s in range(args.seeds)]).astype(np.float64)
                    per_render = (time.perf_counter() - t0) / args.seeds
                finally:
                    caustica.bsdfs.NARROW_ALPHA = default[0]
                    if default[1] is not None:
                        caustica.bsdfs.transmits_glossily = default[1]
                one = float(np.mean([rel_rmse(im, ref) for im in images]))
                mean_img = images.mean(axis=0)
                of_mean = rel_rmse(mean_img, ref)
                out = [np.sqrt(max(e * e - ref_noise * ref_noise, 0.0)) for e in (one, of_mean)]
                print(f"| {value:g} | {alpha:.4g} | {variant} | {one:.4f} ({out[0]:.4f}) | {of_mean:.4f} "
                      f"({out[1]:.4f}) | {mean_img.mean() / ref.mean():.4f} | {per_render:.2f} |", flush=True)


if __name__ == "__main__":
    main()
