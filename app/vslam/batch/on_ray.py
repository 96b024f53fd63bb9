"""Run a batch of jobs as tasks on an existing Ray cluster (`vslam eval --manifest … --ray-address HOST:PORT`).

Ray is an optional extra (`pip install 'vslam[cluster]'`) and is imported only inside `run_on_ray`, so importing
this module costs nothing without it.

The cluster's workers unpickle ``function`` by reference (its module and name), so every worker node needs
vslam installed, in the same version, in the Python environment its raylet starts workers with (the same
virtualenv on every node, or one container image). A ``runtime_env={"working_dir": …}`` upload is deliberately
not used: it would ship the Python sources but not the compiled dependencies (OpenCV, GTSAM, Rerun, PyAV), and
its per-job upload and unpacking would hide a version mismatch instead of failing plainly.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any, TypeVar

from vslam_core.errors import VslamError

J = TypeVar("J")
R = TypeVar("R")

#: Seconds to wait for a TCP connection to the head before giving up (a firewall drops packets silently).
CONNECT_TIMEOUT_S = 5.0

#: Task retries after a worker dies (node lost, OOM kill): one survives a lost spot node without repeating a
#: deterministic out-of-memory three times (Ray's default).
MAX_RETRIES = 1

#: Characters kept of a task's error message (a report row, not a log file).
MAX_MESSAGE = 300


def split_address(address: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 as ``[::1]:6379``) to its host and port; a `VslamError` when malformed."""
    host, sep, port = address.strip().rpartition(":")
    if not sep or not host or not port.isdigit():
        raise VslamError(f"--ray-address must be HOST:PORT (the head's GCS port, 6379 by default), not {address!r}")
    return host.strip("[]"), int(port)


def check_reachable(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Fail fast with one line when nothing accepts connections at ``address``.

    Ray's own connect loop retries for many minutes (20 attempts of ~40 s each in 2.60) and prints C++ warnings
    meanwhile; a plain TCP connect answers in milliseconds (refused, unknown host) or ``timeout_s`` (dropped).
    """
    host, port = split_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        if isinstance(error, TimeoutError):
            reason = f"no answer within {timeout_s:g} s"
        raise VslamError(f"cannot reach the Ray cluster at {address} ({reason})") from None


@contextmanager
def _env(**values: str) -> Iterator[None]:
    """Set environment variables (unless the user set them) for the duration of the block."""
    added = {key: value for key, value in values.items() if key not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for key in added:
            os.environ.pop(key, None)


def connect(address: str) -> None:
    """``ray.init`` to the existing cluster at ``address``, quietly; never starts a local one."""
    check_reachable(address)  # before importing ray (~1 s): an unreachable head answers at once
    import ray

    # A port that accepts connections but is no Ray head: one connect attempt (~2-40 s) instead of twenty. Ray's
    # C++ client still prints one warning line then (RAY_BACKEND_LOG_LEVEL does not reach it in 2.60).
    with _env(RAY_gcs_server_port_wait_time_s="1"):
        try:
            ray.init(
                address=address,  # an explicit HOST:PORT: Ray connects, it never starts a local instance
                log_to_driver=False,  # the tasks' stdout/stderr stay in the cluster's log files
                logging_level=logging.WARNING,
                configure_logging=True,
            )
        except (ConnectionError, RuntimeError, ValueError) as error:
            message = str(error).splitlines()[0] if str(error) else type(error).__name__
            raise VslamError(f"cannot reach the Ray cluster at {address} ({message})") from None


def error_line(error: BaseException) -> str:
    """One line for a task that raised or whose worker died: the task's own exception when there is one."""
    cause = getattr(error, "cause", None)  # RayTaskError wraps the task's exception
    shown = cause if isinstance(cause, BaseException) else error
    text = str(shown).strip()
    if "failed to import on the worker" in text:  # Ray's message goes on to list the worker's whole sys.path
        return "a Ray worker cannot import vslam: install the same vslam version in the workers' environment"
    first = text.splitlines()[0] if text else ""
    if len(first) > MAX_MESSAGE:
        first = first[: MAX_MESSAGE - 1] + "…"
    return f"{type(shown).__name__}: {first}" if first else type(shown).__name__


def run_on_ray(
    function: Callable[[J], R],
    jobs: Sequence[J],
    address: str,
    num_cpus: float,
    on_result: Callable[[int, R], None],
    failed: Callable[[R], bool],
    fail_fast: bool,
    on_error: Callable[[J, str], R],
) -> None:
    """Run ``function(job)`` for every job as a Ray task on the cluster at ``address``.

    Each task reserves ``num_cpus`` CPUs (the engine's ``threads``). ``on_result(index, result)`` is called in
    the driver as each task finishes (completion order); a task that raises or whose worker dies (crash, OOM
    kill) is reported as ``on_error(job, one_line_message)``, never raised. With ``fail_fast``, the first result
    for which ``failed`` holds cancels every outstanding task (queued ones never start, running ones get Ray's
    KeyboardInterrupt) and their results are not reported. Ctrl-C
    cancels the outstanding tasks and re-raises; the driver always disconnects (``ray.shutdown``).
    """
    if not jobs:
        return
    # ray.init installs its own SIGTERM handler and leaves SIGINT ignored: the caller's come back after (a
    # process started later would inherit the ignored SIGINT and could not be stopped by Ctrl-C)
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        _run_connected(function, jobs, address, num_cpus, on_result, failed, fail_fast, on_error)
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


def _run_connected(
    function: Callable[[J], R], jobs: Sequence[J], address: str, num_cpus: float,
    on_result: Callable[[int, R], None], failed: Callable[[R], bool], fail_fast: bool,
    on_error: Callable[[J, str], R],
) -> None:
    connect(address)
    import ray

    pending: dict[Any, int] = {}
    try:
        task = ray.remote(num_cpus=num_cpus, max_retries=MAX_RETRIES)(function)
        pending = {task.remote(job): index for index, job in enumerate(jobs)}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                index = pending.pop(ref)
                result = _fetch(ray, ref, jobs[index], on_error)
                on_result(index, result)
                if fail_fast and failed(result):
                    _cancel(ray, pending, force=False)
                    pending = {}
                    return
    except BaseException:  # Ctrl-C (or on_result failing): kill running tasks too, the cluster is shared
        _cancel(ray, pending, force=True)
        raise
    finally:
        ray.shutdown()


def _fetch(ray: Any, ref: Any, job: J, on_error: Callable[[J, str], R]) -> R:
    """The finished task's result, or the failed result ``on_error`` builds when it raised or its worker died."""
    try:
        result: R = ray.get(ref)
        return result
    except ray.exceptions.RayError as error:
        return on_error(job, error_line(error))


def _cancel(ray: Any, pending: dict[Any, int], force: bool) -> None:
    """Cancel outstanding tasks: queued ones never start; ``force`` also kills the running ones' workers."""
    for ref in pending:
        with suppress(Exception):  # a task that finished meanwhile cannot be cancelled: nothing to do
            ray.cancel(ref, force=force)
