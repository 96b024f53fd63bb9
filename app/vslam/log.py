"""Log another odometry pipeline's frames as a vslam recording (docs/logging-api.md, docs/recording-schema.md).

    from vslam.log import CameraIntrinsics, FrameLog

    camera = CameraIntrinsics(fx=718.856, fy=718.856, cx=607.19, cy=185.22, width=1241, height=376)
    with FrameLog("run.rrd", camera=camera, source="kitti-05", pipeline="my-vo") as log:
        for i, image in enumerate(images):
            ...
            log.frame(i, pose=T_world_cam, time=t, image=image, corners=keypoints, tracks=(ids, prev_px, cur_px),
                      inliers=inlier_mask, health="ok", reasons=[], scalars={"matches": n}, gt=T_world_cam_gt)

Only the frame index and the pose are required. Each frame becomes an engine-style `FrameResult` that vslam's
own `Recorder` writes: the same entities, series, drift attribution, events and verdict as a `vslam run`
recording, so `vslam inspect`, `compare`, `crop`, `snapshot`, `open`, `repair` and `check` read it unchanged.
What a pipeline does not report is left out, never recorded as zero or "ok".

Conventions: poses are camera-to-world (4, 4) T_world_cam, camera axes RDF (x right, y down, z forward), metres
(or unit steps with ``scale="none"``); the recording's world is the camera frame of the first logged frame (the
first pose, and the first ground-truth pose, are re-based to the identity). Pixels are raw-image pixels, (x right,
y down).
"""

from __future__ import annotations

import dataclasses
import math
import re
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Literal, cast

import numpy as np

from vslam.common import ClaimedFile, claim
from vslam.recording import JPEG_QUALITY, STAGES, Detail, Recorder, version_properties
from vslam.runs import TrajectoryWriter
from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, FrameStatus, Health, HealthStatus, Reason, TrackFate
from vslam_core.sources.base import CameraIntrinsics, Frame

__all__ = ["TIMED_STAGES", "CameraIntrinsics", "FrameLog", "HealthText", "Tracks"]

#: A frame's health: ``ok``, ``warn`` (used, but suspicious) or ``fail`` (not trusted).
HealthText = Literal["ok", "warn", "fail"]
#: Tracks into this frame: (ids (M,) int, previous-frame pixels (M, 2), this frame's pixels (M, 2)).
Tracks = tuple[np.ndarray, np.ndarray, np.ndarray]
#: Series the API never has (vslam's forward-backward check; the recorder's own time, which would read as the
#: pipeline's): left out of the recording.
_NEVER_REPORTED = frozenset({"fb_rejected", "record"})
#: Stages a pipeline may time (``timings_ms=``): vslam's, so `inspect` and `compare` read them.
TIMED_STAGES = tuple(stage for stage in STAGES if stage != "record")
_NO_IMAGE = np.zeros((0, 0), np.uint8)
_REASON = re.compile(r"[^,\s]+")
_SERIES_NAME = re.compile(r"[A-Za-z0-9_.-]+")


@dataclass
class _Source:
    """The `FrameSource` facts the `Recorder` reads, for frames that come from a pipeline, not a source."""

    name: str
    intrinsics: CameraIntrinsics
    ground_truth: np.ndarray | None
    properties: dict[str, str]
    indices: list[int] = field(default_factory=list)
    camera_height: float | None = None

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self) -> Iterator[Frame]:
        return iter(())


class FrameLog:
    """Writes one run of another pipeline to the `.rrd` at `path` (complete, with footer, once closed: use
    ``with`` or call `close`).

    camera: the pinhole intrinsics (and lens) of the images. source: what the frames are of (``kitti-05``).
    pipeline: the pipeline's name (run property ``pipeline``; the recording is named ``<pipeline> <source>
    frames <first:end>``). ground_truth: (M, 4, 4) T_world_cam with row i = frame index i (a KITTI poses file),
    or give ``gt=`` per frame instead. scale: ``metric`` (poses in metres: errors per frame) or ``none`` (unit or
    arbitrary scale: errors after Sim(3) alignment, when closing). detail: ``standard`` (images, corners, tracks)
    or ``full`` (also track and corner ids on hover: give corners as ``(ids, pixels)``) or ``summary`` (no
    images or pixels). properties: extra run properties (strings). trajectory: also write the (re-based) poses to
    this file, one line per frame as it goes (``kitti`` or ``tum``: `vslam run --trajectory-out`'s writer), for
    ``vslam eval --trajectory``."""

    def __init__(
        self,
        path: str | Path,
        camera: CameraIntrinsics,
        source: str,
        *,
        pipeline: str = "pipeline",
        ground_truth: np.ndarray | None = None,
        scale: Literal["metric", "none"] = "metric",
        detail: Literal["full", "standard", "summary"] = "standard",
        name: str | None = None,
        properties: Mapping[str, str] | None = None,
        jpeg_quality: int = JPEG_QUALITY,
        trajectory: str | Path | None = None,
        trajectory_format: Literal["kitti", "tum"] = "kitti",
    ) -> None:
        self.path = Path(path)
        if self.path.suffix != ".rrd":
            raise ValueError(f"{self.path}: a recording must end in .rrd")
        if not self.path.parent.is_dir():
            raise ValueError(f"{self.path}: its folder does not exist")
        if not isinstance(camera, CameraIntrinsics):
            raise TypeError("camera must be a vslam.log.CameraIntrinsics")
        if scale not in ("metric", "none"):
            raise ValueError(f"scale must be 'metric' or 'none', got {scale!r}")
        self._detail = Detail(detail)
        if self._detail == Detail.OFF:
            raise ValueError("detail 'off' writes no recording")
        self._camera = camera
        self._scale = scale
        self._jpeg_quality = jpeg_quality
        self._ground_truth = None if ground_truth is None else _poses(ground_truth, "ground_truth")
        self._properties = {
            "name": name or f"{pipeline} {source} frames -",
            "recording_id": str(uuid.uuid5(uuid.NAMESPACE_URL, f"vslam-log:{pipeline}:{source}:{self.path.name}")),
            "source": source, "pipeline": pipeline, "scale": scale,
            **version_properties(), **dict(properties or {}),
        }
        self._source = source
        self._recorder: Recorder | None = None
        self._with_gt: bool | None = None  # decided by the first frame
        self._run = RunResult([], [], [])
        self._first_pose: np.ndarray | None = None
        self._first_gt: np.ndarray | None = None
        self._ages: dict[int, int] = {}  # track id → frames lived, as of the previous frame
        self._trajectory: tuple[ClaimedFile, TrajectoryWriter] | None = None
        if trajectory is not None:  # last: nothing above can fail and leave the file claimed
            claimed = claim(Path(trajectory), True, "trajectory")
            self._trajectory = (claimed, TrajectoryWriter(claimed, trajectory_format))
        self._closed = False

    def __enter__(self) -> FrameLog:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 _traceback: TracebackType | None) -> None:
        stopped = None if kind is None else f"stopped by {kind.__name__} after {self._run.frames} frames"
        try:
            self.close(stopped)
        except Exception:
            if kind is None:
                raise  # else the exception in flight is the one to see

    @property
    def frames(self) -> int:
        """Frames logged so far."""
        return self._run.frames

    def frame(
        self,
        index: int,
        *,
        pose: np.ndarray,
        time: float | None = None,
        image: np.ndarray | None = None,
        corners: np.ndarray | tuple[np.ndarray, np.ndarray] | None = None,
        tracks: Tracks | None = None,
        inliers: np.ndarray | None = None,
        health: HealthText | None = None,
        reasons: Sequence[str] = (),
        scalars: Mapping[str, float] | None = None,
        timings_ms: Mapping[str, float] | None = None,
        gt: np.ndarray | None = None,
    ) -> None:
        """Log frame `index` (the ``frame`` timeline: source frame numbers, strictly increasing).

        pose: (4, 4) T_world_cam. time: seconds (the ``time`` timeline). image: (H, W) grey or (H, W, 3) BGR
        uint8. corners: (K, 2) pixels detected in this frame, or ``(ids, pixels)``. tracks: ``(ids, prev_px,
        cur_px)``, one row per track (or match) from the previous frame into this one. inliers: (M,) bool per
        track, e.g. the essential matrix's RANSAC mask. health and reasons: the pipeline's verdict on this frame
        (reason codes without commas, e.g. ``few_matches``). scalars: the pipeline's own series
        (``/metrics/custom/<name>``). timings_ms: milliseconds per stage, of `TIMED_STAGES` (decode, track,
        essential, chirality, detect: ``/metrics/timing_ms/<stage>``). gt: (4, 4) ground-truth T_world_cam of this
        frame (or ``ground_truth=``)."""
        if self._closed:
            raise ValueError("this FrameLog is closed")
        position = self._run.frames
        if self._run.indices and index <= self._run.indices[-1]:
            raise ValueError(f"frame {index}: indices must increase (the last was {self._run.indices[-1]})")
        # every check first: a refused frame changes nothing (the first pose, the track ages)
        checked = _pose(pose, f"frame {index}: pose")
        first_pose = self._first_pose if self._first_pose is not None else invert_pose(checked)
        T_world_cam = first_pose @ checked  # noqa: N806
        truth, first_gt = self._truth(index, gt)
        result, unreported, ages = self._result(position, index, time, T_world_cam, image, corners, tracks, inliers,
                                                health, reasons)
        frame = Frame(index, time, _NO_IMAGE if image is None else _image(image, index))
        if timings_ms:
            result = dataclasses.replace(result, timings_ms=_timings(timings_ms, index))
        series = _scalars(scalars, index) if scalars else {}
        recorder = self._open(index, truth is not None)
        self._first_pose, self._first_gt, self._ages = first_pose, first_gt, ages
        if truth is not None:
            recorder.extend_ground_truth(truth)
        recorder.log_frame(frame, result, unreported)
        if self._trajectory is not None:
            self._trajectory[1](frame, result)
        if series:
            recorder.log_series(frame, series)
        self._run.indices.append(index)
        self._run.timestamps.append(time)
        self._run.poses.append(T_world_cam)
        self._run.tracked += 1

    def close(self, stopped: str | None = None) -> None:
        """Write the verdict (metrics table, drift attribution when there is ground truth) and the footer.
        `stopped`: why the run ended early, for the run properties. Raises `vslam.runs.OutputError` (a
        `VslamError`) when the file could not be written, ValueError when no frame was logged."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._recorder is None:
                raise ValueError(f"{self.path}: no frame was logged, nothing was written")
            self._recorder.finish(self._run, stopped)
        finally:
            if self._trajectory is not None:
                claimed, writer = self._trajectory
                try:
                    writer.finish(self._run)
                finally:
                    claimed.release(keep=self._run.frames > 0)

    # ------------------------------------------------------------------------------------------ helpers

    def _open(self, index: int, with_gt: bool) -> Recorder:
        """The recorder, opened at the first frame (which says whether there is ground truth)."""
        if self._recorder is not None:
            if with_gt != self._with_gt:
                raise ValueError(f"frame {index}: give ground truth for every frame or for none (the first frame "
                                 f"had {'some' if self._with_gt else 'none'})")
            return self._recorder
        self._with_gt = with_gt
        config = EngineConfig().with_scale("gt" if self._scale == "metric" else "none")
        source = _Source(self._source, self._camera, np.zeros((0, 4, 4)) if with_gt else None, {})
        self._recorder = Recorder(self.path, source, config, self._properties, self._detail, self._jpeg_quality,
                                  external=True)
        return self._recorder

    def _truth(self, index: int, gt: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """This frame's ground truth re-based to the first frame's (None without), and the first frame's
        inverse ground truth."""
        if gt is not None and self._ground_truth is not None:
            raise ValueError(f"frame {index}: ground truth given twice (gt= and ground_truth=)")
        if self._ground_truth is not None:
            if not 0 <= index < len(self._ground_truth):
                raise ValueError(f"frame {index}: ground_truth has rows for frames 0..{len(self._ground_truth) - 1}")
            gt = self._ground_truth[index]
        if gt is None:
            return None, self._first_gt
        pose = _pose(gt, f"frame {index}: gt")
        first = self._first_gt if self._first_gt is not None else invert_pose(pose)
        return first @ pose, first

    def _result(self, position: int, index: int, time: float | None, T_world_cam: np.ndarray,  # noqa: N803
                image: np.ndarray | None, corners: np.ndarray | tuple[np.ndarray, np.ndarray] | None,
                tracks: Tracks | None, inliers: np.ndarray | None, health: HealthText | None,
                reasons: Sequence[str]) -> tuple[FrameResult, frozenset[str], dict[int, int]]:
        """The engine-style result of one logged frame, the series it does not report, and the track ages after
        it (track id → frames lived)."""
        unreported = set(_NEVER_REPORTED)
        corner_ids, corner_px = _corners(corners, index, self._detail == Detail.FULL)
        if corners is None:
            unreported.add("new_corners")
        ids, prev_px, cur_px = _tracks(tracks, index)
        if tracks is None:
            unreported |= {"alive", "inliers"}
        elif inliers is None:
            unreported.add("inliers")
        fate = np.full(len(ids), TrackFate.NOT_USED, np.uint8)
        if inliers is not None:
            mask = np.asarray(inliers, dtype=bool).reshape(-1)
            if tracks is None or len(mask) != len(ids):
                raise ValueError(f"frame {index}: inliers needs one flag per track ({len(ids)} tracks)")
            fate = np.where(mask, TrackFate.INLIER, TrackFate.RANSAC_OUTLIER).astype(np.uint8)
        ages = np.array([self._ages.get(int(i), 1) + 1 for i in ids], np.int32)
        ages_after = {int(i): int(a) for i, a in zip(ids, ages, strict=True)} | {int(i): 1 for i in corner_ids}
        if health is None:
            if reasons:
                raise ValueError(f"frame {index}: reasons need a health (ok, warn or fail)")
            unreported.add("status")
        previous = self._run.poses[-1] if self._run.poses else None
        T_key_cur = invert_pose(previous) @ T_world_cam if previous is not None else None  # noqa: N806
        shape = image.shape[:2] if image is not None else (self._camera.height, self._camera.width)
        result = FrameResult(
            position=position, index=index, timestamp=time, T_world_cam=T_world_cam,
            status=FrameStatus.INIT if position == 0 and corners is not None else FrameStatus.OK, reason=None,
            keyframe_position=max(position - 1, 0), image_shape=(int(shape[0]), int(shape[1])),
            track_ids=ids, track_prev=prev_px, track_cur=cur_px, track_age=ages, track_fate=fate,
            new_corner_ids=corner_ids, new_corners=corner_px, live_tracks=len(ids),
            essential=None, candidate_poses=(), chosen_candidate=None, T_key_cur=T_key_cur,
            points_world=np.zeros((0, 3)), scale=None if T_key_cur is None else float(np.linalg.norm(T_key_cur[:3, 3])),
            parallax_px=math.nan, health=_health(health, reasons, index),
        )
        return result, frozenset(unreported), ages_after


def _health(health: HealthText | None, reasons: Sequence[str], index: int) -> Health:
    if health is None:
        return Health(HealthStatus.OK)
    if health not in ("ok", "warn", "fail"):
        raise ValueError(f"frame {index}: health must be ok, warn or fail, got {health!r}")
    codes = tuple(str(r) for r in reasons)
    for code in codes:
        if not _REASON.fullmatch(code):
            raise ValueError(f"frame {index}: reason {code!r}: a code without commas or spaces, e.g. few_matches")
    # the recorder writes reasons as text: another pipeline's codes need not be vslam's `Reason`s
    return Health(HealthStatus(health), cast("tuple[Reason, ...]", codes))


def _pose(value: np.ndarray, what: str) -> np.ndarray:
    """A checked (4, 4) rigid transform."""
    pose = np.asarray(value, dtype=np.float64)
    if pose.shape != (4, 4):
        raise ValueError(f"{what}: expected a (4, 4) T_world_cam, got shape {pose.shape}")
    if not np.isfinite(pose).all():
        raise ValueError(f"{what}: not finite")
    rotation = pose[:3, :3]
    if not np.allclose(pose[3], (0, 0, 0, 1)) or not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4) \
            or np.linalg.det(rotation) < 0:
        raise ValueError(f"{what}: not a rigid transform (rotation not orthonormal, or last row not 0 0 0 1)")
    return pose


def _poses(value: np.ndarray, what: str) -> np.ndarray:
    poses = np.asarray(value, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"{what}: expected (M, 4, 4) poses, got shape {poses.shape}")
    return poses


def _image(image: np.ndarray, index: int) -> np.ndarray:
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"frame {index}: image must be (H, W) or (H, W, 3) uint8, got {image.shape} {image.dtype}")
    return image


def _pixels(value: np.ndarray, what: str) -> np.ndarray:
    pixels = np.asarray(value, dtype=np.float32)
    if pixels.ndim != 2 or pixels.shape[1] != 2:
        raise ValueError(f"{what}: expected (N, 2) pixels, got shape {pixels.shape}")
    return pixels


def _corners(corners: np.ndarray | tuple[np.ndarray, np.ndarray] | None, index: int,
             full: bool) -> tuple[np.ndarray, np.ndarray]:
    """(ids, pixels) of the corners; ids are needed at detail full (they are shown on hover)."""
    if corners is None:
        return np.zeros(0, np.int64), np.zeros((0, 2), np.float32)
    if isinstance(corners, tuple):
        ids, pixels = np.asarray(corners[0], np.int64).reshape(-1), _pixels(corners[1], f"frame {index}: corners")
        if len(ids) != len(pixels):
            raise ValueError(f"frame {index}: corners: {len(ids)} ids for {len(pixels)} pixels")
        return ids, pixels
    if full:
        raise ValueError(f"frame {index}: detail full shows corner ids: give corners as (ids, pixels)")
    pixels = _pixels(corners, f"frame {index}: corners")
    return np.zeros(len(pixels), np.int64), pixels


def _tracks(tracks: Tracks | None, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if tracks is None:
        return np.zeros(0, np.int64), np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    ids = np.asarray(tracks[0], np.int64).reshape(-1)
    prev_px, cur_px = _pixels(tracks[1], f"frame {index}: tracks"), _pixels(tracks[2], f"frame {index}: tracks")
    if not len(ids) == len(prev_px) == len(cur_px):
        raise ValueError(f"frame {index}: tracks: {len(ids)} ids, {len(prev_px)} and {len(cur_px)} pixels")
    return ids, prev_px, cur_px


def _timings(values: Mapping[str, float], index: int) -> dict[str, float]:
    for stage in values:
        if stage not in TIMED_STAGES:
            raise ValueError(f"frame {index}: timings_ms: unknown stage {stage!r} (stages: {', '.join(TIMED_STAGES)}; "
                             "time anything else with scalars=)")
    return {stage: float(ms) for stage, ms in values.items()}


def _scalars(values: Mapping[str, float], index: int) -> dict[str, float]:
    for name in values:
        if not _SERIES_NAME.fullmatch(name):
            raise ValueError(f"frame {index}: series name {name!r}: letters, digits, _ . - only")
    return {name: float(value) for name, value in values.items()}
