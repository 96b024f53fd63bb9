"""What a `vslam eval --trajectory` file holds: its poses, its times and, when it says, the source frame of
every row (docs/evaluation.md, "Windows").

- A KITTI or TUM text file. A TUM file written by `vslam.log.FrameLog(trajectory=…)` starts with a comment
  naming the frames of its rows (`FRAMES_HEADER`, e.g. ``# vslam frames: 50:150``; TUM readers skip comments).
  A KITTI file has no room for one (the KITTI devkit reads numbers only): give ``--frames A:B``.
- A `.rrd` recording (any that `vslam check` accepts): the poses of `/world/camera` by frame, the times of its
  ``time`` timeline: the recording's frame timeline is the source's frame index, so its rows are paired with
  those ground-truth rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam.evaluation.matching import Window
from vslam.runs import FRAMES_HEADER
from vslam_core.errors import TrajectoryFormatError
from vslam_core.sources.base import describe_indices
from vslam_core.trajectory.io import TrajectoryFormat, detect_format, read_kitti_poses, read_tum_poses

#: The start of every .rrd (Rerun's file header).
RRD_MAGIC = b"RRF2"


@dataclass(frozen=True)
class Estimate:
    """times: (N,) seconds or None; poses: (N, 4, 4) T_world_cam; window: the source frames of its rows when the
    file says (a recording, a `vslam.log` header), else None."""

    times: np.ndarray | None
    poses: np.ndarray
    window: Window | None = None


def load_estimate(path: Path, fmt: TrajectoryFormat | None) -> Estimate:
    """The estimate of a trajectory file or recording (see the module docstring). Raises
    `TrajectoryFormatError` (or `RecordingError` for a recording) in one line."""
    if is_recording(path):
        return _from_recording(path)
    fmt = fmt or detect_format(path)
    if fmt == "tum":
        times, poses = read_tum_poses(path)
        frames = header_frames(path)
        if frames is not None and len(frames) != len(poses):
            raise TrajectoryFormatError(f"{path}: its header names {len(frames)} frames for {len(poses)} rows")
        window = Window(tuple(frames), exact=True, how=f"its header: frames {describe_indices(frames)}") \
            if frames is not None else None
        return Estimate(times, poses, window)
    return Estimate(None, read_kitti_poses(path))


def is_recording(path: Path) -> bool:
    """A Rerun recording (by its magic bytes, whatever its name), not a text trajectory."""
    try:
        with path.open("rb") as file:
            return file.read(4) == RRD_MAGIC
    except OSError:
        return False


def _from_recording(path: Path) -> Estimate:
    from vslam.rrd import RecordingError, camera_poses, check_recording, comparison_prefixes

    result = check_recording(path)
    if not result.conforms:
        raise RecordingError(f"{path}: does not conform to the recording schema: {result.problems[0].line()} "
                             f"(vslam check {path})")
    camera = camera_poses(path)
    if not len(camera.frames) and (runs := comparison_prefixes(path)):
        raise RecordingError(f"{path}: a vslam compare output of {len(runs)} runs ({', '.join(runs)}): give one "
                             "run's own recording")
    if len(camera.frames) < 2:
        raise RecordingError(f"{path}: {len(camera.frames)} camera pose(s): nothing to score")
    frames = [int(f) for f in camera.frames]
    times = camera.times if camera.times is not None and np.isfinite(camera.times).all() else None
    return Estimate(times, camera.poses,
                    Window(tuple(frames), exact=True, how=f"its recording's frames {describe_indices(frames)}"))


def header_frames(path: Path) -> list[int] | None:
    """The frames named by a `FRAMES_HEADER` first line, or None without one."""
    try:
        with path.open(encoding="utf-8-sig") as file:
            first = file.readline().strip()
    except (OSError, UnicodeDecodeError):
        return None
    if not first.startswith(FRAMES_HEADER.strip()):
        return None
    spec = first.removeprefix(FRAMES_HEADER.strip()).strip()
    try:
        if "," in spec or ":" not in spec:
            return [int(v) for v in spec.split(",") if v.strip()]
        parts = [int(v) for v in spec.split(":")]
        return list(range(parts[0], parts[1], parts[2] if len(parts) > 2 else 1))
    except (ValueError, IndexError):
        raise TrajectoryFormatError(f"{path}:1: {first!r}: expected {FRAMES_HEADER}START:END[:STEP] or a "
                                    "comma-separated list of frames") from None
