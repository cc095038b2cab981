"""``report.md``: one page tying together every experiment's tables and figures found in a folder."""
from __future__ import annotations

import json
from pathlib import Path

from ..imageio import atomic_write

METHOD_NOTES = """\
## How the images are measured

- **Reference**: caustica's `pt` (path tracing, NEE + MIS) at a high sample count, rendered as two
  independent halves (different seeds) and cached; the reference is their mean. Its own noise is
  given with every table: the row *reference noise: half A vs half B* holds the metrics of one half
  against the other, and the line below the title the estimated relative RMSE of the reference
  itself (between-halves relative RMSE / 2). Errors smaller than that noise floor are not resolved.
  A user's EXR can stand in (`--reference`).
- **Caustic region**: the pixels where `pm`'s caustic map (photons shot at the mirror / glass,
  light -> specular+ -> diffuse) is bright: records splatted into the camera with occlusion,
  box-blurred, thresholded at 0.1 x the 99.9th percentile, dilated by one pixel. Its photons have
  random numbers of their own (never PM+C's caustic photons). The mask is saved beside each
  experiment's tables.
- **Seeds**: every measured configuration is rendered with `--seeds` seeds (default 3); each error
  is the mean over them, "± s.d." their standard deviation (a difference well inside it is noise).
- **relMSE**: mean over pixels and channels of (t - r)^2 / (r^2 + 0.01).
- **block err**: relative RMS error of the means of tiles of 1/64 of the image side (8 px at 512):
  sqrt(sum (bt - br)^2 / sum br^2); noise averages out inside a tile, bias and blur stay.
- **mean err**: (sum of the test - sum of the reference) / sum of the reference: energy missing or
  added (the truncation at mr diffuse bounces shows here). Tables 2 and 3 add a row *PM, mr = 64*:
  the paper's PM with many bounces, the floor that the cut at mr = 4 puts under every photon method.
- **SSIM**: scikit-image's `structural_similarity` on the sRGB previews (exposure 0, clamped;
  1 = identical). **FLIP**: NVIDIA's HDR-FLIP (`flip_evaluator`) on the linear images (0 = identical).
  Over the caustic region both are the mean of their per-pixel maps inside the mask.
- **time s**: photon tracing + map build + camera pass (`total_s` of the render minus scene loading
  and JIT compilation), on the machine that ran it; the fastest of the configuration's renders (its
  seeds, and at least `--repeat`).
- **Merge ablation**: SPM 10,000 x 10 under both estimators and without associated photons, against
  PM with 10,000 photons (as many as SPM has streams) and the 100,000-photon settings, on the
  caustic block err (docs/experiments.md says what it shows and what it does not test).
- **Equal error / equal time** (Tables 2 and 3), on the **caustic block err** (the caustic relMSE,
  dominated by a few outlier pixels, is not monotone in the photon budget and cannot be inverted):
  each configuration is also rendered with its photon budget scaled (x0.25 ... x4; streams for SPM,
  photons for PM, both maps for PM+C). Render time is fitted as a + c * budget (least squares: a
  fixed camera pass plus a cost per photon; c = 0 when timing noise makes it negative); the error is
  interpolated piecewise-linearly in log-log against the budget. *Equal error*: the budget at which
  a configuration's error equals SPM's (paper settings), and the fitted time for it; also the time
  SPM needs to reach PM+C's error. *Equal time*: the budget that runs in SPM's time, and the error
  there. Values extrapolated beyond the sweep carry `*`; beyond a factor 2 past its ends they are
  n/a, and the summary says where the extrapolation would put them.
"""

ORDER = ("table1", "table2", "table3", "fig5", "fig6", "fig8", "fig9", "merge-ablation")


def write_report(out: Path) -> Path:
    out = Path(out)
    intro = ("The paper's experiments (Guzek & Napieralski), measured against a converged reference of "
             "the same scene. Each section links its CSV/Markdown tables and PNG figures; "
             "`results.json` in each folder holds every number.\n")
    parts = ["# caustica experiments\n", intro]
    found = []
    for name in ORDER:
        p = out / name / "results.json"
        if not p.is_file():
            continue
        try:
            res = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        found.append(name)
        s = res.get("settings", {})
        parts.append(f"## {res.get('title', name)}\n")
        if res.get("skipped"):
            parts.append(f"**Skipped.** {res['skipped']}\n")
            continue
        seeds = s.get("seeds") or [s.get("seed")]
        seed_text = (f"seeds {seeds[0]}..{seeds[-1]} (errors: mean ± s.d. over {len(seeds)} renders)"
                     if len(seeds) > 1 else f"seed {seeds[0]}")
        parts.append(f"Resolution {s.get('res')}x{s.get('res')}, {seed_text}"
                     f"{', quick mode' if s.get('quick') else ''}"
                     f"{', overrides: ' + json.dumps(s.get('overrides')) if s.get('overrides') else ''}; "
                     f"wall time {res.get('wall_s', 0):.1f} s.\n")
        if s.get("cluster"):
            c = s["cluster"]
            n = c.get("workers")
            parts.append(f"Rendered on a Dask cluster ({c.get('scheduler')}, {n} worker{'' if n == 1 else 's'}): "
                         f"every render one task on one worker, at most one render per worker at a time, on all of "
                         f"its threads; the times are the workers' own.\n")
        if res.get("reference"):
            parts.append(f"{res['reference']}.\n")
        if res.get("summary"):
            parts.append(f"**{res['summary']}**\n")
        for title, md in (res.get("tables") or {}).items():
            parts.append(f"### {title}\n\n{md}")
        links = [f"[{c}]({name}/{c})" for c in res.get("csv", [])]
        if links:
            parts.append("Data: " + ", ".join(links) + "\n")
        for fig in res.get("figures", []):
            parts.append(f"![{fig}]({name}/{fig})\n")
        masks = res.get("mask_images") or ({res["mask_image"]: res.get("mask_pixels", 0)}
                                           if res.get("mask_image") else {})
        for fname, pixels in masks.items():
            parts.append(f"Caustic region ({pixels} pixels): [{fname}]({name}/{fname})\n")
    parts.append(METHOD_NOTES)
    text = "\n".join(parts)
    path = out / "report.md"
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return path
