"""scripts/mitsuba_corpus_compare.py's verdicts and its Mitsuba side, without the corpus (tests/test_mitsuba_corpus.py
renders the corpus itself when it is there)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "mitsuba_corpus_compare.py"


def script():
    spec = importlib.util.spec_from_file_location("mitsuba_corpus_compare", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def noisy(mean, seed):
    rng = np.random.default_rng(seed)
    return [np.clip(rng.normal(mean, 0.05 * mean, (16, 16, 3)), 0, None) for _ in range(4)]


def test_verdicts():
    cmp = script()
    black = [np.zeros((16, 16, 3)) for _ in range(4)]
    assert cmp.compare(black, black)["verdict"] == "agree"          # two black images: nothing differs
    assert cmp.compare(noisy(0.5, 1), black)["verdict"] == "differs"
    assert cmp.compare(noisy(0.5, 1), noisy(0.5, 2))["verdict"] == "agree"
    assert cmp.compare(noisy(0.55, 1), noisy(0.5, 2))["verdict"] == "differs"   # 10 % brighter


def test_a_scene_without_an_integrator_gets_mitsubas_path_tracer(mi, tmp_path):
    """Mitsuba's render() refuses a scene with no <integrator>; caustica renders it with pt, so the script gives
    Mitsuba its path tracer and says so."""
    path = tmp_path / "no-integrator.xml"
    path.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                    '<integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>'
                    '<emitter type="constant"><rgb name="radiance" value="0.5"/></emitter></scene>')
    notes = []
    images, spp, _ = script().render_mitsuba(mi, path, (8, 8), 0.5, 8, notes)
    assert len(images) == 4 and spp >= 4
    assert all(abs(float(img.mean()) - 0.5) < 1e-3 for img in images)     # the sky seen directly
    assert notes and "path tracer" in notes[0]
