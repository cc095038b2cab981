"""Published Mitsuba 3 scenes (scripts/fetch_mitsuba_scenes.py): every one loads or is refused cleanly.

The corpus is not part of the repository: fetch it with ``python scripts/fetch_mitsuba_scenes.py`` (into
out/mitsuba-corpus) or point ``CAUSTICA_MITSUBA_CORPUS`` at a copy; without it these tests are skipped.
"""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

from caustica.errors import SceneError
from caustica.scene import load_scene_file

REPO = Path(__file__).resolve().parents[1]
CORPUS = Path(os.environ.get("CAUSTICA_MITSUBA_CORPUS", REPO / "out" / "mitsuba-corpus"))
#: Scenes that load today (2026-12-03); the list only grows as the loader learns more.
LOADING = [
    "mitsuba-renderer+mitsuba-data/docs/scenes/integrator_depth_1.xml",
    "mitsuba-renderer+mitsuba-data/docs/scenes/integrator_depth_inf.xml",
    "mitsuba-renderer+mitsuba-data/docs/scenes/integrator_direct_both.xml",     # plastic and roughplastic
    "mitsuba-renderer+mitsuba-data/docs/scenes/integrator_direct_bsdf.xml",
    "mitsuba-renderer+mitsuba-data/docs/scenes/integrator_direct_lum.xml",
    "mitsuba-renderer+mitsuba-data/docs/scenes/variants_cbox_rgb.xml",
    "mitsuba-renderer+mitsuba-data/scenes/cbox/cbox-rgb.xml",
    "mitsuba-renderer+mitsuba-data/scenes/cbox/cbox.xml",
    "mitsuba-renderer+mitsuba-data/scenes/hello.xml",
    "mitsuba-renderer+mitsuba-data/tests/scenes/instancing/test_instancing_path.xml",
    "mitsuba-renderer+mitsuba-tutorials/scenes/cbox.xml",
    "mitsuba-renderer+mitsuba-tutorials/scenes/simple.xml",
    # with environment emitters (constant, envmap)
    "mitsuba-renderer+mitsuba-data/docs/scenes/bsdf_twosided_cbox.xml",
    "mitsuba-renderer+mitsuba-data/docs/scenes/bsdf_twosided_cbox_onesided.xml",
    "mitsuba-renderer+mitsuba-data/tests/scenes/infinite_mirrors/scene_path.xml",
    "mitsuba-renderer+mitsuba-data/tests/scenes/participating_media/test_homo_dielectric_envmap_volpath.xml",
]

pytestmark = pytest.mark.skipif(not (CORPUS / "SOURCES.md").is_file(),
                                reason=f"no Mitsuba scene corpus at {CORPUS} (scripts/fetch_mitsuba_scenes.py)")


def report_module():
    spec = importlib.util.spec_from_file_location("mitsuba_corpus_report", REPO / "scripts" / "mitsuba_corpus_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_published_scene_loads_or_is_refused_in_one_clean_message():
    scenes = report_module().find_scenes(CORPUS)
    assert len(scenes) > 100
    loaded = 0
    for path in scenes:
        try:
            load_scene_file(path)
            loaded += 1
        except SceneError as exc:
            msg = str(exc)
            lines = msg.split("\n")
            # one problem: one line; several: a count, then one line each, every one naming a file and line
            assert len(lines) == 1 or lines[0].endswith("problems, each with its file and line (and what is "
                                                        "supported there):"), msg
            for line in lines[1:] or lines:
                assert ".xml:" in line or ".serialized" in line or ".obj" in line or ".ply" in line, line
    assert loaded >= len(LOADING)


@pytest.mark.parametrize("name", LOADING)
def test_these_published_scenes_load(name):
    d = load_scene_file(CORPUS / name)
    assert d.shapes and d.camera.width > 0
