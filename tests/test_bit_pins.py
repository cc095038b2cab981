"""Bit pins: small renders of every method and option family, pinned by the hash of their pixels.

A refactor of the transport code must keep these images bit for bit (issue 18): the test renders
each case with a fixed seed and compares the SHA-256 of its float32 pixels with ``bit_pins.json``.
A change that is meant to change an image (a fix) updates the pins in the same commit and says why:

    .venv/bin/python tests/test_bit_pins.py --update [CASE ...]

The pins hold on the machine kind the project runs on (CI runs on the same kind); Numba compiles
without fastmath, so the arithmetic is IEEE and the same for any thread count.
"""
from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

PINS_FILE = Path(__file__).resolve().parent / "bit_pins.json"

DIA = "cornell-diacaustic"
CATA = "cornell-catacaustic"
FOG = "cornell-diacaustic-fog"
SCENES = Path(__file__).resolve().parent / "scenes"
#: The feature scenes of tests/scenes (the branches the Cornell boxes do not take: coatings, normal maps, glossy
#: lobes, mixtures, media behind glass, volpath's thin dielectric); a (file, (old, new)) pair renders a copy of the
#: file with one string replaced.
PLASTIC, NORMALMAP, PPLASTIC = SCENES / "plastic.xml", SCENES / "normalmap.xml", SCENES / "pplastic.xml"
GLOSSY, MASK, BLEND, MEDIA_GLASS = (SCENES / "glossy-caustic.xml", SCENES / "mask.xml", SCENES / "blend.xml",
                                    SCENES / "media-glass.xml")
THIN_VOLPATH = (SCENES / "thindielectric.xml", ('<integrator type="path"/>', '<integrator type="volpath"/>'))

#: name -> (scene, method, render keywords).  Small images and budgets: the pins are about bits,
#: not quality, but each case goes through every branch of its method (glass and mirror chains,
#: diffuse bounces, media, the caustic map, split streams, and the feature scenes' materials).
CASES = {
    "pt": (DIA, "pt", dict(res=24, spp=4, passes=2)),
    "pt-cata-rr": (CATA, "pt", dict(res=24, spp=4, rr_depth=2, max_depth=8)),
    "pm": (DIA, "pm", dict(res=24, photons=4000, k=20)),
    "pm-roulette-cone": (CATA, "pm", dict(res=24, photons=4000, k=20, termination="roulette", filter="cone")),
    "pmc": (DIA, "pm", dict(res=24, photons=3000, caustic_photons=3000, k=20)),
    "spm": (DIA, "spm", dict(res=24, streams=600, assoc=5, k=20)),
    "spm-photons": (CATA, "spm", dict(res=24, streams=600, assoc=5, k=20, estimator="photons",
                                      termination="roulette")),
    "sppm": (DIA, "sppm", dict(res=24, passes=3)),
    "sppm-caustic-disc": (DIA, "sppm", dict(res=24, passes=3, caustic_filter="none")),
    "sppm-plain-shared": (CATA, "sppm", dict(res=24, passes=3, caustic_photons=0)),
    "sppm-global": (DIA, "sppm", dict(res=24, passes=3, schedule="global", caustic_statistics="shared")),
    "pspm-merge": (DIA, "pspm", dict(res=24, passes=3)),
    "pspm-photons-caustic": (CATA, "pspm", dict(res=24, passes=3, estimator="photons", caustic_photons=300)),
    "pspm-split": (DIA, "pspm", dict(res=24, passes=3, specular="split", stream_radius=1.0)),
    "pspm-split-cata": (CATA, "pspm", dict(res=24, passes=3, specular="split", stream_radius=1.0,
                                           estimator="photons")),
    "pt-fog": (FOG, "pt", dict(res=16, spp=4)),
    "pm-fog": (FOG, "pm", dict(res=16, photons=3000, k=20)),
    "spm-fog": (FOG, "spm", dict(res=16, streams=500, assoc=4, k=20)),
    "sppm-fog": (FOG, "sppm", dict(res=16, passes=2)),
    "pspm-fog-merge": (FOG, "pspm", dict(res=16, passes=2)),
    "pspm-fog-spread": (FOG, "pspm", dict(res=16, passes=2, medium_scattering="spread", estimator="photons")),
    "pt-normalmap": (NORMALMAP, "pt", dict(res=16, spp=4)),
    "pt-thin-volpath": (THIN_VOLPATH, "pt", dict(res=16, spp=4)),
    "pm-plastic": (PLASTIC, "pm", dict(res=16, photons=3000, k=10)),
    "pm-normalmap": (NORMALMAP, "pm", dict(res=16, photons=3000, k=10)),
    "pm-glossy": (GLOSSY, "pm", dict(res=16, photons=3000, k=10)),
    "pm-thin-volpath": (THIN_VOLPATH, "pm", dict(res=16, photons=3000, k=10)),
    "spm-glossy": (GLOSSY, "spm", dict(res=16, streams=500, assoc=4, k=10)),
    "spm-thin-volpath": (THIN_VOLPATH, "spm", dict(res=16, streams=500, assoc=4, k=10)),
    "sppm-plastic": (PLASTIC, "sppm", dict(res=16, passes=2)),
    "sppm-normalmap": (NORMALMAP, "sppm", dict(res=16, passes=2)),
    "sppm-pplastic": (PPLASTIC, "sppm", dict(res=16, passes=2)),
    "sppm-glossy": (GLOSSY, "sppm", dict(res=16, passes=2)),
    "sppm-glossy-depth": (GLOSSY, "sppm", dict(res=16, passes=2, max_depth=5)),
    "sppm-mask": (MASK, "sppm", dict(res=16, passes=2)),
    "sppm-blend": (BLEND, "sppm", dict(res=16, passes=2)),
    "sppm-media-glass": (MEDIA_GLASS, "sppm", dict(res=16, passes=2)),
    "sppm-thin-volpath": (THIN_VOLPATH, "sppm", dict(res=16, passes=2)),
    "pspm-glossy-split": (GLOSSY, "pspm", dict(res=16, passes=2, specular="split", stream_radius=1.0)),
    "pspm-thin-volpath": (THIN_VOLPATH, "pspm", dict(res=16, passes=2)),
}


def render_hash(name: str, threads: int = 2) -> str:
    import caustica

    scene, method, kw = CASES[name]
    with tempfile.TemporaryDirectory() as tmp:
        if isinstance(scene, tuple):
            (path, (old, new)), scene = scene, Path(tmp) / scene[0].name
            text = path.read_text()
            assert old in text, f"{name}: {old!r} is not in {path}"
            scene.write_text(text.replace(old, new))
        result = caustica.render(str(scene), method=method, seed=3, threads=threads, **kw)
    image = np.ascontiguousarray(result.image, dtype=np.float32)
    return hashlib.sha256(image.tobytes()).hexdigest()[:20]


def load_pins() -> dict:
    return json.loads(PINS_FILE.read_text()) if PINS_FILE.exists() else {}


@pytest.mark.parametrize("name", sorted(CASES))
def test_image_bits_are_pinned(name):
    pins = load_pins()
    if name not in pins:
        pytest.fail(f"no pin for {name!r}: run `python tests/test_bit_pins.py --update {name}`")
    assert render_hash(name) == pins[name], (
        f"{name}: the image's bits changed; if the change is meant (a fix), update the pin and say why in "
        f"the commit")


def test_pins_do_not_depend_on_the_thread_count():
    name = "pspm-split"
    assert render_hash(name, threads=1) == load_pins()[name]


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args or args[0] != "--update":
        sys.exit("usage: python tests/test_bit_pins.py --update [CASE ...]")
    names = args[1:] or sorted(CASES)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        sys.exit(f"unknown cases {unknown}; known: {', '.join(sorted(CASES))}")
    pins = load_pins()
    for n in names:
        new = render_hash(n)
        print(f"{n:24s} {pins.get(n, '-'):22s} -> {new}{'' if pins.get(n) == new else '  (changed)'}")
        pins[n] = new
    PINS_FILE.write_text(json.dumps(dict(sorted(pins.items())), indent=1) + "\n")
