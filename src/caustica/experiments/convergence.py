"""``caustica experiment convergence``: error against wall time, every method given the same budgets.

For each caustic scene (cornell-diacaustic, cornell-catacaustic) at 256 x 256 and each
budget (5, 10, 30, 90 s): ``pt``, ``sppm`` and the ``pspm`` variants render with
``--time BUDGET``; PM with a caustic map renders at several photon counts (one shot:
its time is what it takes); and, when the ``mitsuba`` package is installed, Mitsuba 3's
own path tracer (``scalar_rgb``) renders passes of a few samples per pixel until the
next pass would cross the same budget — the peer anyone can install, timed in the same
process on the same machine, so the ratios travel between machines.

Every image is measured against the reference (Mitsuba's converged renders in
``shared/refs`` when present, else caustica's cached ``pt`` reference) over the whole
image and over the caustic mask: relative RMSE (sqrt(Σ (t - r)² / Σ r²), the goal's
measure), the block-mean error and FLIP (:mod:`caustica.experiments.metrics`).
Each configuration (and Mitsuba) renders once untimed before its first timed render,
so start-up costs (compiling, caches) are not counted.  Every timed render runs alone,
one at a time; Mitsuba uses every core (its default), caustica ``--threads`` (default:
every core).  On a Dask cluster (``--dask``, ``--workers``) every point, Mitsuba's too, is
one task on one worker, alone on it and on all of its threads (:mod:`.dask_renders`), and
each configuration warms up once on every worker that renders it.  One seed per point,
and the summary picks the best of caustica's configurations at each budget: the
seed-to-seed spread is measured separately.
"""
from __future__ import annotations

import math

import os
from pathlib import Path

import numpy as np

from ..imageio import atomic_write
from . import metrics as M
from .mitsuba import mitsuba_equal_time, mitsuba_module  # noqa: F401 (the peer, as the benchmarks import it)

SCENES = ("cornell-diacaustic", "cornell-catacaustic")
BUDGETS_S = (5.0, 10.0, 30.0, 90.0)
QUICK_BUDGETS_S = (0.5, 1.5)
RES = 256
#: Progressive configurations: (label, method, parameters).
PROGRESSIVE = (
    ("pt", "pt", {}),
    ("SPPM", "sppm", {}),   # in these scenes: half of the pass's photons aimed (separate caustic statistics)
    ("SPPM plain", "sppm", {"caustic_photons": 0}),
    ("SPPM 20k + 20k caustic", "sppm", {"photons": 20_000, "caustic_photons": 20_000}),
    ("PSPM merge", "pspm", {}),
    ("PSPM split r_s=1", "pspm", {"specular": "split", "stream_radius": 1.0}),
    ("PSPM merge + 32k caustic", "pspm", {"caustic_photons": 32_768}),
)
#: PM + caustic map at these photon counts (global = caustic), one shot each.
PMC_PHOTONS = (25_000, 100_000, 400_000)
QUICK_PMC_PHOTONS = (5_000,)
MITSUBA_LABEL = "Mitsuba 3 path (scalar_rgb)"


def rel_rmse(test, ref, mask=None) -> float:
    """sqrt(Σ (t - r)² / Σ r²) over the pixels (and channels) in ``mask``: the norm-relative RMSE."""
    t = np.asarray(test, np.float64)
    r = np.asarray(ref, np.float64)
    if mask is not None:
        t, r = t[mask], r[mask]
    den = float(np.sum(r * r))
    return float(np.sqrt(np.sum((t - r) ** 2) / den)) if den > 0 else float("nan")


def measure(image, ref, mask) -> dict:
    out = {"rel_rmse": rel_rmse(image, ref), "caustic_rel_rmse": rel_rmse(image, ref, mask)}
    for key, value in M.all_metrics(image, ref, mask).items():
        if key.endswith(("block_err", "flip")):
            out[key] = value
    return out


def reference_floor(ref, mask) -> dict:
    """The reference's own relative RMSE in this module's measure, when it is made of two halves.

    The mean of two independent halves has half their difference's error:
    rel_rmse(a, b) / 2.  A reference without halves (Mitsuba's in shared/refs: their JSON's
    noise figure is a per-pixel relative error, another measure) gets None: no floor is drawn.
    """
    if ref.half_a is None or ref.half_b is None:
        return {"rel_rmse": None, "caustic_rel_rmse": None}
    return {"rel_rmse": rel_rmse(ref.half_a, ref.half_b) / 2,
            "caustic_rel_rmse": rel_rmse(ref.half_a, ref.half_b, mask) / 2}


def peer_floor(ref, peer_rows) -> dict:
    """The reference's own relative RMSE estimated from Mitsuba's equal-time renders.

    Only for a reference rendered by Mitsuba's path tracer with a known sample count N_ref
    (``shared/refs``): the peer renders are the same estimator with N_b samples, independent of
    the reference's (mitsuba.MITSUBA_SEED_BASE), so their expected relative MSE against the reference is
    v / N_b + v / N_ref, with v the estimator's per-sample relative variance.  Each budget gives
    v_b = relMSE_b / (1 / N_b + 1 / N_ref); they are pooled weighted by N_b, since a path
    tracer's caustic is heavy-tailed and few samples tend to underestimate v; the reference's
    relRMSE is then sqrt(v / N_ref).  The budgets' renders are nested (each starts from the
    same seeds), so they are not independent checks of one another, and E of a ratio is taken
    as a ratio of expectations: an estimate, not a bound.  Every error measured against this reference
    contains it in quadrature.  None when this does not apply.
    """
    none = {"rel_rmse": None, "caustic_rel_rmse": None}
    if not ref.spp or not ref.renderer.lower().startswith("mitsuba") or not peer_rows:
        return none
    out = {}
    weight = sum(r["passes"] for r in peer_rows)
    for key in ("rel_rmse", "caustic_rel_rmse"):
        v = sum(r["passes"] * r[key] ** 2 / (1.0 / r["passes"] + 1.0 / ref.spp) for r in peer_rows) / weight
        out[key] = math.sqrt(v / ref.spp)
    return out


def shared_refs_dir() -> Path | None:
    """``$CAUSTICA_SHARED/refs``, else ``shared/refs`` beside this checkout (None when neither exists)."""
    env = os.environ.get("CAUSTICA_SHARED")
    cand = Path(env) / "refs" if env else Path(__file__).resolve().parents[4] / "shared" / "refs"
    return cand if cand.is_dir() else None


class Convergence:
    """The experiment over a runner (which supplies scenes, references and masks)."""

    def __init__(self, runner):
        self.runner = runner
        self.cfg = runner.cfg
        self.budgets = QUICK_BUDGETS_S if self.cfg.quick else BUDGETS_S
        self.pmc = QUICK_PMC_PHOTONS if self.cfg.quick else PMC_PHOTONS
        self.pending = None      # what submit() sent on its way, by point

    def count(self) -> int:
        mi = 1 if self.runner.renders.has_mitsuba() else 0
        return len(SCENES) * (len(self.budgets) * (len(PROGRESSIVE) + mi) + len(self.pmc))

    def _tick(self):
        if self.runner.bar is not None:
            self.runner.bar.update(1)

    def _submit(self, scene, method, **kw):
        """A point's render on its way; every configuration renders once untimed first (on each process
        that renders it): its kernels compile (or load) there, not in the timed render."""
        untimed = {k: v for k, v in kw.items() if k != "time_s"}
        warm = ((method, tuple(sorted(untimed.items()))), self.cfg.seed)
        res = self.cfg.res
        return self.runner.renders.submit(scene, method, warm=warm, res=(res, res), seed=self.cfg.seed, **kw)

    def submit(self) -> None:
        """Send every point's render on its way (once), Mitsuba's included; :meth:`run` collects them.

        Each timed render is one task on one worker, alone there (:mod:`.dask_renders`).
        """
        if self.pending is not None:
            return
        self.pending = {}
        mitsuba = self.runner.renders.has_mitsuba()
        for name in SCENES:
            scene = self.runner.scene(name)
            for label, method, params in PROGRESSIVE:
                for budget in self.budgets:
                    self.pending[name, label, budget] = self._submit(scene, method, time_s=budget, **params)
            for n in self.pmc:
                self.pending[name, "pm", n] = self._submit(scene, "pm", photons=n, caustic_photons=n)
            if mitsuba:
                for budget in self.budgets:
                    self.pending[name, MITSUBA_LABEL, budget] = self.runner.renders.submit_mitsuba(
                        name, self.cfg.res, budget, self.cfg.seed)

    def plan(self) -> list:
        """(label, scene, method, params) of every caustica render :meth:`run` makes (params with ``time_s``)."""
        return [(label, name, method, dict(params, time_s=budget))
                for name in SCENES for label, method, params in PROGRESSIVE for budget in self.budgets] + [
            (f"PM+C {n:,} + {n:,}", name, "pm", {"photons": n, "caustic_photons": n})
            for name in SCENES for n in self.pmc]

    def run(self, folder: Path) -> dict:
        from .figures import convergence_plot
        res = self.cfg.res
        rows = []
        self.submit()
        pending = self.pending
        for name in SCENES:
            ref = self.runner.reference(name)
            mask = self.runner.mask(name)
            for label, method, params in PROGRESSIVE:
                for budget in self.budgets:
                    result, wall = pending.pop((name, label, budget)).result()
                    st = result.stats
                    rows.append({"scene": name, "label": label, "method": method, "budget_s": budget,
                                 "time_s": wall, "passes": st.get("passes"), **measure(result.image, ref.image,
                                                                                       mask)})
                    self._save(folder, name, label, budget, result)
                    self._tick()
            for n in self.pmc:
                result, wall = pending.pop((name, "pm", n)).result()
                rows.append({"scene": name, "label": f"PM+C {n:,} + {n:,}", "method": "pm", "budget_s": None,
                             "time_s": wall, "passes": 1, **measure(result.image, ref.image, mask)})
                self._save(folder, name, f"PMC_{n}", None, result)
                self._tick()
            for budget in self.budgets:
                if (name, MITSUBA_LABEL, budget) in pending:
                    image, wall, spp = pending.pop((name, MITSUBA_LABEL, budget)).result()
                    rows.append({"scene": name, "label": MITSUBA_LABEL, "method": "mitsuba", "budget_s": budget,
                                 "time_s": wall, "passes": spp, **measure(image, ref.image, mask)})
                    self._tick()
            floor = reference_floor(ref, mask)
            label = "reference's own noise"
            if floor["rel_rmse"] is None:
                floor = peer_floor(ref, [r for r in rows if r["scene"] == name and r["method"] == "mitsuba"])
                label = "reference's own noise (est. from the Mitsuba renders' 1/N)"
            rows.append({"scene": name, "label": label, "method": "reference", "budget_s": None,
                         "time_s": None, "passes": ref.spp, **floor})
        tables, figures = {}, []
        from .tables import markdown_table, write_csv
        cols = ("label", "budget_s", "time_s", "passes", "caustic_rel_rmse", "rel_rmse", "caustic_block_err",
                "block_err", "caustic_flip", "flip")
        headers = {"label": "method", "budget_s": "budget s", "time_s": "time s", "passes": "passes / spp",
                   "caustic_rel_rmse": "caustic relRMSE", "rel_rmse": "relRMSE",
                   "caustic_block_err": "caustic block err", "block_err": "block err",
                   "caustic_flip": "caustic FLIP", "flip": "FLIP"}
        for name in SCENES:
            mine = [r for r in rows if r["scene"] == name]
            tables[name] = markdown_table(mine, cols, headers)
            fig = f"convergence_{name}.png"
            convergence_plot(mine, folder / fig, name)
            figures.append(fig)
        write_csv(folder / "convergence.csv", rows, ("scene",) + cols)
        md = "\n".join(f"### {n}\n\n{t}" for n, t in tables.items())
        atomic_write(folder / "convergence.md", lambda tmp: tmp.write_text(md, encoding="utf-8"))
        return {"title": f"Convergence: error against wall time at {res}x{res}", "scene": ", ".join(SCENES),
                "summary": summary(rows, self.budgets), "tables": tables, "csv": ["convergence.csv"],
                "figures": figures, "rows": rows}

    def _save(self, folder, scene, label, budget, result):
        tag = label.replace(" ", "_").replace(",", "").replace("+", "C").replace("=", "")
        name = f"{scene}_{tag}" + (f"_{budget:g}s" if budget is not None else "") + ".exr"
        result.save(folder / "renders" / name)


def summary(rows, budgets) -> str:
    """Which method has the lowest caustic relRMSE at each budget, and its ratio to Mitsuba's."""
    lines = []
    for scene in SCENES:
        floor = [r for r in rows if r["scene"] == scene and r["method"] == "reference"
                 and r.get("caustic_rel_rmse") is not None]
        if floor:
            f = floor[0]
            lines.append(f"{scene}: {f['label']}: {f['caustic_rel_rmse']:.4f} on the caustic, {f['rel_rmse']:.4f} "
                         f"on the whole image; every error below contains it in quadrature")
        for b in budgets:
            at = [r for r in rows if r["scene"] == scene and r.get("budget_s") == b
                  and r.get("caustic_rel_rmse") is not None]
            ours = [r for r in at if r["method"] not in ("mitsuba",)]
            if not ours:
                continue
            best = min(ours, key=lambda r: r["caustic_rel_rmse"])
            text = (f"{scene} at {b:g} s: best caustic relRMSE {best['caustic_rel_rmse']:.4f} ({best['label']}, "
                    f"whole image {best['rel_rmse']:.4f})")
            peer = [r for r in at if r["method"] == "mitsuba"]
            if peer:
                p = peer[0]
                text += (f"; Mitsuba 3 in the same time: {p['caustic_rel_rmse']:.4f} / {p['rel_rmse']:.4f}, "
                         f"i.e. {p['caustic_rel_rmse'] / best['caustic_rel_rmse']:.1f}x caustica's best error on "
                         f"the caustic and {p['rel_rmse'] / best['rel_rmse']:.2f}x on the whole image")
            lines.append(text)
    return "\n".join(lines)
