"""Real hand-held frames: the TUM RGB-D sequences in ../shared/data/tum (fr1_xyz, fr1_desk; 200 frames each, 30 Hz).

    python -m benchmarks.tum ../shared/data/tum [--sequences xyz,desk] [--backends vo,map] [--jobs 2]

Each backend runs with ground-truth scale and with `--scale none`; per row: ATE after the best Sim(3) alignment,
ATE without alignment (ground-truth scale only), the final rotation error, frames held (status held), steps held
to the motion model's direction (health ``step_held``, vo), and the steps reversed
against the ground truth (the estimated step's direction at cosine < 0 with the true one, among steps whose true
length is at least `MIN_STEP_M`; `reversed_steps`). Ground truth is interpolated at the frames' stamps
(vslam_core/sources/tum_rgbd.py).
"""

from __future__ import annotations

import argparse
import math
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose, rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, Reason
from vslam_core.sources.base import Frame
from vslam_core.sources.tum_rgbd import TumRgbdSource
from vslam_core.trajectory.metrics import ate

#: A true frame-to-frame step shorter than this (m) has no direction worth scoring (mocap noise is ~1 mm).
MIN_STEP_M = 0.003


def reversed_steps(truth: np.ndarray, poses: np.ndarray, min_step_m: float = MIN_STEP_M) -> tuple[list[int], int]:
    """Frames whose estimated step from the previous frame (in the previous camera's frame) points against the
    true one (cosine < 0), among the (N, 4, 4) poses' steps whose true length is ≥ `min_step_m` and whose
    estimate moved at all. Returns (the reversed positions, how many steps were scored)."""
    bad, scored = [], 0
    for i in range(1, len(poses)):
        true_step = (invert_pose(truth[i - 1]) @ truth[i])[:3, 3]
        step = (invert_pose(poses[i - 1]) @ poses[i])[:3, 3]
        if np.linalg.norm(true_step) < min_step_m or np.linalg.norm(step) == 0.0:
            continue
        scored += 1
        if float(true_step @ step) < 0.0:
            bad.append(i)
    return bad, scored


def _run(job: tuple[str, str, str, str]) -> dict[str, object]:
    """One run, in a pool worker (threads = 1; trajectories are identical for any threads value)."""
    root, sequence, backend, scale = job
    source = TumRgbdSource(Path(root) / f"rgbd_dataset_freiburg1_{sequence}")
    held_steps: list[int] = []  # frames whose step direction was held to the motion model's (health step_held)

    def sink(_frame: Frame, result: FrameResult) -> None:
        if Reason.STEP_HELD in result.health.reasons:
            held_steps.append(result.position)

    config = EngineConfig(backend=backend, scale=scale, threads=1)  # type: ignore[arg-type]
    run = run_odometry(source, config, sinks=(sink,))
    truth, poses = source.ground_truth, run.pose_array()
    assert truth is not None
    bad, scored = reversed_steps(truth, poses)
    return {"sequence": sequence, "backend": backend, "scale": scale, "ate_sim3": ate(truth, poses, "sim3"),
            "ate": ate(truth, poses, "none") if scale == "gt" else math.nan,
            "rotation_deg": math.degrees(rotation_angle(truth[-1, :3, :3].T @ poses[-1, :3, :3])),
            "held": run.held, "steps_held": len(held_steps), "frames": len(poses), "reversed": bad, "scored": scored}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", help="the folder holding rgbd_dataset_freiburg1_<sequence>/")
    parser.add_argument("--sequences", default="xyz,desk")
    parser.add_argument("--backends", default="vo,map")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    jobs = [(args.root, sequence, backend, scale) for sequence in args.sequences.split(",")
            for backend in args.backends.split(",") for scale in ("gt", "none")]
    with Pool(args.jobs) as pool:
        rows = pool.map(_run, jobs)
    print("| sequence | backend | scale | ATE Sim(3) cm | ATE cm (no alignment) | final rotation ° | held | "
          "steps held | reversed steps |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        unaligned = "—" if math.isnan(float(r["ate"])) else f"{100 * float(r['ate']):.1f}"  # type: ignore[arg-type]
        print(f"| fr1_{r['sequence']} | {r['backend']} | {r['scale']} | {100 * float(r['ate_sim3']):.1f} | "  # type: ignore[arg-type]
              f"{unaligned} | {float(r['rotation_deg']):.1f} | {r['held']}/{r['frames']} | {r['steps_held']} | "  # type: ignore[arg-type]
              f"{len(r['reversed'])}/{r['scored']} {r['reversed']} |")  # type: ignore[arg-type]


if __name__ == "__main__":
    main()
