"""The command line: ``caustica render | photons | experiment | compare | scenes | methods``.

Every error caused by input (a bad scene, a bad parameter) prints one line
``caustica: error: ...`` and exits with status 2; nothing is written then.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path

from .errors import CausticaError, ClusterError, InterruptedAfterSaving, ParameterError, shorten
from .interrupts import exit_status, sigterm_as_interrupt, signal_of
from .version import __version__

EXIT_USAGE = 2


def _method_param_specs():
    """Every method's parameters, one flag per name (methods share e.g. --max-bounces): name -> [(Param, method)]."""
    from . import methods
    specs = {}
    for cls in methods.available().values():
        for p in cls.params:
            specs.setdefault(p.name, []).append((p, cls.name))
    return specs


def _parse_defines(items):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"-D '{item}': expected name=value (e.g. -D res=256)")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _add_render_options(r, method_names, default_method, output_help):
    """The options shared by ``render`` and ``photons``."""
    r.add_argument("scene", help="a Mitsuba 3 XML file or a built-in scene name (see 'caustica scenes')")
    r.add_argument("--method", "-m", default=default_method, choices=method_names,
                   help=f"rendering method (default: {default_method}); 'caustica methods' describes them")
    r.add_argument("--spp", type=int, help="samples per pixel (default: the scene's sampler for pt, "
                                           "1 for pm and spm as in the paper)")
    r.add_argument("--res", help="image size W or WxH (default: the scene's film)")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same image")
    r.add_argument("--threads", type=int, help="worker threads (default: all cores)")
    r.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE",
                   help="set a scene <default> value, as Mitsuba's -D (repeatable)")
    r.add_argument("-o", "--output", help=output_help)
    r.add_argument("--quiet", "-q", action="store_true", help="no progress bars or summary")
    _add_method_flags(r.add_argument_group("method parameters (each belongs to the methods named)"),
                      method_names, "default")


def _add_cluster_options(group):
    group.add_argument("--dask", metavar="ADDRESS",
                       help="send the work to the Dask scheduler at ADDRESS (e.g. tcp://10.0.0.5:8786; "
                            "start one with 'dask scheduler' and workers with 'dask worker ADDRESS'; tls:// "
                            "uses Dask's TLS settings, distributed.comm.tls.*: docs/cluster.md)")
    group.add_argument("--workers", type=int, metavar="N",
                       help="start a local cluster of N single-threaded worker processes for this run (at most "
                            "the CPUs caustica may use, and N x 360 MB within the memory budget)")


def _add_method_flags(group, method_names, default_word):
    """One flag per parameter of the named methods (``--k``, ``--streams``, ...), stored as param_<name>.

    Methods that share a flag but not its meaning or default are listed with their own.
    """
    allowed = set(method_names)
    for name, owned in sorted(_method_param_specs().items()):
        owned = [(p, m) for p, m in owned if m in allowed]
        if not owned:
            continue
        p = owned[0][0]
        groups = {}
        for q, m in owned:
            shown = "auto" if q.default is None else (f"{q.default:g}" if isinstance(q.default, float)
                                                      else str(q.default))
            groups.setdefault((q.help, shown), []).append(m)
        if len({h for h, _ in groups}) == 1:
            defaults = "; ".join(f"{default_word} {d}: {', '.join(ms)}" for (_, d), ms in groups.items())
            text = f"{p.help} ({defaults})"
        else:
            text = " | ".join(f"{', '.join(ms)}: {h} ({default_word} {d})" for (h, d), ms in groups.items())
        kw = {"type": p.type} if p.type is not bool else {"type": str}
        if p.choices:
            kw["choices"] = p.choices
        group.add_argument(p.flag, dest=f"param_{name}", default=None,
                           metavar=None if p.choices else p.type.__name__.upper(), help=text, **kw)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``caustica: error: ...`` and exit status 2."""

    def error(self, message):
        print(f"caustica: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _output_path(given, default_name: str, quiet: bool) -> str:
    """The output path for ``-o given``: a folder (one that exists, or any path ending in a slash)
    means default_name inside that folder, and says so; no -o means out/default_name."""
    if given is None:
        return f"out/{default_name}"
    if not given:
        raise ParameterError("-o: the output path is empty; give e.g. -o out/render.exr")
    if given.endswith(os.sep) or (os.altsep and given.endswith(os.altsep)) or os.path.isdir(given):
        path = str(Path(given) / default_name)
        if not quiet:
            print(f"caustica: -o {given} is a folder: writing {path} there", file=sys.stderr)
        return path
    return given


def _check_outputs(paths, given, inputs=()) -> None:
    """Refuse, before rendering, outputs that could not be written (see imageio.check_outputs)."""
    from .imageio import check_outputs
    check_outputs(paths, inputs, label=f"-o {shorten(given, 60)}")


def _build_parser():
    from . import methods
    parser = _Parser(
        prog="caustica",
        description="A renderer for caustics: streamed photon mapping (SPM), photon mapping "
                    "(PM, PM + caustic map) and a reference path tracer, on Mitsuba 3 XML scenes.")
    parser.add_argument("--version", action="version", version=f"caustica {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    r = sub.add_parser("render", help="render a scene to EXR + PNG + JSON",
                       description="Render SCENE (an XML file or a built-in name) and write "
                                   "an OpenEXR image, a PNG preview and a JSON sidecar.")
    _add_render_options(r, sorted(methods.available()), "pt",
                        "output image path, .exr (default: out/<scene>_<method>.exr); the .png and "
                        ".json go beside it; a folder (or a path ending in /) means <scene>_<method>.exr in it")
    r.add_argument("--exposure", type=float, default=0.0,
                   help="PNG preview exposure in stops, between -150 and 150 (default 0)")
    prog = r.add_argument_group("progressive rendering (pt, sppm, pspm)")
    prog.add_argument("--passes", type=int, help="passes to render (pt: --spp samples per pixel each, default 1; "
                                                 "sppm/pspm: one visible point per pixel and a photon pass each)")
    prog.add_argument("--time", type=float, dest="time_s", metavar="SECONDS",
                      help="time budget: passes run until the next would end past it (with --passes: "
                           "whichever comes first)")
    prog.add_argument("--checkpoint", metavar="FILE",
                      help="save the state to FILE (.npz) every 5 s, after the last pass and on Ctrl-C or "
                           "SIGTERM (exit 130 / 143, the checkpoint and outputs of the passes finished written); "
                           "if FILE exists, resume from it (same scene and settings; it is checked: its hash, "
                           "dtypes, shapes and values) up to --passes; a lock on .FILE.lock refuses a second "
                           "render with the same FILE")
    prog.add_argument("--aov", metavar="NAMES",
                      help="also write per-pixel images NAME.<aov>.exr: radius (final gather radius) and/or "
                           "count (photon events gathered), comma-separated (sppm, pspm)")
    _add_cluster_options(r.add_argument_group("rendering on a Dask cluster (pt, and sppm/pspm --schedule global; "
                                              "the bits of a local render of the same passes)"))

    ph = sub.add_parser("photons", help="picture where photons and streams land",
                        description="Trace the photon map(s) of a photon method and write a PNG of the "
                                    "stored records projected into the camera view, coloured by power: "
                                    "pm shows the global | caustic map, spm the leading | associated photons.")
    _add_render_options(ph, ["pm", "spm"], "spm", "output PNG path (default: out/<scene>_<method>_photons.png; "
                                                  "a folder means that name in it)")

    ex = sub.add_parser("experiment", help="run the paper's experiments against a converged reference",
                        description="Run the paper's experiments (table1, table2, table3, fig5, fig6, fig8, "
                                    "fig9, merge-ablation, or all; and convergence): render what the paper rendered, measure "
                                    "each image against "
                                    "a converged reference (cached), write CSV and Markdown tables, PNG figures "
                                    "and DIR/report.md. See docs/experiments.md.")
    ex.add_argument("names", nargs="+", metavar="NAME",
                    help="table1 | table2 | table3 | fig5 | fig6 | fig8 | fig9 | merge-ablation | all (the "
                         "paper's and the ablation) | convergence (error against wall time, every method and "
                         "Mitsuba 3 at 5, 10, 30, 90 s; about 35 min; 256x256 unless --res) (several may be given)")
    ex.add_argument("-o", "--output", default="out/experiments", help="output folder (default: out/experiments)")
    ex.add_argument("--quick", action="store_true",
                    help="the same pipeline at 48x48 with a 64-spp reference, a 3-point budget sweep and one seed")
    ex.add_argument("--res", type=int, help="image size (square; default 512, the paper's; 48 with --quick)")
    ex.add_argument("--seed", type=int, default=0, help="random seed of the renders (default 0)")
    ex.add_argument("--seeds", type=int, help="seeds per measured configuration (seed, seed+1, ...): errors are "
                                              "their mean ± s.d. (default 3; 1 with --quick)")
    ex.add_argument("--threads", type=int, help="worker threads (default: all cores)")
    ex.add_argument("--reference", action="append", metavar="[SCENE=]PATH",
                    help="use this EXR as the reference instead of caustica's pt (repeatable; SCENE=PATH for "
                         "one scene; a folder is searched for <scene>_<res>.exr, e.g. Mitsuba's shared/refs)")
    ex.add_argument("--reference-spp", type=int,
                    help="samples per pixel of the pt reference (default 1024; 64 with --quick)")
    ex.add_argument("--repeat", type=int, help="renders per configuration, the time reported is the fastest "
                                               "(default 2; 1 with --quick): times on a busy machine vary")
    ex.add_argument("--cache-dir", help="reference cache folder (default: $CAUSTICA_CACHE/references or "
                                        "~/.cache/caustica/references)")
    ex.add_argument("--quiet", "-q", action="store_true", help="no progress bars or messages")
    _add_cluster_options(ex.add_argument_group(
        "running the renders on a Dask cluster (each render one task on one worker, one render per worker at a "
        "time, on all its threads; the same tables, the workers' own times; see docs/experiments.md)"))
    group = ex.add_argument_group("method parameters (override the paper's in every render that uses them; "
                                  "in Table 1 a swept one fixes that axis)")
    _add_method_flags(group, ("pm", "spm"), "paper:")

    cmp_ = sub.add_parser("compare", help="print error metrics of an image against a reference",
                          description="Print relMSE, block-mean error, SSIM and FLIP of TEST against REF "
                                      "(linear RGB EXRs of the same size), over the whole image and, with "
                                      "--mask, over the mask's nonzero pixels.")
    cmp_.add_argument("test", help="the image to judge (.exr)")
    cmp_.add_argument("ref", help="the reference (.exr)")
    cmp_.add_argument("--mask", help="a PNG; nonzero pixels form the region measured separately")
    cmp_.add_argument("--no-flip", action="store_true", help="skip FLIP (the slowest metric)")

    sub.add_parser("scenes", help="list the built-in scenes")
    sub.add_parser("methods", help="list the methods and their parameters")
    return parser


def _note_integrator(scene, method: str, params: dict) -> None:
    """One line on stderr when the scene's <integrator> is not what this render does, one when a medium's mesh
    faces inwards (SceneDescription.media_note) and one for each thing the loader accepted and renders otherwise
    than Mitsuba would (SceneDescription.loader_notes) -- after the method's checks of the scene, so that a scene the
    method refuses gets its one-line error alone."""
    from . import methods
    from .api import check_bsdfs
    cls = methods.get(method)
    check_bsdfs(cls, scene)
    note = scene.description.integrator_note(
        method, methods.params.resolve(method, cls.params, methods.scene_params(cls, scene.description, params)))
    for line in (note, scene.description.media_note(method), *scene.description.loader_notes):
        if line:
            print(f"caustica: note: {line}", file=sys.stderr)


def _default_stem(scene: str) -> str:
    return Path(scene).stem if scene.endswith(".xml") or os.path.isfile(scene) else scene


def _cmd_render(args) -> int:
    from . import methods
    from .api import check_aovs, load_scene, render
    from .imageio import check_exposure, output_paths
    from .result import RenderResult
    params = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    defines = _parse_defines(args.defines)
    exposure = check_exposure(args.exposure)
    from .cluster import check_args, quiet_cluster_logs
    check_args(args.dask, args.workers)
    if args.dask is not None or args.workers is not None:
        quiet_cluster_logs()
    given = args.output
    args.output = _output_path(given, f"{_default_stem(args.scene)}_{args.method}.exr", args.quiet)
    outputs = list(output_paths(args.output))
    outputs += [RenderResult.aov_path(outputs[0], a) for a in check_aovs(methods.get(args.method), args.aov)]
    _check_outputs(outputs, args.output)  # refuse before spending time loading and rendering
    scene = load_scene(args.scene, **defines)
    _check_outputs(outputs, args.output, scene.description.files)  # never write over an input
    if args.checkpoint is not None:
        from .checkpoint import check_path
        check_path(args.checkpoint, outputs, scene.description.files)
    _note_integrator(scene, args.method, params)
    result = render(scene, args.method, spp=args.spp, res=args.res, seed=args.seed,
                    threads=args.threads, progress=not args.quiet, passes=args.passes, time_s=args.time_s,
                    checkpoint=args.checkpoint, aov=args.aov or (), dask=args.dask, workers=args.workers, **params)
    exr, png, js = result.save(args.output, exposure_stops=exposure, inputs=scene.description.files)
    if not args.quiet:
        t = result.stats["timings"]
        passes = f", {result.stats['passes']} passes" if "passes" in result.stats else ""
        print(f"{scene.name}: {result.width}x{result.height} {args.method} in {t['total_s']:.2f} s{passes} "
              f"-> {exr}, {png}, {js}")
    late = result.stats.get("cluster", {}).get("late_tasks", 0)
    if late:
        print(f"caustica: warning: {late} task(s) had not come back within the --time budget's "
              f"grace and were given up (docs/cluster.md); the image has the {result.stats['passes']} passes merged in "
              f"order before them", file=sys.stderr)
    if result.stats.get("interrupted"):
        by = result.stats.get("interrupted_by", "SIGINT")
        print(f"caustica: interrupted ({by}): wrote the image of the {result.stats['passes']} passes finished"
              + (f" and the checkpoint {args.checkpoint}" if args.checkpoint else ""), file=sys.stderr)
        return exit_status(signal.Signals[by])
    return 0


def _cmd_photons(args) -> int:
    from .api import load_scene, progress_factory, resolve_settings
    from .imageio import write_png
    from .photon_view import photon_picture
    params = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    args.output = _output_path(args.output, f"{_default_stem(args.scene)}_{args.method}_photons.png", args.quiet)
    if Path(args.output).suffix.lower() != ".png":
        raise ParameterError(f"-o {args.output}: the photon picture is a .png file")
    _check_outputs([Path(args.output)], args.output)
    scene = load_scene(args.scene, **_parse_defines(args.defines))
    _check_outputs([Path(args.output)], args.output, scene.description.files)
    scene, cls, settings = resolve_settings(scene, args.method, spp=args.spp, res=args.res, seed=args.seed,
                                            threads=args.threads, **params)
    _note_integrator(scene, args.method, params)
    picture, stats = photon_picture(scene, cls, settings, progress_factory(not args.quiet))
    write_png(args.output, picture, inputs=scene.description.files)
    if not args.quiet:
        print(f"{scene.name}: {stats['photons_stored']:,} photons stored ({' | '.join(stats['panels'])}) "
              f"-> {args.output}")
    return 0


def _cmd_experiment(args) -> int:
    from .experiments import config as experiment_config, runner
    params = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    names = experiment_config.expand(args.names)          # unknown names fail before anything is written
    log = None if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    # Config checks every setting and method parameter (and -o), run() the references, every planned
    # render and the reference cache, all before anything is created.
    config = experiment_config.Config(
        out=args.output, res=args.res, seed=args.seed, quick=args.quick, reference_spp=args.reference_spp,
        references=args.reference or [], params=params, threads=args.threads, cache_dir=args.cache_dir,
        repeat=args.repeat, seeds=args.seeds, progress=not args.quiet, log=log, dask=args.dask, workers=args.workers)
    out = config.out
    _check_outputs([out / "report.md"], args.output)
    try:
        _run_experiments(runner, names, config, args)
    except KeyboardInterrupt as exc:
        raise ExperimentInterrupted(signal_of(exc)) from None
    if not args.quiet:
        print(f"{', '.join(names)} -> {out / 'report.md'}")
    return 0


class ExperimentInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) stopped an experiment: no render cut short was scored, and no table was written after it."""

    def __init__(self, signum: int = signal.SIGINT):
        super().__init__()
        self.signum = int(signum)


def _run_experiments(runner, names, config, args) -> None:
    if args.dask is None and args.workers is None:
        runner.run(names, config)
    else:
        from .cluster import cluster_failures, quiet_cluster_logs
        quiet_cluster_logs()
        try:
            runner.run(names, config)
        except cluster_failures() as exc:
            if isinstance(exc, CausticaError):   # e.g. a full disk (OutputError is an OSError too)
                raise
            where = f"--dask {args.dask}" if args.dask else f"--workers {args.workers}"
            raise ClusterError(f"{where}: the cluster failed during the experiment ({type(exc).__name__}: "
                               f"{str(exc).splitlines()[0] if str(exc) else 'no detail'}); run it again") from None


def _cmd_compare(args) -> int:
    import math

    from .experiments.metrics import METRIC_LABELS, all_metrics, require_finite, undefined_reason
    from .imageio import read_exr, read_png_mask
    test, ref = read_exr(args.test), read_exr(args.ref)
    require_finite(test, args.test)
    require_finite(ref, args.ref)
    mask = read_png_mask(args.mask) if args.mask else None
    values = all_metrics(test, ref, mask, with_flip=not args.no_flip)
    names = [m for m in METRIC_LABELS if m in values]
    print(f"{'region':10s} " + " ".join(f"{METRIC_LABELS[m]:>12s}" for m in names))
    regions = [("whole", "", None)] + ([("mask", "caustic_", mask)] if mask is not None else [])
    for title, prefix, _ in regions:
        print(f"{title:10s} " + " ".join(f"{values[prefix + m]:12.6g}" for m in names))
    if mask is not None:
        print(f"mask: {int(mask.sum())} of {mask.size} pixels")
    for title, prefix, m in regions:
        for name in names:
            if math.isnan(values[prefix + name]):
                print(f"note: {METRIC_LABELS[name]} over the {'mask' if m is not None else 'whole image'} is nan: "
                      f"{undefined_reason(name, test, ref, m)}")
    return 0


def _cmd_scenes() -> int:
    from .scene.builtin import builtin_scene_names, describe_builtin
    for name in builtin_scene_names():
        print(describe_builtin(name))
    return 0


def _cmd_methods() -> int:
    from . import methods
    for name, cls in sorted(methods.available().items()):
        print(f"{name}: {cls.summary}")
        for p in cls.params:
            if p.choices:
                allowed = "|".join(map(str, p.choices))
            else:
                allowed = "true|false" if p.type is bool else p.describe_range()
            default = "auto" if p.default is None else (f"{p.default:g}" if isinstance(p.default, float)
                                                         else p.default)
            print(f"  {p.flag:22s} {p.help} (default {default}{'; ' + allowed if allowed else ''})")
    return 0


def main(argv=None) -> int:
    """The command line; SIGTERM is handled as Ctrl-C while it runs (exit 143, 130 for Ctrl-C)."""
    with sigterm_as_interrupt():
        return _main(argv)


def _main(argv) -> int:
    try:
        parser = _build_parser()
        args = parser.parse_args(argv)
        if args.command == "render":
            return _cmd_render(args)
        if args.command == "photons":
            return _cmd_photons(args)
        if args.command == "experiment":
            return _cmd_experiment(args)
        if args.command == "compare":
            return _cmd_compare(args)
        if args.command == "scenes":
            return _cmd_scenes()
        if args.command == "methods":
            return _cmd_methods()
        parser.print_help()
        return EXIT_USAGE
    except CausticaError as exc:
        print(f"caustica: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ExperimentInterrupted as exc:
        print(f"caustica: interrupted ({signal.Signals(exc.signum).name}): the experiment stopped; no render cut "
              "short was scored, and the tables of the experiment under way were not written (renders saved before "
              "stay)", file=sys.stderr)
        return exit_status(exc.signum)
    except InterruptedAfterSaving as exc:
        print(f"caustica: interrupted ({signal.Signals(exc.signum).name}); {exc.saved} had been written in full",
              file=sys.stderr)
        return exit_status(exc.signum)
    except KeyboardInterrupt as exc:   # Ctrl-C, or SIGTERM (Terminated), before a render had a pass to save
        print(f"caustica: interrupted ({signal.Signals(signal_of(exc)).name}); no output file was replaced",
              file=sys.stderr)
        return exit_status(signal_of(exc))


if __name__ == "__main__":
    sys.exit(main())
