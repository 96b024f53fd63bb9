"""Frame by frame: where the map placed each frame of a KITTI window and why PnP failed when it did.

    python -m benchmarks.map_frames ../shared/data/kitti 00 150:300:2 [--scale none] [--seed 0] [--set key=value ...]

One line a frame: the mode (map, two_view, ...), PnP's failure (`too_few_in_view`, `too_few_matched`, `ransac`,
`disagrees`) or its rejection, the local map's landmarks the prediction projected into the image, the landmarks
matched (tracked or found by the search) and PnP's inliers, the widest search window, the step's rotation error
and length over the ground truth's (after the best Sim(3) with `--scale none`), and the keyframe made there
(why, landmarks observed and new, culled). Then the counts of (mode, failure) and the run's ATE and t_err.
`--set` changes a `[map]` setting (e.g. `--set starving_keyframes=false`). Deterministic, like every run.
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.accuracy import benchmark_config
from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose, rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import ate, kitti_errors, sim3_aligned


def with_settings(config: EngineConfig, settings: list[str]) -> EngineConfig:
    """`config` with `[map]` settings given as key=value (the value parsed as the field's type)."""
    types = {f.name: type(getattr(config.map, f.name)) for f in fields(config.map)}
    changes: dict[str, Any] = {}
    for setting in settings:
        key, _, value = setting.partition("=")
        if key not in types or not value:
            raise SystemExit(f"--set {setting!r}: not a [map] setting key=value")
        kind = types[key]
        changes[key] = value.lower() in ("1", "true", "yes") if kind is bool else kind(value)
    return replace(config, map=replace(config.map, **changes))


def frame_line(i: int, result: FrameResult, gt: np.ndarray, poses: np.ndarray) -> str:
    """One frame's line (see the module docstring); `poses` already aligned to `gt` when unscaled."""
    mapping = result.mapping
    assert mapping is not None
    pnp = mapping.pnp
    failure = "-" if pnp is None else str(pnp.failure) if pnp.failure is not None else \
        f"rejected: {pnp.rejected}" if pnp.rejected else "ok"
    true, estimate = invert_pose(gt[i - 1]) @ gt[i], invert_pose(poses[i - 1]) @ poses[i]
    rotation = math.degrees(rotation_angle(true[:3, :3].T @ estimate[:3, :3]))
    length = float(np.linalg.norm(true[:3, 3]))
    ratio = float(np.linalg.norm(estimate[:3, 3])) / length if length > 0 else math.nan
    matched = len(pnp.landmark_ids) if pnp is not None else 0
    inliers = int(pnp.inlier_mask.sum()) if pnp is not None else 0
    keyframe = mapping.keyframe
    made = (f"  keyframe ({keyframe.why}): observes {keyframe.observed_landmarks}, new {keyframe.new_landmarks}, "
            f"culled {keyframe.culled_landmarks}") if keyframe is not None else ""
    return (f"{i:4d} {mapping.mode.value:11s} {failure[:34]:34s} in view {pnp.in_view if pnp else -1:4d} "
            f"matched {matched:4d} inliers {inliers:4d} window {pnp.search_radius_px if pnp else 0:4.0f} px "
            f"rotation error {rotation:5.2f}° step/true {ratio:5.3f}{made}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kitti", type=Path)
    parser.add_argument("sequence")
    parser.add_argument("frames", help="a:b or a:b:step")
    parser.add_argument("--scale", choices=("gt", "height", "none"), default="none")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], dest="settings", metavar="KEY=VALUE")
    args = parser.parse_args(argv)
    source = KittiSource(args.kitti, sequence=args.sequence, frames=FrameRange.parse(args.frames))
    if source.ground_truth is None:
        parser.error(f"KITTI {args.sequence}: no ground truth")
    config = with_settings(benchmark_config(None, "map", args.scale, args.seed), args.settings)
    results: list[FrameResult] = []
    run = run_odometry(source, config, (lambda _frame, result: results.append(result),))
    poses = run.pose_array()
    gt = source.ground_truth[:len(poses)]
    scored = sim3_aligned(gt, poses) if args.scale == "none" else poses
    counts: Counter[tuple[str, str]] = Counter()
    for i, result in enumerate(results[1:], start=1):
        print(frame_line(i, result, gt, scored))
        assert result.mapping is not None
        pnp = result.mapping.pnp
        counts[(result.mapping.mode.value, "-" if pnp is None else str(pnp.failure or "ok"))] += 1
    print("frames by (mode, PnP failure): " + ", ".join(f"{m} {f}: {n}" for (m, f), n in counts.most_common()))
    print(f"KITTI {args.sequence} {args.frames} --scale {args.scale} seed {args.seed}: ATE after Sim(3) "
          f"{ate(gt, poses, 'sim3'):.3f} m, t_err {kitti_errors(gt, scored)[0]:.2f} %"
          f"{' (after Sim(3))' if args.scale == 'none' else ''}")


if __name__ == "__main__":
    main()
