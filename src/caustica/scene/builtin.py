"""The built-in scenes (the paper's four test scenes, and the diacaustic one in fog) and the data search path.

The XML files live in the package folder ``scene/builtin/`` together with the small
``half_ring.obj``.  The Stanford bunny is data, not part of the package: mesh files
that are not next to the XML are looked up on a search path (see
:func:`data_search_dirs`), and a missing file gives an error saying where to get it.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import SceneError

BUILTIN_DIR = Path(__file__).resolve().parent / "builtin"

#: The environment variable holding extra data folders (os.pathsep-separated).
DATA_PATH_ENV = "CAUSTICA_DATA_PATH"

_SCENES = {
    "cornell-diacaustic": "a glass sphere (IOR 1.5, radius 4) in the Cornell box: "
                          "the paper's diacaustic scene (Fig. 7 top, Fig. 8, Table 2)",
    "cornell-catacaustic": "a curved mirror (half a cylinder, radius 3.5) in the Cornell box: "
                           "the paper's catacaustic scene (Fig. 7 bottom, Fig. 9, Table 3)",
    "cornell-pyramid": "six white cubes stacked 3-2-1 in the Cornell box: the paper's Fig. 5",
    "cornell-bunny": "the Stanford bunny in the Cornell box: the paper's Fig. 6 "
                     "(needs bunny.ply, not shipped; see CAUSTICA_DATA_PATH)",
    "cornell-diacaustic-fog": "the diacaustic scene filled with a thin fog (mean free path 20, the box's size): "
                              "the light's cone and the sphere's focused beam show (every method renders it; docs/media.md)",
}

#: What to tell users about data files that are not shipped with caustica.
DATA_HINTS = {
    "bunny.ply": ("bunny.ply is the Stanford bunny from the Stanford 3D Scanning Repository "
                  "(https://graphics.stanford.edu/data/3Dscanrep/): download the bunny archive, "
                  "take bunny/reconstruction/bun_zipper.ply and rename it to bunny.ply"),
}


def builtin_scene_names() -> list[str]:
    """The names ``caustica render <name>`` accepts."""
    return list(_SCENES)


def builtin_scene_path(name: str) -> Path:
    """The XML file of a built-in scene; SceneError listing the names for an unknown one."""
    if name not in _SCENES:
        raise SceneError(f"unknown built-in scene '{name}'; built-in scenes: {', '.join(_SCENES)}")
    return BUILTIN_DIR / f"{name}.xml"


def describe_builtin(name: str) -> str:
    """One line for ``caustica scenes``."""
    builtin_scene_path(name)
    return f"{name}: {_SCENES[name]}"


def _repo_data_dirs() -> list[Path]:
    """Existing ``shared/data`` folders beside the folders above the package (the repository's)."""
    return [a / "shared" / "data" for a in Path(__file__).resolve().parents
            if (a / "shared" / "data").is_dir()]


def data_search_dirs(xml_dir: str | Path | None, extra_dirs=()) -> list[Path]:
    """Folders searched for a mesh file, in order.

    $CAUSTICA_DATA_PATH (os.pathsep-separated), the XML file's folder, ``extra_dirs`` (the
    loader passes the main scene file's folder and the scene's ``<path>`` folders, the last
    declared first, as Mitsuba's file resolver does), ../shared/data relative to the current
    directory (as cwd's parent/shared/data), then shared/data beside every folder above the
    installed package (which finds the repository's shared/data).  Duplicates removed.
    """
    dirs: list[Path] = []
    env = os.environ.get(DATA_PATH_ENV, "")
    dirs += [Path(p) for p in env.split(os.pathsep) if p.strip()]
    if xml_dir is not None:
        dirs.append(Path(xml_dir))
    dirs += [Path(d) for d in extra_dirs]
    dirs.append(Path.cwd().parent / "shared" / "data")
    dirs += _repo_data_dirs()
    seen, out = set(), []
    for d in dirs:
        key = os.path.normcase(os.path.abspath(d))
        if key not in seen:
            seen.add(key)
            out.append(d)
    return out


def find_data_file(filename: str, xml_dir: str | Path | None, extra_dirs=(), what: str = "mesh file") -> Path:
    """Resolve a ``filename`` a scene names (a mesh; ``what`` names the kind in the error).

    An absolute path is used as is.  A relative one is tried in each folder of
    :func:`data_search_dirs` (as written, and then by its base name so that
    ``../data/bunny.ply`` is also found in a data folder).  Raises SceneError saying
    what is missing, which folders were searched and how to add one.
    """
    p = Path(filename)
    if p.is_absolute():
        if p.is_file():
            return p
        searched: list[Path] = [p.parent]
    else:
        searched = data_search_dirs(xml_dir, extra_dirs)
        for d in searched:
            for cand in (d / p, d / p.name):
                if cand.is_file():
                    return cand
    msg = (f"{what} '{filename}' not found; searched: "
           f"{', '.join(str(d) for d in searched)}; put it in one of these folders or set "
           f"{DATA_PATH_ENV} to the folder holding it")
    hint = DATA_HINTS.get(p.name.lower())
    if hint:
        msg += f". {hint}"
    raise SceneError(msg)
