"""Reconstruction filters (Mitsuba 3's ``box``, ``tent`` and ``gaussian``), applied by importance sampling.

Mitsuba splats every sample onto the pixels its filter covers, with weight ``f(x - xi) f(y - yi)``
(the filters are separable), and a pixel's value is ``sum f L / sum f``.  caustica draws instead each
camera sample's position from the filter itself, centred on its pixel (filter importance sampling, as
pbrt-v4 does): every sample has weight 1 and lands in its own pixel's film sum, so every method
gets the same filter with no change to how it accumulates.  For a filter without negative lobes
(all three) both converge to the same image, ``∫ f(s - c) L(s) ds / ∫ f(s - c) ds`` about the pixel
centre ``c``.

The film's edge: Mitsuba (``sample_border`` false, its default) takes samples only inside the film,
so a pixel near the edge averages over the part of its filter inside the film.  Here the filter's
distribution is truncated to the film per axis (the film is a rectangle and the filter separable,
so the truncated 2-D distribution is the product of the truncated 1-D ones): the same image.
With ``sample_border`` the filter is not truncated.

The map from the caller's two uniform numbers to the position is one monotone inverse CDF per axis
(:func:`film_position`), so a stratified or low-discrepancy pair stays stratified in the filter's
measure.  The filters, as Mitsuba 3 defines them (``src/rfilters/*.cpp``):

* ``box``: 1 on [-1/2, 1/2) -- uniform over the pixel, the same arithmetic (and bits) as before
  filters existed: ``px + u``;
* ``tent``: ``max(0, 1 - |x| / r)``, ``radius`` r (default 1 pixel); sampled by the triangle's
  inverse CDF in closed form;
* ``gaussian``: ``max(0, exp(-x² / 2σ²) - exp(-r² / 2σ²))`` with ``stddev`` σ (default 0.5 pixel)
  and r = 4σ (Mitsuba subtracts the value at the cut-off so that the filter reaches 0 there);
  sampled by its inverse CDF, tabulated (1024 steps against the square root of the CDF, linear
  within each: the sampled CDF is within 2e-7 of the filter's), the film's edge placed by the CDF
  written with ``erf``.

Mitsuba's scalar variants evaluate a filter from a 31-step table over [0, r] (the value at each
step's inner end) rather than the formula; its JIT variants use the formula.  The step table moves
a straight edge's response by at most 0.8 % (gaussian) / 0.4 % (tent) of the edge's contrast;
caustica follows the formula.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import kernel

#: Filter kind codes, as the camera passes them to kernels.
BOX = 0
TENT = 1
GAUSSIAN = 2
FILTER_KINDS = {"box": BOX, "tent": TENT, "gaussian": GAUSSIAN}

#: Where Mitsuba cuts the gaussian off, in standard deviations.
GAUSSIAN_CUTOFF = 4.0

_SQRT_HALF_PI = math.sqrt(0.5 * math.pi)
_INV_SQRT2 = 1.0 / math.sqrt(2.0)


def filter_radius(kind: int, radius: float, stddev: float) -> float:
    """The filter's support radius in pixels (box 1/2; the tent's radius; 4 deviations for the gaussian)."""
    if kind == BOX:
        return 0.5
    if kind == GAUSSIAN:
        return GAUSSIAN_CUTOFF * stddev
    return radius


@kernel
def filter_cdf(kind, radius, stddev, x):
    """The filter's integral from 0 to x (not normalised; odd in x), for x in [-radius, radius].

    Measured from the centre, not from -radius, so that differences of two values keep their
    precision for any radius."""
    if kind == TENT:
        return x - x * abs(x) / (2.0 * radius)
    if kind == GAUSSIAN:
        return stddev * _gaussian_cdf(x / stddev)
    return x   # box


# The gaussian in units of its deviation, z = x / σ: always the same shape, exp(-z²/2) - exp(-8) on
# [-4, 4], whatever σ.
_GAUSSIAN_BIAS = math.exp(-0.5 * GAUSSIAN_CUTOFF ** 2)


@kernel
def _gaussian_cdf(z):
    return _SQRT_HALF_PI * math.erf(z * _INV_SQRT2) - _GAUSSIAN_BIAS * z


def _gaussian_inverse_table(n: int) -> np.ndarray:
    """z (in [-4, 0]) where the standard gaussian's CDF is v², at v = sqrt(1/2) i / n for i = 0 .. n.

    Tabulated against the square root of the CDF because at the cut-off the filter falls to 0
    linearly, so its CDF grows as the square of the distance from there: in v the inverse is close
    to linear at the ends too, and linear interpolation stays accurate over the whole support."""
    z = np.linspace(-GAUSSIAN_CUTOFF, 0.0, 400_001)
    f = np.maximum(0.0, np.exp(-0.5 * z * z) - _GAUSSIAN_BIAS)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(z))])
    cdf *= 0.5 / cdf[-1]
    v = np.linspace(0.0, math.sqrt(0.5), n + 1)
    table = np.interp(v * v, cdf, z)
    table[0], table[-1] = -GAUSSIAN_CUTOFF, 0.0
    return table


#: The inverse CDF's lower half against sqrt(CDF), in 1024 steps: sampling it with linear interpolation
#: gives a CDF within 2e-7 of the filter's everywhere (tests/test_rfilter.py).
GAUSSIAN_TABLE_STEPS = 1024
_GAUSSIAN_TABLE = _gaussian_inverse_table(GAUSSIAN_TABLE_STEPS)
_GAUSSIAN_HALF_MASS = _SQRT_HALF_PI * math.erf(GAUSSIAN_CUTOFF * _INV_SQRT2) - _GAUSSIAN_BIAS * GAUSSIAN_CUTOFF
_TABLE_SCALE = GAUSSIAN_TABLE_STEPS / math.sqrt(0.5)


@kernel
def _gaussian_lower(v):
    """The tabulated z <= 0 where the CDF is v² (v in [0, sqrt(1/2)])."""
    w = min(max(v * _TABLE_SCALE, 0.0), GAUSSIAN_TABLE_STEPS)
    i = min(int(w), GAUSSIAN_TABLE_STEPS - 1)
    return _GAUSSIAN_TABLE[i] + (w - i) * (_GAUSSIAN_TABLE[i + 1] - _GAUSSIAN_TABLE[i])


@kernel
def _sample_gaussian(zlo, zhi, u):
    """z in [zlo, zhi] (within [-4, 4]) from the standard gaussian restricted there; non-decreasing in u.

    The window's ends become fractions of the whole mass through the CDF (``erf``; only for pixels
    near the film's edge, the others have the whole support), the fraction between them a position
    through the tabulated inverse CDF (symmetric: the upper half mirrors the lower)."""
    f_lo, f_hi = 0.0, 1.0
    if zlo > -GAUSSIAN_CUTOFF:
        f_lo = 0.5 + 0.5 * _gaussian_cdf(zlo) / _GAUSSIAN_HALF_MASS
    if zhi < GAUSSIAN_CUTOFF:
        f_hi = 0.5 + 0.5 * _gaussian_cdf(zhi) / _GAUSSIAN_HALF_MASS
    f = f_lo + u * (f_hi - f_lo)
    if f <= 0.5:
        z = _gaussian_lower(math.sqrt(max(f, 0.0)))
    else:
        z = -_gaussian_lower(math.sqrt(max(1.0 - f, 0.0)))
    return min(max(z, zlo), zhi)


@kernel
def sample_filter(kind, radius, stddev, lo, hi, u):
    """An offset in [lo, hi] (within [-radius, radius]) drawn from the filter restricted to [lo, hi],
    from one uniform number u in [0, 1); non-decreasing in u."""
    if kind == TENT:
        c_lo = filter_cdf(kind, radius, stddev, lo)
        t = c_lo + u * (filter_cdf(kind, radius, stddev, hi) - c_lo)
        # t = x - x|x| / 2r solved for x, in the form without cancellation near 0
        x = 2.0 * radius * t / (radius + math.sqrt(max(0.0, radius * (radius - 2.0 * abs(t)))))
        return min(max(x, lo), hi)
    if kind == GAUSSIAN:
        return stddev * _sample_gaussian(lo / stddev, hi / stddev, u)
    return lo + u * (hi - lo)   # box


@kernel(inline=True)
def film_position(kind, radius, stddev, sample_border, p, n, u):
    """The film coordinate (in pixels, 0 at the film's first edge) of a sample of pixel p of n along
    one axis, drawn with the uniform number u from the filter centred on the pixel (see the module).

    Box: ``p + u``, as before filters existed.  Otherwise the pixel centre plus an offset from the
    filter, truncated to the film unless ``sample_border``.
    """
    if kind == BOX:
        return p + u
    c = p + 0.5
    lo = -radius
    hi = radius
    if not sample_border:
        lo = max(lo, -c)
        hi = min(hi, n - c)
    return c + sample_filter(kind, radius, stddev, lo, hi, u)
