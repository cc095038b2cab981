"""The command line: ``caustica render | photons | scenes | methods``.

Every error caused by input (a bad scene, a bad parameter) prints one line
``caustica: error: ...`` and exits with status 2; nothing is written then.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from . import __version__
from .errors import CausticaError, ParameterError

EXIT_USAGE = 2


def _method_param_specs():
    """Every method's parameters, one flag per name (methods share e.g. --max-bounces)."""
    from . import methods
    specs = {}
    for cls in methods.available().values():
        for p in cls.params:
            if p.name in specs:
                specs[p.name][1].append(cls.name)
            else:
                specs[p.name] = (p, [cls.name])
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
    group = r.add_argument_group("method parameters (each belongs to the methods named)")
    allowed = set(method_names)
    for name, (p, owners) in sorted(_method_param_specs().items()):
        owners = [o for o in owners if o in allowed]
        if not owners:
            continue
        kw = {"type": p.type} if p.type is not bool else {"type": str}
        if p.choices:
            kw["choices"] = p.choices
        group.add_argument(p.flag, dest=f"param_{name}", default=None,
                           metavar=None if p.choices else p.type.__name__.upper(),
                           help=f"{p.help} (default {p.default}; {', '.join(owners)})", **kw)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``caustica: error: ...`` and exit status 2."""

    def error(self, message):
        print(f"caustica: error: {message} (see '{self.prog} --help')", file=sys.stderr)
        sys.exit(EXIT_USAGE)


def _check_output_folder(path: Path) -> None:
    folder = Path(path).parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"-o {path}: cannot create the folder {folder}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK):
        raise ParameterError(f"-o {path}: the folder {folder} is not writable")


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
                        "output image path, .exr (default: out/<scene>_<method>.exr); "
                        "the .png and .json go beside it")
    r.add_argument("--exposure", type=float, default=0.0, help="PNG preview exposure in stops (default 0)")

    ph = sub.add_parser("photons", help="picture where photons and streams land",
                        description="Trace the photon map(s) of a photon method and write a PNG of the "
                                    "stored records projected into the camera view, coloured by power: "
                                    "pm shows the global | caustic map, spm the leading | associated photons.")
    _add_render_options(ph, ["pm", "spm"], "spm", "output PNG path (default: out/<scene>_<method>_photons.png)")

    sub.add_parser("scenes", help="list the built-in scenes")
    sub.add_parser("methods", help="list the methods and their parameters")
    return parser


def _cmd_render(args) -> int:
    from .api import load_scene, render
    from .imageio import output_paths
    params = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    defines = _parse_defines(args.defines)
    if args.output is None:
        stem = Path(args.scene).stem if args.scene.endswith(".xml") else args.scene
        args.output = f"out/{stem}_{args.method}.exr"
    _check_output_folder(output_paths(args.output)[0])  # refuse before spending time rendering
    scene = load_scene(args.scene, **defines)
    result = render(scene, args.method, spp=args.spp, res=args.res, seed=args.seed,
                    threads=args.threads, progress=not args.quiet, **params)
    try:
        exr, png, js = result.save(args.output, exposure_stops=args.exposure)
    except OSError as exc:
        raise CausticaError(f"-o {args.output}: cannot write the output: {exc.strerror or exc}") from None
    if not args.quiet:
        t = result.stats["timings"]
        print(f"{scene.name}: {result.width}x{result.height} {args.method} in {t['total_s']:.2f} s "
              f"-> {exr}, {png}, {js}")
    return 0


def _cmd_photons(args) -> int:
    from .api import load_scene, progress_factory, resolve_settings
    from .imageio import write_png
    from .photon_view import photon_picture
    params = {k[len("param_"):]: v for k, v in vars(args).items() if k.startswith("param_") and v is not None}
    if args.output is None:
        stem = Path(args.scene).stem if args.scene.endswith(".xml") else args.scene
        args.output = f"out/{stem}_{args.method}_photons.png"
    if Path(args.output).suffix.lower() != ".png":
        raise ParameterError(f"-o {args.output}: the photon picture is a .png file")
    _check_output_folder(Path(args.output))
    scene = load_scene(args.scene, **_parse_defines(args.defines))
    scene, cls, settings = resolve_settings(scene, args.method, spp=args.spp, res=args.res, seed=args.seed,
                                            threads=args.threads, **params)
    picture, stats = photon_picture(scene, cls, settings, progress_factory(not args.quiet))
    write_png(args.output, picture)
    if not args.quiet:
        print(f"{scene.name}: {stats['photons_stored']:,} photons stored ({' | '.join(stats['panels'])}) "
              f"-> {args.output}")
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
            print(f"  {p.flag:22s} {p.help} (default {p.default})")
    return 0


def main(argv=None) -> int:
    try:
        parser = _build_parser()
        args = parser.parse_args(argv)
        if args.command == "render":
            return _cmd_render(args)
        if args.command == "photons":
            return _cmd_photons(args)
        if args.command == "scenes":
            return _cmd_scenes()
        if args.command == "methods":
            return _cmd_methods()
        parser.print_help()
        return EXIT_USAGE
    except CausticaError as exc:
        print(f"caustica: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("caustica: interrupted; a file being written when it happened was left as it was",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
