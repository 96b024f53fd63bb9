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


class _StopRequest:
    """The first SIGINT or SIGTERM of a run, noted by the handler and acted on between frames: an exception
    raised inside library code (Rerun converts data under a catch-all) could be swallowed or leave a
    half-written batch, so the handler only records the signal."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def note(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum

    def interruption(self) -> Interrupted | None:
        """The noted signal as the exception that stops a run, if one arrived."""
        if self.signum is None:
            return None
        return Interrupted(128 + self.signum, signal.Signals(self.signum).name)

    def check(self) -> None:
        if (interruption := self.interruption()) is not None:
            raise interruption


@contextmanager
def _signals_stop_between_frames() -> Iterator[_StopRequest]:
    stop = _StopRequest()
    previous = {signum: signal.signal(signum, stop.note) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


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
    with Progress(*columns, console=console, transient=True) as progress, _signals_stop_between_frames() as stop:
        task = progress.add_task(source.name, total=len(source))

        def advance(_frame: Frame, _result: FrameResult) -> None:
            progress.advance(task)
            stop.check()

        sinks: tuple[FrameSink, ...] = (advance,) if recorder is None else (recorder.log_frame, advance)
        try:
            run_odometry(source, config, sinks, result)
        except Interrupted as exc:
            interrupted = exc
        except VslamError as exc:
            failure = exc
        finally:
            if recorder is not None:
                recorder.finish(result, _stopped(result, interrupted or stop.interruption(), failure))
        interrupted = interrupted or stop.interruption()  # a signal during the last frame or finalising
    return RecordedRun(result, interrupted, failure)


def _stopped(result: RunResult, interrupted: Interrupted | None, failure: VslamError | None) -> str | None:
    """Why a run ended before its last frame, for the recording (None: it did not)."""
    if interrupted is not None:
        return f"interrupted by {interrupted} after {result.frames} frames"
    if failure is not None:
        return f"stopped by an error after {result.frames} frames: {failure}"
    return None
