"""The Python API: ``load_scene`` and ``render``.

>>> import caustica
>>> scene = caustica.load_scene("cornell-diacaustic", res=128)
>>> result = caustica.render(scene, method="pt", spp=16, seed=1)
>>> result.save("out/diacaustic.exr")
"""
from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np

from . import checkpoint as ckpt
from . import driver, methods
from .bsdfs import DELTA, DIFFUSE_REFLECTION, GLOSSY_REFLECTION, GLOSSY_TRANSMISSION, SMOOTH
from .errors import ParameterError, RenderError, SceneError, quoted
from .film import FILM_BYTES_PER_PIXEL, IMAGE_BYTES_PER_PIXEL
from .version import __version__
from .jit import default_threads
from .limits import MAX_PIXELS
from .memory import check_budget
from .methods.params import COMMON, COMMON_PARAMS, Settings
from .result import RenderResult, peak_memory_bytes
from .scene import load_scene_description
from .scene.description import MATERIAL_NAMES, MIXTURES, ROUGHPLASTIC, WRAPPERS
from .tables import Scene, compile_scene



def load_scene(path_or_name, **defaults) -> Scene:
    """Load an XML scene file or a built-in scene (``caustica scenes`` lists them).

    Keyword arguments are Mitsuba-style ``-D name=value`` defaults, e.g. ``res=256``.
    """
    if not isinstance(path_or_name, (str, os.PathLike)) or isinstance(os.fspath(path_or_name), bytes):
        raise ParameterError(f"load_scene: {quoted(path_or_name)} is not a scene file name or a built-in scene "
                             f"name (a str or os.PathLike)")
    t0 = time.perf_counter()
    desc = load_scene_description(path_or_name, **defaults)
    t1 = time.perf_counter()
    scene = compile_scene(desc)
    scene.timings["scene_parse_s"] = t1 - t0
    scene.timings["scene_load_s"] = time.perf_counter() - t0
    return scene


def progress_factory(show: bool):
    """A tqdm-like constructor: real bars on a terminal when ``show``, silence otherwise."""
    if not show:
        return driver.QuietBar
    from tqdm import tqdm

    def bar(total, desc, unit="it"):
        return tqdm(total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True,
                    file=sys.stderr, disable=not sys.stderr.isatty())
    return bar


def _parse_res(res):
    """(width, height) of ``res``: W, (W, H) or "WxH" with W and H integers (not True, not 16.5)."""
    if res is None:
        return None, None
    if isinstance(res, (tuple, list)) and len(res) == 2:
        sizes = list(res)
    elif isinstance(res, str):
        sizes = res.lower().split("x") if "x" in res.lower() else [res, res]
    else:
        sizes = [res, res]
    try:
        if len(sizes) != 2 or any(isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer, str))
                                  for v in sizes):
            raise ValueError
        return int(sizes[0]), int(sizes[1])
    except ValueError:
        raise ParameterError(f"--res: {quoted(res)} is not W or WxH with whole numbers (e.g. 512, (640, 480) or "
                             f"'640x480')") from None


def check_common(*, spp, width, height, seed, threads, film_source: str | None = None,
                 bytes_per_pixel: int = IMAGE_BYTES_PER_PIXEL) -> Settings:
    """spp, width, height, seed and threads converted and checked (caustica.limits), the image's memory too.

    ``film_source`` ("file:line") when the size is the scene's film rather than --res.
    """
    common = methods.params.resolve("common", COMMON_PARAMS, dict(spp=spp, width=width, height=height,
                                                                  seed=seed, threads=threads))
    if common.width is None or common.height is None or common.spp is None:
        raise ParameterError("--res and --spp need a value")   # only reachable from Python
    if common.threads is None:
        common = common.replace(threads=default_threads())
    w, h = common.width, common.height
    what, hint = f"a {w}x{h} image", "lower --res"
    if film_source:  # the scene's film: name its file and line
        what = f"{film_source}: <film>: {what}"
        hint = "lower the film's width and height, or pass --res"
    if w * h > MAX_PIXELS:
        raise ParameterError(f"{what} has {w * h:,} pixels, more than the {MAX_PIXELS:,} (int32) the kernels "
                             f"can index; {hint}")
    check_budget(w * h * bytes_per_pixel, what, hint)
    return common


def check_bsdfs(cls, scene) -> None:
    """Refuse a scene with a BSDF the method does not render, which would be a silently wrong image.

    Each method declares what it renders beyond diffuse surfaces, mirrors and glass:
    ``renders_glossy = True`` — every BSDF (``pt``); ``passes_glossy = True`` — glossy BSDFs without a
    diffuse lobe (roughconductor, roughdielectric), which its camera paths and photons pass by sampling
    (``pm``, ``sppm``; ``spm``, ``pspm``, whose streams meet them as mirrors); ``renders_coated = True`` — a delta coating over a diffuse lobe (plastic:
    every photon method); ``renders_mixtures = True`` — mask and blendbsdf, resolved
    at each hit to one of their parts (every method; a stream's associated photons each resolve their own);
    ``renders_normal_maps = True`` — normalmap and bumpmap (``pt``; every photon method: its visible points under a
    map weight each photon, or stream record, by the BSDF in the perturbed frame, except under a delta coating, and
    its photons, or a stream's leading photon, scatter there by the adjoint wrapped BSDF);
    ``renders_rough_coated = True`` — a glossy coating over a separable diffuse lobe (roughplastic: every photon
    method, its lobes apart as plastic's); ``evaluates_bsdfs = True`` — other glossy
    lobes beside a diffuse one (pplastic, principled, principledthin), whose visible point (sppm) or k-nearest
    estimate (pm) weights each photon, and each shadow ray of its direct light, by the BSDF at the photon's (ray's)
    direction (every photon method), the photons and lights of both sides where a diffuse lobe transmits; a narrow
    glossy lobe, or a glossy transmission, a camera path takes apart first (bsdfs.splits_lobes), the point then
    weighing by the diffuse lobes alone.
    """
    for mat in scene.description.materials:
        if mat.kind in WRAPPERS and not getattr(cls, "renders_normal_maps", False):
            raise SceneError(f"{mat.source}: <bsdf type=\"{MATERIAL_NAMES[mat.kind]}\">: method {cls.name} does not "
                             f"render normalmap or bumpmap yet; use --method pt")
        if mat.kind in WRAPPERS and not getattr(cls, "renders_glossy", False):
            inner = mat.nested[0]
            if scene.materials.flags[inner] & DELTA and scene.materials.flags[inner] & DIFFUSE_REFLECTION:
                raise SceneError(f"{mat.source}: <bsdf type=\"{MATERIAL_NAMES[mat.kind]}\">: method {cls.name} "
                                 f"does not render a delta coating over a diffuse lobe (plastic) under a normal or "
                                 f"bump map yet (its visible points there weight each photon by the BSDF, which "
                                 f"holds no delta lobe); use --method pt")
        if mat.kind in MIXTURES and not getattr(cls, "renders_mixtures", False):
            raise SceneError(f"{mat.source}: <bsdf type=\"{MATERIAL_NAMES[mat.kind]}\">: method {cls.name} does not "
                             f"render mask or blendbsdf yet (its streams would place their associated photons "
                             f"on a surface that is partly absent or of another BSDF); use --method pt, pm or sppm")
    if getattr(cls, "renders_glossy", False):
        return
    flags_of = scene.materials.flags
    for mat in scene.description.materials:
        parts = [k for k in mat.nested if flags_of[k] & DIFFUSE_REFLECTION] if mat.kind in MIXTURES else []
        coated = [k for k in parts if flags_of[k] & DELTA or scene.materials.kind[k] == ROUGHPLASTIC]
        if len(parts) == 2 and parts[0] != parts[1] and coated:
            raise SceneError(f"{mat.source}: <bsdf type=\"blendbsdf\">: method {cls.name} does not render a blend "
                             f"of a coated diffuse lobe (plastic, roughplastic) with another diffuse lobe yet (a photon's record "
                             f"carries the factor of the part it met, which the other part's visible points would "
                             f"read); use --method pt")
    for mat, flags in zip(scene.description.materials, scene.materials.flags):
        where = f"{mat.source}: " if mat.source else ""
        name = MATERIAL_NAMES[mat.kind]
        if mat.kind in MIXTURES + WRAPPERS:
            continue   # resolved at each hit to one of its parts, each a material of its own, checked as such
        if flags & (GLOSSY_REFLECTION | GLOSSY_TRANSMISSION):
            if mat.kind == ROUGHPLASTIC and getattr(cls, "renders_rough_coated", False):
                continue
            if flags & DIFFUSE_REFLECTION and getattr(cls, "evaluates_bsdfs", False):
                continue
            if flags & DIFFUSE_REFLECTION:
                raise SceneError(f"{where}<bsdf type=\"{name}\">: method {cls.name} does not render a glossy lobe "
                                 f"beside a diffuse one yet (its gather would treat both as Lambertian); use "
                                 f"--method pt, pm, sppm, spm or pspm")
            if not getattr(cls, "passes_glossy", False):
                raise SceneError(f"{where}<bsdf type=\"{name}\">: method {cls.name} does not render glossy BSDFs "
                                 f"yet; use --method pt, pm, sppm, spm or pspm")
        if flags & DELTA and flags & SMOOTH and not getattr(cls, "renders_coated", False):
            raise SceneError(f"{where}<bsdf type=\"{name}\">: method {cls.name} does not render "
                             f"a delta coating over a diffuse lobe yet (its streams would lose the coating's "
                             f"reflection); use --method pt, pm or sppm")


def resolve_settings(scene, method: str, *, spp=None, res=None, seed: int = 0, threads=None,
                     multi_pass: bool = False, **params):
    """(scene, method class, settings): every render setting checked and defaulted in one place.

    ``multi_pass``: the render runs several passes (--passes, --time); ``spp`` is then
    per pass and defaults to 1.
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    cls = methods.get(method)
    check_bsdfs(cls, scene)
    width, height = _parse_res(res)
    width = scene.width if width is None else width
    height = scene.height if height is None else height
    if spp is None:
        # pt follows the scene's sampler; the photon methods default to the paper's one
        # camera ray per pixel (their direct light already takes n x n shadow rays);
        # a pass of a multi-pass render takes one sample per pixel.
        spp = 1 if multi_pass else (getattr(cls, "default_spp", None) or scene.spp)
    per_pixel = getattr(cls, "bytes_per_pixel", IMAGE_BYTES_PER_PIXEL)
    if multi_pass:  # the film of several passes holds up to MAX_FILM_IMAGES float64 images, not one
        per_pixel += FILM_BYTES_PER_PIXEL - 24
    common = check_common(spp=spp, width=width, height=height, seed=seed, threads=threads,
                          film_source=scene.description.camera.film_source if res is None else None,
                          bytes_per_pixel=per_pixel)
    settings = methods.params.resolve(method, cls.params, methods.scene_params(cls, scene.description, params))
    # Work arrays each worker thread allocates, sized by a parameter (e.g. the k-nearest search's).
    for p in cls.params:
        if p.scratch and settings[p.name]:
            check_budget(common.threads * settings[p.name] * p.scratch,
                         f"{p.flag} {settings[p.name]:,} on {common.threads} threads "
                         f"({p.scratch} bytes per unit per thread)", f"lower {p.flag} or --threads")
    return scene, cls, settings.merged(common)



def _rfilter_stats(rf) -> dict:
    """The film's reconstruction filter as the sidecar records it: its type and the parameter it takes."""
    if rf.kind == "tent":
        return {"type": "tent", "radius": rf.radius}
    if rf.kind == "gaussian":
        return {"type": "gaussian", "stddev": rf.stddev}
    return {"type": rf.kind}


def render(scene, method: str = "pt", *, spp: int | None = None, res=None, seed: int = 0,
           threads: int | None = None, progress: bool = False, passes: int | None = None,
           time_s: float | None = None, checkpoint=None, aov=(), dask=None, workers: int | None = None,
           **params) -> RenderResult:
    """Render ``scene`` (a Scene, a path or a built-in name) with ``method``.

    spp: samples per pixel (default: the scene's sampler for pt, 1 for the photon
    methods, as in the paper; per pass, default 1, when rendering several passes);
    res: W, (W, H) or "WxH" (default: the scene's film); seed: the random seed (the
    same seed gives the same image whatever the thread count); threads: worker threads
    (default: all cores); progress: show progress bars on a terminal.
    Progressive methods (pt, sppm, pspm) also take passes: passes to render;
    time_s: a time budget in seconds (passes run until the next would cross it);
    checkpoint: a file the state is saved to (every 5 s and at the end) and resumed from when it
    exists; aov: names of extra per-pixel images ("radius", "count") put in
    ``result.aovs``.  params: the method's own parameters (``caustica methods``
    lists them).  Ctrl-C during a multi-pass render returns the passes finished so far
    (``stats["interrupted"]``).
    dask: a Dask scheduler's address (or a ``distributed.Client``) to render the passes on;
    workers: start a local cluster of that many worker processes instead.  Either gives
    the bits of a local render of the same passes (:mod:`caustica.cluster`).
    """
    t_start = time.perf_counter()
    preloaded = isinstance(scene, Scene)
    cls = methods.get(method)
    plan = driver.check_plan(cls, passes, time_s, checkpoint)
    aov = check_aovs(cls, aov)
    scene, cls, settings = resolve_settings(scene, method, spp=spp, res=res, seed=seed, threads=threads,
                                            multi_pass=plan.multi, **params)
    cluster_log = None
    if plan.checkpoint is not None:
        ckpt.check_path(plan.checkpoint, inputs=scene.description.files)
    with ckpt.locked(plan.checkpoint):
        if dask is None and workers is None:
            state, log = driver.run(cls, scene, settings, plan, progress_factory(progress))
        else:
            from . import cluster
            cluster.check_args(dask, workers)
            if threads is not None:
                raise ParameterError("--threads sizes the local thread pool; on a cluster each task runs on one "
                                     "worker thread (start workers with 'dask worker --nthreads T' to run T at once)")
            check_distributable(cls, settings, plan)
            with cluster.connect(dask, workers) as cl:
                passes = cluster.DaskPasses(cl, cls, scene, settings, plan)   # the same loop, passes as Dask tasks
                state, log = driver.run(cls, scene, settings, plan, progress_factory(progress), passes)
                cluster_log = passes.clog.to_json(cl.address)
    image = cls.image(scene, settings, state)
    require_finite(image, method, state.passes if plan.multi else None)
    stats = dict(log.counters)
    stats.update(cls.final_stats(scene, settings, state))
    width, height, spp, threads = settings.width, settings.height, settings.spp, settings.threads
    timings = {"scene_load_s": scene.timings.get("scene_load_s", 0.0)}
    timings.update(log.timings)
    # total_s covers the scene load too, also when the scene was loaded before render().
    timings["total_s"] = time.perf_counter() - t_start + (timings["scene_load_s"] if preloaded else 0.0)
    out = {
        "method": method,
        "scene": scene.name,
        "parameters": {k: settings[k] for k in settings if k not in COMMON},
        "spp": spp,
        "seed": seed,
        "width": width,
        "height": height,
        "version": __version__,
        "threads": threads,
        "timings": timings,
        "integrator_note": scene.description.integrator_note(method, settings),
        "media_note": scene.description.media_note(method),
        "scene_notes": list(scene.description.loader_notes),
        "rfilter": _rfilter_stats(scene.description.camera.rfilter),
        **stats,
    }
    if plan.multi:
        out["passes"] = state.passes
        out["passes_this_run"] = len(log.pass_seconds)
        out["pass_seconds"] = log.pass_seconds
        out["time_budget_s"] = plan.time_s
        out["interrupted"] = log.interrupted
        if log.interrupted:
            out["interrupted_by"] = signal.Signals(log.interrupt_signal or signal.SIGINT).name
        if plan.checkpoint is not None:
            out["checkpoint"] = plan.checkpoint
            out["resumed_from_pass"] = log.resumed_from
    if cluster_log is not None:
        out["cluster"] = cluster_log
        out["threads"] = cluster_log["worker_threads"]   # the threads that rendered, not this process's
    out["peak_memory_bytes"] = peak_memory_bytes()
    out["peak_memory_mb"] = out["peak_memory_bytes"] / 1e6
    aovs = {name: cls.aov(scene, settings, state, name) for name in aov}
    return RenderResult(image, out, aovs, inputs=tuple(scene.description.files))


def require_finite(image, method: str, passes: int | None) -> None:
    """Refuse an image with NaN or infinite pixels: no render returns (or writes) one as a success.

    The one check every render's image passes through, whatever the method, the schedule or the
    cluster; it names the method, the passes and how many pixels are wrong.
    """
    finite = np.isfinite(image).all(axis=-1)
    bad = int(finite.size - np.count_nonzero(finite))
    if bad:
        nan = int(np.isnan(image).any(axis=-1).sum())
        when = f" after {passes} pass{'es' if passes != 1 else ''}" if passes is not None else ""
        raise RenderError(f"{method}: the image{when} has {bad:,} of {finite.size:,} pixels that are not finite "
                          f"({nan:,} NaN, {bad - nan:,} infinite), so no image was written; unless a parameter is "
                          f"extreme this is a bug: please report it with the command")


def check_distributable(cls, settings, plan) -> None:
    """One-line errors for a render a cluster cannot take apart (before connecting)."""
    if not getattr(cls, "progressive", False):
        raise ParameterError(f"--dask/--workers: '{cls.name}' renders in one shot; a cluster renders the passes of "
                             f"pt, sppm and pspm")
    if not cls.independent(settings):
        raise ParameterError(f"--dask/--workers: {cls.name} --schedule pixel updates every pixel's radius after "
                             f"each pass, so its passes cannot run apart; --schedule global (one radius per pass, "
                             f"Knaus & Zwicker 2011) can")
    if plan.passes is None and plan.time_s is None:
        raise ParameterError("--dask/--workers: say how long to render with --passes N or --time SECONDS "
                             "(a cluster renders passes)")


def check_aovs(cls, aov) -> tuple:
    """The names of the extra images asked for (a comma-separated string or a list of names), each one of
    the method's ``aovs``: an AOV is a name, never a path."""
    if isinstance(aov, str):
        aov = [a.strip() for a in aov.split(",") if a.strip()]
    elif aov is None:
        aov = ()
    elif not isinstance(aov, (list, tuple)) or not all(isinstance(a, str) for a in aov):
        raise ParameterError(f"--aov: {quoted(aov)} is not a comma-separated string or a list of names")
    aov = tuple(dict.fromkeys(aov))   # each once, in the order given
    offered = getattr(cls, "aovs", ())
    for name in aov:
        if name not in offered:
            what = ", ".join(offered) if offered else "none"
            raise ParameterError(f"--aov: {quoted(name)} is not an image method '{cls.name}' makes (it makes: {what})")
    return aov
