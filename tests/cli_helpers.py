"""Running the `vslam` CLI of this checkout from the tests.

- `vslam(...)`: the CLI's entry point (`vslam.cli.main`: Typer, the one-line errors, the exit codes) in this
  process, with stdout and stderr captured, the environment and working folder set for the call and put back
  after it. A new process spends ~1 s importing rerun, polars and OpenCV; over ~200 calls that was a third
  of the suite's time.
- `vslam(..., process=True)`: ``python -m vslam.cli …`` in its own process (its own session: a time-out kills
  it and everything it started, the viewer or batch workers included). For what only a process shows:
  signals, exit handlers, output written by native code to the file descriptors, a killed or stuck writer.
- `vslam_here(...)`: the in-process call, kept as a name for input refused before any work starts.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from vslam.cli import main as cli_main
from vslam.viewer import processes as viewer_processes

ROOT = Path(__file__).resolve().parents[1]

#: `vslam run *VO …`: the odometry backend, for tests whose subject is not the engine (a tool, an input format,
#: an output file): the default `map` backend costs them ~1.5x the time; the engine's own tests name theirs
VO = ("--backend", "vo")


def vslam(*args: str | Path, cwd: Path | None = None, env: dict[str, str] | None = None, process: bool = False,
          timeout: float = 600, **popen: Any) -> subprocess.CompletedProcess[str]:
    """Run ``vslam ARGS`` (this checkout's, not an installed one) with `env` added to the environment
    (RAY_ADDRESS of the caller's environment left out); capture stdout and stderr as text. In this process
    unless `process` (or any `popen` argument) asks for a process of its own."""
    if not process and not popen:
        return _in_process(args, cwd, {"RAY_ADDRESS": None, **(env or {})})
    environment = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "app"), str(ROOT),
                                                              environment.get("PYTHONPATH")]))
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


@dataclass(frozen=True)
class InterruptedRun:
    """`vslam run KITTI --sequence 00 -o RECORDING --trajectory-out TRAJECTORY` in its own process, sent a signal
    once the trajectory holds `INTERRUPT_AFTER` poses (frames written): `interrupt_kitti_run`."""

    recording: Path
    trajectory: Path
    returncode: int
    stderr: str


#: Poses on disk before the signal: the run is in its frame loop, its outputs hold frames. (It waited for a 2 MB
#: recording before: ~100 frames, ~4 s more of the run per interrupted run.)
INTERRUPT_AFTER = 20


def interrupt_kitti_run(kitti_root: Path, folder: Path, signum: int) -> InterruptedRun:
    """Start the run of KITTI 00 writing into `folder`, send `signum` once it has written some frames, wait."""
    rrd, trajectory = folder / "i.rrd", folder / "i.txt"
    process = subprocess.Popen(
        [sys.executable, "-m", "vslam.cli", "run", str(kitti_root), "--sequence", "00", "-o", str(rrd),
         "--trajectory-out", str(trajectory)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 60
    while (not trajectory.exists() or trajectory.read_bytes().count(b"\n") < INTERRUPT_AFTER) and (
            time.monotonic() < deadline and process.poll() is None):
        time.sleep(0.05)
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=60)
    return InterruptedRun(rrd, trajectory, process.returncode, stderr)


def vslam_here(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run ``vslam ARGS`` in this process through the CLI's own entry point."""
    return _in_process(args, cwd, {})


def _in_process(args: tuple[str | Path, ...], cwd: Path | None,
                env: dict[str, str | None]) -> subprocess.CompletedProcess[str]:
    argv = ["vslam", *map(str, args)]
    stdout, stderr = io.StringIO(), io.StringIO()
    code: int = 0
    saved_argv, saved_env = sys.argv, {name: os.environ.get(name) for name in env}
    sys.argv = argv
    _set_environment(env)
    try:
        with contextlib.chdir(cwd or ROOT), contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            cli_main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.argv = saved_argv
        _set_environment(saved_env)
    return subprocess.CompletedProcess(argv, code, stdout.getvalue(), stderr.getvalue())


def _set_environment(values: dict[str, str | None]) -> None:
    for name, value in values.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


def need_vulkan() -> None:
    """Skip a test that starts the viewer when no Vulkan adapter is here, except when CI is set: there the
    viewer's tests must run, so it fails instead (.ci/run installs mesa-vulkan-drivers)."""
    if not viewer_processes.vulkan_available():
        if "CI" in os.environ:
            pytest.fail(f"{viewer_processes.NO_VULKAN} (CI is set: the viewer tests must not be skipped)")
        pytest.skip(viewer_processes.NO_VULKAN)


def assert_same_recording(a: Path, b: Path, tmp: Path, named: tuple[str, ...] = ()) -> None:
    """Two recordings of the same input hold the same rows but for the measured stage timings and the `named`
    entities (those that name the input, when it was read from two folders). (Where rows are
    cut into chunks is not deterministic: they are written every 1.5 s of wall-clock time, issue 56;
    `rerun rrd optimize` merges them the same way, but for the event log, whose rows from during and after the
    run it interleaves by chunk: compared as rows.)"""
    from vslam.recording import STAGES
    from vslam.recording.metrics import MAP_STAGES
    from vslam.rrd.read import read_events

    events = [sorted(read_events(path)) for path in (a, b)]
    assert len(events[0]) > 10 and events[0] == events[1]
    measured = [f"/metrics/timing_ms/{stage}" for stage in (*STAGES, *MAP_STAGES)] + ["/metrics/ba/milliseconds"]
    drop = [arg for entity in (*measured, "/events", "/events/at_end", *named) for arg in ("--drop-entity", entity)]
    merged = []
    for name, path in (("a", a), ("b", b)):
        filtered, optimised = tmp / f"{name}-no-timing.rrd", tmp / f"{name}-merged.rrd"
        subprocess.run(["rerun", "rrd", "filter", *drop, "-o", str(filtered), str(path)], check=True,
                       capture_output=True, timeout=120)
        subprocess.run(["rerun", "rrd", "optimize", "-o", str(optimised), str(filtered)], check=True,
                       capture_output=True, timeout=120)
        merged.append(optimised)
    compare = subprocess.run(["rerun", "rrd", "compare", "--unordered", *map(str, merged)], capture_output=True,
                             text=True, timeout=120)
    assert compare.returncode == 0, compare.stderr[-2000:]
