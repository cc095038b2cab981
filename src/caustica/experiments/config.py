"""The experiments' configuration: which experiments exist, the scenes and parameters each renders,
and :class:`Config`, the user's settings checked once before anything is written."""
from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

from .. import methods
from ..api import check_common
from ..errors import ParameterError, quoted
from ..limits import MAX_PIXELS, MAX_SEED, MAX_SPP, MAX_THREADS
from ..methods.params import Param, non_negative, positive, resolve
from . import convergence

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
        return convergence.SCENES
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


def method_setting(text: str) -> tuple[str, object]:
    """--set KEY=VALUE: a method setting, its value an int, a float or else a string."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--set {text!r}: expected KEY=VALUE, e.g. termination=roulette")
    for convert in (int, float):
        try:
            return key.replace("-", "_"), convert(value)
        except ValueError:
            pass
    return key.replace("-", "_"), value
