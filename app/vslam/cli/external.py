"""`vslam eval --trajectory …`: score other systems' trajectory files and, with ``--report DIR``, write each
as a recording `DIR/<name>.rrd` (with its camera frames from ``--images``)."""

from __future__ import annotations

import hashlib
import json
import uuid
from pathlib import Path

import numpy as np

from vslam.cli.common import fail, report_writes
from vslam.common import TrajectoryImages, markdown_table, open_images
from vslam.evaluation import (
    Evaluation,
    MatchMode,
    ScoredTrajectory,
    evaluate_trajectory_files,
    match_images,
    write_trajectory_report,
)
from vslam.recording import Detail, ExternalRun, RunFrames, record_external, version_properties
from vslam_core.sources.base import describe_indices
from vslam_core.trajectory.io import TrajectoryFormat


def evaluate_external(
    trajectories: list[Path],
    gt: Path,
    fmt: TrajectoryFormat | None,
    report: Path | None,
    detail: Detail,
    images: Path | None,
    intrinsics: str | None,
    calib: Path | None,
    gt_times: Path | None,
    match: MatchMode,
    tolerance_ms: float,
    window: str | None = None,
    time_offset: float | None = None,
) -> Evaluation:
    """Score every trajectory file against `gt` (`window`: ``--frames``, the ground-truth rows they hold;
    `time_offset`: seconds added to their times); with `report`, write the tables, the top view and (unless
    `detail` is off) one recording per file. Bad input fails before anything is written."""
    if images is not None and (report is None or detail == Detail.OFF):
        fail("--images goes into the recordings of --report DIR (and --detail off writes none)")
    frames = open_images(images, intrinsics, calib) if images is not None else None
    evaluation, scored = evaluate_trajectory_files(trajectories, gt, fmt, gt_times, match, tolerance_ms, window,
                                                   time_offset)
    if report is None:
        return evaluation
    pairs = [_pair(s, frames, match, tolerance_ms) if frames is not None else None for s in scored]
    with report_writes(report):
        write_trajectory_report(report, evaluation, scored)
        if detail != Detail.OFF:
            for trajectory, paired in zip(scored, pairs, strict=True):
                run, properties = _external_run(trajectory, gt, paired, match, tolerance_ms, fmt)
                record_external(report / f"{trajectory.name}.rrd", run, properties, detail,
                                paired[0] if paired is not None else None)
    return evaluation


def _pair(trajectory: ScoredTrajectory, frames: TrajectoryImages, match: MatchMode, tolerance_ms: float
          ) -> tuple[RunFrames, str]:
    """Each matched row's image (`vslam.evaluation.matching.match_images`) and how they were paired."""
    if trajectory.matching.method == "frame":  # each row's source frame is known: its image is that frame's
        picks = np.asarray(trajectory.matching.truth_rows, np.int64)
        if len(frames.files) <= int(picks.max()):
            fail(f"--images {frames.path}: {len(frames.files)} images, but {trajectory.path} reaches frame "
                 f"{int(picks.max())} (image i is frame i)")
        return RunFrames(frames, picks), f"images by frame: image i is frame i ({trajectory.matching.how})"
    picks, how = match_images(trajectory.matching.rows, trajectory.total_rows, trajectory.times, frames.times,
                              len(frames.files), (trajectory.path, frames.path), match, tolerance_ms)
    return RunFrames(frames, picks), how


def _external_run(trajectory: ScoredTrajectory, gt: Path, paired: tuple[RunFrames, str] | None, match: MatchMode,
                  tolerance_ms: float, fmt: TrajectoryFormat | None) -> tuple[ExternalRun, dict[str, str]]:
    """The recording's data and run properties (``vslam inspect`` shows them; the producer is "external")."""
    rows = list(trajectory.matching.rows)
    # the recording's frame timeline is the source's frame index: the paired ground-truth row when it is known
    frames = list(trajectory.matching.truth_rows) if trajectory.matching.method == "frame" else rows
    selected = describe_indices(frames)
    name = f"vslam eval external {trajectory.name} frames {selected}"
    key = [trajectory.name, _digest(trajectory.path), _digest(gt), str(fmt), str(match), tolerance_ms,
           [] if paired is None else [paired[0].images.path.name, len(paired[0].images.files), paired[1]]]
    properties = {
        "name": name,
        "recording_id": str(uuid.uuid5(uuid.NAMESPACE_URL, "vslam-external:" + json.dumps(key))),
        "source": f"external trajectory {trajectory.path.name}",
        "source_path": str(trajectory.path),
        "frames": selected,
        "frame_count": str(len(rows)),
        "scale": "external",
        "backend": "external",
        "ground_truth": str(gt),
        "matching": trajectory.matching.describe(),
        **({"images": str(paired[0].images.path), "images_matching": paired[1]} if paired is not None else {}),
        **version_properties(),
    }
    lines = [f"# {name}", "", f"`{trajectory.path.name}`, another system's trajectory (no health, tracks or "
             f"timings), against `{gt.name}`: {trajectory.matching.describe()}"
             + (f"; {paired[1]}" if paired is not None else "") + ".", "",
             markdown_table([{k: v for k, v in trajectory.row.items() if k != "alignment"}])]
    times = trajectory.times[rows] if trajectory.times is not None else None
    run = ExternalRun(trajectory.name, trajectory.estimate, trajectory.ground_truth,
                      np.asarray(frames, np.int64), times, "\n".join(lines))
    return run, properties


def _digest(path: Path) -> str:
    """SHA-256 of a file's bytes: the recording id follows the data, not where it lies."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


