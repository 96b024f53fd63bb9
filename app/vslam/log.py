"""Log another odometry pipeline's frames as a vslam recording (docs/logging-api.md, docs/recording-schema.md).

    from vslam.log import CameraIntrinsics, FrameLog

    camera = CameraIntrinsics(fx=718.856, fy=718.856, cx=607.19, cy=185.22, width=1241, height=376)
    with FrameLog("run.rrd", camera=camera, source="kitti-05", pipeline="my-vo") as log:
        for i, image in enumerate(images):
            ...
            log.frame(i, pose=T_world_cam, time=t, image=image, corners=Corners(px=keypoints),
                      tracks=Tracks(ids=ids, prev=prev_px, cur=cur_px), inliers=inlier_mask, health="ok",
                      reasons=[], scalars={"matches": n}, gt=T_world_cam_gt)

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
from typing import TYPE_CHECKING, Literal, cast

import numpy as np

from vslam.common import ClaimedFile, claim
from vslam.log_arrays import Candidates, Corners, Tracks, candidate_poses, corner_arrays, points_array, track_arrays
from vslam.recording import STAGES, Detail, Recorder, version_properties
from vslam.runs import TrajectoryWriter
from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, FrameStatus, Health, HealthStatus, Reason, TrackFate
from vslam_core.sources.base import CameraIntrinsics, Frame

if TYPE_CHECKING:
    import rerun as rr

__all__ = ["TIMED_STAGES", "CameraIntrinsics", "Candidates", "Corners", "FrameLog", "HealthText", "Tracks"]

#: A frame's health: ``ok``, ``warn`` (used, but suspicious) or ``fail`` (not trusted).
HealthText = Literal["ok", "warn", "fail"]
#: Series the API never has (vslam's forward-backward check; the recorder's own time, which would read as the
#: pipeline's): left out of the recording.
_NEVER_REPORTED = frozenset({"fb_rejected", "record"})
#: vslam's own stage names (``timings_ms=``); a pipeline's own names are recorded beside them.
TIMED_STAGES = tuple(stage for stage in STAGES if stage != "record")
_NO_IMAGE = np.zeros((0, 0), np.uint8)
_REASON = re.compile(r"[^,\s]+")
_SERIES_NAME = re.compile(r"[A-Za-z0-9_.-]+")
#: A series name with the plot it asks for: ``plot/name``.
_PLOTTED_NAME = re.compile(r"(?:[A-Za-z0-9_.-]+/)?[A-Za-z0-9_.-]+")


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
    images or pixels); the images are stored at half size at ``standard`` (at full size at ``full``), as JPEG at
    `jpeg_quality` (default: `vslam run`'s). properties: extra run properties (strings). trajectory: also write
    the (re-based) poses to this file, one line per frame as it goes (``kitti`` or ``tum``: `vslam run
    --trajectory-out`'s writer), for ``vslam eval --trajectory``. force: replace an existing file at `path`
    (else FileExistsError).
    `stream`: the underlying `rr.RecordingStream` (from the first frame on), for what the schema does not cover."""

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
        jpeg_quality: int | None = None,
        trajectory: str | Path | None = None,
        trajectory_format: Literal["kitti", "tum"] = "kitti",
        force: bool = False,
    ) -> None:
        self.path = Path(path)
        if self.path.suffix != ".rrd":
            raise ValueError(f"{self.path}: a recording must end in .rrd")
        if not self.path.parent.is_dir():
            raise ValueError(f"{self.path}: its folder does not exist")
        if self.path.exists() and not force:
            raise FileExistsError(f"{self.path}: exists already (FrameLog(..., force=True) replaces it)")
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
            # one per file (the viewer merges recordings that share one): from the file's absolute path
            "recording_id": str(uuid.uuid5(uuid.NAMESPACE_URL,
                                           f"vslam-log:{pipeline}:{source}:{self.path.resolve()}")),
            # backend "external": not vslam's engine (`inspect` names the pipeline; properties= may say more)
            "source": source, "pipeline": pipeline, "backend": "external", "scale": scale,
            **version_properties(), **dict(properties or {}),
        }
        self._source = source
        self._recorder: Recorder | None = None
        self._with_gt: bool | None = None  # decided by the first frame
        self._run = RunResult([], [], [])
        self._first_pose: np.ndarray | None = None
        self._first_gt: np.ndarray | None = None
        self._ages: dict[int, int] = {}  # track id → frames lived, as of the previous frame
        self._plots: tuple[str, ...] | None = None  # the plots of own series, fixed by the first frame
        self._trajectory: tuple[ClaimedFile, TrajectoryWriter] | None = None
        # last: nothing above can fail and leave a file claimed
        self._claimed = claim(self.path, True, "recording")
        if trajectory is not None:
            try:
                claimed = claim(Path(trajectory), True, "trajectory")
            except BaseException:
                self._claimed.release(keep=False)
                raise
            self._trajectory = (claimed, TrajectoryWriter(claimed, trajectory_format, header=True))
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

    @property
    def stream(self) -> rr.RecordingStream:
        """The underlying Rerun stream, for entities the schema does not cover (set its time yourself:
        ``log.stream.set_time("frame", sequence=i)``). It opens with the first frame (which says whether there is
        ground truth): ValueError before."""
        if self._recorder is None:
            raise ValueError("FrameLog.stream opens with the first frame: log a frame first")
        return self._recorder.stream

    def frame(
        self,
        index: int,
        *,
        pose: np.ndarray,
        time: float | None = None,
        image: np.ndarray | None = None,
        corners: Corners | np.ndarray | tuple[np.ndarray, np.ndarray] | None = None,
        tracks: Tracks | tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        inliers: np.ndarray | None = None,
        candidates: Candidates | None = None,
        points: np.ndarray | None = None,
        health: HealthText | None = None,
        reasons: Sequence[str] = (),
        scalars: Mapping[str, float] | None = None,
        timings_ms: Mapping[str, float] | None = None,
        gt: np.ndarray | None = None,
    ) -> None:
        """Log frame `index` (the ``frame`` timeline: source frame numbers, strictly increasing).

        pose: (4, 4) T_world_cam. time: seconds (the ``time`` timeline). image: (H, W) grey or (H, W, 3) BGR
        uint8. corners: `Corners` (px (K, 2), ids (K,)) detected in this frame, or bare (K, 2) pixels. tracks:
        `Tracks` (ids (M,), prev (M, 2), cur (M, 2)), one row per track (or match) from the previous frame into
        this one (the tuple ``(ids, prev, cur)`` works too). inliers: (M,) bool per track, e.g. the essential
        matrix's RANSAC mask. candidates: the four `Candidates` poses of the essential matrix with their
        chirality counts (``/world/candidates``, ``/metrics/ransac/chirality_margin``). points: (P, 3)
        triangulated points in the pipeline's world (``/world/points``, re-based like the poses). health and
        reasons: the pipeline's verdict on this frame (reason codes without commas, e.g. ``few_matches``).
        scalars: the pipeline's own series, ``name`` or ``plot/name`` (``/metrics/custom/[plot/]name``: one plot
        per ``plot``, fixed by the first frame's names; the others share "pipeline series"). timings_ms:
        milliseconds per stage, vslam's (`TIMED_STAGES`) or the pipeline's own names
        (``/metrics/timing_ms/<stage>``). gt: (4, 4) ground-truth T_world_cam of this frame (or
        ``ground_truth=``)."""
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
        if candidates is not None:
            poses, chosen = candidate_poses(candidates, index)
            result = dataclasses.replace(result, candidate_poses=poses, chosen_candidate=chosen)
        if points is not None:
            world = first_pose[:3, :3] @ points_array(points, index).T + first_pose[:3, 3:4]
            result = dataclasses.replace(result, points_world=world.T)
        frame = Frame(index, time, _NO_IMAGE if image is None else _image(image, index))
        own_timings: dict[str, float] = {}
        if timings_ms:
            timings = _timings(timings_ms, index)
            result = dataclasses.replace(result, timings_ms={k: v for k, v in timings.items() if k in STAGES})
            own_timings = {k: v for k, v in timings.items() if k not in STAGES}
        series = _scalars(scalars, index) if scalars else {}
        plots = self._plots if self._plots is not None else tuple(sorted({n.split("/")[0] for n in series if "/" in n}))
        for name in series:
            if "/" in name and name.split("/")[0] not in plots:
                raise ValueError(f"frame {index}: scalars: plot {name.split('/')[0]!r} is new (the plots are those "
                                 f"of the first frame's scalars: {', '.join(plots) or 'none'})")
        recorder = self._open(index, truth is not None, plots)
        self._first_pose, self._first_gt, self._ages = first_pose, first_gt, ages
        if truth is not None:
            recorder.extend_ground_truth(truth)
        recorder.log_frame(frame, result, unreported)
        if self._trajectory is not None:
            self._trajectory[1](frame, result)
        if series:
            recorder.log_series(frame, series)
        if own_timings:
            recorder.log_series(frame, own_timings, "/metrics/timing_ms")
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
            self._claimed.release(keep=self._recorder is not None)
            if self._trajectory is not None:
                claimed, writer = self._trajectory
                try:
                    writer.finish(self._run)
                finally:
                    claimed.release(keep=self._run.frames > 0)

    # ------------------------------------------------------------------------------------------ helpers

    def _open(self, index: int, with_gt: bool, plots: tuple[str, ...]) -> Recorder:
        """The recorder, opened at the first frame (which says whether there is ground truth, and which plots
        the pipeline's own series ask for)."""
        if self._recorder is not None:
            if with_gt != self._with_gt:
                raise ValueError(f"frame {index}: give ground truth for every frame or for none (the first frame "
                                 f"had {'some' if self._with_gt else 'none'})")
            return self._recorder
        self._with_gt, self._plots = with_gt, plots
        # the odometry's layout: a pipeline of one's own has no map (the default engine's entities would be empty)
        config = EngineConfig(backend="vo").with_scale("gt" if self._scale == "metric" else "none")
        source = _Source(self._source, self._camera, np.zeros((0, 4, 4)) if with_gt else None, {})
        self._recorder = Recorder(self.path, source, config, self._properties, self._detail, self._jpeg_quality,
                                  external=True, own_plots=plots)
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
                image: np.ndarray | None, corners: object, tracks: object, inliers: np.ndarray | None,
                health: HealthText | None, reasons: Sequence[str]
                ) -> tuple[FrameResult, frozenset[str], dict[int, int]]:
        """The engine-style result of one logged frame, the series it does not report, and the track ages after
        it (track id → frames lived)."""
        unreported = set(_NEVER_REPORTED)
        corner_ids, corner_px = (corner_arrays(corners, index, self._detail == Detail.FULL) if corners is not None
                                 else (np.zeros(0, np.int64), np.zeros((0, 2), np.float32)))
        if corners is None:
            unreported.add("new_corners")
        no_pixels = np.zeros((0, 2), np.float32)
        ids, prev_px, cur_px = (track_arrays(tracks, index) if tracks is not None
                                else (np.zeros(0, np.int64), no_pixels, no_pixels))
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


def _timings(values: Mapping[str, float], index: int) -> dict[str, float]:
    """Milliseconds per stage: vslam's names or the pipeline's own (``record`` is vslam's recorder's)."""
    for stage in values:
        if stage == "record" or not _SERIES_NAME.fullmatch(stage):
            raise ValueError(f"frame {index}: timings_ms: stage {stage!r}: a name of letters, digits, _ . - "
                             "(not 'record', the recorder's own)")
    return {stage: _number(ms, f"frame {index}: timings_ms[{stage!r}]") for stage, ms in values.items()}


def _scalars(values: Mapping[str, float], index: int) -> dict[str, float]:
    for name in values:
        if not _PLOTTED_NAME.fullmatch(name):
            raise ValueError(f"frame {index}: series name {name!r}: name or plot/name, of letters, digits, _ . -")
    return {name: _number(value, f"frame {index}: scalars[{name!r}]") for name, value in values.items()}


def _number(value: object, what: str) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected a number, got {type(value).__name__}") from None
