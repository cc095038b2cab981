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

import numpy as np

from ..arrays import require_array
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
        return PassSums.empty(settings.width, settings.height)

    @classmethod
    def run_pass(cls, scene, settings, state, progress):
        image, counts, stats = cls.pass_output(scene, settings, state.end, progress)
        return state.add(state.end, image, counts), stats

    @classmethod
    def render_part(cls, scene, settings, start: int, stop: int, progress):
        """The passes [start, stop) as a part to merge into the render's state, with (seconds, stats) per pass."""
        part = PassSums.part(settings.width, settings.height, start)
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
        """The film a checkpoint holds, every array's dtype, shape and range checked first."""
        h, w = settings.height, settings.width
        shape = require_array(arrays, "film_shape", np.int64, (3,))
        if tuple(int(v) for v in shape) != (h, w, 3):
            raise ParameterError(f"checkpoint: its film is {shape[1]}x{shape[0]}, this render is {w}x{h}")
        require_array(arrays, "film_range", np.int64, (2,), low=0)
        blocks = arrays.get("film_blocks")
        require_array(arrays, "film_blocks", np.int64, (0 if blocks is None or blocks.ndim != 2 else len(blocks), 2),
                      low=0)
        for i in range(len(blocks)):
            require_array(arrays, f"film_block_{i}", np.float64, (h, w, 3))
        if "film_trunk" in arrays:
            require_array(arrays, "film_trunk", np.float64, (h, w, 3))
        if "pixel_counts" in arrays:
            require_array(arrays, "pixel_counts", np.int64, (h * w,), low=0)
        try:
            return PassSums.from_arrays(arrays)
        except (KeyError, ValueError, TypeError) as exc:
            raise ParameterError(f"checkpoint: not a film of this method's passes ({exc})") from None
