"""Reading a bitmap texture's image file into linear RGB texels, as Mitsuba 3's ``bitmap`` texture does.

OpenEXR files (``.exr``) are linear and read with OpenEXR (:func:`caustica.imageio.read_exr`); every other file
(PNG, JPEG, BMP, TGA, ...) with Pillow.  Integer images are sRGB-encoded: each texel is decoded to linear with the
sRGB curve unless ``raw`` (Mitsuba's ``raw=true``, for data that is not a colour).  A grey image becomes three
equal channels; alpha is dropped.  An image smaller than 2 x 2 is padded by repeating its edge, so that bilinear
filtering has a cell (Mitsuba pads such images too).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import CausticaError, SceneError, quoted

#: The most texels one texture may hold (float32 RGB: 3 GB at this size).
MAX_TEXELS = 1 << 28


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (IEC 61966-2-1), on values in [0, 1]."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def _pillow_image(path: Path) -> tuple[np.ndarray, bool]:
    """(array (h, w, c) float64 in [0, 1] or as stored for float images, whether it is integer-coded)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            img.load()
            mode = img.mode
            if mode in ("F",):
                return np.asarray(img, dtype=np.float64)[..., None], False
            if mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):
                a = np.asarray(img).astype(np.float64)
                return (a / 65535.0)[..., None], True
            if mode in ("L", "LA", "1"):
                img = img.convert("L")
            elif mode != "RGB":
                img = img.convert("RGB")   # palette, RGBA, CMYK, YCbCr, ...: RGB (alpha dropped)
            a = np.asarray(img, dtype=np.float64) / 255.0
            return (a[..., None] if a.ndim == 2 else a), True
    except UnidentifiedImageError:
        raise SceneError(f"texture file '{path}' is not an image Pillow can read (PNG, JPEG, BMP, TGA, ...; "
                         f"OpenEXR files need the .exr suffix)") from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise SceneError(f"texture file '{path}' cannot be read as an image: {quoted(exc, 120)}") from None


def read_texels(path: str | Path, raw: bool = False) -> np.ndarray:
    """The image at ``path`` as float32 (height, width, 3) linear RGB, row 0 the image's top row.  SceneError naming
    the file when it cannot be read, is empty, too large or holds a value that is not finite."""
    path = Path(path)
    if path.suffix.lower() == ".exr":
        from ..imageio import read_exr
        try:
            a = read_exr(path).astype(np.float64)
        except CausticaError as exc:
            raise SceneError(f"texture file '{path}': {exc}") from None
    else:
        a, coded = _pillow_image(path)
        if coded and not raw:
            a = srgb_to_linear(a)
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise SceneError(f"texture file '{path}' holds no pixels")
    if a.shape[0] * a.shape[1] > MAX_TEXELS:
        raise SceneError(f"texture file '{path}' is {a.shape[1]:,} x {a.shape[0]:,} pixels, more than the "
                         f"{MAX_TEXELS:,} a texture may hold")
    if a.shape[2] == 1:
        a = np.repeat(a, 3, axis=2)
    a = a[..., :3]
    if not np.all(np.isfinite(a)):
        raise SceneError(f"texture file '{path}' holds a value that is not a finite number")
    if a.shape[0] < 2 or a.shape[1] < 2:
        a = np.pad(a, ((0, max(0, 2 - a.shape[0])), (0, max(0, 2 - a.shape[1])), (0, 0)), mode="edge")
    return np.ascontiguousarray(a, dtype=np.float32)
