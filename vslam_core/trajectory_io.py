"""Read and write trajectories: KITTI (12 numbers a line, row-major 3x4 [R|t]) and TUM
(``timestamp tx ty tz qx qy qz qw``). Poses are (N, 4, 4) camera-to-world T_w_c.

Malformed files raise `TrajectoryFormatError` naming the file and the line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from vslam_core.errors import TrajectoryFormatError

TrajectoryFormat = Literal["kitti", "tum"]

_ROTATION_TOLERANCE = 1e-3


def _rows(
    path: Path, columns: int, max_rows: int | None = None, skip_non_finite: bool = False
) -> list[tuple[int, list[float]]]:
    """Numeric rows of a whitespace-separated text file, with their 1-based line numbers.

    Blank lines and ``#`` comments are skipped. Each row must hold exactly ``columns`` numbers; a row holding
    NaN or infinity is an error, or left out with ``skip_non_finite``.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (Windows editors) is no number
    except FileNotFoundError:
        raise TrajectoryFormatError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryFormatError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    rows: list[tuple[int, list[float]]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if max_rows is not None and len(rows) >= max_rows:
            break
        fields = stripped.replace(",", " ").split()
        if len(fields) != columns:
            raise TrajectoryFormatError(
                f"{path}:{number}: expected {columns} numbers, found {len(fields)}"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise TrajectoryFormatError(f"{path}:{number}: not a number in {stripped[:60]!r}") from None
        if not all(np.isfinite(values)):
            if skip_non_finite:
                continue
            raise TrajectoryFormatError(f"{path}:{number}: non-finite value")
        rows.append((number, values))
    if not rows:
        raise TrajectoryFormatError(f"{path}: no poses in file")
    return rows


def _check_rotation(path: Path, line: int, rotation: np.ndarray) -> None:
    """A pose's 3x3 block must be a proper rotation (orthonormal, det +1) within a loose tolerance."""
    error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if error > _ROTATION_TOLERANCE or np.linalg.det(rotation) < 0:
        raise TrajectoryFormatError(f"{path}:{line}: not a rotation matrix (|RᵀR - I| = {error:.2g})")


def read_kitti_poses(path: str | Path, max_rows: int | None = None) -> np.ndarray:
    """Read a KITTI poses file: (N, 4, 4) T_w_c; ``max_rows`` keeps the first rows only."""
    path = Path(path)
    rows = _rows(path, 12, max_rows)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    for i, (line, values) in enumerate(rows):
        poses[i, :3, :] = np.asarray(values).reshape(3, 4)
        _check_rotation(path, line, poses[i, :3, :3])
    return poses


def write_kitti_poses(path: str | Path, poses: np.ndarray) -> None:
    """Write (N, 4, 4) poses as KITTI text, one row-major 3x4 matrix a line."""
    poses = np.asarray(poses, dtype=np.float64)
    Path(path).write_text("".join(kitti_line(pose) for pose in poses))


def kitti_line(pose: np.ndarray) -> str:
    """One KITTI line (with its newline): the row-major 3x4 [R|t] of a (4, 4) pose."""
    return " ".join(f"{v:.9e}" for v in np.asarray(pose, dtype=np.float64)[:3, :].reshape(-1)) + "\n"


def tum_line(stamp: float, pose: np.ndarray) -> str:
    """One TUM line (with its newline): ``timestamp tx ty tz qx qy qz qw``."""
    qx, qy, qz, qw = quaternion_from_rotation(pose[:3, :3])
    tx, ty, tz = pose[:3, 3]
    return f"{stamp:.6f} {tx:.9f} {ty:.9f} {tz:.9f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n"


def quaternion_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> unit quaternion (qx, qy, qz, qw) with qw >= 0 (Shepperd's method)."""
    m = rotation
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def rotation_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (qx, qy, qz, qw) -> (3, 3) rotation (the quaternion is normalised first)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def read_tum_poses(path: str | Path, skip_non_finite: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory: timestamps (N,) seconds and (N, 4, 4) T_w_c. ``skip_non_finite``: rows holding NaN
    (frames without a pose, as in TUM monoVO's groundtruthSync.txt) are left out instead of being an error."""
    path = Path(path)
    rows = _rows(path, 8, skip_non_finite=skip_non_finite)
    timestamps = np.empty(len(rows))
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    for i, (line, values) in enumerate(rows):
        quaternion = np.asarray(values[4:8])
        norm = np.linalg.norm(quaternion)
        if abs(norm - 1.0) > 1e-2:
            raise TrajectoryFormatError(f"{path}:{line}: quaternion is not unit length (|q| = {norm:.4g})")
        timestamps[i] = values[0]
        poses[i, :3, 3] = values[1:4]
        poses[i, :3, :3] = rotation_from_quaternion(quaternion)
    return timestamps, poses


def write_tum_poses(path: str | Path, timestamps: np.ndarray, poses: np.ndarray) -> None:
    """Write timestamps (N,) and (N, 4, 4) poses as TUM text."""
    Path(path).write_text("".join(tum_line(stamp, pose) for stamp, pose in zip(timestamps, poses, strict=True)))


def detect_format(path: str | Path) -> TrajectoryFormat:
    """Guess a trajectory file's format from the column count of its first data line."""
    path = Path(path)
    try:
        for line in path.read_text(encoding="utf-8-sig").splitlines():
            stripped = line.strip()
            if stripped and not stripped.startswith("#"):
                count = len(stripped.replace(",", " ").split())
                if count == 12:
                    return "kitti"
                if count == 8:
                    return "tum"
                raise TrajectoryFormatError(
                    f"{path}: first line has {count} columns; expected 12 (KITTI) or 8 (TUM)"
                )
    except FileNotFoundError:
        raise TrajectoryFormatError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryFormatError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    raise TrajectoryFormatError(f"{path}: no poses in file")
