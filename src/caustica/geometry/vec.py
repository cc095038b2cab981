"""3-vector arithmetic on tuples of floats, for use inside kernels.

Vectors are ``(x, y, z)`` tuples: Numba keeps them in registers, so no small
arrays are allocated per ray.
"""
from __future__ import annotations

import math

from ..jit import kernel


@kernel
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel
def mul(a, s):
    """Vector times scalar."""
    return (a[0] * s, a[1] * s, a[2] * s)


@kernel
def hadamard(a, b):
    """Component-wise product (RGB throughput times reflectance)."""
    return (a[0] * b[0], a[1] * b[1], a[2] * b[2])


@kernel
def madd(a, b, s):
    """a + b * s."""
    return (a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s)


@kernel
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def length(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@kernel
def normalize(a):
    n = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if n == 0.0:
        return a
    inv = 1.0 / n
    return (a[0] * inv, a[1] * inv, a[2] * inv)


@kernel
def neg(a):
    return (-a[0], -a[1], -a[2])


@kernel
def max_component(a):
    return max(a[0], max(a[1], a[2]))


@kernel
def mean(a):
    return (a[0] + a[1] + a[2]) / 3.0


@kernel
def row(arr, i):
    """Row i of an (n, 3) array as a tuple."""
    return (arr[i, 0], arr[i, 1], arr[i, 2])


@kernel(inline=True)
def set_row(arr, i, v):
    """Row i of an (n, 3) array set to the vector v (the record writers' one line per field)."""
    for c in range(3):
        arr[i, c] = v[c]


@kernel
def orthonormal_basis(n):
    """Two unit vectors completing n to a right-handed frame (Duff et al. 2017)."""
    sign = 1.0 if n[2] >= 0.0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    t = (b, sign + n[1] * n[1] * a, -n[1])
    return s, t


@kernel
def from_local(s, t, n, v):
    """Local (v in the s, t, n frame) to world."""
    return (s[0] * v[0] + t[0] * v[1] + n[0] * v[2],
            s[1] * v[0] + t[1] * v[1] + n[1] * v[2],
            s[2] * v[0] + t[2] * v[1] + n[2] * v[2])


@kernel
def offset_origin(p, ng, direction):
    """Move p off its surface to the side that ``direction`` leaves towards.

    The offset scales with the magnitude of p so rays neither re-hit their own
    surface (self-intersection) nor tunnel through thin geometry.
    """
    scale = 1e-7 * (1.0 + max(abs(p[0]), max(abs(p[1]), abs(p[2])))) + 1e-9
    eps = 64.0 * scale
    if dot(ng, direction) < 0.0:
        eps = -eps
    return (p[0] + ng[0] * eps, p[1] + ng[1] * eps, p[2] + ng[2] * eps)
