"""Upper bounds of the integer settings: values the kernels can honour.

The kernels compute in 64-bit integers, and a value Python accepts may not fit
them (Numba refuses an integer above 2**63 - 1 with a ``TypingError``) or may
overflow inside them (a camera sample's index is ``(y * width + x) * spp + s``;
n x n light samples use 2 n² random dimensions).  Every integer a user gives is
checked against a bound from here, where it is read, before any work starts:

* the common settings (:func:`caustica.api.resolve_settings` and the scene's
  ``<film>`` and ``<sampler>``) use the constants below;
* a method parameter (:class:`caustica.methods.params.Param`) has its own ``max``,
  or :data:`INT_MAX` when it declares none.

With at most 2**31 - 1 pixels and spp <= 2**20 a sample index stays below 2**51, so
it is exact in int64, uint64 and float64.  Counts sized by memory (photons,
streams, k) are also checked against the memory budget (:mod:`caustica.memory`).
"""
from __future__ import annotations

#: Default bound of an integer method parameter: a 32-bit count.  Products of two
#: such counts with the small ones (bounces, spp) stay far inside 64 bits.
INT_MAX = 2**31 - 1

#: Samples per pixel.  One pixel's samples are the smallest piece of work a thread
#: runs, so this also keeps one piece in seconds, not hours, and a pixel's count of
#: k-nearest searches (at most 18 per sample) inside the int32 that records it.
MAX_SPP = 2**20

#: Pixels of an image (width x height): a pixel's index is an int32 (the image must
#: also fit the memory budget).  The scene loader bounds a film the same way.
MAX_PIXELS = 2**31 - 1

#: The random seed: 32 bits, as Mitsuba's.
MAX_SEED = 2**32 - 1

#: Worker threads.
MAX_THREADS = 1024
