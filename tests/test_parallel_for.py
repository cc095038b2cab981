"""``caustica.jit.parallel_for`` (issue 8): every item once, any thread count; Ctrl-C stops it at once.

The kernel here is a toy range kernel that marks the items it ran and spins a little
per item, so chunks take measurable time.
"""
from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from caustica.jit import _WORKERS, _Chunks, kernel, parallel_for


@kernel
def _mark(out, spin, i0, i1):
    for i in range(i0, i1):
        x = 0.0
        for j in range(spin):
            x += np.sqrt(float(i + j))
        out[i] += 1.0 + 0.0 * x   # 0.0 * x is not folded away (x could be inf), so the spin stays


@kernel
def _fail_at(out, bad, i0, i1):
    for i in range(i0, i1):
        if i == bad:
            raise ValueError("item failed")
        out[i] = 1.0


class _Bar:
    """A progress bar that raises KeyboardInterrupt (as Ctrl-C would) after ``after`` updates."""

    def __init__(self, after):
        self.after = after
        self.updates = 0
        self.items = 0

    def update(self, n):
        self.updates += 1
        self.items += n
        if self.updates == self.after:
            raise KeyboardInterrupt


def _workers_busy():
    """Worker threads still running a task (the pool's threads live on, idle, between calls)."""
    return _WORKERS.started - _WORKERS.idle


def _wait_until_idle(seconds=30):
    """Wait (up to ``seconds``) for every worker thread to finish its task; the number still busy."""
    deadline = time.monotonic() + seconds
    while _workers_busy() and time.monotonic() < deadline:
        time.sleep(0.01)
    return _workers_busy()


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_every_item_runs_exactly_once(threads):
    out = np.zeros(10_001)
    bar = _Bar(after=-1)
    parallel_for(_mark, out.size, (out, 10), threads=threads, progress=bar)
    assert np.all(out == 1.0)
    assert bar.items == out.size


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_later_calls_sized_by_the_last_one_run_every_item_once(threads):
    for n in (10_001, 37, 20_000):   # the second and third calls start from the first's time per item
        out = np.zeros(n)
        bar = _Bar(after=-1)
        parallel_for(_mark, out.size, (out, 10), threads=threads, progress=bar)
        assert np.all(out == 1.0) and bar.items == n


def test_items_far_slower_than_the_last_calls_get_small_chunks_again():
    """The floor and first chunks come from the last call's time per item; when item 0 shows this call's items are
    far slower, the chunks start from one item again (else a chunk could run for seconds)."""
    fast = np.zeros(20_000)
    parallel_for(_mark, fast.size, (fast, 1), threads=2)
    slow = np.zeros(200)
    bar = _Bar(after=-1)
    parallel_for(_mark, slow.size, (slow, 1_000_000), threads=2, progress=bar)   # about 2 ms per item
    assert np.all(slow == 1.0)
    assert bar.updates >= 8


def test_no_chunk_but_the_last_is_below_the_floor():
    chunks = _Chunks(0, 1000, 2, None, floor=100)
    sizes = []
    while (r := chunks.take(10_000)) is not None:
        sizes.append(r[1] - r[0])
    assert sum(sizes) == 1000 and min(sizes[:-1]) >= 100
    assert sizes[0] == 250   # a quarter of the work at first: the other thread's share is left to it


@pytest.mark.parametrize("threads", [2, 3])
def test_a_short_call_gives_every_thread_two_chunks(threads):
    """A call worth less than the chunk floor (SPPM's passes at 96 x 96 take a few milliseconds) is still split so
    that each thread gets at least two chunks: with the floor alone it ran as one chunk, the other threads idle."""
    parallel_for(_mark, 20_000, (np.zeros(20_000), 1), threads=threads)   # the time per item: well under the floor
    out = np.zeros(2_000)
    bar = _Bar(after=-1)
    parallel_for(_mark, out.size, (out, 1), threads=threads, progress=bar)
    assert np.all(out == 1.0)
    assert bar.updates >= 1 + 2 * threads   # item 0, then at least two chunks a thread


@pytest.mark.parametrize("chunk", [1, 7, 100_000])
def test_a_fixed_chunk_runs_every_item_once(chunk):
    out = np.zeros(1000)
    parallel_for(_mark, out.size, (out, 1), threads=2, chunk=chunk)
    assert np.all(out == 1.0)


@pytest.mark.parametrize("threads", [1, 2])
def test_interrupt_returns_at_once_and_cancels_the_pending_chunks(threads):
    """Ctrl-C in the waiting thread: KeyboardInterrupt at once, the running chunks end, no others start."""
    out = np.zeros(20_000)
    parallel_for(_mark, 2, (np.zeros(2), 1), threads=1)            # compiled before timing anything
    bar = _Bar(after=3)   # the first item, then two chunks of the rest
    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        parallel_for(_mark, out.size, (out, 20_000), threads=threads, progress=bar)
    returned_s = time.perf_counter() - t0
    assert not _wait_until_idle()
    done = int(out.sum())
    assert np.all((out == 0.0) | (out == 1.0))
    # without cancelling, every item would have run (the whole job takes many seconds)
    assert done < out.size / 2, (done, returned_s)
    assert done >= bar.items


def test_calls_side_by_side_each_get_their_threads():
    """Worker threads are kept between calls.  A call gets the threads it asks for even while every kept thread is
    busy (a Dask worker's other task, a notebook's interrupted chunk still finishing), and calls from several
    threads at once each run every item once."""
    release = threading.Event()
    _WORKERS.run(lambda: release.wait(120), _WORKERS.idle + 2)   # every kept thread busy, and two more
    out = np.zeros(1000)
    caller = threading.Thread(target=parallel_for, args=(_mark, out.size, (out, 1)), kwargs={"threads": 2})
    caller.start()
    caller.join(60)   # a call that had to share the busy threads would still be waiting for the release
    finished = not caller.is_alive()
    release.set()
    caller.join(60)
    assert finished and np.all(out == 1.0)
    outs = [np.zeros(3000) for _ in range(4)]
    errors = []

    def call(out):
        try:
            parallel_for(_mark, out.size, (out, 200), threads=2)
        except BaseException as exc:   # reported below
            errors.append(exc)

    callers = [threading.Thread(target=call, args=(out,)) for out in outs]
    for t in callers:
        t.start()
    for t in callers:
        t.join(60)
    assert not errors and all(np.all(out == 1.0) for out in outs)
    assert not _wait_until_idle()
    started = _WORKERS.started
    parallel_for(_mark, 100, (np.zeros(100), 1), threads=2)   # served by the threads already started
    assert _WORKERS.started == started and not _workers_busy()


def test_an_error_in_a_chunk_is_raised_in_the_caller():
    out = np.zeros(5000)
    with pytest.raises(ValueError, match="item failed"):
        parallel_for(_fail_at, out.size, (out, 3000), threads=2)
    assert not _wait_until_idle()


def test_idle_worker_threads_hold_no_arguments_of_the_last_call():
    """A kept thread that has finished its task drops it: the call's arguments (a pass's visible points, 245 bytes a
    pixel on roughplastic) are freed when the call returns, not when the thread's next task replaces them, which
    held two passes' visible points at once (the peak of a pspm render 692 bytes a pixel, 438 after)."""
    import gc
    import weakref
    out = np.zeros(4000)
    ref = weakref.ref(out)
    parallel_for(_mark, out.size, (out, 1), threads=2)
    del out
    assert not _wait_until_idle()
    gc.collect()
    assert ref() is None


@pytest.mark.parametrize("threads", [1, 2])
def test_a_real_sigint_reaches_the_waiting_thread_at_once(threads):
    """A SIGINT (not a progress bar raising) while the calling thread waits for the workers (done.get()).  Python's
    own handler is set for the test: a process started in the background by a shell without job control (a CI
    runner's, ``make test &``) inherits SIGINT ignored."""
    out = np.zeros(20_000)
    parallel_for(_mark, 2, (np.zeros(2), 1), threads=1)            # warm: item 0 runs on this thread
    # a job of about 4 s on one thread whatever the machine (a fast one did 0.52 of a fixed job in 0.2 s): the
    # SIGINT at 0.2 s then comes before a tenth of it is done
    t0 = time.perf_counter()
    parallel_for(_mark, 1000, (np.zeros(1000), 20_000), threads=1)
    spin = int(20_000 * max(1.0, 4.0 / (out.size / 1000 * (time.perf_counter() - t0))))
    sent = []
    timer = threading.Timer(0.2, lambda: (sent.append(time.perf_counter()), os.kill(os.getpid(), signal.SIGINT)))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            parallel_for(_mark, out.size, (out, spin), threads=threads)
        latency = time.perf_counter() - sent[0]
        timer.join()
    finally:
        signal.signal(signal.SIGINT, previous)
    assert not _wait_until_idle()
    # at once: well under the whole job (2-4 s on two or one thread), with room for a loaded machine
    assert latency < 0.3 and out.sum() < out.size / 2, (latency, out.sum())


def test_a_new_specialisation_compiles_on_a_worker_thread(monkeypatch):
    """A warm kernel called with new argument types compiles them on a worker, not on the calling thread (which
    would hold Ctrl-C back for as long as an LLVM pass runs: seconds on a render kernel)."""
    parallel_for(_mark, 100, (np.zeros(100), 1), threads=2)          # warm with float64
    twin = _mark.from_python
    original = twin._compile_for_args
    compiled_on = []

    def spy(*args, **kws):
        result = original(*args, **kws)
        compiled_on.append(threading.current_thread())
        return result

    monkeypatch.setattr(twin, "_compile_for_args", spy)
    out = np.zeros(100, np.float32)                                  # new argument types
    parallel_for(_mark, out.size, (out, 1), threads=2)
    assert np.all(out == 1.0)
    assert compiled_on and threading.current_thread() not in compiled_on
