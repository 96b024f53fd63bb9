"""Turn the engine's per-frame results into Rerun entities (the only module that logs to Rerun).

Entity layout (world = camera frame of the first frame, RDF: x right, y down, z forward):

    /world                              ViewCoordinates.RDF (static)
    /world/camera                       Transform3D T_world_cam per frame
    /world/camera/image                 Pinhole (static) + JPEG frame
    /world/camera/image/corners         Points2D: corners detected in this frame (track id on hover)
    /world/camera/image/flow            Arrows2D: previous → current position per track, class = fate
    /world/candidates/{0..3}            the four (R, t) decompositions of E, placed at the keyframe
    /world/points                       triangulated inliers of this frame (world coordinates)
    /world/trajectory/estimate          one line segment per frame (O(1) per frame)
    /world/trajectory/ground_truth      same, from the source's ground truth
    /metrics/...                        per-frame scalars
    /events                             text log: held frames and their reasons
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

import vslam_core
from vslam_core.config import EngineConfig
from vslam_core.geometry import angle_between, invert_pose, rotation_angle
from vslam_core.results import FrameResult, FrameStatus, TrackFate
from vslam_core.sources.base import Frame, FrameSource

APPLICATION_ID = "vslam"

# Legend of the flow arrows: one annotation context, so the viewer explains the colours.
FATE_STYLE: dict[TrackFate, tuple[str, tuple[int, int, int]]] = {
    TrackFate.LOST: ("lost (KLT failed / left image)", (120, 120, 120)),
    TrackFate.FB_REJECTED: ("rejected by forward–backward check", (255, 140, 0)),
    TrackFate.NOT_USED: ("tracked, no keyframe position yet", (80, 160, 255)),
    TrackFate.RANSAC_OUTLIER: ("RANSAC outlier", (230, 30, 30)),
    TrackFate.CHIRALITY_FAILED: ("failed chirality (behind a camera)", (200, 0, 200)),
    TrackFate.INLIER: ("inlier", (40, 220, 60)),
}
CANDIDATE_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 160), (160, 255, 0)]


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
                    overrides={"/world/trajectory": rrb.VisibleTimeRanges([whole_past])},
                ),
                row_shares=[1, 2],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="tracks", origin="/metrics/tracks"),
                rrb.TimeSeriesView(name="inliers", origin="/metrics/ransac"),
                rrb.TimeSeriesView(name="error vs ground truth", origin="/metrics/error"),
                rrb.TextLogView(name="events", origin="/events"),
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
        jpeg_quality: int = 85,
    ) -> None:
        self.path = path
        self._jpeg_quality = jpeg_quality
        self._gt = source.ground_truth
        self._previous_position: np.ndarray | None = None
        # send_properties=False: no wall-clock start time, so two runs of the same input compare equal
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=properties.get("recording_id"), send_properties=False)
        self._rec.set_log_time_enabled(False)  # reproducible files: no wall-clock column
        self._rec.save(path, default_blueprint=blueprint())
        self._rec.send_recording_name(properties.get("name", source.name))
        self._rec.send_property("run", rr.AnyValues(**properties))  # type: ignore[arg-type]
        self._rec.send_property("config", rr.AnyValues(**_flatten(config.to_dict())))
        self._log_static(source)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush and write the footer; the file is valid afterwards."""
        self._rec.disconnect()

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

    def log_frame(self, frame: Frame, result: FrameResult) -> None:
        """Log everything about one frame on the `frame` timeline (and `time`, when known)."""
        rec = self._rec
        rec.set_time("frame", sequence=frame.index)
        if frame.timestamp is not None:
            rec.set_time("time", duration=frame.timestamp)
        pose = result.T_world_cam
        rec.log("/world/camera", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        ok, jpeg = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, self._jpeg_quality])
        if ok:
            rec.log("/world/camera/image", rr.EncodedImage(contents=jpeg.tobytes(), media_type="image/jpeg"))
        rec.log(
            "/world/camera/image/corners",
            rr.Points2D(result.new_corners, radii=2.0, colors=(255, 255, 0)),
            rr.AnyValues(track_id=result.new_corner_ids),
        )
        reached = result.track_fate != TrackFate.LOST
        rec.log(
            "/world/camera/image/flow",
            rr.Arrows2D(
                origins=result.track_prev[reached],
                vectors=result.track_cur[reached] - result.track_prev[reached],
                class_ids=result.track_fate[reached],
                radii=0.6,
            ),
            rr.AnyValues(track_id=result.track_ids[reached], age=result.track_age[reached]),
        )
        self._log_geometry(result)
        self._log_trajectories(result)
        self._log_metrics(result)
        if result.status == FrameStatus.HELD:
            rec.log("/events", rr.TextLog(f"frame {frame.index}: pose held ({result.reason})", level="WARN"))

    def _log_geometry(self, result: FrameResult) -> None:
        """The four candidate poses at the keyframe's pose, and the triangulated points."""
        rec = self._rec
        if result.candidate_poses and result.T_key_cur is not None:
            T_w_key = result.T_world_cam @ invert_pose(result.T_key_cur)  # noqa: N806
            length = max(float(np.linalg.norm(result.T_key_cur[:3, 3])), 0.5)
            for i, candidate in enumerate(result.candidate_poses):
                chosen = i == result.chosen_candidate
                centre = T_w_key[:3, :3] @ (length * candidate.translation) + T_w_key[:3, 3]
                rotation = T_w_key[:3, :3] @ candidate.rotation
                rec.log(
                    f"/world/candidates/{i}",
                    rr.Transform3D(translation=centre, mat3x3=rotation),
                    rr.TransformAxes3D(axis_length=0.8 if chosen else 0.4),
                    rr.Points3D([[0.0, 0.0, 0.0]], radii=0.15 if chosen else 0.08,
                                colors=CANDIDATE_COLOURS[i],
                                labels=[f"{i}: {candidate.in_front} in front" + (" (chosen)" if chosen else "")]),
                )
        rec.log("/world/points", rr.Points3D(result.points_world, radii=0.05, colors=(200, 200, 200)))

    def _log_trajectories(self, result: FrameResult) -> None:
        """One segment per frame for the estimate and the ground truth (never the whole path again)."""
        rec = self._rec
        position = result.T_world_cam[:3, 3]
        previous = self._previous_position if self._previous_position is not None else position
        rec.log("/world/trajectory/estimate", rr.LineStrips3D([[previous, position]], colors=(255, 80, 80)))
        if self._gt is not None:
            gt = self._gt[:, :3, 3]
            i = result.position
            rec.log(
                "/world/trajectory/ground_truth",
                rr.LineStrips3D([[gt[max(i - 1, 0)], gt[i]]], colors=(80, 255, 120)),
            )
        self._previous_position = position

    def _log_metrics(self, result: FrameResult) -> None:
        rec = self._rec
        counts = result.fate_counts()
        used = counts["ransac_outlier"] + counts["chirality_failed"] + counts["inlier"]
        rec.log("/metrics/tracks/alive", rr.Scalars(result.live_tracks))
        rec.log("/metrics/tracks/new_corners", rr.Scalars(len(result.new_corners)))
        rec.log("/metrics/tracks/fb_rejected", rr.Scalars(counts["fb_rejected"]))
        rec.log("/metrics/ransac/inliers", rr.Scalars(counts["inlier"]))
        rec.log("/metrics/ransac/inlier_ratio", rr.Scalars(counts["inlier"] / used if used else 0.0))
        if result.T_key_cur is not None:
            rec.log("/metrics/motion/rotation_deg", rr.Scalars(np.degrees(rotation_angle(result.T_key_cur[:3, :3]))))
            rec.log("/metrics/motion/scale", rr.Scalars(result.scale or 0.0))
        if self._gt is not None:
            gt_pose = self._gt[result.position]
            rec.log("/metrics/error/position_m",
                    rr.Scalars(float(np.linalg.norm(gt_pose[:3, 3] - result.T_world_cam[:3, 3]))))
            if result.T_key_cur is not None:
                gt_step = invert_pose(self._gt[result.keyframe_position]) @ gt_pose
                rec.log("/metrics/error/translation_direction_deg",
                        rr.Scalars(np.degrees(angle_between(gt_step[:3, 3], result.T_key_cur[:3, 3]))))


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
