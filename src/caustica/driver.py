"""The one render loop: a method's passes under a pass count or a time budget.

Every method is parameters + ``new_state`` + ``run_pass`` + ``image`` (see
:mod:`caustica.methods`).  This module runs the passes, times them, drives the
progress bar, writes checkpoints and turns Ctrl-C (or SIGTERM, :mod:`caustica.interrupts`)
into a result of the passes finished so far.  ``run_pass`` returns a *new* state rather than changing the old
one, so an interrupt in the middle of a pass leaves the last finished state whole.

Time budget: passes run while the next one, predicted to take as long as the
slowest of the last three (compile time left out), would still end within the budget
(the first pass always runs).  The budget counts from the start of the first pass and
includes compile time.

Checkpoints are written after a pass when CHECKPOINT_INTERVAL_S have passed since the
last one, after the last pass and when interrupted (a save costs an fsync: for passes
of milliseconds, saving each would cost more than rendering).  An interrupt during a
save is held until the checkpoint is complete (:func:`save_checkpoint`), so it never
costs the passes being saved.
"""
from __future__ import annotations

import math
import os
import time
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
    work_seconds: list = field(default_factory=list)   # pass_seconds without compile time
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
        self.work_seconds.append(max(0.0, seconds - stats.get("timings", {}).get("compile_s", 0.0)))
        for k, v in stats.get("timings", {}).items():
            self.timings[k] = self.timings.get(k, 0.0) + v
        for k, v in stats.items():
            if k == "timings":
                continue
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                self.counters[k] = self.counters.get(k, 0) + v
            else:
                self.counters[k] = v


def run(method_cls, scene, settings, plan: PassPlan, progress):
    """Run the passes of ``plan``: (final state, PassLog)."""
    state, log = load_checkpoint(method_cls, scene, settings, plan)
    if state is None:
        state = method_cls.new_state(scene, settings)
    multi = plan.multi
    target = plan.passes if plan.passes is not None else (None if plan.time_s is not None else 1)
    bar = None
    if multi:
        total = target if target is not None else None
        bar = progress(total=total, desc=f"{method_cls.name} passes", unit="pass")
        if log.resumed_from:
            bar.update(log.resumed_from)
    inner = progress if not multi else QuietBar
    t_start = time.perf_counter()
    last_save = t_start
    try:
        while target is None or state.passes < target:
            elapsed = time.perf_counter() - t_start
            if plan.time_s is not None and log.pass_seconds:
                predicted = max(log.work_seconds[-3:])
                if elapsed + predicted > plan.time_s:
                    break
            t0 = time.perf_counter()
            state, stats = method_cls.run_pass(scene, settings, state, inner)
            log.add(time.perf_counter() - t0, stats)
            if plan.checkpoint is not None and time.perf_counter() - last_save >= CHECKPOINT_INTERVAL_S:
                save_checkpoint(plan, method_cls, scene, settings, state, log)
                last_save = time.perf_counter()
            if bar is not None:
                bar.update(1)
                if plan.time_s is not None:
                    bar.set_postfix_str(f"{time.perf_counter() - t_start:.1f} of {plan.time_s:g} s")
    except KeyboardInterrupt as exc:   # Ctrl-C, or SIGTERM (interrupts.Terminated)
        if state.passes == 0 or not multi:
            raise
        log.interrupt(exc)
    finally:
        if bar is not None:
            bar.close()
    final_checkpoint(plan, method_cls, scene, settings, state, log)
    return state, log


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


def final_checkpoint(plan, method_cls, scene, settings, state, log: PassLog) -> None:
    """Save the plan's checkpoint after the last pass (unless it holds them all already).

    Ctrl-C or SIGTERM during this save is held until the checkpoint is complete and then
    recorded as an interrupt: the render still returns, so its outputs are written too.
    """
    if plan.checkpoint is None or state.passes <= log.checkpoint_passes:
        return
    try:
        save_checkpoint(plan, method_cls, scene, settings, state, log)
    except InterruptedAfterSaving as exc:
        log.interrupt(exc)


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
