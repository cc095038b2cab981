"""The one pass loop: a method's passes under a pass count or a time budget, here or on a Dask cluster.

Every method is parameters + ``new_state`` + ``run_pass`` + ``image`` (see
:mod:`caustica.methods`).  :func:`run` decides how many passes run, times them, drives the
progress bar, writes checkpoints and turns Ctrl-C (or SIGTERM, :mod:`caustica.interrupts`)
into a result of the passes finished so far.  An executor runs the passes it is sent:
:class:`LocalPasses` one after another in this process (``run_pass`` returns a *new* state, so
an interrupt in the middle of a pass leaves the last finished state whole), ``cluster.DaskPasses``
ranges of independent passes as Dask tasks, merged in pass order with the same bits.

Time budget: a task is sent while it would still end within the budget, a pass predicted to take
as long as the slowest of the last three tasks' passes (compile time left out); the first pass
always runs.  The budget counts from the start of the first pass and includes compile time.

Checkpoints are written after a task comes back when CHECKPOINT_INTERVAL_S have passed since
the last one, after the last pass and when interrupted (a save costs an fsync: for passes
of milliseconds, saving each would cost more than rendering).  An interrupt during a
save is held until the checkpoint is complete (:func:`save_checkpoint`), so it never
costs the passes being saved.
"""
from __future__ import annotations

import math
import os
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from . import checkpoint as ckpt
from . import interrupts
from .errors import InterruptedAfterSaving, ParameterError, quoted

#: Upper bound of --passes: pass indices stay far inside the random-number key's range.
MAX_PASSES = 1 << 30
#: Upper bound of --time in seconds (a year).
MAX_TIME_S = 365 * 24 * 3600.0
#: Least time between two checkpoint saves, in seconds.
CHECKPOINT_INTERVAL_S = 5.0


@dataclass
class PassPlan:
    """How long a render runs: ``passes`` (None: as the budget allows), ``time_s`` (None: no budget)."""
    passes: int | None = None
    time_s: float | None = None
    checkpoint: str | None = None

    @property
    def multi(self) -> bool:
        return self.time_s is not None or (self.passes is not None and self.passes != 1) \
            or self.checkpoint is not None


def check_plan(method_cls, passes=None, time_s=None, checkpoint=None) -> PassPlan:
    """The pass plan, checked: a one-line ParameterError for anything out of range."""
    if passes is not None:
        if isinstance(passes, bool) or not isinstance(passes, int) or not 1 <= passes <= MAX_PASSES:
            raise ParameterError(f"--passes: an integer between 1 and {MAX_PASSES} (got {quoted(passes)})")
    if time_s is not None:
        try:
            if isinstance(time_s, (bool, np.bool_)):
                raise TypeError
            time_s = float(time_s)
        except (TypeError, ValueError, OverflowError):
            raise ParameterError(f"--time: {quoted(time_s)} is not a number of seconds") from None
        if not math.isfinite(time_s) or not 0.0 < time_s <= MAX_TIME_S:
            raise ParameterError(f"--time: seconds, > 0 and at most {MAX_TIME_S:.0f} (got {time_s})")
    if checkpoint is not None:
        if not isinstance(checkpoint, (str, os.PathLike)) or isinstance(checkpoint, bytes):
            raise ParameterError(f"--checkpoint: a file name (str or os.PathLike), not a {type(checkpoint).__name__} "
                                 f"({quoted(checkpoint)})")
        checkpoint = os.fspath(checkpoint)
        if not checkpoint.strip():
            raise ParameterError("--checkpoint: the file name is empty; give e.g. --checkpoint out/render.npz")
    plan = PassPlan(passes, time_s, checkpoint)
    if plan.multi and not getattr(method_cls, "progressive", False):
        progressive = "pt, sppm, pspm"
        raise ParameterError(f"--passes, --time and --checkpoint are for the progressive methods "
                             f"({progressive}); '{method_cls.name}' renders in one shot")
    if plan.checkpoint is not None and plan.passes is None and plan.time_s is None:
        raise ParameterError("--checkpoint needs --passes or --time (how long to render)")
    return plan


@dataclass
class PassLog:
    """What the loop measured: seconds per pass, summed per-phase timings and counters."""
    pass_seconds: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    counters: dict = field(default_factory=dict)
    interrupted: bool = False
    #: the signal that interrupted the render (SIGINT: Ctrl-C; SIGTERM), when interrupted
    interrupt_signal: int = 0
    resumed_from: int = 0
    #: passes the checkpoint file holds (written by this run or resumed from)
    checkpoint_passes: int = 0

    def interrupt(self, exc: KeyboardInterrupt) -> None:
        """Record that ``exc`` (Ctrl-C, SIGTERM) stopped the render after the passes finished so far."""
        self.interrupted = True
        self.interrupt_signal = interrupts.signal_of(exc)

    def add(self, seconds: float, stats: dict) -> None:
        self.pass_seconds.append(seconds)
        for k, v in stats.get("timings", {}).items():
            self.timings[k] = self.timings.get(k, 0.0) + v
        for k, v in stats.items():
            if k == "timings":
                continue
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                self.counters[k] = self.counters.get(k, 0) + v
            else:
                self.counters[k] = v


def run(method_cls, scene, settings, plan: PassPlan, progress, executor=None):
    """Run the passes of ``plan`` on ``executor`` (default: :class:`LocalPasses`): (final state, PassLog)."""
    if executor is None:
        executor = LocalPasses(method_cls, scene, settings, QuietBar if plan.multi else progress)
    state, log = load_checkpoint(method_cls, scene, settings, plan)
    if state is None:
        state = method_cls.new_state(scene, settings)
    executor.start()
    # passes rendered elsewhere are counted, and kept on Ctrl-C, even when there is one (its own bar is not shown)
    multi = plan.multi or bool(executor.label)
    target = plan.passes if plan.passes is not None else (None if plan.time_s is not None else 1)
    bar = progress(total=target, desc=f"{method_cls.name} passes{executor.label}", unit="pass") if multi \
        else QuietBar()
    if log.resumed_from:
        bar.update(log.resumed_from)
    first = next_pass = state.passes
    pass_s = deque(maxlen=3)   # work seconds per pass of the last tasks back (compile time left out)
    t_start = last_save = time.perf_counter()
    end = None if plan.time_s is None else t_start + plan.time_s
    try:
        while True:
            next_pass = _send(executor, next_pass, target, max(pass_s, default=None), end, next_pass == first)
            back = executor.collect(state, end)
            if back is None:   # nothing out, or what was out is given up (late past the budget)
                break
            state, passes, task_pass_s = back
            for seconds, stats in passes:
                log.add(seconds, stats)
            pass_s.append(task_pass_s)
            # saved when passes were merged since the last save: a cluster's first task back may be one that
            # waits for an earlier pass, and a checkpoint of none would only say the render had begun
            if plan.checkpoint is not None and state.passes > log.checkpoint_passes \
                    and time.perf_counter() - last_save >= CHECKPOINT_INTERVAL_S:
                save_checkpoint(plan, method_cls, scene, settings, state, log)
                last_save = time.perf_counter()
            bar.update(len(passes))
            if end is not None:
                bar.set_postfix_str(f"{time.perf_counter() - t_start:.1f} of {plan.time_s:g} s")
    except BaseException as exc:   # Ctrl-C, SIGTERM (interrupts.Terminated), or a failure
        executor.stop(exc, state)   # cancels what is out; may raise an error of its own instead
        if not isinstance(exc, KeyboardInterrupt) or state.passes == 0 or not multi:
            raise
        log.interrupt(exc)
    finally:
        bar.close()
    if plan.checkpoint is not None and state.passes > log.checkpoint_passes:
        try:   # Ctrl-C or SIGTERM in this last save is held until it is complete, then recorded as an interrupt
            save_checkpoint(plan, method_cls, scene, settings, state, log)
        except InterruptedAfterSaving as exc:   # the render still returns, so its outputs are written too
            log.interrupt(exc)
    return state, log


def _send(executor, next_pass: int, target, pass_s, end, first: bool) -> int:
    """Send tasks while the executor has room and passes are left: the next pass to send.  ``pass_s`` predicts a
    pass (None until a task is back: tasks of one pass); a task is halved (keeping its alignment) until it ends
    within the budget (``end``), and not sent if one pass would not, unless it is the render's ``first``."""
    for _ in range(executor.room()):
        if target is not None and next_pass >= target:
            break
        size = 1 if pass_s is None else executor.task_size(next_pass, target, pass_s)
        if end is not None and not first:
            left, p = end - time.perf_counter(), pass_s or 0.0
            while size > 1 and size * p > left:
                size //= 2
            if size * p > left:
                break
        executor.submit(next_pass, next_pass + size)
        next_pass, first = next_pass + size, False
    return next_pass


class LocalPasses:
    """The executor of a render in this process, and the reference for what an executor does (the other is
    ``cluster.DaskPasses``): it takes ranges of passes [start, stop) in pass order and gives them back merged
    in pass order, while :func:`run` decides how many.  Here a task is one pass, run on the loop's state
    as it is taken back (on the method's threads): any method's passes, independent or not."""
    label = ""   # follows "passes" in the progress bar

    def __init__(self, method_cls, scene, settings, progress):
        self.method_cls, self.scene, self.settings, self.progress = method_cls, scene, settings, progress
        self.sent = False

    def start(self) -> None:
        """Before the first task, after the checkpoint is read."""

    def room(self) -> int:
        """How many tasks may be sent now."""
        return 0 if self.sent else 1

    def task_size(self, start: int, target, pass_s: float) -> int:
        """The passes (at least 1) of a task from ``start``; ``pass_s`` predicts a pass's work."""
        return 1

    def submit(self, start: int, stop: int) -> None:
        """Send the passes [start, stop) (here one, from the state's end)."""
        self.sent = True

    def collect(self, state, late_after):
        """The next task back: (``state`` with the passes now in order merged in, their (seconds, stats), its
        work seconds per pass); None when none is out, or those out were given up as late (past
        ``late_after``, the budget's end, and the executor's grace)."""
        if not self.sent:
            return None
        self.sent = False
        t0 = time.perf_counter()
        state, stats = self.method_cls.run_pass(self.scene, self.settings, state, self.progress)
        seconds = time.perf_counter() - t0
        return state, [(seconds, stats)], max(0.0, seconds - stats.get("timings", {}).get("compile_s", 0.0))

    def stop(self, exc: BaseException, state) -> None:
        """The loop ends on ``exc``: cancel what is out (or raise an error of the executor's own)."""


def save_checkpoint(plan, method_cls, scene, settings, state, log: PassLog) -> None:
    """Save the plan's checkpoint during the passes, and record in ``log`` the passes it holds.

    An interrupt during the save is held until the file is complete, then raised (as
    InterruptedAfterSaving), with the passes saved recorded first so they are not saved again.
    """
    try:
        ckpt.save(plan.checkpoint, method_cls, scene, settings, state)
    except InterruptedAfterSaving:   # the save is complete
        log.checkpoint_passes = state.passes
        raise
    log.checkpoint_passes = state.passes


def load_checkpoint(method_cls, scene, settings, plan):
    """(state saved in the plan's checkpoint or None, a PassLog that says where it resumed)."""
    state = None
    log = PassLog()
    if plan.checkpoint is not None:
        state = ckpt.load(plan.checkpoint, method_cls, scene, settings)
        if state is not None:
            log.resumed_from = log.checkpoint_passes = state.passes
            if plan.passes is not None and state.passes > plan.passes:
                raise ParameterError(f"--checkpoint {plan.checkpoint}: holds {state.passes} passes, more than "
                                     f"--passes {plan.passes}; ask for at least {state.passes}")
    return state, log


class QuietBar:
    """A progress bar that shows nothing (tqdm's interface); the class itself is a bar factory."""

    def __init__(self, *a, **k):
        pass

    def update(self, n=1):
        pass

    def close(self):
        pass

    def set_postfix_str(self, s):
        pass
