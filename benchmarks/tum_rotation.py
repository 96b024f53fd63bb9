"""Where a run's rotation drift comes from, against the ground truth (issue 53 item 4's diagnosis, docs/method.md).

    python -m benchmarks.tum_rotation ../shared/data/tum/rgbd_dataset_freiburg1_desk [--backend vo] [--seeds 0,1,2]

Per run: the final rotation error; per camera axis, the gain and the offset of the estimate's frame-to-frame
rotation vectors regressed on the ground truth's (error = gain · true + offset: a gain of −0.3 about x is a
rotation about x estimated 30 % short, an offset a constant turn per frame, given × the frame count); and the
final error when the worst 5 / 20 steps are replaced by the true ones (it barely falls when the drift is a steady
bias rather than a few bad frames).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from benchmarks.accuracy import benchmark_config
from vslam_core.errors import SourceError
from vslam_core.geometry import rotation_angle, so3_log
from vslam_core.pipeline import run_odometry
from vslam_core.sources.tum_rgbd import TumRgbdSource


def step_rotations(poses: np.ndarray) -> np.ndarray:
    """(N - 1, 3, 3) frame-to-frame rotations R_{i-1}ᵀ·R_i of (N, 4, 4) or (N, 3, 3+) poses."""
    rotations = poses[:, :3, :3]
    return np.einsum("nji,njk->nik", rotations[:-1], rotations[1:])


def final_error_deg(truth_steps: np.ndarray, steps: np.ndarray) -> float:
    """Degrees between the chained true and estimated steps at the last frame."""
    true, estimate = np.eye(3), np.eye(3)
    for t, e in zip(truth_steps, steps, strict=True):
        true, estimate = true @ t, estimate @ e
    return math.degrees(rotation_angle(true.T @ estimate))


def axis_gains(truth_steps: np.ndarray, steps: np.ndarray) -> list[tuple[float, float]]:
    """Per camera axis (x, y, z): (gain, offset ° a frame) of the least-squares fit error = gain · true + offset,
    with error = log(R_trueᵀ·R_est) and true = log(R_true) of each step, in degrees."""
    errors = np.degrees([so3_log(t.T @ e) for t, e in zip(truth_steps, steps, strict=True)])
    true = np.degrees([so3_log(t) for t in truth_steps])
    fits = []
    for axis in range(3):
        design = np.column_stack((true[:, axis], np.ones(len(true))))
        (gain, offset), *_ = np.linalg.lstsq(design, errors[:, axis], rcond=None)
        fits.append((float(gain), float(offset)))
    return fits


def worst_fixed_deg(truth_steps: np.ndarray, steps: np.ndarray, count: int) -> float:
    """The final error once the `count` steps farthest from the truth are replaced by the true ones."""
    errors = [rotation_angle(t.T @ e) for t, e in zip(truth_steps, steps, strict=True)]
    fixed = steps.copy()
    worst = np.argsort(errors)[::-1][:count]
    fixed[worst] = truth_steps[worst]
    return final_error_deg(truth_steps, fixed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", help="a TUM RGB-D sequence folder (its groundtruth.txt is the truth)")
    parser.add_argument("--backend", default="vo", choices=("vo", "map"))
    parser.add_argument("--seeds", default="0")
    args = parser.parse_args()
    try:
        source = TumRgbdSource(args.folder)
    except SourceError as error:
        parser.error(str(error))
    if source.ground_truth is None:
        parser.error(f"{args.folder}: no ground truth (groundtruth.txt)")
    print("| seed | final ° | gain x / y / z | offset ° x / y / z (× frames) | worst 5 fixed ° | worst 20 fixed ° |")
    print("|---|---|---|---|---|---|")
    for seed in (int(s) for s in args.seeds.split(",")):
        run = run_odometry(source, benchmark_config(None, args.backend, "gt", seed))
        poses = run.pose_array()
        truth_steps, steps = step_rotations(source.ground_truth[: len(poses)]), step_rotations(poses)
        fits = axis_gains(truth_steps, steps)
        gains = " / ".join(f"{g:+.2f}" for g, _ in fits)
        offsets = " / ".join(f"{o * len(steps):+.1f}" for _, o in fits)
        print(f"| {seed} | {final_error_deg(truth_steps, steps):.2f} | {gains} | {offsets} | "
              f"{worst_fixed_deg(truth_steps, steps, 5):.2f} | {worst_fixed_deg(truth_steps, steps, 20):.2f} |")


if __name__ == "__main__":
    main()
