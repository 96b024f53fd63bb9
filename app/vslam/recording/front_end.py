"""The front end's per-frame entities, pure functions of the frames' results: the tracks and the four candidate
poses (drawn for the frames since the recorder's last flush together), the road under the camera (``--scale
height``, and the outline of its plane: `road_outline`) and the frame's events (`Recorder.log_frame` calls them)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from vslam.recording.columns import ColumnBuffer, Part, add_event, kept_per_row
from vslam_core.geometry import invert_pose
from vslam_core.lens import distort_pixels
from vslam_core.results import FrameResult, FrameStatus, HealthStatus, Reason, TrackFate
from vslam_core.sources.base import CameraIntrinsics, Frame

#: Flow arrows are recorded to 1/FLOW_STEPS of a pixel: both ends within 1/4 px of the tracked positions, which
#: no view shows (a KITTI frame is drawn at about half size), and the file's LZ4 then packs them into 19 % fewer
#: bytes than at 1/8 px (7.9 → 6.4 KB a frame, KITTI 05 frames 0:300; docs/recordings.md).
FLOW_STEPS = 2


def log_tracks(columns: ColumnBuffer, frames: Sequence[Frame], results: Sequence[FrameResult], full: bool) -> None:
    """The frames' new corners and the flow of every track that reached each, coloured by its fate; `full`
    (--detail full): also each track's id and age. Built for the frames of a flush together (a frame at a time
    this was ~0.1 ms of the recording thread's Python a frame, which holds the engine back: docs/recordings.md)."""
    if not results:
        return
    corners: list[Part] = [(rr.Points2D.columns, {"positions": _joined([r.new_corners for r in results])})]
    if full:
        corners.append((rr.AnyValues.columns, {
            "track_id": _joined([r.new_corner_ids for r in results]).astype(np.uint32)}))
    corner_counts = [len(r.new_corners) for r in results]
    columns.add_rows("/world/camera/image/corners", frames, *corners, lengths=[corner_counts] * len(corners))
    fate = _joined([r.track_fate for r in results])
    reached = fate != TrackFate.LOST
    # both ends to 1/2 px (`FLOW_STEPS`): LZ4 packs the coarser values tighter
    prev = np.round(_joined([r.track_prev for r in results])[reached] * FLOW_STEPS) / FLOW_STEPS
    cur = np.round(_joined([r.track_cur for r in results])[reached] * FLOW_STEPS) / FLOW_STEPS
    flow: list[Part] = [(rr.Arrows2D.columns, {
        "origins": prev.astype(np.float32),
        "vectors": (cur - prev).astype(np.float32),
        "class_ids": fate[reached].astype(np.uint16),
    })]
    if full:
        flow.append((rr.AnyValues.columns, {
            "track_id": _joined([r.track_ids for r in results])[reached].astype(np.uint32),
            "age": _joined([r.track_age for r in results])[reached].astype(np.uint16)}))
    arrows = kept_per_row([len(r.track_fate) for r in results], reached)
    columns.add_rows("/world/camera/image/flow", frames, *flow, lengths=[arrows] * len(flow))


def log_candidates(columns: ColumnBuffer, frames: Sequence[Frame], results: Sequence[FrameResult]) -> None:
    """Each frame's four candidate poses, each at the keyframe pose moved by its (R, t): a point (the chosen one
    larger, its label listing every chirality count) and the candidate camera's axes. A frame without
    candidates logs an empty row, so the previous frame's do not linger. Built for the frames of a flush together
    (`log_tracks`)."""
    if not results:
        return
    placed = [r for r in results if r.T_key_cur is not None and r.candidate_poses]
    counts = [len(r.candidate_poses) if r.T_key_cur is not None else 0 for r in results]
    centres, axes = np.zeros((0, 3)), np.zeros((0, 3))
    chosen = np.concatenate([np.arange(n) == r.chosen_candidate for n, r in zip(counts, results, strict=True)])
    labels: list[str] = []
    if placed:
        T_key_cur = np.array([r.T_key_cur for r in placed])  # noqa: N806  (P, 4, 4)
        T_w_key = np.array([r.T_world_cam for r in placed]) @ invert_pose(T_key_cur)  # noqa: N806
        length = np.maximum(np.linalg.norm(T_key_cur[:, :3, 3], axis=1), 0.5)
        translations = np.array([[c.translation for c in r.candidate_poses] for r in placed])  # (P, 4, 3)
        rotations = np.array([[c.rotation for c in r.candidate_poses] for r in placed])  # (P, 4, 3, 3)
        centres = ((length[:, None, None] * translations) @ T_w_key[:, :3, :3].transpose(0, 2, 1)
                   + T_w_key[:, None, :3, 3]).reshape(-1, 3)
        scaled = np.where(chosen, 0.8, 0.4).reshape(len(placed), -1)[:, :, None, None]
        axes = ((T_w_key[:, None, :3, :3] @ rotations).transpose(0, 1, 3, 2) * scaled).reshape(-1, 3)
        for r in placed:
            # (R1, t) and (R2, t) share a centre: one label, on the chosen candidate, lists every count
            listed = ", ".join(f"#{i}: {c.in_front}" for i, c in enumerate(r.candidate_poses))
            labels += [f"chosen #{i} — in front {listed}" if i == r.chosen_candidate else ""
                       for i in range(len(r.candidate_poses))]
    in_front = np.array([c.in_front for r in placed for c in r.candidate_poses], np.int64)
    columns.add_rows(
        "/world/candidates", frames,
        (rr.Points3D.columns, {"positions": centres, "radii": np.where(chosen, 0.15, 0.08), "labels": labels}),
        (rr.Arrows3D.columns, {"origins": np.repeat(centres, 3, axis=0), "vectors": axes}),
        (rr.AnyValues.columns, {"in_front": in_front, "chosen": chosen}),
        lengths=[counts, [3 * n for n in counts], counts],
    )


def _joined(arrays: list[np.ndarray]) -> np.ndarray:
    """The frames' arrays, one after the other."""
    return np.concatenate(arrays) if len(arrays) > 1 else arrays[0]


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
