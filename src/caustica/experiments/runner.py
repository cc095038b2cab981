"""The paper's experiments: every render through ``caustica.render``, measured against a reference.

``run(names, config)`` runs ``table1 table2 table3 fig5 fig6 fig8 fig9 merge-ablation``
(or ``all``) into ``config.out``: per experiment a folder with the renders (EXR + PNG + JSON),
``*.csv`` and ``*.md`` tables, PNG figures and a ``results.json``; ``report.md`` at
the top ties them together (rebuilt after each experiment from every results.json
present, so experiments run one at a time still make one report).

Every measured configuration is rendered with ``config.seeds`` seeds (seed, seed + 1,
...); its errors are the mean over them, with the standard deviation beside each
(``*_sd``), so a difference can be told from seed-to-seed noise.
"""
from __future__ import annotations

import contextlib
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import driver, methods
from ..api import check_common, load_scene, resolve_settings
from ..errors import ParameterError, SceneError, quoted
from ..imageio import atomic_write, write_json, write_png
from ..limits import MAX_PIXELS, MAX_SEED, MAX_SPP, MAX_THREADS
from ..methods.params import Param, non_negative, positive, resolve
from . import metrics as M
from .convergence import RES as CONVERGENCE_RES, SCENES as CONVERGENCE_SCENES, Convergence, shared_refs_dir
from .masks import caustic_mask
from .reference import Reference, _spp_halves, cache_folder, check_cache_writable, is_cached, pt_reference, \
    submit_halves, user_reference
from .renders import LocalRenders
from .tables import _fmt, markdown_table, write_csv

EXPERIMENTS = ("table1", "table2", "table3", "fig5", "fig6", "fig8", "fig9", "merge-ablation", "convergence")
#: What ``all`` runs: the paper's experiments and the ablation (``convergence`` takes half an hour: ask for it).
ALL = EXPERIMENTS[:-1]

PAPER_RES = 512
QUICK_RES = 48
DEFAULT_REFERENCE_SPP = 1024
QUICK_REFERENCE_SPP = 64
DEFAULT_SEEDS = 3
QUICK_SEEDS = 1
#: Seeds stay below the pt reference's (seed + 1000, seed + 1001), so no render shares its numbers.
MAX_SEEDS = 100
TABLE1_SCENE = "cornell-diacaustic"
TABLE_SCENES = {"table2": "cornell-diacaustic", "table3": "cornell-catacaustic"}
FIG_SCENES = {"fig5": "cornell-pyramid", "fig6": "cornell-bunny", "fig8": "cornell-diacaustic",
              "fig9": "cornell-catacaustic"}
#: Figures that show images without measuring them (no reference).
UNMEASURED = ("fig5", "fig6")
BUDGET_FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
QUICK_BUDGET_FACTORS = (0.5, 1.0, 2.0)
SWEEP_STREAMS = (1000, 5000, 10000)
SWEEP_ASSOC = (10, 50, 100)
SWEEP_RS = (0.1, 2.5, 5.0)

# The paper's three configurations of Tables 2 and 3; `fixed` are keys no override touches.
CONFIGS = {
    "SPM": {"method": "spm", "params": {"streams": 10_000, "assoc": 10, "stream_radius": 5.0}, "fixed": ()},
    "PM": {"method": "pm", "params": {"photons": 100_000, "caustic_photons": 0}, "fixed": ("caustic_photons",)},
    "PM+C": {"method": "pm", "params": {"photons": 100_000, "caustic_photons": 100_000}, "fixed": ()},
}
BUDGET_KEYS = {"SPM": ("streams",), "PM": ("photons",), "PM+C": ("photons", "caustic_photons")}
#: The truncation floor of Tables 2 and 3: PM as in the paper but with mr = 64 diffuse bounces
#: (the references have unlimited depth; after 64 bounces at most 0.75^64 ~ 1e-8 of a photon's power is left).
FLOOR_LABEL = "PM, mr = 64"
FLOOR_MAX_BOUNCES = 64
#: The merge ablation (docs/experiments.md): SPM's caustic against PM with as many photons as SPM
#: has streams, under both estimators.  Each: (label, method, parameters no override touches).
#: "estimator" is left out for the default (stream) so the renders are shared with Tables 2 and 3.
ABLATION_SCENES = ("cornell-diacaustic", "cornell-catacaustic")
ABLATION_PASSES = 16
ABLATION = (
    ("SPM 10,000 x 10, eq. 2 (stream estimator)", "spm", {"streams": 10_000, "assoc": 10, "stream_radius": 5.0}),
    ("SPM 10,000 x 10, photons estimator", "spm",
     {"streams": 10_000, "assoc": 10, "stream_radius": 5.0, "estimator": "photons"}),
    ("SPM 10,000 x 0 (no associated photons)", "spm", {"streams": 10_000, "assoc": 0, "stream_radius": 5.0}),
    ("PM 10,000 (as many photons as SPM has streams)", "pm", {"photons": 10_000, "caustic_photons": 0}),
    ("SPM 100,000 x 10, eq. 2", "spm", {"streams": 100_000, "assoc": 10, "stream_radius": 5.0}),
    ("PM 100,000", "pm", {"photons": 100_000, "caustic_photons": 0}),
    # the merge itself, removed: only progressive SPM has --specular split (a different estimator)
    (f"pspm, {ABLATION_PASSES} passes, --specular merge (the paper's rule)", "pspm",
     {"passes": ABLATION_PASSES, "specular": "merge"}),
    (f"pspm, {ABLATION_PASSES} passes, --specular split (no merge)", "pspm",
     {"passes": ABLATION_PASSES, "specular": "split"}),
)
ABLATION_FIXED = ("streams", "assoc", "stream_radius", "estimator", "photons", "caustic_photons", "specular")
#: The error that equal-time / equal-error compare.
#: relMSE over the ~1000 caustic pixels is dominated by a few outlier pixels and is not monotone
#: in the photon budget (it cannot be inverted); the block-mean error falls steadily.
EQUAL_METRIC = "caustic_block_err"
EQUAL_NAME = "caustic block err"
#: How far beyond the budget sweep (as a factor) equal-error may extrapolate.
MAX_EXTRAPOLATION = 2.0
#: The pt reference's two halves use seeds seed + REFERENCE_SEED_OFFSET and that + 1.
REFERENCE_SEED_OFFSET = 1000

#: The experiment's own settings, checked (with the bounds of caustica.limits) before anything is written.
SETTINGS = (
    Param("res", int, None, "image size", lambda v: v >= 8, ">= 8", max=math.isqrt(MAX_PIXELS)),
    Param("seed", int, 0, "random seed", non_negative, ">= 0", max=MAX_SEED - REFERENCE_SEED_OFFSET - 1),
    Param("threads", int, None, "worker threads", positive, ">= 1", max=MAX_THREADS),
    Param("reference_spp", int, None, "samples per pixel of the pt reference", lambda v: v >= 2,
          ">= 2 (two halves)", max=2 * MAX_SPP),
    Param("repeat", int, None, "renders per configuration", positive, ">= 1", max=100),
    Param("seeds", int, None, "seeds per measured configuration", positive, ">= 1", max=MAX_SEEDS),
)

ROW_COLUMNS = ("experiment", "scene", "label", "method", "streams", "assoc", "stream_radius", "photons",
               "caustic_photons", "photons_emitted", "photons_stored", "map_mb", "time_s",
               "seeds", "rel_mse", "block_err", "mean_err", "ssim", "flip",
               "caustic_rel_mse", "caustic_block_err", "caustic_mean_err", "caustic_ssim", "caustic_flip",
               "rel_mse_sd", "block_err_sd", "mean_err_sd", "ssim_sd", "flip_sd",
               "caustic_rel_mse_sd", "caustic_block_err_sd", "caustic_mean_err_sd", "caustic_ssim_sd",
               "caustic_flip_sd", "image")


@dataclass
class Config:
    out: Path
    res: int | None = None
    seed: int = 0
    quick: bool = False
    reference_spp: int | None = None
    references: list = field(default_factory=list)   # "PATH" | "SCENE=PATH" | a folder
    params: dict = field(default_factory=dict)       # method parameters given by the user
    threads: int | None = None
    cache_dir: Path | None = None
    repeat: int | None = None                        # renders per configuration, time = the fastest
    seeds: int | None = None                         # seeds per measured configuration (errors: mean, s.d.)
    progress: bool = True
    log: object = None
    dask: object = None                              # a scheduler's address (or a distributed.Client)
    workers: int | None = None                       # or a local cluster of this many worker processes

    def __post_init__(self):
        if not str(self.out).strip():   # Path("") is the working directory: never write there unasked
            raise ParameterError("-o: the output folder is empty; give e.g. -o out/experiments")
        self.out = Path(self.out)
        self.res_given = self.res is not None
        if self.res is None:
            self.res = QUICK_RES if self.quick else PAPER_RES
        if self.reference_spp is None:
            self.reference_spp = QUICK_REFERENCE_SPP if self.quick else DEFAULT_REFERENCE_SPP
        if self.repeat is None:
            self.repeat = 1 if self.quick else 2
        if self.seeds is None:
            self.seeds = QUICK_SEEDS if self.quick else DEFAULT_SEEDS
        checked = resolve("experiment", SETTINGS, {p.name: getattr(self, p.name) for p in SETTINGS})
        for name, value in checked.items():
            setattr(self, name, value)
        check_common(spp=1, width=self.res, height=self.res, seed=self.seed, threads=self.threads)
        # every method parameter given, against the photon methods' tables (the experiments render pm and spm)
        specs = {p.name: p for m in ("pm", "spm") for p in methods.get(m).params}
        resolve("pm/spm", tuple(specs.values()), self.params)
        if self.on_cluster:
            from ..cluster import check_args
            check_args(self.dask, self.workers)
            if self.threads is not None:
                raise ParameterError("--threads: with --dask or --workers every render runs on all the threads of "
                                     "its worker; leave --threads out")

    @property
    def on_cluster(self) -> bool:
        return self.dask is not None or self.workers is not None


HEADERS = {"label": "configuration", "photons_emitted": "photons", "map_mb": "map MB", "time_s": "time s",
           "rel_mse": "relMSE", "block_err": "block err", "mean_err": "mean err", "ssim": "SSIM", "flip": "FLIP",
           "caustic_rel_mse": "caustic relMSE", "caustic_block_err": "caustic block err",
           "caustic_mean_err": "caustic mean err",
           "caustic_ssim": "caustic SSIM", "caustic_flip": "caustic FLIP", "stream_radius": "r_s"}


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
            res["scenes"] = list(CONVERGENCE_SCENES)
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


# ---------------------------------------------------------------------- equal time / equal error


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


# ---------------------------------------------------------------------- entry point


def expand(names) -> list[str]:
    out = []
    for n in names:
        if n == "all":
            out.extend(ALL)
        elif n in EXPERIMENTS:
            out.append(n)
        else:
            raise ParameterError(f"unknown experiment '{n}'; choose from {', '.join(EXPERIMENTS)} or all")
    seen = set()
    return [n for n in out if not (n in seen or seen.add(n))]


def scenes_of(name: str) -> tuple[str, ...]:
    """The scenes an experiment renders."""
    if name == "table1":
        return (TABLE1_SCENE,)
    if name == "merge-ablation":
        return ABLATION_SCENES
    if name == "convergence":
        return CONVERGENCE_SCENES
    return (TABLE_SCENES.get(name) or FIG_SCENES[name],)


def measured_scenes(names) -> set[str]:
    """The scenes whose renders these experiments measure against a reference."""
    return {scene for n in names if n not in UNMEASURED for scene in scenes_of(n)}


def split_reference(item: str) -> tuple[str | None, Path]:
    """``--reference`` as (scene or None, path): SCENE=PATH, or a path (which may hold '=' if it exists)."""
    if "=" in item and not Path(item).exists():
        scene, path = item.split("=", 1)
        return scene, Path(path)
    return None, Path(item)


def check_references(references, measured) -> None:
    """Every --reference names an existing file or folder and, as SCENE=PATH, a scene these experiments
    measure (once); a plain file only when they measure one scene."""
    seen = {}
    for item in references:
        scene, path = split_reference(item)
        if not path.exists():
            raise ParameterError(f"--reference {quoted(item)}: no such file or folder: {quoted(str(path))}")
        if scene is None:
            if not path.is_dir() and len(measured) > 1:
                raise ParameterError(f"--reference {item}: these experiments measure {len(measured)} scenes "
                                     f"({', '.join(sorted(measured))}); give SCENE=PATH for each, or a folder")
            continue
        if scene not in measured:
            what = f"the scenes measured: {', '.join(sorted(measured))}" if measured else \
                "these experiments measure no scene (their figures are not compared with a reference)"
            raise ParameterError(f"--reference {quoted(item)}: {quoted(scene)} is not a scene these experiments "
                                 f"measure; {what}")
        if scene in seen:
            raise ParameterError(f"--reference {quoted(item)}: {scene} has a reference already ({seen[scene]}); "
                                 f"give one per scene")
        seen[scene] = item


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
