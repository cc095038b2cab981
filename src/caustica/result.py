"""What a render returns: the linear image plus the statistics SPEC §5 asks every render to report."""
from __future__ import annotations

import base64
import html
import os
import resource
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import imageio

__all__ = ["RenderResult", "peak_memory_bytes"]


def peak_memory_bytes() -> int:
    """Peak resident memory of this process so far, in bytes (ru_maxrss is KiB on Linux, bytes on macOS)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(rss) if sys.platform == "darwin" else int(rss) * 1024


@dataclass
class RenderResult:
    """A finished render: `image` (float32 H×W×3, linear RGB) and `stats`.

    `stats` holds what the JSON sidecar reports: method, parameters, seed, version, width,
    height, timings per phase in seconds, photon/stream counts, photon map memory and peak
    memory. `version`, `width` and `height` are filled in if the renderer left them out.
    """

    image: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)
    #: extra per-pixel images (``--aov``), name -> float32 H×W (e.g. the final gather radius)
    aovs: dict[str, np.ndarray] = field(default_factory=dict)
    #: The files the render read (the scene file, its meshes): `save` never writes over one.
    inputs: tuple[Path, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        from .version import __version__

        img = np.asarray(self.image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"RenderResult.image must be H×W×3, got shape {img.shape}")
        self.image = np.ascontiguousarray(img, dtype=np.float32)
        self.stats = dict(self.stats)  # never mutate the caller's dict
        self.inputs = tuple(Path(p) for p in self.inputs)
        self.stats.setdefault("version", __version__)
        self.stats.setdefault("width", int(self.image.shape[1]))
        self.stats.setdefault("height", int(self.image.shape[0]))

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    def to_srgb8(self, exposure_stops: float = 0.0) -> np.ndarray:
        """The sRGB 8-bit preview (uint8 H×W×3) at the given exposure."""
        return imageio.to_srgb8(self.image, exposure_stops)

    def save(self, path: str | os.PathLike[str], exposure_stops: float = 0.0, *,
             inputs=None) -> tuple[Path, Path, Path]:
        """Write name.exr, name.png (preview at `exposure_stops`) and name.json as one set.

        `path` may end in .exr, .png or nothing (see `imageio.output_paths`). All of them (and the AOVs) are
        written to temporaries first and only then renamed into place together
        (`imageio.atomic_write_all`): a failure or an interrupt leaves the previous set whole,
        and no output may be one of `inputs` (default: the files the render read). The exposure
        must be finite, within ±150 stops. The JSON is `stats` plus the output file names and
        the preview exposure. Raises ParameterError or OutputError (nothing replaced then).
        Returns (exr, png, json).
        """
        exposure = imageio.check_exposure(exposure_stops)
        exr, png, js = imageio.output_paths(path)
        sidecar = dict(self.stats)
        sidecar["outputs"] = {"exr": exr.name, "png": png.name, "json": js.name}
        files = [(exr, imageio.exr_writer(self.image)), (png, imageio.png_writer(self.image, exposure))]
        for name, aov in self.aovs.items():
            aov_path = self.aov_path(exr, name)
            sidecar["outputs"][f"aov_{name}"] = aov_path.name
            files.append((aov_path, imageio.exr_writer(np.repeat(np.asarray(aov, np.float32)[:, :, None], 3, 2))))
        sidecar["preview_exposure_stops"] = exposure
        files.append((js, imageio.json_writer(sidecar)))
        imageio.atomic_write_all(files, self.inputs if inputs is None else inputs)
        return exr, png, js

    @staticmethod
    def aov_path(exr: Path, name: str) -> Path:
        """Where AOV ``name`` of the render saved as ``exr`` goes: name.<aov>.exr beside it."""
        return exr.with_name(f"{exr.stem}.{name}.exr")

    def _repr_png_(self) -> bytes:
        """Jupyter shows a RenderResult as its sRGB preview."""
        return imageio.encode_png(self.image)

    def _repr_html_(self) -> str:
        """Jupyter: the preview with a one-line summary (method, size, total time if known)."""
        data = base64.b64encode(self._repr_png_()).decode("ascii")
        parts = [str(self.stats.get("method", "render")), f"{self.width}×{self.height}"]
        timings = self.stats.get("timings")
        if isinstance(timings, dict):
            try:
                parts.append(f"{sum(float(v) for v in timings.values()):.2f} s")
            except (TypeError, ValueError):
                pass
        caption = html.escape(", ".join(parts))
        return (
            f'<figure style="margin:0"><img src="data:image/png;base64,{data}" '
            f'style="image-rendering:pixelated"/><figcaption>{caption}</figcaption></figure>'
        )

    def __repr__(self) -> str:
        return f"RenderResult(method={self.stats.get('method')!r}, {self.width}x{self.height})"
