"""A real one-node Ray cluster for the tests (`ray start --head`), stopped afterwards even when a test fails.

`ray stop` stops every Ray process of the machine (other test sessions' clusters too), so the head runs with
``--block`` in its own process group and a private temp dir: teardown signals that group, then kills any
process still naming the temp dir (Ray's daemons and workers carry it on their command line).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent

#: Seconds the head may take to accept drivers (a loaded 2-core CI machine: ~5-10 s).
START_TIMEOUT_S = 90.0

#: `ray start --block` runs through this (PR_SET_PDEATHSIG, as the viewer processes): it gets SIGTERM, on which it stops
#: its daemons, when the process that started it dies, even by SIGKILL, so a test session killed by a signal leaves no
#: cluster behind (one was found still running 70 minutes after such a kill).
DIE_WITH_PARENT = ROOT / "app" / "vslam" / "viewer" / "die_with_parent.py"

#: Measured by the last `start_cluster` call (reported by the tests and the benchmark).
last_start_seconds: float = float("nan")


def free_port() -> int:
    """A TCP port nothing listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def ray_command() -> str:
    """The `ray` CLI, or a failure/skip when the `cluster` extra is missing (a failure when CI is set)."""
    found = shutil.which("ray")
    if found is None:
        message = "ray is not installed (pip install -e '.[cluster]')"
        if "CI" in os.environ:
            pytest.fail(f"{message}; CI is set: the Ray tests must not be skipped")
        pytest.skip(message)
    return found


def _ready(address: str, temp_dir: Path) -> bool:
    """The GCS port answers and the raylet has written its socket (drivers can connect)."""
    host, port = address.rsplit(":", 1)
    try:
        with socket.create_connection((host, int(port)), timeout=1):
            pass
    except OSError:
        return False
    return any(temp_dir.glob("session_*/sockets/raylet*"))


def start_cluster(num_cpus: int = 2) -> tuple[subprocess.Popen[bytes], str, Path]:
    """Start a head node with ``num_cpus`` CPUs on a free port; returns (process, "127.0.0.1:PORT", temp dir)."""
    global last_start_seconds
    ray = ray_command()
    port = free_port()
    temp_dir = Path(tempfile.mkdtemp(prefix="vr", dir="/tmp"))  # short: Unix socket paths max 107 bytes
    address = f"127.0.0.1:{port}"
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    # The workers unpickle the tests' task functions by module name: the repo and tests/ on their path.
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "app"), str(ROOT), str(TESTS),
                                                      os.environ.get("PYTHONPATH")]))
    started = time.perf_counter()
    process = subprocess.Popen(
        [sys.executable, "-I", "-S", str(DIE_WITH_PARENT), "--signal", "TERM", str(os.getpid()),
         ray, "start", "--head", "--block", "--node-ip-address", "127.0.0.1", "--port", str(port),
         "--num-cpus", str(num_cpus), "--disable-usage-stats", "--include-dashboard", "false",
         "--temp-dir", str(temp_dir),
         # Free ports for what binds fixed ones by default, so clusters of parallel test sessions coexist.
         "--dashboard-port", str(free_port()),
         "--dashboard-agent-listen-port", str(free_port())],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True,
    )
    while not _ready(address, temp_dir):
        if process.poll() is not None or time.perf_counter() - started > START_TIMEOUT_S:
            stop_cluster(process, temp_dir)
            raise RuntimeError(f"ray start --head did not come up at {address} (exit {process.poll()})")
        time.sleep(0.2)
    last_start_seconds = time.perf_counter() - started
    return process, address, temp_dir


def _pids_naming(text: str) -> list[int]:
    """Processes whose command line contains ``text`` (this cluster's own temp dir: nobody else's)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and int(entry.name) != os.getpid():
            try:
                if text in (entry / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(entry.name))
            except OSError:
                continue
    return pids


def stop_cluster(process: subprocess.Popen[bytes], temp_dir: Path) -> None:
    """Stop the head started by `start_cluster`, its daemons and workers, and delete its temp dir."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)  # `ray start --block` stops its daemons on SIGTERM
        try:
            process.wait(timeout=1)  # it often takes ~20 s: the sweep below finishes the job
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    for pid in _pids_naming(str(temp_dir)):
        with suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    shutil.rmtree(temp_dir, ignore_errors=True)


#: The cluster of this test process while a module that uses it runs, kept for the next module when that one
#: uses it too (test_batch.py, then test_batch_ray.py on the same worker: tests/conftest.py SAME_WORKER): a Ray
#: head costs ~6.5 s of CPU to start, in daemons the tests' own CPU figures never see.
_running: tuple[subprocess.Popen[bytes], str, Path] | None = None
#: The test that runs after the current one (None: the last of this process), set by `note_next_test`.
_next_test: pytest.Item | None = None


def note_next_test(nextitem: pytest.Item | None) -> None:
    """Called (tests/conftest.py) before a test's fixtures are torn down, with the test that runs next."""
    global _next_test
    _next_test = nextitem


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[str]:
    """Address ("127.0.0.1:PORT") of a 2-CPU Ray head started for this module, or kept running from the module
    before when it used one too; stopped after the module (even on failure) unless the next test uses it."""
    global _running
    if _running is None or _running[0].poll() is not None:
        _running = start_cluster(num_cpus=2)
    process, address, temp_dir = _running
    try:
        yield address
    finally:
        if _next_test is None or "ray_cluster" not in getattr(_next_test, "fixturenames", ()):
            _running = None
            stop_cluster(process, temp_dir)
