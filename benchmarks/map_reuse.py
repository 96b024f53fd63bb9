"""Map reuse on real frames (issue 26): a map saved from the even frames of a KITTI window (map backend, scale
from ground truth), the odd frames localised in it. Prints a table per sequence:

    python -m benchmarks.map_reuse ../shared/data/kitti [--sequences 00,05] [--frames 0:300]

- run ATE: the mapping run's poses (even frames, after the run, before the global bundle adjustment) against the
  ground truth, no alignment (both in the first frame's camera frame, which is the map's frame); its SE(3)-aligned
  ATE (the error left once the drive's placement is removed) and that alignment's rotation (degrees: how far the
  whole drive is turned); map keyframes ATE: the saved keyframes' poses;
- localised: the share of odd frames placed in the map;
- odd ATE vs GT: the odd frames' poses against the ground truth, no alignment (the issue's figure, target
  <= 0.3 m);
- odd ATE vs run: the odd frames against the mapping run's trajectory at the same instants (each odd frame
  halfway between its even neighbours: position midway, rotation on the geodesic) - localisation quality
  apart from the map's own error;
- vs keyframes: the same against the saved map's keyframe poses, interpolated by frame index (only what the
  map file holds), and its RMS along the map cameras' x (right), y (down) and z (forward) axes (linear
  interpolation assumes a constant speed between keyframes up to 20 source frames apart: much of its z error is
  that);
- vs nearest keyframe + GT motion: against the nearest keyframe's map pose moved by the ground truth's motion from
  that keyframe to the frame: what a perfect localisation in this map would give (the map's own error stays in
  the reference), so this is the localisation's own error;
- the last two over the localised frames only (a frame that is not localised keeps the last pose: a frame's
  travel, ~1 m, off).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from vslam.runs import map_saver
from vslam_core.config import EngineConfig
from vslam_core.geometry import interpolate_pose, rotation_angle
from vslam_core.mapping.storage import load_map
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameStatus
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import ate, umeyama_alignment


def rms(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(error) ** 2)))


def position_errors(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N,) distances between the (N, 4, 4) poses' positions."""
    return np.asarray(np.linalg.norm(estimate[:, :3, 3] - reference[:, :3, 3], axis=1))


def in_camera(estimate: np.ndarray, reference: np.ndarray) -> list[float]:
    """RMS of the position errors along the reference cameras' x (right), y (down), z (forward) axes."""
    local = np.einsum("nji,nj->ni", reference[:, :3, :3], estimate[:, :3, 3] - reference[:, :3, 3])
    return [rms(local[:, axis]) for axis in range(3)]


def from_nearest_keyframe(keyframe_frames: np.ndarray, keyframe_poses: np.ndarray, truth: np.ndarray,
                          at: np.ndarray) -> np.ndarray:
    """(N, 4, 4) reference poses at source frames `at`: the nearest keyframe's map pose moved by the ground
    truth's relative motion from that keyframe's frame to the frame (`truth`: the whole sequence's poses). What
    a perfect localisation in this map would give: it keeps the map's own error, not an interpolation's."""
    nearest = np.abs(at[:, None] - keyframe_frames[None, :]).argmin(axis=1)
    return np.array([keyframe_poses[k] @ np.linalg.inv(truth[keyframe_frames[k]]) @ truth[frame]
                     for k, frame in zip(nearest, at, strict=True)]).reshape(-1, 4, 4)


def interpolated(frames: np.ndarray, poses: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses at source frames `at` from (K, 4, 4) poses at sorted source frames `frames` (geodesic rotation,
    linear position); only the frames inside [frames[0], frames[-1]]: returns (kept mask, poses)."""
    kept = (at >= frames[0]) & (at <= frames[-1])
    out = []
    for frame in at[kept]:
        after = int(np.searchsorted(frames, frame))
        if frames[after] == frame:
            out.append(poses[after])
            continue
        before = after - 1
        fraction = (frame - frames[before]) / (frames[after] - frames[before])
        out.append(interpolate_pose(poses[before], poses[after], float(fraction)))
    return kept, np.array(out).reshape(-1, 4, 4)


def measure(root: Path, sequence: str, start: int, stop: int, config: EngineConfig, folder: Path,
            adjust: bool) -> dict[str, float]:
    even = KittiSource(root, sequence=sequence, frames=FrameRange(start, stop, 2))
    odd = KittiSource(root, sequence=sequence, frames=FrameRange(start + 1, stop, 2))
    path = folder / f"{sequence}-even"
    mapping_config = config if adjust else replace(config, map=replace(config.map, adjust_at_end=False))
    mapping = run_odometry(even, mapping_config, finish=map_saver(path, even, mapping_config, adjust))
    mapped = mapping.pose_array()
    prior = load_map(path, odd.intrinsics)
    statuses: list[FrameStatus] = []
    localised = run_odometry(odd, config, prior_map=prior, sinks=(lambda _f, r: statuses.append(r.status),))
    odd_poses = localised.pose_array()
    placed = np.array([status == FrameStatus.OK for status in statuses])  # the others keep the last pose
    # the ground truth in the map's frame: the first (even) frame's camera (a source's own ground truth starts at
    # its first frame: the whole sequence's is re-based here)
    whole = KittiSource(root, sequence=sequence).ground_truth
    assert whole is not None
    origin = np.linalg.inv(whole[start])
    truth_even = origin @ whole[np.array(even.indices)]
    truth_odd = origin @ whole[np.array(odd.indices)]
    even_frames = np.array(even.indices)
    odd_frames = np.array(odd.indices)
    kept, map_at_odd = interpolated(even_frames, mapped, odd_frames)
    order = np.argsort(prior.frame_indices)
    kept_kf, keyframes_at_odd = interpolated(prior.frame_indices[order], prior.poses[order], odd_frames)
    truth_keyframes = origin @ whole[prior.frame_indices]
    nearest_reference = from_nearest_keyframe(prior.frame_indices, prior.poses, whole, odd_frames)
    return {
        "map_ate": rms(position_errors(mapped, truth_even)),
        "keyframe_ate": rms(position_errors(prior.poses, truth_keyframes)),
        "map_ate_se3": ate(truth_even, mapped, "se3"),
        "alignment_deg": float(np.degrees(rotation_angle(
            umeyama_alignment(mapped[:, :3, 3].T, truth_even[:, :3, 3].T, with_scale=False)[0]))),
        "localised": 100.0 * localised.tracked / len(odd_poses),
        "odd_ate_gt": rms(position_errors(odd_poses, truth_odd)),
        "odd_ate_map": rms(position_errors(odd_poses[kept], map_at_odd)),
        "odd_ate_keyframes": rms(position_errors(odd_poses[kept_kf], keyframes_at_odd)),
        **dict(zip(("odd_x", "odd_y", "odd_z"), in_camera(odd_poses[kept_kf], keyframes_at_odd), strict=True)),
        "odd_ate_nearest": rms(position_errors(odd_poses, nearest_reference)),
        "odd_ate_gt_placed": rms(position_errors(odd_poses[placed], truth_odd[placed])),
        "odd_ate_nearest_placed": rms(position_errors(odd_poses[placed], nearest_reference[placed])),
        "keyframes": float(len(prior.keyframe_ids)),
        "landmarks": float(len(prior.landmark_ids)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--no-adjust", action="store_true", help="save the map without the global bundle adjustment")
    args = parser.parse_args()
    start, stop = (int(v) for v in args.frames.split(":")[:2])
    config = EngineConfig(backend="map", scale="gt")
    adjusted = "without" if args.no_adjust else "with"
    print(f"KITTI, map from frames {start}:{stop}:2 ({adjusted} the global bundle adjustment), odd frames localised "
          "in it (ATE in m, no alignment unless said)")
    print("| seq | keyframes | landmarks | run ATE | run ATE (SE(3)-aligned) | its rotation ° | map keyframes ATE | "
          "localised | odd ATE vs GT | odd ATE vs run | odd ATE vs keyframes (x / y / z) | odd ATE vs nearest keyframe "
          "+ GT motion | localised frames only: vs GT / vs nearest keyframe + GT motion |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for sequence in args.sequences.split(","):
            r = measure(args.root, sequence, start, stop, config, Path(folder), not args.no_adjust)
            print(f"| {sequence} | {r['keyframes']:.0f} | {r['landmarks']:.0f} | {r['map_ate']:.3f} | "
                  f"{r['map_ate_se3']:.3f} | {r['alignment_deg']:.3f} | {r['keyframe_ate']:.3f} | "
                  f"{r['localised']:.1f} % | "
                  f"{r['odd_ate_gt']:.3f} | {r['odd_ate_map']:.3f} | "
                  f"{r['odd_ate_keyframes']:.3f} ({r['odd_x']:.3f} / {r['odd_y']:.3f} / {r['odd_z']:.3f}) | "
                  f"{r['odd_ate_nearest']:.3f} | {r['odd_ate_gt_placed']:.3f} / {r['odd_ate_nearest_placed']:.3f} |",
                  flush=True)


if __name__ == "__main__":
    main()
