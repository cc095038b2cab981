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

DELTA = DELTA_REFLECTION | DELTA_TRANSMISSION
GLOSSY = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
SMOOTH = DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
TRANSMISSION = GLOSSY_TRANSMISSION | DELTA_TRANSMISSION

#: Feature codes of a material table beyond its kinds (:mod:`caustica.features`; a kind's code is the kind itself):
#: some colour, opacity, weight or normal comes from a texture; some BSDF has a glossy lobe; some microfacet roughness
#: is anisotropic (its BSDF reads the shading frame from dp/du).
TEXTURED = 30
GLOSSY_LOBES = 29
ANISOTROPIC = 28
