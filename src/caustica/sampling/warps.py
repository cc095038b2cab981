"""Warps from uniform numbers on [0,1)^2 to directions and points, with their pdfs."""
from __future__ import annotations

import math

from ..jit import kernel

INV_PI = 1.0 / math.pi


@kernel
def square_to_cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +z (Malley's method); pdf = cos(theta) / pi."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    x = r * math.cos(phi)
    y = r * math.sin(phi)
    z = math.sqrt(max(0.0, 1.0 - u1))
    return (x, y, z)


@kernel
def square_to_uniform_disk(u1, u2):
    """Uniform point in the unit disk (polar map); pdf = 1 / pi."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    return (r * math.cos(phi), r * math.sin(phi))


@kernel
def square_to_uniform_sphere(u1, u2):
    """Uniform direction on the unit sphere; pdf = 1 / (4 pi)."""
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return (r * math.cos(phi), r * math.sin(phi), z)


@kernel
def square_to_uniform_cone(u1, u2, cos_max):
    """Uniform direction in the cone about +z of half-angle acos(cos_max); pdf = 1 / (2 pi (1 - cos_max))."""
    cos_t = 1.0 - u1 * (1.0 - cos_max)
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * u2
    return (sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t)
