"""scripts/mitsuba_corpus_compare.py's verdicts and its Mitsuba side, without the corpus (tests/test_mitsuba_corpus.py
renders the corpus itself when it is there)."""
from __future__ import annotations

import importlib.util
import sys
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


def test_fetch_independent_selects_the_other_repositories(tmp_path, monkeypatch):
    """scripts/fetch_mitsuba_scenes.py --independent fetches INDEPENDENT (into out/mitsuba-independent unless --dest),
    without it SOURCES; the fetching itself is replaced here (it needs the network or local mirrors)."""
    path = SCRIPT.parent / "fetch_mitsuba_scenes.py"
    spec = importlib.util.spec_from_file_location("fetch_mitsuba_scenes", path)
    fetch = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "fetch_mitsuba_scenes", fetch)   # its dataclass looks its module up there
    spec.loader.exec_module(fetch)
    got = []
    monkeypatch.setattr(fetch, "fetch", lambda src, dest, mirror: got.append((src.repo, dest)) or dest)
    monkeypatch.setattr(fetch, "write_sources", lambda dest, fetched: None)
    monkeypatch.chdir(tmp_path)
    assert fetch.main(["--independent"]) == 0
    assert [r for r, _ in got] == [s.repo for s in fetch.INDEPENDENT] and got[0][1] == Path("out/mitsuba-independent")
    assert not {s.repo for s in fetch.INDEPENDENT} & {s.repo for s in fetch.SOURCES}
    got.clear()
    assert fetch.main(["--dest", str(tmp_path / "c")]) == 0
    assert [r for r, _ in got] == [s.repo for s in fetch.SOURCES] and got[0][1] == tmp_path / "c"
