"""Running the `vslam` CLI of this checkout from the tests.

- `vslam(...)`: ``python -m vslam.cli …`` in its own process (its own session: a time-out kills it and
  everything it started, the viewer or batch workers included). For whatever runs the engine, writes files,
  starts processes or handles signals.
- `vslam_here(...)`: the same entry point (`vslam.cli.main`: Typer, the one-line errors, the exit codes) in
  this process, for input refused before any work starts; it saves the ~0.8 s a new process spends
  importing, over ~100 such calls in the suite.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from vslam.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]


def vslam(*args: str | Path, cwd: Path | None = None, env: dict[str, str] | None = None, timeout: float = 600,
          **popen: Any) -> subprocess.CompletedProcess[str]:
    """Run ``vslam ARGS`` (this checkout's, not an installed one) with `env` added to the environment
    (RAY_ADDRESS of the caller's environment left out); capture stdout and stderr as text."""
    environment = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), environment.get("PYTHONPATH")]))
    command = [sys.executable, "-m", "vslam.cli", *map(str, args)]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd or ROOT,
                          env={**environment, **(env or {})}, start_new_session=True, **popen) as process:
        try:
            stdout, stderr = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            raise
    return subprocess.CompletedProcess(command, process.returncode, stdout, stderr)


def vslam_here(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``vslam ARGS`` in this process through the CLI's own entry point; only for input the CLI refuses
    before it starts any work (no engine, no recording, no threads, no signal handlers)."""
    argv = ["vslam", *map(str, args)]
    stdout, stderr = io.StringIO(), io.StringIO()
    code: int = 0
    saved_argv = sys.argv
    sys.argv = argv
    try:
        with contextlib.chdir(cwd or ROOT), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            cli_main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = saved_argv
    return subprocess.CompletedProcess(argv, code, stdout.getvalue(), stderr.getvalue())
