"""One run of the engine as the CLI does it: progress bar, optional recording, safe interruption."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from app.recording import Detail, Recorder
from vslam_core.config import EngineConfig
from vslam_core.errors import VslamError
from vslam_core.pipeline import FrameSink, RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameSource


class Interrupted(Exception):
    """The run was stopped by a signal; `code` is the conventional exit code (128 + signal number)."""

    def __init__(self, code: int, name: str) -> None:
        super().__init__(name)
        self.code = code


@dataclass
class RecordedRun:
    result: RunResult  # the frames processed (all of them unless stopped early)
    interrupted: Interrupted | None  # stopped by a signal
    failure: VslamError | None = None  # stopped by bad input (e.g. an unreadable image with on_bad_frame=fail)


def _raise_interrupted(signum: int, _frame: FrameType | None) -> None:
    raise Interrupted(128 + signum, signal.Signals(signum).name)


@contextmanager
def _sigterm_raises() -> Iterator[None]:
    """SIGTERM becomes an exception, so `finally` blocks finalise files as they do on Ctrl-C."""
    previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def record_run(
    source: FrameSource,
    config: EngineConfig,
    rrd: Path | None,
    properties: dict[str, str],
    console: Console,
    detail: Detail = Detail.FULL,
    jpeg_quality: int = 75,
) -> RecordedRun:
    """Run the engine over `source`, recording to `rrd` (None: no recording). Ctrl-C, SIGTERM and bad input
    (a `VslamError` from the source) stop the run cleanly: the recording is finalised and the frames
    processed so far are returned with what stopped them."""
    result = RunResult([], [], [])
    interrupted: Interrupted | None = None
    failure: VslamError | None = None
    recorder = Recorder(rrd, source, config, properties, detail, jpeg_quality) if rrd is not None else None
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with Progress(*columns, console=console, transient=True) as progress, _sigterm_raises():
        task = progress.add_task(source.name, total=len(source))

        def advance(_frame: Frame, _result: FrameResult) -> None:
            progress.advance(task)

        sinks: tuple[FrameSink, ...] = (advance,) if recorder is None else (recorder.log_frame, advance)
        try:
            run_odometry(source, config, sinks, result)
        except KeyboardInterrupt:
            interrupted = Interrupted(130, "SIGINT")
        except Interrupted as exc:
            interrupted = exc
        except VslamError as exc:
            failure = exc
        finally:
            if recorder is not None:
                recorder.finish(result, interrupted is not None or failure is not None)
    return RecordedRun(result, interrupted, failure)
