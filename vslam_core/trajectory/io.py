"""Read and write trajectories: KITTI (12 numbers a line, row-major 3x4 [R|t]) and TUM
(``timestamp tx ty tz qx qy qz qw``). Poses are (N, 4, 4) camera-to-world T_w_c.

Malformed files raise `TrajectoryFormatError` naming the file and the line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from vslam_core.errors import TrajectoryFormatError

TrajectoryFormat = Literal["kitti", "tum"]

_ROTATION_TOLERANCE = 1e-3
#: No road vehicle moves faster: a ground-truth step that needs more is a broken row (a jump), not motion.
MAX_GROUND_TRUTH_SPEED_M_S = 100.0
#: The time between two rows assumed when neither the file nor the frames have a clock: one row a second, the
#: slowest frame rate a driving log has (so a real file at any frame rate passes; 100 m per row at most).
UNTIMED_ROW_S = 1.0
#: Rows closer in time than this are allowed the step of this much time (repeated or rounded stamps).
MIN_ROW_INTERVAL_S = 0.01
#: A row this far (metres) from both neighbours, and `SPIKE_RATIO` times further than they are from each other, is
#: a broken row whatever the clock: the camera cannot leave its path and come back between two frames.
SPIKE_MIN_M = 5.0
SPIKE_RATIO = 4.0


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


def _check_rotations(path: Path, lines: list[int], rotations: np.ndarray) -> None:
    """Each pose's (N, 3, 3) block must be a proper rotation (orthonormal, det +1) within a loose tolerance; the
    first that is not is reported by its file line."""
    errors = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((errors > _ROTATION_TOLERANCE) | (np.linalg.det(rotations) < 0))
    if len(bad):
        raise TrajectoryFormatError(f"{path}:{lines[bad[0]]}: not a rotation matrix (|RᵀR - I| = "
                                    f"{errors[bad[0]]:.2g})")


def read_kitti_poses(path: str | Path, max_rows: int | None = None) -> np.ndarray:
    """Read a KITTI poses file: (N, 4, 4) T_w_c; ``max_rows`` keeps the first rows only."""
    path = Path(path)
    rows = _rows(path, 12, max_rows)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = np.array([values for _, values in rows], dtype=np.float64).reshape(-1, 3, 4)
    _check_rotations(path, [line for line, _ in rows], poses[:, :3, :3])
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



@dataclass(frozen=True)
class GroundTruthJump:
    """A ground-truth row that cannot be a camera's motion: `row` (0-based) is `metres` from the row before,
    `seconds` after it; `spike`: it is that far from the row after too, whose distance to the row before is
    `across` metres."""

    row: int
    metres: float
    seconds: float
    spike: bool = False
    across: float = 0.0


def first_jump(positions: np.ndarray, row_seconds: np.ndarray | None = None) -> GroundTruthJump | None:
    """The first implausible row of a ground truth, or None. positions: (N, 3) camera positions in metres;
    row_seconds: (N,) time of each row (None: `UNTIMED_ROW_S` apart). A row is implausible when reaching it needs
    more than `MAX_GROUND_TRUTH_SPEED_M_S` over the time since the row before (at least `MIN_ROW_INTERVAL_S`), or
    when it is a spike: at least `SPIKE_MIN_M` from both neighbours and `SPIKE_RATIO` times their distance to each
    other (one row off the path, at any frame rate)."""
    positions = np.asarray(positions, np.float64)
    if len(positions) < 2:
        return None
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    if row_seconds is None:
        seconds = np.full(len(steps), UNTIMED_ROW_S)
    else:
        seconds = np.maximum(np.abs(np.diff(np.asarray(row_seconds, np.float64))), MIN_ROW_INTERVAL_S)
    too_fast = ~(steps <= MAX_GROUND_TRUTH_SPEED_M_S * seconds)  # NaN counts as too fast
    across = np.linalg.norm(positions[2:] - positions[:-2], axis=1)
    nearer = np.minimum(steps[:-1], steps[1:])
    spike = (nearer > SPIKE_MIN_M) & (nearer > SPIKE_RATIO * across)
    rows = [int(np.argmax(too_fast)) + 1 if too_fast.any() else len(positions),
            int(np.argmax(spike)) + 1 if spike.any() else len(positions)]
    row = min(rows)
    if row == len(positions):
        return None
    is_spike = row == rows[1] and row != rows[0]
    return GroundTruthJump(row, float(steps[row - 1]), float(seconds[row - 1]), is_spike,
                           float(across[row - 1]) if is_spike else 0.0)


def check_ground_truth_steps(path: str | Path, poses: np.ndarray, row_seconds: np.ndarray | None = None,
                             skip_non_finite: bool = False, lines: list[int] | None = None) -> None:
    """`TrajectoryFormatError` naming the file's line when a ground truth read from `path` (rows as read: (N, 4, 4)
    `poses`, (N,) `row_seconds` or None) jumps (`first_jump`): one broken row would otherwise set the scale of a
    ``--scale gt`` run and every error figure. `lines`: each row's line number in the file (None: a KITTI or TUM
    file, re-read for them, `skip_non_finite` as it was read)."""
    jump = first_jump(np.asarray(poses)[:, :3, 3], row_seconds)
    if jump is None:
        return
    path = Path(path)
    if lines is None:
        columns = 12 if detect_format(path) == "kitti" else 8
        lines = [line for line, _ in _rows(path, columns, max_rows=jump.row + 2, skip_non_finite=skip_non_finite)]
    line, before = lines[jump.row], lines[jump.row - 1]
    if jump.spike:
        why = (f"lies {jump.metres:.3g} m off the path: lines {before} and {lines[jump.row + 1]} around it are "
               f"{jump.across:.3g} m apart")
    else:
        clock = "" if row_seconds is not None else f", {UNTIMED_ROW_S:g} s assumed between rows"
        why = (f"jumps {jump.metres:.3g} m from line {before} in {jump.seconds:.3g} s ({jump.metres / jump.seconds:.3g}"
               f" m/s{clock}; no car moves faster than {MAX_GROUND_TRUTH_SPEED_M_S:g} m/s)")
    raise TrajectoryFormatError(f"{path}:{line}: ground truth {why}: a broken row? fix or remove it")
