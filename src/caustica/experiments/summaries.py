"""The plain sentences of the experiments' report: what each measured table says, with its seeds' spread."""
from __future__ import annotations

import math

import numpy as np

from .config import ABLATION, ABLATION_PASSES, EQUAL_METRIC, EQUAL_NAME, FLOOR_MAX_BOUNCES
from .statistics import _paired_text, paired
from .tables import _fmt


def _pm(row: dict, key: str, digits: int = 3) -> str:
    """ "0.123 ± 0.004" (mean ± s.d. over seeds) or "0.123" with one seed."""
    v, sd = row.get(key), row.get(key + "_sd")
    if isinstance(sd, float) and math.isfinite(sd):
        return f"{_fmt(v, digits)} ± {_fmt(sd, 2)}"
    return _fmt(v, digits)


def _pct(v: float) -> str:
    return f"{100 * v:+.1f} %" if isinstance(v, float) and math.isfinite(v) else "n/a"


def seed_pair_summary(rows_main: list[dict]) -> str:
    """The caustic block err differences between the paper's configurations, paired over the seeds."""
    by = {r["config"]: r for r in rows_main}
    k = EQUAL_METRIC
    parts = [f"{a} - {b} {_paired_text(by[a], by[b], k)}" for a, b in (("SPM", "PM+C"), ("SPM", "PM"), ("PM", "PM+C"))
             if a in by and b in by and paired(by[a], by[b], k) is not None]
    return f"Paired over the seeds, {EQUAL_NAME}: " + "; ".join(parts) + "." if parts else ""


def floor_summary(pm: dict, floor: dict) -> str:
    """One sentence: what PM's cut at mr diffuse bounces costs against the unlimited-depth reference."""
    if pm.get("mean_err") is None or floor.get("mean_err") is None:
        return ""
    d = paired(floor, pm, "mean_err")
    gain = f" (paired difference {_pct(d[0])} ± {100 * d[1]:.2g} %)" if d else ""
    return (f"Truncation floor: with the paper's mr = 4 PM's image mean is {_pct(pm['mean_err'])} off the "
            f"reference's, with mr = {FLOOR_MAX_BOUNCES} {_pct(floor['mean_err'])}{gain}; block err "
            f"{_pm(pm, 'block_err')} -> {_pm(floor, 'block_err')} (whole image), "
            f"{_pm(pm, 'caustic_block_err')} -> {_pm(floor, 'caustic_block_err')} (caustic region).")


def ablation_summary(rows: list[dict]) -> str:
    """Plain sentences on the merge ablation of one scene (rows in ABLATION's order)."""
    by = {label: r for (label, _m, _p), r in zip(ABLATION, rows)}
    spm, spm_ph, spm0, pm_n, spm_big, pm_big, merge, split = (by[a[0]] for a in ABLATION)
    k = "caustic_block_err"
    return (f"caustic block err (mean ± s.d. over {spm.get('seeds')} seeds): SPM 10,000 x 10 "
            f"{_pm(spm, k)} with eq. 2, {_pm(spm_ph, k)} with the photons estimator "
            f"(paired difference photons - eq. 2: {_paired_text(spm_ph, spm, k)}), {_pm(spm0, k)} with no "
            f"associated photons; PM with 10,000 photons {_pm(pm_n, k)} (SPM eq. 2 - PM 10,000: "
            f"{_paired_text(spm, pm_n, k)}); SPM 100,000 x 10 {_pm(spm_big, k)}, PM 100,000 {_pm(pm_big, k)} "
            f"(difference {_paired_text(spm_big, pm_big, k)}). Without the merge (pspm, {ABLATION_PASSES} passes): "
            f"merge {_pm(merge, k)}, split {_pm(split, k)} (split - merge {_paired_text(split, merge, k)}); "
            f"caustic mean err merge {_pm(merge, 'caustic_mean_err')}, split {_pm(split, 'caustic_mean_err')}; "
            f"whole-image mean err merge {_pm(merge, 'mean_err')}, split {_pm(split, 'mean_err')}.")


def table1_summary(rows: list[dict]) -> str:
    """What each swept parameter changes in the caustic block err, in one or two sentences."""
    def spread(key_fixed):
        groups = {}
        for r in rows:
            v = r.get("caustic_block_err")
            if v is not None and math.isfinite(v):
                groups.setdefault(tuple(r[k] for k in key_fixed), []).append(v)
        worst = [max(g) / min(g) - 1 for g in groups.values() if len(g) > 1 and min(g) > 0]
        return max(worst) if worst else float("nan")
    parts = []
    for name, fixed in (("r_s", ("streams", "assoc")), ("assoc", ("streams", "stream_radius")),
                        ("streams", ("assoc", "stream_radius"))):
        sp = spread(fixed)
        if math.isfinite(sp):
            parts.append(f"{name} changes the caustic block err by up to {100 * sp:.0f} %")
    rel_sd = [r["caustic_block_err_sd"] / r["caustic_block_err"] for r in rows
              if isinstance(r.get("caustic_block_err_sd"), float) and math.isfinite(r["caustic_block_err_sd"])
              and r.get("caustic_block_err")]
    noise = (f" Seed to seed, a configuration's caustic block err varies by {100 * float(np.median(rel_sd)):.0f} % "
             f"(median s.d. / mean over {rows[0].get('seeds')} seeds): differences below that are noise."
             if rel_sd else "")
    return ("At fixed other parameters, " + "; ".join(parts) + "." + noise) if parts else ""


def equal_summary(eq: dict, rows_main: list[dict], eq_pmc: dict | None = None) -> str:
    """Plain sentences: does SPM beat PM+C at equal time and at equal error?"""
    main = {r["config"]: r for r in rows_main}
    spm, pmc = main.get("SPM"), main.get("PM+C")
    if spm is None or pmc is None:
        return ""
    e_spm, t_spm = spm[EQUAL_METRIC], spm["time_s"]
    q = eq.get("PM+C", {})
    x = lambda d, k: " (extrapolated)" if d.get(k) else ""
    lines = []
    e_pmc = q.get("equal_time_error", float("nan"))
    if math.isfinite(e_pmc):
        verdict = "beats" if e_spm < e_pmc else "does not beat"
        lines.append(f"Equal time ({t_spm:.1f} s): SPM's {EQUAL_NAME} is {_fmt(e_spm)}, PM+C's about "
                     f"{_fmt(e_pmc)}{x(q, 'equal_time_extrapolated')}: SPM {verdict} PM+C.")
    else:
        lines.append(f"Equal time ({t_spm:.1f} s): PM+C cannot render in SPM's time "
                     f"({q.get('equal_time_note', 'n/a')}); at its own {pmc['time_s']:.1f} s its {EQUAL_NAME} "
                     f"is {_fmt(pmc[EQUAL_METRIC])} against SPM's {_fmt(e_spm)}.")
    t_pmc = q.get("equal_error_time_s", float("nan"))
    if math.isfinite(t_pmc):
        verdict = "beats" if t_spm < t_pmc else "does not beat"
        lines.append(f"Equal error at SPM's level ({EQUAL_NAME} {_fmt(e_spm)}): SPM {t_spm:.1f} s, "
                     f"PM+C about {t_pmc:.1f} s"
                     f"{x(q, 'equal_error_extrapolated')}: SPM {verdict} PM+C.")
    else:
        lines.append(f"Equal error at SPM's level ({EQUAL_NAME} {_fmt(e_spm)}): "
                     f"PM+C: {q.get('equal_error_note', 'n/a')}.")
    if eq_pmc:
        r = eq_pmc.get("SPM", {})
        t_s = r.get("equal_error_time_s", float("nan"))
        if math.isfinite(t_s):
            verdict = "beats" if t_s < pmc["time_s"] else "does not beat"
            lines.append(f"Equal error at PM+C's level ({EQUAL_NAME} {_fmt(pmc[EQUAL_METRIC])}): "
                         f"PM+C {pmc['time_s']:.1f} s, "
                         f"SPM about {t_s:.1f} s{x(r, 'equal_error_extrapolated')}: SPM {verdict} PM+C.")
        else:
            lines.append(f"Equal error at PM+C's level ({EQUAL_NAME} {_fmt(pmc[EQUAL_METRIC])}): SPM: "
                         f"{r.get('equal_error_note', 'n/a')}: SPM does not beat PM+C.")
    return " ".join(lines)
