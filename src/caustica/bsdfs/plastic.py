"""``plastic``: Mitsuba 3's smooth plastic, a diffuse base under a smooth dielectric coating (relative IOR
eta = int_ior / ext_ior, no absorption in the coating), with two lobes:

* a **delta reflection** off the coating, about the shading normal, of weight F_i · specular_reflectance, F_i the
  Fresnel reflectance at the incident cosine cos θ_i;
* a **diffuse lobe**, light refracted in, scattered by the base and refracted out, with the light reflected back
  down inside the coating summed as a geometric series:
  f = ρ / (1 - Fdr) · (1 - F_i)(1 - F_o) / (π eta²), F_o the Fresnel reflectance at cos θ_o and Fdr the coating's
  internal diffuse reflectance, Mitsuba's fit (:func:`fresnel_diffuse_reflectance` at 1 / eta); with
  ``nonlinear`` the series keeps the base's colour, ρ / (1 - ρ Fdr) per channel.

Sampling picks the delta lobe with probability P = F_i w / (F_i w + (1 - F_i)(1 - w)), w = mean(specular) /
(mean(diffuse) + mean(specular)) (Mitsuba's specular sampling weight, the ``spec_weight`` column), on the first
number; the diffuse lobe's direction is cosine-weighted on the next two, its density (1 - P) cos θ_o / π, which
is also what :func:`eval_pdf` gives (the delta lobe has none).  The weights are f cos / pdf of each lobe:
F_i · specular / P and the diffuse f cos θ_o / ((1 - P) cos θ_o / π).  Every sample takes three numbers, whichever
lobe it picks.  Cosines are about the shading normal (Mitsuba's frame); the back is black unless ``twosided``;
directions below the geometric surface are refused.

The flags are ``DELTA_REFLECTION | DIFFUSE_REFLECTION``: ``pt`` gives the surface next-event estimation through
:func:`eval_pdf` (the diffuse lobe only) and follows the delta lobe as a specular bounce without MIS.  For the
photon methods the lobes come apart (:func:`coat`, :func:`entry`): the diffuse lobe is A(wo) B(wi), the photons
and shadow rays carry B and the visible point A (docs/architecture.md); ``pm`` and ``sppm`` render it, the stream
methods refuse it (``api.check_bsdfs``).
"""
from __future__ import annotations

import math

from ..geometry import vec
from ..jit import kernel
from ..sampling.rng import uniform
from ..sampling.warps import square_to_cosine_hemisphere
from ..scene.description import PLASTIC
from .flags import DELTA_REFLECTION, DIFFUSE_REFLECTION
from .optics import fresnel_dielectric, mirror_reflect
from .textures import colour

KIND = PLASTIC
FLAGS = DELTA_REFLECTION | DIFFUSE_REFLECTION
INV_PI = 1.0 / math.pi
#: The plastics' parameters, columns of the material table's ``coating`` (one array, not one column each: every
#: kernel that takes the table unpacks its arrays, so fewer arrays compile faster): specular_reflectance (RGB), the
#: specular sampling weight, the coating's internal reflectance Fdr, nonlinear (1 or 0), and from TABLE on a
#: roughplastic's coating transmittance at TABLE_RES cosines.
SPEC, SPEC_WEIGHT, INTERNAL, NONLINEAR, TABLE = 0, 3, 4, 5, 6
TABLE_RES = 64
COATING_COLUMNS = TABLE + TABLE_RES


@kernel(inline=True)
def specular(mats, m):
    """specular_reflectance."""
    return (mats.coating[m, SPEC], mats.coating[m, SPEC + 1], mats.coating[m, SPEC + 2])


def fresnel_diffuse_reflectance(eta: float) -> float:
    """The cosine-weighted hemispherical average of the Fresnel reflectance of an interface of relative IOR eta,
    by the fits Mitsuba 3 uses: Egan and Hilgeman (1973) for eta < 1, d'Eon and Irving (2011) otherwise."""
    if eta < 1.0:
        return -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    x = 1.0 / eta
    return 0.919317 + x * (-3.4793 + x * (6.75335 + x * (-7.80989 + x * (4.98554 + x * -1.36881))))


def specular_sampling_weight(diffuse, specular, diffuse_mean=None) -> float:
    """Mitsuba's weight w = mean(specular) / (mean(diffuse) + mean(specular)) of the coating's lobe (1/2 for a black
    plastic, where Mitsuba divides 0 by 0).  One number per material, as Mitsuba's: a textured diffuse reflectance
    gives its texture's mean (``diffuse_mean``, :func:`caustica.bsdfs.textures.mitsuba_mean`), not the colour at the
    point."""
    d = sum(diffuse) / 3.0 if diffuse_mean is None else diffuse_mean
    s = sum(specular) / 3.0
    return s / (d + s) if d + s > 0.0 else 0.5


@kernel(inline=True)
def base(mats, m, uv):
    """The diffuse base's colour with the coating's internal reflections, ρ / (1 - Fdr) (or ρ / (1 - ρ Fdr) per
    channel with ``nonlinear``), ρ the diffuse reflectance at surface coordinates uv (its texture's there, as
    Mitsuba evaluates it per point): shared with :mod:`.roughplastic`, whose Fdr is its rough coating's."""
    fdr = mats.coating[m, INTERNAL]
    r = colour(mats, m, uv)
    if mats.coating[m, NONLINEAR] != 0.0:
        return (r[0] / (1.0 - r[0] * fdr), r[1] / (1.0 - r[1] * fdr), r[2] / (1.0 - r[2] * fdr))
    return vec.mul(r, 1.0 / (1.0 - fdr))


@kernel(inline=True)
def choice(mats, m, F_i):
    """The probability of sampling the coating's delta lobe at incident Fresnel reflectance F_i."""
    w = mats.coating[m, SPEC_WEIGHT]
    ps = F_i * w
    pd = (1.0 - F_i) * (1.0 - w)
    return ps / (ps + pd) if ps + pd > 0.0 else 0.0


@kernel
def sample(mats, m, d, ng, ns, uv, key, dim):
    """The coating's reflection with probability P (number dim), else a cosine-weighted direction about ns (numbers
    dim + 1, dim + 2): see :func:`caustica.bsdfs.sample` and the module's docstring (uv: where the diffuse
    reflectance's texture is read)."""
    zero = (0.0, 0.0, 0.0)
    cos_i = -vec.dot(d, ns)
    if cos_i <= 0.0:
        return False, zero, zero, 0.0, DIFFUSE_REFLECTION, 1.0, dim + 3
    eta = mats.eta[m]
    F_i, _ = fresnel_dielectric(cos_i, eta)
    P = choice(mats, m, F_i)
    if uniform(key, dim) < P:
        wr = mirror_reflect(d, ng, ns)
        return True, wr, vec.mul(specular(mats, m), F_i / P), 0.0, DELTA_REFLECTION, 1.0, dim + 3
    local = square_to_cosine_hemisphere(uniform(key, dim + 1), uniform(key, dim + 2))
    s, t = vec.orthonormal_basis(ns)
    wi = vec.from_local(s, t, ns, local)
    if vec.dot(wi, ng) <= 0.0 or local[2] <= 0.0:
        return False, wi, zero, 0.0, DIFFUSE_REFLECTION, 1.0, dim + 3
    F_o, _ = fresnel_dielectric(local[2], eta)
    # f cos / pdf = base (1 - F_i)(1 - F_o) / (π eta²) cos / ((1 - P) cos / π)
    w = (1.0 - F_i) * (1.0 - F_o) / (eta * eta * (1.0 - P))
    return True, wi, vec.mul(base(mats, m, uv), w), (1.0 - P) * local[2] * INV_PI, DIFFUSE_REFLECTION, 1.0, dim + 3


@kernel
def eval_pdf(mats, m, d, ng, ns, uv, wi):
    """The diffuse lobe towards wi, f = (base colour, (1 - F_i)(1 - F_o) / (π eta²)), and its density (1 - P) cos θ_o
    / π; zero below the shading or the geometric surface, or seen from below."""
    cos_i = -vec.dot(d, ns)
    cos_o = vec.dot(ns, wi)
    if cos_i <= 0.0 or cos_o <= 0.0 or vec.dot(ng, wi) <= 0.0:
        return (0.0, 0.0, 0.0), 0.0, 0.0
    eta = mats.eta[m]
    F_i, _ = fresnel_dielectric(cos_i, eta)
    F_o, _ = fresnel_dielectric(cos_o, eta)
    P = choice(mats, m, F_i)
    return base(mats, m, uv), (1.0 - F_i) * (1.0 - F_o) * INV_PI / (eta * eta), (1.0 - P) * cos_o * INV_PI


@kernel
def coat(mats, m, d, ng, ns, uv):
    """The two lobes apart, for the photon methods (see :func:`caustica.bsdfs.coat`): (the coating's reflected
    direction, the probability P that :func:`sample` picks it, its weight F_i · specular / P, the diffuse lobe's
    outgoing factor A = base (1 - F_i) / (π eta²), its colour at uv); P = 0 and A = 0 seen from below."""
    zero = (0.0, 0.0, 0.0)
    wr = mirror_reflect(d, ng, ns)
    cos_i = -vec.dot(d, ns)
    if cos_i <= 0.0:
        return wr, 0.0, zero, zero
    eta = mats.eta[m]
    F_i, _ = fresnel_dielectric(cos_i, eta)
    P = choice(mats, m, F_i)
    w = vec.mul(specular(mats, m), F_i / P) if P > 0.0 else zero
    return wr, P, w, vec.mul(base(mats, m, uv), (1.0 - F_i) * INV_PI / (eta * eta))


@kernel
def entry(mats, m, cos_o):
    """The diffuse lobe's factor on the light's side, B = 1 - F(cos θ_o): f = A B (:func:`coat`)."""
    if cos_o <= 0.0:
        return 0.0
    F_o, _ = fresnel_dielectric(cos_o, mats.eta[m])
    return 1.0 - F_o
