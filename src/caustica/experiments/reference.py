"""Converged references: caustica's ``pt`` at a high sample count, rendered once and cached.

A reference is rendered as two independent halves (seeds ``seed`` and ``seed + 1``,
``spp / 2`` samples each); the reference is their mean.  Comparing the halves gives
its noise: with per-pixel variance s^2 in each half, the difference has 2 s^2 and
the mean s^2 / 2, so the reference's own relative error is about half the
between-halves relative RMSE (its relMSE a quarter of the between-halves relMSE).

The cache is a folder per (scene, size, spp, seed, caustica version), holding
``half_a.exr``, ``half_b.exr``, ``reference.exr`` and ``reference.json`` (timings and
noise).  It lives in ``$CAUSTICA_CACHE`` or ``$XDG_CACHE_HOME/caustica/references``
(``~/.cache/caustica/references``) unless a folder is given.

A user's own reference (``--reference PATH.exr``, e.g. Mitsuba's in shared/refs) is
used as it is; its noise is then unknown unless a ``_a.exr``/``_b.exr`` pair or a JSON
sidecar with ``noise.est_rel_rmse_of_full`` sits beside it.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..version import __version__
from ..errors import CausticaError
from ..imageio import read_exr, write_exr, write_json
from . import metrics


def default_cache_dir() -> Path:
    if os.environ.get("CAUSTICA_CACHE"):
        return Path(os.environ["CAUSTICA_CACHE"]) / "references"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "caustica" / "references"


def check_cache_writable(folder: Path) -> None:
    """Refuse, before anything is rendered, a cache folder that could not be created or written."""
    existing = Path(folder).absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise CausticaError(f"cannot write the reference cache {folder}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise CausticaError(f"cannot write the reference cache {folder}: {existing} is not writable")


@dataclass
class Reference:
    image: np.ndarray
    source: str                      # "pt <spp> spp (cached|rendered)" or the user's path
    noise: dict = field(default_factory=dict)   # see noise_stats
    half_a: np.ndarray | None = None
    half_b: np.ndarray | None = None
    render_s: float = 0.0            # time spent rendering it in this run (0 when cached)
    spp: int | None = None           # its samples per pixel, when its JSON sidecar says
    renderer: str = ""               # what rendered it, when its JSON sidecar says ("mitsuba 3.9.1 ...")

    def noise_line(self) -> str:
        n = self.noise
        if not n:
            return f"reference: {self.source}; its noise is unknown (no independent halves)"
        parts = [f"reference: {self.source}",
                 f"own noise: est. relative RMSE {n['est_rel_rmse_of_full']:.4f} (whole image)"]
        if n.get("caustic_est_rel_rmse_of_full") is not None:
            parts.append(f"{n['caustic_est_rel_rmse_of_full']:.4f} (caustic region)")
        return "; ".join(parts) + " — from two independent halves: between-halves relative RMSE / 2"


def noise_stats(a: np.ndarray, b: np.ndarray, mask=None) -> dict:
    """The reference's own noise from its two halves (see the module's docstring)."""
    out = {}
    for prefix, m in (("", None), ("caustic_", mask)):
        if prefix and (m is None or not np.any(m)):
            continue
        # symmetric relative error of the halves against their mean
        mean = 0.5 * (a + b)
        d = (a - b) ** 2 / (mean ** 2 + metrics.REL_EPS)
        if m is not None:
            d = d[m]
        rel_mse_between = float(d.mean())
        out[prefix + "relmse_between_halves"] = rel_mse_between
        out[prefix + "rel_rmse_between_halves"] = float(np.sqrt(rel_mse_between))
        out[prefix + "est_rel_rmse_of_full"] = float(np.sqrt(rel_mse_between) / 2)
        out[prefix + "est_relmse_of_full"] = rel_mse_between / 4
    return out


def cache_key(scene_name: str, width: int, height: int, spp: int, seed: int) -> str:
    return f"{scene_name}_{width}x{height}_pt{spp}_seed{seed}_v{__version__}"


def _spp_halves(spp: int) -> tuple[int, int]:
    a = max(1, spp // 2)
    return a, max(1, spp - a)


def cache_folder(scene_name: str, width: int, height: int, spp: int, seed: int, cache_dir=None) -> Path:
    """The reference's folder in the cache (``cache_dir``, else :func:`default_cache_dir`)."""
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    return cache / cache_key(scene_name, width, height, spp, seed)


def is_cached(folder: Path) -> bool:
    return all((folder / f"{k}.exr").is_file() for k in ("half_a", "half_b", "reference"))


def submit_halves(renders, scene, width: int, height: int, *, spp: int, seed: int = 0, progress: bool = False):
    """The two independent halves of :func:`pt_reference` as renders on their way (``renders``:
    :mod:`caustica.experiments.renders`), so that a cluster renders them side by side."""
    return tuple(renders.submit(scene, "pt", spp=s, res=(width, height), seed=sd, progress=progress)
                 for s, sd in zip(_spp_halves(spp), (seed, seed + 1)))


def pt_reference(scene, width: int, height: int, *, spp: int, seed: int = 0, cache_dir=None,
                 threads=None, progress: bool = False, mask=None, log=None, halves=None) -> Reference:
    """caustica's pt at ``spp`` samples (two halves), from the cache or rendered and cached.

    ``halves``: the halves already submitted (:func:`submit_halves`), used when the cache has none.
    """
    from .renders import LocalRenders
    folder = cache_folder(scene.name, width, height, spp, seed, cache_dir)
    files = {k: folder / f"{k}.exr" for k in ("half_a", "half_b", "reference")}
    if is_cached(folder):
        a, b, full = (read_exr(files[k]) for k in ("half_a", "half_b", "reference"))
        if a.shape[:2] == (height, width):
            return Reference(full, f"caustica pt, {spp} spp, cached in {folder}",
                             noise_stats(a, b, mask), a, b)
    if log:
        log(f"rendering the pt reference of {scene.name} at {width}x{height}, {spp} spp "
            f"(once; cached in {folder})")
    sa, sb = _spp_halves(spp)
    if halves is None:
        halves = submit_halves(LocalRenders(threads), scene, width, height, spp=spp, seed=seed, progress=progress)
    (ra, _), (rb, _) = (h.result() for h in halves)
    # the halves' own time, wherever they ran (the scene was loaded before, once)
    render_s = sum(r.stats["timings"]["total_s"] - r.stats["timings"]["scene_load_s"] for r in (ra, rb))
    a, b = ra.image.astype(np.float64), rb.image.astype(np.float64)
    full = (sa * a + sb * b) / (sa + sb)
    try:
        write_exr(files["half_a"], a)
        write_exr(files["half_b"], b)
        write_exr(files["reference"], full)
        write_json(folder / "reference.json", {
            "scene": scene.name, "width": width, "height": height, "method": "pt", "spp": spp,
            "spp_halves": [sa, sb], "seeds": [seed, seed + 1], "version": __version__,
            "render_s": render_s, "noise": noise_stats(a, b)})
    except OSError as exc:
        raise CausticaError(f"cannot write the reference cache {folder}: {exc.strerror or exc}") from None
    return Reference(full.astype(np.float32), f"caustica pt, {spp} spp, rendered in {render_s:.0f} s",
                     noise_stats(a, b, mask), a, b, render_s)


def check_reference_image(img, label: str, mask=None) -> None:
    """A reference must have finite pixels and light, over the image and over the caustic mask: every
    error is relative to it (a zero reference leaves them undefined, NaN in every table and plot)."""
    metrics.require_finite(img, label)
    if not np.any(np.asarray(img, np.float64) != 0):
        raise CausticaError(f"{label}: every pixel is zero; errors relative to it are undefined: give a rendered "
                            f"reference of the scene")
    if mask is not None and np.any(mask) and not np.any(np.asarray(img)[mask] != 0):
        raise CausticaError(f"{label}: every pixel of the caustic mask ({int(np.sum(mask))} pixels) is zero; "
                            f"the caustic's errors relative to it are undefined: give a rendered reference of "
                            f"the scene")


def user_reference(path, width: int, height: int, mask=None) -> Reference:
    """An EXR given by the user, with its noise if halves or a JSON sidecar sit beside it.

    Refused (CausticaError) when its size is not the experiment's or when
    :func:`check_reference_image` refuses it (over ``mask`` too, when given).
    """
    p = Path(path)
    img = read_exr(p)
    if img.shape[:2] != (height, width):
        raise CausticaError(f"--reference {p}: it is {img.shape[1]}x{img.shape[0]} but the experiment "
                            f"renders {width}x{height}; give --res {img.shape[1]}")
    check_reference_image(img, f"--reference {p}", mask)
    ref = Reference(img, str(p))
    pa, pb = p.with_name(p.stem + "_a.exr"), p.with_name(p.stem + "_b.exr")
    if pa.is_file() and pb.is_file():
        ref.half_a, ref.half_b = read_exr(pa), read_exr(pb)
        ref.noise = noise_stats(ref.half_a, ref.half_b, mask)
    if p.with_suffix(".json").is_file():
        try:
            side = json.loads(p.with_suffix(".json").read_text())
            if isinstance(side.get("spp"), int) and side["spp"] > 0:
                ref.spp = side["spp"]
            ref.renderer = str(side.get("renderer", ""))
            est = side.get("noise", {}).get("est_rel_rmse_of_full")
            if est is not None and not ref.noise:
                ref.noise = {"est_rel_rmse_of_full": float(est), "from": "the reference's JSON sidecar"}
        except (OSError, ValueError, AttributeError, TypeError):
            pass
    return ref
