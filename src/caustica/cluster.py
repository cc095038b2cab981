"""Rendering beyond one machine: the passes of a render as tasks on a Dask cluster.

Dask's ``distributed`` is the engine (imported only here, and only when a cluster is
asked for): ``--dask ADDRESS`` connects to a running scheduler, ``--workers N`` starts
a local cluster of N single-threaded worker processes.  What goes over the wire:

* the scene, once per worker (:func:`send_scene`);
* a task per range of consecutive passes [a, b), run on one worker thread
  (:meth:`~caustica.methods.independent.IndependentPasses.render_part`), which sends
  back a part of the film (:class:`~caustica.film.PassSums`) and its per-pass stats;
* the client merges the parts in pass order, so the image has the bits of a local
  render of the same passes whatever the number of workers, the task sizes or the
  order tasks finish in (:mod:`caustica.film`).

The pass loop (pass count, time budget, checkpoints, progress, Ctrl-C) is a local render's,
:func:`caustica.driver.run`, given a :class:`DaskPasses` as its executor.

Tasks start at one pass; once the first are back, a task gets a power of two of passes
(at most :data:`MAX_TASK_PASSES`) that takes about :data:`TASK_SECONDS` (longer on more than 16 worker threads), so a task's
overhead (scheduling, moving a part of the film) is a small share of its work; with a time budget a task is only sent if
its predicted end is within the budget.  A worker that dies loses nothing: Dask runs
its tasks again elsewhere, and as every pass's random numbers are keyed by its index
the result is the same.  Ctrl-C cancels this render's tasks on the cluster.
"""
from __future__ import annotations

import logging
import os
import queue
import time
from dataclasses import dataclass, field

from . import checkpoint as ckpt
from .errors import CausticaError, ClusterError, ParameterError, quoted, shorten
from .film import MAX_FILM_IMAGES, TRUNK_PASSES
from .limits import MAX_THREADS
from .methods.params import Settings

#: Address schemes of Dask's comms a scheduler can listen on.
SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
#: ... of which these need Dask's TLS settings (certificates in its configuration).
SECURE_SCHEMES = ("tls", "wss")
#: The port 'dask scheduler' listens on unless told otherwise.
DEFAULT_PORT = 8786
#: Seconds to wait for each step of reaching a scheduler (the TCP connection, Dask's handshake, its answer).
CONNECT_TIMEOUT_S = 5.0
#: After a failed handshake on tcp://, how long to read what the other end sends, to say what it is.
SNIFF_S = 1.0
#: Memory of one local worker process once it has rendered (its kernels loaded): measured 354-356 MB RSS
#: (212 MB of its own) after pt and sppm renders at 64 x 64, 2026-12-02, this 2-core machine.
WORKER_PROCESS_BYTES = 360 * 10**6
#: The most passes one task renders (16 film trunk blocks: a part of the film per 64 passes).
MAX_TASK_PASSES = 16 * TRUNK_PASSES
#: A task is made about this long (its passes' measured work), once the first tasks are back ...
TASK_SECONDS = 1.0
#: ... times (worker threads / this) when more: the client takes in one part per task, so with many
#: workers longer tasks keep its network link and its merging from becoming the bottleneck.
THREADS_FOR_LONGER_TASKS = 16
#: With --time, tasks still out this long after the budget (or 3x the longest task so far, if more)
#: are given up, once any task has come back: the render keeps the passes merged in order before
#: them (a hung worker, a lost task) rather than waiting for ever.
LATE_TASK_GRACE_S = 10.0
#: ... and before any task has come back (the workers may be compiling their kernels: a cold
#: compile of the progressive methods takes about a minute on a 2-core machine).
FIRST_TASK_GRACE_S = 180.0
#: Of a worker's memory share per thread, what one task may fill (Dask itself pauses a worker at 80 %).
TASK_MEMORY_FRACTION = 0.6
#: Parts finished ahead of a pass still out are held by the client until it is back; past this
#: many per task slot, no new task is sent (their memory, part_bytes_per_pixel each, stays bounded).
MAX_HELD_PARTS_PER_SLOT = 4
#: Test hook: "PASS:FILE" makes the worker that renders pass PASS exit at once, the first time
#: only (the one that creates FILE), as a worker that dies mid-render; "PASS:" every time;
#: "PASS:hang" makes that task sleep for an hour, as a hung task.
KILL_HOOK_ENV = "CAUSTICA_TEST_KILL_WORKER_AT_PASS"
HANG_FLAG = "hang"


def _distributed():
    try:
        import distributed
    except ModuleNotFoundError:
        raise ParameterError("--dask and --workers need Dask's distributed package: "
                             "pip install 'caustica[dask]'") from None
    return distributed


@dataclass
class Cluster:
    """A connected Dask client (and the local cluster it started, if any)."""
    client: object
    local: object = None
    address: str = ""
    #: Whether closing this closes the client (not when the caller handed in its own Client).
    owned: bool = True
    #: Set by a render that Ctrl-C stopped: closing then stops the local workers at once.
    interrupted: bool = False

    @property
    def worker_threads(self) -> dict:
        """Threads of each worker, by worker address."""
        return dict(self.client.nthreads())

    @property
    def threads(self) -> int:
        return sum(self.worker_threads.values())

    def task_memory_bytes(self) -> int | None:
        """The memory one task may use: the smallest worker's memory limit per thread (None: no limit set)."""
        try:
            info = self.client.scheduler_info(n_workers=-1)   # some releases list only 5 workers by default
        except TypeError:   # releases without the argument list them all
            info = self.client.scheduler_info()
        shares = [w["memory_limit"] / max(1, w.get("nthreads", 1))
                  for w in info["workers"].values() if w.get("memory_limit")]
        return int(min(shares)) if shares else None

    def close(self, at_once: bool = False) -> None:
        """Close the client (if ours) and the local cluster (if any); ``at_once`` (after Ctrl-C) stops
        the local worker processes first rather than letting them shut down in turn (1.4 s for two)."""
        if at_once or self.interrupted:
            self.stop_local_workers()
        try:
            if self.owned:
                self.client.close()
        finally:
            if self.local is not None:
                self.local.close()

    def stop_local_workers(self) -> None:
        """SIGTERM to the worker processes of the local cluster this started (they hold nothing a render
        still needs: its parts are merged here); a cluster of the caller's is left alone."""
        if self.local is not None:
            _stop_workers(self.local)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        self.close(at_once=exc_type is not None and issubclass(exc_type, KeyboardInterrupt))


def quiet_cluster_logs() -> None:
    """Keep Dask's own log lines (worker deaths, closing comms) off a command line's stderr.

    What matters reaches the user as caustica's one-line error; the command line calls
    this, the Python API leaves the caller's logging alone. Dask is imported first: its import sets
    the level of its loggers from its config (``distributed`` at INFO), which would undo a level set
    before it, and lines such as "Batched Comm Closed" with a traceback reached stderr after Ctrl-C.
    """
    try:
        import distributed  # noqa: F401 - for its logging set-up, see above
    except ModuleNotFoundError:
        return   # nothing to quiet; connecting says what to install
    names = ["distributed", "tornado.application", "asyncio"]
    names += [n for n in logging.root.manager.loggerDict if n.startswith("distributed.")]
    for name in names:   # distributed.client and others have handlers of their own and do not propagate
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def check_args(address=None, workers=None) -> None:
    """One-line errors for --dask / --workers, before anything starts (an address is read here, not reached)."""
    if address is not None and workers is not None:
        raise ParameterError("--dask and --workers: give one (a running scheduler, or a local cluster to start)")
    if workers is not None:
        if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_THREADS:
            raise ParameterError(f"--workers: an integer between 1 and {MAX_THREADS} (got {shorten(workers)})")
        check_local_workers(workers)
    if address is not None and not isinstance(address, str):
        if type(address).__name__ != "Client" or not hasattr(address, "submit"):
            raise ParameterError(f"dask=: a scheduler address (str) or a distributed.Client, not {shorten(repr(address))}")
        if getattr(address, "status", "running") != "running":
            raise ParameterError(f"dask=: the distributed.Client is {shorten(address.status)}, not running; pass an "
                                 f"open one (or the scheduler's address)")
        return  # a distributed.Client of the caller's
    if address is not None:
        parse_address(address)


def check_local_workers(workers: int) -> None:
    """A local cluster of ``workers`` single-threaded processes must fit the machine: its memory
    (WORKER_PROCESS_BYTES each, measured) and its CPUs (more workers than CPUs only share them, and the
    experiments' timed renders, alone on their worker, would be timed slower than they are)."""
    from .jit import default_threads
    from .memory import check_budget
    check_budget(workers * WORKER_PROCESS_BYTES,
                 f"--workers {workers}: {workers} worker processes (about {WORKER_PROCESS_BYTES / 1e6:.0f} MB each "
                 f"once they have rendered)", "give fewer workers")
    cpus = default_threads()
    if workers > cpus:
        raise ParameterError(f"--workers {workers}: this machine lets caustica use {cpus} CPU"
                             f"{'' if cpus == 1 else 's'}, and each worker is one single-threaded process: more "
                             f"than {cpus} would only share them; give at most --workers {cpus} (or --dask ADDRESS "
                             f"for a cluster of more machines)")


def connect(address=None, workers=None) -> Cluster:
    """Connect to the scheduler at ``address`` (or a ``distributed.Client``), or start ``workers`` local workers.

    Refuses, in one line, an address that is malformed or where no Dask scheduler answers
    (:func:`probe_scheduler`: every step within CONNECT_TIMEOUT_S), tls:// without Dask's TLS
    settings (:func:`connection_args`), a local cluster the machine cannot hold
    (:func:`check_local_workers`), a cluster without workers, and workers that run another
    build of caustica (their passes would not have this build's bits).
    """
    check_args(address, workers)
    distributed = _distributed()
    if address is not None and not isinstance(address, str):
        cluster = Cluster(address, None, str(address.scheduler.address), owned=False)
    elif address is not None:
        addr = parse_address(address)
        conn = connection_args(addr)
        probe_scheduler(addr, conn)
        try:
            client = distributed.Client(f"{addr.scheme}://{_loc(addr)}", timeout=CONNECT_TIMEOUT_S,
                                        security=conn["security"], set_as_default=False)
        except Exception as exc:   # noqa: BLE001 - the probe answered; anything now is the link or the scheduler
            raise ParameterError(f"--dask {shorten(address)}: the scheduler answered, then the client could not "
                                 f"connect ({type(exc).__name__}: {_first_line(exc)})") from None
        cluster = Cluster(client, None, addr.text)
    else:
        import signal
        # worker processes started with SIGINT ignored keep ignoring it: Ctrl-C reaches this process
        # alone, which cancels the tasks and stops them (no traceback from every worker). A Ctrl-C
        # while they start is lost with it (a blocked SIGINT would be held, but the spawned processes
        # do not inherit the mask): docs/cluster.md, Not handled.
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if _main_thread() else None
        try:
            local = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                             dashboard_address=":0", silence_logs=logging.CRITICAL)  # any port
        finally:
            if previous is not None:
                signal.signal(signal.SIGINT, previous)
        try:
            client = distributed.Client(local, set_as_default=False)
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt):
                _stop_workers(local)
            local.close()
            raise
        cluster = Cluster(client, local, local.scheduler_address)
    try:
        if workers is None:
            try:
                cluster.client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
            except (TimeoutError, OSError):
                raise ParameterError(f"--dask {cluster.address}: the scheduler has no workers; start some with "
                                     f"'dask worker {cluster.address}'") from None
        check_workers_build(cluster)
    except BaseException as exc:
        cluster.close(at_once=isinstance(exc, KeyboardInterrupt))
        raise
    return cluster


def _main_thread() -> bool:
    import threading
    return threading.current_thread() is threading.main_thread()



def _stop_workers(local) -> None:
    """SIGTERM to the worker processes of a LocalCluster (they hold nothing a render still needs).

    Each nanny is marked as closing first: it then closes when its worker exits, rather than
    starting a new one (which would log a traceback on stderr when the cluster closes it).
    """
    import signal
    from distributed.core import Status
    for nanny in list(getattr(local, "workers", {}).values()):
        pid = getattr(getattr(nanny, "process", None), "pid", None)
        if pid:
            nanny.status = Status.closing_gracefully
            try:
                os.kill(pid, signal.SIGTERM)
            except OSError:   # gone already
                pass


@dataclass(frozen=True)
class SchedulerAddress:
    """A scheduler address as given, and its parts."""
    text: str
    scheme: str
    host: str
    port: int

    @property
    def secure(self) -> bool:
        return self.scheme in SECURE_SCHEMES


def parse_address(address: str) -> SchedulerAddress:
    """``scheme://host:port`` checked (scheme tcp:// when none is given), one line naming the part that is wrong."""
    text = address.strip()
    where = f"--dask {shorten(address)}"
    example = "e.g. tcp://10.0.0.5:8786 (what 'dask scheduler' prints)"
    if not text:
        raise ParameterError(f"--dask: give the scheduler's address, {example}")
    if not text.isprintable():
        raise ParameterError(f"--dask {quoted(address)}: control characters in the address; {example}")
    scheme, sep, loc = text.partition("://")
    if not sep:
        scheme, loc = "tcp", text
    scheme = scheme.lower()
    if scheme not in SCHEMES:
        raise ParameterError(f"{where}: '{shorten(scheme)}://' is not a scheduler address Dask can reach "
                             f"(use {', '.join(s + '://' for s in SCHEMES)}), {example}")
    loc = loc.rstrip("/")
    if loc.startswith("["):                      # [IPv6]:port
        host, _, rest = loc[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else (None if not rest else rest)
    else:
        host, sep, port_text = loc.rpartition(":")
        if not sep:
            host, port_text = loc, None
    if not host:
        raise ParameterError(f"{where}: no host; give the scheduler's host and port, {example}")
    if port_text is None:
        raise ParameterError(f"{where}: no port; give the port the scheduler listens on ({DEFAULT_PORT} unless "
                             f"told otherwise), {example}")
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ParameterError(f"{where}: port {quoted(port_text)} is not a port number (1 to 65535), {example}")
    return SchedulerAddress(text, scheme, host, int(port_text))


def connection_args(addr: SchedulerAddress) -> dict:
    """Dask's connection arguments for ``addr``: from Dask's configuration (``distributed.comm.tls.*`` and
    ``require-encryption``), read as ``distributed.Security()`` reads them.  tls:// and wss:// need a CA
    file and the client's certificate and key there."""
    distributed = _distributed()
    where = f"--dask {shorten(addr.text)}"
    try:
        security = distributed.Security()
        args = security.get_connection_args("client")
    except (OSError, ValueError, TypeError) as exc:   # ssl.SSLError is an OSError: a file missing or not PEM
        import dask
        tls = dask.config.get("distributed.comm.tls", {}) or {}
        client = tls.get("client", {}) or {}
        files = [(name, value) for name, value in (("ca-file", tls.get("ca-file")), ("client.cert", client.get("cert")),
                                                   ("client.key", client.get("key"))) if value]
        missing = [f"{name} {shorten(value, 200)}" for name, value in files
                   if not str(value).lstrip().startswith("-----BEGIN") and not os.path.isfile(value)]
        if missing:
            what = f"no such file: distributed.comm.tls.{', '.join(missing)}"
        else:
            what = (f"{_first_line(exc)}: distributed.comm.tls."
                    f"{', '.join(f'{n} {shorten(v, 200)}' for n, v in files) or ' (nothing set)'}")
        raise ParameterError(f"{where}: Dask's TLS settings cannot be used ({what})") from None
    if addr.secure and args.get("ssl_context") is None:
        raise ParameterError(f"{where}: {addr.scheme}:// needs Dask's TLS settings: set distributed.comm.tls.ca-file, "
                             f"distributed.comm.tls.client.cert and distributed.comm.tls.client.key in Dask's "
                             f"configuration (docs/cluster.md)")
    if args.get("require_encryption") and not addr.secure:
        raise ParameterError(f"{where}: Dask's configuration requires encryption "
                             f"(distributed.comm.require-encryption): give a tls:// address")
    return {"security": security, "args": args}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return shorten(text.splitlines()[0], 160) if text else type(exc).__name__


def probe_scheduler(addr: SchedulerAddress, args: dict) -> None:
    """Refuse, in one line naming ``addr`` and what answered there, anything but a Dask scheduler.

    Each step has a timeout (CONNECT_TIMEOUT_S): a refused or unknown address fails at once,
    a listener that stays silent or answers with bytes that are not Dask's protocol fails
    within the timeout, without Dask ever sizing a buffer from those bytes beyond what
    arrives, and a Dask worker or nanny is told apart from the scheduler.
    """
    where = f"--dask {shorten(addr.text)}"
    start = "start one with 'dask scheduler' and workers with 'dask worker ADDRESS'"
    if addr.scheme != "ucx":     # every other comm runs over TCP: refused or unknown at once
        import socket
        try:
            socket.create_connection((addr.host, addr.port), timeout=CONNECT_TIMEOUT_S).close()
        except UnicodeError:   # a label longer than DNS allows (63), ...
            raise ParameterError(f"{where}: {quoted(addr.host)} is not a host name DNS can look up") from None
        except OSError as exc:
            reason = getattr(exc, "strerror", None) or _first_line(exc)
            raise ParameterError(f"{where}: no Dask scheduler answers there ({reason}); {start}") from None
    from distributed.comm.registry import get_backend
    try:
        get_backend(addr.scheme).get_connector()
    except Exception as exc:   # noqa: BLE001 - e.g. ucx://, which distributed 2025+ moved to distributed-ucxx
        hint = "; UCX needs the distributed-ucxx package" if addr.scheme == "ucx" else ""
        raise ParameterError(f"{where}: this installation of Dask cannot connect over {addr.scheme}:// "
                             f"({type(exc).__name__}: {_first_line(exc)}){hint}") from None
    result = _in_a_thread(lambda: _identity(addr, args["args"]), CONNECT_TIMEOUT_S + 1.0)
    if isinstance(result, dict) and result.get("type") == "Scheduler":
        return
    if isinstance(result, dict) and result.get("type") in ("Worker", "Nanny"):
        theirs = result.get("scheduler")
        raise ParameterError(f"{where}: a Dask {result['type'].lower()} answers there, not the scheduler; give the "
                             f"scheduler's address{f' ({theirs})' if theirs else ''}")
    if isinstance(result, dict):
        raise ParameterError(f"{where}: a Dask {shorten(result.get('type'))} answers there, not a scheduler; {start}")
    what = _describe(addr, result)
    raise ParameterError(f"{where}: {what}: not a Dask scheduler; give the address 'dask scheduler' prints")


def _in_a_thread(fn, timeout):
    """fn() in a thread of its own (its own event loop: the caller's may be running, as in Jupyter), waited
    for at most ``timeout`` s: its result, the exception it raised, or TimeoutError."""
    import threading
    box = []

    def target():
        try:
            box.append(fn())
        except BaseException as exc:   # noqa: BLE001 - handed to the caller, who reports it
            box.append(exc)
    thread = threading.Thread(target=target, name="caustica-probe", daemon=True)
    thread.start()
    thread.join(timeout)
    return box[0] if box else TimeoutError(f"no answer in {timeout:g} s")


def _identity(addr: SchedulerAddress, args: dict):
    """Dask's handshake and its ``identity`` call at ``addr``, each within CONNECT_TIMEOUT_S."""
    import asyncio
    import warnings
    from distributed.comm import connect as comm_connect

    async def ask():
        comm = await asyncio.wait_for(comm_connect(f"{addr.scheme}://{_loc(addr)}", timeout=CONNECT_TIMEOUT_S,
                                                   **args), CONNECT_TIMEOUT_S)
        try:
            await asyncio.wait_for(comm.write({"op": "identity", "reply": True}), CONNECT_TIMEOUT_S)
            return await asyncio.wait_for(comm.read(), CONNECT_TIMEOUT_S)
        finally:
            comm.abort()
    with warnings.catch_warnings():          # e.g. ucx's FutureWarning: it is reported as the error instead
        warnings.simplefilter("ignore")
        return asyncio.run(ask())


def _loc(addr: SchedulerAddress) -> str:
    return f"[{addr.host}]:{addr.port}" if ":" in addr.host else f"{addr.host}:{addr.port}"


def _describe(addr: SchedulerAddress, error: BaseException) -> str:
    """What answered at ``addr`` when Dask's handshake failed with ``error``: for plain TCP, the first
    bytes it sends on its own (a Dask scheduler greets at once), read within SNIFF_S."""
    if isinstance(error, TimeoutError):
        waited = f"no Dask handshake over {addr.scheme}:// within {CONNECT_TIMEOUT_S:g} s"
    else:
        waited = f"Dask's {addr.scheme}:// handshake failed ({type(error).__name__}: {_first_line(error)})"
    if addr.scheme != "tcp":
        return waited
    import socket
    try:
        with socket.create_connection((addr.host, addr.port), timeout=SNIFF_S) as sock:
            data = sock.recv(64)
    except socket.timeout:
        return (f"something accepted the connection but sent nothing (waited {CONNECT_TIMEOUT_S:g} s; a Dask "
                f"scheduler greets at once, a tls:// one waits for TLS)")
    except OSError as exc:
        return f"the connection failed ({getattr(exc, 'strerror', None) or _first_line(exc)})"
    if not data:
        return "something accepted the connection and closed it without a word"
    return f"something answered with bytes that are not Dask's protocol ({shorten(repr(data), 60)})"


def _source_hash() -> str:
    from .jit import source_hash
    return source_hash()


def check_workers_build(cluster: Cluster) -> None:
    mine = _source_hash()
    for worker, theirs in cluster.client.run(_source_hash).items():
        if theirs != mine:
            raise ParameterError(f"--dask {cluster.address}: worker {worker} runs another build of caustica "
                                 f"(source {theirs}, this one {mine}); its passes would not have this "
                                 f"build's bits: install the same caustica on every worker")


def _kill_hook(start: int, stop: int) -> None:
    hook = os.environ.get(KILL_HOOK_ENV)
    if not hook:
        return
    at, _, flag = hook.partition(":")
    if start <= int(at) < stop:
        if flag == HANG_FLAG:
            time.sleep(3600)
            return
        if not flag:
            os._exit(70)   # no FILE: every time, as a task that always kills its worker
        try:
            fd = os.open(flag, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            return  # killed once already: this is the task run again
        os.close(fd)
        os._exit(70)


def _scene_task(scene):
    return scene


def send_scene(client, scene):
    """A future of ``scene`` held by every worker; waits until it is.

    Sent as a task's argument, not scattered: the scheduler keeps the task, so when
    every worker holding the scene dies it is made again rather than lost (scattered
    data cannot be recovered, and a lost scene would cancel the whole render).
    """
    fut = client.submit(_scene_task, scene, pure=False)
    client.replicate([fut])    # waits for the task, then copies its result to every worker
    return fut


class WorkerBuildError(ParameterError):
    """A worker that runs another build of caustica than the client (its passes would have other bits)."""


def render_part_task(scene, method_name: str, settings: Settings, start: int, stop: int, source: str):
    """A worker's task: the passes [start, stop) on one thread, (part, per-pass log, seconds).

    ``source`` is the client's source hash: a worker that joined after connecting and runs
    another build refuses the task rather than mixing its bits in.
    """
    from . import methods
    from .driver import QuietBar
    if _source_hash() != source:
        raise WorkerBuildError(f"a worker runs another build of caustica (source {_source_hash()}, the client's "
                               f"{source}): install the same caustica on every worker")
    _kill_hook(start, stop)
    t0 = time.perf_counter()
    part, log = methods.get(method_name).render_part(scene, settings.replace(threads=1), start, stop, QuietBar)
    return part, log, time.perf_counter() - t0


@dataclass
class ClusterLog:
    """What the distributed loop measured, for the sidecar."""
    workers: int = 0
    worker_threads: int = 0
    tasks: int = 0
    task_passes: list = field(default_factory=list)
    task_seconds: list = field(default_factory=list)      # worker-side work of each task
    task_wall_seconds: list = field(default_factory=list)  # from sending the task to having its result
    scene_transfer_s: float = 0.0
    result_transfer_s: float = 0.0
    result_bytes: int = 0
    max_task_passes: int = MAX_TASK_PASSES   # the cap the workers' memory set (max_task_passes)
    late_grace_s: float = 0.0  # the grace after the budget when tasks were given up
    late_tasks: int = 0       # tasks given up past the --time budget's grace (their passes dropped)
    dropped_passes: int = 0   # passes rendered or in flight but not merged: after a late task's gap

    def to_json(self, address: str) -> dict:
        wall, work = sum(self.task_wall_seconds), sum(self.task_seconds)
        return {"scheduler": address, "workers": self.workers, "worker_threads": self.worker_threads,
                "tasks": self.tasks, "task_passes": self.task_passes, "task_seconds": self.task_seconds,
                "task_wall_seconds": self.task_wall_seconds, "scene_transfer_s": self.scene_transfer_s,
                "result_transfer_s": self.result_transfer_s, "result_bytes": self.result_bytes,
                "task_overhead_s": max(0.0, wall - work), "max_task_passes": self.max_task_passes,
                "late_tasks": self.late_tasks,
                "dropped_passes": self.dropped_passes}


class _ClusterFailed(Exception):
    """What the cluster (not caustica, not the disk) raised while this render waited on it."""

    def __init__(self, cause):
        super().__init__(str(cause))
        self.cause = cause


def cluster_failures() -> tuple:
    """The exceptions that mean the cluster, not caustica, failed: a task that killed its workers, a lost link."""
    from asyncio import CancelledError
    from concurrent.futures import CancelledError as FutureCancelled
    from distributed.comm.core import CommClosedError
    distributed = _distributed()
    return (distributed.KilledWorker, CommClosedError, CancelledError, FutureCancelled, TimeoutError, OSError)


def _next_size(start: int, want: int, limit: int) -> int:
    """The passes of the next task: a power of two <= want, limit and MAX_TASK_PASSES, aligned when it can be.

    A part aligned to its size (or to a trunk block, when larger) carries one film block
    per trunk block of passes, the least data a part can carry.
    """
    size = 1
    while size * 2 <= min(want, limit, MAX_TASK_PASSES):
        size *= 2
    while start % min(size, TRUNK_PASSES):
        size //= 2
    return size


def part_bytes_per_pixel(passes: int) -> int:
    """Bytes per pixel a worker's part of ``passes`` passes holds at most: a float64 RGB image per block.

    Tasks are powers of two aligned to min(size, TRUNK_PASSES) (:func:`_next_size`): a part keeps
    each finished 64-pass block apart (the client folds them into its trunk, in order) and, while
    it adds passes, the pairwise chain of the block in progress, at most MAX_FILM_IMAGES images.
    """
    return (passes // TRUNK_PASSES + MAX_FILM_IMAGES) * 3 * 8


def max_task_passes(cluster: Cluster, method_cls, settings, scene=None) -> int:
    """The most passes a task may take so that its part and a pass's work fit a worker's memory share.

    A pass's work: the method's per-pixel arrays and its photon or stream buffers
    (``pass_buffer_bytes``, which do not scale with the pixels).  Read once per render: a
    worker with less memory that joins later is not seen.  Raises ParameterError, with the
    estimate, when not even one pass fits.
    """
    budget = cluster.task_memory_bytes()
    if budget is None:
        return MAX_TASK_PASSES
    budget = int(budget * TASK_MEMORY_FRACTION)
    pixels = settings.width * settings.height
    from .film import IMAGE_BYTES_PER_PIXEL
    per_pass = pixels * getattr(method_cls, "bytes_per_pixel", IMAGE_BYTES_PER_PIXEL)
    if scene is not None and hasattr(method_cls, "pass_buffer_bytes"):
        per_pass += method_cls.pass_buffer_bytes(scene, settings)
    need = per_pass + pixels * part_bytes_per_pixel(1)
    if need > budget:
        raise ParameterError(f"--dask: a task of a {settings.width}x{settings.height} {method_cls.name} render "
                             f"would need about {need / 1e9:.2f} GB, more than the {budget / 1e9:.2f} GB a worker "
                             f"thread may use ({TASK_MEMORY_FRACTION:.0%} of its share of the worker's memory "
                             f"limit); give the workers more memory or fewer threads, or lower --res")
    blocks = (budget - need) // (pixels * 3 * 8)
    return int(max(1, min(MAX_TASK_PASSES, (blocks + 1) * TRUNK_PASSES - 1)))


class DaskPasses:
    """The driver's executor on a Dask cluster (:class:`caustica.driver.LocalPasses` says what each method does):
    a range of passes is a task on one worker thread; parts come back in any order and are merged in pass order."""

    def __init__(self, cluster: Cluster, method_cls, scene, settings, plan):
        self.cluster, self.method_cls, self.scene, self.settings, self.plan = cluster, method_cls, scene, settings, plan
        self.clog = ClusterLog(workers=len(cluster.worker_threads), worker_threads=cluster.threads)
        self.label = f" on {self.clog.workers} workers"
        self.source = _source_hash()
        self.flying: dict = {}               # future -> (start, stop, time sent)
        self.done: dict = {}                 # start -> (part, per-pass log), back before a pass still out
        self.arrived = queue.SimpleQueue()   # tasks that ended (done, failed or cancelled), in the order they did
        self.slots = 1

    def start(self) -> None:
        try:
            self.clog.max_task_passes = max_task_passes(self.cluster, self.method_cls, self.settings, self.scene)
        except cluster_failures() as exc:
            raise ClusterError(f"--dask {self.cluster.address}: the scheduler did not answer when asked for the "
                               f"workers' memory ({type(exc).__name__})") from None
        t0 = time.perf_counter()
        self.scene_f = send_scene(self.cluster.client, self.scene)
        self.clog.scene_transfer_s = time.perf_counter() - t0

    def room(self) -> int:
        """Free task slots (workers may join or leave during the render); none while too many parts are held."""
        try:
            self.slots = max(1, self.cluster.threads)
        except cluster_failures() as exc:
            raise _ClusterFailed(exc) from exc
        self.clog.workers = max(self.clog.workers, len(self.cluster.worker_threads))
        self.clog.worker_threads = max(self.clog.worker_threads, self.slots)
        return 0 if len(self.done) >= MAX_HELD_PARTS_PER_SLOT * self.slots else max(0, self.slots - len(self.flying))

    def task_size(self, start: int, target, pass_s: float) -> int:
        """About TASK_SECONDS of passes (longer on many threads), what is left shared among the slots."""
        limit = self.clog.max_task_passes if target is None else min(target - start, self.clog.max_task_passes)
        want = max(1, int(TASK_SECONDS * max(1.0, self.slots / THREADS_FOR_LONGER_TASKS) / max(pass_s, 1e-6)))
        if target is not None:
            want = min(want, -(-(target - start) // self.slots))
        return _next_size(start, want, limit)

    def submit(self, start: int, stop: int) -> None:
        fut = self.cluster.client.submit(render_part_task, self.scene_f, self.method_cls.name, self.settings, start,
                                         stop, self.source, pure=False)
        self.flying[fut] = (start, stop, time.perf_counter())
        fut.add_done_callback(self.arrived.put)   # on Dask's thread, when the task ends however it ends

    def collect(self, state, late_after):
        if not self.flying:
            return None
        fut = self._next_back(late_after)
        if fut is None:   # late: given up
            self._give_up(state)
            return None
        try:
            start, stop, sent = self.flying[fut]
            t1 = time.perf_counter()
            part, part_log, work_s = fut.result()
            del self.flying[fut]
        except cluster_failures() as exc:
            if isinstance(exc, CausticaError):
                raise
            raise _ClusterFailed(exc) from exc
        clog = self.clog
        clog.result_transfer_s += time.perf_counter() - t1
        clog.result_bytes += part.nbytes
        clog.tasks += 1
        clog.task_passes.append(stop - start)
        clog.task_seconds.append(work_s)
        clog.task_wall_seconds.append(time.perf_counter() - sent)
        compile_s = sum(stats.get("timings", {}).get("compile_s", 0.0) for _, stats in part_log)
        self.done[start] = (part, part_log)
        merged = []
        while state.end in self.done:
            part, part_log = self.done.pop(state.end)
            state = state.merge(part)
            merged += part_log
        return state, merged, max(0.0, work_s - compile_s) / (stop - start)

    def _next_back(self, late_after):
        """The next task to end, waited for in short waits (so Ctrl-C is seen at once whatever the platform's
        locks do); None when none ended by ``late_after`` and the grace after it."""
        deadline = None
        if late_after is not None:
            # past the budget and its grace, what is still out is given up; before any task has come
            # back the workers may still be compiling or loading their kernels: a longer allowance
            self.grace = (max(LATE_TASK_GRACE_S, 3.0 * max(self.clog.task_wall_seconds)) if self.clog.tasks
                          else FIRST_TASK_GRACE_S)
            deadline = late_after + self.grace
        while True:
            left = None if deadline is None else deadline - time.perf_counter()
            try:   # past the deadline, one look without waiting: a task that ended just now is not late
                return self.arrived.get(timeout=0.5 if left is None else min(0.5, max(0.0, left)))
            except queue.Empty:
                if left is not None and left <= 0:
                    return None

    def _give_up(self, state) -> None:
        """Cancel the late tasks: their passes, and those back after them, are dropped."""
        clog = self.clog
        clog.late_grace_s, clog.late_tasks = self.grace, len(self.flying)
        clog.dropped_passes = (sum(stop - start for start, stop, _ in self.flying.values())
                               + sum(len(part_log) for _, part_log in self.done.values()))
        try:
            self.cluster.client.cancel(list(self.flying))
        except cluster_failures() as exc:   # a scheduler gone by now: nothing left to cancel
            raise _ClusterFailed(exc) from exc
        self.flying.clear()
        self.done.clear()
        if state.passes == 0:
            raise ClusterError(f"--time {self.plan.time_s:g}: no pass could be merged within the budget and its "
                               f"grace of {clog.late_grace_s:g} s ({clog.late_tasks} task(s) still out, given up): "
                               f"are the workers hung?")

    def stop(self, exc: BaseException, state) -> None:
        """Cancel this render's tasks; after Ctrl-C closing stops a local cluster at once; a failure of the
        cluster is one ClusterError (the passes finished saved to the checkpoint first)."""
        try:
            self.cluster.client.cancel(list(self.flying))
        except Exception:   # a scheduler that is gone has nothing left to cancel
            pass
        if isinstance(exc, KeyboardInterrupt):
            self.cluster.interrupted = True
        if not isinstance(exc, _ClusterFailed):
            return
        exc, saved = exc.cause, ""
        if self.plan.checkpoint is not None and state.passes > 0:
            ckpt.save(self.plan.checkpoint, self.method_cls, self.scene, self.settings, state)
            saved = f"; saved to {self.plan.checkpoint}, rerun to resume"
        if isinstance(exc, _distributed().KilledWorker):
            what = "a task killed every worker that ran it (Dask's KilledWorker)"
        elif self.cluster.client.status != "running":
            what = f"lost the scheduler ({type(exc).__name__})"
        else:
            what = f"the cluster dropped this render's tasks ({type(exc).__name__}: " \
                   f"{str(exc).splitlines()[0] if str(exc) else 'no detail'})"
        where = self.cluster.address
        flag = f"--dask {where}" if self.cluster.local is None else f"--workers (a local cluster at {where})"
        raise ClusterError(f"{flag}: {what}; {state.passes} passes were finished{saved}") from None
