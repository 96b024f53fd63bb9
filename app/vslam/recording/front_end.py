"""The front end's per-frame entities that are pure functions of one frame's result: the tracks, the four
candidate poses, the road under the camera (``--scale height``, and the outline of its plane: `road_outline`)
and the frame's events (`Recorder.log_frame` calls them)."""

from __future__ import annotations

import numpy as np
import rerun as rr

from vslam.recording.columns import ColumnBuffer, Part, add_event
from vslam_core.geometry import invert_pose
from vslam_core.lens import distort_pixels
from vslam_core.results import FrameResult, FrameStatus, HealthStatus, Reason, TrackFate
from vslam_core.sources.base import CameraIntrinsics, Frame

#: Flow arrows are recorded to 1/FLOW_STEPS of a pixel: both ends within 1/4 px of the tracked positions, which
#: no view shows (a KITTI frame is drawn at about half size), and the file's LZ4 then packs them into 19 % fewer
#: bytes than at 1/8 px (7.9 → 6.4 KB a frame, KITTI 05 frames 0:300; docs/recordings.md).
FLOW_STEPS = 2


def log_tracks(columns: ColumnBuffer, frame: Frame, result: FrameResult, full: bool) -> None:
    """The frame's new corners and the flow of every track that reached it, coloured by its fate; `full`
    (--detail full): also each track's id and age."""
    corners: list[Part] = [(rr.Points2D.columns, {"positions": result.new_corners})]
    if full:
        corners.append((rr.AnyValues.columns, {"track_id": result.new_corner_ids.astype(np.uint32)}))
    columns.add("/world/camera/image/corners", frame, *corners, batch=True)
    reached = result.track_fate != TrackFate.LOST
    # both ends to 1/2 px (`FLOW_STEPS`): LZ4 packs the coarser values tighter
    prev = np.round(result.track_prev[reached] * FLOW_STEPS) / FLOW_STEPS
    cur = np.round(result.track_cur[reached] * FLOW_STEPS) / FLOW_STEPS
    flow: list[Part] = [(rr.Arrows2D.columns, {
        "origins": prev.astype(np.float32),
        "vectors": (cur - prev).astype(np.float32),
        "class_ids": result.track_fate[reached].astype(np.uint16),
    })]
    if full:
        flow.append((rr.AnyValues.columns, {"track_id": result.track_ids[reached].astype(np.uint32),
                                            "age": result.track_age[reached].astype(np.uint16)}))
    columns.add("/world/camera/image/flow", frame, *flow, batch=True)


def log_candidates(columns: ColumnBuffer, frame: Frame, result: FrameResult) -> None:
    """The four candidate poses, each at the keyframe pose moved by its (R, t): a point (the chosen one
    larger, its label listing every chirality count) and the candidate camera's axes. A frame without
    candidates logs an empty row, so the previous frame's do not linger."""
    candidates = result.candidate_poses if result.T_key_cur is not None else ()
    centres, axes = np.zeros((len(candidates), 3)), np.zeros((3 * len(candidates), 3))
    chosen = np.arange(len(candidates)) == result.chosen_candidate
    labels = [""] * len(candidates)
    if candidates:
        assert result.T_key_cur is not None
        T_w_key = result.T_world_cam @ invert_pose(result.T_key_cur)  # noqa: N806
        length = max(float(np.linalg.norm(result.T_key_cur[:3, 3])), 0.5)
        counts = ", ".join(f"#{i}: {c.in_front}" for i, c in enumerate(candidates))
        # all four at once (a frame's Python is what a recording costs the engine: docs/recordings.md)
        centres = (length * np.array([c.translation for c in candidates])) @ T_w_key[:3, :3].T + T_w_key[:3, 3]
        axes = ((T_w_key[:3, :3] @ np.array([c.rotation for c in candidates])).transpose(0, 2, 1)
                * np.where(chosen, 0.8, 0.4)[:, None, None]).reshape(-1, 3)
        # (R1, t) and (R2, t) share a centre: one label, on the chosen candidate, lists every count
        labels = [f"chosen #{i} — in front {counts}" if chosen[i] else "" for i in range(len(candidates))]
    columns.add(
        "/world/candidates", frame,
        (rr.Points3D.columns, {"positions": centres, "radii": np.where(chosen, 0.15, 0.08), "labels": labels}),
        (rr.Arrows3D.columns, {"origins": np.repeat(centres, 3, axis=0), "vectors": axes}),
        (rr.AnyValues.columns, {"in_front": np.array([c.in_front for c in candidates], np.int64),
                                "chosen": chosen}),
        batch=True,
    )


def log_road(columns: ColumnBuffer, frame: Frame, result: FrameResult, intrinsics: CameraIntrinsics,
             image: bool) -> None:
    """--scale height: the road points and plane behind this frame's step length (empty rows when the
    frame had none, so earlier ones do not linger); `image`: also the road pixels on the frame."""
    estimate = result.scale_estimate
    pose = result.T_world_cam
    points, pixels, outline = np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 5, 3))
    if estimate is not None:
        points = estimate.road_points @ pose[:3, :3].T + pose[:3, 3]
        pixels = distort_pixels(estimate.road_pixels, intrinsics)  # ideal → raw image pixels
        if estimate.plane_normal is not None and estimate.camera_height is not None:
            outline = (road_outline(estimate.plane_normal, estimate.camera_height) @ pose[:3, :3].T
                       + pose[:3, 3])[None]
    columns.add("/world/road/points", frame, (rr.Points3D.columns, {"positions": points}), batch=True)
    columns.add("/world/road/plane", frame, (rr.LineStrips3D.columns, {"strips": list(outline)}), batch=True)
    if image:
        columns.add("/world/camera/image/road", frame, (rr.Points2D.columns, {"positions": pixels}), batch=True)


def log_events(columns: ColumnBuffer, frame: Frame, result: FrameResult) -> None:
    """The frame's events: initialisation, re-detections (DEBUG), a health warning or failure."""
    def event(text: str, level: str) -> None:
        add_event(columns, frame, text, level)

    if result.status == FrameStatus.INIT:
        event(f"initialised with {len(result.new_corners)} corners", "INFO")
    elif len(result.new_corners):
        event(f"re-detected {len(result.new_corners)} corners", "DEBUG")
    health = result.health
    if health.status != HealthStatus.OK:
        what = "used"
        if result.status == FrameStatus.HELD:
            what = "dead-reckoned" if Reason.COASTED in health.reasons else "pose held"
        event(f"{health.status} ({what}): " + ", ".join(health.reasons),
              "ERROR" if health.status == HealthStatus.FAIL else "WARN")


def road_outline(normal: np.ndarray, height: float, half_width: float = 2.0, near: float = 4.0,
                 far: float = 20.0) -> np.ndarray:
    """(5, 3) closed outline of the plane nᵀ·X = height (camera frame) over x ∈ ±half_width, z ∈ [near, far]
    metres: the patch of road ahead that the plane describes."""
    corners = []
    for x, z in ((-half_width, near), (half_width, near), (half_width, far), (-half_width, far), (-half_width, near)):
        y = (height - normal[0] * x - normal[2] * z) / normal[1]
        corners.append((x, y, z))
    return np.array(corners)
