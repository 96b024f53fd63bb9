"""The type check (mypy, configured in pyproject.toml) started once by the test session's controlling process, at
the lowest priority (nice 19), when the session will run tests/test_types.py: it then runs on the CPU the test
workers leave idle (their waits for subprocesses, viewers, disks: ~0.2 of the 2 cores over a run) instead of taking
one worker's core for ~20 s with a cold cache, as on a fresh CI machine. test_types.py waits for its result; run
alone (no session-started check) it runs mypy itself."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The folder holding the started check's `output` and, once it has finished, its `exit_code`.
ENVIRONMENT = "VSLAM_TEST_TYPE_CHECK"


@dataclass(frozen=True)
class TypeCheck:
    exit_code: int
    output: str


def _lowest_priority() -> None:
    os.nice(19)


def start(config: pytest.Config) -> subprocess.Popen[bytes] | None:
    """In the controlling process: start mypy in the background when test_types.py is among the session's tests
    (no keyword or mark filter, and the paths given hold it); its folder in `ENVIRONMENT` for the workers."""
    if hasattr(config, "workerinput") or config.option.keyword or config.option.markexpr:
        return None
    wanted = ROOT / "tests" / "test_types.py"
    paths = [Path(arg.split("::")[0]).resolve() for arg in config.args] or [ROOT / "tests"]
    if not any(path == wanted or path in wanted.parents for path in paths):
        return None
    folder = Path(tempfile.mkdtemp(prefix="vslam-type-check-"))
    script = f'"{sys.executable}" -m mypy > "{folder}/output" 2>&1; echo $? > "{folder}/exit_code.tmp" && ' \
             f'mv "{folder}/exit_code.tmp" "{folder}/exit_code"'
    # nice 19 among the session's processes; its own process group (to be killed whole), not its own session: with
    # the kernel's autogroups (Linux's default) a new session is a scheduling group of its own, which would get as
    # much CPU as all the test workers together whatever its nice value
    process = subprocess.Popen(["sh", "-c", script], cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, preexec_fn=_lowest_priority, process_group=0)
    os.environ[ENVIRONMENT] = str(folder)
    return process


def stop(process: subprocess.Popen[bytes] | None) -> None:
    """In the controlling process, at the session's end: a check still running (its test deselected or failed
    early) is killed, and its folder removed."""
    if process is None:  # a worker's, or a session that started none: nothing of its own to stop
        return
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
    folder = os.environ.pop(ENVIRONMENT, None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


def result(timeout_s: float = 600) -> TypeCheck:
    """The session's type check once it has finished, or mypy run here when the session started none."""
    folder = os.environ.get(ENVIRONMENT)
    if not folder:
        done = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout_s)
        return TypeCheck(done.returncode, done.stdout + done.stderr)
    exit_code, deadline = Path(folder) / "exit_code", time.monotonic() + timeout_s
    while not exit_code.exists():
        if time.monotonic() > deadline:
            pytest.fail(f"the session's type check did not finish within {timeout_s:.0f} s")
        time.sleep(0.2)
    return TypeCheck(int(exit_code.read_text()), (Path(folder) / "output").read_text())
