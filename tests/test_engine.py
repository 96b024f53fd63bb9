"""The engine end to end: accuracy against ground truth, one pose per frame, determinism."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.config import EngineConfig
from vslam_core.engine import Odometry
from vslam_core.errors import ConfigError
from vslam_core.geometry import normalise_points, rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameStatus, Reason, TrackFate
from vslam_core.scale import GroundTruthScale, make_scale_provider
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.trajectory.metrics import kitti_errors


@pytest.fixture(scope="module")
def kitti_runs(kitti_root: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Default engine on KITTI 00 and 05, frames 0–299, ground-truth scale: (gt, estimate) per sequence."""
    runs = {}
    for sequence in ("00", "05"):
        source = KittiSource(kitti_root, sequence=sequence, frames=FrameRange(0, 300))
        result = run_odometry(source, EngineConfig())
        assert source.ground_truth is not None
        runs[sequence] = (source.ground_truth, result.pose_array())
    return runs


@pytest.mark.kitti
def test_kitti_accuracy_beats_the_paper_configuration(kitti_runs: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """Issue target: mean over 00 and 05 of t_err ≤ 1 % and r_err ≤ 1 °/100 m; each sequence better than
    the paper configuration's average (00: 1.2–1.4 %, 1.6–1.7 °/100 m; 05: 0.7–2.0 %, 0.8–2.0 °/100 m)."""
    errors = {seq: kitti_errors(gt, est) for seq, (gt, est) in kitti_runs.items()}
    for gt, est in kitti_runs.values():
        assert len(est) == len(gt) == 300
    assert errors["00"][0] < 1.2 and errors["00"][1] < 1.6
    assert errors["05"][0] < 0.8 and errors["05"][1] < 0.8
    assert np.mean([e[0] for e in errors.values()]) <= 1.0
    assert np.mean([e[1] for e in errors.values()]) <= 1.0


def test_synthetic_street_is_tracked_within_one_percent() -> None:
    """At half the image size (a quarter of the rendering time; fewer pixels per feature, so no easier): the
    renderer's full-size frames are tested in test_synthetic.py and the engine's full size on KITTI above.
    150 frames, ~150 m (t_err's segments start at 100 m): measured 0.11 % and 0.35 °/100 m (0:300: 0.19 %,
    0.48 °/100 m)."""
    source = SyntheticStreet(frames=FrameRange(0, 150), resolution=0.5)
    result = run_odometry(source, EngineConfig())
    assert source.ground_truth is not None
    t_err, r_err = kitti_errors(source.ground_truth, result.pose_array())
    assert result.frames == 150
    assert t_err < 1.0
    assert r_err < 1.0


class _Rendered:
    """A source's frames rendered once and replayed: the same input for every run (the synthetic street's own
    determinism is tested in test_synthetic.py; rendering is most of a synthetic run's time)."""

    def __init__(self, source: SyntheticStreet) -> None:
        self.name, self.intrinsics, self.indices = source.name, source.intrinsics, source.indices
        self.camera_height, self.ground_truth = source.camera_height, source.ground_truth
        self._frames = list(source)

    def __len__(self) -> int:
        return len(self._frames)

    def __iter__(self) -> Iterator[Frame]:
        return iter(self._frames)


def test_same_input_and_config_give_the_identical_trajectory() -> None:
    """At half the image size (the renderer is not the subject: a quarter of its time, and fewer corners a frame):
    measured: the two runs bit-identical, seed 7's poses up to 0.35 m from seed 0's (full size: 0.03 m)."""
    source = _Rendered(SyntheticStreet(frames=FrameRange(0, 40), resolution=0.5))
    first = run_odometry(source, EngineConfig()).pose_array()
    second = run_odometry(source, EngineConfig()).pose_array()
    assert np.array_equal(first, second)
    other_seed = dataclasses.replace(EngineConfig(), pose=dataclasses.replace(EngineConfig().pose, seed=7))
    assert not np.array_equal(first, run_odometry(source, other_seed).pose_array())


def test_every_frame_gets_a_pose_and_a_frozen_frame_holds_it() -> None:
    """Repeating a frame (no motion) keeps the previous pose with a reason; the run goes on."""
    source = SyntheticStreet(frames=FrameRange(0, 12))
    frames = list(source)
    repeated = frames[:6] + [frames[5]] * 3 + frames[6:]
    assert source.ground_truth is not None
    gt = source.ground_truth
    scale_gt = np.concatenate((gt[:6], np.repeat(gt[5:6], 3, axis=0), gt[6:]))
    engine = Odometry(source.intrinsics, EngineConfig(), GroundTruthScale(scale_gt))
    results = [engine.process(Frame(i, None, f.image)) for i, f in enumerate(repeated)]
    assert len(results) == len(repeated)
    assert results[0].status == FrameStatus.INIT
    for held in results[6:9]:
        assert held.status == FrameStatus.HELD and held.reason == Reason.STATIONARY
        assert np.array_equal(held.T_world_cam, results[5].T_world_cam)
    assert results[9].status == FrameStatus.OK
    assert results[9].keyframe_position == 5  # measured from the last accepted frame
    assert np.linalg.norm(results[-1].T_world_cam[:3, 3] - gt[-1, :3, 3]) < 0.3


def test_frame_result_holds_every_intermediate() -> None:
    source = SyntheticStreet(frames=FrameRange(0, 3))
    assert source.ground_truth is not None
    engine = Odometry(source.intrinsics, EngineConfig(), GroundTruthScale(source.ground_truth))
    first, second, _ = (engine.process(f) for f in source)
    assert len(first.new_corners) > 500 and len(first.new_corner_ids) == len(first.new_corners)
    assert second.status == FrameStatus.OK
    m = len(second.track_ids)
    assert second.track_prev.shape == second.track_cur.shape == (m, 2)
    assert np.array_equal(second.track_ids, first.new_corner_ids)  # ids are stable across frames
    assert set(np.unique(second.track_fate)) <= {int(f) for f in TrackFate}
    assert second.inlier_count > 200
    # four candidates; the chosen one has the most points in front and matches cv2.recoverPose
    assert len(second.candidate_poses) == 4 and second.chosen_candidate is not None
    counts = [c.in_front for c in second.candidate_poses]
    assert counts[second.chosen_candidate] == max(counts)
    inliers = second.track_fate >= TrackFate.CHIRALITY_FAILED
    p_cur, p_prev = second.track_cur[inliers].astype(np.float64), second.track_prev[inliers].astype(np.float64)
    assert second.essential is not None
    _, r_cv, _, _ = cv2.recoverPose(second.essential, p_cur, p_prev, source.intrinsics.K)
    assert np.allclose(r_cv, second.candidate_poses[second.chosen_candidate].rotation, atol=1e-9)
    # refined motion is close to ground truth, scale from ground truth
    gt_step = np.linalg.inv(source.ground_truth[0]) @ source.ground_truth[1]
    assert second.T_key_cur is not None
    assert np.degrees(rotation_angle(second.T_key_cur[:3, :3].T @ gt_step[:3, :3])) < 0.1
    assert np.linalg.norm(second.T_key_cur[:3, 3]) == pytest.approx(np.linalg.norm(gt_step[:3, 3]))
    # triangulated points are in front of the camera, in world coordinates
    assert len(second.points_world) > 100
    cam = (second.points_world - second.T_world_cam[:3, 3]) @ second.T_world_cam[:3, :3]
    assert np.all(cam[:, 2] > 0)
    assert normalise_points(second.track_cur, source.intrinsics.K).shape == (m, 2)


def test_gt_scale_without_ground_truth_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="ground truth"):
        make_scale_provider(EngineConfig(scale="gt"), None, np.eye(3), None)
