"""Which estimated pose goes with which ground-truth pose, for `vslam eval --trajectory`.

By timestamp (nearest ground-truth time within a tolerance) whenever both sides have times: a TUM file
carries its own, a KITTI ground-truth file gets them from the sequence's ``times.txt`` (`--gt-times`).
Row by row (row i of both files is frame i) only when the two files have the same length, or when asked
(``--match rows``): a trajectory with dropped frames matched row by row compares every pose after the
gap with the wrong frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
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
    """How the rows were paired: `method` ``"timestamp"``, ``"rows"`` or ``"frame"`` (each row's source frame
    known: `--frames`, a recording's frame timeline, a `vslam.log` TUM header), `matched` pairs out of
    `estimate_rows` estimated and `gt_rows` ground-truth poses; `tolerance_ms` for timestamps."""

    method: str
    matched: int
    estimate_rows: int
    gt_rows: int
    tolerance_ms: float | None = None
    #: the estimate's row numbers that were kept, in order (the recording's `frame` timeline)
    rows: tuple[int, ...] = field(default=(), compare=False, repr=False)
    #: the ground-truth row paired with each kept row (row i of a KITTI poses file is frame i)
    truth_rows: tuple[int, ...] = field(default=(), compare=False, repr=False)
    #: how the source frames were known (``--frames 50:150``, ``its recording's frame timeline``), or the clock
    #: of the timestamps when it was not the ground truth's own (``times since frame 50``, ``--time-offset 5``)
    how: str = ""
    note: str = ""  # a doubt worth saying (times that may be on another clock)

    def describe(self) -> str:
        """``matched by timestamp: 290 of 300 rows, tolerance 10 ms`` / ``matched row by row: 300 rows`` /
        ``matched by frame (--frames 50:150): 100 rows, ground-truth rows 50..149``."""
        if self.method == "timestamp":
            text = (f"matched by timestamp: {self.matched} of {self.estimate_rows} rows, "
                    f"tolerance {self.tolerance_ms:g} ms")
            if self.how:
                text += f" ({self.how}), ground-truth rows {_span(self.truth_rows)}"
        elif self.method == "frame":
            text = f"matched by frame ({self.how}): {self.matched} rows, ground-truth rows {_span(self.truth_rows)}"
        else:
            text = f"matched row by row: {self.matched} rows"
        return text + (f"; {self.note}" if self.note else "")

    def as_json(self) -> dict[str, Any]:
        return {"method": self.method, "matched": self.matched, "estimate_rows": self.estimate_rows,
                "gt_rows": self.gt_rows, "tolerance_ms": self.tolerance_ms,
                "ground_truth_rows": _span(self.truth_rows) if self.truth_rows else None, "text": self.describe()}


def _span(rows: tuple[int, ...]) -> str:
    """``50..149`` (or ``50..149, 98 rows`` when some are missing)."""
    if not rows:
        return "none"
    text = f"{min(rows)}..{max(rows)}"
    return text if len(rows) == max(rows) - min(rows) + 1 else f"{text}, {len(rows)} rows"


@dataclass(frozen=True)
class Window:
    """Which source frames an estimate holds, as the user or the file says: `frames` (the rows of a row-indexed
    ground truth, KITTI poses: row i = frame i), `exact` when row i of the estimate IS frames[i] (a recording's
    frame timeline, a `vslam.log` header) rather than a window it lies in (``--frames A:B``), `how` for the
    messages; `time_offset` seconds to add to the estimate's times (``--time-offset``)."""

    frames: tuple[int, ...] | None = None
    exact: bool = False
    how: str = ""
    time_offset: float | None = None


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
    window: Window | None = None,
    gt_own_times: bool = False,
) -> tuple[np.ndarray, np.ndarray, Matching]:
    """Frame-aligned (estimate, ground truth) and how they were matched. `gt_times` may cover only the
    first rows of `gt` (a ``times.txt`` of the frames that exist); `gt_own_times`: the ground truth is TUM (its
    rows are stamps, not frames). `window`: the frames the estimate holds, or a shift of its clock (see
    `match_window`). Raises `TrajectoryFormatError`."""
    have_times = est_times is not None and gt_times is not None
    if mode is MatchMode.timestamps and not have_times:
        missing = names[0] if est_times is None else names[1]
        raise TrajectoryFormatError(
            f"--match timestamps: {missing} has no timestamps (TUM files have them; give a KITTI ground truth "
            "its times.txt with --gt-times)")
    if window is not None and (window.frames is not None or window.time_offset is not None) \
            and not (gt_own_times and window.exact and window.time_offset is None):
        return match_window(est_times, est, gt_times, gt, names, mode, tolerance_ms, window, gt_own_times)
    if have_times and mode is not MatchMode.rows:
        assert est_times is not None and gt_times is not None
        est_m, gt_m, matching = _by_timestamp(est_times, est, gt_times, gt[: len(gt_times)], names, tolerance_ms)
        if len(est) < len(gt_times) and abs(est_times[0] - gt_times[0]) * 1000.0 <= tolerance_ms \
                and abs(gt_times[0]) * 1000.0 <= tolerance_ms:  # times from 0: since the sequence's start, or
            # since the estimate's own first frame? (a window of frames 50..149 would be paired with rows 0..99)
            matching = replace(matching, note=f"ground-truth rows {_span(matching.truth_rows)}: its times are taken "
                               "on the ground truth's clock; if they count from a later first frame, give --frames "
                               "A:B")
        return est_m, gt_m, matching
    if len(est) != len(gt):
        how = ("give the ground truth's timestamps with --gt-times (the sequence's times.txt)" if est_times is not None
               else "give the estimate as TUM (with timestamps) and --gt-times")
        asked = " with --match rows" if mode is MatchMode.rows else ""
        raise TrajectoryFormatError(
            f"{names[0]} has {len(est)} poses and {names[1]} {len(gt)}{asked}, and no way to tell which ground-truth "
            f"rows they are: --frames A:B (row i of the estimate is frame A+i, e.g. --frames 0:{len(est)}), or "
            f"{how}")
    n = len(est)
    return est, gt, Matching("rows", n, len(est), len(gt), rows=tuple(range(n)), truth_rows=tuple(range(n)))


def match_window(
    est_times: np.ndarray | None, est: np.ndarray, gt_times: np.ndarray | None, gt: np.ndarray,
    names: tuple[Path, Path], mode: MatchMode, tolerance_ms: float, window: Window, gt_own_times: bool,
) -> tuple[np.ndarray, np.ndarray, Matching]:
    """An estimate of known source frames (`window.frames`) or on a stated clock (`window.time_offset`):
    by frame when row i is known to be frames[i] (or asked, ``--match rows``: the counts must agree), else by
    timestamp among the window's ground-truth rows, the estimate's clock being the ground truth's, the times
    since the window's first frame, or shifted by ``--time-offset``. Raises `TrajectoryFormatError`."""
    estimate, truth = names
    frames = window.frames
    if frames is not None and gt_own_times and window.exact:
        frames = None  # a recording's (or header's) frames are not rows of a TUM ground truth: by time only
    if frames is not None:
        if gt_own_times:
            raise TrajectoryFormatError(
                f"{window.how}: {truth} is a TUM ground truth (rows are stamps, not frames): pair by timestamp, "
                "with --time-offset SECONDS when the estimate's clock differs")
        if max(frames) >= len(gt):
            raise TrajectoryFormatError(f"{window.how} reaches frame {max(frames)}: {truth} has rows 0..{len(gt) - 1}")
    have_times = est_times is not None and gt_times is not None
    by_frame = frames is not None and window.time_offset is None and (
        mode is MatchMode.rows or (mode is MatchMode.auto and (window.exact or not have_times)))
    if by_frame:
        assert frames is not None
        if len(frames) != len(est):
            raise TrajectoryFormatError(
                f"{estimate} has {len(est)} poses but {window.how} is {len(frames)} frames: row i must be the i-th "
                "frame" + ("; a trajectory with dropped frames needs timestamps (TUM, and --gt-times)"
                           if not have_times else "; without --match rows its timestamps pair the rows"))
        picked = np.asarray(frames, np.int64)
        return est, gt[picked], Matching("frame", len(est), len(est), len(gt), rows=tuple(range(len(est))),
                                         truth_rows=tuple(int(f) for f in picked), how=window.how)
    if est_times is None or gt_times is None:
        missing = estimate if est_times is None else truth
        raise TrajectoryFormatError(f"--time-offset shifts timestamps: {missing} has none (TUM files have them; a "
                                    "KITTI ground truth its times.txt, --gt-times)")
    if mode is MatchMode.rows:
        raise TrajectoryFormatError("--time-offset pairs rows by timestamp: not with --match rows")
    low, high = (min(frames), max(frames) + 1) if frames is not None else (0, len(gt_times))
    if low >= len(gt_times):
        raise TrajectoryFormatError(f"{window.how}: the ground truth's times cover rows 0..{len(gt_times) - 1} only")
    offset, clock = _clock(est_times, gt_times, low, window, estimate, tolerance_ms)
    est_m, gt_m, matching = _by_timestamp(est_times + offset, est, gt_times[low:high], gt[low:high], names,
                                          tolerance_ms)
    return est_m, gt_m, replace(matching, truth_rows=tuple(low + r for r in matching.truth_rows), how=clock)


def _clock(est_times: np.ndarray, gt_times: np.ndarray, low: int, window: Window, estimate: Path,
           tolerance_ms: float) -> tuple[float, str]:
    """Seconds to add to the estimate's times and the clock they were on: ``--time-offset``, else the ground
    truth's own when its first time is frame `low`'s, else times since frame `low` when it is 0; refused when
    neither (a guess would pair every row with the wrong frame)."""
    if window.time_offset is not None:
        return window.time_offset, f"--time-offset {window.time_offset:g} s"
    first, start = float(est_times[0]), float(gt_times[low])
    if abs(first - start) * 1000.0 <= tolerance_ms:
        return 0.0, f"{window.how}, times on the ground truth's clock"
    if abs(first) * 1000.0 <= tolerance_ms:
        return start, f"{window.how}, times since frame {low}"
    raise TrajectoryFormatError(
        f"{estimate}: its times start at {first:.6f} s, neither frame {low}'s time on the ground truth's clock "
        f"({start:.6f} s) nor 0 (times since frame {low}): give --time-offset SECONDS (added to its times)")


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
            f"(need {MIN_MATCHES}; is it the right sequence, or its times on another clock: --time-offset?)")
    return est[close], gt[pick[close]], Matching("timestamp", matched, len(est), len(gt), tolerance_ms,
                                                 tuple(int(i) for i in np.flatnonzero(close)),
                                                 tuple(int(i) for i in pick[close]))


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
