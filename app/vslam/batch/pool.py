"""Each log of a batch on local worker processes (`vslam eval --manifest … --workers N`), as `vslam.batch.on_ray`
does on a Ray cluster: results are reported as they finish, in any order, with their manifest index.

- Spawned processes (fork would copy Rerun's and OpenCV's threads in a broken state), one log in flight per
  worker, the next handed over as one finishes: a stop (Ctrl-C, SIGTERM, fail-fast) then waits for those only.
- A worker that dies (a crash in native code, an OOM kill) breaks the whole pool, and every log in flight
  with it. Those logs are run again one at a time: the one that kills its worker again is the one that
  failed (`on_crash`); the others finish normally and the batch goes on, on a fresh pool.
- Ctrl-C / SIGTERM are noted and acted on between waits (an exception raised by a signal handler inside the
  pool's own code can leave it waiting forever); the workers' runs are asked to stop (SIGINT, which a run
  notes between frames) and their results are kept.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import TypeVar

from vslam.no_pandas import leave_out_pandas

Job = TypeVar("Job")
Result = TypeVar("Result")

#: The error of a log whose worker died twice, once with other logs and once alone.
CRASH = "crash: its worker process died (out of memory? a crash in native code?)"


class Terminated(KeyboardInterrupt):
    """SIGTERM to the batch's process: handled as Ctrl-C, reported as SIGTERM (exit 143)."""


def run_on_pool(task: Callable[[Job], Result], jobs: list[Job], workers: int,
                on_result: Callable[[int, Result], None], stops: Callable[[Result], bool],
                on_crash: Callable[[Job], Result]) -> None:
    """Run ``task(job)`` for every job on `workers` spawned processes; ``on_result(index, result)`` as each
    finishes. After a result for which `stops` is true, the logs not started are dropped (those running are
    kept). `task` must never raise (a log's failure is a result); `on_crash(job)` is the result of a job whose
    worker died, alone. Raises `KeyboardInterrupt` (`Terminated` for SIGTERM) after keeping what finished."""
    waiting = deque(range(len(jobs)))
    while waiting:
        lost, stopped = _run_pool(task, jobs, waiting, workers, on_result, stops)
        for index in lost:  # alone: the one whose worker dies again is the one that kills it
            if stopped:
                return
            lost_again, stopped = _run_pool(task, jobs, deque([index]), 1, on_result, stops)
            if lost_again:
                result = on_crash(jobs[index])
                on_result(index, result)
                stopped = stops(result)
        if stopped:
            return


def _run_pool(task: Callable[[Job], Result], jobs: list[Job], waiting: deque[int], workers: int,
              on_result: Callable[[int, Result], None], stops: Callable[[Result], bool]) -> tuple[list[int], bool]:
    """Run jobs from `waiting` on one pool until it is empty, a result stops the batch, or the pool breaks;
    (the jobs in flight when it broke, whether a result stopped the batch)."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, min(workers, len(waiting))), mp_context=context,
                             initializer=leave_out_pandas) as pool:
        pending: dict[Future[Result], int] = {}

        def submit_next() -> None:
            if waiting:
                index = waiting.popleft()
                pending[pool.submit(task, jobs[index])] = index

        with _workers_ignore_sigint():  # a spawn pool starts its processes at the first submits
            for _ in range(workers):
                submit_next()
        with signals_noted() as signals:
            try:
                while pending:
                    if signals:
                        raise Terminated if signals[0] == signal.SIGTERM else KeyboardInterrupt
                    done, _ = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                    lost, stopped = _report(done, pending, on_result, stops)
                    if lost:  # every other log in flight is lost with it: wait for the pool to say so
                        more, stopped_too = _report(wait(pending).done, pending, on_result, stops)
                        return sorted(lost + more), stopped or stopped_too
                    if stopped:
                        _drain(pending, on_result)
                        return [], True
                    for _ in done:
                        submit_next()
            except KeyboardInterrupt:
                _drain(pending, on_result, nudge=lambda: _stop_workers(pool))
                raise
    return [], False


def _report(done: set[Future[Result]], pending: dict[Future[Result], int],
            on_result: Callable[[int, Result], None], stops: Callable[[Result], bool]) -> tuple[list[int], bool]:
    """Report the finished futures in manifest order; (indices of those whose worker died, a result stops)."""
    lost: list[int] = []
    stopped = False
    for future in sorted(done, key=lambda f: pending[f]):
        index = pending.pop(future)
        try:
            result = future.result()
        except BrokenProcessPool:
            lost.append(index)
            continue
        on_result(index, result)
        stopped = stopped or stops(result)
    return lost, stopped


def _drain(pending: dict[Future[Result], int], on_result: Callable[[int, Result], None],
           nudge: Callable[[], None] | None = None) -> None:
    """Cancel the jobs not started; wait for the running ones and keep their results (a stop: a worker that
    dies now loses its log, which is reported as not run). `nudge` (asking the workers to stop) is repeated
    while they run: a worker's run notes SIGINT only once its handler is in."""
    for future in pending:
        future.cancel()
    running = [future for future in pending if not future.cancelled()]
    while nudge is not None and running:
        nudge()
        running = list(wait(running, timeout=0.5).not_done)
    for future in wait(running).done:
        with contextlib.suppress(BrokenProcessPool):
            on_result(pending[future], future.result())


@contextlib.contextmanager
def _workers_ignore_sigint() -> Iterator[None]:
    """Start workers with SIGINT ignored (an ignored signal stays ignored across exec, and Python then keeps
    it so): Ctrl-C goes to the whole process group, and a worker still importing would die of it with a
    traceback. A run notes SIGINT between frames with its own handler; an idle worker ignores it."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def signals_noted() -> Iterator[list[int]]:
    """SIGINT and SIGTERM noted (in order of arrival) instead of acted on, inside the block."""
    noted: list[int] = []
    previous = {signum: signal.signal(signum, lambda signum, _frame: noted.append(signum))
                for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield noted
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Ask each worker's run to stop between frames (SIGINT, which a run notes; Ctrl-C in a terminal has sent
    it already, a SIGTERM to this process has not). The pool keeps its processes in a private attribute."""
    for process in list(getattr(pool, "_processes", {}).values()):
        if process.pid is not None and process.is_alive():
            with contextlib.suppress(OSError):
                os.kill(process.pid, signal.SIGINT)
