"""Tests of vslam_core.trajectory.metrics: known answers, Umeyama round trips, real KITTI ground truth, evo."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vslam_core.errors import GeometryError, VslamError
from vslam_core.geometry import so3_exp
from vslam_core.trajectory.io import read_kitti_poses
from vslam_core.trajectory.metrics import (
    KITTI_LENGTHS,
    TrajectoryMetrics,
    align_positions,
    ate,
    evaluate,
    heading_errors,
    kitti_errors,
    kitti_errors_by_length,
    kitti_segment_errors,
    paper_rms_error,
    position_errors,
    rpe,
    rpe_by_distance,
    sim3_aligned,
    trajectory_distances,
    umeyama_alignment,
)

# --------------------------------------------------------------------------------------------------
# helpers


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation about the camera's y axis (down): a yaw for a KITTI camera."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """Rotation vector -> rotation matrix."""
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.eye(3)
    k = rotvec / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx


def straight_line(n: int, spacing: float) -> np.ndarray:
    """(n, 4, 4) identity rotations, camera moving forward (+z) by ``spacing`` per frame."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 2, 3] = spacing * np.arange(n)
    return poses


def winding_trajectory(n: int = 600, step: float = 0.5) -> np.ndarray:
    """A non-planar drive: yaw and pitch vary smoothly, forward steps of ``step`` metres."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(1, n):
        yaw = 0.8 * math.sin(i / 90.0)
        pitch = 0.05 * math.sin(i / 37.0)
        poses[i, :3, :3] = rot_y(yaw) @ rot_x(pitch)
        poses[i, :3, 3] = poses[i - 1, :3, 3] + poses[i - 1, :3, :3] @ np.array([0.0, 0.0, step])
    return poses


def apply_sim3(poses: np.ndarray, rotation: np.ndarray, translation: np.ndarray, scale: float) -> np.ndarray:
    """Left-multiply camera-to-world poses by a similarity: p' = s R p + t, R' = R R_i."""
    out = poses.copy()
    out[:, :3, :3] = rotation @ poses[:, :3, :3]
    out[:, :3, 3] = scale * poses[:, :3, 3] @ rotation.T + translation
    return out


def scale_translations(poses: np.ndarray, factor: float) -> np.ndarray:
    out = poses.copy()
    out[:, :3, 3] *= factor
    return out


# --------------------------------------------------------------------------------------------------
# distances and the KITTI score


def test_trajectory_distances_cumulative() -> None:
    poses = straight_line(5, 2.0)
    poses[4, :3, 3] = [3.0, 4.0, 6.0]  # 5 m from frame 3 at (0, 0, 6)
    np.testing.assert_allclose(trajectory_distances(poses), [0.0, 2.0, 4.0, 6.0, 11.0])
    assert trajectory_distances(poses[:1]).tolist() == [0.0]


def test_constant_scale_error_on_straight_line() -> None:
    # 500 m straight line, a frame every 0.1 m, estimate 1 % too long everywhere.
    gt = straight_line(5001, 0.1)
    est = scale_translations(gt, 1.01)
    records = kitti_segment_errors(gt, est)
    d = trajectory_distances(gt)
    # d[last] > d[first] + L is strict: the 500 m segment does not fit in a 500 m path.
    assert {r.length for r in records} == {100.0, 200.0, 300.0, 400.0}
    for r in records:
        assert d[r.last] > d[r.first] + r.length >= d[r.last - 1]
        # the devkit divides the error over the actual segment by the nominal length L
        assert r.t_err == pytest.approx(0.01 * (d[r.last] - d[r.first]) / r.length, rel=1e-9)
        assert r.r_err == pytest.approx(0.0, abs=1e-9)
    t_err, r_err = kitti_errors(gt, est)
    assert t_err == pytest.approx(1.0, abs=1e-3)  # the 0.1 m overshoot of each segment: < 0.001 %
    assert r_err == pytest.approx(0.0, abs=1e-6)


def test_pure_yaw_drift_known_answer() -> None:
    # Ground truth: 1000 m straight ahead, 1 m a frame (exact distances). Estimate: every frame moves
    # 1 m forward and turns by omega about the camera's y axis (a yaw drift of 1 deg per 100 m), i.e.
    # E_{i+1} = E_i · [Ry(omega) | (0, 0, 1)]. Over n frames the error is a yaw of n·omega and a
    # translation |n·e_z - sum_k Ry(k omega) e_z| (closed form of the geometric sums below).
    omega = math.radians(0.01)
    n_frames = 1001
    gt = straight_line(n_frames, 1.0)
    step = np.eye(4)
    step[:3, :3] = rot_y(omega)
    step[2, 3] = 1.0
    est = np.tile(np.eye(4), (n_frames, 1, 1))
    for i in range(1, n_frames):
        est[i] = est[i - 1] @ step

    expected_t, expected_r = [], []
    for first in range(0, n_frames, 10):
        for length in KITTI_LENGTHS:
            n = int(length) + 1  # first frame with d > d[first] + L, d in whole metres
            if first + n >= n_frames:
                continue
            half = math.sin(n * omega / 2.0) / math.sin(omega / 2.0)
            sum_sin = half * math.sin((n - 1) * omega / 2.0)
            sum_cos = half * math.cos((n - 1) * omega / 2.0)
            expected_t.append(math.hypot(sum_sin, n - sum_cos) / length)
            expected_r.append(n * omega / length)
    records = kitti_segment_errors(gt, est)
    assert len(records) == len(expected_t)
    np.testing.assert_allclose([r.t_err for r in records], expected_t, rtol=1e-6)
    np.testing.assert_allclose([r.r_err for r in records], expected_r, rtol=1e-6)

    t_err, r_err = kitti_errors(gt, est)
    assert r_err == pytest.approx(math.degrees(np.mean(expected_r)) * 100.0, rel=1e-6)
    assert r_err == pytest.approx(1.0, rel=0.01)  # 1 deg/100 m, plus the one-frame overshoot (L+1)/L
    assert t_err == pytest.approx(np.mean(expected_t) * 100.0, rel=1e-6)

    # RPE of the same case: every consecutive pair is off by exactly omega, with no translation error.
    rpe_trans, rpe_rot = rpe(gt, est)
    assert rpe_trans == pytest.approx(0.0, abs=1e-9)
    assert rpe_rot == pytest.approx(0.01, rel=1e-6)
    # the per-frame heading error grows linearly: i · 0.01 deg
    np.testing.assert_allclose(heading_errors(gt, est)[::100], 0.01 * np.arange(0, n_frames, 100), rtol=1e-6)


def test_short_path_gives_nan_not_an_error() -> None:
    gt = straight_line(100, 0.5)  # 49.5 m: no 100 m segment
    est = scale_translations(gt, 1.1)
    assert kitti_segment_errors(gt, est) == []
    t_err, r_err = kitti_errors(gt, est)
    assert math.isnan(t_err) and math.isnan(r_err)
    metrics = evaluate(gt, est)
    assert math.isnan(metrics.t_err) and math.isnan(metrics.r_err)
    assert metrics.ate_sim3 == pytest.approx(0.0, abs=1e-9)


def test_identical_trajectories_give_zero_everywhere() -> None:
    gt = winding_trajectory()
    metrics = evaluate(gt, gt.copy())
    assert metrics.frames == len(gt)
    assert metrics.length_m == pytest.approx(0.5 * (len(gt) - 1))
    for name in ("t_err", "r_err", "ate_se3", "ate_sim3", "rpe_trans", "rpe_rot", "paper_rms"):
        assert getattr(metrics, name) == pytest.approx(0.0, abs=1e-5), name
    assert ate(gt, gt, "none") == 0.0
    assert np.all(position_errors(gt, gt) == 0.0)
    np.testing.assert_allclose(heading_errors(gt, gt), 0.0, atol=1e-5)


@settings(max_examples=50, deadline=None)
@given(st.floats(1e-7, 3.1), st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
    lambda v: np.linalg.norm(v) > 1e-3))
def test_rotation_errors_keep_their_digits_at_every_angle(angle: float, axis: list[float]) -> None:
    """The angle of a rotation by `angle` about any axis reads back to 1e-9 of itself, small angles too (acos of
    the trace alone kept ~1e-4 of a 0.05° step: its cosine is 1 − 4·10⁻⁷)."""
    gt = np.repeat(np.eye(4)[None], 2, axis=0)
    est = gt.copy()
    est[1, :3, :3] = so3_exp(angle * np.asarray(axis) / np.linalg.norm(axis))
    assert heading_errors(gt, est)[1] == pytest.approx(math.degrees(angle), rel=1e-9)


def test_paper_rms_position_and_heading_errors() -> None:
    gt = winding_trajectory(50)
    est = gt.copy()
    est[:, :3, 3] += [3.0, 4.0, 5.0]  # constant offset: x-z error sqrt(9 + 25), 3-D error sqrt(50)
    est[:, :3, :3] = est[:, :3, :3] @ rot_z(math.radians(10.0))
    assert paper_rms_error(gt, est) == pytest.approx(math.sqrt(34.0))
    np.testing.assert_allclose(position_errors(gt, est), math.sqrt(50.0))
    np.testing.assert_allclose(heading_errors(gt, est), 10.0)
    assert ate(gt, est, "none") == pytest.approx(math.sqrt(50.0))
    assert ate(gt, est, "se3") == pytest.approx(0.0, abs=1e-9)  # a pure offset is aligned away


def test_rpe_known_answer() -> None:
    gt = straight_line(11, 1.0)
    est = straight_line(11, 1.1)  # every step 10 cm too long
    rpe_trans, rpe_rot = rpe(gt, est)
    assert rpe_trans == pytest.approx(0.1)
    assert rpe_rot == pytest.approx(0.0, abs=1e-9)
    assert rpe(gt, est, delta=5)[0] == pytest.approx(0.5)
    assert all(math.isnan(v) for v in rpe(gt, est, delta=11))
    with pytest.raises(GeometryError, match="delta"):
        rpe(gt, est, delta=0)


# --------------------------------------------------------------------------------------------------
# Umeyama and ATE

rotation_vectors = st.tuples(*[st.floats(-math.pi, math.pi) for _ in range(3)]).map(np.array)
translations = st.tuples(*[st.floats(-100.0, 100.0) for _ in range(3)]).map(np.array)
scales = st.floats(0.05, 20.0)


@settings(max_examples=60, deadline=None)
@given(rotvec=rotation_vectors, translation=translations, scale=scales)
def test_umeyama_sim3_round_trip(rotvec: np.ndarray, translation: np.ndarray, scale: float) -> None:
    rotation = rodrigues(rotvec)
    est = winding_trajectory(200)
    gt = apply_sim3(est, rotation, translation, scale)
    r, t, s = umeyama_alignment(est[:, :3, 3].T, gt[:, :3, 3].T, with_scale=True)
    np.testing.assert_allclose(r, rotation, atol=1e-9)
    np.testing.assert_allclose(t, translation, atol=1e-9)
    assert s == pytest.approx(scale, rel=1e-9)
    assert np.linalg.det(r) == pytest.approx(1.0)
    assert ate(gt, est, "sim3") == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(align_positions(gt, est, "sim3"), gt[:, :3, 3], atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(rotvec=rotation_vectors, translation=translations)
def test_umeyama_se3_round_trip(rotvec: np.ndarray, translation: np.ndarray) -> None:
    rotation = rodrigues(rotvec)
    est = winding_trajectory(200)
    gt = apply_sim3(est, rotation, translation, 1.0)
    r, t, s = umeyama_alignment(est[:, :3, 3].T, gt[:, :3, 3].T, with_scale=False)
    np.testing.assert_allclose(r, rotation, atol=1e-9)
    np.testing.assert_allclose(t, translation, atol=1e-9)
    assert s == 1.0
    assert ate(gt, est, "se3") == pytest.approx(0.0, abs=1e-9)


def test_umeyama_handles_a_reflection_free_planar_and_collinear_set() -> None:
    # planar points: the covariance is rank 2, the rotation is still unique and proper (eq. 43)
    rng = np.random.default_rng(3)
    src = np.vstack([rng.normal(size=(2, 30)), np.zeros((1, 30))])
    rotation = rodrigues(np.array([0.3, -1.2, 2.0]))
    dst = 2.5 * rotation @ src + np.array([[1.0], [2.0], [3.0]])
    r, t, s = umeyama_alignment(src, dst, with_scale=True)
    np.testing.assert_allclose(r, rotation, atol=1e-9)
    assert s == pytest.approx(2.5)
    # collinear points (a straight drive): R is not unique, but the alignment is still exact
    line = straight_line(20, 1.0)
    target = apply_sim3(line, rotation, np.array([5.0, 0.0, -1.0]), 0.7)
    assert ate(target, line, "sim3") == pytest.approx(0.0, abs=1e-9)


def test_ate_of_a_scaled_copy_se3_positive_sim3_zero() -> None:
    gt = winding_trajectory()
    est = scale_translations(gt, 0.5)  # a monocular estimate at half the true scale
    assert ate(gt, est, "se3") > 1.0
    assert ate(gt, est, "sim3") == pytest.approx(0.0, abs=1e-9)
    assert ate(gt, est, "none") > ate(gt, est, "se3")


def test_umeyama_degenerate_and_bad_shapes() -> None:
    points = np.zeros((3, 5))
    with pytest.raises(GeometryError, match="coincide"):
        umeyama_alignment(points, points + 1.0, with_scale=True)
    r, t, s = umeyama_alignment(points, points + 1.0, with_scale=False)
    np.testing.assert_allclose(r @ points[:, :1] + t[:, None], np.ones((3, 1)))
    with pytest.raises(GeometryError, match=r"\(3, N\)"):
        umeyama_alignment(np.zeros((5, 3)), np.zeros((5, 3)), with_scale=True)
    with pytest.raises(GeometryError, match="shape"):
        umeyama_alignment(np.zeros((3, 5)), np.zeros((3, 4)), with_scale=True)


def test_evaluate_stationary_estimate_has_nan_sim3() -> None:
    gt = winding_trajectory(300)
    est = np.tile(np.eye(4), (300, 1, 1))  # tracking never started
    metrics = evaluate(gt, est)
    assert math.isnan(metrics.ate_sim3)
    assert metrics.ate_se3 > 0 and metrics.t_err == pytest.approx(100.0, rel=0.05)


# --------------------------------------------------------------------------------------------------
# input checks and the summary record


def test_input_checks_raise_geometry_error() -> None:
    gt = straight_line(10, 1.0)
    with pytest.raises(GeometryError, match="10 poses but the estimate has 9"):
        evaluate(gt, gt[:9])
    with pytest.raises(GeometryError, match=r"\(N, 4, 4\)"):
        ate(gt, gt[:, :3, :], "se3")
    with pytest.raises(GeometryError, match=r"\(N, 4, 4\)"):
        trajectory_distances(np.zeros((4, 4)))
    with pytest.raises(GeometryError, match="no poses"):
        kitti_errors(gt[:0], gt[:0])
    bad = gt.copy()
    bad[3, 0, 3] = np.nan
    with pytest.raises(GeometryError, match="NaN"):
        rpe(gt, bad)
    with pytest.raises(GeometryError):
        position_errors(gt, bad)
    singular = gt.copy()
    singular[4] = 0.0
    with pytest.raises(GeometryError, match="singular"):
        rpe(gt, singular)
    assert issubclass(GeometryError, VslamError)
    with pytest.raises(ValueError, match="align"):
        ate(gt, gt, "xyz")  # type: ignore[arg-type]


def test_trajectory_metrics_as_dict() -> None:
    gt = winding_trajectory(400)
    metrics = evaluate(gt, scale_translations(gt, 1.05))
    assert isinstance(metrics, TrajectoryMetrics)
    record = metrics.as_dict()
    assert list(record) == [
        "t_err", "r_err", "ate_se3", "ate_sim3", "rpe_trans", "rpe_rot", "paper_rms", "frames", "length_m",
    ]  # fmt: skip
    assert record["frames"] == 400
    assert record["t_err"] == pytest.approx(5.0, abs=0.3)
    with pytest.raises(AttributeError):
        metrics.t_err = 0.0  # type: ignore[misc]


# --------------------------------------------------------------------------------------------------
# real KITTI ground truth


@pytest.mark.kitti
def test_real_kitti_00_scale_error(kitti_root: Path) -> None:
    gt = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=300)
    assert gt.shape == (300, 4, 4)
    assert trajectory_distances(gt)[-1] == pytest.approx(216.2, abs=0.1)  # README: 216.2 m
    est = scale_translations(gt, 1.02)
    records = kitti_segment_errors(gt, est)
    assert {r.length for r in records} == {100.0, 200.0}  # 300 frames: only 100 m and 200 m fit
    # With E = G but positions x1.02, Err = [R_dᵀ | -0.02 R_dᵀ t_dG]: the error of a segment is 2 % of its
    # CHORD |p_last - p_first|, not of its path length. Frames 0-299 of 00 hold a 90° right turn and a
    # 90° left turn, so every segment is curved (chord 70-90 % of L) and the score is ~1.58 %, not 2 %.
    for r in records:
        chord = np.linalg.norm(gt[r.last, :3, 3] - gt[r.first, :3, 3])
        assert r.t_err == pytest.approx(0.02 * chord / r.length, rel=1e-6)
        assert r.r_err == pytest.approx(0.0, abs=1e-8)
    t_err, r_err = kitti_errors(gt, est)
    assert t_err == pytest.approx(1.5845, abs=1e-3)
    assert r_err == pytest.approx(0.0, abs=1e-4)
    metrics = evaluate(gt, est)
    assert metrics.t_err == t_err
    assert metrics.ate_sim3 == pytest.approx(0.0, abs=1e-6)
    assert metrics.ate_se3 > 0.1
    assert metrics.rpe_rot == pytest.approx(0.0, abs=1e-4)


@pytest.mark.kitti
def test_real_kitti_05_straight_segment_scale_error(kitti_root: Path) -> None:
    # Frames 0-109 of 05 are a straight 100 m drive: there the 2 % scale error is a 2 % t_err.
    gt = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=300)
    assert trajectory_distances(gt)[-1] == pytest.approx(231.3, abs=0.1)  # README: 231.3 m
    est = scale_translations(gt, 1.02)
    first = kitti_segment_errors(gt, est)[0]
    assert (first.first, first.length) == (0, 100.0)
    assert first.t_err * 100.0 == pytest.approx(2.0, abs=0.05)
    assert first.r_err == pytest.approx(0.0, abs=1e-8)


# --------------------------------------------------------------------------------------------------
# cross-check against evo (enabled when evo is installed)


def _noisy_estimate(gt: np.ndarray, seed: int) -> np.ndarray:
    """gt with a scale error and random per-frame perturbations of the relative motions."""
    rng = np.random.default_rng(seed)
    est = np.tile(np.eye(4), (len(gt), 1, 1))
    for i in range(1, len(gt)):
        motion = np.linalg.inv(gt[i - 1]) @ gt[i]
        noise = np.eye(4)
        noise[:3, :3] = rodrigues(rng.normal(scale=0.002, size=3))
        noise[:3, 3] = rng.normal(scale=0.02, size=3)
        motion[:3, 3] *= 0.8
        est[i] = est[i - 1] @ motion @ noise
    return est


def test_cross_check_with_evo() -> None:
    pytest.importorskip("evo")
    from evo.core import geometry as evo_geometry
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PosePath3D

    unit_frames = evo_metrics.Unit.frames  # evo.core.units.Unit, re-exported by evo.core.metrics

    gt = winding_trajectory(500)
    est = _noisy_estimate(gt, seed=7)
    ref_path = PosePath3D(poses_se3=list(gt))
    est_path = PosePath3D(poses_se3=list(est))

    for with_scale, align in ((False, "se3"), (True, "sim3")):
        r_evo, t_evo, s_evo = evo_geometry.umeyama_alignment(est[:, :3, 3].T, gt[:, :3, 3].T, with_scale)
        r, t, s = umeyama_alignment(est[:, :3, 3].T, gt[:, :3, 3].T, with_scale)
        np.testing.assert_allclose(r, r_evo, atol=1e-9)
        np.testing.assert_allclose(t, t_evo, atol=1e-9)
        assert s == pytest.approx(s_evo, rel=1e-9)

        aligned = copy.deepcopy(est_path)
        aligned.align(ref_path, correct_scale=with_scale)
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((ref_path, aligned))
        expected = ape.get_statistic(evo_metrics.StatisticsType.rmse)
        assert ate(gt, est, align) == pytest.approx(expected, rel=1e-9)  # type: ignore[arg-type]

    for delta in (1, 5):
        trans, rot = rpe(gt, est, delta)
        rpe_t = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta, unit_frames, all_pairs=True)
        rpe_t.process_data((ref_path, est_path))
        rpe_r = evo_metrics.RPE(
            evo_metrics.PoseRelation.rotation_angle_deg, delta, unit_frames, all_pairs=True
        )
        rpe_r.process_data((ref_path, est_path))
        assert trans == pytest.approx(rpe_t.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)
        assert rot == pytest.approx(rpe_r.get_statistic(evo_metrics.StatisticsType.mean), rel=1e-6)


@pytest.mark.kitti
def test_matches_evo_on_real_kitti_ground_truth_with_perturbed_estimates(kitti_root: Path) -> None:
    """ATE (SE(3), Sim(3)) and RPE (per frame and per metre) agree with evo on real KITTI 00 and 05
    ground truth, perturbed by a scale error, a slow yaw drift and per-frame noise."""
    pytest.importorskip("evo")
    from evo.core import metrics as evo_metrics
    from evo.core.trajectory import PosePath3D

    rng = np.random.default_rng(3)
    for sequence in ("00", "05"):
        gt = read_kitti_poses(kitti_root / "poses" / f"{sequence}.txt", max_rows=1000)
        est = gt.copy()
        est[:, :3, 3] *= 1.03
        for i in range(len(est)):
            drift = so3_exp(np.array([0.0, 2e-4 * i, 0.0]))  # 0.0115° more yaw every frame
            est[i, :3, :3] = drift @ est[i, :3, :3]
            est[i, :3, 3] += rng.normal(0, 0.05, 3)
        ref_path, est_path = PosePath3D(poses_se3=list(gt)), PosePath3D(poses_se3=list(est))
        for align, with_scale in (("se3", False), ("sim3", True)):
            aligned = copy.deepcopy(est_path)
            aligned.align(ref_path, correct_scale=with_scale)
            ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
            ape.process_data((ref_path, aligned))
            assert ate(gt, est, align) == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-7)
        for delta, unit in ((1, evo_metrics.Unit.frames), (10.0, evo_metrics.Unit.meters)):
            stats = []
            for relation, statistic in ((evo_metrics.PoseRelation.translation_part, evo_metrics.StatisticsType.rmse),
                                        (evo_metrics.PoseRelation.rotation_angle_deg, evo_metrics.StatisticsType.mean)):
                metric = evo_metrics.RPE(relation, delta, unit, rel_delta_tol=0.1, all_pairs=True,
                                         pairs_from_reference=True)
                metric.process_data((ref_path, est_path))
                stats.append(metric.get_statistic(statistic))
            ours = rpe(gt, est, 1) if unit == evo_metrics.Unit.frames else rpe_by_distance(gt, est, 10.0)
            assert ours[0] == pytest.approx(stats[0], rel=1e-7)
            assert ours[1] == pytest.approx(stats[1], rel=1e-6)


def test_kitti_errors_by_length_split_the_score() -> None:
    """A constant 1 % scale error on a straight line: every segment length scores 1 %."""
    gt = np.tile(np.eye(4), (2001, 1, 1))
    gt[:, 2, 3] = np.arange(2001) * 0.5  # 1000 m straight ahead
    est = gt.copy()
    est[:, 2, 3] *= 1.01
    by_length = kitti_errors_by_length(gt, est)
    assert sorted(by_length) == list(KITTI_LENGTHS)
    for t_err, r_err, count in by_length.values():
        assert t_err == pytest.approx(1.0, abs=0.01) and r_err == pytest.approx(0.0, abs=1e-9) and count > 0
    total = kitti_errors(gt, est)
    assert total[0] == pytest.approx(1.0, abs=0.01)


def test_rpe_by_distance_uses_pairs_one_distance_apart() -> None:
    gt = np.tile(np.eye(4), (101, 1, 1))
    gt[:, 2, 3] = np.arange(101) * 1.0
    est = gt.copy()
    est[:, 2, 3] *= 1.1  # every 10 m pair is 1 m too long
    trans, rot = rpe_by_distance(gt, est, 10.0, tolerance_m=0.5)  # only pairs exactly 10 m apart
    assert trans == pytest.approx(1.0) and rot == pytest.approx(0.0)
    assert rpe_by_distance(gt, est, 10.0)[0] < 1.0  # the default 1 m tolerance also takes 9 m pairs at the end
    assert all(math.isnan(v) for v in rpe_by_distance(gt, est, 500.0))


def test_sim3_aligned_undoes_a_known_similarity() -> None:
    gt = winding_trajectory(200)
    rotation = so3_exp(np.array([0.3, -1.2, 0.5]))
    moved = gt.copy()
    moved[:, :3, 3] = 0.37 * gt[:, :3, 3] @ rotation.T + np.array([4.0, -2.0, 9.0])
    moved[:, :3, :3] = rotation @ gt[:, :3, :3]
    np.testing.assert_allclose(sim3_aligned(gt, moved), gt, atol=1e-9)
