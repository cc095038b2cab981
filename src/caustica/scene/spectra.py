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

The tables (``data/cie1931_d65.csv``) are the CIE 1931 2-degree standard observer (x-bar, y-bar, z-bar) and the
CIE standard illuminant D65 (relative, 100 at 560 nm), both at 5 nm from 360 to 830 nm: the CIE's published data (CIE 018:2019 / ISO/CIE
11664-1 and 11664-2; also at http://cvrl.ucl.ac.uk), here as Mitsuba 3 tabulates them (src/core/spectrum.cpp
and include/mitsuba/core/spectrum.h, BSD-3-Clause, Copyright (c) 2017 Wenzel Jakob), so that the conversion agrees
with Mitsuba's to rounding.
"""
from __future__ import annotations

import math

import numpy as np

from .data import read_csv

#: (wavelength nm, x-bar, y-bar, z-bar, D65) every 5 nm from 360 to 830 nm (data/cie1931_d65.csv).
CIE_TABLE = np.array(read_csv("cie1931_d65.csv")[1], dtype=np.float64)

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
