"""Timestamps of logged frames: matching ground truth to frames by time, and checking a log's stamp order."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vslam_core.errors import SourceError, TrajectoryFormatError
from vslam_core.sources.base import rebase_poses
from vslam_core.trajectory.io import check_ground_truth_steps, detect_format, read_kitti_poses, read_tum_poses

DEFAULT_GT_TOLERANCE_S = 0.010
#: Where poses are interpolated (TUM RGB-D's 100 Hz motion capture): the largest gap between the two rows
#: bracketing a frame. fr1_desk has a 50 ms gap; 100 ms of hand-held motion is still close to linear.
DEFAULT_GT_MAX_GAP_S = 0.100
#: How ground truth without a clock is paired with the frames (the run summary's ``ground truth`` line).
ROW_BY_ROW = "row by row"


def matched_by_time(frames: int, tolerance_s: float, offset_s: float = 0.0) -> str:
    """``matched by time, 200 of 200 frames, tolerance 10 ms`` (every selected frame has its pose), and
    ``, the ground truth's clock +0.100 s from the frames'`` with `--gt-time-offset`."""
    text = f"matched by time, {frames} of {frames} frames, tolerance {tolerance_s * 1000:g} ms"
    return text + (f", the ground truth's clock {offset_s:+.3f} s from the frames' (--gt-time-offset)" if offset_s
                   else "")


def nearest_in_time(query: np.ndarray, reference: np.ndarray, tolerance_s: float) -> tuple[np.ndarray, np.ndarray]:
    """For each of the (N,) `query` times, the index of the nearest of the (M,) `reference` times (any
    order) and whether it is within `tolerance_s`. Returns ((N,) int64 indices, (N,) bool close)."""
    query = np.asarray(query, np.float64)
    reference = np.asarray(reference, np.float64)
    if len(reference) == 0:
        return np.zeros(len(query), np.int64), np.zeros(len(query), bool)
    order = np.argsort(reference, kind="stable")
    ordered = reference[order]
    right = np.clip(np.searchsorted(ordered, query), 0, len(ordered) - 1)
    left = np.clip(right - 1, 0, len(ordered) - 1)
    take_left = np.abs(ordered[left] - query) <= np.abs(ordered[right] - query)
    pick = order[np.where(take_left, left, right)]
    return pick.astype(np.int64), np.abs(reference[pick] - query) <= tolerance_s


def ground_truth_at(
    frame_stamps: np.ndarray, gt_stamps: np.ndarray, gt_poses: np.ndarray, tolerance_s: float, where: str
) -> np.ndarray:
    """(N, 4, 4) ground-truth camera poses of the frames stamped (N,) `frame_stamps`, each the pose of
    the (M,) `gt_stamps` nearest in time, re-based on the first frame. Every frame must have one within
    `tolerance_s`: otherwise a `SourceError` naming the first frame without and the ground truth's span."""
    pick, close = nearest_in_time(frame_stamps, gt_stamps, tolerance_s)
    if len(gt_stamps) == 0:
        raise SourceError(f"{where}: the ground truth has no poses")
    if not close.all():
        first = int(np.argmin(close))
        raise SourceError(
            f"{where}: no ground-truth pose within {tolerance_s * 1000:g} ms of frame {first} "
            f"(stamp {frame_stamps[first]:.6f} s; the ground truth spans {np.min(gt_stamps):.6f}–"
            f"{np.max(gt_stamps):.6f} s, {int((~close).sum())} of {len(close)} frames unmatched): choose "
            "--frames inside it or widen --gt-tolerance")
    return rebase_poses(np.asarray(gt_poses, np.float64)[pick])


def interpolated_ground_truth(
    frame_stamps: np.ndarray, gt_stamps: np.ndarray, gt_poses: np.ndarray, max_gap_s: float, where: object,
    indices: list[int] | None = None,
) -> tuple[np.ndarray, str]:
    """(N, 4, 4) poses T_w_c at the (N,) `frame_stamps`, each interpolated between the two rows of the (M,)
    `gt_stamps` (M, 4, 4) `gt_poses` that bracket it (translation linearly, rotation by slerp,
    `interpolate_pose`; a frame on a row takes it), re-based on the first frame; and the matching as the run
    summary states it. A frame outside the rows' span or inside a gap wider than `max_gap_s` is a `SourceError`
    naming it and the frames that do have one (choose --frames inside them; `indices`: the frames' source
    indices, as --frames counts them, default 0..N-1)."""
    frame_stamps = np.asarray(frame_stamps, np.float64)
    order = np.argsort(gt_stamps, kind="stable")
    stamps, poses = np.asarray(gt_stamps, np.float64)[order], np.asarray(gt_poses, np.float64)[order]
    if len(stamps) == 0:
        raise SourceError(f"{where}: the ground truth has no poses")
    after = np.clip(np.searchsorted(stamps, frame_stamps, side="left"), 0, len(stamps) - 1)
    on_row = stamps[after] == frame_stamps
    before = np.where(on_row, after, np.clip(after - 1, 0, len(stamps) - 1))
    gap = stamps[after] - stamps[before]
    inside = on_row | ((stamps[before] <= frame_stamps) & (frame_stamps <= stamps[after]) & (gap <= max_gap_s))
    if not inside.all():
        number = np.arange(len(frame_stamps)) if indices is None else np.asarray(indices)
        first = int(np.argmin(inside))
        runs = ", ".join(f"{a}:{b}" for a, b in _runs(number[inside])[:4]) or "none"
        raise SourceError(
            f"{where}: {int((~inside).sum())} of {len(inside)} frames are not between two ground-truth rows at most "
            f"{max_gap_s * 1000:g} ms apart (first: frame {number[first]} at {frame_stamps[first]:.6f} s; the "
            f"ground truth spans {stamps[0]:.6f}–{stamps[-1]:.6f} s); frames {runs} are: choose --frames inside them "
            "or widen --gt-tolerance (the largest gap interpolated over)")
    fraction = np.where(gap > 0, (frame_stamps - stamps[before]) / np.where(gap > 0, gap, 1.0), 0.0)
    from vslam_core.geometry import interpolate_pose  # here: geometry loads OpenCV, which `vslam --help` never needs

    matched = np.stack([interpolate_pose(poses[b], poses[a], float(f))
                        for b, a, f in zip(before, after, fraction, strict=True)])
    farthest = np.minimum(frame_stamps - stamps[before], stamps[after] - frame_stamps)
    how = (f"matched by time, interpolated (translation linear, rotation slerp) between the rows bracketing each "
           f"frame, {len(frame_stamps)} of {len(frame_stamps)} frames, gaps up to {max_gap_s * 1000:g} ms allowed "
           f"(widest used {gap.max() * 1000:.0f} ms, farthest frame {farthest.max() * 1000:.0f} ms from a row)")
    return rebase_poses(matched), how


def read_tum_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM file of camera poses to match to frames by time: ((M,) stamps in seconds, (M, 4, 4) T_w_c), read
    with `read_tum_poses`; rows holding NaN (frames without a pose, as in TUM monoVO's groundtruthSync.txt) are
    left out. A missing or malformed file, one without any pose, or one that jumps (`check_ground_truth_steps`) is
    a `SourceError` naming it (and the line)."""
    if not path.is_file():
        raise SourceError(f"{path}: ground-truth file not found")
    try:
        stamps, poses = read_tum_poses(path, skip_non_finite=True)
        check_ground_truth_steps(path, poses, stamps, skip_non_finite=True)
        return stamps, poses
    except TrajectoryFormatError as exc:
        raise SourceError(str(exc)) from None


def _runs(indices: np.ndarray) -> list[tuple[int, int]]:
    """Sorted source indices as (START, END) runs of consecutive indices (END exclusive)."""
    if len(indices) == 0:
        return []
    breaks = np.flatnonzero(np.diff(indices) != 1)
    starts = np.concatenate([[indices[0]], indices[breaks + 1]])
    ends = np.concatenate([indices[breaks], [indices[-1]]]) + 1
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def require_ground_truth(
    frame_stamps: np.ndarray, indices: list[int], gt_stamps: np.ndarray, tolerance_s: float, label: str,
    where: object,
) -> None:
    """`SourceError` when a selected frame has no ground-truth pose within `tolerance_s`, saying which frames
    (START:END runs) do have one, so the user can choose --frames inside them (a ground truth that starts
    after the images, or covers only the start and end of a sequence, is common).

    `frame_stamps` are every frame's stamps (s, frame order), `indices` the selected ones."""
    _, close = nearest_in_time(frame_stamps, gt_stamps, tolerance_s)
    selected = close[np.asarray(indices)]
    if selected.all():
        return
    first = indices[int(np.argmin(selected))]
    span = f"the ground truth spans {np.min(gt_stamps):.3f}–{np.max(gt_stamps):.3f} s"
    runs = _runs(np.flatnonzero(close))
    if not runs:
        raise SourceError(
            f"{where}: no frame has a ground-truth pose within {tolerance_s * 1000:g} ms in {label} ({span}, "
            f"the frames {frame_stamps.min():.3f}–{frame_stamps.max():.3f} s): is it this sequence's ground truth?")
    shown = ", ".join(f"{a}:{b}" for a, b in runs[:4]) + (", …" if len(runs) > 4 else "")
    raise SourceError(
        f"{where}: {int((~selected).sum())} of the {len(indices)} selected frames have no ground-truth pose within "
        f"{tolerance_s * 1000:g} ms in {label} (first: frame {first} at {frame_stamps[first]:.3f} s; {span}); "
        f"frames {shown} have one: choose --frames inside them")


def selected_ground_truth(
    frame_stamps: np.ndarray, indices: list[int], gt_stamps: np.ndarray, gt_poses: np.ndarray, tolerance_s: float,
    label: str, where: object, offset_s: float = 0.0,
) -> np.ndarray:
    """(N, 4, 4) ground-truth camera poses of the selected frames (`indices` into every frame's `frame_stamps`),
    each the pose nearest in time, re-based on the first; a selected frame without a pose within `tolerance_s`
    is the `SourceError` of `require_ground_truth` (`label`: where the poses come from). `offset_s`
    (`--gt-time-offset`): the ground truth's clock reads this much more than the frames' at the same instant, so
    frame time t takes the pose stamped t + offset_s."""
    frame_stamps = np.asarray(frame_stamps, np.float64) + offset_s
    require_ground_truth(frame_stamps, indices, gt_stamps, tolerance_s, label, where)
    return ground_truth_at(frame_stamps[np.asarray(indices)], gt_stamps, gt_poses, tolerance_s, f"{where} ({label})")


def tum_camera_poses(gt_file: Path, frame_stamps: np.ndarray, indices: list[int], tolerance_s: float,
                     where: object, offset_s: float = 0.0) -> tuple[np.ndarray, str]:
    """A TUM file of camera poses T_w_c given as a dataset's ground truth: ((N, 4, 4) poses of the selected
    frames, matched by time and re-based, as `selected_ground_truth`), and the label the run summary shows."""
    gt_stamps, gt_poses = read_tum_ground_truth(gt_file)
    label = f"{gt_file.name} (TUM, camera poses)"
    return selected_ground_truth(frame_stamps, indices, gt_stamps, gt_poses, tolerance_s, label, where,
                                 offset_s), label


def optional_tum_camera_poses(gt_file: Path | None, frame_stamps: np.ndarray, indices: list[int],
                              tolerance_s: float, where: object, offset_s: float = 0.0
                              ) -> tuple[np.ndarray | None, str, str | None]:
    """`tum_camera_poses` of `gt_file` with how they were matched (`matched_by_time`); without a file, no poses,
    the label "none" and no matching."""
    if gt_file is None:
        return None, "none", None
    poses, label = tum_camera_poses(gt_file, frame_stamps, indices, tolerance_s, where, offset_s)
    return poses, label, matched_by_time(len(indices), tolerance_s, offset_s)


def stamp_problems(stamps: np.ndarray) -> list[str]:
    """What is wrong with a log's (N,) frame stamps in arrival order: out-of-order and duplicate stamps,
    as short notes (empty when they increase strictly)."""
    stamps = np.asarray(stamps, np.float64)
    steps = np.diff(stamps)
    notes = []
    if (backwards := int((steps < 0).sum())) > 0:
        first = int(np.argmax(steps < 0)) + 1
        notes.append(f"{backwards} frames arrived out of stamp order (first: message {first}); frames are "
                     "used in stamp order")
    if (repeated := int((steps == 0).sum()) + _duplicates_out_of_order(stamps, steps)) > 0:
        notes.append(f"{repeated} frames repeat an earlier stamp (kept in arrival order)")
    return notes


def _duplicates_out_of_order(stamps: np.ndarray, steps: np.ndarray) -> int:
    """Repeated stamps that are not next to each other in arrival order."""
    return len(stamps) - len(np.unique(stamps)) - int((steps == 0).sum())


def parse_gt_rows(text: str) -> tuple[int, int | None]:
    """``--gt-rows A:B`` (or ``A:``): the ground truth's rows A..B-1 are the frames 0.. (0-based, B excluded);
    `SourceError` in one line when malformed."""
    first, colon, last = text.strip().partition(":")
    try:
        start = int(first)
        end = int(last) if last.strip() else None
    except ValueError:
        raise SourceError(f"--gt-rows {text!r}: expected A:B (rows A to B-1 of the ground truth, 0-based)") from None
    if not colon or start < 0 or (end is not None and end <= start):
        raise SourceError(f"--gt-rows {text!r}: expected A:B with 0 <= A < B (rows A to B-1, 0-based)")
    return start, end


def associate_ground_truth(
    path: Path, fmt: str, frame_times: np.ndarray | None, count: int, indices: list[int], tolerance_s: float,
    where: object, offset_s: float = 0.0, rows: tuple[int, int | None] | None = None,
) -> tuple[np.ndarray, str]:
    """The ground truth of the selected frames of an image folder or a video, and how it was paired with them.

    `path`: a KITTI (no clock) or TUM (a stamp per pose) file, `fmt` ``kitti``, ``tum`` or ``auto`` (from the
    columns); `frame_times`: (count,) every frame's stamps in seconds (``times.txt``, a video's container
    times), or None without a clock; `indices`: the selected frames. The rule of every source:

    - both sides have times: each frame takes the pose nearest in time within `tolerance_s` (a TUM file at
      another rate than the camera, or with gaps, is paired correctly), at frame time + `offset_s`
      (``--gt-time-offset``); a frame without one is an error;
    - one side only, or neither: row i is frame i, and the file must hold a pose for every frame; when one
      side has times, it must hold exactly as many poses as there are frames (another count means the rows
      are not the frames: pairing them would give a wrong answer without a word); when neither has, a file
      with more rows than frames is refused too (the frames may be any stretch of the sequence: pairing them
      from row 0 would be a wrong answer), unless `rows` (``--gt-rows A:B``) says which rows are the frames.

    Returns ((N, 4, 4) T_w_c re-based on the first selected frame, ``matched by time, …`` or ``row by row``).
    `SourceError` (or `TrajectoryFormatError` for a malformed file) in one line, naming the file."""
    if not path.is_file():
        raise SourceError(f"{path}: ground-truth file not found")
    kind = detect_format(path) if fmt == "auto" else fmt
    if kind not in ("tum", "kitti"):
        raise SourceError(f"{path}: unknown ground-truth format {fmt!r} (kitti, tum or auto)")
    if kind == "tum" and frame_times is not None:
        gt_stamps, gt_poses = read_tum_poses(path)
        check_ground_truth_steps(path, gt_poses, gt_stamps)
        if rows is not None:
            raise SourceError(f"--gt-rows does not apply here: {path.name} is matched to the frames by time (a TUM "
                              "file and frames with times); --gt-time-offset shifts its clock")
        poses = selected_ground_truth(np.asarray(frame_times, np.float64), indices, gt_stamps, gt_poses,
                                      tolerance_s, path.name, where, offset_s)
        return poses, matched_by_time(len(indices), tolerance_s, offset_s)
    if offset_s:
        raise SourceError(f"--gt-time-offset does not apply here: {path.name} is paired with the frames row by row "
                          "(time matching needs timestamps on both sides: a TUM file and frames with a clock)")
    if kind == "tum":
        gt_stamps, gt_poses = read_tum_poses(path)
        check_ground_truth_steps(path, gt_poses, gt_stamps)
    else:
        gt_poses = read_kitti_poses(path)
        check_ground_truth_steps(path, gt_poses, None if frame_times is None or len(frame_times) != len(gt_poses)
                                 else np.asarray(frame_times, np.float64))
    if rows is not None:
        return _given_rows(path, gt_poses, rows, count, indices)
    if kind == "tum" and len(gt_poses) != count:
        raise SourceError(
            f"{path}: {len(gt_poses)} timestamped poses for {count} frames without timestamps ({where} has no "
            "times.txt): they cannot be matched by time, and row by row needs one pose per frame (put the "
            "frames' times.txt beside the images, or say which rows are the frames with --gt-rows A:B)")
    if frame_times is not None and len(gt_poses) != count:
        raise SourceError(
            f"{path}: {len(gt_poses)} poses without timestamps (KITTI format) for {count} timestamped frames: "
            "they cannot be matched by time, and row by row needs one pose per frame (give the ground truth "
            "as TUM, with timestamps on the frames' clock, or say which rows are the frames with --gt-rows A:B)")
    if len(gt_poses) < count:
        raise SourceError(f"{path}: {len(gt_poses)} poses for {count} frames (need one pose per frame)")
    if len(gt_poses) > count:
        raise SourceError(
            f"{path}: {len(gt_poses)} poses for {count} frames and nothing pairs them by time (no times.txt "
            f"beside the images): row by row from row 0 is right only if the frames are the first {count} of the "
            f"sequence; say which rows they are with --gt-rows A:B (e.g. --gt-rows 100:{100 + count} for frames "
            "that start at the sequence's frame 100), give a TUM ground truth and the frames' times.txt, or keep "
            "the whole sequence's frames and choose some with --frames")
    return rebase_poses(gt_poses[np.asarray(indices)]), ROW_BY_ROW


def _given_rows(path: Path, poses: np.ndarray, rows: tuple[int, int | None], count: int, indices: list[int]
                ) -> tuple[np.ndarray, str]:
    """`--gt-rows A:B`: rows A..B-1 of the file are frames 0..count-1 (B - A must be the frame count)."""
    start, end = rows
    end = start + count if end is None else end
    if end - start != count:
        raise SourceError(f"--gt-rows {start}:{end} holds {end - start} rows for {count} frames: the rows must be "
                          f"the frames, one each (e.g. --gt-rows {start}:{start + count})")
    if end > len(poses):
        raise SourceError(f"--gt-rows {start}:{end}: {path} has {len(poses)} poses (rows 0:{len(poses)})")
    return (rebase_poses(poses[start:end][np.asarray(indices)]),
            f"row by row from row {start} (--gt-rows {start}:{end}: line {start + 1} of {path.name} is frame 0)")


def stamped_lines(path: Path, holding: str) -> Iterator[tuple[int, str, list[str]]]:
    """(line number, the line stripped, its whitespace-separated fields) of each line of a dataset's text list
    (``times.txt``, ``rgb.txt``) that is neither empty nor a ``#`` comment; `SourceError` naming the file (what
    it is `holding`) when it cannot be read. A byte-order mark (Windows editors) is not part of the first line."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read {holding} ({exc.__class__.__name__})") from None
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            yield number, stripped, stripped.split()


def parse_stamp(path: Path, number: int, text: str) -> float:
    """A timestamp in seconds from line `number` of `path`; `SourceError` naming both when it is not a finite
    number."""
    try:
        stamp = float(text)
    except ValueError:
        raise SourceError(f"{path}:{number}: timestamp {text[:30]!r} is not a number") from None
    if not np.isfinite(stamp):
        raise SourceError(f"{path}:{number}: timestamp is not finite")
    return stamp
