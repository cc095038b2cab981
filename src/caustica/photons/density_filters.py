"""Density-estimation filters: how a photon at distance d from the query point is weighted within radius r.

Each filter W is normalised to integrate to 1 over the disc of radius r:

- none (the uniform disc): W = 1 / (π r²);
- cone (Jensen, k = 1): W = 3 (1 - d/r) / (π r²);
- Gaussian (Jensen's profile, β = 1.953): W = α [1 - (1 - e^{-β d²/(2r²)}) / (1 - e^{-β})] / (π r²), with α
  computed so that W integrates to exactly 1 (Jensen's quoted α = 0.918 does not: it integrates to 0.53 with
  this normalisation);
- Epanechnikov: W = 2 (1 - d²/r²) / (π r²).

Their blur differs: over a disc of radius r a filter's second moment ∫ d² W is r²/2 (none), 3r²/10 (cone),
r²/3 (Epanechnikov), so at one radius the bias of a smooth density's estimate (∝ that moment times its Laplacian)
is 0.6 (cone) or 2/3 (Epanechnikov) of the uniform disc's, and the variance (∝ ∫ W²) 1.5 or 4/3 times it.
Used by the k-nearest estimate of :mod:`caustica.photons.estimate` (pm's ``--filter``) and by the progressive
methods' caustic statistics (``--caustic-filter``, :func:`caustica.photons.grid.grid_range_sum`).
"""
from __future__ import annotations

import math

from ..jit import kernel

FILTER_NONE = 0
FILTER_CONE = 1
FILTER_GAUSSIAN = 2
FILTER_EPANECHNIKOV = 3
FILTERS = {"none": FILTER_NONE, "cone": FILTER_CONE, "gaussian": FILTER_GAUSSIAN,
           "epanechnikov": FILTER_EPANECHNIKOV}

_GAUSS_BETA = 1.953
# ∫_0^1 [1 - (1 - e^{-β s²/2}) / (1 - e^{-β})] 2 s ds, in closed form.
_GAUSS_ALPHA = 1.0 / (1.0 - (1.0 - (2.0 / _GAUSS_BETA) * (1.0 - math.exp(-_GAUSS_BETA / 2.0)))
                      / (1.0 - math.exp(-_GAUSS_BETA)))


@kernel
def filter_weight(filt, d2, r2):
    """W(d, r) of the filter, normalised over the disc of radius r (see module doc)."""
    return filter_shape(filt, d2, r2) * (1.0 / (math.pi * r2))


@kernel(inline=True)
def filter_shape(filt, d2, r2):
    """π r² W(d, r): the filter's weight relative to the uniform disc's (mean 1 over the disc; exactly 1 for
    ``none``, so a weight of none leaves a sum's bits as they were)."""
    if filt == FILTER_NONE:
        return 1.0
    if filt == FILTER_CONE:
        return 3.0 * (1.0 - math.sqrt(d2 / r2))
    if filt == FILTER_GAUSSIAN:
        return _GAUSS_ALPHA * (1.0 - (1.0 - math.exp(-_GAUSS_BETA * d2 / (2.0 * r2)))
                               / (1.0 - math.exp(-_GAUSS_BETA)))
    return 2.0 * (1.0 - d2 / r2)
