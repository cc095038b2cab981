"""``conductor``: a smooth mirror, f a Dirac delta about the shading normal, scaled by
``specular_reflectance`` (Mitsuba's ``material="none"``)."""
from __future__ import annotations

from ..geometry import vec
from ..jit import kernel
from ..scene.description import CONDUCTOR
from .flags import DELTA_REFLECTION
from .optics import mirror_reflect

KIND = CONDUCTOR
FLAGS = DELTA_REFLECTION


@kernel(inline=True)
def delta_branches(mats, m, d, ng, ns):
    """The one reflected direction, as both branches with F = 1 (see :func:`caustica.bsdfs.delta_branches`)."""
    wr = mirror_reflect(d, ng, ns)
    return wr, wr, 1.0, 1.0, vec.row(mats.rgb, m)


@kernel(inline=True)
def sample(mats, m, d, ng, ns, key, dim):
    """The reflection, weight ``specular_reflectance``.  Like every delta BSDF it takes one number (its
    lobe choice, of one lobe here), so a mirror and a glass advance a path's numbers alike."""
    return True, mirror_reflect(d, ng, ns), vec.row(mats.rgb, m), 0.0, DELTA_REFLECTION, 1.0, dim + 1
