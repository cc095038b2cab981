"""Spectra in Mitsuba 3 XML (``<spectrum>``) converted to linear RGB as Mitsuba 3's RGB variants convert them.

A ``<spectrum value="0.5"/>`` is a constant; ``value="400:0.1, 500:0.4, 600:0.9"`` gives wavelength (nm):value
pairs, linearly interpolated between them and zero outside them; ``filename="x.spd"`` reads the pairs from a text
file (one "wavelength value" pair per line, ``#`` comments).  In Mitsuba 3's RGB variants (src/core/properties.cpp,
get_texture; src/core/spectrum.cpp, spectrum_list_to_srgb):

* a constant c is (c, c, c), except for an emitter, where it is c x xyz_to_srgb(1, 1, 1) (a flat spectrum is not
  white under sRGB's D65 white point);
* pairs are integrated against the CIE 1931 colour matching functions at 1000 evenly spaced wavelengths over
  360-830 nm, weighted by the CIE D65 illuminant unless they are an emitter's, normalised so that a flat
  spectrum of 1 has luminance 1, converted from XYZ to linear sRGB (Rec. 709 primaries) and clamped to [0, 1]
  for reflectances (to >= 0 for emitters and unbounded quantities such as a medium's sigma_t).

The tables below are the CIE 1931 2-degree standard observer (x-bar, y-bar, z-bar) and the CIE standard illuminant
D65 (relative, 100 at 560 nm), both at 5 nm from 360 to 830 nm: the CIE's published data (CIE 018:2019 / ISO/CIE
11664-1 and 11664-2; also at http://cvrl.ucl.ac.uk), here as Mitsuba 3 tabulates them (src/core/spectrum.cpp
and include/mitsuba/core/spectrum.h, BSD-3-Clause, Copyright (c) 2017 Wenzel Jakob), so that the conversion agrees
with Mitsuba's to rounding.
"""
from __future__ import annotations

import math

import numpy as np

#: (wavelength nm, x-bar, y-bar, z-bar, D65) every 5 nm from 360 to 830 nm.
CIE_TABLE = np.array([
    (360, 0.0001299, 3.917e-06, 0.0006061, 46.6383),
    (365, 0.0002321, 6.965e-06, 0.001086, 49.3637),
    (370, 0.0004149, 1.239e-05, 0.001946, 52.0891),
    (375, 0.0007416, 2.202e-05, 0.003486, 51.0323),
    (380, 0.001368, 3.9e-05, 0.006450001, 49.9755),
    (385, 0.002236, 6.4e-05, 0.01054999, 52.3118),
    (390, 0.004243, 0.00012, 0.02005001, 54.6482),
    (395, 0.00765, 0.000217, 0.03621, 68.7015),
    (400, 0.01431, 0.000396, 0.06785001, 82.7549),
    (405, 0.02319, 0.00064, 0.1102, 87.1204),
    (410, 0.04351, 0.00121, 0.2074, 91.486),
    (415, 0.07763, 0.00218, 0.3713, 92.4589),
    (420, 0.13438, 0.004, 0.6456, 93.4318),
    (425, 0.21477, 0.0073, 1.0390501, 90.057),
    (430, 0.2839, 0.0116, 1.3856, 86.6823),
    (435, 0.3285, 0.01684, 1.62296, 95.7736),
    (440, 0.34828, 0.023, 1.74706, 104.865),
    (445, 0.34806, 0.0298, 1.7826, 110.936),
    (450, 0.3362, 0.038, 1.77211, 117.008),
    (455, 0.3187, 0.048, 1.7441, 117.41),
    (460, 0.2908, 0.06, 1.6692, 117.812),
    (465, 0.2511, 0.0739, 1.5281, 116.336),
    (470, 0.19536, 0.09098, 1.28764, 114.861),
    (475, 0.1421, 0.1126, 1.0419, 115.392),
    (480, 0.09564, 0.13902, 0.8129501, 115.923),
    (485, 0.05795001, 0.1693, 0.6162, 112.367),
    (490, 0.03201, 0.20802, 0.46518, 108.811),
    (495, 0.0147, 0.2586, 0.3533, 109.082),
    (500, 0.0049, 0.323, 0.272, 109.354),
    (505, 0.0024, 0.4073, 0.2123, 108.578),
    (510, 0.0093, 0.503, 0.1582, 107.802),
    (515, 0.0291, 0.6082, 0.1117, 106.296),
    (520, 0.06327, 0.71, 0.07824999, 104.79),
    (525, 0.1096, 0.7932, 0.05725001, 106.239),
    (530, 0.1655, 0.862, 0.04216, 107.689),
    (535, 0.2257499, 0.9148501, 0.02984, 106.047),
    (540, 0.2904, 0.954, 0.0203, 104.405),
    (545, 0.3597, 0.9803, 0.0134, 104.225),
    (550, 0.4334499, 0.9949501, 0.008749999, 104.046),
    (555, 0.5120501, 1.0, 0.005749999, 102.023),
    (560, 0.5945, 0.995, 0.0039, 100.0),
    (565, 0.6784, 0.9786, 0.002749999, 98.1671),
    (570, 0.7621, 0.952, 0.0021, 96.3342),
    (575, 0.8425, 0.9154, 0.0018, 96.0611),
    (580, 0.9163, 0.87, 0.001650001, 95.788),
    (585, 0.9786, 0.8163, 0.0014, 92.2368),
    (590, 1.0263, 0.757, 0.0011, 88.6856),
    (595, 1.0567, 0.6949, 0.001, 89.3459),
    (600, 1.0622, 0.631, 0.0008, 90.0062),
    (605, 1.0456, 0.5668, 0.0006, 89.8026),
    (610, 1.0026, 0.503, 0.00034, 89.5991),
    (615, 0.9384, 0.4412, 0.00024, 88.6489),
    (620, 0.8544499, 0.381, 0.00019, 87.6987),
    (625, 0.7514, 0.321, 0.0001, 85.4936),
    (630, 0.6424, 0.265, 4.999999e-05, 83.2886),
    (635, 0.5419, 0.217, 3e-05, 83.4939),
    (640, 0.4479, 0.175, 2e-05, 83.6992),
    (645, 0.3608, 0.1382, 1e-05, 81.863),
    (650, 0.2835, 0.107, 0.0, 80.0268),
    (655, 0.2187, 0.0816, 0.0, 80.1207),
    (660, 0.1649, 0.061, 0.0, 80.2146),
    (665, 0.1212, 0.04458, 0.0, 81.2462),
    (670, 0.0874, 0.032, 0.0, 82.2778),
    (675, 0.0636, 0.0232, 0.0, 80.281),
    (680, 0.04677, 0.017, 0.0, 78.2842),
    (685, 0.0329, 0.01192, 0.0, 74.0027),
    (690, 0.0227, 0.00821, 0.0, 69.7213),
    (695, 0.01584, 0.005723, 0.0, 70.6652),
    (700, 0.01135916, 0.004102, 0.0, 71.6091),
    (705, 0.008110916, 0.002929, 0.0, 72.979),
    (710, 0.005790346, 0.002091, 0.0, 74.349),
    (715, 0.004109457, 0.001484, 0.0, 67.9765),
    (720, 0.002899327, 0.001047, 0.0, 61.604),
    (725, 0.00204919, 0.00074, 0.0, 65.7448),
    (730, 0.001439971, 0.00052, 0.0, 69.8856),
    (735, 0.0009999493, 0.0003611, 0.0, 72.4863),
    (740, 0.0006900786, 0.0002492, 0.0, 75.087),
    (745, 0.0004760213, 0.0001719, 0.0, 69.3398),
    (750, 0.0003323011, 0.00012, 0.0, 63.5927),
    (755, 0.0002348261, 8.48e-05, 0.0, 55.0054),
    (760, 0.0001661505, 6e-05, 0.0, 46.4182),
    (765, 0.000117413, 4.24e-05, 0.0, 56.6118),
    (770, 8.307527e-05, 3e-05, 0.0, 66.8054),
    (775, 5.870652e-05, 2.12e-05, 0.0, 65.0941),
    (780, 4.150994e-05, 1.499e-05, 0.0, 63.3828),
    (785, 2.935326e-05, 1.06e-05, 0.0, 63.8434),
    (790, 2.067383e-05, 7.4657e-06, 0.0, 64.304),
    (795, 1.455977e-05, 5.2578e-06, 0.0, 61.8779),
    (800, 1.025398e-05, 3.7029e-06, 0.0, 59.4519),
    (805, 7.221456e-06, 2.6078e-06, 0.0, 55.7054),
    (810, 5.085868e-06, 1.8366e-06, 0.0, 51.959),
    (815, 3.581652e-06, 1.2934e-06, 0.0, 54.6998),
    (820, 2.522525e-06, 9.1093e-07, 0.0, 57.4406),
    (825, 1.776509e-06, 6.4153e-07, 0.0, 58.8765),
    (830, 1.251141e-06, 4.5181e-07, 0.0, 60.3125),
], dtype=np.float64)

CIE_MIN, CIE_MAX = 360.0, 830.0
#: A flat spectrum of 1 integrates to a luminance of 1 with this factor (Mitsuba's MI_CIE_Y_NORMALIZATION).
CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625
#: D65 scaled by this integrates to a luminance of 1 (Mitsuba's MI_CIE_D65_NORMALIZATION).
CIE_D65_NORMALIZATION = 1.0 / 98.99741751876255
#: XYZ to linear sRGB (Rec. 709 primaries, D65 white), as Mitsuba's xyz_to_srgb.
XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])
#: The number of steps of Mitsuba's integration.
STEPS = 1000


def _table_at(w: np.ndarray) -> np.ndarray:
    """The table's columns (x, y, z, D65) linearly interpolated at wavelengths w (in [360, 830])."""
    t = (w - CIE_MIN) * ((len(CIE_TABLE) - 1) / (CIE_MAX - CIE_MIN))
    i0 = np.clip(t.astype(np.int64), 0, len(CIE_TABLE) - 2)
    f = (t - i0)[:, None]
    return (1.0 - f) * CIE_TABLE[i0, 1:] + f * CIE_TABLE[i0 + 1, 1:]


def constant_to_rgb(value: float, emitter: bool) -> tuple[float, float, float]:
    """A constant spectrum's RGB: (v, v, v), or v x xyz_to_srgb(1, 1, 1) for an emitter (as Mitsuba's RGB variants)."""
    if not emitter:
        return (float(value),) * 3
    return tuple(float(value * c) for c in XYZ_TO_SRGB.sum(axis=1))


def pairs_to_rgb(wavelengths, values, emitter: bool, unbounded: bool = False) -> tuple[float, float, float]:
    """wavelength:value pairs (wavelengths strictly increasing, at least 2) to linear sRGB, as Mitsuba 3's
    spectrum_list_to_srgb(bounded=not (emitter or unbounded), d65=not emitter)."""
    wl = np.asarray(wavelengths, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    w = CIE_MIN + (np.arange(STEPS) / (STEPS - 1)) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wl[0]) & (w <= wl[-1])]
    if len(w) == 0:
        return (0.0, 0.0, 0.0)
    s = np.interp(w, wl, v)
    tab = _table_at(w)
    weight = s * (1.0 if emitter else tab[:, 3] * CIE_D65_NORMALIZATION)
    xyz = (tab[:, :3] * weight[:, None]).sum(axis=0) * ((CIE_MAX - CIE_MIN) * CIE_Y_NORMALIZATION / STEPS)
    rgb = XYZ_TO_SRGB @ xyz
    rgb = np.maximum(rgb, 0.0) if (emitter or unbounded) else np.clip(rgb, 0.0, 1.0)
    return tuple(float(c) for c in rgb)


def parse_spectrum(text: str) -> float | tuple[list[float], list[float]]:
    """A ``<spectrum value=...>``: a float (a constant) or (wavelengths, values); ValueError saying what is wrong
    (a value that is not a number, a pair without ':', fewer than 2 pairs, wavelengths not increasing)."""
    tokens = [t for t in text.replace(",", " ").split() if t]
    if len(tokens) == 1 and ":" not in tokens[0]:
        try:
            v = float(tokens[0])
        except ValueError:
            raise ValueError(f"{tokens[0]!r} is not a number; a spectrum is one number or wavelength:value "
                             f"pairs") from None
        if not math.isfinite(v):
            raise ValueError(f"{tokens[0]!r} is not a finite number")
        return v
    wl, vals = [], []
    for tok in tokens:
        parts = tok.split(":")
        if len(parts) != 2:
            raise ValueError(f"{tok!r} is not a wavelength:value pair (e.g. 400:0.5)")
        try:
            a, b = float(parts[0]), float(parts[1])
        except ValueError:
            raise ValueError(f"{tok!r} is not a pair of numbers (e.g. 400:0.5)") from None
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"{tok!r} is not a pair of finite numbers")
        wl.append(a)
        vals.append(b)
    return check_pairs(wl, vals)


def check_pairs(wl: list[float], vals: list[float]) -> tuple[list[float], list[float]]:
    if len(wl) < 2:
        raise ValueError(f"a spectrum of wavelength:value pairs needs at least 2 pairs, got {len(wl)}")
    for i in range(1, len(wl)):
        if not wl[i] > wl[i - 1]:
            raise ValueError(f"wavelengths must increase, but {wl[i]:g} follows {wl[i - 1]:g}")
    return wl, vals


def read_spd(path) -> tuple[list[float], list[float]]:
    """An .spd file (Mitsuba's): "wavelength value" per line, '#' comments; ValueError naming the line."""
    wl, vals = [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for n, line in enumerate(f, 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.replace(",", " ").split()
            try:
                if len(parts) != 2:
                    raise ValueError
                a, b = float(parts[0]), float(parts[1])
                if not (math.isfinite(a) and math.isfinite(b)):
                    raise ValueError
            except ValueError:
                raise ValueError(f"line {n} of {path} is not 'wavelength value'") from None
            wl.append(a)
            vals.append(b)
    return check_pairs(wl, vals)
