"""caustica: a renderer for caustics built around streamed photon mapping.

>>> import caustica
>>> result = caustica.render(caustica.load_scene("cornell-diacaustic", res=128), method="pt", spp=16)
>>> result.save("out/diacaustic.exr")
"""
from __future__ import annotations

from .version import __version__  # noqa: E402
from .api import load_scene, render  # noqa: E402
from .errors import CausticaError, ParameterError, SceneError  # noqa: E402
from .result import RenderResult  # noqa: E402

__all__ = ["load_scene", "render", "RenderResult", "CausticaError", "SceneError", "ParameterError",
           "__version__"]
