"""`vslam.batch.on_ray.run_on_ray` against a real one-node Ray cluster (the `ray_cluster` fixture)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from dataclasses import dataclass

import pytest
import ray_cluster as cluster

from vslam.batch.on_ray import MAX_MESSAGE, error_line, run_on_ray
from vslam_core.errors import VslamError

pytestmark = pytest.mark.ray

RAISES, FAILS, CRASHES = -1, -2, -3


@dataclass(frozen=True)
class Result:
    """What the tasks return: a value, or a failure with its message (like the batch runner's LogResult)."""

    job: int
    value: int | None
    status: str = "ok"
    message: str = ""


def square(job: int) -> Result:
    """The task: squares a number; the special jobs raise, return a failed result or kill their worker."""
    if job == RAISES:
        raise ValueError("bad log\nsecond line")
    if job == FAILS:
        return Result(job, None, "failed", "no frames")
    if job == CRASHES:
        os._exit(1)  # a worker crash (what an OOM kill looks like to Ray)
    if job >= 100:
        time.sleep(0.5)  # a slow job, for fail-fast
    return Result(job, job * job)


def as_failed(job: int, message: str) -> Result:
    return Result(job, None, "failed", message)


def is_failed(result: Result) -> bool:
    return result.status == "failed"


def run(address: str, jobs: list[int], fail_fast: bool = False) -> list[tuple[int, Result]]:
    seen: list[tuple[int, Result]] = []
    run_on_ray(square, jobs, address, num_cpus=1, on_result=lambda i, r: seen.append((i, r)), failed=is_failed,
               fail_fast=fail_fast, on_error=as_failed)
    return seen


def test_the_fixture_started_a_cluster_quickly(ray_cluster: str) -> None:
    print(f"ray start --head: ready in {cluster.last_start_seconds:.1f} s")
    assert cluster.last_start_seconds < cluster.START_TIMEOUT_S


def test_every_result_arrives_with_its_index_and_failures_come_back_as_results(
    ray_cluster: str, capfd: pytest.CaptureFixture[str]
) -> None:
    jobs = [3, RAISES, 4, FAILS, 5, CRASHES, 6]
    seen = run(ray_cluster, jobs)
    assert sorted(index for index, _ in seen) == list(range(len(jobs)))
    by_index = dict(seen)
    for index, job in enumerate(jobs):
        assert by_index[index].job == job
        if job >= 0:
            assert by_index[index] == Result(job, job * job)
    assert by_index[1].status == "failed" and by_index[1].message == "ValueError: bad log"  # one line
    assert by_index[3] == Result(FAILS, None, "failed", "no frames")
    assert by_index[5].status == "failed" and "\n" not in by_index[5].message and by_index[5].message
    noise = capfd.readouterr().err
    print(f"driver stderr ({len(noise.splitlines())} lines):\n{noise}")


def test_fail_fast_cancels_the_outstanding_jobs(ray_cluster: str) -> None:
    jobs = [FAILS] + [100 + i for i in range(20)]
    seen = run(ray_cluster, jobs, fail_fast=True)
    assert (0, Result(FAILS, None, "failed", "no frames")) in seen
    assert len(seen) < len(jobs)


def test_an_unreachable_address_is_one_line_and_fast() -> None:
    address = f"127.0.0.1:{cluster.free_port()}"
    started = time.perf_counter()
    with pytest.raises(VslamError) as raised:
        run(address, [1])
    assert time.perf_counter() - started < 10
    message = str(raised.value)
    assert message.startswith(f"cannot reach the Ray cluster at {address} (") and "\n" not in message


def test_a_malformed_address_is_refused() -> None:
    with pytest.raises(VslamError, match="HOST:PORT"):
        run("no-port", [1])


def test_importing_the_module_does_not_import_ray() -> None:
    code = "import sys, vslam.batch.on_ray; assert 'ray' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=cluster.ROOT,
                   env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(cluster.ROOT / "app"), str(cluster.ROOT)])))


class FakeTaskError(Exception):
    """Like ray.exceptions.RayTaskError: the task's own exception in ``cause``."""

    def __init__(self, cause: BaseException) -> None:
        super().__init__("ray::square() (pid=1)\n" + str(cause))
        self.cause = cause


def test_error_line_is_one_short_line() -> None:
    assert error_line(FakeTaskError(KeyError("x"))) == "KeyError: 'x'"
    assert error_line(FakeTaskError(MemoryError())) == "MemoryError"
    assert len(error_line(FakeTaskError(ValueError("y" * 1000)))) <= len("ValueError: ") + MAX_MESSAGE
    missing = RuntimeError("The remote function failed to import on the worker. This may be … sys.path [...]:")
    assert "cannot import vslam" in error_line(FakeTaskError(missing))
