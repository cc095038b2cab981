"""Image error metrics against a reference, over the whole image or a boolean mask.

All metrics take linear RGB float images (H x W x 3) and an optional boolean H x W
mask (True = pixel counts).  The definitions (also in docs/experiments.md):

* ``rel_mse``: mean over pixels and channels of (t - r)^2 / (r^2 + eps), eps = 1e-2
  (``REL_EPS``; radiances in the paper's scenes are ~0.1-1, so eps only matters for
  near-black pixels).
* ``block_err``: relative RMS error of block means.  The image is cut into
  ``block`` x ``block`` pixel tiles; each tile's mean (over its pixels inside the
  mask) is taken for test and reference, and
  sqrt(sum (bt - br)^2 / sum br^2) over tiles and channels.  Pixel noise averages
  out inside a tile, so this measures bias and blur: what a photon map gets wrong.
* ``ssim``: skimage.metrics.structural_similarity on the sRGB previews (exposure 0,
  clamped to [0, 1], the same encoding as caustica's PNGs), channel_axis=2,
  data_range=1; with a mask, the mean of the SSIM map over the mask.  1 = identical.
* ``mean_err``: the signed relative error of the mean, (sum t - sum r) / sum r over the
  pixels (in the mask) and channels: missing or extra energy (e.g. paths cut off by a
  bounce limit), which no amount of blur hides.
* ``flip``: NVIDIA's FLIP (flip_evaluator) in HDR mode on the linear images (its
  exposure range computed from the reference); with a mask, the mean of the FLIP
  map over the mask.  0 = identical.  NaN for a black reference (brightest luminance
  below 2^-22), where FLIP has no exposure range (and would end the process).

Every metric refuses (CausticaError) images with NaN or infinite pixels.  A metric that is
undefined for the images (an empty mask, a reference that is zero for ``block_err`` and
``mean_err``) is
NaN; `undefined_reason` says why.
"""
from __future__ import annotations

import numpy as np

from ..errors import CausticaError

REL_EPS = 1e-2
METRICS = ("rel_mse", "block_err", "mean_err", "ssim", "flip")
METRIC_LABELS = {"rel_mse": "relMSE", "block_err": "block err", "mean_err": "mean err", "ssim": "SSIM",
                 "flip": "FLIP"}


def _check(test, ref, mask):
    t = np.asarray(test, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    if t.ndim == 2:
        t = np.repeat(t[:, :, None], 3, axis=2)
    if r.ndim == 2:
        r = np.repeat(r[:, :, None], 3, axis=2)
    if t.shape != r.shape or t.ndim != 3 or t.shape[2] != 3:
        raise CausticaError(f"the images differ in size: test {t.shape[1]}x{t.shape[0]}, "
                            f"reference {r.shape[1]}x{r.shape[0]} (render the test with --res to match)")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != t.shape[:2]:
            raise CausticaError(f"the mask is {mask.shape[1]}x{mask.shape[0]}, the images "
                                f"{t.shape[1]}x{t.shape[0]}")
    require_finite(t, "the test image")
    require_finite(r, "the reference")
    return t, r, mask


def require_finite(image, name: str) -> None:
    """CausticaError unless every pixel of `image` is finite: a NaN or infinite pixel has no error
    to measure, and scoring it as black (or dropping it) would hide a broken render."""
    img = np.asarray(image)
    bad = ~np.isfinite(img)
    if img.ndim == 3:
        bad = bad.any(axis=2)
    if bad.any():
        y, x = (int(v) for v in np.argwhere(bad)[0])
        raise CausticaError(f"{name}: {int(bad.sum())} of {bad.size} pixels are not finite (NaN or infinite), "
                            f"the first at x={x}, y={y}; the metrics need finite images")


#: FLIP's HDR mode takes its exposure range from the reference's luminance and, when the brightest
#: pixel is below float32's epsilon (2^-23), finds the range reversed and ends the process. Below
#: twice that, FLIP is reported as undefined (NaN) instead.
FLIP_MIN_REFERENCE = 2.0 ** -22


def _flip_defined(r: np.ndarray) -> bool:
    lum = 0.2126 * r[:, :, 0] + 0.7152 * r[:, :, 1] + 0.0722 * r[:, :, 2]
    return bool(lum.max() >= FLIP_MIN_REFERENCE)


def undefined_reason(name: str, test, ref, mask=None) -> str:
    """In words, why metric `name` (over `mask`, if given) came out NaN for these images."""
    t, r, mask = _check(test, ref, mask)
    if mask is not None and not mask.any():
        return "the mask has no pixels"
    region = "over the mask" if mask is not None else "everywhere"
    if name in ("block_err", "mean_err"):
        return f"the reference is zero {region}, and the error is relative to the reference"
    if name == "ssim":
        return "SSIM needs an image of at least 3x3 pixels"
    if name == "flip" and not _flip_defined(np.maximum(r, 0.0)):
        return ("FLIP takes its exposure range from the reference, whose brightest pixel is black "
                f"(luminance below {FLIP_MIN_REFERENCE:.2g})")
    return "undefined for these images"


def rel_mse(test, ref, mask=None, eps: float = REL_EPS) -> float:
    """Mean of (t - r)^2 / (r^2 + eps) over the pixels (in the mask) and channels."""
    t, r, mask = _check(test, ref, mask)
    e = (t - r) ** 2 / (r ** 2 + eps)
    if mask is not None:
        if not mask.any():
            return float("nan")
        e = e[mask]
    return float(e.mean())


def default_block(width: int, height: int) -> int:
    """Tile size for block means: 1/64 of the smaller side (8 px at 512), at least 2."""
    return max(2, min(width, height) // 64)


def block_means(image, mask, block: int):
    """(tile means H' x W' x 3, tile weights H' x W'): mean over each tile's pixels in the mask."""
    h, w = image.shape[:2]
    hb, wb = -(-h // block), -(-w // block)
    m = np.ones((h, w)) if mask is None else mask.astype(np.float64)
    pad = ((0, hb * block - h), (0, wb * block - w))
    img = np.stack([np.pad(image[:, :, c] * m, pad) for c in range(3)], axis=-1)
    mm = np.pad(m, pad)
    sums = img.reshape(hb, block, wb, block, 3).sum(axis=(1, 3))
    counts = mm.reshape(hb, block, wb, block).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts[:, :, None]
    return means, counts


def block_err(test, ref, mask=None, block: int | None = None) -> float:
    """Relative RMS error of tile means: sqrt(sum (bt - br)^2 / sum br^2) over tiles with pixels in the mask."""
    t, r, mask = _check(test, ref, mask)
    if block is None:
        block = default_block(t.shape[1], t.shape[0])
    bt, n = block_means(t, mask, block)
    br, _ = block_means(r, mask, block)
    keep = n > 0
    if not keep.any():
        return float("nan")
    num = ((bt[keep] - br[keep]) ** 2).sum()
    den = (br[keep] ** 2).sum()
    if den > 0:
        return float(np.sqrt(num / den))
    return 0.0 if num == 0 else float("nan")  # a zero reference: only an equal image has a defined error


def mean_err(test, ref, mask=None) -> float:
    """Signed relative error of the mean: (sum t - sum r) / sum r over the pixels (in the mask) and channels."""
    t, r, mask = _check(test, ref, mask)
    if mask is not None:
        if not mask.any():
            return float("nan")
        t, r = t[mask], r[mask]
    den, num = float(r.sum()), float(t.sum())
    if den > 0:
        return (num - den) / den
    return 0.0 if num == den else float("nan")  # a zero reference: only an equal image has a defined error


def tonemap(image) -> np.ndarray:
    """The sRGB preview of a linear image as floats in [0, 1] (caustica's PNG encoding, exposure 0)."""
    from ..imageio import to_srgb8
    return to_srgb8(image).astype(np.float64) / 255.0


def ssim(test, ref, mask=None) -> float:
    """SSIM (skimage) of the sRGB previews; with a mask, the SSIM map's mean over the mask."""
    from skimage.metrics import structural_similarity
    t, r, mask = _check(test, ref, mask)
    h, w = t.shape[:2]
    win = min(7, h, w)
    if win % 2 == 0:
        win -= 1
    if win < 3:
        return float("nan")
    value, smap = structural_similarity(tonemap(r), tonemap(t), channel_axis=2, data_range=1.0,
                                        win_size=win, full=True)
    if mask is None:
        return float(value)
    if not mask.any():
        return float("nan")
    return float(smap.mean(axis=2)[mask].mean())


def flip(test, ref, mask=None) -> float:
    """HDR-FLIP (flip_evaluator) of the linear images; with a mask, the FLIP map's mean over the mask."""
    import flip_evaluator
    t, r, mask = _check(test, ref, mask)
    t = np.ascontiguousarray(np.maximum(t, 0.0), dtype=np.float32)
    r = np.ascontiguousarray(np.maximum(r, 0.0), dtype=np.float32)
    if not r.any() and not t.any():
        return 0.0
    if not _flip_defined(r):
        return float("nan")
    fmap, mean, _ = flip_evaluator.evaluate(r, t, "HDR", applyMagma=False)
    fmap = np.asarray(fmap).reshape(t.shape[0], t.shape[1], -1).mean(axis=2)
    if mask is None:
        return float(mean)
    if not mask.any():
        return float("nan")
    return float(fmap[mask].mean())


def all_metrics(test, ref, mask=None, *, with_flip: bool = True) -> dict:
    """Every metric over the whole image and (with a mask) over the mask: {'rel_mse': .., 'caustic_rel_mse': ..}.

    SSIM and FLIP maps are computed once and averaged over both regions.
    """
    import flip_evaluator
    from skimage.metrics import structural_similarity
    t, r, mask = _check(test, ref, mask)
    out = {}
    regions = [("", None)] + ([("caustic_", mask)] if mask is not None else [])
    h, w = t.shape[:2]
    win = min(7, h, w)
    win -= 1 - win % 2
    smap = None
    if win >= 3:
        smap = structural_similarity(tonemap(r), tonemap(t), channel_axis=2, data_range=1.0,
                                     win_size=win, full=True)[1].mean(axis=2)
    fmap = None
    if with_flip:
        tf = np.ascontiguousarray(np.maximum(t, 0.0), dtype=np.float32)
        rf = np.ascontiguousarray(np.maximum(r, 0.0), dtype=np.float32)
        if not (rf.any() or tf.any()):
            fmap = np.zeros((h, w))
        elif not _flip_defined(rf):
            fmap = np.full((h, w), np.nan)
        else:
            fmap = np.asarray(flip_evaluator.evaluate(rf, tf, "HDR", applyMagma=False)[0]).reshape(h, w, -1)
            fmap = fmap.mean(axis=2)
    for prefix, m in regions:
        empty = m is not None and not m.any()
        out[prefix + "rel_mse"] = rel_mse(t, r, m)
        out[prefix + "block_err"] = block_err(t, r, m)
        out[prefix + "mean_err"] = mean_err(t, r, m)
        out[prefix + "ssim"] = float("nan") if smap is None or empty else float(
            smap.mean() if m is None else smap[m].mean())
        if with_flip:
            out[prefix + "flip"] = float("nan") if empty else float(fmap.mean() if m is None else fmap[m].mean())
    return out
