"""One run of the engine as the CLI does it: progress (a bar, or plain lines without a terminal), optional
recording, safe interruption."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

import numpy as np
from rich.console import Console

from vslam.common import OutputError
from vslam.recording import DEFAULT_DETAIL, Detail, ImageCodec
from vslam.runs.progress import progress
from vslam.runs.trajectory_out import TrajectoryWriter
from vslam_core.config import EngineConfig
from vslam_core.errors import VslamError
from vslam_core.pipeline import Engine, FrameSink, RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameSource, ground_truth_matching
from vslam_core.trajectory.gt_check import GroundTruthCheck

if TYPE_CHECKING:
    from vslam.recording import Recorder
    from vslam_core.mapping.storage import StoredMap


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
    gt_check: GroundTruthCheck | None = None  # the ground truth against the images (a source with ground truth)

    def warnings(self) -> list[str]:
        """One line each, for the user: the ground truth disagrees with the images (`GroundTruthCheck`), or the
        height scale rests on few road planes (`RunResult.road_warning`)."""
        check = self.gt_check.summary() if self.gt_check is not None else None
        road = self.result.road_warning
        return [*(check.warnings() if check is not None else []), *([road] if road is not None else [])]


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


def log_prior_map(recorder: Recorder, prior: StoredMap) -> None:
    """`vslam run --map`: the map localised in, static: its landmarks (grey) and keyframe path (white)."""
    import rerun as rr

    recorder.log_static("/world/prior_map/landmarks", rr.Points3D(prior.landmark_positions.astype(np.float32),
                                                                  radii=0.05, colors=(170, 170, 170)))
    recorder.log_static("/world/prior_map/keyframes", rr.LineStrips3D([prior.poses[:, :3, 3].astype(np.float32)],
                                                                      radii=0.1, colors=(255, 255, 255)))


def record_run(
    source: FrameSource,
    config: EngineConfig,
    rrd: Path | None,
    properties: dict[str, str],
    console: Console,
    detail: Detail = DEFAULT_DETAIL,
    jpeg_quality: int | None = None,
    trajectory: TrajectoryWriter | None = None,
    image_codec: ImageCodec = ImageCodec.JPEG,
    prior_map: StoredMap | None = None,
    finish: Callable[[Engine], None] | None = None,
    live_url: str | None = None,
) -> RecordedRun:
    """Run the engine over `source`, recording to `rrd` (None: no recording) and writing each frame's pose
    to `trajectory` as it goes. Ctrl-C, SIGTERM, bad input (a `VslamError` from the source) and a write
    error (full disk: `OutputError`) stop the run cleanly: the outputs keep what was written, the recording
    is finalised where the disk allows, and the frames processed so far are returned with what stopped
    them. `live_url`: also stream the recording to that viewer (`vslam.viewer.live`)."""
    result = RunResult([], [], [])
    interrupted: Interrupted | None = None
    failure: VslamError | None = None
    recorder: Recorder | None = None
    # the ground truth against the images; not in a prior map's frame (the run's own tracks are still its)
    gt = source.ground_truth
    by_time = (ground_truth_matching(source) or "").startswith("matched by time")
    gt_check = GroundTruthCheck(gt, source.intrinsics, by_time) if gt is not None else None
    if rrd is not None:  # `--detail off` never loads the recorder (nor rerun: ~0.7 s of CPU)
        from vslam.recording import Recorder

        recorder = Recorder(rrd, source, config, properties, detail, jpeg_quality, image_codec, live_url=live_url,
                            gt_check=gt_check)
    if recorder is not None and prior_map is not None:
        log_prior_map(recorder, prior_map)
    with progress(console, source.name, len(source)) as step, _signals_stop_between_frames() as stop:

        def advance(_frame: Frame, _result: FrameResult) -> None:
            step()
            stop.check()

        # the trajectory first: a frame the recorder fails on still has its pose on disk
        sinks: list[FrameSink] = [trajectory] if trajectory is not None else []
        sinks += [gt_check] if gt_check is not None else []  # before the recorder, which logs its figures
        sinks += [recorder.log_frame] if recorder is not None else []
        try:
            run_odometry(source, config, (*sinks, advance), result, prior_map, finish)
        except Interrupted as exc:
            interrupted = exc
        except VslamError as exc:
            failure = exc
        finally:
            stopped = _stopped(result, interrupted or stop.interruption(), failure)
            closing = _close_outputs(recorder, trajectory, result, stopped)
        failure = _with_progress(failure or closing, result)  # the first error is the one to report
        interrupted = interrupted or stop.interruption()  # a signal during the last frame or finalising
    return RecordedRun(result, interrupted, failure, gt_check)


def _with_progress(failure: VslamError | None, result: RunResult) -> VslamError | None:
    """A write error, with how far the run got (its outputs keep that much)."""
    if not isinstance(failure, OutputError):
        return failure
    done = f"at frame {result.indices[-1]}" if result.indices else "before the first frame"
    return OutputError(f"{failure}; the run stopped {done}, the outputs keep what was written")


def _close_outputs(recorder: Recorder | None, trajectory: TrajectoryWriter | None, result: RunResult,
                   stopped: str | None) -> VslamError | None:
    """Finish both outputs whatever happens to the other; the first write error, if any."""
    first: VslamError | None = None
    if recorder is not None:
        try:
            recorder.finish(result, stopped)
        except VslamError as exc:
            first = exc
    if trajectory is not None:
        try:
            trajectory.finish(result)
        except VslamError as exc:
            first = first or exc
    return first


def _stopped(result: RunResult, interrupted: Interrupted | None, failure: VslamError | None) -> str | None:
    """Why a run ended before its last frame, for the recording (None: it did not)."""
    if interrupted is not None:
        return f"interrupted by {interrupted} after {result.frames} frames"
    if failure is not None:
        return f"stopped by an error after {result.frames} frames: {failure}"
    return None
