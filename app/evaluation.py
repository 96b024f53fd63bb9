"""`vslam eval`: run the engine over sequences (or take a trajectory file) and write a report folder.

The report folder holds metrics.csv and metrics.parquet (one row per sequence plus the mean), report.md,
each estimated trajectory (KITTI format), each recording and a top-view plot per sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from rich.console import Console

import vslam_core
from app.matching import DEFAULT_TOLERANCE_MS, Matching, MatchMode, gt_times_for, match_poses
from app.plots import write_top_view
from app.recording import Detail, version_properties
from app.report import COLUMNS, json_ready, markdown_table, mean_row, metrics_row, scored_estimate
from app.runner import Interrupted, record_run
from vslam_core.config import EngineConfig
from vslam_core.errors import SourceError
from vslam_core.metrics import kitti_errors_by_length
from vslam_core.sources.base import FrameSource, describe_indices, rebase_poses
from vslam_core.trajectory_io import (
    TrajectoryFormat,
    detect_format,
    read_kitti_poses,
    read_tum_poses,
    write_kitti_poses,
)

REPORT_FILES = ("metrics.csv", "metrics.parquet", "report.md")


@dataclass
class Evaluation:
    rows: list[dict[str, Any]]  # one per sequence
    mean: dict[str, Any]
    by_length: dict[str, dict[float, tuple[float, float, int]]] = field(default_factory=dict)
    interrupted: Interrupted | None = None
    matching: Matching | None = None  # --trajectory files: how their rows were paired with the ground truth
    inject: str | None = None  # faults injected into every sequence (--inject)
    notes: list[str] = field(default_factory=list)  # which sequence was interrupted, after how many frames

    def as_json(self) -> dict[str, Any]:
        extra = {"matching": self.matching.as_json()} if self.matching is not None else {}
        return json_ready({"sequences": self.rows, "mean": self.mean, **extra})


def evaluate_sources(
    sources: list[FrameSource],
    config: EngineConfig,
    report_dir: Path | None,
    console: Console,
    detail: Detail = Detail.FULL,
    properties: dict[str, str] | None = None,
    *,
    names: list[str] | None = None,
    write_tables: bool = True,
) -> Evaluation:
    """Run each source (each must have ground truth) and evaluate it; with `report_dir`, write its
    recording, trajectory and plot there, then the tables (unless not `write_tables`: a batch writes one
    report over all its logs). `names` (one per source) replace the sources' names in rows and file names,
    so two windows of one sequence do not collide."""
    rows, by_length = [], {}
    interrupted = None
    notes: list[str] = []  # how the runs ended early, for report.md
    for position, source in enumerate(sources):
        name = names[position] if names is not None else source.name
        gt = source.ground_truth
        if gt is None:
            raise SourceError(f"{source.name}: no ground truth, nothing to evaluate against")
        rrd = report_dir / f"{name}.rrd" if report_dir is not None and detail != Detail.OFF else None
        selected = describe_indices(source.indices)
        props = {
            "name": f"vslam eval {source.name} frames {selected} scale {config.scale}",
            "source": source.name,
            "frames": selected,
            "frame_count": str(len(source)),
            "scale": config.scale,
            "backend": config.backend,
            **version_properties(),
            **(properties or {}),
        }
        run = record_run(source, config, rrd, props, console, detail)
        if run.failure is not None:
            raise run.failure
        if run.result.frames >= 3:
            row, lengths = _score(name, gt, run.result.pose_array(), config, report_dir)
            row["fps"] = run.result.frames / run.result.seconds if run.result.seconds else math.nan
            rows.append(row)
            by_length[name] = lengths
        if run.interrupted is not None:
            interrupted = run.interrupted
            notes.append(f"{source.name}: interrupted by {interrupted} after {run.result.frames} of {len(source)} "
                         "frames" + (" (its row covers those frames only)" if run.result.frames >= 3
                                     else " (too few to score: no row)"))
            if position + 1 < len(sources):
                notes.append("not run: " + ", ".join(s.name for s in sources[position + 1:]))
            break
    evaluation = Evaluation(rows, mean_row(rows), by_length, interrupted, inject=(properties or {}).get("inject"),
                            notes=notes)
    if report_dir is not None and write_tables and (rows or notes):
        write_report(report_dir, evaluation, config)
    return evaluation


def _score(name: str, gt: np.ndarray, poses: np.ndarray, config: EngineConfig, report_dir: Path | None
           ) -> tuple[dict[str, Any], dict[float, tuple[float, float, int]]]:
    """The metrics row and per-length KITTI errors of one run; with `report_dir`, its trajectory (as run) and
    top view (the scored estimate: Sim(3)-aligned with --scale none) there."""
    gt = gt[: len(poses)]
    row = metrics_row(name, gt, poses, config.scale, config.backend)
    scored = scored_estimate(gt, poses, config.scale)
    if report_dir is not None:
        write_kitti_poses(report_dir / f"{name}.txt", poses)
        aligned = " Sim(3)-aligned" if row["alignment"] == "sim3" else ""
        write_top_view(report_dir / f"{name}_top.png", gt, scored,
                       f"{name}  ({len(poses)} frames, scale {config.scale}{aligned}, backend {config.backend})",
                       _subtitle(row))
    return row, kitti_errors_by_length(gt, scored)


def _subtitle(row: dict[str, Any]) -> str:
    def f(value: float, fmt: str) -> str:
        return "n/a" if math.isnan(value) else fmt.format(value)

    return (
        f"t_err {f(row['t_err'], '{:.2f}')} %   r_err {f(row['r_err'], '{:.2f}')} deg/100 m   "
        f"ATE Sim3 {f(row['ate_sim3'], '{:.3f}')} m   paper RMS {f(row['paper_rms'], '{:.3f}')} m"
    )


def write_report(report_dir: Path, evaluation: Evaluation, config: EngineConfig) -> None:
    """metrics.csv, metrics.parquet and report.md for an evaluation."""
    table = pl.DataFrame([*evaluation.rows, evaluation.mean], schema_overrides={"frames": pl.Int64})
    table.write_csv(report_dir / "metrics.csv")
    table.write_parquet(report_dir / "metrics.parquet")
    rows = evaluation.rows + ([evaluation.mean] if len(evaluation.rows) > 1 else [])
    aligned = config.scale == "none"
    lines = [
        "# vslam evaluation",
        "",
        f"vslam {vslam_core.__version__}, {datetime.now():%Y-%m-%d %H:%M}, scale source `{config.scale}`, "
        f"backend `{evaluation.mean.get('backend', config.backend)}`.",
        "",
        *_provenance_lines(evaluation, aligned),
        markdown_table([{k: r.get(k) for k in COLUMNS if k not in ("scale", "backend", "alignment")} for r in rows]),
        "",
        ("Every number is of the Sim(3)-aligned estimate. " if aligned else "")
        + "t_err, r_err: KITTI devkit segment errors (100–800 m, every 10th frame), "
        + ("after that alignment" if aligned else "no alignment")
        + ". ATE: RMSE after Umeyama SE(3) / Sim(3) alignment. RPE: consecutive frames (and pairs 10 m of path "
        "apart), translation RMSE and mean rotation. Paper RMS: the seed paper's x–z position RMS, "
        + ("after that alignment." if aligned else "no alignment."),
    ]
    if evaluation.by_length:
        lengths = sorted({length for v in evaluation.by_length.values() for length in v})
        lines += [
            "",
            "## KITTI error per segment length",
            "",
            "| sequence | " + " | ".join(f"{length:g} m t_err % / r_err °/100 m (n)" for length in lengths) + " |",
            "|---|" + "---|" * len(lengths),
        ]
        for name, values in evaluation.by_length.items():
            cells = [
                f"{values[length][0]:.2f} / {values[length][1]:.2f} ({values[length][2]})"
                if length in values
                else "n/a"
                for length in lengths
            ]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    plots = [
        f"![{r['sequence']}]({r['sequence']}_top.png)"
        for r in evaluation.rows
        if (report_dir / f"{r['sequence']}_top.png").exists()
    ]
    if plots:
        lines += ["", "## Trajectories (top view)", "", *plots]
    (report_dir / "report.md").write_text("\n".join(lines) + "\n")


def _provenance_lines(evaluation: Evaluation, aligned: bool) -> list[str]:
    """What report.md says before its table: alignment, row matching, injected faults, interruption."""
    lines = []
    if aligned:
        lines.append("`--scale none`: the estimates have unit steps (no metric scale), so each is Sim(3)-aligned "
                     "onto the ground truth before scoring and plotting.")
    if evaluation.matching is not None:
        lines.append(f"Rows {evaluation.matching.describe()}.")
    if evaluation.matching is None:
        lines.append(f"Faults injected into every sequence: `{evaluation.inject}` (`--inject`)." if evaluation.inject
                     else "No faults injected.")
    if evaluation.notes:
        lines.append(f"**Interrupted by {evaluation.interrupted}**: " + "; ".join(evaluation.notes) + ".")
    return [line for item in lines for line in (item, "")]


def load_trajectory(path: Path, fmt: TrajectoryFormat | None) -> tuple[np.ndarray | None, np.ndarray]:
    """(timestamps or None, (N, 4, 4) poses) of a KITTI or TUM file (format guessed when None)."""
    fmt = fmt or detect_format(path)
    if fmt == "tum":
        return read_tum_poses(path)
    return None, read_kitti_poses(path)


def evaluate_trajectory_file(
    estimate: Path,
    ground_truth: Path,
    fmt: TrajectoryFormat | None,
    report_dir: Path | None,
    gt_times: Path | None = None,
    match: MatchMode = MatchMode.auto,
    tolerance_ms: float = DEFAULT_TOLERANCE_MS,
) -> Evaluation:
    """Score any system's trajectory file against ground truth, both re-based to their first pose; rows are
    matched by timestamp when both sides have times (`gt_times`: a KITTI ``times.txt`` for a KITTI ground
    truth), else row by row (see `app.matching`)."""
    est_times, est = load_trajectory(estimate, fmt)
    own_gt_times, gt = load_trajectory(ground_truth, fmt)
    times = gt_times_for(gt_times, own_gt_times, len(gt), ground_truth)
    est, gt, matching = match_poses(est_times, est, times, gt, (estimate, ground_truth), match, tolerance_ms)
    est, gt = rebase_poses(est), rebase_poses(gt)
    row = metrics_row(estimate.stem, gt, est, "external", "external")
    row["matching"] = matching.describe()
    evaluation = Evaluation([row], mean_row([row]), {estimate.stem: kitti_errors_by_length(gt, est)},
                            matching=matching)
    if report_dir is not None:
        write_top_view(
            report_dir / f"{estimate.stem}_top.png", gt, est, f"{estimate.name}  ({len(est)} poses)", _subtitle(row)
        )
        write_report(report_dir, evaluation, EngineConfig(scale="gt"))
    return evaluation


def check_gates(
    rows: list[dict[str, Any]], max_t_err: float | None, max_r_err: float | None, max_ate: float | None
) -> list[str]:
    """One message per sequence and metric over its gate (an unavailable metric fails its gate too)."""
    failures = []
    for row in rows:
        for key, limit, unit in (
            ("t_err", max_t_err, "%"),
            ("r_err", max_r_err, "°/100 m"),
            ("ate_sim3", max_ate, "m"),
        ):
            if limit is None:
                continue
            value = row[key]
            if math.isnan(value):
                failures.append(f"{row['sequence']}: {key} not available (path too short?), gate {limit:g} {unit}")
            elif value > limit:
                failures.append(f"{row['sequence']}: {key} {value:.3f} {unit} > {limit:g} {unit}")
    return failures
