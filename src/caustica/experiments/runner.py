"""The paper's experiments: every render through ``caustica.render``, measured against a reference.

``run(names, config)`` runs ``table1 table2 table3 fig5 fig6 fig8 fig9 merge-ablation``
(or ``all``) into ``config.out``: per experiment a folder with the renders (EXR + PNG + JSON),
``*.csv`` and ``*.md`` tables, PNG figures and a ``results.json``; ``report.md`` at
the top ties them together (rebuilt after each experiment from every results.json
present, so experiments run one at a time still make one report).

Every measured configuration is rendered with ``config.seeds`` seeds (seed, seed + 1,
...); its errors are the mean over them, with the standard deviation beside each
(``*_sd``), so a difference can be told from seed-to-seed noise.

What each experiment renders is :mod:`.config`; the statistics over seeds and the equal-time /
equal-error fit :mod:`.statistics`; the report's sentences :mod:`.summaries`; this module submits
the renders, measures them and writes each experiment's folder.
"""
from __future__ import annotations

import contextlib
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import driver, methods
from ..api import load_scene, resolve_settings
from ..errors import ParameterError, SceneError
from ..imageio import atomic_write, write_json, write_png
from . import metrics as M
from .config import ABLATION, ABLATION_FIXED, ABLATION_SCENES, BUDGET_FACTORS, BUDGET_KEYS, CONFIGS, EQUAL_METRIC, \
    EQUAL_NAME, FIG_SCENES, FLOOR_LABEL, FLOOR_MAX_BOUNCES, HEADERS, QUICK_BUDGET_FACTORS, REFERENCE_SEED_OFFSET, \
    ROW_COLUMNS, SWEEP_ASSOC, SWEEP_RS, SWEEP_STREAMS, TABLE1_SCENE, TABLE_SCENES, UNMEASURED, Config, \
    check_references, expand, measured_scenes, split_reference
from . import convergence
from .convergence import RES as CONVERGENCE_RES, Convergence, shared_refs_dir
from .masks import caustic_mask
from .reference import Reference, _spp_halves, cache_folder, check_cache_writable, is_cached, pt_reference, \
    submit_halves, user_reference
from .renders import LocalRenders
from .statistics import equal_comparison, seed_statistics
from .summaries import ablation_summary, equal_summary, floor_summary, seed_pair_summary, table1_summary
from .tables import markdown_table, write_csv


def _file_stem(label: str) -> str:
    """A render's file name from its label: "PM+C x0.5" -> "PMC_x0.5", "SPM 10,000 x 10" -> "SPM_10000_x_10"."""
    s = label.replace("+", "C").replace(",", "").replace("=", "").replace("×", "x")
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", s)
    return s.strip("_.") or "render"


def _work_time(stats: dict) -> float:
    t = stats["timings"]
    return t["total_s"] - t.get("compile_s", 0.0) - t.get("scene_load_s", 0.0)


@dataclass
class _Submitted:
    """A configuration's renders on their way: one per seed (measured), then the repeats (timed only)."""
    seeds: list
    repeats: list


class Runner:
    """The experiments over one Config: every render is submitted to ``renders`` first (:meth:`submit`),
    then each experiment collects what it needs in the order of its tables (:meth:`run_one`)."""

    def __init__(self, config: Config, renders=None):
        self.cfg = config
        self.renders = renders or LocalRenders(config.threads)
        self.scenes = {}
        self.masks = {}
        self.refs = {}
        self.halves = {}     # scene -> its pt reference's two halves on their way
        self.memo = {}       # (scene, method, params) -> _Submitted, then (image, row) once collected
        self.bar = None
        self._convergence = None

    # ------------------------------------------------------------------ helpers
    def log(self, msg):
        if self.cfg.log:
            self.cfg.log(msg)

    def scene(self, name):
        if name not in self.scenes:
            self.scenes[name] = load_scene(name)
        return self.scenes[name]

    def mask(self, name):
        if name not in self.masks:
            r = self.cfg.res
            photons = 20_000 if self.cfg.quick else 200_000
            self.masks[name] = caustic_mask(self.scene(name), r, r, photons=photons, seed=self.cfg.seed,
                                            threads=self.cfg.threads)
        return self.masks[name]

    def _user_reference_path(self, scene_name):
        refs = [split_reference(item) for item in self.cfg.references]
        for scene, path in refs:
            if scene == scene_name:
                return path
        plain = [path for scene, path in refs if scene is None]
        for p in plain:
            if p.is_dir():
                cand = p / f"{scene_name}_{self.cfg.res}.exr"
                if cand.is_file():
                    return cand
        files = [p for p in plain if not p.is_dir()]
        if files:
            return files[0]
        return None

    def reference(self, name) -> Reference:
        if name not in self.refs:
            r = self.cfg.res
            path = self._user_reference_path(name)
            if path is not None:
                self.refs[name] = user_reference(path, r, r, self.mask(name))
            else:
                self.refs[name] = pt_reference(self.scene(name), r, r, spp=self.cfg.reference_spp,
                                               seed=self.cfg.seed + REFERENCE_SEED_OFFSET,
                                               cache_dir=self.cfg.cache_dir,
                                               threads=self.cfg.threads, progress=self.cfg.progress,
                                               mask=self.mask(name), log=self.log,
                                               halves=self.halves.pop(name, None))
        return self.refs[name]

    def submit_reference(self, name):
        """Send the pt reference's halves on their way, unless a user's reference or the cache has it."""
        if name in self.refs or name in self.halves or self._user_reference_path(name) is not None:
            return
        r, seed = self.cfg.res, self.cfg.seed + REFERENCE_SEED_OFFSET
        scene = self.scene(name)
        if not is_cached(cache_folder(scene.name, r, r, self.cfg.reference_spp, seed, self.cfg.cache_dir)):
            self.halves[name] = submit_halves(self.renders, scene, r, r, spp=self.cfg.reference_spp, seed=seed,
                                              progress=self.cfg.progress)

    def params_for(self, method, params, fixed=()):
        """The configuration's parameters with the user's overrides for the ones this method has."""
        from .. import methods
        names = {p.name for p in methods.get(method).params}
        out = dict(params)
        for k, v in self.cfg.params.items():
            if k in names and k not in fixed:
                out[k] = v
        return out

    def seed_list(self) -> list[int]:
        """The seeds of every measured configuration: seed, seed + 1, ..., seed + seeds - 1."""
        return [self.cfg.seed + j for j in range(self.cfg.seeds)]

    def submit_render(self, scene_name, method, params, measure=True):
        """Send a configuration's renders on their way, once (:meth:`run_render` collects them).

        One render per seed of :meth:`seed_list` (only the first when not ``measure``), then
        the first seed again up to ``--repeat`` renders.  The first render of a method on a
        process (here, or each worker) is preceded by an untimed one: it pays the start-up costs.
        """
        key = (scene_name, method, tuple(sorted(params.items())))
        if key not in self.memo:
            scene, r = self.scene(scene_name), self.cfg.res
            seeds = self.seed_list() if measure else [self.cfg.seed]
            warm = (method, self.cfg.seed)
            self.memo[key] = _Submitted(
                [self.renders.submit(scene, method, warm=warm, res=(r, r), seed=seed, progress=self.cfg.progress,
                                     **params) for seed in seeds],
                [self.renders.submit(scene, method, warm=warm, res=(r, r), seed=seeds[0], **params)
                 for _ in range(len(seeds), self.cfg.repeat)])
        return key

    def run_render(self, experiment, scene_name, label, method, params, folder: Path, measure=True,
                   stem=None) -> dict:
        """Render one configuration: (row, the first seed's image).

        Measured: one render per seed of :meth:`seed_list`, the row's metrics their mean and
        ``*_sd`` their standard deviation.  Time: the fastest render of the configuration
        (the seeds' renders, plus renders of the first seed again up to ``--repeat``).
        Only the first seed's render is saved under ``renders/``.
        """
        key = self.submit_render(scene_name, method, params, measure)
        if not isinstance(self.memo[key], _Submitted):
            image, row = self.memo[key]
            row = dict(row, experiment=experiment, label=label)
        else:
            submitted = self.memo[key]
            times, per_seed, result = [], [], None
            for pending in submitted.seeds:
                res_s, _ = pending.result()
                times.append(_work_time(res_s.stats))
                if measure:
                    ref = self.reference(scene_name)
                    per_seed.append(M.all_metrics(res_s.image, ref.image, self.mask(scene_name)))
                if result is None:
                    result = res_s
            for pending in submitted.repeats:   # the first seed again: the same image, only the time differs
                times.append(_work_time(pending.result()[0].stats))
            stats = result.stats
            image = result.image
            row = {"experiment": experiment, "scene": scene_name, "label": label, "method": method,
                   **{k: params.get(k) for k in ("streams", "assoc", "stream_radius", "photons",
                                                  "caustic_photons")},
                   "photons_emitted": stats.get("photons_emitted"), "photons_stored": stats.get("photons_stored"),
                   "map_mb": stats.get("map_mb"),
                   "time_s": min(times), "seeds": len(submitted.seeds) if measure else None}
            fname = folder / "renders" / (_file_stem(stem or label) + ".exr")
            result.save(fname)
            row["image"] = str(fname.relative_to(self.cfg.out))
            if measure:
                row.update(seed_statistics(per_seed))
            self.memo[key] = (image, row)
        if self.bar is not None:
            self.bar.update(1)
        return row, image

    # ------------------------------------------------------------------ noise row
    def noise_row(self, experiment, scene_name):
        ref = self.reference(scene_name)
        row = {"experiment": experiment, "scene": scene_name, "label": "reference noise: half A vs half B",
               "method": "pt"}
        if ref.half_a is not None:
            row.update(M.all_metrics(ref.half_a, ref.half_b, self.mask(scene_name)))
        return row

    # ------------------------------------------------------------------ experiments
    def count(self, name):
        """Renders an experiment makes (for the experiment's progress bar)."""
        if name == "table1":
            return len(self._table1_grid())
        if name in TABLE_SCENES:
            return len(self._budget_factors()) * 3 + 1
        if name == "merge-ablation":
            return len(ABLATION) * len(ABLATION_SCENES)
        if name == "convergence":
            return self.convergence().count()
        return {"fig5": 2, "fig6": 1, "fig8": 3, "fig9": 3}[name]

    def convergence(self) -> Convergence:
        """The convergence study over this runner (one, so that what it submits is what it collects)."""
        if self._convergence is None:
            self._convergence = Convergence(self)
        return self._convergence

    def submit(self, names):
        """Send every render of the experiments ``names`` on its way: the references' halves first, then
        each experiment's renders in the order its tables collect them.

        Locally nothing runs yet: each render runs when collected, as in a plain loop.  On a
        cluster the workers start at once, and the results wait there until collected.
        """
        for scene_name in sorted(measured_scenes(names)):
            self.submit_reference(scene_name)
        for name in names:
            if name == "convergence":
                self.convergence().submit()
                continue
            for _label, scene_name, method, params in self.plan(name):
                try:
                    self.scene(scene_name)
                except SceneError:   # the experiment reports it as skipped
                    continue
                self.submit_render(scene_name, method, params, measure=name not in UNMEASURED)

    def _table1_grid(self):
        p = self.cfg.params
        streams = [p["streams"]] if "streams" in p else SWEEP_STREAMS
        assoc = [p["assoc"]] if "assoc" in p else SWEEP_ASSOC
        rs = [p["stream_radius"]] if "stream_radius" in p else SWEEP_RS
        return [(s, a, r) for s in streams for a in assoc for r in rs]

    def _budget_factors(self):
        return QUICK_BUDGET_FACTORS if self.cfg.quick else BUDGET_FACTORS

    def _table1_params(self, s, a, r):
        params = self.params_for("spm", {"streams": s, "assoc": a, "stream_radius": r})
        params.update(streams=s, assoc=a, stream_radius=r)
        return params

    def _budget_params(self, label, factor):
        c = CONFIGS[label]
        params = self.params_for(c["method"], c["params"], c["fixed"])
        for k in BUDGET_KEYS[label]:
            params[k] = max(1, round(params[k] * factor))
        return params

    def _figure_items(self, name):
        """(label, method, params) of each panel of a figure."""
        if name == "fig5":
            base = self.params_for("spm", CONFIGS["SPM"]["params"])
            return [(f"SPM r_s={rs:g}", "spm", dict(base, stream_radius=rs)) for rs in (5.0, 0.1)]
        if name == "fig6":
            return [("SPM", "spm", self.params_for("spm", CONFIGS["SPM"]["params"]))]
        return [(lab, c["method"], self.params_for(c["method"], c["params"], c["fixed"]))
                for lab, c in CONFIGS.items()]

    def _floor_params(self):
        """The truncation floor: the paper's PM with mr = 64 instead of 4 (the references have no limit)."""
        params = self.params_for("pm", CONFIGS["PM"]["params"], ("caustic_photons", "max_bounces"))
        params["max_bounces"] = FLOOR_MAX_BOUNCES
        return params

    def _ablation_params(self, method, base):
        params = self.params_for(method, base, ABLATION_FIXED)
        params.update(base)
        return params

    def plan(self, name):
        """(label, scene, method, params) of every render experiment ``name`` makes.

        params may hold the render's ``passes`` and ``time_s`` besides the method's parameters.
        """
        if name == "table1":
            return [(f"SPM {s}x{a} r_s={r:g}", TABLE1_SCENE, "spm", self._table1_params(s, a, r))
                    for s, a, r in self._table1_grid()]
        if name in TABLE_SCENES:
            scene = TABLE_SCENES[name]
            return [(f"{label} x{f:g}", scene, CONFIGS[label]["method"], self._budget_params(label, f))
                    for f in self._budget_factors() for label in CONFIGS] + [
                (FLOOR_LABEL, scene, "pm", self._floor_params())]
        if name == "merge-ablation":
            return [(label, scene, method, self._ablation_params(method, base))
                    for scene in ABLATION_SCENES for label, method, base in ABLATION]
        if name == "convergence":
            return self.convergence().plan()
        return [(lab, FIG_SCENES[name], m, p) for lab, m, p in self._figure_items(name)]

    def preflight(self, names):
        """Check every render and reference the experiments need before anything is written.

        Each planned render's settings pass the same checks as a render (ranges, memory of
        the image and the search scratch); each measured scene's reference is readable at the
        right size, or the reference cache can be written.  Scenes that cannot be loaded are
        left to their experiment, which reports them as skipped.
        """
        cfg, r = self.cfg, self.cfg.res
        for name in names:
            for label, scene_name, method, params in self.plan(name):
                try:
                    scene = self.scene(scene_name)
                except SceneError:
                    continue
                params = dict(params)
                passes, time_s = params.pop("passes", None), params.pop("time_s", None)
                try:
                    pass_plan = driver.check_plan(methods.get(method), passes, time_s)
                    resolve_settings(scene, method, res=(r, r), seed=cfg.seed, threads=cfg.threads,
                                     multi_pass=pass_plan.multi, **params)
                except ParameterError as exc:
                    raise ParameterError(f"{name} would render {label} ({method}, {scene_name}): {exc}") from None
        for scene_name in sorted(measured_scenes(names)):
            path = self._user_reference_path(scene_name)
            if path is not None:
                user_reference(path, r, r)   # its size and its pixels (the mask's are checked when it is made)
                continue
            scene = self.scene(scene_name)
            seed = cfg.seed + REFERENCE_SEED_OFFSET
            for half_spp, half_seed in zip(_spp_halves(cfg.reference_spp), (seed, seed + 1)):
                resolve_settings(scene, "pt", spp=half_spp, res=(r, r), seed=half_seed, threads=cfg.threads)
            folder = cache_folder(scene.name, r, r, cfg.reference_spp, seed, cfg.cache_dir)
            if not is_cached(folder):
                check_cache_writable(folder)

    def table1(self, folder):
        from .figures import fig4_plot
        scene = TABLE1_SCENE
        rows = [self.noise_row("table1", scene)]
        for s, a, r in self._table1_grid():
            params = self._table1_params(s, a, r)
            row, _ = self.run_render("table1", scene, f"SPM {s}x{a} r_s={r:g}", "spm", params, folder)
            rows.append(row)
        cols = ("label", "streams", "assoc", "stream_radius", "photons_emitted", "time_s", "map_mb",
                "rel_mse", "block_err", "ssim", "flip", "caustic_rel_mse", "caustic_block_err",
                "caustic_ssim", "caustic_flip")
        write_csv(folder / "table1.csv", rows, ROW_COLUMNS)
        md = markdown_table(rows, cols, HEADERS)
        atomic_write(folder / "table1.md", lambda tmp: tmp.write_text(md, encoding="utf-8"))
        fig4_plot(rows[1:], folder / "fig4_error_vs_streams.png")
        return {"title": f"Table 1: the SPM parameter sweep ({scene})", "scene": scene,
                "summary": table1_summary(rows[1:]),
                "tables": {"table1": md}, "csv": ["table1.csv"], "figures": ["fig4_error_vs_streams.png"],
                "rows": rows}

    def budget_table(self, name, folder):
        scene = TABLE_SCENES[name]
        rows_main, sweep = [], {k: [] for k in CONFIGS}
        for factor in self._budget_factors():
            for label, c in CONFIGS.items():
                params = self._budget_params(label, factor)
                tag = label if factor == 1.0 else f"{label} x{factor:g}"
                row, _ = self.run_render(name, scene, tag, c["method"], params, folder)
                row = dict(row, config=label, budget_factor=factor)
                sweep[label].append(row)
                if factor == 1.0:
                    rows_main.append(row)
        order = {k: i for i, k in enumerate(CONFIGS)}
        rows_main.sort(key=lambda r: order[r["config"]])
        floor, _ = self.run_render(name, scene, FLOOR_LABEL, "pm", self._floor_params(), folder)
        floor = dict(floor, config=FLOOR_LABEL, budget_factor=1.0)
        noise = self.noise_row(name, scene)
        eq = equal_comparison(sweep, "SPM")
        eq_pmc = equal_comparison(sweep, "PM+C")
        for r in rows_main:
            r.update(eq.get(r["config"], {}))
            other = eq_pmc.get(r["config"], {})
            r["time_to_pmc_error_s"] = other.get("equal_error_time_s")
            r["time_to_pmc_error_s_text"] = other.get("equal_error_time_s_text")
            r["time_to_pmc_error_extrapolated"] = other.get("equal_error_extrapolated")
        cols = ("label", "photons_emitted", "map_mb", "time_s", "caustic_block_err", "caustic_mean_err",
                "caustic_rel_mse", "caustic_ssim", "caustic_flip", "block_err", "mean_err", "rel_mse", "ssim",
                "flip")
        md = markdown_table(rows_main + [floor, noise], cols, HEADERS)
        eq_cols = ("label", "time_s", EQUAL_METRIC, "equal_error_time_s", "equal_time_error",
                   "time_to_pmc_error_s")
        eq_headers = {**HEADERS, "equal_error_time_s": f"time to SPM's {EQUAL_NAME} (s)",
                      "equal_time_error": f"{EQUAL_NAME} in SPM's time",
                      "time_to_pmc_error_s": f"time to PM+C's {EQUAL_NAME} (s)"}
        eq_rows = [{**r, "equal_error_time_s": r.get("equal_error_time_s_text"),
                    "equal_time_error": r.get("equal_time_error_text"),
                    "time_to_pmc_error_s": r.get("time_to_pmc_error_s_text")} for r in rows_main]
        md_eq = markdown_table(eq_rows, eq_cols, eq_headers)
        all_rows = [r for k in CONFIGS for r in sweep[k]]
        write_csv(folder / f"{name}.csv", rows_main + [floor, noise],
                  ROW_COLUMNS + ("equal_error_time_s", "equal_error_extrapolated", "equal_time_error",
                                 "equal_time_extrapolated", "time_to_pmc_error_s", "time_to_pmc_error_extrapolated"))
        write_csv(folder / f"{name}_budget_sweep.csv", all_rows, ROW_COLUMNS + ("config", "budget_factor"))
        atomic_write(folder / f"{name}.md", lambda tmp: tmp.write_text(md + "\n" + md_eq, encoding="utf-8"))
        from .figures import budget_plot
        budget_plot(sweep, eq, folder / f"{name}_error_vs_time.png", scene, EQUAL_METRIC, EQUAL_NAME)
        return {"title": f"{'Table 2' if name == 'table2' else 'Table 3'}: SPM vs PM vs PM+C ({scene})",
                "scene": scene, "tables": {name: md, f"{name} equal-error / equal-time": md_eq},
                "csv": [f"{name}.csv", f"{name}_budget_sweep.csv"], "figures": [f"{name}_error_vs_time.png"],
                "rows": rows_main + [floor, noise], "equal": eq, "equal_to_pmc": eq_pmc,
                "summary": " ".join(x for x in (equal_summary(eq, rows_main, eq_pmc), seed_pair_summary(rows_main),
                                                 floor_summary(next(r for r in rows_main if r["config"] == "PM"), floor)) if x)}

    def merge_ablation(self, folder):
        """SPM's caustic against PM with n_fs photons, both estimators, on both caustic scenes (docs/experiments.md)."""
        tables, rows_all, summaries, csvs = {}, [], [], []
        cols = ("label", "photons_emitted", "seeds", "caustic_block_err", "caustic_mean_err", "caustic_rel_mse",
                "block_err", "mean_err", "rel_mse")
        for scene in ABLATION_SCENES:
            rows = []
            for label, method, base in ABLATION:
                params = self._ablation_params(method, base)
                row, _ = self.run_render("merge-ablation", scene, label, method, params, folder,
                                         stem=f"{scene}_{label}")
                rows.append(row)
            noise = self.noise_row("merge-ablation", scene)
            md = markdown_table(rows + [noise], cols, HEADERS)
            tables[f"merge ablation: {scene}"] = md
            csv_name = f"merge_ablation_{scene}.csv"
            write_csv(folder / csv_name, rows + [noise], ROW_COLUMNS)
            csvs.append(csv_name)
            summaries.append(f"{scene}: {ablation_summary(rows)}")
            rows_all.extend(rows + [noise])
        text = "\n\n".join(f"## {t}\n\n{m}" for t, m in tables.items())
        atomic_write(folder / "merge_ablation.md", lambda tmp: tmp.write_text(text, encoding="utf-8"))
        return {"title": "Merge ablation: what SPM's caustic is", "scenes": list(ABLATION_SCENES),
                "tables": tables, "csv": csvs, "rows": rows_all, "summary": " ".join(summaries)}

    def figure(self, name, folder):
        from .figures import side_by_side
        scene = FIG_SCENES[name]
        items = self._figure_items(name)
        try:
            self.scene(scene)
        except SceneError as exc:
            msg = f"{name} skipped: the scene {scene} cannot be loaded: {exc}"
            self.log(msg)
            if self.bar is not None:
                self.bar.update(len(items))
            return {"title": f"{name}: skipped", "scene": scene, "skipped": msg}
        has_caustic = name in ("fig8", "fig9")
        panels = []
        for label, method, params in items:
            row, image = self.run_render(name, scene, label, method, params, folder, measure=has_caustic)
            panels.append((label, image, row))
        mask = self.mask(scene) if has_caustic else None
        fname = f"{name}_{scene}.png"
        side_by_side(panels, folder / fname, title=f"{name}: {scene}, {self.cfg.res}x{self.cfg.res}",
                     mask=mask, scene=scene)
        out = {"title": f"{name.replace('fig', 'Figure ')}: {scene}", "scene": scene, "figures": [fname],
               "rows": [p[2] for p in panels]}
        if has_caustic:
            cols = ("label", "photons_emitted", "map_mb", "time_s", "caustic_block_err", "caustic_rel_mse",
                    "caustic_ssim", "caustic_flip")
            out["tables"] = {name: markdown_table(out["rows"], cols, HEADERS)}
        return out

    def run_one(self, name) -> dict:
        folder = self.cfg.out / name
        folder.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        if name == "table1":
            res = self.table1(folder)
        elif name in TABLE_SCENES:
            res = self.budget_table(name, folder)
        elif name == "merge-ablation":
            res = self.merge_ablation(folder)
        elif name == "convergence":
            res = self.convergence().run(folder)
            res["scenes"] = list(convergence.SCENES)
        else:
            res = self.figure(name, folder)
        res["name"] = name
        res["wall_s"] = time.perf_counter() - t0
        scenes = res.get("scenes") or [res.get("scene")]
        refs = [s for s in scenes if s in self.refs]
        if refs:
            res["reference"] = "; ".join((f"{s}: " if len(scenes) > 1 else "") + self.refs[s].noise_line()
                                         for s in refs)
            res["reference_noise"] = (self.refs[refs[0]].noise if len(scenes) == 1
                                      else {s: self.refs[s].noise for s in refs})
        for scene in scenes:
            if scene in self.masks:
                m = self.masks[scene]
                fname = f"{scene}_caustic_mask.png"
                write_png(folder / fname, np.repeat(m[:, :, None], 3, axis=2).astype(np.float32))
                res.setdefault("mask_images", {})[fname] = int(m.sum())
                res["mask_pixels"] = int(m.sum())
                res["mask_image"] = fname
        res["settings"] = {"res": self.cfg.res, "seed": self.cfg.seed, "seeds": self.seed_list(),
                           "quick": self.cfg.quick, "repeat": self.cfg.repeat,
                           "reference_spp": self.cfg.reference_spp, "overrides": self.cfg.params}
        where = self.renders.describe()
        if where is not None:
            res["settings"]["cluster"] = where
        write_json(folder / "results.json", res)
        return res


@contextlib.contextmanager
def _renders(config: Config, log):
    """Where the renders run: here, or on the cluster of ``--dask``/``--workers`` (connected for the run;
    a ``distributed.Client`` of the caller's stays open)."""
    if not config.on_cluster:
        yield LocalRenders(config.threads)
        return
    from ..cluster import connect
    from .dask_renders import DaskRenders
    with connect(config.dask, config.workers) as cluster:   # Ctrl-C: a local cluster stops at once
        n = len(cluster.worker_threads)
        log(f"rendering on the Dask cluster at {cluster.address}: {n} worker{'' if n == 1 else 's'}, "
            f"{cluster.threads} threads")
        yield DaskRenders(cluster)    # closing leaves a caller's own Client open (Cluster.owned)


def run(names, config: Config) -> dict:
    """Run the experiments ``names`` (see EXPERIMENTS, or 'all'); returns {name: results} and writes report.md."""
    from .report import write_report
    names = expand(names)
    if "convergence" in names:
        # the convergence study's size is the Mitsuba references' (256) unless --res says otherwise
        if not config.res_given and not config.quick:
            config.res = CONVERGENCE_RES
        refs = shared_refs_dir()
        if not config.references and refs is not None and any(refs.glob(f"*_{config.res}.exr")):
            config.references.append(str(refs))
    check_references(config.references, measured_scenes(names))
    runner = Runner(config)
    runner.preflight(names)   # nothing is created before every check has passed
    # an unreachable scheduler fails here, in one line, before anything is created
    with _renders(config, runner.log) as renders:
        runner.renders = renders
        config.out.mkdir(parents=True, exist_ok=True)
        total = sum(runner.count(n) for n in names)
        bar = None
        if config.progress:
            from tqdm import tqdm
            bar = tqdm(total=total, desc="experiment", unit="render", position=0, file=sys.stderr,
                       dynamic_ncols=True, disable=not sys.stderr.isatty())
        runner.bar = bar
        results = {}
        t0 = time.perf_counter()
        try:
            runner.submit(names)
            for n in names:
                if bar is not None:
                    bar.set_description(f"experiment {n}")
                results[n] = runner.run_one(n)
                runner.log(f"{n}: done in {results[n]['wall_s']:.1f} s -> {config.out / n}")
        finally:
            if bar is not None:
                bar.close()
    report = write_report(config.out)
    runner.log(f"{', '.join(names)} in {time.perf_counter() - t0:.1f} s; report: {report}")
    return results
