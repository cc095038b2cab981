"""What kind of scattering a BSDF (or one of its sampled lobes) does: bits combined with ``|``.

The transport loops decide by these, never by a BSDF's name: a surface with a ``SMOOTH`` lobe
(non-delta) gets next-event estimation and stores photons; a purely delta one (mirror, glass) is
followed as a specular bounce.  A BSDF may have both (``plastic``: a delta coating over a diffuse base);
:func:`caustica.bsdfs.sample` reports which lobe it sampled.
"""
from __future__ import annotations

DIFFUSE_REFLECTION = 1
GLOSSY_REFLECTION = 2
GLOSSY_TRANSMISSION = 4
DELTA_REFLECTION = 8
DELTA_TRANSMISSION = 16

DELTA = DELTA_REFLECTION | DELTA_TRANSMISSION
GLOSSY = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
SMOOTH = DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
TRANSMISSION = GLOSSY_TRANSMISSION | DELTA_TRANSMISSION
