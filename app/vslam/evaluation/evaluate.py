"""`vslam eval`: run the engine over sequences (or take a trajectory file) and write a report folder.

The report folder holds metrics.csv and metrics.parquet (one row per sequence plus the mean), report.md,
each estimated trajectory (KITTI format), each recording and a top-view plot per sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from rich.console import Console
from rich.text import Text

import vslam_core
from vslam.common import COLUMNS, json_ready, markdown_table, mean_row, metrics_row, scored_estimate
from vslam.evaluation.estimates import load_estimate
from vslam.evaluation.matching import (
    DEFAULT_TOLERANCE_MS,
    Matching,
    MatchMode,
    Window,
    gt_times_for,
    match_poses,
)
from vslam.evaluation.plots import write_top_view
from vslam.recording import DEFAULT_DETAIL, Detail, ImageCodec, version_properties
from vslam.runs import Interrupted, record_run
from vslam_core.config import EngineConfig
from vslam_core.errors import SourceError, TrajectoryFormatError
from vslam_core.geometry import invert_pose
from vslam_core.sources.base import FrameRange, FrameSource, describe_indices, rebase_poses
from vslam_core.trajectory.io import (
    TrajectoryFormat,
    check_ground_truth_steps,
    detect_format,
    read_kitti_poses,
    read_tum_poses,
    write_kitti_poses,
)
from vslam_core.trajectory.metrics import kitti_errors_by_length

REPORT_FILES = ("metrics.csv", "metrics.parquet", "report.md")
#: The top view of several --trajectory files.
MULTI_PLOT = "trajectories_top.png"


@dataclass
class Evaluation:
    rows: list[dict[str, Any]]  # one per sequence
    mean: dict[str, Any]
    by_length: dict[str, dict[float, tuple[float, float, int]]] = field(default_factory=dict)
    interrupted: Interrupted | None = None
    matching: Matching | None = None  # one --trajectory file: how its rows were paired with the ground truth
    matchings: dict[str, Matching] = field(default_factory=dict)  # every --trajectory file's, by name
    inject: str | None = None  # faults injected into every sequence (--inject)
    notes: list[str] = field(default_factory=list)  # which sequence was interrupted, after how many frames
    # which poses the engine's rows are of: "refined" (the map's) or "as tracked"; None for trajectory files
    scored_trajectory: str | None = None

    def as_json(self) -> dict[str, Any]:
        extra: dict[str, Any] = {"matching": self.matching.as_json()} if self.matching is not None else {}
        if len(self.matchings) > 1:
            extra = {"matchings": {name: m.as_json() for name, m in self.matchings.items()}}
        if self.scored_trajectory is not None:
            extra["scored_trajectory"] = self.scored_trajectory
        return json_ready({"sequences": self.rows, "mean": self.mean, **extra})


def evaluate_sources(
    sources: list[FrameSource],
    config: EngineConfig,
    report_dir: Path | None,
    console: Console,
    detail: Detail = DEFAULT_DETAIL,
    properties: dict[str, str] | None = None,
    image_codec: ImageCodec = ImageCodec.JPEG,
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
    scored: str | None = None
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
        run = record_run(source, config, rrd, props, console, detail, image_codec=image_codec)
        if run.failure is not None:
            raise run.failure
        for warning in run.warnings():  # the scores against a suspect ground truth are suspect
            console.print(Text.assemble(("warning:", "bold yellow"), f" {source.name}: {warning}"), soft_wrap=True)
        scored = run.result.scored_trajectory
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
                            notes=notes, scored_trajectory=scored)
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
        f"vslam {vslam_core.__version__}, {datetime.now():%Y-%m-%d %H:%M}, scale source "
        f"`{'external' if evaluation.matchings else config.scale}`, "
        f"backend `{evaluation.mean.get('backend', config.backend)}`.",
        "",
        *_provenance_lines(evaluation, aligned),
        markdown_table([{k: r.get(k) for k in COLUMNS if k not in ("scale", "backend", "alignment")
                        and (k in r or k != "status")} for r in rows]),
        "",
        ("Every number is of the Sim(3)-aligned estimate. " if aligned else "")
        + "t_err, r_err: KITTI devkit segment errors (100–800 m, every 10th frame), "
        + ("after that alignment" if aligned else "no alignment")
        + ". ATE: RMSE after Umeyama SE(3) / Sim(3) alignment. RPE: consecutive frames (and pairs 10 m of path "
        "apart), translation RMSE and mean rotation. Paper RMS: the seed paper's x–z position RMS, "
        + ("after that alignment." if aligned else "no alignment."),
    ]
    lengths = sorted({length for v in evaluation.by_length.values() for length in v})
    if lengths:  # none on paths under 100 m
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
    ] + ([f"![trajectories]({MULTI_PLOT})"] if len(evaluation.matchings) > 1 else [])
    if plots:
        lines += ["", "## Trajectories (top view)", "", *plots]
    (report_dir / "report.md").write_text("\n".join(lines) + "\n")


def scored_sentence(scored: str) -> str:
    """Which poses the rows are of (``refined`` or ``as tracked``: `RunResult.scored_trajectory`)."""
    if scored == "refined":
        return ("Scored: the map's refined poses (after bundle adjustment and loop closing), as the trajectory "
                "files hold them.")
    return "Scored: the poses as tracked (nothing refined them)."


def _provenance_lines(evaluation: Evaluation, aligned: bool) -> list[str]:
    """What report.md says before its table: alignment, row matching, injected faults, interruption."""
    lines = []
    if aligned:
        lines.append("`--scale none`: the estimates have unit steps (no metric scale), so each is Sim(3)-aligned "
                     "onto the ground truth before scoring and plotting.")
    if evaluation.matching is not None:
        lines.append(f"Rows {evaluation.matching.describe()}.")
    elif evaluation.matchings:
        lines.append("Rows " + "; ".join(f"of {name} {m.describe()}" for name, m in evaluation.matchings.items())
                     + ".")
    if not evaluation.matchings:
        lines.append(f"Faults injected into every sequence: `{evaluation.inject}` (`--inject`)." if evaluation.inject
                     else "No faults injected.")
    if evaluation.scored_trajectory is not None:
        lines.append(scored_sentence(evaluation.scored_trajectory))
    if evaluation.notes:
        lines.append(f"**Interrupted by {evaluation.interrupted}**: " + "; ".join(evaluation.notes) + ".")
    return [line for item in lines for line in (item, "")]


def load_trajectory(path: Path, fmt: TrajectoryFormat | None) -> tuple[np.ndarray | None, np.ndarray]:
    """(timestamps or None, (N, 4, 4) poses) of a KITTI or TUM file (format guessed when None)."""
    fmt = fmt or detect_format(path)
    if fmt == "tum":
        return read_tum_poses(path)
    return None, read_kitti_poses(path)


@dataclass(frozen=True)
class ScoredTrajectory:
    """One trajectory file matched to the ground truth and scored. estimate, ground_truth: (N, 4, 4) T_w_c,
    re-based to the first matched row; anchor: (4, 4) that row's ground-truth pose as the file has it (places
    estimates of different windows in one plot); times: (R,) seconds of every row of the file, or None."""

    path: Path
    estimate: np.ndarray
    ground_truth: np.ndarray
    anchor: np.ndarray
    times: np.ndarray | None
    total_rows: int
    matching: Matching
    row: dict[str, Any]

    @property
    def name(self) -> str:
        return self.path.stem


def evaluate_trajectory_files(
    estimates: list[Path],
    ground_truth: Path,
    fmt: TrajectoryFormat | None,
    gt_times: Path | None = None,
    match: MatchMode = MatchMode.auto,
    tolerance_ms: float = DEFAULT_TOLERANCE_MS,
    frames: str | None = None,
    time_offset: float | None = None,
) -> tuple[Evaluation, list[ScoredTrajectory]]:
    """Score any systems' trajectory files against one ground truth, each re-based to its first pose; rows are
    matched by timestamp when both sides have times (`gt_times`: a KITTI ``times.txt`` for a KITTI ground
    truth), else row by row (see `vslam.evaluation.matching`). One metrics row per file, named after it (names must
    differ: `TrajectoryFormatError`). `frames` (``--frames A:B[:S]``: the ground-truth rows the estimates hold)
    and `time_offset` (seconds added to their times) say which ground-truth rows they are of; a recording or a
    `vslam.log` TUM file says it itself (`vslam.evaluation.estimates`). Nothing is written: see
    `write_trajectory_report`."""
    names: dict[str, Path] = {}
    for path in estimates:
        if path.stem in names:
            raise TrajectoryFormatError(f"--trajectory {names[path.stem]} and {path}: both are named "
                                        f"{path.stem!r} (rows and recordings are named after the file): rename one")
        names[path.stem] = path
    own_gt_times, gt_all = load_trajectory(ground_truth, fmt)
    times = gt_times_for(gt_times, own_gt_times, len(gt_all), ground_truth)
    # a broken row would skew every figure (KITTI times.txt may cover the first rows only: then 1 s a row)
    check_ground_truth_steps(ground_truth, gt_all, times if times is not None and len(times) == len(gt_all) else None)
    stated = _stated_window(frames, time_offset, len(gt_all))
    scored = []
    for path in estimates:
        estimate = load_estimate(path, fmt)
        est_times, est = estimate.times, estimate.poses
        window = stated if stated is not None and stated.frames is not None else estimate.window
        if stated is not None and stated.time_offset is not None:
            window = replace(window or Window(), time_offset=stated.time_offset)
        matched, gt, matching = match_poses(est_times, est, times, gt_all, (path, ground_truth), match, tolerance_ms,
                                            window, own_gt_times is not None)
        row = metrics_row(path.stem, rebase_poses(gt), rebase_poses(matched), "external", "external")
        row["matching"] = matching.describe()
        scored.append(ScoredTrajectory(path, rebase_poses(matched), rebase_poses(gt), gt[0].copy(), est_times,
                                       len(est), matching, row))
    rows = [s.row for s in scored]
    evaluation = Evaluation(rows, mean_row(rows), {s.name: kitti_errors_by_length(s.ground_truth, s.estimate)
                                                   for s in scored},
                            matching=scored[0].matching if len(scored) == 1 else None,
                            matchings={s.name: s.matching for s in scored})
    return evaluation, scored


def _stated_window(frames: str | None, time_offset: float | None, gt_rows: int) -> Window | None:
    """``--frames`` (clamped to the ground truth's rows like a Python slice) and ``--time-offset`` as a `Window`."""
    if frames is None and time_offset is None:
        return None
    if frames is None:
        return Window(time_offset=time_offset)
    try:
        indices = FrameRange.parse(frames).indices(gt_rows)
    except SourceError as exc:
        raise TrajectoryFormatError(f"{exc} (the ground truth has {gt_rows} rows)") from None
    return Window(tuple(indices), exact=False, how=f"--frames {frames}", time_offset=time_offset)


def write_trajectory_report(report_dir: Path, evaluation: Evaluation, scored: list[ScoredTrajectory]) -> None:
    """The tables and the top view of scored trajectory files: ``<name>_top.png`` for one file, one
    ``trajectories_top.png`` with every estimate for several (each placed at its first row's ground truth)."""
    if len(scored) == 1:
        only = scored[0]
        write_top_view(report_dir / f"{only.name}_top.png", only.ground_truth, only.estimate,
                       f"{only.path.name}  ({len(only.estimate)} poses)", _subtitle(only.row))
    else:
        origin = invert_pose(scored[0].anchor)
        placed = [(origin @ s.anchor) @ poses for s in scored for poses in (s.ground_truth, s.estimate)]
        write_top_view(report_dir / MULTI_PLOT, placed[0::2], [(s.name, e) for s, e in zip(scored, placed[1::2],
                                                                                          strict=True)],
                       f"{len(scored)} trajectories vs ground truth", "  ".join(
                           f"{s.name}: t_err {_number(s.row['t_err'], '{:.2f}')} %" for s in scored))
    write_report(report_dir, evaluation, EngineConfig(scale="gt"))


def _number(value: float, fmt: str) -> str:
    return "n/a" if math.isnan(value) else fmt.format(value)


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
