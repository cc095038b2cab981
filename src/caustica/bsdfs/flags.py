"""What kind of scattering a BSDF (or one of its sampled lobes) does: bits combined with ``|``.

The transport loops decide by these, never by a BSDF's name: a surface with a ``SMOOTH`` lobe
(non-delta) gets next-event estimation and stores photons; a purely delta one (mirror, glass) is
followed as a specular bounce.  A BSDF may have both (``plastic``: a delta coating over a diffuse base);
:func:`caustica.bsdfs.sample` reports which lobe it sampled.  ``NULL_TRANSMISSION`` marks a straight-on
transmission as no bounce at all (thindielectric under Mitsuba's ``volpath``, :func:`caustica.bsdfs.null_transmitting`).
"""
from __future__ import annotations

DIFFUSE_REFLECTION = 1
GLOSSY_REFLECTION = 2
GLOSSY_TRANSMISSION = 4
DELTA_REFLECTION = 8
DELTA_TRANSMISSION = 16
#: Set by a method, never by a BSDF (a copy of the material table, ``pt`` for Mitsuba's ``volpath``): the BSDF's
#: straight-on transmission is Mitsuba's ``Null`` lobe, a crossing that is no scattering event (not counted in
#: the path's depth; a shadow ray passes with the BSDF's :func:`caustica.bsdfs.null_transmission`).
NULL_TRANSMISSION = 32
#: Reported by :func:`caustica.bsdfs.sample` as a sampled lobe, never set on a material: a diffuse transmission
#: (principledthin's), reported with ``GLOSSY_TRANSMISSION`` (for the loops, a lobe that transmits).
DIFFUSE_TRANSMISSION = 64
#: Set by the material table on a row with glossy lobes beside diffuse ones (pplastic, principled, principledthin) some
#: glossy lobe of which may be narrower than :data:`NARROW_ALPHA`, or one of which transmits (principled's and
#: principledthin's ``spec_trans``, however broad): the photon methods' camera paths take its lobes apart
#: (:func:`caustica.bsdfs.splits_lobes`).
NARROW_GLOSSY = 128
#: The microfacet roughness below which glossy lobes that only reflect, beside a diffuse lobe, are taken apart rather
#: than weighed into photon estimates.  Measured (docs/results.md, "Which glossy lobes a camera path takes apart",
#: 2026-12-07, ``benchmarks/narrow_threshold.py``): on a pplastic floor in the Cornell box, which reflects the lit
#: walls, taking the lobe apart gave 2.3x, 1.6x and 1.07x lower error at alpha 0.05, 0.1 and 0.2, and 1.05x higher at
#: 0.4; on a floor that reflects only a small light and a caustic, 1.3-1.4x higher at every alpha from 0.05 to 0.2.  A
#: judgement between the two.  A glossy transmission is taken apart at any alpha: through a frosted panel that gave
#: 4-220x less error.
NARROW_ALPHA = 0.1

DELTA = DELTA_REFLECTION | DELTA_TRANSMISSION
GLOSSY = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
SMOOTH = DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
TRANSMISSION = GLOSSY_TRANSMISSION | DELTA_TRANSMISSION
#: The lobes a visible point holds where a BSDF has glossy lobes beside them (:func:`caustica.bsdfs.glossy_share`).
DIFFUSE_LOBES = DIFFUSE_REFLECTION | DIFFUSE_TRANSMISSION

#: Which lobes an evaluation takes (:func:`caustica.bsdfs.eval_part`): all of them, the diffuse ones (with a
#: principled's sheen) or the glossy ones, with the density of :func:`caustica.bsdfs.sample` picking one of those
#: lobes and giving the direction.
ALL_LOBES, DIFFUSE_PART, GLOSSY_PART = 0, 1, 2

#: Feature codes of a material table beyond its kinds (:mod:`caustica.features`; a kind's code is the kind itself):
#: some colour, opacity, weight or normal comes from a texture; some BSDF has a glossy lobe; some microfacet roughness
#: is anisotropic (its BSDF reads the shading frame from dp/du).
TEXTURED = 30
GLOSSY_LOBES = 29
ANISOTROPIC = 28
