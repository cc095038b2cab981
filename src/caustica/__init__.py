"""caustica: a renderer for caustics built around streamed photon mapping.

>>> import caustica
>>> result = caustica.render(caustica.load_scene("cornell-diacaustic", res=128), method="pt", spp=16)
>>> result.save("out/diacaustic.exr")

The API is imported on first use (PEP 562): ``import caustica`` alone loads no NumPy or Numba, so
the command line is inside its own Ctrl-C handling before the heavy imports start.
"""
from __future__ import annotations

import importlib

from .version import __version__  # noqa: E402
from .errors import CausticaError, ParameterError, SceneError  # noqa: E402

#: Names the package exports, and the module each comes from (imported when first used).
_LAZY = {"load_scene": "api", "render": "api", "RenderResult": "result"}

__all__ = ["load_scene", "render", "RenderResult", "CausticaError", "SceneError", "ParameterError",
           "__version__"]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    else:
        try:   # a submodule: caustica.methods, caustica.driver, ...
            value = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
