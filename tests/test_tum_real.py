"""The real TUM RGB-D hand-held frames of ../shared/data/tum (fr1_desk, fr1_xyz, frames 400-599): ground truth
interpolated on the mocap clock, the folder's calibration, the accelerometer recorded and read back, and a run
scored against the ground truth."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam

from benchmarks.tum import reversed_steps
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig, PoseConfig
from vslam_core.geometry import rotation_angle
from vslam_core.mapping.global_adjustment import GlobalAdjusted
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, Reason
from vslam_core.sources.base import FrameRange
from vslam_core.sources.open import open_source
from vslam_core.sources.tum_rgbd import TumRgbdSource
from vslam_core.trajectory.io import read_tum_poses
from vslam_core.trajectory.metrics import ate

pytestmark = pytest.mark.tum

DESK = "rgbd_dataset_freiburg1_desk"


def _rotation(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """(3, 3) rotation of a unit quaternion (the textbook formula, written out here on purpose)."""
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])


def _slerp(q0: np.ndarray, q1: np.ndarray, f: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (the shorter arc)."""
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    if q0 @ q1 < 0:
        q1 = -q1
    theta = math.acos(min(1.0, float(q0 @ q1)))
    return (math.sin((1 - f) * theta) * q0 + math.sin(f * theta) * q1) / math.sin(theta)


def test_ground_truth_is_interpolated_across_the_50_ms_gap(tum_root: Path) -> None:
    # fr1_desk frames 40 and 41 (stamps ...467.459692 and ...467.496058) both fall in the mocap's 50 ms gap
    # between rows ...467.4592 and ...467.5092; frame 41 is 13 ms from the nearer row.
    source = open_source(str(tum_root / DESK), frames=FrameRange.parse("40:42"))
    assert isinstance(source, TumRgbdSource)
    assert source.gt_matching is not None and "interpolated" in source.gt_matching
    assert "widest used 50 ms, farthest frame 13 ms from a row" in source.gt_matching
    q_a, q_b = np.array([0.7679, 0.4147, -0.2370, -0.4269]), np.array([0.7648, 0.4267, -0.2396, -0.4191])
    f40, f41 = 0.000492 / 0.05, 0.036858 / 0.05  # 0.00984 and 0.73716 of the way
    # positions by hand: row a (1.6200, -0.2264, 1.4394) + f * (0.0229, 0.0075, -0.0001)
    p40, p41 = np.array([1.620225, -0.226326, 1.439399]), np.array([1.636881, -0.220871, 1.439326])
    r40, r41 = _rotation(*_slerp(q_a, q_b, f40)), _rotation(*_slerp(q_a, q_b, f41))
    gt = source.ground_truth
    assert gt is not None
    np.testing.assert_allclose(gt[1][:3, 3], r40.T @ (p41 - p40), atol=2e-6)  # re-based on frame 40
    np.testing.assert_allclose(gt[1][:3, :3], r40.T @ r41, atol=1e-6)
    nearest = np.array([1.6429, -0.2189, 1.4393]) - np.array([1.6200, -0.2264, 1.4394])  # nearest rows: 6 mm off
    assert np.linalg.norm(r40.T @ (p41 - p40) - _rotation(*q_a).T @ nearest) > 0.005


def test_calibration_comes_from_the_folder_and_a_gap_too_wide_is_refused(tum_root: Path) -> None:
    camera = open_source(str(tum_root / DESK)).intrinsics
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (
        517.3, 516.5, 318.6, 255.3, 640, 480)
    assert camera.model == "plumb_bob" and camera.coefficients == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    assert camera.origin.startswith("calibration.txt")
    result = vslam("run", tum_root / DESK, "--frames", "38:43", "--gt-tolerance", "40", "--detail", "off")
    assert result.returncode != 0
    assert "2 of 5 frames are not between two ground-truth rows at most 40 ms apart" in result.stderr
    assert "first: frame 40 at 1305031467.459692" in result.stderr and "frames 38:40, 42:43 are" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_accelerometer_is_recorded_as_gravity_in_the_camera_frame(tum_root: Path, tmp_path: Path) -> None:
    folder = tum_root / DESK
    out = tmp_path / "desk.rrd"
    result = vslam("run", folder, "--frames", "30:50", "--detail", "summary", "-o", out)
    assert result.returncode == 0, result.stderr
    stamps = np.array([float(line.split()[0]) for line in (folder / "rgb.txt").read_text().splitlines()
                       if not line.startswith("#")])
    raw = np.loadtxt(folder / "accelerometer.txt")
    recorded = np.stack([
        np.concatenate(read_entity(out, f"/metrics/accelerometer/{axis}")["Scalars:scalars"].to_list())
        for axis in "xyz"], axis=1)
    assert recorded.shape == (20, 3)
    for row, i in enumerate(range(30, 50)):  # the mean over the frame's interval, az turned to z forward
        inside = (raw[:, 0] > stamps[i - 1]) & (raw[:, 0] <= stamps[i])
        np.testing.assert_allclose(recorded[row], raw[inside, 1:].mean(axis=0) * [1, 1, -1], rtol=1e-6)
    # physically: gravity (the mocap world's -z) seen from the ground-truth camera, within 10° (hand motion)
    source = open_source(str(folder), frames=FrameRange.parse("30:50"))
    truth, world = source.ground_truth, _world_pose(folder, stamps[30])
    assert truth is not None
    down = np.array([(world @ pose)[:3, :3].T @ [0.0, 0.0, -1.0] for pose in truth])
    cosines = np.sum(down * recorded, axis=1) / np.linalg.norm(recorded, axis=1)
    assert np.degrees(np.arccos(np.median(cosines))) < 10.0


def _world_pose(folder: Path, stamp: float) -> np.ndarray:
    """(4, 4) T_world_cam of the mocap row nearest `stamp` (orientation only matters here)."""
    rows = np.loadtxt(folder / "groundtruth.txt")
    row = rows[np.argmin(np.abs(rows[:, 0] - stamp))]
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(*row[4:8]), row[1:4]
    return pose


def _steps(source: TumRgbdSource, hold: bool) -> tuple[list[int], list[int]]:
    """vo with ground-truth scale on `source`, the reversed-step rule on or off, a keyframe on every accepted step
    (``keyframe_parallax_px`` 0: the rule judges one-frame steps only): (the positions whose step from the previous
    frame points against the true one, cosine < 0, among true steps ≥ 3 mm; the positions held)."""
    pose = replace(PoseConfig(), hold_reversed_step=hold, keyframe_parallax_px=0.0)
    config = EngineConfig(scale="gt", backend="vo", threads=1, pose=pose)
    results: list[FrameResult] = []
    run = run_odometry(source, config, sinks=(lambda _frame, result: results.append(result),))
    truth = source.ground_truth
    assert truth is not None
    reversed_at, _ = reversed_steps(truth, run.pose_array())
    return reversed_at, [r.position for r in results if Reason.STEP_HELD in r.health.reasons]


def test_steps_of_a_hand_held_start_are_held_not_reversed(tum_root: Path) -> None:
    """fr1_desk's first 50 frames (hand-held, 30 Hz, ~1 cm a frame 1 m from the desk): without the rule three
    two-view steps come out against the true one (measured: frames 4, 19, 45); with it, the frames whose step
    went against the motion model's are held to it (named in their health) and only a step right after a held one
    (the rule never holds twice in a row, so that a real reversal is taken) may still be reversed (measured:
    frame 4, after 3)."""
    source = TumRgbdSource(tum_root / DESK, frames=FrameRange.parse("0:50"))
    reversed_off, _ = _steps(source, hold=False)
    assert len(reversed_off) >= 3, reversed_off
    reversed_on, held = _steps(source, hold=True)
    assert len(reversed_on) <= 1 and {19, 45} <= set(held), (reversed_on, held)
    assert all(position - 1 in held for position in reversed_on), (reversed_on, held)


def test_rotation_of_fr1_desk_is_not_lost_to_short_steps(tum_root: Path) -> None:
    """fr1_desk's first 100 frames (3.3 s, hand-held, 30 Hz), vo with ground-truth scale: chained one-frame
    two-view steps lose the rotation about the camera's x axis (traded for a sideways step); measuring from a
    keyframe until 10 px of parallax are left once the rotation is removed (``pose.keyframe_parallax_px``) keeps
    it (an option, off by default: it made KITTI and the synthetic routes worse). Measured: 4.7° off at the last
    frame (8.0° with a keyframe on every frame, the default)."""
    source = TumRgbdSource(tum_root / DESK, frames=FrameRange.parse("0:100"))
    run = run_odometry(source, EngineConfig(scale="gt", backend="vo", threads=1,
                                            pose=replace(PoseConfig(), keyframe_parallax_px=10.0)))
    truth, poses = source.ground_truth, run.pose_array()
    assert truth is not None and run.held == 0
    true_turn = truth[0, :3, :3].T @ truth[-1, :3, :3]
    estimated_turn = poses[0, :3, :3].T @ poses[-1, :3, :3]
    assert math.degrees(rotation_angle(true_turn.T @ estimated_turn)) < 6.0


def test_the_map_without_a_scale_source_follows_the_hand_held_desk(tum_root: Path) -> None:
    """The whole of fr1_desk (200 frames), the default engine with `--scale none`, against issue 53's 3 cm after
    Sim(3): bundle adjustment corrects the front end's rotations where two views could not tell them from a step
    sideways (the chained rotation's covariance loosens the prior there), and the map's adjustment as a whole once
    the run ended corrects what the windows left behind them. Measured: 2.2 cm (seeds 1-3: 2.4, 4.1, 2.9); 3.2 cm
    without the adjustment at the end (seeds 1-3: 6.3, 6.2, 6.4)."""
    source = TumRgbdSource(tum_root / DESK)
    run = run_odometry(source, EngineConfig(scale="none", threads=1))
    assert source.ground_truth is not None and run.held == 0 and isinstance(run.adjusted_at_end, GlobalAdjusted)
    assert ate(source.ground_truth, run.pose_array(), "sim3") < 0.03


def test_the_map_with_ground_truth_scale_holds_the_hand_held_desks_turn(tum_root: Path) -> None:
    """fr1_desk's first 140 frames (4.7 s, hand-held, turning about the camera's x axis), the default engine with
    ground-truth scale, against issue 53's 3° at the last frame: the camera moves sideways, so after its first
    keyframes the map takes `--scale none`'s settings (rotations held loosely where two views were ambiguous, the
    map adjusted as a whole at the end) with the ground truth's step lengths. Measured (seeds 0-3): 2.9 / 3.1 / 3.2
    / 1.4° and 3.3 / 4.2 / 3.0 / 4.6 cm unaligned; with the settings of a car's camera 14.4 / 14.6 / 12.5 / 12.2°
    and 9.6 / 10.5 / 10.0 / 12.3 cm (the whole 200 frames: 3.2° and 4.3 cm at seed 0, before 11.9° and 9.2 cm)."""
    source = TumRgbdSource(tum_root / DESK, frames=FrameRange.parse("0:140"))
    run = run_odometry(source, EngineConfig(scale="gt", threads=1))
    truth, poses = source.ground_truth, run.pose_array()
    assert truth is not None and run.held == 0 and run.sideways is not None and run.sideways[1] < 0.5
    assert isinstance(run.adjusted_at_end, GlobalAdjusted)
    true_turn, estimated_turn = truth[0, :3, :3].T @ truth[-1, :3, :3], poses[0, :3, :3].T @ poses[-1, :3, :3]
    assert math.degrees(rotation_angle(true_turn.T @ estimated_turn)) < 4.0
    assert ate(truth, poses, "none") < 0.05


def test_a_run_on_fr1_xyz_against_its_ground_truth(tum_root: Path, tmp_path: Path) -> None:
    """`vslam run` on fr1_xyz's first 60 frames (2 s, 0.73 m of hand-held path), the default engine with
    ground-truth scale: the TUM trajectory carries the frames' own stamps, and scored against the interpolated
    ground truth (measured: ATE 1.4 cm unaligned, 1.1 cm after Sim(3), 0.9° off at the last frame; with a car's
    settings 2.4, 1.6 cm, 3.6°); the summary and the recording's report say the map took `--scale none`'s settings
    for a camera moving sideways."""
    folder = tum_root / "rgbd_dataset_freiburg1_xyz"
    trajectory, rrd = tmp_path / "xyz.txt", tmp_path / "xyz.rrd"
    result = vslam("run", folder, "--frames", "0:60", "--detail", "summary", "-o", rrd, "--trajectory-out",
                   trajectory, "--trajectory-format", "tum")
    assert result.returncode == 0, result.stderr
    assert "from calibration.txt" in result.stdout and "widest used 10 ms" in result.stdout
    settings = [line for line in result.stdout.splitlines() if line.startswith("settings")]
    assert len(settings) == 1 and re.match(r"settings +a camera moving sideways \(median \|cos\| of keyframe step "
                                           r"and optical axis 0\.\d\d by frame \d+\): the map's --scale none "
                                           r"settings from there, the steps' lengths still from gt$", settings[0])
    report = read_entity(rrd, "/report", static=True)["TextDocument:text"].to_list()[-1][0]
    assert f"Settings: {settings[0].removeprefix('settings').strip()}." in report, report
    events = [text for row in read_entity(rrd, "/events")["TextLog:text"].to_list() for text in row]
    switched = [text for text in events if "a camera moving sideways" in text]  # on the timeline, where it happened
    found = re.search(r"\|cos\| of keyframe step and optical axis (0\.\d\d) by frame (\d+)", settings[0])
    assert found is not None and switched == [f"frame {found[2]}: a camera moving sideways (median |cos| of keyframe "
                                              f"step and optical axis {found[1]}): the map's --scale none settings "
                                              "from here on"], switched
    stamps, poses = read_tum_poses(trajectory)
    listed = [float(line.split()[0]) for line in (folder / "rgb.txt").read_text().splitlines()
              if not line.startswith("#")][:60]
    np.testing.assert_allclose(stamps, listed, atol=1e-6)
    truth = open_source(str(folder), frames=FrameRange.parse("0:60")).ground_truth
    assert truth is not None
    assert ate(truth, poses, "none") < 0.025 and ate(truth, poses, "sim3") < 0.02
    assert math.degrees(rotation_angle(truth[-1, :3, :3].T @ poses[-1, :3, :3])) < 5.0
    # the summary scores what the trajectory file holds, with a hand-held camera's measure (no 100 m KITTI segment)
    assert re.search(r"^KITTI +t_err — +r_err — +\(path < 100 m: no segment\)$", result.stdout, re.MULTILINE)
    assert re.search(rf"^ATE +{ate(truth, poses, 'none'):.3f} m without alignment, {ate(truth, poses, 'sim3'):.3f} m "
                     r"after Sim\(3\) \(3-D RMSE over 60 frames\)$", result.stdout, re.MULTILINE), result.stdout
