"""The complex indices of refraction of the conductors Mitsuba 3 knows by name (``material="Cu"`` etc.), in RGB.

Mitsuba tabulates each material's eta and k spectra (``resources/data/ior/<name>.eta.spd`` / ``.k.spd``, after
Palik's Handbook of Optical Constants of Solids and the other sources its documentation cites) and its RGB
variants integrate them to linear sRGB, clamping negative components to 0.  The values
(``data/conductors_rgb.csv``) are those integrations as Mitsuba 3.9.1 (``scalar_rgb``) reports them for
``<bsdf type="conductor">`` with each ``material`` (``mi.traverse(bsdf)['eta.value']`` / ``['k.value']``), to
six significant digits; Mitsuba 3's default material, used when none is given, is ``Cu``.
"""
from __future__ import annotations

from .data import read_csv

#: name -> ((eta R, G, B), (k R, G, B)), from data/conductors_rgb.csv.
CONDUCTOR_IOR = {r[0]: (tuple(map(float, r[1:4])), tuple(map(float, r[4:7])))
                 for r in read_csv("conductors_rgb.csv")[1]}
#: Mitsuba 3's conductor material when none is given.
DEFAULT_CONDUCTOR = "Cu"
