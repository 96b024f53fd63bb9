"""Starting and stopping a background worker process (the bundle adjuster's, the loop search's) the same way
each time, and keeping idle ones for the next run when asked to (`reuse_workers`)."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import types
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from multiprocessing.queues import Queue
from typing import Any


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


def stop_worker(connection: Connection | None, process: BaseProcess | None, *, awaiting_result: bool,
                jobs: Queue[Any] | None = None, timeout_s: float = 5.0) -> None:
    """Drain, stop, join and if need be kill a worker process.

    `connection` is this side of the pipe the worker answers on; if `awaiting_result`, the answer to the job
    still in flight is received (and dropped) first, so the worker is not left blocked on a full pipe. The
    stop message (None) goes on `jobs` if the worker takes its jobs from a queue, else through `connection`.
    A worker already gone (closed pipe) is not an error. The worker gets `timeout_s` to exit, then is killed.
    """
    if connection is not None:
        try:
            if awaiting_result:
                connection.recv()
            if jobs is not None:
                jobs.put(None)
            else:
                connection.send(None)
        except (OSError, EOFError):
            pass
        connection.close()
    if jobs is not None:
        jobs.close()
        jobs.join_thread()  # the queue's feeder thread has written everything to the pipe
    if process is not None:
        process.join(timeout=timeout_s)
        if process.is_alive():
            process.kill()


@dataclass(frozen=True)
class IdleWorker:
    """A worker process whose run closed, with this side of its channels: `connection` (results, or both ways)
    and `jobs` (a queue of jobs, for workers that take them from one)."""

    process: BaseProcess
    connection: Connection
    jobs: Queue[Any] | None = None


MAX_IDLE = 2  # idle workers kept per kind
_pool: dict[str, list[IdleWorker]] = {}
_pool_lock = threading.Lock()
_pool_owner = os.getpid()
_reuse = False


def reuse_workers(enabled: bool = True) -> None:
    """Keep the map backend's worker processes when a run closes, for the next run of this process (a test
    session, a batch worker running many short windows): starting one costs ~0.7 s of CPU (Python, numpy and
    gtsam imports), as much as a short run's work. A reused worker starts each run from a fresh state, so results
    are the same. Off by default: a run then stops its workers when it closes (so their CPU time and peak RSS
    count as this process's finished children, which `benchmarks/speed.py` reads). Turning it off stops the idle
    ones."""
    global _reuse
    with _pool_lock:
        _reuse = enabled
        stopping = [] if enabled else [w for workers in _pool.values() for w in workers]
        if not enabled:
            _pool.clear()
    for worker in stopping:
        stop_worker(worker.connection, worker.process, awaiting_result=False, jobs=worker.jobs)


def take_idle_worker(kind: str) -> IdleWorker | None:
    """A live idle worker of this kind kept by an earlier run of this process, or None."""
    global _pool_owner
    with _pool_lock:
        if os.getpid() != _pool_owner:  # a forked child: the workers and their channels are its parent's
            _pool.clear()
            _pool_owner = os.getpid()
        workers = _pool.get(kind, [])
        while workers:
            worker = workers.pop()
            if worker.process.is_alive():
                return worker
    return None


def keep_idle_worker(kind: str, worker: IdleWorker) -> bool:
    """Keep a worker that finished its run (nothing in flight) for the next one, if `reuse_workers` is on and it
    is alive; False if it was not kept (the caller stops it)."""
    with _pool_lock:
        workers = _pool.setdefault(kind, [])
        if not _reuse or os.getpid() != _pool_owner or len(workers) >= MAX_IDLE or not worker.process.is_alive():
            return False
        workers.append(worker)
        return True


def release_worker(kind: str, worker: IdleWorker, *, awaiting_result: bool, restart: Any = None) -> None:
    """A run is done with its worker: the answer in flight, if `awaiting_result`, is received and dropped;
    `restart`, if given, goes on the worker's job queue (it lets go of the run's state); then the worker is kept
    idle for the next run (`keep_idle_worker`) or stopped (`stop_worker`). A worker already gone is stopped."""
    try:
        if awaiting_result:
            worker.connection.recv()
            awaiting_result = False
        if restart is not None and worker.jobs is not None:
            worker.jobs.put(restart)
        if keep_idle_worker(kind, worker):
            return
    except (OSError, EOFError):  # the worker is gone
        awaiting_result = False
    stop_worker(worker.connection, worker.process, awaiting_result=awaiting_result, jobs=worker.jobs)
