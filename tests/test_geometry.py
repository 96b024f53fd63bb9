"""Two-view geometry on synthetic scenes with known motion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam_core.errors import GeometryError
from vslam_core.geometry import (
    angle_between,
    candidate_poses,
    chain,
    chirality_check,
    essential_from_pose,
    invert_pose,
    normalise_points,
    pose_matrix,
    refine_relative_pose,
    relative_pose_covariance,
    rotation_angle,
    sampson_errors,
    sampson_jacobian,
    so3_exp,
    so3_log,
    triangulate,
    triangulate_each,
)

K = np.array([[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]])


def rot(yaw_deg: float = 0.0, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation in the camera frame (y down): yaw about y, pitch about x, roll about z."""
    yaw, pitch, roll = np.radians([yaw_deg, pitch_deg, roll_deg])
    return so3_exp(np.array([0.0, yaw, 0.0])) @ so3_exp(np.array([pitch, 0.0, 0.0])) @ so3_exp(
        np.array([0.0, 0.0, roll])
    )


def two_view(T_prev_cur: np.ndarray, n: int = 400, seed: int = 0, noise_px: float = 0.0):  # noqa: N803
    """Points in front of both cameras, projected into the current and previous image (pixels)."""
    rng = np.random.default_rng(seed)
    # depths within 50 baselines, where the chirality count (like cv2.recoverPose) still counts points
    points_cur = np.column_stack((rng.uniform(-15, 15, n), rng.uniform(-3, 2, n), rng.uniform(4, 40, n)))
    points_prev = points_cur @ T_prev_cur[:3, :3].T + T_prev_cur[:3, 3]
    keep = points_prev[:, 2] > 1.0
    points_cur, points_prev = points_cur[keep], points_prev[keep]

    def project(p: np.ndarray) -> np.ndarray:
        uv = (p / p[:, 2:3]) @ K.T
        return uv[:, :2] + rng.normal(0, noise_px, (len(p), 2)) if noise_px else uv[:, :2]

    return project(points_cur), project(points_prev), points_cur


MOTIONS = {
    "forward": pose_matrix(np.eye(3), [0.0, 0.0, 1.0]),
    "sideways": pose_matrix(rot(yaw_deg=1.0), [1.0, 0.0, 0.1]),
    "turning": pose_matrix(rot(yaw_deg=6.0), [0.15, 0.0, 0.98]),
    "turning_with_pitch_and_roll": pose_matrix(rot(yaw_deg=5.0, pitch_deg=1.5, roll_deg=-1.0), [0.1, 0.05, 0.99]),
}


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_chirality_recovers_known_motion_and_agrees_with_recover_pose(name: str) -> None:
    T_prev_cur = MOTIONS[name]  # noqa: N806
    p_cur, p_prev, _ = two_view(T_prev_cur, noise_px=0.1)
    E, mask = cv2.findEssentialMat(p_cur, p_prev, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)  # noqa: N806
    inliers = mask.ravel().astype(bool)
    x_cur, x_prev = normalise_points(p_cur[inliers], K), normalise_points(p_prev[inliers], K)
    candidates, best = chirality_check(E, x_cur, x_prev)

    assert len(candidates) == 4
    counts = sorted(c.in_front for c in candidates)
    assert counts[-1] >= 0.75 * inliers.sum()  # the winner has most points (noise near the epipole aside)
    assert counts[-2] < 0.6 * counts[-1]  # and the others clearly fewer
    winner = candidates[best]
    true_t = T_prev_cur[:3, 3] / np.linalg.norm(T_prev_cur[:3, 3])
    # the minimal-sample RANSAC model is only roughly right; what matters is the right candidate
    assert np.degrees(rotation_angle(winner.rotation.T @ T_prev_cur[:3, :3])) < 0.5
    assert np.degrees(angle_between(winner.translation, true_t)) < 5.0
    for i, other in enumerate(candidates):
        if i != best:
            assert (np.degrees(rotation_angle(other.rotation.T @ T_prev_cur[:3, :3])) > 5.0
                    or np.degrees(angle_between(other.translation, true_t)) > 90.0)

    count, R_cv, t_cv, _ = cv2.recoverPose(E, p_cur[inliers], p_prev[inliers], K)  # noqa: N806
    assert np.allclose(R_cv, winner.rotation, atol=1e-9)
    assert np.allclose(t_cv.ravel(), winner.translation, atol=1e-9)
    # same candidate; counts agree up to the few far points near the epipole, where midpoint (ours) and
    # DLT (OpenCV's) triangulation put the depth on different sides of the 50-baseline cut-off
    assert abs(count - winner.in_front) <= 0.05 * count


def test_candidates_are_the_four_decompositions() -> None:
    R, t = rot(yaw_deg=3.0, pitch_deg=1.0), np.array([0.2, 0.0, 0.98])  # noqa: N806
    E = essential_from_pose(R, t / np.linalg.norm(t))  # noqa: N806
    candidates = candidate_poses(E)
    assert len(candidates) == 4
    r1, t1 = candidates[0]
    assert np.allclose(candidates[1][0], r1) and np.allclose(candidates[1][1], -t1)
    assert np.allclose(candidates[3][1], -candidates[2][1])
    for rotation, translation in candidates:
        assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        assert np.linalg.norm(translation) == pytest.approx(1.0)
        # every candidate reproduces E up to sign and scale
        e = essential_from_pose(rotation, translation)
        assert min(np.abs(e - E).max(), np.abs(e + E).max()) < 1e-9


def test_chaining_order_matters_when_pitching_while_turning() -> None:
    """T_w_cur = T_w_prev · T_prev_cur reproduces a known trajectory; mono-vo's R_w = R·R_w does not."""
    # a 90° turn over 20 frames with the car pitching and rolling on the way
    steps = [
        pose_matrix(rot(yaw_deg=4.5, pitch_deg=2.0 * (-1) ** (i // 5), roll_deg=1.5 * np.sin(i / 2)), [0, 0, 1.0])
        for i in range(20)
    ]
    truth = [np.eye(4)]
    for step in steps:
        truth.append(truth[-1] @ step)

    correct, wrong_r, wrong_t = np.eye(4), np.eye(3), np.zeros(3)
    for step in steps:
        correct = chain(correct, step)
        wrong_t = wrong_t + wrong_r @ step[:3, 3]
        wrong_r = step[:3, :3] @ wrong_r  # the classic mono-vo order
    assert np.allclose(correct, truth[-1], atol=1e-12)
    assert np.degrees(rotation_angle(wrong_r.T @ truth[-1][:3, :3])) > 10.0
    assert np.linalg.norm(wrong_t - truth[-1][:3, 3]) > 1.0


def test_relative_pose_round_trip_through_chaining() -> None:
    a = pose_matrix(rot(10, 2, -1), [3.0, 0.2, 7.0])
    b = pose_matrix(rot(25, -1, 2), [5.0, 0.1, 12.0])
    relative = invert_pose(a) @ b
    assert np.allclose(chain(a, relative), b, atol=1e-12)
    assert np.allclose(invert_pose(a) @ a, np.eye(4), atol=1e-12)


def test_a_stack_of_poses_inverts_pose_by_pose() -> None:
    poses = np.array([pose_matrix(rot(10, 2, -1), [3.0, 0.2, 7.0]), pose_matrix(rot(-25, 1, 2), [5.0, 0.1, -12.0])])
    inverses = invert_pose(poses)
    assert inverses.shape == (2, 4, 4)
    for pose, inverse in zip(poses, inverses, strict=True):
        assert np.allclose(inverse, invert_pose(pose), atol=1e-15)
        assert np.allclose(inverse @ pose, np.eye(4), atol=1e-12)


def test_triangulation_returns_points_in_the_current_frame_up_to_baseline() -> None:
    T_prev_cur = MOTIONS["turning_with_pitch_and_roll"]  # noqa: N806
    p_cur, p_prev, truth = two_view(T_prev_cur, n=50)
    baseline = np.linalg.norm(T_prev_cur[:3, 3])
    points = triangulate(T_prev_cur[:3, :3], T_prev_cur[:3, 3] / baseline,
                         normalise_points(p_cur, K), normalise_points(p_prev, K))
    assert np.allclose(points * baseline, truth, rtol=1e-6, atol=1e-6)


def test_triangulating_many_pairs_at_once_is_triangulating_each_pair() -> None:
    """`triangulate_each` (a camera pair per point, as local mapping triangulates tracks first seen at different
    keyframes) gives each pair's `triangulate` points, parallel rays (NaN) included."""
    motions = [MOTIONS["turning_with_pitch_and_roll"], MOTIONS["turning"], pose_matrix(np.eye(3), np.zeros(3))]
    pairs = [two_view(T, n=30, seed=k) for k, T in enumerate(motions)]  # noqa: N806
    x_cur = np.vstack([normalise_points(p_cur, K) for p_cur, _, _ in pairs])
    x_prev = np.vstack([normalise_points(p_prev, K) for _, p_prev, _ in pairs])
    rotations = np.repeat(np.array([T[:3, :3] for T in motions]), 30, axis=0)
    translations = np.repeat(np.array([T[:3, 3] for T in motions]), 30, axis=0)
    points = triangulate_each(rotations, translations, x_cur, x_prev)
    for k, T in enumerate(motions):  # noqa: N806
        expected = triangulate(T[:3, :3], T[:3, 3], x_cur[30 * k: 30 * (k + 1)], x_prev[30 * k: 30 * (k + 1)])
        np.testing.assert_allclose(points[30 * k: 30 * (k + 1)], expected, rtol=1e-9, atol=1e-12)
    assert np.isnan(points[60:]).all() and np.isfinite(points[:60]).all()  # no baseline: rays parallel


def test_refinement_reduces_direction_error_on_noisy_points() -> None:
    T_prev_cur = MOTIONS["turning"]  # noqa: N806
    true_t = T_prev_cur[:3, 3] / np.linalg.norm(T_prev_cur[:3, 3])
    errors_before, errors_after = [], []
    for seed in range(5):
        p_cur, p_prev, _ = two_view(T_prev_cur, n=800, seed=seed, noise_px=0.5)
        x_cur, x_prev = normalise_points(p_cur, K), normalise_points(p_prev, K)
        # start from a perturbed pose, as a minimal-sample RANSAC model would be
        r0 = T_prev_cur[:3, :3] @ so3_exp(np.radians([0.05, -0.05, 0.03]))
        t0 = true_t + np.array([0.03, -0.02, 0.0])
        t0 /= np.linalg.norm(t0)
        r1, t1 = refine_relative_pose(r0, t0, x_cur, x_prev, robust_scale=1.0 / K[0, 0])
        errors_before.append(angle_between(t0, true_t))
        errors_after.append(angle_between(t1, true_t))
        assert np.allclose(r1.T @ r1, np.eye(3), atol=1e-9)
        assert np.linalg.norm(t1) == pytest.approx(1.0)
    assert np.mean(errors_after) < 0.3 * np.mean(errors_before)


def test_bad_input_raises_geometry_error() -> None:
    with pytest.raises(GeometryError):
        candidate_poses(np.full((3, 3), np.nan))
    with pytest.raises(GeometryError):
        normalise_points(np.zeros((4, 3)), K)


def test_sampson_jacobian_matches_finite_differences() -> None:
    T_prev_cur = MOTIONS["turning_with_pitch_and_roll"]  # noqa: N806
    p_cur, p_prev, _ = two_view(T_prev_cur, n=40, noise_px=0.5)
    x_cur, x_prev = normalise_points(p_cur, K), normalise_points(p_prev, K)
    rotation, t = T_prev_cur[:3, :3], T_prev_cur[:3, 3] / np.linalg.norm(T_prev_cur[:3, 3])
    basis = np.linalg.svd(np.eye(3) - np.outer(t, t))[0][:, :2]  # any orthonormal basis of t's tangent plane
    h_cur, h_prev = np.column_stack((x_cur, np.ones(len(x_cur)))), np.column_stack((x_prev, np.ones(len(x_prev))))
    analytic = sampson_jacobian(rotation, t, basis, h_cur, h_prev)

    def errors(params: np.ndarray) -> np.ndarray:
        moved_t = t + basis @ params[3:]
        moved_t /= np.linalg.norm(moved_t)
        return sampson_errors(essential_from_pose(rotation @ so3_exp(params[:3]), moved_t), x_cur, x_prev)

    eps = 1e-6
    numeric = np.column_stack([(errors(eps * axis) - errors(-eps * axis)) / (2 * eps) for axis in np.eye(5)])
    assert analytic.shape == (len(x_cur), 5)
    assert np.allclose(analytic, numeric, rtol=1e-5, atol=1e-9)


def test_the_relative_pose_covariance_is_the_spread_of_refined_poses_under_pixel_noise() -> None:
    """Monte Carlo: a short step down with a pitch (a hand-held camera's; the views hardly tell the pitch from the
    step), refined under 0.5 px of noise many times. The spread of the refined rotations is the predicted
    covariance: its largest axis (about x), and its size within a third."""
    motion = pose_matrix(rot(pitch_deg=0.8), [0.0, 0.05, 0.02])
    rotation, t = motion[:3, :3], motion[:3, 3] / np.linalg.norm(motion[:3, 3])
    errors, predicted = [], []
    for seed in range(150):
        p_cur, p_prev, _ = two_view(motion, n=150, seed=seed, noise_px=0.5)
        x_cur, x_prev = normalise_points(p_cur, K), normalise_points(p_prev, K)
        r1, t1 = refine_relative_pose(rotation, t, x_cur, x_prev, robust_scale=1.0 / K[0, 0])
        covariance = relative_pose_covariance(r1, t1, x_cur, x_prev, robust_scale=1.0 / K[0, 0])
        assert covariance is not None and covariance.shape == (5, 5)
        errors.append(so3_log(rotation.T @ r1))
        predicted.append(covariance[:3, :3])
    empirical = np.cov(np.array(errors).T)
    expected = np.mean(predicted, axis=0)
    (empirical_values, empirical_axes), (values, axes) = np.linalg.eigh(empirical), np.linalg.eigh(expected)
    assert abs(axes[0, -1]) > 0.9 and abs(empirical_axes[0, -1]) > 0.9  # about x
    assert 0.67 < empirical_values[-1] / values[-1] < 1.5
    assert values[-1] > 10 * values[0]  # the ambiguity: one direction far looser than the others
