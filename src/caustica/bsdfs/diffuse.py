"""``diffuse``: Lambertian reflection, f = ρ / π, sampled by the cosine-weighted hemisphere."""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import DIFFUSE
from .flags import DIFFUSE_REFLECTION
from .textures import colour

KIND = DIFFUSE
FLAGS = DIFFUSE_REFLECTION
INV_PI = 1.0 / math.pi


@kernel(inline=True)
def sample(mats, m, d, ng, ns, uv, key, dim):
    """A cosine-weighted direction about ns (numbers dim, dim + 1): see :func:`caustica.bsdfs.sample`.

    The weight f cos / pdf is ρ exactly; a direction below the geometric surface is refused.
    """
    local = square_to_cosine_hemisphere(uniform(key, dim), uniform(key, dim + 1))
    s, t = vec.orthonormal_basis(ns)
    wi = vec.from_local(s, t, ns, local)
    ok = not (vec.dot(wi, ng) <= 0.0 or local[2] <= 0.0)
    return ok, wi, colour(mats, m, uv), local[2] * INV_PI, DIFFUSE_REFLECTION, 1.0, dim + 2


@kernel(inline=True)
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """f = ρ · (1 / π) towards wi (zero below the surface) and the sampling density cos θ / π."""
    cos_i = vec.dot(ns, wi)
    if cos_i <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    return colour(mats, m, uv), INV_PI, cos_i * INV_PI
