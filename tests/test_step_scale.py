"""The length of a two-view step measured against landmarks (vslam_core/mapping/map_search.py)."""

from __future__ import annotations

import numpy as np

from vslam_core.geometry import pose_matrix
from vslam_core.mapping.map_search import fit_step_length, rescale_step
from vslam_core.mapping.pnp import project

K = np.array([[718.856, 0.0, 607.19], [0.0, 718.856, 185.22], [0.0, 0.0, 1.0]])


def _scene(true_length: float, outliers: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A keyframe pose, the step at unit length (its true length `true_length`), (L, 3) landmarks and their
    (L, 2) pixels in the current frame, the last `outliers` of them 40 px off."""
    rng = np.random.default_rng(3)
    T_world_key = pose_matrix(np.eye(3), np.array([2.0, 0.0, 5.0]))  # noqa: N806
    angle = np.radians(4.0)  # turning left while driving forward, as a car does
    rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    direction = np.array([0.05, 0.0, 1.0]) / np.linalg.norm([0.05, 0.0, 1.0])
    points = np.column_stack([rng.uniform(-12, 12, 40), rng.uniform(-2, 2, 40), rng.uniform(8, 40, 40)])
    world = points + T_world_key[:3, 3]
    pixels = project(world, T_world_key @ pose_matrix(rotation, true_length * direction), K)
    pixels[len(pixels) - outliers:] += 40.0
    return T_world_key, pose_matrix(rotation, direction), world, pixels


def test_the_length_is_recovered_despite_outliers() -> None:
    T_world_key, unit_step, world, pixels = _scene(1.37, outliers=12)  # noqa: N806
    fit = fit_step_length(T_world_key, unit_step, world, pixels, K, 2.0)
    assert fit is not None
    assert abs(fit.length - 1.37) < 1e-6
    assert (fit.inliers, fit.landmarks) == (28, 40)
    step = rescale_step(unit_step, fit.length)
    assert np.isclose(np.linalg.norm(step[:3, 3]), 1.37) and np.allclose(step[:3, :3], unit_step[:3, :3])


def test_no_length_without_a_translation_or_landmarks() -> None:
    T_world_key, unit_step, world, pixels = _scene(1.0, outliers=0)  # noqa: N806
    assert fit_step_length(T_world_key, pose_matrix(unit_step[:3, :3], np.zeros(3)), world, pixels, K, 2.0) is None
    assert fit_step_length(T_world_key, unit_step, world[:0], pixels[:0], K, 2.0) is None
