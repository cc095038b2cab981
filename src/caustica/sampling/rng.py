"""Counter-based random numbers: a pure function of (seed, stream, index, dimension).

No state is shared between threads, so the same seed gives the same bits whatever
the thread count or scheduling (SPEC §2).  Each random path (a camera sample, a
photon, a stream) has a 64-bit *key* made from the render seed, a *stream* tag
naming the phase (camera pass, photon pass, ...) and the path's index; its
``dim``-th number is ``uniform(key, dim)``.

The mixing function is the SplitMix64 finaliser (Steele et al. 2014), which
passes BigCrush when used as a counter-based generator.
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import kernel

# Stream tags: one per kind of random path, so phases never share numbers.
STREAM_CAMERA = 1
STREAM_PHOTON = 2
STREAM_CAUSTIC_PHOTON = 3
STREAM_SPM = 4
STREAM_DIRECT = 5
# Per-pixel scrambles of the camera pass's low-discrepancy sequence over passes (never a pass's own numbers).
STREAM_CAMERA_SCRAMBLE = 6
# The progressive camera pass's next-event estimates along its medium segments (photons/segments.py).
STREAM_CAMERA_MEDIA = 7
# Tags from 100 up belong to measurement tools, not to any method's image: the caustic
# mask of the experiments (experiments/masks.py) traces its own photons, so the region an
# experiment measures is never drawn from the very photons of the PM+C render it judges.
STREAM_CAUSTIC_MASK = 101

#: Bits of a stream tag that name the phase; the pass index sits above them.
PHASE_BITS = 8


def pass_stream(phase: int, pass_index: int) -> int:
    """The stream tag of ``phase`` in render pass ``pass_index``: (seed, phase, pass, index) keys.

    Pass 0 is the phase's own tag, so a one-pass render draws exactly the numbers a
    one-shot render drew; later passes never share numbers with it or each other.
    """
    if not 0 <= phase < (1 << PHASE_BITS):
        raise ValueError(f"phase tag {phase} out of range")
    if not 0 <= pass_index < (1 << (63 - PHASE_BITS)):
        raise ValueError(f"pass index {pass_index} out of range")
    return phase + (pass_index << PHASE_BITS)

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_LENS_SALT = np.uint64(0x6C656E73A5A5A5A5)   # "lens"
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53


@kernel(inline=True)
def mix64(z):
    """SplitMix64 finaliser: a bijective avalanche of a 64-bit integer."""
    z = np.uint64(z)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@kernel
def path_key(seed, stream, index):
    """The key of random path ``index`` in phase ``stream`` for render ``seed``."""
    k = mix64(np.uint64(seed) * _GOLDEN + np.uint64(stream))
    return mix64(k ^ (np.uint64(index) * _GOLDEN + _M2))


@kernel(inline=True)
def lens_key(key):
    """The key of a camera sample's lens numbers: a stream of its own, so a pinhole's path keeps its numbers."""
    return mix64(key ^ _LENS_SALT)


@kernel(inline=True)
def uniform(key, dim):
    """The ``dim``-th uniform number in [0, 1) of the path with this key."""
    z = mix64(key + np.uint64(dim + 1) * _GOLDEN)
    return float(z >> _S11) * _INV53


_MASK32 = np.uint64(0xFFFFFFFF)
_ONE = np.uint64(1)
_INV32 = 1.0 / 4294967296.0


@kernel(inline=True)
def _reverse32(v):
    v = np.uint64(v) & _MASK32
    v = ((v >> np.uint64(1)) & np.uint64(0x55555555)) | ((v & np.uint64(0x55555555)) << np.uint64(1))
    v = ((v >> np.uint64(2)) & np.uint64(0x33333333)) | ((v & np.uint64(0x33333333)) << np.uint64(2))
    v = ((v >> np.uint64(4)) & np.uint64(0x0F0F0F0F)) | ((v & np.uint64(0x0F0F0F0F)) << np.uint64(4))
    v = ((v >> np.uint64(8)) & np.uint64(0x00FF00FF)) | ((v & np.uint64(0x00FF00FF)) << np.uint64(8))
    return ((v >> np.uint64(16)) | (v << np.uint64(16))) & _MASK32


@kernel
def sobol02(index, key):
    """Point ``index`` of the 2-D Sobol' (0, 2)-sequence, digitally shifted by ``key``'s numbers: (u1, u2).

    The first two dimensions of Sobol's sequence (van der Corput in base 2, and the
    Pascal-matrix dimension): every block of 2^m consecutive points from 0 is a
    (0, m, 2)-net -- one point in each of 2^m elementary boxes of every shape.  The shift XORs
    each coordinate's 32 bits with a random word drawn from ``key`` (Cranley-Patterson's
    rotation in base 2): it keeps the net property and makes every single point uniform
    on [0, 1)^2, so each point is an unbiased sample and a prefix of n points stratifies.
    """
    i = np.uint64(index) & _MASK32
    x = _reverse32(i)
    y = np.uint64(0)
    v = np.uint64(0x80000000)
    while i != np.uint64(0):
        if i & _ONE:
            y ^= v
        i >>= _ONE
        v ^= v >> _ONE
    sx = mix64(key + _GOLDEN) & _MASK32
    sy = mix64(key + np.uint64(2) * _GOLDEN) & _MASK32
    return float(x ^ sx) * _INV32, float(y ^ sy) * _INV32


#: Kronecker (rank-1) generators for the progressive camera pass's other dimensions, one per
#: dimension, so that the pass-indexed points frac(s + p alpha) are uniformly distributed jointly:
#:
#: * 0 .. 2: 1/g, 1/g^2, 1/g^3 for the root g of x^4 = x + 1 (Roberts' R_3 sequence): the first
#:   glass branch and the visible point's light strata (u1, u2);
#: * 3 .. 5: 1/h, 1/h^2, 1/h^3 for the root h of x^6 = x + 1 (R_5's): the first medium segment's
#:   distance and light point.
#:
#: 1, the g powers and the h powers are linearly independent over the rationals (x^n - x - 1 is
#: irreducible, Selmer; the two fields meet only in Q), which is what joint uniformity needs.  Two
#: dimensions that shared a generator (they did until 2026-12-03: the segment's distance and the
#: glass branch) differ by a constant shift, so their points lie on one line of the torus and a
#: path through glass into a medium never sees most distances with the branch it took.
_G3 = 1.2207440846057596
_G5 = 1.1347241384015194
KRONECKER_ALPHA = (1.0 / _G3, 1.0 / _G3 ** 2, 1.0 / _G3 ** 3, 1.0 / _G5, 1.0 / _G5 ** 2, 1.0 / _G5 ** 3)


@kernel(inline=True)
def kronecker(index, alpha, shift):
    """frac(shift + index * alpha): point ``index`` of a randomly shifted 1-D Kronecker sequence."""
    x = shift + float(index) * alpha
    return x - math.floor(x)
