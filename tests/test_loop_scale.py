"""Loop closing with --scale none: the scale of a loop edge (candidate map units per query map unit) measured
from the landmarks both keyframes see, and what follows a Sim(3) correction (frames, the map's speed)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam_core.config import LoopConfig
from vslam_core.geometry import pose_matrix
from vslam_core.lens import distort_pixels
from vslam_core.loop.closing import rescale_relative
from vslam_core.loop.places import KeyframePlace
from vslam_core.loop.verification import map_scale, verify
from vslam_core.mapping.map_scale import MapSpeed
from vslam_core.results import LoopClosed
from vslam_core.sources.base import CameraIntrinsics

CAMERA = CameraIntrinsics(718.9, 718.9, 607.2, 185.2, 1241, 376)  # KITTI 00's pinhole
K = CAMERA.K
T_CANDIDATE_QUERY = pose_matrix(cv2.Rodrigues(np.array([0.0, 0.05, 0.0]))[0], np.array([0.3, 0.0, -1.5]))
SCALE = 0.8  # candidate units per query unit


def _place(points_cam: np.ndarray, descriptors: np.ndarray, pixels: np.ndarray | None = None,
           features: np.ndarray | None = None) -> KeyframePlace:
    empty = np.zeros((0, 32), np.uint8)
    return KeyframePlace(
        keyframe_id=0, position=0, segment=0,
        pixels=np.zeros((0, 2), np.float32) if pixels is None else pixels.astype(np.float32),
        descriptors=empty if features is None else features, point_ids=np.arange(len(points_cam)),
        points_cam=points_cam, point_pixels=np.zeros((len(points_cam), 2), np.float32),
        point_descriptors=descriptors, thumbnail=np.zeros((0, 0), np.uint8))


def _shared_landmarks(rng: np.random.Generator, count: int, off_ray: int) -> tuple[KeyframePlace, KeyframePlace]:
    """`count` landmarks seen by both keyframes (same descriptors): in the query's frame (query units) and in the
    candidate's (candidate units, SCALE times the query's); the first `off_ray` matched to a wrong landmark of
    the candidate, 2.5-4 times as far away in another direction (what wrong descriptor matches give)."""
    query_points = rng.uniform([-8, -2, 6], [8, 2, 30], (count, 3))
    in_candidate_units = SCALE * query_points * rng.normal(1.0, 0.01, (count, 1))  # 1 % depth noise
    candidate_points = in_candidate_units @ T_CANDIDATE_QUERY[:3, :3].T + T_CANDIDATE_QUERY[:3, 3]
    wrong = rng.uniform([-8, -2, 6], [8, 2, 30], (off_ray, 3)) * rng.uniform(2.5, 4.0, (off_ray, 1))
    candidate_points[:off_ray] = SCALE * wrong @ T_CANDIDATE_QUERY[:3, :3].T + T_CANDIDATE_QUERY[:3, 3]
    descriptors = rng.integers(0, 256, (count, 32), dtype=np.uint8)
    return _place(query_points, descriptors), _place(candidate_points, descriptors)


def test_loop_edge_scale_ignores_matches_off_the_ray() -> None:
    """A true match lies on the same ray from the query camera in both maps, only its depth differs (by the
    scale); wrong matches do not. With 60 % wrong matches, all farther, the median of every ratio would be
    off by > 2x; the ratio over the matches on the same ray is the scale."""
    query, candidate = _shared_landmarks(np.random.default_rng(3), count=40, off_ray=24)
    scale = map_scale(query, candidate, T_CANDIDATE_QUERY, ratio=0.8)
    assert scale is not None
    assert abs(scale - SCALE) < 0.01 * SCALE


def test_a_loop_whose_scale_cannot_be_measured_is_rejected_with_scale_none() -> None:
    """PnP verifies the place (60 landmarks of the candidate seen in the query's features), but only 3 of the
    landmarks both keyframes hold lie on the same ray: with --scale none the edge's scale is unknown, so the
    candidate is rejected and says why; with a metric scale the same candidate is accepted."""
    rng = np.random.default_rng(4)
    query, candidate = _shared_landmarks(rng, count=13, off_ray=10)
    assert map_scale(query, candidate, T_CANDIDATE_QUERY, ratio=0.8) is None
    seen_points = rng.uniform([-8, -2, 6], [8, 2, 30], (60, 3))  # in the candidate's frame
    in_query = (seen_points - T_CANDIDATE_QUERY[:3, 3]) @ T_CANDIDATE_QUERY[:3, :3]
    pixels = in_query @ K.T
    features = rng.integers(0, 256, (60, 32), dtype=np.uint8)
    query = _place(query.points_cam, query.point_descriptors, pixels[:, :2] / pixels[:, 2:], features)
    candidate = _place(np.vstack([candidate.points_cam, seen_points]),
                       np.vstack([candidate.point_descriptors, features]))
    config = LoopConfig()
    unit = verify(query, candidate, CAMERA, config, (0,), metric=False)
    assert unit.T_candidate_query is None
    assert unit.rejected is not None and unit.rejected.startswith("scale not measured")
    metric = verify(query, candidate, CAMERA, config, (0,), metric=True)
    assert metric.rejected is None and metric.inliers >= config.min_inliers and metric.scale == 1.0
    assert metric.T_candidate_query is not None
    np.testing.assert_allclose(metric.T_candidate_query, T_CANDIDATE_QUERY, atol=1e-3)


def _closed(keyframe_ids: list[int], scales: list[float]) -> LoopClosed:
    count = len(keyframe_ids)
    poses = np.tile(np.eye(4), (count, 1, 1))
    return LoopClosed(query_keyframe=keyframe_ids[-1], candidate_keyframe=keyframe_ids[0], query_position=0,
                      candidate_position=0, inliers=50, similarity=True, keyframe_ids=np.array(keyframe_ids),
                      keyframe_positions=np.arange(count), poses_before=poses, poses_after=poses,
                      correction_m=np.zeros(count), correction_deg=np.zeros(count), scales=np.array(scales),
                      landmarks_moved=0, milliseconds=0.0)


def test_frames_move_with_their_keyframes_scale() -> None:
    """A Sim(3) correction made keyframe 1's neighbourhood 0.9 times as large and keyframe 2's 0.8: frames
    stored relative to them are that much closer to them; a frame of a keyframe outside the graph stays."""
    step = pose_matrix(np.eye(3), np.array([0.1, 0.0, 2.0]))
    relative = {5: (1, step), 6: (2, step), 7: (9, step)}
    rescale_relative(_closed([0, 1, 2], [1.0, 0.9, 0.8]), relative)
    np.testing.assert_allclose([relative[p][1][:3, 3] for p in (5, 6, 7)],
                               [0.9 * step[:3, 3], 0.8 * step[:3, 3], step[:3, 3]])
    assert all(relative[p][0] == k for p, k in ((5, 1), (6, 2), (7, 9)))
    np.testing.assert_array_equal(step[:3, 3], [0.1, 0.0, 2.0])  # the stored pose is replaced, not changed


def test_the_maps_speed_follows_a_similarity_correction() -> None:
    """After the world was scaled by 0.5 (and moved), the recent speed is half, and the next frame's step is
    measured from where the last frame's centre moved to, not from its old place."""
    speed = MapSpeed(frames=3)
    for position in range(4):
        speed.observe(position, pose_matrix(np.eye(3), np.array([0.0, 0.0, 2.0 * position])), measured=True)
    assert speed.speed == 2.0
    similarity = np.eye(4)
    similarity[:3, :3] *= 0.5
    similarity[:3, 3] = [5.0, 0.0, 0.0]
    speed.move(similarity)
    assert speed.speed == pytest.approx(1.0)
    speed.observe(4, pose_matrix(np.eye(3), np.array([5.0, 0.0, 4.0])), measured=True)  # 0.5 * 8 + 1 step
    assert speed.speed == pytest.approx(1.0)


def test_a_candidate_seen_through_a_lens_is_verified_on_undistorted_features() -> None:
    """The query keyframe's features are raw pixels of a strongly distorted lens (k1 −0.28, k2 0.07, as the tests'
    re-imaged logs): with the lens they are undistorted for the PnP and every one is an inlier at the true pose;
    taken as pinhole pixels, PnP finds a pose off by decimetres or fails."""
    rng = np.random.default_rng(5)
    lens = CameraIntrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], 1241, 376, "plumb_bob", (-0.28, 0.07, 1e-4, -2e-4, 0.0))
    seen_points = rng.uniform([-8, -2, 6], [8, 2, 30], (80, 3))  # in the candidate's frame
    in_query = (seen_points - T_CANDIDATE_QUERY[:3, 3]) @ T_CANDIDATE_QUERY[:3, :3]
    ideal = in_query @ K.T
    raw = distort_pixels(ideal[:, :2] / ideal[:, 2:], lens)
    features = rng.integers(0, 256, (80, 32), dtype=np.uint8)
    query = _place(np.zeros((0, 3)), np.zeros((0, 32), np.uint8), raw, features)
    candidate = _place(seen_points, features)
    config = LoopConfig()
    through = verify(query, candidate, lens, config, (0,), metric=True)
    assert through.rejected is None and through.inliers == 80
    assert through.T_candidate_query is not None
    np.testing.assert_allclose(through.T_candidate_query, T_CANDIDATE_QUERY, atol=1e-3)
    np.testing.assert_allclose(through.query_pixels, raw, atol=1e-3)  # drawn where the features are: raw pixels
    pinhole = verify(query, candidate, CAMERA, config, (0,), metric=True)
    assert pinhole.T_candidate_query is None or \
        np.linalg.norm(pinhole.T_candidate_query[:3, 3] - T_CANDIDATE_QUERY[:3, 3]) > 0.1
