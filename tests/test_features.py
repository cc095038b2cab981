"""Feature-specialised tables (caustica.features): kernels compiled for a scene's kinds alone render the same bits.

A scene's material and light tables are instances of classes that say which kinds they may hold; kernels compile
the code of those kinds only (``has``).  The paper's scenes get the core set; any other kind gets every kind's
code.  The images must not depend on it: the bit pins (tests/test_bit_pins.py) are rendered with the core set,
and here the same cases with tables of the base classes (every kind compiled) give the pinned bits too.
"""
from __future__ import annotations

import hashlib
import pickle
from pathlib import Path

import numba
import numpy as np
import pytest

import caustica
from caustica.bsdfs import MaterialTable
from caustica.emitters import LightTable
from caustica.features import ALL, bits, features_of, guarded_by, has, specialised
from caustica.jit import KernelCompiler, kernel
from caustica.scene.description import BUMPMAP, CONDUCTOR, DIELECTRIC, NORMALMAP, PLASTIC
from caustica.tables import CORE_LIGHTS, CORE_MATERIALS

from test_bit_pins import CASES, load_pins

SCENES = Path(__file__).resolve().parent / "scenes"


@pytest.mark.parametrize("name", ["cornell-diacaustic", "cornell-catacaustic", "cornell-diacaustic-fog"])
def test_the_papers_scenes_compile_the_core_kinds(name):
    scene = caustica.load_scene(name)
    assert features_of(scene.materials) == CORE_MATERIALS
    assert features_of(scene.lights) == CORE_LIGHTS


def test_a_scene_beyond_the_core_compiles_every_kind():
    scene = caustica.load_scene(str(SCENES / "glossy-caustic.xml"))   # a rough conductor ring
    assert type(scene.materials) is MaterialTable and type(scene.lights) is LightTable
    assert features_of(scene.materials) == ALL


def test_specialised_tables_keep_their_class_through_replace_and_pickle():
    mats = caustica.load_scene("cornell-diacaustic").materials
    cls = type(mats)
    assert cls is not MaterialTable and isinstance(mats, MaterialTable)
    assert type(mats._replace(flags=mats.flags.copy())) is cls
    back = pickle.loads(pickle.dumps(mats))
    assert type(back) is cls and all(np.array_equal(a, b) for a, b in zip(back, mats))
    assert pickle.loads(pickle.dumps(cls)) is cls   # as Numba's cache index stores the class
    assert specialised(MaterialTable, ALL) is MaterialTable


@kernel
def _has_plastic_and_conductor(mats):
    return has(mats, PLASTIC), has(mats, CONDUCTOR)


def test_has_is_decided_by_the_tables_type():
    core = caustica.load_scene("cornell-diacaustic").materials
    assert _has_plastic_and_conductor(core) == (False, True)
    assert _has_plastic_and_conductor(MaterialTable(*core)) == (True, True)
    only_glass = specialised(MaterialTable, 1 << DIELECTRIC)(*core)
    assert _has_plastic_and_conductor(only_glass) == (False, False)


# Not cached (plain njit with the kernels' pipeline), so that what is compiled is what this process compiled.
@numba.njit
def _under_plastic_as_argument():
    return 1.0


@numba.njit
def _under_plastic_as_item():
    return 2.0


@numba.njit
def _under_plastic_unpacked():
    return 3.0


@numba.njit(pipeline_class=KernelCompiler)
def _plastic_branches(mats, tables):
    """``has`` on an argument, on an item of a tuple argument, on a name unpacked from one: the three ways kernels
    reach their tables."""
    total = 0.0
    if has(mats, PLASTIC):
        total += _under_plastic_as_argument()
    second = tables[1]
    if has(second, PLASTIC):
        total += _under_plastic_as_item()
    _, third = tables
    if has(third, PLASTIC):
        total += _under_plastic_unpacked()
    return total


def test_the_code_of_a_missing_kind_is_not_even_compiled():
    """jit.FoldFeatureTests: ``has`` is folded before typing, so the callees of a missing kind's branch are never
    typed or compiled (they were, for LLVM to drop them: a third of the paper's scene's cold start).  With every
    kind, each callee is compiled and taken."""
    core = caustica.load_scene("cornell-diacaustic").materials
    callees = (_under_plastic_as_argument, _under_plastic_as_item, _under_plastic_unpacked)
    assert _plastic_branches(core, (core, core)) == 0.0
    assert [len(k.signatures) for k in callees] == [0, 0, 0]
    every = MaterialTable(*core)
    assert _plastic_branches(every, (every, every)) == 6.0
    assert [len(k.signatures) for k in callees] == [1, 1, 1]


@numba.njit
def _under_a_map():
    return 1.0


@guarded_by(NORMALMAP, BUMPMAP)
@numba.njit(pipeline_class=KernelCompiler)
def _maps_here(mats, m):
    """A guard as bsdfs.perturb.wrapped is one: False without either feature, else decided per row."""
    return (has(mats, NORMALMAP) or has(mats, BUMPMAP)) and m >= 0


@numba.njit(pipeline_class=KernelCompiler)
def _map_branch(mats, m):
    if _maps_here(mats, m):
        return _under_a_map()
    return 0.0


def test_a_guarded_kernels_branch_is_not_compiled_where_its_features_are_missing():
    """features.guarded_by: a call to a kernel marked with the features it needs is folded to False before typing
    where the table holds none of them, so its caller's branch goes as a ``has`` test's does (a kernel is compiled
    apart, so the ``has`` inside it could not prune the caller).  Where the table may hold one, the call stays and
    decides at run time.  (On the paper's spm render, 2026-12-07: 301 -> 246 compilations, compile CPU -18 %: docs/results.md.)"""
    core = caustica.load_scene("cornell-diacaustic").materials
    assert _map_branch(core, 0) == 0.0
    assert len(_under_a_map.signatures) == 0
    every = MaterialTable(*core)
    assert _map_branch(every, 0) == 1.0 and _map_branch(every, -1) == 0.0
    assert len(_under_a_map.signatures) == 1


def test_the_media_table_says_whether_paths_meet_media_or_cross_surfaces():
    """The media table's features, rounded to three sets (media.medium_features): none in a scene without media or
    null surfaces (media.in_a_medium is then folded to False: the loops' medium code is not compiled), HOMOGENEOUS |
    CROSSABLE with homogeneous media or null surfaces (a mask; the copy with volpath's null thin dielectric), every
    feature with a grid medium."""
    from caustica.media import CROSSABLE
    from caustica.scene.description import HETEROGENEOUS, HOMOGENEOUS
    scenes = Path(__file__).resolve().parent / "scenes"
    every = bits(HOMOGENEOUS, HETEROGENEOUS, CROSSABLE)
    some = bits(HOMOGENEOUS, CROSSABLE)
    assert features_of(caustica.load_scene("cornell-diacaustic").media) & every == 0
    assert features_of(caustica.load_scene(scenes / "mask.xml").media) & every == some
    thin = caustica.load_scene(scenes / "thindielectric.xml")
    assert features_of(thin.media) & every == 0
    assert features_of(thin.with_null_thin_dielectric().media) & every == some
    assert features_of(caustica.load_scene("cornell-diacaustic-fog").media) & every == some


@pytest.mark.parametrize("name", sorted({str(scene) for scene, _, _ in CASES.values() if not isinstance(scene, tuple)}))
def test_a_media_tables_features_cover_what_it_holds(name):
    """What the kernels skip where the media table lacks a feature must never be there: a medium index (the camera's,
    a shape's side) needs HOMOGENEOUS, null surfaces (shadow rays crossing) CROSSABLE; the volpath copy too.  Over the
    bit pins' scenes."""
    from caustica.media import CROSSABLE
    from caustica.scene.description import HOMOGENEOUS
    scene = caustica.load_scene(name)
    for media in (scene.media, scene.with_null_thin_dielectric().media):
        held = features_of(media)
        if media.camera[0] >= 0 or np.any(media.interior >= 0) or np.any(media.exterior >= 0):
            assert held & bits(HOMOGENEOUS)
        if media.null_surfaces[0] != 0:
            assert held & bits(CROSSABLE)


@numba.njit(pipeline_class=KernelCompiler)
def _has_then_reassigned(mats, change):
    ok = has(mats, CONDUCTOR)
    if change:
        ok = False
    if ok:
        return 1
    return 0


def test_a_folded_test_keeps_the_variables_other_assignments():
    """A variable assigned from ``has`` and again elsewhere keeps both values (the fold's first version replaced the
    variable's every definition by the constant, and the branch on it was pruned as if it could not change)."""
    core = caustica.load_scene("cornell-diacaustic").materials   # holds conductors
    assert _has_then_reassigned(core, False) == 1
    assert _has_then_reassigned(core, True) == 0


@pytest.mark.parametrize("name", ["pt", "pm", "spm", "sppm", "pspm-split", "pt-fog", "sppm-fog"])
def test_every_kind_compiled_gives_the_pinned_bits(name):
    scene_name, method, kw = CASES[name]
    scene = caustica.load_scene(scene_name)
    scene.materials = MaterialTable(*scene.materials)
    scene.lights = LightTable(*scene.lights)
    result = caustica.render(scene, method=method, seed=3, threads=2, **kw)
    image = np.ascontiguousarray(result.image, dtype=np.float32)
    assert hashlib.sha256(image.tobytes()).hexdigest()[:20] == load_pins()[name]
