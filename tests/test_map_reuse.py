"""Map reuse: the global bundle adjustment run before a map is saved, and localisation's second pass (landmarks
re-found by projection, the pose refined on them), on scenes with exact ground truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vslam_core.config import MapConfig
from vslam_core.geometry import pose_matrix, rotation_angle, so3_exp
from vslam_core.mapping.global_adjustment import adjust_at_end, adjust_map
from vslam_core.mapping.localisation_refine import match_by_projection, refine_pose
from vslam_core.mapping.map import Map
from vslam_core.mapping.map_scale import for_scale, forward_share, sideways_camera
from vslam_core.mapping.pnp import project

K = np.array([[700.0, 0.0, 610.0], [0.0, 700.0, 185.0], [0.0, 0.0, 1.0]])
SIZE = (1220, 370)


def _street(rng: np.random.Generator, count: int = 600) -> np.ndarray:
    """(count, 3) points along both sides of a street ahead of the camera (x right, y down, z forward)."""
    side = rng.choice([-1.0, 1.0], count)
    return np.column_stack((side * rng.uniform(3.0, 9.0, count), rng.uniform(-3.0, 1.5, count),
                            rng.uniform(4.0, 45.0, count)))


def _true_poses(count: int) -> np.ndarray:
    """(count, 4, 4) T_world_cam: 1.2 m forward a keyframe, turning slowly left."""
    return np.array([pose_matrix(so3_exp(np.array([0.0, -0.01 * i, 0.0])), np.array([0.05 * i, 0.0, 1.2 * i]))
                     for i in range(count)])


@pytest.fixture(scope="module")
def scene() -> tuple[Map, np.ndarray, np.ndarray, dict[int, int]]:
    return _drifted_map()


def _drifted_map() -> tuple[Map, np.ndarray, np.ndarray, dict[int, int]]:
    """A map of 8 keyframes whose poses and landmarks were perturbed (drift), its observations exact (0.3 px
    noise); returns the map, the true poses and points, and landmark id -> true point row."""
    rng = np.random.default_rng(3)
    truth = _true_poses(8)
    points = _street(rng)
    map_ = Map()
    for i, pose in enumerate(truth):
        drifted = pose_matrix(so3_exp(rng.normal(0, 0.004, 3)) @ pose[:3, :3], pose[:3, 3] + rng.normal(0, 0.15, 3))
        map_.add_keyframe(i, 0, truth[0] if i == 0 else drifted, np.zeros(0, np.int64), np.zeros((0, 2)),
                          None if i == 0 else float(np.linalg.norm(pose[:3, 3] - truth[i - 1][:3, 3])))
    rows: dict[int, int] = {}
    for row, point in enumerate(points):
        observations = {}
        for i, pose in enumerate(truth):
            pixel = project(point[None], pose, K)[0]
            if np.all(np.isfinite(pixel)) and 0 <= pixel[0] < SIZE[0] and 0 <= pixel[1] < SIZE[1]:
                observations[i] = pixel + rng.normal(0, 0.3, 2)
        if len(observations) >= 2:
            landmark = map_.add_landmark(point + rng.normal(0, 0.3, 3), observations)
            rows[landmark.id] = row
    return map_, truth, points, rows


def test_global_adjustment_brings_the_map_back_to_the_truth(
        scene: tuple[Map, np.ndarray, np.ndarray, dict[int, int]]) -> None:
    map_, truth, points, rows = scene
    before = np.array([k.T_world_cam[:3, 3] for k in map_.keyframes.values()])
    assert np.abs(before - truth[:, :3, 3]).max() > 0.2  # drifted
    adjusted = adjust_map(map_, K, MapConfig(), "gt")
    assert adjusted is not None
    assert adjusted.keyframes == 8 and adjusted.landmarks == len(rows)
    assert adjusted.mean_error_before > 5.0 and adjusted.mean_error_after < 0.5  # px
    after = np.array([k.T_world_cam for k in map_.keyframes.values()])
    np.testing.assert_array_equal(after[0], truth[0])  # the gauge: the first keyframe is held
    assert np.linalg.norm(after[:, :3, 3] - truth[:, :3, 3], axis=1).max() < 0.03  # m
    assert max(np.degrees(rotation_angle(a[:3, :3] @ t[:3, :3].T)) for a, t in zip(after, truth, strict=True)) < 0.05
    # the scale source's steps are kept (1 cm priors): the distances between keyframes are the true ones
    steps = np.linalg.norm(np.diff(after[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(steps, np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1), atol=0.01)
    landmark_error = [np.linalg.norm(map_.landmarks[i].position - points[rows[i]]) for i in map_.landmarks]
    assert np.median(landmark_error) < 0.1  # from 0.3 m (far points seen over short baselines stay vaguer)


def test_global_adjustment_frees_only_the_newest_keyframes_that_see_enough() -> None:
    """A run's adjustment at the end (`map.adjust_at_end_keyframes`): beyond the limit the oldest keyframes are
    held, and a keyframe whose landmarks were all forgotten (a long drive) is left out, not left unconstrained."""
    map_, truth, _, rows = _drifted_map()
    map_.add_keyframe(8, 0, truth[7] @ pose_matrix(np.eye(3), np.array([0.0, 0.0, 1.2])), np.zeros(0, np.int64),
                      np.zeros((0, 2)), 1.2)  # sees nothing
    before = {k: keyframe.T_world_cam.copy() for k, keyframe in map_.keyframes.items()}
    seen_by_free = sum(1 for i in rows if set(map_.landmarks[i].observations) & {4, 5, 6, 7})
    adjusted = adjust_map(map_, K, MapConfig(), "gt", max_keyframes=4)
    assert adjusted is not None
    assert (adjusted.keyframes, adjusted.free, adjusted.landmarks) == (8, 4, seen_by_free) and seen_by_free < len(rows)
    moved = {k for k, keyframe in map_.keyframes.items() if not np.array_equal(keyframe.T_world_cam, before[k])}
    assert moved == {4, 5, 6, 7}
    assert adjusted.mean_error_after < adjusted.mean_error_before / 2


def test_the_adjustment_at_the_end_is_off_for_a_camera_moving_ahead_or_after_a_loop() -> None:
    """`map.adjust_at_end` (on with --scale none: `for_scale`) runs for a camera moving sideways only (the real
    case: tests/test_tum_real.py): this street is driven straight ahead, and a closed loop stops it too; each says
    why. Nothing is moved then."""
    map_, _, _, _ = _drifted_map()
    before = [keyframe.T_world_cam.copy() for keyframe in map_.keyframes.values()]
    assert adjust_at_end(map_, K, MapConfig(), "none") is None  # off unless the scale source turns it on
    config = for_scale(MapConfig(), "none")
    assert forward_share(map_) > 0.95 and config.adjust_at_end  # drifted poses: the steps ~10° off the axis
    assert str(adjust_at_end(map_, K, config, "none")).startswith("not run: the camera moves along its optical axis")
    map_.loop_keyframes.add(1)
    assert str(adjust_at_end(map_, K, config, "none")).startswith("not run: a loop was closed")
    for keyframe, pose in zip(map_.keyframes.values(), before, strict=True):
        np.testing.assert_array_equal(keyframe.T_world_cam, pose)


def _moving_map(steps: np.ndarray, depth: float = 10.0) -> Map:
    """Keyframes of an upright camera at the cumulative (K, 3) `steps` (world = camera axes), each seeing the same
    100 landmarks `depth` ± 20 % ahead of the start."""
    rng = np.random.default_rng(4)
    points = depth * np.column_stack((rng.uniform(-0.4, 0.4, 100), rng.uniform(-0.2, 0.2, 100),
                                      rng.uniform(0.8, 1.2, 100)))
    map_ = Map()
    for i, centre in enumerate(np.cumsum(steps, axis=0)):
        map_.add_keyframe(i, 0, pose_matrix(np.eye(3), centre), np.zeros(0, np.int64), np.zeros((0, 2)), None)
    for point in points:
        map_.add_landmark(point, {i: np.zeros(2) for i in map_.keyframes})
    return map_


def test_a_camera_moving_sideways_is_told_from_a_car_and_a_standstill_counts_for_nothing() -> None:
    """`map_scale.sideways_camera` (with a scale source, at each keyframe, the newest 5): keyframes stepping 3 cm
    along the camera's x axis and a little along z, 1 m from the scene (a hand-held camera at a desk), move
    sideways, 1 m steps ahead (a car) do not, and 1 mm steps in random directions 10 m from the landmarks (a car
    waiting at a light) count for nothing (their directions are noise), so they decide nothing, alone or before
    the car drives off."""
    config = MapConfig()
    rng = np.random.default_rng(8)
    desk = _moving_map(np.array([[0.03, 0.0, 0.01]] * 6) * rng.choice([-1.0, 1.0], (6, 1)), depth=1.0)
    car = _moving_map(np.array([[0.02, 0.0, 1.0]] * 6))
    standstill = rng.normal(0.0, 1.0, (9, 3))
    waiting = _moving_map(0.001 * standstill / np.linalg.norm(standstill, axis=1, keepdims=True))
    share = sideways_camera(desk, config, "gt")
    assert share is not None and share < 0.4 and share <= config.sideways_forward_share
    assert sideways_camera(car, config, "gt") == pytest.approx(1.0, abs=1e-3)
    assert forward_share(waiting, 5) == pytest.approx(0.44, abs=0.01)  # counted, the noise would call it sideways
    assert sideways_camera(waiting, config, "gt") is None
    drives_off = _moving_map(np.vstack((0.001 * standstill[:4] / np.linalg.norm(standstill[:4], axis=1, keepdims=True),
                                        [[0.0, 0.0, 1.0]])))
    assert sideways_camera(drives_off, config, "gt") == pytest.approx(1.0)
    assert sideways_camera(desk, config, "none") is None  # --scale none has these settings already
    assert sideways_camera(desk, replace(config, sideways_as_none=False), "gt") is None
    assert sideways_camera(_moving_map(np.array([[0.03, 0.0, 0.0]] * 4), 1.0), config, "gt") is None  # 4 keyframes


def test_global_adjustment_needs_two_keyframes() -> None:
    map_ = Map()
    map_.add_keyframe(0, 0, np.eye(4), np.zeros(0, np.int64), np.zeros((0, 2)), None)
    assert adjust_map(map_, K, MapConfig(), "gt") is None


def test_landmarks_refound_by_projection_refine_the_pose() -> None:
    """600 landmarks with descriptors; the frame sees those of 400 of them inside the image (descriptors with 10
    bits flipped, pixels with 0.5 px noise) among 600 distractor features. From a pose 0.22 m and 0.3° off,
    projection finds the right features and the refined pose is within 3 cm and 0.05° of the truth."""
    rng = np.random.default_rng(5)
    points = _street(rng)
    truth = _true_poses(3)[2]
    landmark_descriptors = rng.integers(0, 256, (len(points), 32), dtype=np.uint8)
    seen = np.sort(rng.choice(len(points), 400, replace=False))
    pixels_true = project(points[seen], truth, K)
    with np.errstate(invalid="ignore"):
        inside = np.all((pixels_true >= 0) & (pixels_true < SIZE), axis=1)
    seen, pixels_true = seen[inside], pixels_true[inside]
    noisy = landmark_descriptors[seen].copy()
    for row in noisy:
        bits = rng.choice(256, 10, replace=False)
        row[bits // 8] ^= (1 << (bits % 8)).astype(np.uint8)
    pixels = np.concatenate((pixels_true + rng.normal(0, 0.5, pixels_true.shape),
                             rng.uniform((0, 0), SIZE, (600, 2)))).astype(np.float32)
    descriptors = np.concatenate((noisy, rng.integers(0, 256, (600, 32), dtype=np.uint8)))
    guess = pose_matrix(so3_exp(np.radians([0.0, 0.3, 0.0])) @ truth[:3, :3], truth[:3, 3] + [0.1, 0.0, 0.2])
    which, feature = match_by_projection(project(points, guess, K), landmark_descriptors, pixels, descriptors,
                                         radius_px=15.0)
    assert len(which) >= 0.8 * len(seen)  # the nearest points move more than the radius
    correct = {int(s): n for n, s in enumerate(seen.tolist())}
    assert np.mean([correct.get(int(w), -1) == f for w, f in zip(which, feature, strict=True)]) > 0.98
    assert len(set(feature.tolist())) == len(feature)  # each feature used once
    solution = refine_pose(points[which], pixels[feature].astype(np.float64), K, guess, threshold_px=2.0)
    assert solution.T_world_cam is not None
    assert np.linalg.norm(solution.T_world_cam[:3, 3] - truth[:3, 3]) < 0.03
    assert np.degrees(rotation_angle(solution.T_world_cam[:3, :3] @ truth[:3, :3].T)) < 0.05
    assert solution.inlier_mask.mean() > 0.95
