"""The camera poses of a recording by frame (`/world/camera`, docs/recording-schema.md), whichever rotation the
schema allows it was logged with: ``mat3x3``, ``quaternion`` or ``rotation_axis_angle``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vslam.rrd.read import read_entity
from vslam_core.trajectory.io import rotation_from_quaternion


@dataclass(frozen=True)
class CameraPoses:
    """frames: (N,) the ``frame`` timeline, increasing; poses: (N, 4, 4) T_world_cam as logged; times: (N,)
    seconds on the ``time`` timeline (since the start, or Unix time), None when the recording has none."""

    frames: np.ndarray
    poses: np.ndarray
    times: np.ndarray | None


def camera_poses(path: Path, prefix: str = "") -> CameraPoses:
    """Every `{prefix}/world/camera` pose by frame (rows without a translation left out; a row without a rotation
    has the world's orientation, as a bare position logged with the plain SDK)."""
    camera = read_entity(path, f"{prefix}/world/camera")
    if camera.is_empty() or "frame" not in camera.columns or "Transform3D:translation" not in camera.columns:
        return CameraPoses(np.zeros(0, np.int64), np.zeros((0, 4, 4)), None)
    columns = {name: camera[name].to_list() if name in camera.columns else [None] * len(camera)
               for name in ("Transform3D:translation", "Transform3D:mat3x3", "Transform3D:quaternion",
                            "Transform3D:rotation_axis_angle")}
    seconds = _seconds(camera)
    frames, poses, times = [], [], []
    for row, frame in enumerate(camera["frame"].to_list()):
        translation = _first(columns["Transform3D:translation"][row])
        if frame is None or translation is None:
            continue
        pose = np.eye(4)
        pose[:3, 3] = np.asarray(translation, np.float64).reshape(3)
        pose[:3, :3] = _rotation(columns["Transform3D:mat3x3"][row], columns["Transform3D:quaternion"][row],
                                 columns["Transform3D:rotation_axis_angle"][row])
        frames.append(int(frame))
        poses.append(pose)
        times.append(seconds[row] if seconds is not None else np.nan)
    order = np.argsort(frames, kind="stable")
    return CameraPoses(np.asarray(frames, np.int64)[order], np.asarray(poses, np.float64).reshape(-1, 4, 4)[order],
                       np.asarray(times, np.float64)[order] if seconds is not None else None)


def _first(value: Any) -> Any:
    """A one-instance component's value (the reader gives a list of instances)."""
    if isinstance(value, list):
        return value[0] if value else None
    return value


def _rotation(matrix: Any, quaternion: Any, axis_angle: Any) -> np.ndarray:
    """(3, 3) rotation of one row (identity without one). Rerun's Mat3x3 is column-major; quaternions xyzw."""
    if (m := _first(matrix)) is not None:
        return np.asarray(m, np.float64).reshape(3, 3).T
    if (q := _first(quaternion)) is not None:
        xyzw = np.asarray(q, np.float64).reshape(4)
        return rotation_from_quaternion(xyzw / np.linalg.norm(xyzw))
    if (a := _first(axis_angle)) is not None:
        axis = np.asarray(a["axis"], np.float64).reshape(3)
        vector = axis / np.linalg.norm(axis) * float(a["angle"])
        import cv2  # here: only a recording logged with axis-angle rotations needs it

        return np.asarray(cv2.Rodrigues(vector)[0], np.float64)
    return np.eye(3)


def _seconds(table: Any) -> list[float] | None:
    """The ``time`` timeline in seconds (a duration since the start, or a timestamp as Unix time), None without."""
    if "time" not in table.columns:
        return None
    column = table["time"]
    if str(column.dtype).startswith("Duration"):
        return [np.nan if v is None else v / 1e6 for v in column.dt.total_microseconds().to_list()]
    if column.dtype.is_temporal():
        return [np.nan if v is None else v / 1e6 for v in column.dt.epoch("us").to_list()]
    return [np.nan if v is None else float(v) for v in column.to_list()]
