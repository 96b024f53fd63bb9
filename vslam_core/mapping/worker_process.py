"""The map backend's worker process: one per run, beside tracking, serving the bundle adjuster's problems and the
loop search's keyframes in the order they were submitted (`BackendWorker`, and each service's side of it,
`ServiceClient`); started and stopped the same way each time, and kept idle for the next run when asked to
(`reuse_workers`).

One process, not one per job kind: starting a process costs Python's start, numpy's, OpenCV's and gtsam's imports,
~1.2 s of CPU for the loop search's own process (measured: on KITTI 05 0:300 that was nearly all the CPU loop closing
cost, its 73 searches ~0.35 s), taken from tracking on 2 cores. The two kinds of job share the process's core in turn;
each result is still collected at a fixed point chosen by its client, so runs stay deterministic.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import ctypes.util
import importlib
import multiprocessing
import os
import queue
import sys
import threading
import types
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from multiprocessing.queues import Queue
from typing import Any, Generic, Protocol, TypeVar


class WorkerGone(Exception):
    """The worker process is gone (killed, crashed): its client does the job in this process from now on."""


class Service(Protocol):
    """What the worker process runs jobs on: a bundle adjuster, a loop search."""

    def run(self, job: Any) -> Any: ...


@dataclass(frozen=True)
class _Setup:
    """To the worker: (re)create the service `name` as `factory(*args)` (a picklable module-level callable)."""

    name: str
    factory: Callable[..., Service]
    args: tuple[Any, ...]


@dataclass(frozen=True)
class _Reset:
    """To a kept worker: a run closed; forget its services (and what they hold) until the next run sets them up."""


@contextlib.contextmanager
def without_main() -> Iterator[None]:
    """Start a spawned process without running the parent's main module in it. Spawn imports the parent's
    `__main__` in the child (so that what was pickled from it resolves): the `vslam` script (the whole CLI) or
    `benchmarks.speed` (polars, rerun), 1.1–1.4 s of CPU measured in the loop worker, more than all its searches
    on KITTI 05 0:300 together, taken from tracking on 2 cores. A worker's target and arguments all come from
    vslam_core, so the child needs no main module: multiprocessing sends none while `__main__` has no spec or
    file (multiprocessing.spawn.get_preparation_data)."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


def _free_memory_returner() -> Callable[[], None]:
    """A call handing the heap's free pages back to the system (glibc's `malloc_trim(0)`; elsewhere nothing).
    The worker unpickles a keyframe's image and arrays for each job (~0.5 MB on KITTI) and frees them: without it
    its resident memory grew 11.4 KB a frame over a revisited street while what it holds stayed flat (with it,
    1.6 KB; docs/map-backend.md, memory on a revisited street)."""
    name = ctypes.util.find_library("c") if sys.platform.startswith("linux") else None
    trim = getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    if trim is None:
        return lambda: None
    return lambda: trim(0)


def _serve(jobs: Any, connection: Connection, preload: tuple[str, ...]) -> None:
    """The worker process: import `preload`, then handle the messages on `jobs` in order until None arrives. A job
    `(name, job)` is run by the service `name` and its result sent back as `(name, result)`."""
    for module in preload:  # before the first job, while the run starts up (gtsam: ~0.5 s)
        importlib.import_module(module)
    services: dict[str, Service] = {}
    parent = multiprocessing.parent_process()
    release = _free_memory_returner()
    while True:
        try:
            message = jobs.get(timeout=1.0)
        except queue.Empty:  # nothing to do: stop if the run's process is gone (killed: no None will come)
            if parent is not None and not parent.is_alive():
                return
            continue
        if message is None:
            return
        if isinstance(message, _Setup):
            services[message.name] = message.factory(*message.args)
        elif isinstance(message, _Reset):
            services.clear()
        else:
            name, job = message
            try:
                connection.send((name, services[name].run(job)))
            except (BrokenPipeError, OSError):  # the run's process is gone
                return
            del job, message  # the job's arrays freed before the heap is trimmed
            release()


def stop_worker(connection: Connection, process: BaseProcess, jobs: Queue[Any], *, gone: bool = False,
                timeout_s: float = 5.0) -> None:
    """Stop, join and if need be kill a worker process whose answers were all received.

    `connection` is this side of the pipe the worker answers on. The stop message (None) goes on `jobs`. A worker
    already gone (closed pipe) is not an error; one known `gone` is sent nothing, and what is left in its queue
    is dropped. The worker gets `timeout_s` to exit, then is killed.
    """
    if not gone:
        with contextlib.suppress(OSError, EOFError):
            jobs.put(None)
    connection.close()
    jobs.close()
    if gone:  # nothing will read the queue: do not wait for its feeder thread
        jobs.cancel_join_thread()
    else:
        jobs.join_thread()  # the queue's feeder thread has written everything to the pipe
    process.join(timeout=timeout_s)
    if process.is_alive():
        process.kill()


@dataclass(frozen=True)
class IdleWorker:
    """A worker process whose run closed, with this side of its channels: `jobs` (a queue) and `connection`
    (the pipe its results come back on)."""

    process: BaseProcess
    connection: Connection
    jobs: Queue[Any]


MAX_IDLE = 2  # idle workers kept
_pool: list[IdleWorker] = []
_pool_lock = threading.Lock()
_pool_owner = os.getpid()
_reuse = False


def reuse_workers(enabled: bool = True) -> None:
    """Keep the map backend's worker process when a run closes, for the next run of this process (a test
    session, a batch worker running many short windows): starting one costs ~1 s of CPU (Python, numpy, gtsam
    and OpenCV imports), as much as a short run's work. A reused worker starts each run with fresh services, so
    results are the same. Off by default: a run then stops its worker when it closes (so its CPU time and peak
    RSS count as this process's finished children, which `benchmarks/speed.py` reads). Turning it off stops the
    idle ones."""
    global _reuse
    with _pool_lock:
        _reuse = enabled
        stopping = [] if enabled else list(_pool)
        if not enabled:
            _pool.clear()
    for worker in stopping:
        stop_worker(worker.connection, worker.process, worker.jobs)


def _take_idle_worker() -> IdleWorker | None:
    """A live idle worker kept by an earlier run of this process, or None."""
    global _pool_owner
    with _pool_lock:
        if os.getpid() != _pool_owner:  # a forked child: the workers and their channels are its parent's
            _pool.clear()
            _pool_owner = os.getpid()
        while _pool:
            worker = _pool.pop()
            if worker.process.is_alive():
                return worker
    return None


def _keep_idle_worker(worker: IdleWorker) -> bool:
    """Keep a worker that finished its run (nothing in flight) for the next one, if `reuse_workers` is on and it
    is alive; False if it was not kept (the caller stops it)."""
    with _pool_lock:
        if not _reuse or os.getpid() != _pool_owner or len(_pool) >= MAX_IDLE or not worker.process.is_alive():
            return False
        _pool.append(worker)
        return True


class BackendWorker:
    """This side of a run's worker process: set services up, submit jobs to them, receive their results.

    Jobs are run one at a time in the order submitted, whatever their service; `receive(name)` returns the
    oldest result of that service not yet received, waiting for it (results of other services read meanwhile
    are kept for their own `receive`). Jobs go through a queue, whose feeder thread writes them to the pipe, so
    submitting a keyframe's image does not block tracking. If the process is gone, `submit` and `receive` raise
    `WorkerGone` and every client does its jobs itself from then on.
    """

    def __init__(self, preload: tuple[str, ...] = ("gtsam",)) -> None:
        self._results: dict[str, collections.deque[Any]] = collections.defaultdict(collections.deque)
        self._awaiting = 0  # jobs submitted whose result has not been read from the pipe
        self._gone = False
        self._closed = False
        self._process: BaseProcess
        if (idle := _take_idle_worker()) is not None:
            self._process, self._connection, self._jobs = idle.process, idle.connection, idle.jobs
            return
        context = multiprocessing.get_context("spawn")
        self._jobs = context.Queue()
        self._connection, child = context.Pipe(duplex=False)
        self._process = context.Process(target=_serve, args=(self._jobs, child, preload), name="vslam-backend",
                                        daemon=True)
        with without_main():
            self._process.start()
        child.close()

    @property
    def alive(self) -> bool:
        return not self._gone and self._process.is_alive()

    def setup(self, name: str, factory: Callable[..., Service], *args: Any) -> None:
        """Create the service `name` in the worker as `factory(*args)` (before its first job)."""
        self._jobs.put(_Setup(name, factory, args))

    def submit(self, name: str, job: Any) -> None:
        if self._closed or not self.alive:
            self._gone = True
            raise WorkerGone
        self._jobs.put((name, job))
        self._awaiting += 1

    def receive(self, name: str) -> Any:
        waiting = self._results[name]
        while not waiting:
            if self._gone:
                raise WorkerGone
            try:
                service, result = self._connection.recv()
            except (EOFError, OSError):
                self._gone = True
                raise WorkerGone from None
            self._awaiting -= 1
            self._results[service].append(result)
        return waiting.popleft()

    def close(self) -> None:
        """The run is done with its worker: the results in flight are received and dropped, its services reset,
        then the worker is kept idle for the next run (`reuse_workers`) or stopped. Closing again does nothing."""
        if self._closed:
            return
        self._closed = True
        worker = IdleWorker(self._process, self._connection, self._jobs)
        awaiting, self._awaiting = self._awaiting, 0
        self._results.clear()
        if self._gone:
            stop_worker(self._connection, self._process, self._jobs, gone=True)
            return
        try:
            for _ in range(awaiting):  # received and dropped, so the worker is not left blocked on a full pipe
                self._connection.recv()
            self._jobs.put(_Reset())
            if _keep_idle_worker(worker):
                return
        except (OSError, EOFError):  # the worker is gone
            pass
        stop_worker(self._connection, self._process, self._jobs)


Job = TypeVar("Job")
Result = TypeVar("Result")


class ServiceClient(Generic[Job, Result]):
    """One service's side of the run's worker (the bundle adjuster's, the loop search's): one job at a time,
    submitted now and collected at a fixed point chosen by the caller. Without a worker, or once it is gone, the
    job is run here by `run_here` when it is collected; `on_gone` is called when the worker is found gone (to
    start the service's state afresh in this process)."""

    def __init__(self, worker: BackendWorker | None, name: str, run_here: Callable[[Job], Result],
                 factory: Callable[..., Service], *args: Any, on_gone: Callable[[], None] | None = None) -> None:
        """`factory(*args)` creates the service in the worker."""
        self._worker = worker
        self._name = name
        self._run_here = run_here
        self._on_gone = on_gone
        self._pending: Job | None = None
        self._sent = False  # the pending job went to the worker
        if worker is not None:
            worker.setup(name, factory, *args)

    @property
    def busy(self) -> bool:
        return self._pending is not None

    def submit(self, job: Job) -> None:
        assert self._pending is None, "collect the previous result first"
        self._pending, self._sent = job, False
        if self._worker is not None:
            try:
                self._worker.submit(self._name, job)
                self._sent = True
            except WorkerGone:
                self._gone()

    def collect(self) -> tuple[Job, Result] | None:
        """The submitted job and its result (waiting for it), or None if nothing was submitted."""
        job, self._pending = self._pending, None
        if job is None:
            return None
        if self._worker is not None and self._sent:
            try:
                result: Result = self._worker.receive(self._name)
                return job, result
            except WorkerGone:  # the worker died (e.g. killed): run here from now on
                self._gone()
        return job, self._run_here(job)

    def _gone(self) -> None:
        self._worker = None
        if self._on_gone is not None:
            self._on_gone()
