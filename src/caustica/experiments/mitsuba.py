"""Mitsuba 3 as the peer renderer: its path tracer at equal wall time (``scalar_rgb``, the test dependency)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..scene import builtin_scene_path

MITSUBA_SPP_PER_PASS = 4
#: Mitsuba's render(spp, seed) is a prefix of render(more spp, same seed), and shared/refs was rendered
#: in passes seeded 0, 1, 2, ...: the peer's passes start far past those seeds, so that its samples are
#: independent of the reference's (peer_floor assumes it).
MITSUBA_SEED_BASE = 1 << 20


def mitsuba_module():
    """Mitsuba 3 with the scalar_rgb variant, or None when it is not installed."""
    try:
        import mitsuba as mi
        mi.set_variant("scalar_rgb")
    except Exception:  # not installed, or the variant is not compiled in: the peer column is left out
        return None
    return mi


def mitsuba_equal_time(mi, scene_name, res, budget_s, seed, **params):
    """Mitsuba's path tracer, passes of a few spp (new seed each) until the next would cross the budget.

    ``scene_name``: a built-in scene's name, or the path of an XML file; ``params``: its ``<default>`` values.
    Returns (image, wall seconds, spp)."""
    path = scene_name if isinstance(scene_name, Path) else builtin_scene_path(scene_name)
    scene = mi.load_file(str(path), res=res, **params)
    mi.render(scene, spp=1, seed=2**31)   # untimed, as caustica's warm-up
    acc = None
    passes = 0
    t0 = time.perf_counter()
    last = 0.0
    while passes == 0 or time.perf_counter() - t0 + last <= budget_s:
        t1 = time.perf_counter()
        img = np.array(mi.render(scene, spp=MITSUBA_SPP_PER_PASS,
                                 seed=(MITSUBA_SEED_BASE + seed * 100_003 + passes) % 2**32),
                       dtype=np.float64)[..., :3]
        acc = img if acc is None else acc + img
        passes += 1
        last = time.perf_counter() - t1
    return (acc / passes).astype(np.float32), time.perf_counter() - t0, passes * MITSUBA_SPP_PER_PASS
