"""Accuracy of vslam's engine vs the paper configuration over sequences, windows and RANSAC seeds.

    python -m benchmarks.accuracy ../shared/data/kitti --sequences 00,05 --windows 0:300,0:150,150:300 \
        --seeds 0,1,2 --csv accuracy.csv

Prints a markdown table (mean and range over seeds and windows) and writes one CSV row per run.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from multiprocessing import Pool
from pathlib import Path

import numpy as np
import polars as pl

from benchmarks.paper_baseline import run_paper_configuration
from vslam_core.config import EngineConfig, load_config
from vslam_core.metrics import ate, kitti_errors
from vslam_core.pipeline import run_odometry
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource


def _one(job: tuple[str, str, str, str, int, str | None]) -> dict[str, object]:
    system, root, sequence, window, seed, config_path = job
    source = KittiSource(root, sequence=sequence, frames=FrameRange.parse(window))
    gt = source.ground_truth
    assert gt is not None
    if system == "paper":
        baseline = run_paper_configuration(source, seed=seed)
        poses, seconds = baseline.poses, baseline.seconds
    else:
        config = load_config(config_path) if config_path else EngineConfig()
        config = dataclasses.replace(config, pose=dataclasses.replace(config.pose, seed=seed))
        run = run_odometry(source, config)
        poses, seconds = run.pose_array(), run.seconds
    t_err, r_err = kitti_errors(gt, poses)
    return {"system": system, "sequence": sequence, "window": window, "seed": seed, "t_err": t_err,
            "r_err": r_err, "ate_sim3": ate(gt, poses, "sim3"), "fps": len(poses) / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--windows", default="0:300")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--systems", default="paper,vslam")
    parser.add_argument("--config", default=None, help="TOML config for vslam (default: built-in defaults)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    jobs = [
        (system, str(args.root), seq, window, int(seed), args.config)
        for system, seq, window, seed in itertools.product(
            args.systems.split(","), args.sequences.split(","), args.windows.split(","), args.seeds.split(",")
        )
    ]
    with Pool(args.jobs) as pool:
        rows = pool.map(_one, jobs, chunksize=1)
    table = pl.DataFrame(rows)
    if args.csv:
        table.write_csv(args.csv)
    summary = (
        table.group_by("system", "sequence", maintain_order=True)
        .agg(
            pl.len().alias("runs"),
            *[pl.col(m).mean().alias(m) for m in ("t_err", "r_err", "ate_sim3", "fps")],
            *[pl.col(m).min().alias(f"{m}_min") for m in ("t_err", "r_err")],
            *[pl.col(m).max().alias(f"{m}_max") for m in ("t_err", "r_err")],
        )
    )
    print("| system | seq | runs | t_err % mean [min–max] | r_err °/100 m mean [min–max] | ATE Sim3 m | fps |")
    print("|---|---|---|---|---|---|---|")
    for r in summary.iter_rows(named=True):
        print(f"| {r['system']} | {r['sequence']} | {r['runs']} | {r['t_err']:.2f} [{r['t_err_min']:.2f}–"
              f"{r['t_err_max']:.2f}] | {r['r_err']:.2f} [{r['r_err_min']:.2f}–{r['r_err_max']:.2f}] | "
              f"{r['ate_sim3']:.2f} | {r['fps']:.1f} |")
    for system in table["system"].unique(maintain_order=True):
        part = table.filter(pl.col("system") == system)
        mean_t = np.mean([part.filter(pl.col("sequence") == s)["t_err"].mean() for s in part["sequence"].unique()])
        mean_r = np.mean([part.filter(pl.col("sequence") == s)["r_err"].mean() for s in part["sequence"].unique()])
        print(f"{system}: mean over sequences t_err {mean_t:.2f} %, r_err {mean_r:.2f} °/100 m")


if __name__ == "__main__":
    main()
