"""Injected faults are flagged at their frames, the run goes on, and tracking recovers afterwards; frames too
degraded to track are dead-reckoned (coasted), also through a turn."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam
from ros_logs import PLUMB_BOB, kitti_clip, make_reimager, write_lens_folder

from vslam.rrd.read import read_events
from vslam_core.config import EngineConfig
from vslam_core.errors import SourceError
from vslam_core.geometry import rotation_angle
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult, HealthStatus, Reason
from vslam_core.sources.base import FrameRange
from vslam_core.sources.faults import Fault, FaultInjector, parse_faults
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.open import open_source
from vslam_core.trajectory.metrics import kitti_errors, rpe

N_FRAMES = 70
FRAMES = FrameRange(0, N_FRAMES)  # KITTI 00: straight road, no turn before frame 90; 27 frames after the faults
FAULT_AT = (40, 42)

# kind -> (status on the faulty frames, a reason among them)
EXPECTED = {
    "dark": (HealthStatus.FAIL, Reason.IMAGE_TOO_DARK),
    "overexposed": (HealthStatus.FAIL, Reason.IMAGE_TOO_BRIGHT),
    "blur": (HealthStatus.FAIL, Reason.IMAGE_BLURRED),
    "frozen": (HealthStatus.WARN, Reason.STATIONARY),
    "noise": (HealthStatus.WARN, Reason.IMAGE_NOISY),
}


def run(kitti_root: Path, inject: str | None) -> tuple[list[FrameResult], np.ndarray]:
    source = open_source(str(kitti_root), sequence="00", frames=FRAMES, inject=inject)
    results: list[FrameResult] = []
    run_odometry(source, EngineConfig(backend="vo"), sinks=(lambda _f, r: results.append(r),))
    assert source.ground_truth is not None
    return results, source.ground_truth


@pytest.fixture(scope="module")
def clean(kitti_root: Path) -> tuple[list[FrameResult], np.ndarray]:
    return run(kitti_root, None)


def step_error(results: list[FrameResult], gt: np.ndarray, first: int, last: int) -> tuple[float, float]:
    """RPE (1 frame) over source frames first..last-1."""
    positions = [i for i, r in enumerate(results) if first <= r.index < last]
    poses = np.array([results[i].T_world_cam for i in positions])
    return rpe(gt[positions], poses, 1)


@pytest.mark.kitti
def test_clean_run_flags_nothing(clean: tuple[list[FrameResult], np.ndarray]) -> None:
    results, _ = clean
    assert all(r.health.status == HealthStatus.OK for r in results[1:])


@pytest.mark.kitti
@pytest.mark.parametrize("kind", sorted(EXPECTED))
def test_fault_is_flagged_at_its_frames_and_tracking_recovers(
    kind: str, kitti_root: Path, clean: tuple[list[FrameResult], np.ndarray]
) -> None:
    results, gt = run(kitti_root, f"{kind}@{FAULT_AT[0]}:{FAULT_AT[1]}")
    assert len(results) == N_FRAMES  # one pose per frame, the run went on
    status, reason = EXPECTED[kind]
    for r in results:
        if FAULT_AT[0] <= r.index <= FAULT_AT[1]:
            assert r.health.status == status and reason in r.health.reasons, (r.index, r.health)
        elif r.index > 0 and r.index not in range(FAULT_AT[0], FAULT_AT[1] + 4):
            assert r.health.status == HealthStatus.OK, (r.index, r.health)  # nothing else is flagged
    clean_results, _ = clean
    after = (FAULT_AT[1] + 3, N_FRAMES)
    trans, rot = step_error(results, gt, *after)
    clean_trans, clean_rot = step_error(clean_results, gt, *after)
    assert trans < 2 * clean_trans + 0.01 and rot < 2 * clean_rot + 0.02  # per-frame accuracy is back
    if status == HealthStatus.FAIL:  # unusable frames are dead-reckoned from their degraded images
        untracked = [r for r in results if FAULT_AT[0] <= r.index <= FAULT_AT[1]]
        assert all(Reason.COASTED in r.health.reasons for r in untracked), [r.health for r in untracked]
        trans, rot = step_error(results, gt, FAULT_AT[0] - 1, FAULT_AT[1] + 1)
        assert trans < 0.15 and rot < 0.3  # metres, degrees per frame: the car kept moving (1 m a frame)
    # the motion over the gap was measured, not dropped: the end is where the clean run ends
    clean_end = clean_results[-1].T_world_cam[:3, 3]
    assert np.linalg.norm(results[-1].T_world_cam[:3, 3] - clean_end) < 0.3


@pytest.mark.kitti
def test_a_turn_taken_while_blind_is_not_lost(kitti_root: Path) -> None:
    """blur@200:210 on KITTI 00 100:300: the car turns ~43° in those 11 frames and the frame after them cannot be
    tracked from the last sharp one. Dead reckoning keeps the heading: measured t_err 2.10 % (the clean run of
    100:300: 1.78 %), final heading error 1.1°; holding the pose lost the turn: t_err 32.1 %, heading 44.8°.
    (Over 0:300 the bound was 2.0 %: 1.15 % measured, 1.10 % clean, 16.4 % holding; the 100 frames more only
    cost time.)"""
    source = open_source(str(kitti_root), sequence="00", frames=FrameRange(100, 300), inject="blur@200:210")
    results: list[FrameResult] = []
    run = run_odometry(source, EngineConfig(backend="vo"), sinks=(lambda _f, r: results.append(r),))
    gt = source.ground_truth
    assert gt is not None
    coasted = [r.index for r in results if Reason.COASTED in r.health.reasons]
    assert coasted == list(range(200, 212))  # the blurred frames and the first one after them
    assert (run.held, run.coasted) == (12, 12) and "12 dead-reckoned" in run.held_summary
    t_err, _ = kitti_errors(gt, run.pose_array())
    heading = np.degrees(rotation_angle(gt[-1, :3, :3].T @ run.poses[-1][:3, :3]))
    assert t_err < 2.5 and heading < 2.5, (t_err, heading)  # %, degrees


@pytest.fixture(scope="module")
def lens_folder(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """KITTI 00 frames 170–239 (the second turn) re-imaged through a strong radial–tangential lens
    (tests/ros_logs.py) as a folder of PNGs with times and ground truth, and the lens as a ROS camera_info YAML:
    what a user brings."""
    clip = kitti_clip(kitti_root, "00", range(170, 240))
    folder = tmp_path_factory.mktemp("lens") / "frames"
    calib = write_lens_folder(clip, make_reimager(clip.camera, "plumb_bob", PLUMB_BOB), folder)
    return folder, calib


def _through_lens(lens_folder: tuple[Path, Path], inject: str, backend: str) -> tuple[RunResult, float]:
    """The run of `backend` on the lens folder with `inject` (folder frame numbers), and its final heading error."""
    folder, calib = lens_folder
    source = FaultInjector(ImageFolderSource(folder, calib=calib, ground_truth=folder / "gt.txt"), parse_faults(inject))
    assert source.intrinsics.distorted
    run = run_odometry(source, EngineConfig(backend=backend, threads=1))  # type: ignore[arg-type]
    gt = source.ground_truth
    assert gt is not None
    return run, float(np.degrees(rotation_angle(gt[-1, :3, :3].T @ run.poses[-1][:3, :3])))


@pytest.mark.kitti
@pytest.mark.parametrize("backend", ["vo", "map"])
def test_a_turn_taken_while_blind_through_a_lens_is_not_lost(lens_folder: tuple[Path, Path], backend: str) -> None:
    """The turn above (KITTI 00 frames 200–210 blurred) through a strong radial–tangential lens: dead reckoning
    tracks the raw images and undistorts the corners before the essential matrix. Measured final heading 1.5°
    (`vo`) / 1.4° (map), clean 0.6° / 0.7°; before, a distorted lens was never dead-reckoned, the frames were
    held and the turn was lost: 44°."""
    run, heading = _through_lens(lens_folder, "blur@30:40", backend)
    assert run.coasted >= 11
    assert heading < 2.5, heading


@pytest.mark.kitti
def test_a_dead_reckoned_step_the_ambiguity_turned_around_repeats_the_step_before(
        lens_folder: tuple[Path, Path]) -> None:
    """KITTI 00 frames 191–198 blurred, through the lens: the blurred pair 197 → 198 measures 1.6° of yaw the wrong
    way (the car turned 2.6°) with the car sliding sideways, the rotation–translation ambiguity's other solution;
    a step over 1.5° from the one before it repeats that one (`coasting.steady`). Measured final heading 0.7°,
    without the check 7.4°."""
    run, heading = _through_lens(lens_folder, "blur@21:28", "vo")
    assert run.coasted >= 8
    assert heading < 2.0, heading


@pytest.mark.kitti
def test_dead_reckoned_frames_in_the_output_recording_and_inspect(kitti_root: Path, tmp_path: Path) -> None:
    rrd = tmp_path / "blind.rrd"
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "190:230", "--inject", "blur@200:210", "-o", rrd,
                   "--backend", "vo")
    assert result.returncode == 0, result.stderr
    assert "frames      40 (13 not tracked: 13 dead-reckoned, 0 held the previous pose)" in result.stdout
    report = json.loads(vslam("inspect", rrd, "--json").stdout)
    assert report["flagged"][0] == {"start": 200, "end": 210, "status": "fail", "reasons": ["image_blurred", "coasted"]}
    assert report["drift"]["rotation"][0]["deg"] < 1.0  # each blurred frame's own error (holding: ~3.9°)
    events = [text for _, _, text in read_events(rrd)]
    assert "frame 200: fail (dead-reckoned): image_blurred, coasted" in events


@pytest.mark.kitti
def test_no_dead_reckoning_before_the_first_usable_frame(kitti_root: Path) -> None:
    results, _ = run(kitti_root, "dark@0:4")
    assert all(np.array_equal(r.T_world_cam, np.eye(4)) for r in results[:6])  # frame 5 starts the trajectory
    assert not any(Reason.COASTED in r.health.reasons for r in results[:5])


@pytest.mark.kitti
def test_dropped_frames_are_flagged_as_a_jump_and_skipped(kitti_root: Path) -> None:
    results, gt = run(kitti_root, "drop@40:42")
    assert len(results) == N_FRAMES - 3 and len(gt) == N_FRAMES - 3
    assert [r.index for r in results][38:42] == [38, 39, 43, 44]
    after_gap = next(r for r in results if r.index == 43)
    assert after_gap.health.status == HealthStatus.WARN and Reason.SCALE_JUMP in after_gap.health.reasons
    # measured on 0:70: 1.47 m (clean run: 1.46 m; on 0:90 the bound was 2.2 m for a clean 1.9 m)
    assert np.linalg.norm(results[-1].T_world_cam[:3, 3] - gt[-1, :3, 3]) < 1.8


@pytest.mark.kitti
def test_sudden_brightness_change_is_flagged(kitti_root: Path) -> None:
    results, _ = run(kitti_root, "brightness@40:60")
    flagged = {r.index for r in results if Reason.BRIGHTNESS_JUMP in r.health.reasons}
    assert flagged == {40, 61}  # the jump up and the jump back down
    assert all(r.status != "held" for r in results[1:])


def test_inject_syntax() -> None:
    assert parse_faults("dark@120,blur@200:210") == [Fault("dark", 120, 120), Fault("blur", 200, 210)]
    for bad in ("dark", "smoke@3", "blur@5:2", "blur@a:b", "dark@-1"):
        with pytest.raises(SourceError, match="--inject"):
            parse_faults(bad)
