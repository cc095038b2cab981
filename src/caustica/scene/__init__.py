"""Scenes: the Mitsuba-XML loader, the built-in scenes and the scene description types.

:func:`load_scene_description` is the entry point: a built-in scene's name
(``caustica scenes`` lists them) or a path to a Mitsuba 3 XML file.
"""
from __future__ import annotations

from pathlib import Path

from ..errors import SceneError
from .builtin import builtin_scene_names, builtin_scene_path, describe_builtin
from .description import SceneDescription
from .xml_loader import load_scene_file, parse_scene_string

__all__ = ["load_scene_description", "load_scene_file", "parse_scene_string",
           "builtin_scene_names", "builtin_scene_path", "describe_builtin", "SceneDescription"]


def load_scene_description(path_or_name, **defaults) -> SceneDescription:
    """Load a built-in scene by name or an XML file by path.

    defaults: Mitsuba ``-D`` style values for the file's ``$name`` parameters
    (e.g. ``spp=64, res=256``); they are converted to strings and override the
    file's ``<default>`` values.  A built-in scene's ``source`` is its name.
    """
    name = str(path_or_name)
    if isinstance(path_or_name, str) and name in builtin_scene_names():
        desc = load_scene_file(builtin_scene_path(name), defaults)
        desc.source = name
        return desc
    path = Path(path_or_name)
    if path.exists():
        return load_scene_file(path, defaults)
    raise SceneError(f"{name}: no such scene file, and not a built-in scene; "
                     f"built-in scenes: {', '.join(builtin_scene_names())}")
