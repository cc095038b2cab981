"""Where an experiment's renders run: in this process (:class:`LocalRenders`) or on a Dask cluster.

The runner first *submits* every render an experiment makes and *collects* the results
afterwards, in the order its tables need them.  Here a submitted render is only
written down and runs when it is collected, so a local run renders, measures and
saves in exactly the order (and with the warm-ups and timings) of a plain loop.  On
a cluster (:mod:`caustica.experiments.dask_renders`) the same submissions are Dask
tasks that start at once and wait on the workers until collected.
"""
from __future__ import annotations

import time

from ..api import render

#: Size of the untimed warm-up render that precedes the first timed render of a configuration.
WARM_RES = (16, 16)
#: Keyword arguments of a render that its warm-up leaves out (it has its own size and seed, no budget).
NOT_WARMED = ("res", "seed", "time_s", "progress")


class Pending:
    """A render on its way: ``result()`` waits for it (or runs it) once and keeps the answer."""

    def __init__(self, get):
        self._get = get
        self._value = None

    def result(self):
        if self._get is not None:
            self._value, self._get = self._get(), None   # drop the future: the worker may free the result
        return self._value


def render_job(scene, method: str, kw: dict, warm, warmed: set, threads):
    """One render of an experiment on ``threads`` threads: (RenderResult, seconds around ``render``).

    ``warm`` is None or (key, seed): the first job of a key in this process (``warmed``
    holds the keys done) renders once untimed at WARM_RES with that seed first, so its
    kernels compile (or load from the cache) there and no timed render pays for it.
    A render that Ctrl-C cut short raises KeyboardInterrupt rather than being returned.
    """
    if warm is not None and warm[0] not in warmed:
        untimed = {k: v for k, v in kw.items() if k not in NOT_WARMED}
        render(scene, method, res=WARM_RES, seed=warm[1], threads=threads, **untimed)
        warmed.add(warm[0])
    t0 = time.perf_counter()
    result = render(scene, method, threads=threads, **kw)
    if result.stats.get("interrupted"):
        # Ctrl-C during a multi-pass render returns the passes finished so far: an experiment would score
        # them as if the render had run its budget.  It stops the experiment instead (exit 130).
        raise KeyboardInterrupt
    return result, time.perf_counter() - t0


class LocalRenders:
    """Renders in this process with ``threads`` threads, each when its result is collected."""

    def __init__(self, threads=None):
        self.threads = threads
        self.warmed = set()

    def submit(self, scene, method: str, *, warm=None, **kw) -> Pending:
        """A render of ``scene`` (``caustica.render``'s keywords); ``result()`` is (RenderResult, seconds)."""
        return Pending(lambda: render_job(scene, method, kw, warm, self.warmed, self.threads))

    def submit_mitsuba(self, scene_name: str, res: int, budget_s: float, seed: int) -> Pending:
        """Mitsuba 3's equal-time render (:func:`.mitsuba.mitsuba_equal_time`): (image, seconds, spp)."""
        from .mitsuba import mitsuba_equal_time, mitsuba_module
        return Pending(lambda: mitsuba_equal_time(mitsuba_module(), scene_name, res, budget_s, seed))

    def has_mitsuba(self) -> bool:
        from .mitsuba import mitsuba_module
        return mitsuba_module() is not None

    def describe(self):
        """Where the renders ran, for results.json (None: here)."""
        return None
