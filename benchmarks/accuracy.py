"""Accuracy of vslam's engine (each backend) vs the paper configuration over sequences, windows and RANSAC seeds.

    python -m benchmarks.accuracy ../shared/data/kitti --sequences 00,05 --windows 0:300,0:150,150:300 \
        --seeds 0,1,2 --backends vo,map --scale gt --csv accuracy.csv

Runs every (system, backend, sequence, window, seed) in a multiprocessing pool of `--jobs` workers and prints
a markdown table with one row per (system, backend): per sequence the mean and [min–max] over seeds and
windows of KITTI t_err (%) and r_err (°/100 m), then the mean over sequences (of the per-sequence means).
A second table gives runs, ATE Sim(3), the relative pose error from each frame to the next (RPE, Sturm et al.
2012, after the alignment t_err is scored with: how steady the poses are) and fps per sequence. One CSV row per
run (`--csv`), with a `backend` column.

The paper configuration (benchmarks/paper_baseline.py) has no backend and always takes its step length from
ground truth: it runs once per (sequence, window, seed), with backend `-`, whatever `--backends` and
`--scale` say. `--scale` (gt, height or none) and `--backends` apply to vslam. `--align sim3` scores t_err /
r_err (KITTI devkit) after the best Sim(3) alignment of the estimate onto ground truth (the default with
`--scale none`, whose trajectory has an arbitrary scale).

vslam runs with ``threads = 1`` here, whatever `--config` says: pool workers are daemonic processes, which
may not start children, and with threads ≥ 2 the map backend runs its bundle adjustment in a worker process
of its own. Trajectories are identical for any threads value (by design, and tested), so only fps differs
from a default (2-thread) run; the pool's `--jobs` use the cores instead. Use benchmarks/speed.py for speed.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import polars as pl

from benchmarks.paper_baseline import run_paper_configuration
from vslam_core.config import Backend, EngineConfig, ScaleSource
from vslam_core.config_file import load_config
from vslam_core.pipeline import run_odometry
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import ate, kitti_errors, rpe, sim3_aligned

BACKENDS: tuple[Backend, ...] = ("vo", "map")
SCALES: tuple[ScaleSource, ...] = ("gt", "height", "none")
NO_BACKEND = "-"  # the paper configuration's backend column


@dataclasses.dataclass(frozen=True)
class Job:
    system: str  # paper or vslam
    backend: str  # vo, map, or NO_BACKEND for the paper configuration
    root: str
    sequence: str
    window: str
    seed: int
    scale: str
    config_path: str | None
    align: str = "none"  # "sim3": t_err / r_err of the estimate after its Umeyama Sim(3) alignment


def benchmark_config(config_path: str | None, backend: Backend, scale: ScaleSource, seed: int) -> EngineConfig:
    """vslam's config for one run: the file's (or the defaults), with this backend, scale source and RANSAC
    seed, and one thread (see the module docstring)."""
    config = load_config(config_path) if config_path else EngineConfig()
    config = config.with_backend(backend).with_scale(scale)
    return dataclasses.replace(config, threads=1, pose=dataclasses.replace(config.pose, seed=seed))


def _one(job: Job) -> dict[str, object]:
    source = KittiSource(job.root, sequence=job.sequence, frames=FrameRange.parse(job.window))
    gt = source.ground_truth
    assert gt is not None
    if job.system == "paper":
        baseline = run_paper_configuration(source, seed=job.seed)
        poses, seconds, scale = baseline.poses, baseline.seconds, "gt"
    else:
        assert job.backend in BACKENDS and job.scale in SCALES
        config = benchmark_config(job.config_path, job.backend, job.scale, job.seed)
        run = run_odometry(source, config)
        poses, seconds, scale = run.pose_array(), run.seconds, config.scale
    scored = sim3_aligned(gt, poses) if job.align == "sim3" else poses
    t_err, r_err = kitti_errors(gt, scored)
    rpe_m, rpe_deg = rpe(gt, scored, 1)  # from each frame to the next: how steady the poses are
    return {"system": job.system, "backend": job.backend, "scale": scale, "sequence": job.sequence,
            "window": job.window, "seed": job.seed, "t_err": t_err, "r_err": r_err,
            "ate_sim3": ate(gt, poses, "sim3"), "rpe_m": rpe_m, "rpe_deg": rpe_deg, "fps": len(poses) / seconds}


def make_jobs(root: str, systems: list[str], backends: list[str], sequences: list[str], windows: list[str],
              seeds: list[int], scale: str, config_path: str | None, align: str = "none") -> list[Job]:
    jobs = []
    for system in systems:
        for backend in backends if system != "paper" else [NO_BACKEND]:
            for sequence, window, seed in itertools.product(sequences, windows, seeds):
                jobs.append(Job(system, backend, root, sequence, window, seed, scale, config_path, align))
    return jobs


def _range_cell(values: pl.Series) -> str:
    """mean [min–max] of the finite values (n/a when none: paths under 100 m have no KITTI segment)."""
    finite = [v for v in values.to_list() if v is not None and math.isfinite(v)]
    if not finite:
        return "n/a"
    missing = len(values) - len(finite)
    return (f"{np.mean(finite):.2f} [{min(finite):.2f}–{max(finite):.2f}]"
            + (f" ({missing} n/a)" if missing else ""))


def _mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _number(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{value:.2f}"


def summary_tables(table: pl.DataFrame) -> str:
    """The markdown tables printed by `main` (one row per (system, backend))."""
    sequences = table["sequence"].unique(maintain_order=True).to_list()
    groups = table.select("system", "backend").unique(maintain_order=True).iter_rows()
    header = ["system", "backend"] + [f"{s} {m}" for s in sequences for m in ("t_err %", "r_err °/100 m")]
    header += ["mean over sequences t_err %", "mean over sequences r_err °/100 m"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    details = ["| system | backend | seq | runs | ATE Sim3 m | RPE 1 frame cm / ° | fps |", "|---" * 7 + "|"]
    for system, backend in groups:
        part = table.filter((pl.col("system") == system) & (pl.col("backend") == backend))
        cells: list[str] = []
        means: dict[str, list[float]] = {"t_err": [], "r_err": []}
        for sequence in sequences:
            runs = part.filter(pl.col("sequence") == sequence)
            for metric in ("t_err", "r_err"):
                cells.append(_range_cell(runs[metric]))
                means[metric].append(_mean(runs[metric].to_list()))
            ate_m, rpe_m, rpe_deg, fps = (_mean(runs[c].to_list()) for c in ("ate_sim3", "rpe_m", "rpe_deg", "fps"))
            details.append(f"| {system} | {backend} | {sequence} | {len(runs)} | {_number(ate_m)} | "
                           f"{_number(100 * rpe_m)} / {rpe_deg:.3f} | {fps:.1f} |")
        cells += [_number(_mean(means["t_err"])), _number(_mean(means["r_err"]))]
        lines.append(f"| {system} | {backend} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\n" + "\n".join(details)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--windows", default="0:300")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--systems", default="paper,vslam")
    parser.add_argument("--backends", default="vo,map", help="vslam's backends (the paper configuration has none)")
    parser.add_argument("--scale", choices=SCALES, default="gt",
                        help="vslam's scale source (the paper configuration always uses ground truth)")
    parser.add_argument("--align", choices=("none", "sim3"), default=None,
                        help="score t_err / r_err after this alignment (default: sim3 with --scale none, else none)")
    parser.add_argument("--config", default=None, help="TOML config for vslam (default: built-in defaults)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    split = [part.strip() for part in args.backends.split(",") if part.strip()]
    if not split or any(b not in BACKENDS for b in split):
        parser.error(f"--backends {args.backends!r}: a comma-separated list of {', '.join(BACKENDS)}")
    systems = [part.strip() for part in args.systems.split(",") if part.strip()]
    if not systems or any(s not in ("paper", "vslam") for s in systems):
        parser.error(f"--systems {args.systems!r}: a comma-separated list of paper, vslam")
    jobs = make_jobs(str(args.root), systems, split, args.sequences.split(","), args.windows.split(","),
                     [int(seed) for seed in args.seeds.split(",")], args.scale, args.config,
                     args.align or ("sim3" if args.scale == "none" else "none"))
    with Pool(args.jobs) as pool:
        rows = pool.map(_one, jobs, chunksize=1)
    table = pl.DataFrame(rows)
    if args.csv:
        table.write_csv(args.csv)
    align = args.align or ("sim3" if args.scale == "none" else "none")
    print(f"KITTI {args.sequences}, windows {args.windows}, seeds {args.seeds}, vslam scale {args.scale} "
          f"(paper: gt); t_err / r_err after {align} alignment; mean [min–max] over seeds and windows")
    print(summary_tables(table))


if __name__ == "__main__":
    main()
