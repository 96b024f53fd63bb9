"""A frame tracked between two keyframes follows the refinements of both (`mapping.map.NextKeyframeAnchors`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vslam_core.config import EngineConfig
from vslam_core.geometry import interpolate_pose, invert_pose, pose_matrix, rotation_angle
from vslam_core.mapping.map import Keyframe, Map, NextKeyframeAnchors
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import FrameRange
from vslam_core.sources.tum_rgbd import TumRgbdSource
from vslam_core.trajectory.metrics import ate


def _keyframe(id_: int, position: int, pose: np.ndarray, segment: int = 0) -> Keyframe:
    return Keyframe(id_, position, segment, pose, np.zeros(0, np.int64), np.zeros((0, 2), np.float32), None)


def _turn(degrees: float, x: float) -> np.ndarray:
    angle = np.radians(degrees)
    rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    return pose_matrix(rotation, np.array([x, 0.0, 0.0]))


def _street(segment_of_second: int = 0) -> tuple[Map, dict[int, tuple[int, np.ndarray]], list[np.ndarray]]:
    """Keyframes at frames 0 and 10 of a camera moving 1 m a frame along z and turning 1° a frame; frames 1-9
    stored relative to the first (as tracking stores them), the later keyframe's anchors made."""
    tracked = [pose_matrix(_turn(i, 0.0)[:3, :3], np.array([0.0, 0.0, float(i)])) for i in range(11)]
    map_ = Map()
    map_.keyframes[0] = _keyframe(0, 0, tracked[0].copy())
    map_.keyframes[1] = _keyframe(1, 10, tracked[10].copy(), segment_of_second)
    relative = {i: (0, invert_pose(tracked[0]) @ tracked[i]) for i in range(1, 10)}
    return map_, relative, tracked


def _poses(map_: Map, relative: dict[int, tuple[int, np.ndarray]], anchors: NextKeyframeAnchors) -> list[np.ndarray]:
    return [anchors.pose(map_, i, relative[i], map_.keyframes[0].T_world_cam @ relative[i][1]) for i in range(1, 10)]


def test_without_a_refinement_the_frames_stay_where_they_were_tracked() -> None:
    map_, relative, tracked = _street()
    anchors = NextKeyframeAnchors()
    anchors.keyframe_made(map_, 0, 1)
    assert list(anchors.anchors) == [0]  # one pose a keyframe, none a frame
    for i, pose in enumerate(_poses(map_, relative, anchors), start=1):
        np.testing.assert_allclose(pose, tracked[i], atol=1e-9)


def test_the_later_keyframes_correction_is_spread_along_the_frames() -> None:
    """The later keyframe moved 0.8 m sideways and turned 2° by a refinement, the earlier left alone: frame i of the
    ten moves by i/10 of that (`interpolate_pose`), where one anchor alone would leave all of them behind."""
    map_, relative, tracked = _street()
    anchors = NextKeyframeAnchors()
    anchors.keyframe_made(map_, 0, 1)
    correction = _turn(2.0, 0.8)
    map_.keyframes[1].T_world_cam = correction @ tracked[10]
    for i, pose in enumerate(_poses(map_, relative, anchors), start=1):
        expected = interpolate_pose(tracked[i], correction @ tracked[i], i / 10)
        np.testing.assert_allclose(pose, expected, atol=1e-9)
    ninth = _poses(map_, relative, anchors)[8]  # frame 9: nine tenths of the way to the corrected pose
    np.testing.assert_allclose(ninth[:3, 3], 0.9 * (correction @ tracked[9])[:3, 3] + 0.1 * tracked[9][:3, 3],
                               atol=1e-9)
    turned = _poses(map_, relative, anchors)[4]  # frame 5: half the 2° turn
    assert np.degrees(rotation_angle(tracked[5][:3, :3].T @ turned[:3, :3])) == pytest.approx(1.0, abs=1e-6)


def test_a_new_map_segment_or_a_culled_keyframe_leaves_one_anchor() -> None:
    map_, relative, tracked = _street(segment_of_second=1)  # the later keyframe starts a new map segment
    anchors = NextKeyframeAnchors()
    anchors.keyframe_made(map_, 0, 1)
    assert anchors.anchors == {}
    map_, relative, tracked = _street()
    anchors.keyframe_made(map_, 0, 1)
    map_.keyframes[1].T_world_cam = _turn(2.0, 0.8) @ tracked[10]
    del map_.keyframes[1]  # culled: its frames' anchors are not followed
    for i, pose in enumerate(_poses(map_, relative, anchors), start=1):
        np.testing.assert_allclose(pose, tracked[i], atol=1e-9)
    map_.keyframes[2] = _keyframe(2, 20, tracked[10].copy())
    del map_.keyframes[0]
    anchors.keyframe_made(map_, 1, 2)  # a culled keyframe's entry is forgotten at the next keyframe
    assert anchors.anchors == {}


def test_the_frames_before_a_hand_held_maps_second_keyframe_follow_it(tum_root: Path) -> None:
    """TUM fr1_desk 0:40, the default engine with ground-truth scale. The two-view steps of frames 3, 4 and 8 point
    85-94° off the truth (2 cm at 1 m), so the keyframe at frame 10 was placed 9 cm off; the adjustments took it
    back to 2 cm. Moved with the first keyframe alone, frames 3-9 stayed 3.0-9.3 cm off (ATE 4.20 cm unaligned, 2.54
    cm after Sim(3)); following both keyframes, 0.4-2.7 cm (2.92 and 1.16 cm)."""
    source = TumRgbdSource(tum_root / "rgbd_dataset_freiburg1_desk", frames=FrameRange.parse("0:40"))
    results: list[FrameResult] = []
    run = run_odometry(source, EngineConfig(scale="gt", threads=1), (lambda _f, r: results.append(r),))
    truth, poses = source.ground_truth, run.pose_array()
    assert truth is not None
    keyframes = [r.position for r in results if r.mapping is not None and r.mapping.keyframe is not None]
    assert keyframes[:2] == [0, 10]
    errors = np.linalg.norm(poses[1:10, :3, 3] - truth[1:10, :3, 3], axis=1)
    assert errors.max() < 0.04, errors
    assert ate(truth, poses, "none") < 0.035 and ate(truth, poses, "sim3") < 0.018
