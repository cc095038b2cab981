"""Interrupts: Ctrl-C (SIGINT) and SIGTERM stop a render the same way, and saves are never cut in half.

SIGTERM is what Slurm, Kubernetes, systemd and Dask's nanny send to stop or preempt a job.  The
command line turns it into :class:`Terminated`, a KeyboardInterrupt, so everything that handles
Ctrl-C handles it too: a multi-pass render stops at once, keeps the passes it finished, writes
its checkpoint and outputs, and exits with 143 (128 + 15) where Ctrl-C exits with 130.

:func:`held` holds both signals while something that must complete runs (a checkpoint being
written, a set of outputs being renamed into place) and tells the caller which arrived.
Only the main thread can install handlers; elsewhere signals are not delivered to Python code
anyway, and these helpers do nothing.
"""
from __future__ import annotations

import contextlib
import signal
import threading

from .errors import InterruptedAfterSaving

#: The signals handled as an interrupt, and the exit status of a process they stopped (128 + the number).
SIGNALS = (signal.SIGINT, signal.SIGTERM)


def exit_status(signum: int) -> int:
    """The shell's convention for a process stopped by signal ``signum``: 130 for SIGINT, 143 for SIGTERM."""
    return 128 + int(signum)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived (the command line installs the handler): handled as Ctrl-C is, exit status 143."""
    signum = signal.SIGTERM


def signal_of(exc: BaseException) -> int:
    """The signal a KeyboardInterrupt stands for (SIGINT unless it says otherwise)."""
    return int(getattr(exc, "signum", signal.SIGINT))


def _raise_terminated(signum, frame):
    raise Terminated()


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def sigterm_as_interrupt():
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread, as SIGINT raises KeyboardInterrupt."""
    if not _main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _raises_in_python(signum: int, handler) -> bool:
    """Whether ``handler`` for ``signum`` is one that turns the signal into an exception we can hand on."""
    return handler is signal.default_int_handler or handler is _raise_terminated


@contextlib.contextmanager
def held():
    """Hold SIGINT and SIGTERM while the block runs; yields a list of the signals that arrived.

    When the block ends normally, a held signal whose handler raises an exception (Python's
    Ctrl-C handler, the command line's SIGTERM handler) stays in the list for the caller, who
    raises :class:`InterruptedAfterSaving` once what it was doing is complete (see :func:`raise_held`);
    any other handler (a notebook's, the default action that ends the process) is given the
    signal again now.  Signals ignored, or handled outside Python, are left alone.
    """
    pending: list[int] = []
    if not _main_thread():
        yield pending
        return
    previous = {}
    for signum in SIGNALS:
        handler = signal.getsignal(signum)
        if handler is None or handler is signal.SIG_IGN:
            continue
        previous[signum] = handler
        signal.signal(signum, lambda s, frame: pending.append(s))
    try:
        yield pending
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    for signum in list(dict.fromkeys(pending)):
        if not _raises_in_python(signum, previous.get(signum)):
            pending[:] = [s for s in pending if s != signum]
            signal.raise_signal(signum)   # what that handler would have done (ignore, exit, ...)


def raise_held(pending: list[int], saved: str) -> None:
    """Raise InterruptedAfterSaving for the first signal :func:`held` kept (nothing when none arrived);
    ``saved`` says what was completed first ("the outputs", "the checkpoint out/a.npz")."""
    if pending:
        raise InterruptedAfterSaving(pending[0], saved)
