"""Many logs of a manifest: one job per log, run by interchangeable executors (serial, local processes, Ray).

`run_log` is the unit of work: top level and picklable, it runs one log into the report folder (recording,
trajectory, plot) and returns its `LogResult`, never raising for a bad log. An executor takes the jobs, calls
``on_result(index, result)`` as each finishes (in completion order) and, with ``fail_fast``, stops submitting
and cancels what is pending after the first failed result. The engine is deterministic, so a log's metrics do
not depend on the executor.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console

from vslam.batch.manifest import LogSpec
from vslam.batch.pool import CRASH, Terminated, run_on_pool
from vslam.evaluation import evaluate_sources
from vslam.recording import DEFAULT_DETAIL, Detail, ImageCodec
from vslam.runs import input_warnings, with_camera_height
from vslam_core.config import EngineConfig
from vslam_core.config_file import load_config
from vslam_core.errors import VslamError
from vslam_core.sources.base import FrameRange
from vslam_core.sources.open import open_source

#: memory budget of one worker: a 200-frame KITTI log at --detail full peaks at ~0.3 GB resident (measured),
#: long sequences grow with their trajectory and map; 1 GiB leaves headroom
LOG_MEMORY_BYTES = 1 << 30


@dataclass(frozen=True)
class LogJob:
    """Everything a worker needs to run one log (picklable: plain data only)."""

    spec: LogSpec
    config: EngineConfig  # the batch's config (--config, --scale, --backend); the log's own columns win
    report_dir: Path
    detail: Detail = DEFAULT_DETAIL
    image_codec: ImageCodec = ImageCodec.JPEG


@dataclass
class LogResult:
    """How one log ended: ``ok`` with its metrics row, ``failed`` with a one-line error, or ``interrupted``."""

    index: int  # the log's position in the manifest
    name: str
    status: str
    error: str = ""
    row: dict[str, Any] | None = None
    by_length: dict[float, tuple[float, float, int]] = field(default_factory=dict)
    elapsed_s: float = 0.0
    warnings: list[str] = field(default_factory=list)
    spec_hash: str = ""  # of the manifest row it ran: --resume reruns a log whose row changed

    def as_json(self) -> dict[str, Any]:
        return {"index": self.index, "name": self.name, "status": self.status, "error": self.error,
                "row": self.row, "by_length": [[k, *v] for k, v in self.by_length.items()],
                "elapsed_s": self.elapsed_s, "warnings": self.warnings, "spec_hash": self.spec_hash}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LogResult:
        lengths = {float(k): (float(t), float(r), int(n)) for k, t, r, n in data.get("by_length", [])}
        return cls(int(data["index"]), str(data["name"]), str(data["status"]), str(data.get("error", "")),
                   data.get("row"), lengths, float(data.get("elapsed_s", 0.0)), list(data.get("warnings", [])),
                   str(data.get("spec_hash", "")))


OnResult = Callable[[int, LogResult], None]
#: an executor: (jobs, on_result, fail_fast) -> None
Executor = Callable[[list[LogJob], OnResult, bool], None]


def spec_hash(spec: LogSpec) -> str:
    """A short hash of a manifest row (its position aside): what the log's result was computed from."""
    values = {k: str(v) for k, v in dataclasses.asdict(spec).items()
              if k != "index" and not (k == "calib_scale" and v is None)}  # rows without it hash as before it was
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]


def log_config(job: LogJob) -> EngineConfig:
    """The engine config of one log: its own config file (else the batch's), then its scale and backend."""
    spec = job.spec
    config = load_config(spec.config) if spec.config is not None else job.config
    if spec.config is not None:  # the batch's --scale/--backend still apply unless the row says otherwise
        config = config.with_scale(job.config.scale).with_backend(job.config.backend)
    if spec.scale is not None:
        config = config.with_scale(spec.scale)  # type: ignore[arg-type]
    if spec.backend is not None:
        config = config.with_backend(spec.backend)  # type: ignore[arg-type]
    return config


def run_log(job: LogJob) -> LogResult:
    """Run one log into the report folder and score it. Never raises for a bad log (unreadable, bad
    calibration, a crash of the engine): that is a ``failed`` result with a one-line error."""
    spec, start = job.spec, time.monotonic()

    def result(status: str, error: str = "", **values: Any) -> LogResult:
        one_line = " ".join(error.split())
        return LogResult(spec.index, spec.name, status, one_line, elapsed_s=time.monotonic() - start,
                         spec_hash=spec_hash(spec), **values)

    try:
        config = log_config(job)
        source = open_source(spec.source, sequence=spec.sequence, frames=FrameRange.parse(spec.frames),
                             intrinsics=spec.intrinsics, calib=spec.calib, ground_truth=spec.gt, topic=spec.topic,
                             gt_topic=spec.gt_topic, calib_scale=spec.calib_scale)
        config = with_camera_height(config, spec.camera_height, source, "camera_height", "scale height")
        warnings = input_warnings(source, config)
        quiet = Console(file=io.StringIO())  # per-frame progress would interleave: the batch prints per log
        evaluation = evaluate_sources([source], config, job.report_dir, quiet, job.detail,
                                      {"source_path": spec.source, "batch_log": spec.name}, job.image_codec,
                                      names=[spec.name],
                                      write_tables=False)
    except VslamError as exc:
        return result("failed", str(exc))
    except Exception as exc:  # a crash inside the engine or a reader: this log fails, the batch goes on
        return result("failed", f"crash: {type(exc).__name__}: {exc}")
    if evaluation.interrupted is not None:
        return result("interrupted", f"interrupted by {evaluation.interrupted}")
    if not evaluation.rows:
        return result("failed", "fewer than 3 frames: nothing to score")
    return result("ok", row=evaluation.rows[0], by_length=evaluation.by_length.get(spec.name, {}),
                  warnings=warnings)


def stops(result: LogResult, fail_fast: bool) -> bool:
    """Whether a batch stops after this result: an interrupted log, or any failure with fail-fast."""
    return result.status == "interrupted" or (fail_fast and result.status == "failed")


def run_serial(jobs: list[LogJob], on_result: OnResult, fail_fast: bool) -> None:
    """One log after another in this process."""
    for index, job in enumerate(jobs):
        result = run_log(job)
        on_result(index, result)
        if stops(result, fail_fast):
            return


def local_executor(workers: int) -> Executor:
    """`workers` local processes (`vslam.batch.pool`)."""

    def execute(jobs: list[LogJob], on_result: OnResult, fail_fast: bool) -> None:
        run_on_pool(run_log, jobs, workers, on_result, lambda result: stops(result, fail_fast),
                    lambda job: failed_log(job, CRASH))

    return execute


def terminate_as_interrupt(_signum: int, _frame: object) -> None:
    """SIGTERM (a cancelled CI job) stops a batch as Ctrl-C does (a run in this process notes it itself)."""
    raise Terminated


def failed_log(job: LogJob, error: str) -> LogResult:
    """The result of a log whose worker gave no result (it died, or the task could not run)."""
    return LogResult(job.spec.index, job.spec.name, "failed", " ".join(error.split()), spec_hash=spec_hash(job.spec))


def default_workers() -> int:
    """The machine's cores, capped by the memory available for `LOG_MEMORY_BYTES` per log; at least 1."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    available = _available_memory()
    by_memory = cores if available is None else available // LOG_MEMORY_BYTES
    return max(1, min(cores, by_memory))


def _available_memory() -> int | None:
    """MemAvailable of /proc/meminfo in bytes (None where there is none)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def eta_seconds(elapsed: float, done: int, total: int) -> float:
    """Time left at the batch's pace so far (NaN before the first log)."""
    return elapsed / done * (total - done) if done else math.nan
