"""Methods whose passes are independent: pass p's image depends only on (scene, settings, p).

``pt`` always, ``sppm`` and ``pspm`` with ``--schedule global``.  Such a method gives
``pass_output(scene, settings, pass_index, progress) -> (image, counts, stats)``: the
pass's float32 image, an int64 per-pixel count to sum (or None) and its stats.  Its state
is a :class:`~caustica.film.PassSums`, so passes rendered apart — on another thread,
after a checkpoint, on another machine (:mod:`caustica.cluster`) — join with the same
bits as passes rendered one after another.
"""
from __future__ import annotations

import time

from ..errors import ParameterError
from ..film import PassSums


class IndependentPasses:
    """Mixin: ``new_state``, ``run_pass``, ``image`` and checkpoints over ``pass_output``."""
    progressive = True

    @classmethod
    def independent(cls, settings) -> bool:
        """Whether this render's passes may run apart (all of them, for a method of this mixin alone)."""
        return True

    @classmethod
    def new_state(cls, scene, settings):
        return PassSums.empty(settings["width"], settings["height"])

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        image, counts, stats = cls.pass_output(scene, settings, state.end, progress)
        return state.add(state.end, image, counts), stats

    @classmethod
    def render_part(cls, scene, settings, start: int, stop: int, progress):
        """The passes [start, stop) as a part to merge into the render's state, with (seconds, stats) per pass."""
        part = PassSums.part(settings["width"], settings["height"], start)
        log = []
        for p in range(start, stop):
            t0 = time.perf_counter()
            image, counts, stats = cls.pass_output(scene, settings, p, progress)
            part = part.add(p, image, counts)
            log.append((time.perf_counter() - t0, stats))
        return part, log

    @classmethod
    def image(cls, scene, settings, state):
        return state.film.image()

    @classmethod
    def state_from_arrays(cls, scene, settings, arrays):
        try:
            state = PassSums.from_arrays(arrays)
        except (KeyError, ValueError, TypeError) as exc:
            raise ParameterError(f"checkpoint: not a film of this method's passes ({exc})") from None
        want = (settings["height"], settings["width"], 3)
        if state.film.shape != want:
            raise ParameterError(f"checkpoint: its film is {state.film.shape[1]}x{state.film.shape[0]}, "
                                 f"this render is {settings['width']}x{settings['height']}")
        return state
