"""A BSDF against Mitsuba 3's own at random direction pairs: the pairs and Mitsuba's values (test_glossy.py,
test_plastic.py, test_principled.py compare their BSDFs so, each with its own tolerance and evaluation)."""
from __future__ import annotations

import numpy as np


def direction_pairs(n=300, seed=5, upper=False, grazing=0.05):
    """Unit pairs (wo, wi) in the shading frame, wo towards the camera (Mitsuba's ``si.wi``), wi towards the light
    (Mitsuba's ``wo``): n draws of ``seed``'s generator, without the pairs within ``grazing`` of the surface
    (|cos θ| < grazing); ``upper``: both turned to the upper hemisphere first."""
    rng = np.random.default_rng(seed)
    for _ in range(n):
        v = rng.normal(size=(2, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        if upper:
            v[:, 2] = np.abs(v[:, 2])
        if abs(v[0, 2]) < grazing or abs(v[1, 2]) < grazing:
            continue
        yield v[0], v[1]


def mitsuba_f_pdf(mi, theirs, ctx, si, wo, wi):
    """Mitsuba BSDF ``theirs``'s f·|cos θ| (RGB, float64) and pdf at ``si`` for the pair (wo, wi) of
    :func:`direction_pairs`."""
    si.wi = mi.Vector3f(*wo)
    towards_light = mi.Vector3f(*wi)
    return np.array(theirs.eval(ctx, si, towards_light), np.float64), float(theirs.pdf(ctx, si, towards_light))
