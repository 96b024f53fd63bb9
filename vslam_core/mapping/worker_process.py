"""Starting and stopping a background worker process (the bundle adjuster's, the loop search's) the same way
each time."""

from __future__ import annotations

import contextlib
import sys
import types
from collections.abc import Iterator
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
