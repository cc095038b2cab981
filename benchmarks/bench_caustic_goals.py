"""Issue 20's caustic goals: SPPM against Mitsuba 3's path tracer at equal wall time.

    python benchmarks/bench_caustic_goals.py [--scene glossy|envmap|plastic] [--budget 30] [--res 96] [--ref-spp 8192]
                                             [--ptracer-spp 16384] [--seeds 0] [--dist ggx] [--alpha 0.1]
                                             [--threads N] [--reference-only] [--sppm LABEL=KEY:VALUE,...]
                                             [--region-grid N] [--also-region-grid N]

Scenes (``--scene``):

* ``glossy`` (default): tests/scenes/glossy-caustic.xml, a rough glass ball and a rough silver ring (``--dist``,
  ``--alpha`` set both) on a diffuse floor under a small square light.  Goal: sppm's mean within 2 % of the
  reference, its caustic error at 30 s at least 5x below Mitsuba's.
* ``envmap``: benchmarks/scenes/envmap-caustic.xml, a glass ball on a diffuse floor under a sky with a small sun
  (:func:`sun_sky_map`, written with a copy of the scene to out/envmap-caustic/).  Goal: sppm within 3 % of the
  reference, its caustic error at 30 s at least 5x below Mitsuba's.
* ``plastic``: tests/scenes/plastic-caustic.xml, a glass ball on a rough plastic floor (GGX, alpha 0.15) under a
  small square light: the caustic lands on a BSDF with a glossy lobe beside its diffuse one (no goal of its own).

* References, Mitsuba 3 (``scalar_rgb``), each in two halves of independent seeds, cached in out/refs/: for the
  whole image its path tracer at ``--ref-spp`` samples per pixel; for the caustic region its particle tracer
  (``ptracer``, ``--ptracer-spp``), which renders the floor seen directly in full and converges on a caustic far
  sooner (envmap scene, 96 px: its halves' caustic error at 512 spp was 0.027, the path tracer's at 32,768 spp
  0.069).  A reference's own error is half the relative RMSE between its halves; each error is printed as
  measured and with that noise taken out in quadrature.
* Caustic region: the pixels whose rays through a 4 x 4 grid (``--region-grid``) over the pixel all first meet the
  floor (Mitsuba's ``ray_intersect``: a pixel the casters' silhouette crosses is left out, :func:`floor_pixels`; a
  grid of 1 is the pixel's centre ray alone, the region before 2026-12-06) and where the
  particle tracer's reference exceeds a direct-light-only render (Mitsuba, ``max_depth`` 2) by at least 0.1 of that
  excess's 99.9th percentile over the floor: the light that reached the floor through the ball or off the ring.
* Timed: ``sppm`` (:data:`CONFIGS`) with ``--time BUDGET`` after an untimed warm-up (kernels compiled or loaded), and
  Mitsuba's path tracer for the same budget in the same run
  (:func:`caustica.experiments.mitsuba.mitsuba_equal_time`).  Relative RMSE over the caustic region and the whole
  image, image means against the reference's, and the ratio Mitsuba / sppm.  ``--also-region-grid N`` adds the
  caustic error over the region made with an N x N grid, from the same renders (two regions told apart in one run).

The 1-minute load average is printed before each render: read a loaded machine's numbers as such.  No asserts:
numbers to read.
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np

import caustica
from caustica.experiments.config import method_setting
from caustica.experiments.convergence import rel_rmse
from caustica.experiments.mitsuba import mitsuba_equal_time, mitsuba_module
from caustica.imageio import write_exr

REPO = Path(__file__).resolve().parents[1]
SCENES = {"glossy": REPO / "tests" / "scenes" / "glossy-caustic.xml",
          "envmap": REPO / "benchmarks" / "scenes" / "envmap-caustic.xml",
          "plastic": REPO / "tests" / "scenes" / "plastic-caustic.xml"}
REF_SPP_PER_CALL = 256
#: sppm configurations: (label, parameters).  Its defaults: one photon per pixel per pass, half of them aimed at the
#: caustic casters (the ball and the ring; the glass ball), with the caustic events' own statistics.
CONFIGS = (
    ("sppm defaults", {}),
    ("sppm 20k + 20k caustic", {"photons": 20_000, "caustic_photons": 20_000}),
    ("sppm 10k + 60k caustic", {"photons": 10_000, "caustic_photons": 60_000}),
)


def mitsuba_render(mi, scene, spp, seed0, integrator=None):
    """Mean of spp samples per pixel in calls of REF_SPP_PER_CALL, seeded seed0, seed0 + 1, ... (float64)."""
    acc, calls = 0.0, max(1, spp // REF_SPP_PER_CALL)
    for i in range(calls):
        kw = {} if integrator is None else {"integrator": integrator}
        acc = acc + np.array(mi.render(scene, spp=REF_SPP_PER_CALL, seed=seed0 + i, **kw), np.float64)[..., :3]
    return acc / calls


def sun_sky_map(path: Path) -> None:
    """benchmarks/scenes/envmap-caustic.xml's environment (128 x 256, linear RGB): a sky brighter towards the
    zenith, darker below the horizon, and a 2 x 2-texel sun (rows 38-39, columns 63-64: about 35 degrees up, along
    +x in Mitsuba's equirectangular mapping) giving about 4.5 times the sky's irradiance on the floor."""
    h, w = 128, 256
    v = (np.arange(h) + 0.5) / h
    sky = 0.25 + 0.35 * (1 - v)
    img = np.empty((h, w, 3), np.float32)
    img[:] = np.stack([0.6 * sky, 0.8 * sky, sky], -1)[:, None, :]
    img[h // 2:] *= 0.3
    img[38:40, 63:65] = (3000.0, 2800.0, 2400.0)
    write_exr(path, img)


def scene_file(args) -> Path:
    """The scene's XML: the glossy one as it is; the envmap one copied to out/envmap-caustic/ beside its map."""
    if args.scene != "envmap":
        return SCENES[args.scene]
    folder = REPO / "out" / "envmap-caustic"
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(SCENES["envmap"], folder / SCENES["envmap"].name)
    sun_sky_map(folder / "sun-sky.exr")
    return folder / SCENES["envmap"].name


def reference(mi, args, path, params):
    """(reference, its first half, its second half, the direct-light-only render), cached in out/refs/."""
    tag = f"glossy-caustic-{args.dist}-{args.alpha}" if args.scene == "glossy" else f"{args.scene}-caustic"
    cache = REPO / "out" / "refs" / f"{tag}-{args.res}-{args.ref_spp}.npz"
    if cache.is_file():
        z = np.load(cache)
        return z["ref"], z["a"], z["b"], z["direct"]
    scene = mi.load_file(str(path), res=args.res, **params)
    t0 = time.perf_counter()
    half = args.ref_spp // 2
    a = mitsuba_render(mi, scene, half, 0)
    b = mitsuba_render(mi, scene, half, 100_000)
    direct = mitsuba_render(mi, scene, args.ref_spp, 200_000, mi.load_dict({"type": "path", "max_depth": 2}))
    print(f"# reference: {args.ref_spp} spp in two halves and a direct-only render, {time.perf_counter() - t0:.0f} s")
    cache.parent.mkdir(parents=True, exist_ok=True)
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, ref=(a + b) / 2, a=a, b=b, direct=direct)
    os.replace(tmp, cache)
    return (a + b) / 2, a, b, direct


def particle_reference(mi, args, path, params):
    """(the particle tracer's reference, its first half, its second half), cached in out/refs/."""
    tag = f"glossy-caustic-{args.dist}-{args.alpha}" if args.scene == "glossy" else f"{args.scene}-caustic"
    cache = REPO / "out" / "refs" / f"{tag}-{args.res}-ptracer-{args.ptracer_spp}.npz"
    if cache.is_file():
        z = np.load(cache)
        return z["ref"], z["a"], z["b"]
    scene = mi.load_file(str(path), res=args.res, **params)
    ptracer = mi.load_dict({"type": "ptracer"})
    t0 = time.perf_counter()
    half = args.ptracer_spp // 2
    a = mitsuba_render(mi, scene, half, 300_000, ptracer)
    b = mitsuba_render(mi, scene, half, 400_000, ptracer)
    print(f"# particle tracer's reference: {args.ptracer_spp} spp in two halves, {time.perf_counter() - t0:.0f} s")
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, ref=(a + b) / 2, a=a, b=b)
    os.replace(tmp, cache)
    return (a + b) / 2, a, b


def floor_pixels(mi, args, path, params, grid=4):
    """bool[H, W]: the pixels whose rays through each of a ``grid`` x ``grid`` set of positions over the pixel (its box
    filter's footprint) all first meet the shape with id "floor".  A pixel the casters' silhouette crosses is left
    out: the particle tracer's reference cannot see a glass ball or a mirror ring, so it lacks their share there."""
    scene = mi.load_file(str(path), res=args.res, **params)
    sensor = scene.sensors()[0]
    w, h = sensor.film().crop_size()
    offsets = (np.arange(grid) + 0.5) / grid

    def on_floor(u, v):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u / w, v / h), mi.Point2f(0.5, 0.5))
        si = scene.ray_intersect(ray)
        return bool(si.is_valid()) and si.shape.id() == "floor"

    out = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            out[y, x] = all(on_floor(x + ox, y + oy) for oy in offsets for ox in offsets)
    return out


def caustic_region(ref, direct, floor):
    excess = (ref - direct).sum(axis=2)
    level = 0.1 * np.percentile(excess[floor], 99.9)
    return floor & (excess >= level)


def parse_config(text: str) -> tuple[str, dict]:
    """``LABEL=KEY:VALUE,KEY:VALUE`` -> (label, sppm parameters); numbers are read as int or float (argparse type of
    ``--sppm``: an item without its colon is a usage error, not a traceback)."""
    label, _, rest = text.partition("=")
    items = [item.strip() for item in rest.split(",") if item.strip()]
    for item in items:
        if ":" not in item:
            raise argparse.ArgumentTypeError(f"{text!r}: {item!r} is not KEY:VALUE, e.g. 'alpha 0.5=alpha:0.5'")
    return label.strip(), dict(method_setting(item.replace(":", "=", 1)) for item in items)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="glossy", choices=sorted(SCENES))
    ap.add_argument("--budget", type=float, default=30.0, help="seconds per render (default 30)")
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--ref-spp", type=int, default=8192, help="the reference's samples per pixel (default 8192)")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds (default 0)")
    ap.add_argument("--dist", default="ggx", choices=("ggx", "beckmann"), help="glossy: the microfacet distribution")
    ap.add_argument("--alpha", default="0.1", help="glossy: the roughness")
    ap.add_argument("--threads", type=int)
    ap.add_argument("--ptracer-spp", type=int, default=16384,
                    help="the particle tracer's reference, samples per pixel (default 16384)")
    ap.add_argument("--reference-only", action="store_true", help="make (or check) the cached reference and stop")
    ap.add_argument("--region-grid", type=int, default=4, choices=range(1, 9), metavar="N",
                    help="the caustic region's pixels are wholly on the floor at N x N rays each (default 4; 1: the "
                         "centre ray alone)")
    ap.add_argument("--also-region-grid", type=int, choices=range(1, 9), metavar="N",
                    help="also print the caustic error over the region an N x N grid makes, from the same renders")
    ap.add_argument("--sppm", type=parse_config, action="append", metavar="LABEL=KEY:VALUE,...",
                    help="an sppm configuration to time instead of the built-in ones (repeatable), e.g. "
                         "'alpha 0.5=alpha:0.5' or 'defaults='")
    args = ap.parse_args()
    configs = CONFIGS if not args.sppm else tuple(args.sppm)
    mi = mitsuba_module()
    if mi is None:
        raise SystemExit("Mitsuba 3 (scalar_rgb) is needed: pip install mitsuba")
    params = {"dist": args.dist, "alpha": args.alpha} if args.scene == "glossy" else {}
    path = scene_file(args)
    ref, a, b, direct = reference(mi, args, path, params)
    ref_p, a_p, b_p = particle_reference(mi, args, path, params)
    if args.reference_only:
        return
    region = caustic_region(ref_p, direct, floor_pixels(mi, args, path, params, args.region_grid))
    regions = {"caustic": region}
    if args.also_region_grid:
        regions["other"] = caustic_region(ref_p, direct, floor_pixels(mi, args, path, params, args.also_region_grid))
    refs = {"caustic": ref_p, "whole": ref, "other": ref_p}
    noise = {k: rel_rmse(a_p, b_p, r) / 2 for k, r in regions.items()}
    noise["whole"] = rel_rmse(a, b) / 2
    kinds = ("caustic", "whole") + (("other",) if args.also_region_grid else ())
    what = f"{args.dist} alpha {args.alpha}, " if args.scene == "glossy" else ""
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}, {path.name} {what}"
          f"{args.res}x{args.res}, budget {args.budget:g} s, caustic region {int(region.sum())} pixels "
          f"({args.region_grid}x{args.region_grid} rays on the floor), references "
          f"{args.ptracer_spp} spp ptracer (own caustic error {noise['caustic']:.4f}), {args.ref_spp} spp path (own "
          f"whole-image error {noise['whole']:.4f}), mean {ref.mean():.5f}; the caustic region's mean: ptracer / "
          f"path {ref_p[region].mean() / ref[region].mean():.4f}")
    other = ""
    if args.also_region_grid:
        g = args.also_region_grid
        other = f" caustic relRMSE over the {g}x{g} region (noise out) |"
        print(f"# the {g}x{g} region: {int(regions['other'].sum())} pixels, {int((regions['other'] & ~region).sum())} "
              f"of them not in the caustic region, {int((region & ~regions['other']).sum())} of it not in them; the "
              f"ptracer's own error there {noise['other']:.4f}")
    print(f"| seed | renderer | passes / spp | wall s | mean / ref | caustic relRMSE (noise out) | "
          f"whole relRMSE (noise out) |{other} load |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: |" + (" ---: |" if other else "") + " ---: |")
    scene = caustica.load_scene(path, **params)
    for _, config in configs:   # warm-up: compile or load the kernels
        caustica.render(scene, "sppm", res=args.res, passes=2, threads=args.threads, **config)
    for seed in (int(s) for s in args.seeds.split(",")):
        rows = []
        for label, config in configs:
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            r = caustica.render(scene, "sppm", res=args.res, seed=seed, time_s=args.budget, threads=args.threads,
                                **config)
            rows.append((label, r.stats["passes"], time.perf_counter() - t0, r.image, load))
        load = os.getloadavg()[0]
        image, wall, spp = mitsuba_equal_time(mi, path, args.res, args.budget, seed, **params)
        rows.append(("Mitsuba 3 path (scalar_rgb)", spp, wall, image, load))
        errors = []
        for label, count, wall, image, load in rows:
            e = {k: rel_rmse(image, refs[k], regions.get(k)) for k in kinds}
            out = {k: max(e[k] ** 2 - noise[k] ** 2, 0.0) ** 0.5 for k in e}
            errors.append(out)
            cells = " | ".join(f"{e[k]:.4f} ({out[k]:.4f})" for k in kinds)
            print(f"| {seed} | {label} | {count} | {wall:.1f} | {image.mean() / ref.mean():.4f} | {cells} | "
                  f"{load:.2f} |", flush=True)
        best = min(range(len(configs)), key=lambda i: errors[i]["caustic"])
        ratio = {k: f"{errors[-1][k] / errors[best][k]:.2f}x" if errors[best][k] > 0 else "n/a (below the "
                 "reference's noise)" for k in kinds}
        cells = " | ".join(ratio[k] for k in kinds[1:])
        print(f"| {seed} | **ratio Mitsuba / best ({rows[best][0]}), noise out** |  |  |  | **{ratio['caustic']}** | "
              f"{cells} |  |", flush=True)


if __name__ == "__main__":
    main()
