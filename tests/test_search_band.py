"""The search along the step (`[map] search_band_px`, `search_rival_px`; vslam_core/mapping/local_map.py): a
landmark is looked for near the segment its projection sweeps as the predicted step's length varies, and the
ratio test ignores corners next to the best one. Exact synthetic geometry, no data."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from vslam_core.geometry import pose_matrix
from vslam_core.mapping.local_map import FrameCorners, _best_in_window, _near_segments
from vslam_core.mapping.pnp import project

K = np.array([[700.0, 0.0, 640.0], [0.0, 700.0, 360.0], [0.0, 0.0, 1.0]])


def corners_at(pixels: np.ndarray) -> FrameCorners:
    return FrameCorners(np.zeros((720, 1280), np.uint8), pixels, pixels, cKDTree(pixels))


def test_only_corners_near_the_swept_segment_are_candidates() -> None:
    point = np.array([[4.0, 1.0, 20.0]])  # off-axis, so moving forward sweeps it outwards
    origin = np.eye(4)
    predicted = pose_matrix(np.eye(3), np.array([0.0, 0.0, 2.0]))
    near = project(point, pose_matrix(np.eye(3), np.array([0.0, 0.0, 2.6])), K)[0]  # a 30 % longer step
    beside = near + np.array([0.0, 10.0])  # as far, but off the segment
    beyond = project(point, pose_matrix(np.eye(3), np.array([0.0, 0.0, 4.0])), K)[0]  # twice the step
    candidates, reach = _near_segments(corners_at(np.array([near, beside, beyond])), point, predicted, (origin, 0.5),
                                       3.0, K)
    assert candidates == [[0]]
    start, end = (project(point, pose_matrix(np.eye(3), np.array([0.0, 0.0, z])), K)[0] for z in (1.0, 3.0))
    assert np.isclose(reach[0], np.linalg.norm(end - start) / 2 + 3.0)


def test_the_ratio_test_ignores_a_neighbouring_corner_but_not_a_distant_one() -> None:
    pixels = np.array([[100.0, 100.0], [101.0, 100.0], [140.0, 100.0]])
    # landmark 0: its best corner and a neighbour 1 px away score alike; landmark 1: the best and a corner 40 px away
    landmark, corner, distance = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 2]), np.array([20, 22, 20, 22])
    plain, _ = _best_in_window(landmark, corner, distance, 2, 0.8, 64)
    apart, _ = _best_in_window(landmark, corner, distance, 2, 0.8, 64, (pixels, 3.0))
    assert plain.tolist() == [-1, -1]
    assert apart.tolist() == [0, -1]
