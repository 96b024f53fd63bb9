"""Turn the engine's per-frame results into Rerun entities (the only module that logs to Rerun).

Entity layout (world = camera frame of the first frame, RDF: x right, y down, z forward):

    /world                              ViewCoordinates.RDF (static)
    /world/camera                       Transform3D T_world_cam per frame
    /world/camera/image                 Pinhole (static) + JPEG frame
    /world/camera/image/corners         Points2D: corners detected in this frame (track id on hover)
    /world/camera/image/flow            Arrows2D: previous → current position per track, class = fate,
                                        track id and age on hover (the arrow tips are the tracked corners)
    /world/candidates/{0..3}            the four (R, t) decompositions of E, placed at the keyframe
    /world/points                       triangulated inliers of this frame (world coordinates)
    /world/trajectory/estimate          one line segment per frame (O(1) per frame)
    /world/trajectory/ground_truth      same, from the source's ground truth
    /metrics/...                        per-frame scalars (tracks, RANSAC, motion, error, timing_ms)
    /events                             text log: initialisation, re-detections, held frames
    /health                             per frame: status ok / fail and reason codes (for `vslam inspect`)
    /report                             static Markdown written at the end: the run's metrics table

Detail levels: full = all of it; standard = no triangulated points and no per-track hover data;
summary = no image and no per-point data (camera pose, trajectories, series, events); off = no file.
"""

from __future__ import annotations

import time
from enum import StrEnum
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import vslam_core
from app.report import markdown_table, metrics_row
from vslam_core.config import EngineConfig
from vslam_core.geometry import angle_between, invert_pose, rotation_angle
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, FrameStatus, HealthStatus, TrackFate
from vslam_core.sources.base import Frame, FrameSource

APPLICATION_ID = "vslam"


class Detail(StrEnum):
    FULL = "full"
    STANDARD = "standard"
    SUMMARY = "summary"
    OFF = "off"


# Legend of the flow arrows: one annotation context, so the viewer explains the colours.
FATE_STYLE: dict[TrackFate, tuple[str, tuple[int, int, int]]] = {
    TrackFate.LOST: ("lost (KLT failed / left image)", (120, 120, 120)),
    TrackFate.FB_REJECTED: ("rejected by forward–backward check", (255, 140, 0)),
    TrackFate.NOT_USED: ("tracked, no keyframe position yet", (80, 160, 255)),
    TrackFate.RANSAC_OUTLIER: ("RANSAC outlier", (230, 30, 30)),
    TrackFate.CHIRALITY_FAILED: ("failed chirality (behind a camera)", (200, 0, 200)),
    TrackFate.INLIER: ("inlier", (40, 220, 60)),
}
NEW_CORNER_COLOUR = (255, 230, 0)
CANDIDATE_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 160), (160, 255, 0)]
ESTIMATE_COLOUR = (255, 80, 80)
GROUND_TRUTH_COLOUR = (80, 255, 120)
HEALTH_LEVELS = {HealthStatus.OK: 0, HealthStatus.WARN: 1, HealthStatus.FAIL: 2}
STAGES = ("decode", "track", "essential", "chirality", "detect", "record")

# Per-frame series, logged to /metrics/<group>/<series> only on frames that have a value (no NaN: it
# would make identical runs compare unequal). One plot per group. `vslam inspect` reads them back.
METRICS: dict[str, dict[str, tuple[str, tuple[int, int, int]]]] = {
    "tracks": {
        "alive": ("tracks alive", (40, 120, 255)),
        "new_corners": ("corners detected", NEW_CORNER_COLOUR),
        "fb_rejected": ("forward–backward rejects", (255, 140, 0)),
    },
    "ransac": {
        "inliers": ("RANSAC inliers", (40, 220, 60)),
        "chirality_margin": ("chirality margin (best − 2nd)", (200, 0, 200)),
    },
    "ratio": {"inlier_ratio": ("inlier ratio", (40, 220, 60))},
    "health": {"status": ("health: 0 ok, 1 warn, 2 fail", (255, 140, 0))},
    "motion": {"rotation_deg": ("rotation (°)", (255, 200, 0)), "scale": ("step length", (0, 200, 255))},
    "error": {"position_m": ("position error (m)", ESTIMATE_COLOUR)},
    "angle_error": {
        "heading_deg": ("heading error (°)", (255, 80, 200)),
        "translation_direction_deg": ("translation direction error (°)", (0, 200, 255)),
    },
    "timing_ms": {
        "decode": ("decode (ms)", (150, 150, 150)),
        "track": ("track (ms)", (40, 120, 255)),
        "essential": ("essential (ms)", (230, 30, 30)),
        "chirality": ("chirality (ms)", (200, 0, 200)),
        "detect": ("detect (ms)", (255, 230, 0)),
        "record": ("record (ms)", (0, 200, 200)),
    },
}


def blueprint() -> rrb.Blueprint:
    """Frame with overlays | 3-D world with trajectories and candidates | metric plots and events."""
    whole_past = rr.VisibleTimeRange(
        "frame", start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="frame", origin="/world/camera/image"),
                rrb.Spatial3DView(
                    name="world",
                    origin="/world",
                    # follow the car from behind and above (RDF: −y is up, −z is behind)
                    eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0],
                                                   tracking_entity="/world/camera"),
                    # the trajectories keep their whole past; everything else shows the current frame
                    overrides={
                        "/world/trajectory/estimate": rrb.VisibleTimeRanges([whole_past]),
                        "/world/trajectory/ground_truth": rrb.VisibleTimeRanges([whole_past]),
                    },
                ),
                row_shares=[1, 2],
            ),
            rrb.Vertical(
                rrb.Grid(
                    rrb.TimeSeriesView(name="tracks", origin="/metrics/tracks"),
                    rrb.TimeSeriesView(name="inliers", origin="/metrics/ransac"),
                    rrb.TimeSeriesView(name="inlier ratio", origin="/metrics/ratio"),
                    rrb.TimeSeriesView(name="health", origin="/metrics/health"),
                    rrb.TimeSeriesView(name="motion", origin="/metrics/motion"),
                    rrb.TimeSeriesView(name="position error (m)", origin="/metrics/error"),
                    rrb.TimeSeriesView(name="angle errors (°)", origin="/metrics/angle_error"),
                    rrb.TimeSeriesView(name="timing (ms)", origin="/metrics/timing_ms"),
                    rrb.TextLogView(name="events", origin="/events"),
                    rrb.TextDocumentView(name="report", origin="/report"),
                    grid_columns=2,
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class Recorder:
    """Writes one run to a `.rrd` file. Always `close()` it (or use `with`): that writes the footer."""

    def __init__(
        self,
        path: Path,
        source: FrameSource,
        config: EngineConfig,
        properties: dict[str, str],
        detail: Detail = Detail.FULL,
        jpeg_quality: int = 75,
    ) -> None:
        if detail == Detail.OFF:
            raise ValueError("detail 'off' writes no recording: do not build a Recorder")
        self.path = path
        self.detail = detail
        self._jpeg_quality = jpeg_quality
        self._gt = source.ground_truth
        self._name = properties.get("name", source.name)
        self._source_name = source.name
        self._scale = config.scale
        self._previous_position: np.ndarray | None = None
        # send_properties=False: no wall-clock start time, so two runs of the same input compare equal
        # Fewer, larger chunks than the default (0.2 s / 2 MiB): each chunk carries its own schema, and at
        # ~3 frames a chunk the schemas alone were ~16 KB per frame.
        batcher = rr.ChunkBatcherConfig(flush_tick=1.0, flush_num_bytes=8 * 2**20)
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=properties.get("recording_id"),
                                       send_properties=False, batcher_config=batcher)
        self._rec.set_log_time_enabled(False)  # reproducible files: no wall-clock column
        self._rec.save(path, default_blueprint=blueprint())
        self._rec.send_recording_name(properties.get("name", source.name))
        self._rec.send_property("run", rr.AnyValues(**properties, detail=str(detail)))  # type: ignore[arg-type]
        self._rec.send_property("config", rr.AnyValues(**_flatten(config.to_dict())))
        self._log_static(source)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush and write the footer; the file is valid afterwards."""
        self._rec.disconnect()

    def finish(self, run: RunResult, interrupted: bool) -> None:
        """Log the run's verdict (metrics table against ground truth, when there is one) and close."""
        try:
            lines = [f"# {self._name}", "", f"{run.frames} frames, {run.held} held the previous pose"
                     + (" — interrupted" if interrupted else "")]
            if self._gt is not None and run.frames > 2:
                row = metrics_row(self._source_name, self._gt[: run.frames], run.pose_array(), self._scale)
                lines += ["", markdown_table([row])]
            self._rec.log("/report", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN),
                          static=True)
        finally:
            self.close()

    def _log_static(self, source: FrameSource) -> None:
        rec = self._rec
        intr = source.intrinsics
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
        rec.log(
            "/world/camera/image",
            rr.Pinhole(image_from_camera=intr.K, resolution=[intr.width, intr.height],
                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=1.0),
            static=True,
        )
        rec.log(
            "/world/camera/image/flow",
            rr.AnnotationContext([(int(f), label, colour) for f, (label, colour) in FATE_STYLE.items()]),
            static=True,
        )
        for group, series in METRICS.items():
            for name, (legend, colour) in series.items():
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)

    def log_frame(self, frame: Frame, result: FrameResult) -> None:
        """Log everything about one frame on the `frame` timeline (and `time`, when known)."""
        start = time.perf_counter()
        rec = self._rec
        rec.set_time("frame", sequence=frame.index)
        if frame.timestamp is not None:
            rec.set_time("time", duration=frame.timestamp)
        pose = result.T_world_cam
        rec.log("/world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        if self.detail in (Detail.FULL, Detail.STANDARD):
            self._log_image_and_tracks(frame, result)
            self._log_candidates(result)
        if self.detail == Detail.FULL:
            rec.log("/world/points", rr.Points3D(result.points_world.astype(np.float32), radii=0.05,
                                                 colors=(200, 200, 200)))
        self._log_trajectories(result)
        self._log_metrics(result)
        self._log_events(frame, result)
        rec.log("/health", rr.AnyValues(status=str(result.health.status),
                                        reasons=",".join(result.health.reasons) or None))
        timings = dict(result.timings_ms, record=(time.perf_counter() - start) * 1000.0)
        for stage in STAGES:
            if stage in timings:
                rec.log(f"/metrics/timing_ms/{stage}", rr.Scalars(timings[stage]))

    def _log_image_and_tracks(self, frame: Frame, result: FrameResult) -> None:
        rec = self._rec
        ok, jpeg = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, self._jpeg_quality])
        if ok:
            rec.log("/world/camera/image", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))
        full = self.detail == Detail.FULL
        hover = [rr.AnyValues(track_id=result.new_corner_ids.astype(np.uint32))] if full else []
        rec.log("/world/camera/image/corners",
                rr.Points2D(result.new_corners, radii=2.0, colors=NEW_CORNER_COLOUR), *hover)
        reached = result.track_fate != TrackFate.LOST
        hover = [rr.AnyValues(track_id=result.track_ids[reached].astype(np.uint32),
                              age=result.track_age[reached].astype(np.uint16))] if full else []
        rec.log(
            "/world/camera/image/flow",
            rr.Arrows2D(
                origins=result.track_prev[reached],
                vectors=result.track_cur[reached] - result.track_prev[reached],
                class_ids=result.track_fate[reached].astype(np.uint16),
                radii=0.6,
            ),
            *hover,
        )

    def _log_candidates(self, result: FrameResult) -> None:
        """The four candidate poses, each at the keyframe pose moved by its (R, t), with its count."""
        rec = self._rec
        if not result.candidate_poses or result.T_key_cur is None:
            rec.log("/world/candidates", rr.Clear(recursive=True))  # not the previous frame's candidates
            return
        T_w_key = result.T_world_cam @ invert_pose(result.T_key_cur)  # noqa: N806
        length = max(float(np.linalg.norm(result.T_key_cur[:3, 3])), 0.5)
        counts = ", ".join(f"#{i}: {c.in_front}" for i, c in enumerate(result.candidate_poses))
        for i, candidate in enumerate(result.candidate_poses):
            chosen = i == result.chosen_candidate
            centre = T_w_key[:3, :3] @ (length * candidate.translation) + T_w_key[:3, 3]
            rotation = T_w_key[:3, :3] @ candidate.rotation
            # (R1, t) and (R2, t) share a centre: one label, on the chosen candidate, lists every count
            # an empty label on the others, or their label from an earlier frame would stay (latest-at)
            labels = [f"chosen #{i} — in front {counts}" if chosen else ""]
            rec.log(
                f"/world/candidates/{i}",
                rr.Transform3D(translation=centre, mat3x3=rotation),
                rr.TransformAxes3D(axis_length=0.8 if chosen else 0.4),
                rr.Points3D([[0.0, 0.0, 0.0]], radii=0.15 if chosen else 0.08, colors=CANDIDATE_COLOURS[i],
                            labels=labels),
                rr.AnyValues(in_front=candidate.in_front, chosen=chosen),
            )

    def _log_trajectories(self, result: FrameResult) -> None:
        """One segment per frame for the estimate and the ground truth (never the whole path again)."""
        rec = self._rec
        position = result.T_world_cam[:3, 3]
        previous = self._previous_position if self._previous_position is not None else position
        rec.log("/world/trajectory/estimate", rr.LineStrips3D([[previous, position]], colors=ESTIMATE_COLOUR,
                                                                     radii=0.12))
        if self._gt is not None:
            gt = self._gt[:, :3, 3]
            i = result.position
            rec.log("/world/trajectory/ground_truth",
                    rr.LineStrips3D([[gt[max(i - 1, 0)], gt[i]]], colors=GROUND_TRUTH_COLOUR,
                                            radii=0.06))
        self._previous_position = position

    def _log_metrics(self, result: FrameResult) -> None:
        values = frame_metrics(result, self._gt)
        for group, series in METRICS.items():
            for name in series:
                if name in values and group != "timing_ms":
                    self._rec.log(f"/metrics/{group}/{name}", rr.Scalars(values[name]))

    def _log_events(self, frame: Frame, result: FrameResult) -> None:
        rec = self._rec
        if result.status == FrameStatus.INIT:
            rec.log("/events", rr.TextLog(f"frame {frame.index}: initialised with {len(result.new_corners)} "
                                          "corners", level="INFO"))
        elif len(result.new_corners):
            rec.log("/events", rr.TextLog(f"frame {frame.index}: re-detected {len(result.new_corners)} corners",
                                          level="DEBUG"))
        health = result.health
        if health.status != HealthStatus.OK:
            what = "pose held" if result.status == FrameStatus.HELD else "used"
            rec.log("/events", rr.TextLog(f"frame {frame.index}: {health.status} ({what}): "
                                          + ", ".join(health.reasons),
                                          level="ERROR" if health.status == HealthStatus.FAIL else "WARN"))


def frame_metrics(result: FrameResult, ground_truth: np.ndarray | None) -> dict[str, float]:
    """The per-frame series of one result (names as in `METRICS`); absent where a frame has no value."""
    counts = result.fate_counts()
    used = counts["ransac_outlier"] + counts["chirality_failed"] + counts["inlier"]
    values: dict[str, float] = {
        "status": HEALTH_LEVELS[result.health.status],
        "alive": result.live_tracks,
        "new_corners": len(result.new_corners),
        "fb_rejected": counts["fb_rejected"],
        "inliers": counts["inlier"],
    }
    if used:
        values["inlier_ratio"] = counts["inlier"] / used
    if len(result.candidate_poses) == 4:
        in_front = sorted((c.in_front for c in result.candidate_poses), reverse=True)
        values["chirality_margin"] = in_front[0] - in_front[1]
    if result.T_key_cur is not None:
        values["rotation_deg"] = float(np.degrees(rotation_angle(result.T_key_cur[:3, :3])))
        values["scale"] = result.scale or 0.0
    if ground_truth is not None:
        gt_pose = ground_truth[result.position]
        values["position_m"] = float(np.linalg.norm(gt_pose[:3, 3] - result.T_world_cam[:3, 3]))
        values["heading_deg"] = float(np.degrees(rotation_angle(gt_pose[:3, :3].T @ result.T_world_cam[:3, :3])))
        if result.T_key_cur is not None:
            gt_step = invert_pose(ground_truth[result.keyframe_position]) @ gt_pose
            values["translation_direction_deg"] = float(
                np.degrees(angle_between(gt_step[:3, 3], result.T_key_cur[:3, 3])))
    return values


def _flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"pose": {"seed": 0}} -> {"pose.seed": 0} for recording properties."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def version_properties() -> dict[str, str]:
    return {"vslam_version": vslam_core.__version__, "opencv_version": cv2.__version__,
            "rerun_version": rr.__version__}
