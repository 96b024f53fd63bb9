"""A hand-held camera with exact ground truth: the synthetic street's walk route (`vslam run synthetic --route walk`).

    python -m benchmarks.walk [--windows 0:200,200:400,0:450] [--seeds 0,1,2,3] [--backends vo,map] [--jobs 2]

The walk (vslam_core/sources/synthetic/road.py, `walk_path`) carries the camera down the street at 30 Hz, 4.5 cm a
frame, swinging about its centre by up to ~2° a frame: the low parallax and fast rotation of the hand-held
sequences held out from this repository (TUM RGB-D, EuRoC), with ground truth that is exact, in a street whose
façades are 5–20 m away (farther than a room's walls: less parallax a frame). Each backend runs with
ground-truth scale and with `--scale none`; per row, over seeds and windows: the mean ATE after the best Sim(3)
alignment, the mean ATE without alignment (ground-truth scale only), the mean final rotation error and the mean
share of frames held.
"""

from __future__ import annotations

import argparse
import math
from multiprocessing import Pool

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.sources.base import FrameRange
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.trajectory.metrics import ate


def _run(job: tuple[str, str, str, int]) -> dict[str, object]:
    """One run, in a pool worker (threads = 1: pool workers may not start the map backend's worker processes;
    trajectories are identical for any threads value)."""
    backend, scale, window, seed = job
    source = SyntheticStreet(route="walk", seed=seed, frames=FrameRange.parse(window))
    run = run_odometry(source, EngineConfig(backend=backend, scale=scale, threads=1))  # type: ignore[arg-type]
    truth, poses = source.ground_truth, run.pose_array()
    return {"backend": backend, "scale": scale, "window": window, "seed": seed,
            "ate_sim3": ate(truth, poses, "sim3"), "ate": ate(truth, poses, "none") if scale == "gt" else math.nan,
            "rotation_deg": math.degrees(rotation_angle(truth[-1, :3, :3].T @ poses[-1, :3, :3])),
            "held": run.held / len(poses)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--windows", default="0:200,200:400,0:450")
    parser.add_argument("--seeds", default="0,1,2,3", help="the walk's seeds (its street and its swing)")
    parser.add_argument("--backends", default="vo,map")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    jobs = [(backend, scale, window, int(seed)) for backend in args.backends.split(",") for scale in ("gt", "none")
            for window in args.windows.split(",") for seed in args.seeds.split(",")]
    with Pool(args.jobs) as pool:
        rows = pool.map(_run, jobs)
    print(f"synthetic walk, windows {args.windows}, seeds {args.seeds}: mean over them (max in brackets)")
    print("| backend | scale | ATE after Sim(3) m | ATE m (no alignment) | final rotation ° | frames held |")
    print("|---|---|---|---|---|---|")
    for backend, scale in dict.fromkeys((str(r["backend"]), str(r["scale"])) for r in rows):
        mine = [r for r in rows if r["backend"] == backend and r["scale"] == scale]

        def stat(key: str, mine: list[dict[str, object]] = mine) -> str:
            values = np.array([float(r[key]) for r in mine])  # type: ignore[arg-type]
            return "—" if np.isnan(values).all() else f"{values.mean():.3f} [{values.max():.3f}]"

        held = np.mean([float(r["held"]) for r in mine])  # type: ignore[arg-type]
        print(f"| {backend} | {scale} | {stat('ate_sim3')} | {stat('ate')} | {stat('rotation_deg')} | {held:.0%} |")
    for row in rows:
        print(f"  {row['backend']} {row['scale']} {row['window']} seed {row['seed']}: ATE Sim(3) "
              f"{row['ate_sim3']:.4f} m, final rotation {row['rotation_deg']:.2f}°, held {row['held']:.0%}")


if __name__ == "__main__":
    main()
