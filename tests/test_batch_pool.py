"""`vslam.batch.pool.run_on_pool`: each job on spawned local workers, a worker that dies failing its job alone."""

from __future__ import annotations

import os
import signal
import time
from dataclasses import dataclass

from vslam.batch.pool import run_on_pool

CRASHES, FAILS = -1, -2


@dataclass(frozen=True)
class Result:
    job: int
    value: int | None
    status: str = "ok"


def square(job: int) -> Result:
    """The task: squares a number; CRASHES kills its own worker (what an OOM kill or a segfault looks like),
    FAILS returns a failed result; jobs ≥ 100 are slow (they are in flight when another worker dies)."""
    if job == CRASHES:
        os.kill(os.getpid(), signal.SIGKILL)
    if job == FAILS:
        return Result(job, None, "failed")
    if job >= 100:
        time.sleep(1.0)
    return Result(job, job * job)


def crashed(job: int) -> Result:
    return Result(job, None, "crashed")


def run(jobs: list[int], workers: int = 2, fail_fast: bool = False) -> dict[int, Result]:
    seen: dict[int, Result] = {}

    def on_result(index: int, result: Result) -> None:
        assert index not in seen, f"job {index} reported twice"
        seen[index] = result

    run_on_pool(square, jobs, workers, on_result, lambda r: fail_fast and r.status != "ok", crashed)
    return seen


def test_a_dying_worker_fails_its_own_job_alone() -> None:
    """The crash breaks the pool under the slow job beside it: that one is run again and succeeds; the crashed
    job is run again alone, dies again and is the only failure; the jobs after it run on a fresh pool."""
    jobs = [3, 100, CRASHES, 101, 4, 5]
    seen = run(jobs)
    assert sorted(seen) == list(range(len(jobs)))
    assert seen[2] == Result(CRASHES, None, "crashed")
    for index, job in enumerate(jobs):
        if job != CRASHES:
            assert seen[index] == Result(job, job * job), index


def test_a_stopping_result_drops_the_jobs_not_started() -> None:
    seen = run([3, FAILS, 4, 5, 6, 7], workers=1, fail_fast=True)
    assert sorted(seen) == [0, 1] and seen[1].status == "failed"
    seen = run([3, CRASHES, 4, 5], workers=1, fail_fast=True)
    assert sorted(seen) == [0, 1] and seen[1].status == "crashed"
