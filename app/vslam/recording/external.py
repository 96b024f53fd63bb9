"""Another system's trajectory as a recording (`vslam eval --trajectory … --report DIR`): `DIR/<name>.rrd`.

The same entities, frames and styles as a `vslam run` recording (`vslam.recording.recorder`), for what a
trajectory file has: the camera pose per row (``/world/camera``, T_world_cam, world = camera frame of the
first matched row, RDF), the estimate and ground-truth trajectories, the position and heading errors, the
drift attribution (`DriftRecording`: ``/metrics/drift/*``, ``/world/trajectory/{drift,gt_links}``, the worst
frames as events), the metrics table in ``/report`` and the run properties. With ``--images`` also the camera
frames at ``/world/camera/image`` (their image number and file on hover), with a pinhole when the camera is
known. The ``frame`` timeline is the row number in the trajectory file; ``time`` its timestamp (or the image's).

No tracks, health, timings or engine config: an external trajectory has none, and invents none (the drift
events say ``health not reported``, `vslam inspect` lists no reasons).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr

from vslam.common import OutputError, TrajectoryImages, has_footer, write_failure
from vslam.recording.columns import FLUSH_FRAMES, NO_IMAGE, ColumnBuffer
from vslam.recording.drift import DriftRecording, FrameTrail
from vslam.recording.layout import blueprint
from vslam.recording.levels import JPEG_QUALITY, Detail
from vslam.recording.metrics import METRICS
from vslam.recording.schema import SCHEMA_VERSION
from vslam.recording.stream import StreamStopped, close_stream, flush_or_stop, log_world, open_stream
from vslam.recording.video import encode_jpeg
from vslam_core.geometry import rotation_angle
from vslam_core.sources.base import Frame

#: The health an external trajectory's frames have in the drift events: none is known.
NO_HEALTH = "not reported (external trajectory)"
#: The series groups such a recording holds (the engine's tracks, inliers and timings it has not).
GROUPS = ("error", "angle_error", "drift")


@dataclass(frozen=True)
class ExternalRun:
    """One trajectory file matched to the ground truth. estimate, ground_truth: (N, 4, 4) T_world_cam, both
    re-based to the first matched row; rows: (N,) the row numbers in the file (the ``frame`` timeline);
    times: (N,) seconds of those rows (the ``time`` timeline), or None; report: Markdown for ``/report``."""

    name: str
    estimate: np.ndarray
    ground_truth: np.ndarray
    rows: np.ndarray
    times: np.ndarray | None
    report: str


@dataclass(frozen=True)
class RunFrames:
    """The camera frames of a run: `images` and, per matched row, the index of its image in `images.files`."""

    images: TrajectoryImages
    picks: np.ndarray  # (N,) int


def record_external(path: Path, run: ExternalRun, properties: dict[str, str], detail: Detail,
                    frames: RunFrames | None = None) -> None:
    """Write `run` to the recording `path` (complete, with footer); `properties` are the run properties
    (``name`` and ``recording_id`` included). With `frames` at detail full or standard, also the images.
    Raises `OutputError` when the file cannot be written."""
    if detail == Detail.OFF:
        raise ValueError("detail 'off' writes no recording")
    shown = frames if detail in (Detail.FULL, Detail.STANDARD) else None
    camera = shown.images.intrinsics if shown is not None else None
    layout = blueprint(image=shown is not None, engine=False, frustum=camera is not None)
    rec = open_stream(path, properties.get("recording_id"), layout, properties.get("name", run.name))
    stuck = False
    try:
        rec.send_property("run", rr.AnyValues(**{**properties, "detail": str(detail),
                                                  "schema_version": str(SCHEMA_VERSION)}))  # type: ignore[arg-type]
        log_world(rec, camera)
        _log_series_styles(rec)
        columns = ColumnBuffer(rec)
        drift = DriftRecording(run.ground_truth, online=True, trail=FrameTrail())
        for i in range(len(run.estimate)):
            frame = _frame(run, shown, i)
            _log_row(columns, drift, run, frame, i)
            if shown is not None:
                _log_image(columns, shown, frame, int(shown.picks[i]))
            if (i + 1) % FLUSH_FRAMES == 0:
                columns.flush()
        lines = drift.finish(rec, columns, None)
        columns.flush()
        rec.log("/report", rr.TextDocument("\n".join([run.report, "", *lines]), media_type=rr.MediaType.MARKDOWN),
                static=True)
        flush_or_stop(rec, path)
    except StreamStopped as exc:
        stuck = exc.stuck
        raise
    except RuntimeError:
        raise OutputError(write_failure(path)) from None
    finally:
        close_stream(rec, stuck)
    if not has_footer(path):
        raise OutputError(write_failure(path))


def _frame(run: ExternalRun, frames: RunFrames | None, i: int) -> Frame:
    """Row i's frame: its row number, and its time (the trajectory's, else its image's, else none)."""
    stamp: float | None = None
    if run.times is not None:
        stamp = float(run.times[i])
    elif frames is not None and frames.images.times is not None:
        stamp = float(frames.images.times[int(frames.picks[i])])
    return Frame(int(run.rows[i]), stamp, NO_IMAGE)


def _log_row(columns: ColumnBuffer, drift: DriftRecording, run: ExternalRun, frame: Frame, i: int) -> None:
    """Camera pose, one segment of each trajectory, the position and heading errors and the drift series."""
    pose, truth = run.estimate[i], run.ground_truth[i]
    columns.add("/world/camera", frame, (rr.Transform3D.columns, {"translation": pose[:3, 3],
                                                                  "mat3x3": pose[:3, :3]}))
    before = max(i - 1, 0)
    columns.add("/world/trajectory/estimate", frame,
                (rr.LineStrips3D.columns, {"strips": np.array([run.estimate[before, :3, 3], pose[:3, 3]])}))
    columns.add("/world/trajectory/ground_truth", frame,
                (rr.LineStrips3D.columns, {"strips": np.array([run.ground_truth[before, :3, 3], truth[:3, 3]])}))
    columns.add_scalar("/metrics/error/position_m", frame, float(np.linalg.norm(truth[:3, 3] - pose[:3, 3])))
    columns.add_scalar("/metrics/angle_error/heading_deg", frame,
                       float(np.degrees(rotation_angle(truth[:3, :3].T @ pose[:3, :3]))))
    drift.trail.add(frame, pose[:3, 3], NO_HEALTH, "")
    drift.add(frame, i, pose)
    drift.log_series(columns)


def _log_image(columns: ColumnBuffer, frames: RunFrames, frame: Frame, index: int) -> None:
    """The row's image as JPEG, with its image number and file name on hover."""
    jpeg = encode_jpeg(frames.images.read(index), 1.0, JPEG_QUALITY, what=str(frames.images.files[index]))
    columns.add("/world/camera/image", frame, (rr.EncodedImage.columns, {"blob": jpeg, "media_type": "image/jpeg"}),
                (rr.AnyValues.columns, {"image_index": index, "image_file": frames.images.files[index].name}))


def _log_series_styles(rec: rr.RecordingStream) -> None:
    """The Recorder's series styles, for the series such a recording has."""
    for group in GROUPS:
        for name, (legend, colour) in METRICS[group].items():
            if group != "angle_error" or name == "heading_deg":  # no keyframes: no translation direction
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)
