"""Which estimated pose goes with which ground-truth pose, for `vslam eval --trajectory`.

By timestamp (nearest ground-truth time within a tolerance) whenever both sides have times: a TUM file
carries its own, a KITTI ground-truth file gets them from the sequence's ``times.txt`` (`--gt-times`).
Row by row (row i of both files is frame i) only when the two files have the same length, or when asked
(``--match rows``): a trajectory with dropped frames matched row by row compares every pose after the
gap with the wrong frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from vslam_core.errors import TrajectoryFormatError
from vslam_core.sources.stamps import nearest_in_time

DEFAULT_TOLERANCE_MS = 10.0
MIN_MATCHES = 3


class MatchMode(StrEnum):
    auto = "auto"  # by timestamp when both sides have times, else row by row if the lengths agree
    timestamps = "timestamps"
    rows = "rows"


@dataclass(frozen=True)
class Matching:
    """How the rows were paired: `method` ``"timestamp"`` or ``"rows"``, `matched` pairs out of
    `estimate_rows` estimated and `gt_rows` ground-truth poses; `tolerance_ms` for timestamps."""

    method: str
    matched: int
    estimate_rows: int
    gt_rows: int
    tolerance_ms: float | None = None
    #: the estimate's row numbers that were kept, in order (the recording's `frame` timeline)
    rows: tuple[int, ...] = field(default=(), compare=False, repr=False)

    def describe(self) -> str:
        """``matched by timestamp: 290 of 300 rows, tolerance 10 ms`` / ``matched row by row: 300 rows``."""
        if self.method == "timestamp":
            return (f"matched by timestamp: {self.matched} of {self.estimate_rows} rows, "
                    f"tolerance {self.tolerance_ms:g} ms")
        text = f"matched row by row: {self.matched} rows"
        if self.matched != self.estimate_rows or self.matched != self.gt_rows:
            text += f" (the estimate has {self.estimate_rows}, the ground truth {self.gt_rows}; --match rows)"
        return text

    def as_json(self) -> dict[str, Any]:
        return {"method": self.method, "matched": self.matched, "estimate_rows": self.estimate_rows,
                "gt_rows": self.gt_rows, "tolerance_ms": self.tolerance_ms, "text": self.describe()}


def gt_times_for(path: Path | None, gt_times: np.ndarray | None, gt_rows: int, gt_name: Path) -> np.ndarray | None:
    """The ground truth's timestamps: its own (TUM) or those of `path` (a KITTI ``times.txt``, line i = pose
    row i; it may hold fewer lines than the poses file has rows, not more)."""
    if path is None:
        return gt_times
    if gt_times is not None:
        raise TrajectoryFormatError(f"--gt-times {path}: {gt_name} is a TUM file with its own timestamps")
    if not path.is_file():
        raise TrajectoryFormatError(f"--gt-times {path}: file not found")
    lines = [line for line in path.read_text(errors="replace").splitlines()
             if line.strip() and not line.strip().startswith("#")]
    if len(lines) > gt_rows:
        raise TrajectoryFormatError(f"--gt-times {path}: {len(lines)} timestamps but {gt_name} has only "
                                    f"{gt_rows} poses (line i of times.txt is pose row i)")
    from vslam_core.sources.kitti import read_times  # here: the KITTI reader loads OpenCV (the CLI imports this)

    return np.asarray(read_times(path, len(lines)), dtype=np.float64)


def match_poses(
    est_times: np.ndarray | None,
    est: np.ndarray,
    gt_times: np.ndarray | None,
    gt: np.ndarray,
    names: tuple[Path, Path],
    mode: MatchMode = MatchMode.auto,
    tolerance_ms: float = DEFAULT_TOLERANCE_MS,
) -> tuple[np.ndarray, np.ndarray, Matching]:
    """Frame-aligned (estimate, ground truth) and how they were matched. `gt_times` may cover only the
    first rows of `gt` (a ``times.txt`` of the frames that exist). Raises `TrajectoryFormatError`."""
    have_times = est_times is not None and gt_times is not None
    if mode is MatchMode.timestamps and not have_times:
        missing = names[0] if est_times is None else names[1]
        raise TrajectoryFormatError(
            f"--match timestamps: {missing} has no timestamps (TUM files have them; give a KITTI ground truth "
            "its times.txt with --gt-times)")
    if have_times and mode is not MatchMode.rows:
        assert est_times is not None and gt_times is not None
        return _by_timestamp(est_times, est, gt_times, gt[: len(gt_times)], names, tolerance_ms)
    if len(est) != len(gt) and mode is not MatchMode.rows:
        how = ("give the ground truth's timestamps with --gt-times (the sequence's times.txt)" if est_times is not None
               else "give the estimate as TUM (with timestamps) and --gt-times")
        raise TrajectoryFormatError(
            f"{names[0]} has {len(est)} poses and {names[1]} {len(gt)}, and no timestamps on both sides to match "
            f"them by: {how}, or --match rows if row i of both files is the same frame")
    n = min(len(est), len(gt))
    return est[:n], gt[:n], Matching("rows", n, len(est), len(gt), rows=tuple(range(n)))


def _by_timestamp(
    est_times: np.ndarray, est: np.ndarray, gt_times: np.ndarray, gt: np.ndarray, names: tuple[Path, Path],
    tolerance_ms: float,
) -> tuple[np.ndarray, np.ndarray, Matching]:
    """Each estimated pose with the ground-truth pose nearest in time, if within `tolerance_ms`."""
    if len(gt_times) == 0:
        raise TrajectoryFormatError(f"{names[1]}: no timestamps to match by")
    pick, close = nearest_in_time(est_times, gt_times, tolerance_ms / 1000.0)
    matched = int(close.sum())
    if matched < MIN_MATCHES:
        raise TrajectoryFormatError(
            f"{names[0]}: only {matched} of {len(est)} timestamps match {names[1]} within {tolerance_ms:g} ms "
            f"(need {MIN_MATCHES}; is it the right sequence?)")
    return est[close], gt[pick[close]], Matching("timestamp", matched, len(est), len(gt), tolerance_ms,
                                                 tuple(int(i) for i in np.flatnonzero(close)))


def match_images(
    rows: tuple[int, ...],
    total_rows: int,
    est_times: np.ndarray | None,
    image_times: np.ndarray | None,
    image_count: int,
    names: tuple[Path, Path],
    mode: MatchMode = MatchMode.auto,
    tolerance_ms: float = DEFAULT_TOLERANCE_MS,
) -> tuple[np.ndarray, str]:
    """The image of each kept estimate row (`rows`: row numbers of the file `names[0]`, of `total_rows` rows,
    whose (total_rows,) `est_times` are None without times) among the `image_count` images of `names[1]`, and
    how they were paired. The same rule as the ground truth: by timestamp when both sides have times (every
    kept row needs an image within `tolerance_ms`), else row i is image i (the folder needs an image for every
    row of the file). Raises `TrajectoryFormatError` in one line."""
    estimate, images = names
    by_time = est_times is not None and image_times is not None and mode is not MatchMode.rows
    if mode is MatchMode.timestamps and not by_time:
        missing = estimate if est_times is None else images
        raise TrajectoryFormatError(f"--match timestamps: {missing} has no timestamps to match the images by")
    kept = np.asarray(rows, np.int64)
    if by_time:
        assert est_times is not None and image_times is not None
        pick, close = nearest_in_time(est_times[kept], image_times, tolerance_ms / 1000.0)
        if not close.all():
            first = int(kept[np.argmin(close)])
            raise TrajectoryFormatError(
                f"--images {images}: {int((~close).sum())} of {len(kept)} rows of {estimate} have no image within "
                f"{tolerance_ms:g} ms (first: row {first} at {est_times[first]:.6f} s; the images span "
                f"{np.min(image_times):.6f}–{np.max(image_times):.6f} s)")
        return pick, f"images matched by timestamp: {len(kept)} rows, tolerance {tolerance_ms:g} ms"
    total = total_rows
    if image_count < total:
        raise TrajectoryFormatError(
            f"--images {images}: {image_count} images for the {total} rows of {estimate} (row i is image i"
            + ("" if est_times is not None else "; a TUM trajectory is matched to timed images by timestamp")
            + ")")
    return kept, f"images row by row: row i is image i ({len(kept)} rows)"
