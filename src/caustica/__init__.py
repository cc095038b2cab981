"""caustica: a renderer for caustics built around streamed photon mapping."""
from __future__ import annotations

__version__ = "0.1.0"
