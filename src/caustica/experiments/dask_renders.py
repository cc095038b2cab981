"""An experiment's renders as Dask tasks (``caustica experiment ... --dask ADDRESS`` or ``--workers N``).

Every render is one task on one worker; a render is never split across workers
(:class:`caustica.cluster.DaskPasses` does that for one long render, not here).  The scene goes
to every worker once (:func:`caustica.cluster.send_scene`: recoverable, unlike scattered
data, when the workers holding it die); a task receives it,
renders with ``caustica.render`` on all of its worker's threads and sends back the
RenderResult.  Renders whose numbers do not depend on time have the bits of a local
render (same seed, same bits whatever the thread count); times are each worker's own.

One render per worker at a time.  Most numbers of the experiments are timed (Table 1's
and Tables 2 and 3's times, their equal-time and equal-error comparisons, the convergence
study's time budgets and Mitsuba 3 given the same wall time), and a render uses every
thread of its worker: two renders side by side on one worker would share its cores and
each be timed slower than it is.  So every worker gets one unit of the Dask resource
:data:`RESOURCE` and every render task asks for it: the scheduler then runs at most one
render on a worker at a time, whatever its thread count, and places them itself (no
scheduler of ours).  A resource rather than single-threaded workers because a worker
started with ``dask worker ADDRESS`` has a thread per core and should render on all of
them.  The resource is declared by a worker plugin (:class:`RenderSlot`), so workers that
join or restart during the run get it too.
"""
from __future__ import annotations

import time

from distributed import WorkerPlugin, get_worker

from ..cluster import send_scene
from .renders import Pending, render_job

#: The Dask resource a render task holds: one unit per worker, one per task.
RESOURCE = "caustica-render"
#: Keys a worker process has warmed up (see :func:`.renders.render_job`): the worker's own kernels.
_WARMED: set = set()


class RenderSlot(WorkerPlugin):
    """Declares one unit of :data:`RESOURCE` on every worker, present and future."""

    name = "caustica-render-slot"

    async def setup(self, worker):
        await worker.set_resources(**{RESOURCE: 1})


def _worker_threads() -> int:
    return get_worker().state.nthreads


def render_task(scene, method: str, kw: dict, warm):
    """A worker's task: one render on every thread of this worker, its sidecar naming the worker."""
    result, seconds = render_job(scene, method, dict(kw, progress=False), warm, _WARMED, _worker_threads())
    result.stats["worker"] = get_worker().address
    return result, seconds


def mitsuba_task(scene_name: str, res: int, budget_s: float, seed: int):
    """Mitsuba 3's equal-time render on this worker, with as many threads as caustica's renders here get."""
    import drjit as dr

    from .mitsuba import mitsuba_equal_time, mitsuba_module
    dr.set_thread_count(_worker_threads())
    return mitsuba_equal_time(mitsuba_module(), scene_name, res, budget_s, seed)


def _has_mitsuba() -> bool:
    from .mitsuba import mitsuba_module
    return mitsuba_module() is not None


class DaskRenders:
    """Renders as tasks on a connected :class:`caustica.cluster.Cluster` (same interface as LocalRenders)."""

    def __init__(self, cluster):
        self.cluster = cluster
        self.client = cluster.client
        self.client.register_plugin(RenderSlot(), name=RenderSlot.name)
        self._scenes = {}          # id(scene) -> (scene, its future on the workers)
        self._mitsuba = None

    def _sent(self, scene):
        if id(scene) not in self._scenes:
            t0 = time.perf_counter()
            self._scenes[id(scene)] = (scene, send_scene(self.client, scene), time.perf_counter() - t0)
        return self._scenes[id(scene)][1]

    def submit(self, scene, method: str, *, warm=None, **kw) -> Pending:
        fut = self.client.submit(render_task, self._sent(scene), method, kw, warm, pure=False,
                                 resources={RESOURCE: 1})
        return Pending(fut.result)

    def submit_mitsuba(self, scene_name: str, res: int, budget_s: float, seed: int) -> Pending:
        fut = self.client.submit(mitsuba_task, scene_name, res, budget_s, seed, pure=False,
                                 resources={RESOURCE: 1})
        return Pending(fut.result)

    def has_mitsuba(self) -> bool:
        """Whether every worker has Mitsuba 3 (its equal-time renders run on the workers too)."""
        if self._mitsuba is None:
            self._mitsuba = all(self.client.run(_has_mitsuba).values())
        return self._mitsuba

    def describe(self) -> dict:
        threads = self.cluster.worker_threads
        return {"scheduler": self.cluster.address, "workers": len(threads), "worker_threads": threads,
                "scene_transfer_s": sum(t for _, _, t in self._scenes.values()),
                "rule": "every render one task on one worker, at most one render per worker at a time, "
                        "on all of its threads"}
