"""Issue 11's photon goal: sppm and pspm in the fog box against Mitsuba 3's volpath at equal wall time.

    python benchmarks/bench_media.py [--budget 30] [--seeds 0] [--res 256] [--threads N] [--only TEXT,...]
    python benchmarks/bench_media.py --passes 40 --seeds 0,1,2 --only pspm   # equal passes, no Mitsuba
    python benchmarks/bench_media.py --reference-only      # render (or finish) the reference, then stop

The scene is the built-in ``cornell-diacaustic-fog`` at 256 x 256.  Each caustica configuration
below renders once untimed (kernels compiled or loaded), then with ``time_s=BUDGET``; Mitsuba 3's
``volpath`` (the scene's own integrator, ``scalar_rgb``) gets the same budget in the same run
(:func:`caustica.experiments.convergence.mitsuba_equal_time`).  Every image is measured against the
reference over the volumetric caustic mask and over the whole image (relative RMSE), and the ratio
Mitsuba / best caustica is printed.  No asserts: numbers to read.

**The reference** is caustica's own volumetric path tracer (``pt``, which agrees with Mitsuba's
volpath: docs/media.md), REF_CHUNKS renders of 1,024 spp with seeds 1000, 1001, ..., each cached as
``out/media-ref/pt_<res>_spp1024_seed<seed>.npy`` (``out/`` is gitignored; missing chunks are rendered
on the next run, one thread, resumable).  Its own noise is printed: the relative RMSE of half the
chunks against the other half, halved (the error of the mean of all chunks, if their noise is
independent) — the floor under every error measured against it.

**The volumetric caustic mask** is where the light focused by the glass sphere and then scattered in
the fog is a large part of what a pixel sees.  That component is rendered alone, photons only, with
keys of its own (``STREAM_CAUSTIC_MASK``, never a render's): MASK_PASSES passes of MASK_PHOTONS photons
aimed at the sphere (sppm's caustic photons), of which only the first scattering event in the fog
after the glass is kept (light -> glass+ -> fog), gathered by the beam radiance estimate along each
pixel's camera segments with radius MASK_RADIUS (caustica's kernels: camera pass, photon tracer, grid,
gather).  Mask = where that component is bright, by the rule of the surface caustic masks
(experiments/masks.py): a 3 x 3 box blur, at least MASK_LEVEL times its 99.9th percentile, dilated by
one pixel.  The fog is thin (mean free path 20), so even there the component is only about 1 % of a
pixel's radiance: the mask is the region around and behind the sphere where the focused light
passes through the fog — mostly seen through the glass and along its silhouette — and what is
measured there is the whole image's error.  Its size is printed; ``--save-mask FILE.png`` writes it.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

import caustica
from caustica.experiments.convergence import mitsuba_equal_time, mitsuba_module, rel_rmse

SCENE = "cornell-diacaustic-fog"
REF_DIR = Path(__file__).resolve().parents[1] / "out" / "media-ref"
REF_CHUNKS = 16
REF_SPP = 1024
MASK_PASSES = 16
MASK_PHOTONS = 1_000_000
MASK_RADIUS = 0.1
MASK_LEVEL = 0.1
MASK_SEED = 99_991

#: (label, method, parameters).  Every configuration runs photons until roulette ends them (the
#: reference is unbiased, with no depth limit).  sppm's defaults in this scene: 32,768 + 32,768 aimed
#: photons per pass, R_0 = 0.347 (1 % of the diagonal), R_v0 = R_0, separate caustic statistics.
#: pspm's: 5,957 streams of 1 + 10 photons per pass (65,527 photons), r_s = 5 at the first pass; under
#: ``--estimator stream`` a record counts at its leading photon whatever its associated photons do, so
#: ``--medium-scattering`` spread and merge give the same image there with roulette (docs/media.md): one row.
CONVERGED = {"max_bounces": 64, "termination": "roulette"}
PHOTONS = {**CONVERGED, "estimator": "photons"}
AIMED = {"streams": 2_979, "caustic_photons": 32_768}   # 32,769 stream photons + 32,768 aimed, as sppm
CONFIGS = (
    ("sppm defaults (R_v0 = R_0)", "sppm", {**CONVERGED}),
    ("sppm R_v0 2 R_0", "sppm", {**CONVERGED, "volume_radius": 0.6935}),
    ("sppm R_v0 0.2", "sppm", {**CONVERGED, "volume_radius": 0.2}),
    ("sppm 16k + 48k aimed", "sppm", {**CONVERGED, "photons": 16_384, "caustic_photons": 49_152}),
    ("sppm 8k + 56k aimed", "sppm", {**CONVERGED, "photons": 8_192, "caustic_photons": 57_344}),
    ("sppm global schedule", "sppm", {**CONVERGED, "schedule": "global"}),
    ("pspm stream estimator", "pspm", {**CONVERGED}),
    ("pspm photons spread", "pspm", {**PHOTONS, "medium_scattering": "spread"}),
    ("pspm photons merge", "pspm", {**PHOTONS, "medium_scattering": "merge"}),
    ("pspm photons spread r_s 1", "pspm", {**PHOTONS, "stream_radius": 1.0, "medium_scattering": "spread"}),
    ("pspm photons merge r_s 1", "pspm", {**PHOTONS, "stream_radius": 1.0, "medium_scattering": "merge"}),
    ("pspm stream + 32k aimed", "pspm", {**CONVERGED, **AIMED}),
    ("pspm photons spread + 32k aimed", "pspm", {**PHOTONS, **AIMED, "medium_scattering": "spread"}),
)


def load() -> float:
    return os.getloadavg()[0]


def reference(res: int, n_chunks: int = REF_CHUNKS, threads: int | None = 1):
    """(the mean of the reference chunks, the mean of its first half, of its second half); renders missing chunks."""
    REF_DIR.mkdir(parents=True, exist_ok=True)
    scene = None
    chunks = []
    for k in range(n_chunks):
        path = REF_DIR / f"pt_{res}_spp{REF_SPP}_seed{1000 + k}.npy"
        if not path.is_file():
            if scene is None:
                scene = caustica.load_scene(SCENE, res=res)
            t0 = time.perf_counter()
            img = caustica.render(scene, "pt", spp=REF_SPP, seed=1000 + k, threads=threads).image
            np.save(path, img)
            print(f"# reference chunk {k + 1}/{n_chunks}: {time.perf_counter() - t0:.0f} s", flush=True)
        chunks.append(np.load(path).astype(np.float64))
    ref = np.mean(chunks, axis=0)
    half = len(chunks) // 2
    a, b = np.mean(chunks[:half], axis=0), np.mean(chunks[half:2 * half], axis=0)
    return ref, a, b


def volumetric_caustic(res: int, threads: int | None = None) -> np.ndarray:
    """H x W x 3: the light -> glass+ -> fog component alone, by the beam estimate (see the module's docstring)."""
    from caustica.jit import parallel_for
    from caustica.photons.beams import beam_gather, build_volume_grid
    from caustica.photons.records import VOLUME_CAUSTIC, allocate_buffers
    from caustica.photons.trace import trace_caustic_photon_pass
    from caustica.photons.segments import MEDIUM_SEGMENTS, allocate_segments
    from caustica.photons.visible_points import UNLIMITED_DEPTH, VisiblePoints, visible_points
    from caustica.sampling.rng import STREAM_CAUSTIC_MASK, pass_stream
    scene = caustica.load_scene(SCENE, res=res)
    n = res * res
    cam = scene.camera(res, res)
    spheres = scene.specular_bounding_spheres()
    out = np.zeros((n, 3))
    for p in range(MASK_PASSES):
        vp = VisiblePoints(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.bool_),
                           np.empty((n, 3)), np.empty((n, 1)), np.empty(n, np.int32))   # no BSDF-evaluating points
        seg = allocate_segments(n, True)
        keys = (MASK_SEED, pass_stream(STREAM_CAUSTIC_MASK, 2 * p), pass_stream(STREAM_CAUSTIC_MASK, 2 * p + 1), p)
        parallel_for(visible_points, n, (scene.tables, cam, keys, (1, False, 16, UNLIMITED_DEPTH, False), (vp, seg)),
                     threads=threads)
        buf = allocate_buffers(MASK_PHOTONS, 1)
        trace_caustic_photon_pass(scene, buf, MASK_SEED, pass_stream(STREAM_CAUSTIC_MASK, 2 * MASK_PASSES + p),
                                  MASK_PHOTONS, spheres=spheres, threads=threads)
        keep = buf.kind == VOLUME_CAUSTIC
        vg = build_volume_grid(buf.position[keep], buf.direction[keep], buf.power[keep], MASK_RADIUS)
        vol = np.empty((n, 3))
        found = np.empty(n, np.int64)
        parallel_for(beam_gather, n, (vg, scene.media, (seg, MEDIUM_SEGMENTS, None), (vol, found)), threads=threads)
        out += vol
    return (out / MASK_PASSES).reshape(res, res, 3)


def volumetric_caustic_mask(comp: np.ndarray) -> np.ndarray:
    """The pixels where the component is bright: experiments/masks.py's rule (3 x 3 box blur at 256 px, at least
    MASK_LEVEL times the 99.9th percentile of the non-empty pixels, dilated by one pixel)."""
    from caustica.experiments.masks import _box_blur, _dilate
    lum = comp.mean(axis=2)
    smooth = _box_blur(lum, max(1, min(lum.shape) // 256))
    level = MASK_LEVEL * np.percentile(smooth[smooth > 0], 99.9)
    return _dilate(smooth >= level, 1)


#: The configuration --agreement renders by default (the best of the 30-second table, docs/media.md).
BEST = "sppm defaults (R_v0 = R_0)"
#: One-shot configurations, for --agreement only (they take no time budget): their bias does not fall with time.
ONE_SHOT = (
    ("pm 1M photons, 16 spp", "pm", {**CONVERGED, "photons": 1_000_000, "spp": 16}),
    ("pm 1M + 1M aimed, 16 spp", "pm", {**CONVERGED, "photons": 1_000_000, "caustic_photons": 1_000_000, "spp": 16}),
    ("spm 100k streams, 16 spp", "spm", {**CONVERGED, "streams": 100_000, "spp": 16}),
)


def agreement(args, ref, ref_a, ref_b) -> None:
    """Image mean and 16-pixel block means (4 x 4 blocks of the image box-filtered to 32 x 32) against the reference."""
    label = args.agreement_config or BEST
    method, params = {name: (m, p) for name, m, p in CONFIGS + ONE_SHOT}[label]
    budget = {} if method in ("pm", "spm") else {"passes": args.agreement}
    seeds = [int(s) for s in args.seeds.split(",")]
    scene = caustica.load_scene(SCENE)
    f = args.res // 32

    def blocks(img):
        small = img.reshape(32, f, 32, f, 3).mean(axis=(1, 3))
        return small.reshape(8, 4, 8, 4, 3).mean(axis=(1, 3))
    t0 = time.perf_counter()
    ours = [caustica.render(scene, method, res=args.res, seed=s, **budget, threads=args.threads,
                            **params).image.astype(np.float64) for s in seeds]
    wall = time.perf_counter() - t0
    b_ref = blocks(ref)
    b_ours = blocks(np.mean(ours, axis=0))
    # the blocks' noise: the reference's from its halves, ours from the seeds' spread
    se_ref = np.abs(blocks(ref_a) - blocks(ref_b)) / 2
    se_ours = (np.std([blocks(o) for o in ours], axis=0, ddof=1) / np.sqrt(len(ours)) if len(ours) > 1
               else np.zeros_like(b_ref))
    rel = (b_ours - b_ref) / b_ref
    z = (b_ours - b_ref) / np.sqrt(se_ref ** 2 + se_ours ** 2)
    print(f"# {platform.machine()}, {time.strftime('%Y-%m-%d %H:%M')}, load {load():.2f}: {label}, "
          f"{args.agreement if budget else 1} passes x seeds {seeds} ({wall:.0f} s) vs the reference ({args.ref_chunks} x {REF_SPP} spp)")
    print(f"image mean: {np.mean(ours) / ref.mean() - 1:+.2%}; 16-pixel block means (192 values) within 5 %: "
          f"{np.mean(np.abs(rel) <= 0.05):.1%}; largest difference {np.abs(rel).max():.1%}; "
          f"|z| > 3 (noise of both sides, rough): {int(np.sum(np.abs(z) > 3))}")
    worst = np.unravel_index(np.argmax(np.abs(rel)), rel.shape)
    print(f"worst block {worst[:2]} channel {worst[2]}: {b_ours[worst]:.4f} vs {b_ref[worst]:.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=30.0, help="seconds per render (default 30)")
    ap.add_argument("--seeds", default="0", help="comma-separated seeds (default 0)")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--threads", type=int)
    ap.add_argument("--only", help="run only the configurations whose label contains any of these "
                                   "comma-separated texts")
    ap.add_argument("--passes", type=int, help="instead of the budget: this many passes each (an ablation at "
                                               "equal work, free of the machine's load; Mitsuba is not run)")
    ap.add_argument("--reference-only", action="store_true", help="render the missing reference chunks and stop")
    ap.add_argument("--ref-chunks", type=int, default=REF_CHUNKS, help=f"reference chunks to use (default {REF_CHUNKS})")
    ap.add_argument("--save-mask", type=Path, help="write the volumetric caustic mask to this PNG")
    ap.add_argument("--save-images", type=Path, help="write every render to this folder (.npy)")
    ap.add_argument("--json", type=Path, help="also write the rows to this file")
    ap.add_argument("--agreement", type=int, metavar="PASSES",
                    help="instead: the best configuration's image mean and 16-pixel block means at 32 x 32 against "
                         "the reference's, after PASSES passes (seeds as --seeds)")
    ap.add_argument("--agreement-config", metavar="LABEL",
                    help=f"the configuration --agreement renders (default: {BEST!r}; also one-shot ones: "
                         + ", ".join(repr(c[0]) for c in ONE_SHOT) + ")")
    args = ap.parse_args()
    ref, ref_a, ref_b = reference(args.res, args.ref_chunks)
    if args.reference_only:
        return
    if args.agreement:
        agreement(args, ref, ref_a, ref_b)
        return
    comp = volumetric_caustic(args.res, args.threads)
    mask = volumetric_caustic_mask(comp)
    if args.save_mask:
        from caustica.imageio import write_png
        write_png(args.save_mask, np.repeat(mask[..., None], 3, axis=2).astype(np.float32))
    mi = mitsuba_module()
    seeds = [int(s) for s in args.seeds.split(",")]
    configs = [c for c in CONFIGS if args.only is None or any(t in c[0] for t in args.only.split(","))]
    if args.passes:
        mi = None
    print(f"# {platform.machine()}, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M')}, {SCENE} "
          f"{args.res}x{args.res}, " + (f"{args.passes} passes" if args.passes else f"budget {args.budget:g} s")
          + f", seeds {seeds}, "
          f"Mitsuba {'yes' if mi is not None else 'not run' if args.passes else 'not installed'}")
    ref_mask, ref_whole = rel_rmse(ref_a, ref_b, mask) / 2, rel_rmse(ref_a, ref_b) / 2
    print(f"# reference: caustica pt, {args.ref_chunks} x {REF_SPP} spp; its own relRMSE (half vs half / 2): "
          f"mask {ref_mask:.4f}, whole {ref_whole:.4f}; 'net' columns: sqrt(measured^2 - reference's^2)")
    print(f"# volumetric caustic mask: {int(mask.sum())} pixels ({mask.mean():.2%}); its component is "
          f"{comp[mask].sum() / ref[mask].sum():.0%} of the reference's radiance there")
    print("| seed | renderer | passes / spp | wall s | mask relRMSE | net | whole relRMSE | net | load |")
    print("| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")

    def net(e, floor):
        return float(np.sqrt(max(e * e - floor * floor, 0.0)))
    scene = caustica.load_scene(SCENE)
    for label, method, params in configs:   # warm-up: compile or load the kernels
        caustica.render(scene, method, res=args.res, passes=2, threads=args.threads, **params)
    rows = []
    for seed in seeds:
        got = []
        for label, method, params in configs:
            before = load()
            t0 = time.perf_counter()
            budget = {"passes": args.passes} if args.passes else {"time_s": args.budget}
            r = caustica.render(scene, method, res=args.res, seed=seed, threads=args.threads, **budget, **params)
            wall = time.perf_counter() - t0
            if args.save_images:
                args.save_images.mkdir(parents=True, exist_ok=True)
                np.save(args.save_images / f"{label.replace(' ', '_')}_{seed}.npy", r.image)
            got.append({"seed": seed, "label": label, "passes": r.stats["passes"], "wall_s": wall,
                        "mask": rel_rmse(r.image, ref, mask), "whole": rel_rmse(r.image, ref), "load": before})
        if mi is not None:
            before = load()
            image, wall, spp = mitsuba_equal_time(mi, SCENE, args.res, args.budget, seed)
            if args.save_images:
                np.save(args.save_images / f"mitsuba_{seed}.npy", image)
            got.append({"seed": seed, "label": "Mitsuba 3 volpath (scalar_rgb)", "passes": spp, "wall_s": wall,
                        "mask": rel_rmse(image, ref, mask), "whole": rel_rmse(image, ref), "load": before})
        for row in got:
            row["mask_net"], row["whole_net"] = net(row["mask"], ref_mask), net(row["whole"], ref_whole)
            print(f"| {seed} | {row['label']} | {row['passes']} | {row['wall_s']:.2f} | {row['mask']:.4f} | "
                  f"{row['mask_net']:.4f} | {row['whole']:.4f} | {row['whole_net']:.4f} | {row['load']:.2f} |",
                  flush=True)
        if mi is not None:
            peer = got[-1]
            best = min(got[:-1], key=lambda r: r["mask"])
            print(f"|  | **ratio Mitsuba / best ({best['label']})** |  |  | **{peer['mask'] / best['mask']:.1f}x** | "
                  f"{peer['mask_net'] / max(best['mask_net'], 1e-12):.1f}x | {peer['whole'] / best['whole']:.2f}x | "
                  f"{peer['whole_net'] / max(best['whole_net'], 1e-12):.2f}x |  |", flush=True)
        rows += got
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
