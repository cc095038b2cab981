#!/usr/bin/env python3
"""Render every corpus scene caustica loads with caustica (pt, or another method) and with Mitsuba 3
(scalar_rgb); compare.

    python scripts/mitsuba_corpus_compare.py out/mitsuba-corpus [--size 64] [--cap 20] [--subset distinct]
                                             [--only SUBSTRING ...] [--markdown out/compare.md]
                                             [--method sppm] [--mitsuba-cache out/mitsuba-cache]

Both renderers render the scene as its file gives it (its sensor, its rfilter; caustica's pt takes the
scene's <integrator> max_depth, rr_depth and hide_emitters, methods.scene_params), at the same small film:
the scene's film scaled to its exact aspect ratio with a longest side near ``--size`` pixels (small_res).
Mitsuba's film is resized after loading through mi.traverse (``film.size``, ``film.crop_size``), so includes
and fixed sizes need no XML editing.

Noise: each side renders K = 4 independent seeds (4 renders are what tests/imagestats.block_se was checked
with).  Per scene the script prints

* the image mean of each side (all channels) and the relative difference of caustica's from Mitsuba's, with
  its standard error from the spread of the 4 seeds' image means on each side;
* the number of 16-pixel (4 x 4) block values (blocks x RGB) whose difference is beyond 5 combined sigmas
  plus 0.2 % of the image mean (exactly the bound of tests/imagestats.assert_images_agree), and the same
  count for 16 x 16-pixel blocks;
* a verdict: ``agree`` (mean within 5 % of Mitsuba's and no 4 x 4 block beyond the bound: the issue's
  criterion; two images black in every pixel agree), ``differs``, ``failed`` (caustica did not render; its
  one-line error) or ``mitsuba-failed``.

spp: each renderer first renders one seed at a few spp (after a warm-up that compiles caustica's kernels),
then takes the largest power of two of spp that keeps its 4 seeds under ``--cap`` seconds (between 4 and
``--max-spp``).  One render at a time, 2 threads each.  With ``--method sppm`` or ``pspm`` the unit is
passes (each method's defaults otherwise); ``pm`` and ``spm`` scale their camera samples (spp) over one
photon map of their default size.  The photon methods are consistent, not unbiased: at a given budget their
radius blurs the image, which the block test sees where light changes fast.

``--mitsuba-cache DIR`` keeps Mitsuba's renders (per scene, film size, cap and spp limit) so comparing
several methods renders Mitsuba once.
"""
from __future__ import annotations

import argparse
import datetime
import importlib.util
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))
from imagestats import N_SIGMA, block_means, block_se  # noqa: E402  (the tests' statistics, reused)

from caustica.experiments.config import method_setting  # noqa: E402  (--set KEY=VALUE)

SEEDS = (1, 2, 3, 4)
PILOT_SPP = 4

#: With --subset distinct: scenes left out as near-duplicates of one kept (same geometry, lights and
#: materials up to the sampler, the colour variant or polarisation, which pt and scalar_rgb do not see).
DUPLICATES = {
    "docs/scenes/sampler_independent_25spp.xml": "docs/scenes/sampler_independent_16spp.xml",
    "docs/scenes/sampler_ldsampler_16spp.xml": "docs/scenes/sampler_independent_16spp.xml",
    "docs/scenes/sampler_multijitter_16spp.xml": "docs/scenes/sampler_independent_16spp.xml",
    "docs/scenes/sampler_orthogonal_25spp.xml": "docs/scenes/sampler_independent_16spp.xml",
    "docs/scenes/sampler_stratified_16spp.xml": "docs/scenes/sampler_independent_16spp.xml",
    "docs/scenes/variants_cbox_spectral.xml": "docs/scenes/variants_cbox_rgb.xml",
    "scenes/cbox/cbox-spectral.xml": "scenes/cbox/cbox-rgb.xml",
}


def report_module():
    spec = importlib.util.spec_from_file_location("mitsuba_corpus_report", REPO / "scripts" / "mitsuba_corpus_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def small_res(width: int, height: int, size: int) -> tuple[int, int]:
    """The film's exact aspect ratio at a longest side as near ``size`` as it allows (within 1.5x), else the
    longest side ``size`` and the other rounded.  The aspect must not change: Mitsuba keeps its x_fov when
    its film is resized, while caustica applies fov_axis to the new film (a scene with fov_axis="smaller"
    was framed a pixel apart when 768 x 512 became 64 x 44)."""
    g = math.gcd(width, height)
    a, b = width // g, height // g
    k = max(1, round(size / max(a, b)))
    if max(a, b) * k <= 1.5 * size and min(a, b) * k >= 8:
        return a * k, b * k
    s = size / max(width, height)
    return max(4, round(width * s)), max(4, round(height * s))


def pow2_spp(seconds_per_spp: float, cap: float, max_spp: int) -> int:
    budget = cap / (len(SEEDS) * max(seconds_per_spp, 1e-9))
    return int(min(max_spp, max(4, 2 ** math.floor(math.log2(max(budget, 1.0))))))


def one_line(exc: BaseException) -> str:
    text = str(exc).strip().split("\n")
    return f"{type(exc).__name__}: {text[0] if len(text) == 1 else text[0] + ' ' + text[1].strip()}"[:200]


#: What each method's budget counts: pt's samples per pixel, the progressive photon methods' passes, or the
#: camera samples of a one-map photon method.
BUDGET = {"pt": "spp", "sppm": "passes", "pspm": "passes", "pm": "spp", "spm": "spp"}


def render_caustica(scene, method, res, cap, max_spp, settings):
    import caustica
    unit = BUDGET[method]
    # the first render compiles the kernels this scene's kinds of BSDF, light and medium need (seconds for a
    # photon method); the pilot that sets the budget is the faster of the next two (a first pilot at the full size
    # may still compile: sppm on three scenes of NVlabs/sionna and others got the floor of 4 passes for 10 s)
    caustica.render(scene, method, res=(8, 8), seed=98, threads=2, **settings, **{unit: 1})
    per_spp = math.inf
    for _ in range(2):
        t0 = time.perf_counter()
        caustica.render(scene, method, res=res, seed=99, threads=2, **settings, **{unit: PILOT_SPP})
        per_spp = min(per_spp, (time.perf_counter() - t0) / PILOT_SPP)
    spp = pow2_spp(per_spp, cap, max_spp)
    t0 = time.perf_counter()
    runs = [caustica.render(scene, method, res=res, seed=s, threads=2, **settings, **{unit: spp}) for s in SEEDS]
    return [r.image.astype(np.float64) for r in runs], spp, time.perf_counter() - t0, runs[0].stats


DEFAULT = re.compile(r"""<default\s+name\s*=\s*["']([^"']+)["']\s+value\s*=\s*["']([^"']*)["']""")


def file_defaults(path: Path, seen=None) -> dict:
    """The <default>s of a scene file and of the files it includes, wherever they stand."""
    seen = set() if seen is None else seen
    if path.resolve() in seen or not path.is_file():
        return {}
    seen.add(path.resolve())
    text = path.read_text(errors="replace")
    out = {}
    for name in re.findall(r"""<include\s[^>]*filename\s*=\s*["']([^"']+)["']""", text):
        out.update(file_defaults(path.parent / name, seen))
    out.update(DEFAULT.findall(text))
    return out


def mitsuba_scene(mi, path, res, notes):
    try:
        scene = mi.load_file(str(path))
    except RuntimeError as exc:
        # Mitsuba 3 reads a <default> only if it comes before its use; caustica takes the file's <default>s
        # wherever they stand (docs/scenes/sensor_*.xml use $spp before the include that defines it).
        if "undefined parameter" not in str(exc):
            raise
        defaults = file_defaults(path)
        scene = mi.load_file(str(path), **defaults)
        notes.append("Mitsuba was given the file's own <default>s (" + ", ".join(
            f"{k}={v}" for k, v in defaults.items()) + "): it reads a <default> only before its use")
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.endswith("film.size")]
    if len(keys) != 1:
        raise RuntimeError(f"{len(keys)} films found in the Mitsuba scene")
    base = keys[0][: -len("size")]
    params[base + "size"] = list(res)
    params[base + "crop_size"] = list(res)
    params[base + "crop_offset"] = [0, 0]
    params.update()
    size = list(scene.sensors()[0].film().crop_size())
    if size != list(res):
        raise RuntimeError(f"Mitsuba's film is {size} after resizing to {list(res)}")
    return scene


def render_mitsuba(mi, path, res, cap, max_spp, notes):
    scene = mitsuba_scene(mi, path, res, notes)
    integrator = scene.integrator()
    if integrator is None:   # Mitsuba's render() needs one; caustica renders such a scene with pt
        integrator = mi.load_dict({"type": "path"})
        notes.append("the scene has no <integrator>: Mitsuba was given its path tracer, as caustica uses pt")
    t0 = time.perf_counter()
    mi.render(scene, integrator=integrator, spp=PILOT_SPP, seed=99)
    per_spp = (time.perf_counter() - t0) / PILOT_SPP
    spp = pow2_spp(per_spp, cap, max_spp)
    t0 = time.perf_counter()
    images = [np.array(mi.render(scene, integrator=integrator, spp=spp, seed=s), dtype=np.float64)
              for s in SEEDS]
    return [as_linear_srgb(scene, image) for image in images], spp, time.perf_counter() - t0


#: Mitsuba's CIE XYZ to linear sRGB (``xyz_to_srgb`` in its color.h), to compare a film of pixel_format xyz, which
#: caustica renders as linear sRGB (with a note).
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535], [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


def as_linear_srgb(scene, image):
    """Mitsuba's developed film as caustica's image: its first three channels, from XYZ where the film writes XYZ; a
    luminance film (Mitsuba prints its format as y or ya) cannot be compared channel by channel (an error)."""
    fmt = re.search(r"pixel_format = (\w+)", str(scene.sensors()[0].film()))
    fmt = fmt.group(1).lower() if fmt else "rgb"
    if fmt.startswith("xyz"):
        return image[..., :3] @ XYZ_TO_SRGB.T
    if fmt in ("y", "ya") or fmt.startswith("luminance") or image.shape[-1] < 3:
        raise RuntimeError(f"Mitsuba's film writes {fmt}: not compared with caustica's RGB")
    return image[..., :3]


def cached_mitsuba(cache, rel, res, cap, max_spp, render):
    """Mitsuba's (images, spp, seconds) for this scene and budget, from ``cache`` (a folder) or ``render()``."""
    if cache is None:
        return render()
    # "srgb": the images as caustica's linear sRGB (as_linear_srgb); a cache of before it may hold an XYZ film's
    key = cache / f"{rel.replace('/', '__')[:-4]}__{res[0]}x{res[1]}__cap{cap:g}__max{max_spp}__srgb.npz"
    if key.is_file():
        with np.load(key) as z:
            return list(z["images"]), int(z["spp"]), float(z["seconds"])
    images, spp, seconds = render()
    cache.mkdir(parents=True, exist_ok=True)
    tmp = key.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, images=np.stack(images), spp=spp, seconds=seconds)
    tmp.replace(key)
    return images, spp, seconds


def blocks_beyond(a_images, b_images, b: int) -> tuple[int, int, str]:
    """Block values (blocks x channels) of b x b pixels beyond imagestats' bound; their count; the worst."""
    h, w = a_images[0].shape[:2]
    h, w = h - h % b, w - w % b
    a_images = [x[:h, :w] for x in a_images]
    b_images = [x[:h, :w] for x in b_images]
    a = np.mean(a_images, axis=0)
    m = np.mean(b_images, axis=0)
    se = np.sqrt(block_se(a_images, b) ** 2 + block_se(b_images, b) ** 2)
    tol = N_SIGMA * se + 0.002 * m.mean()
    ba, bb = block_means(a, b), block_means(m, b)
    z = np.abs(ba - bb) / np.where(tol > 0, tol, 1e-30)
    worst = np.unravel_index(np.argmax(z), z.shape)
    where = (f"block (row {worst[0]}, col {worst[1]}) ch {worst[2]}: {ba[worst]:.4g} vs {bb[worst]:.4g}, "
             f"{np.abs(ba - bb)[worst] / max(se[worst], 1e-30):.1f} sigma")
    return int(np.sum(z > 1)), z.size, where


def compare(ours, theirs):
    ma = np.array([x.mean() for x in ours])
    mb = np.array([x.mean() for x in theirs])
    a, b = ma.mean(), mb.mean()
    se_a, se_b = ma.std(ddof=1) / math.sqrt(len(ma)), mb.std(ddof=1) / math.sqrt(len(mb))
    if b != 0:
        rel, se_rel = a / b - 1, math.sqrt(se_a ** 2 + (a / b) ** 2 * se_b ** 2) / abs(b)
    elif not any(x.any() for x in ours + theirs):   # both black in every pixel: nothing differs
        rel, se_rel = 0.0, 0.0
    else:
        rel, se_rel = float("inf"), float("inf")
    out4, n4, worst = blocks_beyond(ours, theirs, 4)
    out16, n16, _ = blocks_beyond(ours, theirs, 16) if min(ours[0].shape[:2]) >= 16 else (0, 0, "")
    ch_a = np.mean(ours, axis=(0, 1, 2))
    ch_b = np.mean(theirs, axis=(0, 1, 2))
    verdict = "agree" if abs(rel) <= 0.05 and out4 == 0 else "differs"
    return dict(mean_c=a, mean_m=b, rel=rel, se_rel=se_rel, out4=out4, n4=n4, out16=out16, n16=n16,
                worst=worst, rgb_c=ch_a, rgb_m=ch_b, verdict=verdict)


def caustica_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout.strip()
    except Exception:
        return "?"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--size", type=int, default=64, help="longest side of both films, pixels (default 64)")
    ap.add_argument("--cap", type=float, default=20.0, help="seconds per renderer per scene for its 4 seeds "
                    "(chooses spp; default 20)")
    ap.add_argument("--max-spp", type=int, default=1024)
    ap.add_argument("--subset", choices=("all", "distinct"), default="all",
                    help="distinct: leave out the near-duplicates listed in DUPLICATES")
    ap.add_argument("--only", nargs="*", default=None, help="only scenes whose path contains one of these")
    ap.add_argument("--markdown", type=Path)
    ap.add_argument("--save", type=Path, help="save each scene's mean images here (.npz) for inspection")
    ap.add_argument("--method", choices=sorted(BUDGET), default="pt", help="caustica's method (default pt)")
    ap.add_argument("--mitsuba-cache", type=Path, help="keep Mitsuba's renders in this folder and reuse them")
    ap.add_argument("--set", type=method_setting, action="append", default=[], metavar="KEY=VALUE",
                    help="a setting of caustica's method, repeatable (e.g. --set termination=roulette "
                         "--set max_bounces=1024)")
    args = ap.parse_args(argv)
    settings = dict(args.set)

    import drjit as dr
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    mi.set_log_level(mi.LogLevel.Error)
    dr.set_thread_count(2)
    import caustica
    from caustica.errors import CausticaError

    scenes = report_module().find_scenes(args.corpus)
    rows = []
    counts = {"scenes": len(scenes), "load": 0, "rendered": 0, "agree": 0, "differs": 0, "failed": 0,
              "mitsuba-failed": 0, "skipped": 0}
    warmed = False
    for path in scenes:
        rel = str(path.relative_to(args.corpus))
        short = rel.split("/", 1)[1] if "/" in rel else rel
        if args.only and not any(s in rel for s in args.only):
            continue
        try:
            scene = caustica.load_scene(path)
        except CausticaError:
            continue
        counts["load"] += 1
        if args.subset == "distinct" and short in DUPLICATES:
            counts["skipped"] += 1
            print(f"skipped  {rel} (near-duplicate of {DUPLICATES[short]})", flush=True)
            continue
        res = small_res(scene.width, scene.height, args.size)
        row = dict(scene=rel, res=f"{res[0]}x{res[1]}")
        if not warmed:   # compile the method's kernels once, outside every scene's timing
            try:
                caustica.render(scene, args.method, res=(8, 8), seed=0, threads=2, **settings,
                                **{BUDGET[args.method]: 1})
            except Exception:
                pass
            warmed = True
        try:
            ours, row["spp_c"], row["t_c"], info = render_caustica(scene, args.method, res, args.cap,
                                                                        args.max_spp, settings)
            row["note"] = "; ".join(n for n in (info.get("integrator_note"), info.get("media_note"),
                                                *info.get("scene_notes", ())) if n)
            if res[0] * scene.height != res[1] * scene.width:
                row["note"] = (row["note"] + f"; aspect ratio changed from {scene.width}x{scene.height}").strip("; ")
        except Exception as exc:
            row.update(verdict="failed", error=one_line(exc))
            counts["failed"] += 1
            rows.append(row)
            print(f"failed   {rel}: {row['error']}", flush=True)
            continue
        counts["rendered"] += 1
        try:
            notes = [row["note"]] if row["note"] else []
            theirs, row["spp_m"], row["t_m"] = cached_mitsuba(
                args.mitsuba_cache, rel, res, args.cap, args.max_spp,
                lambda: render_mitsuba(mi, path, res, args.cap, args.max_spp, notes))
            row["note"] = "; ".join(notes)
        except Exception as exc:
            row.update(verdict="mitsuba-failed", error=one_line(exc))
            counts["mitsuba-failed"] += 1
            rows.append(row)
            print(f"mitsuba-failed {rel}: {row['error']}", flush=True)
            continue
        if not all(np.isfinite(x).all() for x in ours + theirs):
            row["note"] = (row["note"] + "; non-finite pixels").strip("; ")
            ours = [np.nan_to_num(x) for x in ours]
            theirs = [np.nan_to_num(x) for x in theirs]
        row.update(compare(ours, theirs))
        counts[row["verdict"]] += 1
        rows.append(row)
        if args.save:
            args.save.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(args.save / (short.replace("/", "__")[:-4] + ".npz"),
                                caustica=np.mean(ours, axis=0), mitsuba=np.mean(theirs, axis=0),
                                caustica_seeds=np.stack(ours), mitsuba_seeds=np.stack(theirs))
        print(f"{row['verdict']:8} {rel} {row['res']}: caustica {row['spp_c']} {BUDGET[args.method]} x4 "
              f"{row['t_c']:.1f} s, "
              f"Mitsuba {row['spp_m']} spp x4 {row['t_m']:.1f} s; mean {row['mean_c']:.4g} vs {row['mean_m']:.4g} "
              f"({100 * row['rel']:+.1f} % +- {100 * row['se_rel']:.1f}); 4x4 blocks out {row['out4']}/{row['n4']}, "
              f"16x16 out {row['out16']}/{row['n16']}; worst {row['worst']}"
              + (f"; note: {row['note']}" if row["note"] else ""), flush=True)

    head = (f"date {datetime.date.today().isoformat()}; caustica {caustica_commit()} --method {args.method} "
            + "".join(f"--set {k}={v} " for k, v in settings.items())
            + f"({BUDGET[args.method]} below); Mitsuba {mi.__version__} "
            f"scalar_rgb; size {args.size}; cap {args.cap:g} s; subset {args.subset}")
    summary = (f"{counts['scenes']} scenes: {counts['load']} load, {counts['skipped']} skipped as near-duplicates, "
               f"{counts['rendered']} rendered by caustica ({counts['failed']} failed), "
               f"{counts['mitsuba-failed']} not rendered by Mitsuba; {counts['agree']} agree, "
               f"{counts['differs']} differ")
    print()
    print(head)
    print(summary)
    if args.markdown:
        md = [head, "", summary, "",
              f"| scene | res | caustica {BUDGET[args.method]} x4, s | Mitsuba spp x4, s | mean caustica | mean Mitsuba | rel. diff (SE) "
              "| 4x4 blocks out | 16x16 blocks out | verdict |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for r in rows:
            if "mean_c" in r:
                md.append(f"| {r['scene']} | {r['res']} | {r['spp_c']}, {r['t_c']:.1f} | {r['spp_m']}, {r['t_m']:.1f} "
                          f"| {r['mean_c']:.4g} | {r['mean_m']:.4g} | {100 * r['rel']:+.1f} % ({100 * r['se_rel']:.1f}) "
                          f"| {r['out4']}/{r['n4']} | {r['out16']}/{r['n16']} | {r['verdict']} |")
            else:
                md.append(f"| {r['scene']} | {r['res']} | | | | | | | | {r['verdict']}: "
                          f"{r['error'].replace('|', '/')} |")
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text("\n".join(md) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
