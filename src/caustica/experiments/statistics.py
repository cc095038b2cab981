"""Statistics over the experiments' renders: means and spreads over seeds, paired differences, and the
equal-time / equal-error comparison fitted over a budget sweep."""
from __future__ import annotations

import math

import numpy as np

from .config import EQUAL_METRIC, MAX_EXTRAPOLATION
from .tables import _fmt


def seed_statistics(per_seed: list[dict]) -> dict:
    """Mean of every metric over the seeds' renders, its sample standard deviation as ``<metric>_sd``
    and the values themselves as ``<metric>_per_seed`` (results.json; for paired comparisons)."""
    out = {}
    for k in per_seed[0]:
        v = np.array([m[k] for m in per_seed], dtype=np.float64)
        out[k] = float(v.mean())
        out[k + "_sd"] = float(v.std(ddof=1)) if len(v) > 1 else float("nan")
        out[k + "_per_seed"] = [float(x) for x in v]
    return out


def paired(a: dict, b: dict, key: str):
    """(mean of a - b, its standard error, z) over the seeds both rows share, or None below two seeds.

    Rows rendered with the same seeds share the camera pass's random numbers (pixel jitter,
    direct light), so the per-seed difference cancels that common noise: a paired comparison
    sees differences that the two rows' own spreads would hide.
    """
    va, vb = a.get(key + "_per_seed"), b.get(key + "_per_seed")
    if not va or not vb or len(va) != len(vb) or len(va) < 2:
        return None
    d = np.asarray(va) - np.asarray(vb)
    if not np.all(np.isfinite(d)):
        return None
    se = float(d.std(ddof=1) / math.sqrt(len(d)))
    mean = float(d.mean())
    z = mean / se if se > 0 else (0.0 if mean == 0 else math.copysign(math.inf, mean))
    return mean, se, z


def _paired_text(a: dict, b: dict, key: str) -> str:
    p = paired(a, b, key)
    if p is None:
        return "n/a"
    mean, se, z = p
    return f"{mean:+.3g} ± {se:.2g} (z = {z:+.1f})"


def _interp_loglog(x, y, x0):
    """Piecewise-linear interpolation of log y against log x at x0; (value, extrapolated)."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    l0 = math.log(x0)
    if l0 < lx[0] or l0 > lx[-1]:
        i = 0 if l0 < lx[0] else len(lx) - 2
        slope = (ly[i + 1] - ly[i]) / (lx[i + 1] - lx[i])
        return float(math.exp(ly[i] + slope * (l0 - lx[i]))), True
    return float(math.exp(np.interp(l0, lx, ly))), False


def equal_comparison(sweep: dict, anchor: str) -> dict:
    """Equal-error time and equal-time error of every configuration against ``anchor``'s 1x budget.

    Per configuration: time(budget) is fitted as a + c * budget (least squares: a fixed
    camera pass plus a cost per photon), error(budget) interpolated piecewise-linearly
    on log-log over the sweep (extrapolated from the end segment outside it).
    Equal error: the budget b* where error = anchor's error, time = a + c b*.
    Equal time: the budget b with a + c b = anchor's time, error = error(b).
    """
    base = {r["budget_factor"]: r for r in sweep[anchor]}[1.0]
    target_err, target_t = base[EQUAL_METRIC], base["time_s"]
    out = {}
    for label, rows in sweep.items():
        rows = sorted(rows, key=lambda r: r["budget_factor"])
        b = np.array([r["budget_factor"] for r in rows])
        t = np.array([r["time_s"] for r in rows])
        e = np.array([r[EQUAL_METRIC] for r in rows])
        c, a = np.polyfit(b, t, 1) if len(b) > 1 else (0.0, t[0])
        if c < 0:   # timing noise larger than the photon cost: time does not grow with the budget
            c, a = 0.0, float(np.mean(t))
        res = {"time_fit_fixed_s": float(a), "time_fit_per_budget_s": float(c)}
        if label == anchor:
            res.update(equal_error_time_s=float(target_t), equal_error_extrapolated=False,
                       equal_time_error=float(target_err), equal_time_extrapolated=False)
        ok = np.isfinite(e) & (e > 0)
        if label != anchor and ok.sum() >= 2 and math.isfinite(target_err) and target_err > 0:
            # equal error: invert error(budget); error is interpolated on log-log
            bb, ee = b[ok], e[ok]
            found = None
            for i in range(len(bb) - 1):
                lo, hi = sorted((ee[i], ee[i + 1]))
                if lo <= target_err <= hi and ee[i] != ee[i + 1]:
                    found = (_interp_loglog(ee[i:i + 2][::-1] if ee[i] > ee[i + 1] else ee[i:i + 2],
                                            bb[i:i + 2][::-1] if ee[i] > ee[i + 1] else bb[i:i + 2],
                                            target_err)[0], False)
                    break
            if found is None:
                # outside the sweep: extrapolate along the end segment nearer the target, if it falls
                i = 0 if target_err > ee.max() else len(bb) - 2
                slope = (math.log(ee[i + 1]) - math.log(ee[i])) / (math.log(bb[i + 1]) - math.log(bb[i]))
                if slope < -1e-6:
                    lb = math.log(bb[i]) + (math.log(target_err) - math.log(ee[i])) / slope
                    found = (math.exp(lb), True)
            if found is not None and found[0] > 0 and found[1] and not (
                    bb[0] / MAX_EXTRAPOLATION <= found[0] <= bb[-1] * MAX_EXTRAPOLATION):
                res["equal_error_time_s"] = float("nan")
                res["equal_error_extrapolated"] = True
                res["equal_error_budget"] = found[0]
                res["equal_error_note"] = (
                    f"its error is {'below' if found[0] < bb[0] else 'above'} the target at every budget of the "
                    f"sweep (x{bb[0]:g} .. x{bb[-1]:g}); log-log extrapolation puts it at x{found[0]:.3g}, too far "
                    "to trust")
            elif found is not None and found[0] > 0:
                res["equal_error_budget"] = found[0]
                res["equal_error_time_s"] = float(a + c * found[0])
                res["equal_error_extrapolated"] = found[1]
            else:
                res["equal_error_time_s"] = float("nan")
                res["equal_error_extrapolated"] = True
                res["equal_error_note"] = "not reached: its error does not fall towards the target"
            # equal time
            if c > 0 and target_t > a:
                b_t = (target_t - a) / c
                val, extra = _interp_loglog(bb, ee, b_t)
                res["equal_time_budget"] = b_t
                res["equal_time_error"] = val
                res["equal_time_extrapolated"] = extra
            elif c == 0 and target_t >= a:
                res["equal_time_budget"] = float(bb[-1])
                res["equal_time_error"] = float(ee[-1])
                res["equal_time_extrapolated"] = True
                res["equal_time_note"] = "its time does not measurably grow with the budget: the error " \
                                         "at the largest budget of the sweep"
            else:
                res["equal_time_error"] = float("nan")
                res["equal_time_extrapolated"] = True
                res["equal_time_note"] = "its fixed cost alone exceeds the target time"
        for key, flag in (("equal_error_time_s", "equal_error_extrapolated"),
                          ("equal_time_error", "equal_time_extrapolated")):
            v = res.get(key)
            if v is None:
                res[key + "_text"] = "n/a"
            else:
                res[key + "_text"] = _fmt(v) + ("*" if res.get(flag) and math.isfinite(v) else "")
        out[label] = res
    return out
