"""The ground truth checked against the images (`vslam_core.trajectory.gt_check`) and how ground truth is paired
with frames that have no clock (--gt-rows), on real frames: KITTI 05 and TUM fr1 xyz, with the wrong ground truth
built in each test (w x y z quaternions, a clock 0.1 s off, rows 100 frames off, the body's poses, a renumbered
folder and the whole sequence's poses). Thresholds and figures: docs/own-data.md."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_helpers import VO, vslam
from kitti_runs import link_images

from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange, FrameSource, rebase_poses
from vslam_core.sources.open import open_source
from vslam_core.trajectory.gt_check import FAR_OFF_RATIO, CheckSummary, GroundTruthCheck
from vslam_core.trajectory.io import read_kitti_poses, write_tum_poses

pytestmark = pytest.mark.kitti

TUM_FRAMES = FrameRange(0, 120)
KITTI_FRAMES = FrameRange(0, 150)


@pytest.fixture(scope="module")
def tum_xyz(tum_root: Path) -> Path:
    """The TUM fr1 xyz frames (`tum_root`: fails instead of skipping under CI)."""
    return tum_root / "rgbd_dataset_freiburg1_xyz"


def _results(source: FrameSource, scale: str) -> list[FrameResult]:
    results: list[FrameResult] = []

    def keep(_frame: Frame, result: FrameResult) -> None:
        results.append(result)

    run_odometry(source, EngineConfig(backend="vo").with_scale(scale), (keep,))  # type: ignore[arg-type]
    return results


def _check(results: list[FrameResult], source: FrameSource) -> CheckSummary:
    assert source.ground_truth is not None
    check = GroundTruthCheck(source.ground_truth, source.intrinsics)
    for result in results:
        check(Frame(result.index, result.timestamp, np.zeros((0, 0), np.uint8)), result)
    summary = check.summary()
    assert summary is not None
    return summary


@pytest.fixture(scope="module")
def tum_run(tum_xyz: Path) -> list[FrameResult]:
    """One run of TUM fr1 xyz frames 0:120 (scale none), checked below against several ground truths."""
    return _results(open_source(str(tum_xyz), frames=TUM_FRAMES), "none")


@pytest.fixture(scope="module")
def kitti_run(kitti_root: Path) -> list[FrameResult]:
    """One run of KITTI 05 frames 0:150 (scale from its ground truth)."""
    return _results(open_source(str(kitti_root), sequence="05", frames=KITTI_FRAMES), "gt")


def _tum_rows(path: Path) -> list[list[str]]:
    return [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


def write_wxyz(xyz: Path, tmp_path: Path) -> Path:
    """TUM fr1 xyz's ground truth with its quaternions written w x y z (read as x y z w)."""
    out = tmp_path / "wxyz.txt"
    out.write_text("".join(f"{r[0]} {r[1]} {r[2]} {r[3]} {r[7]} {r[4]} {r[5]} {r[6]}\n"
                           for r in _tum_rows(xyz / "groundtruth.txt")))
    return out


def write_shifted(xyz: Path, tmp_path: Path, seconds: float) -> Path:
    """TUM fr1 xyz's ground truth with every stamp `seconds` later (its clock ahead of the frames')."""
    out = tmp_path / f"shifted{seconds}.txt"
    out.write_text("".join(f"{float(r[0]) + seconds:.4f} " + " ".join(r[1:]) + "\n"
                           for r in _tum_rows(xyz / "groundtruth.txt")))
    return out


def test_agreeing_ground_truth_passes(tum_run: list[FrameResult], kitti_run: list[FrameResult], tum_xyz: Path,
                                      kitti_root: Path) -> None:
    tum = _check(tum_run, open_source(str(tum_xyz), frames=TUM_FRAMES))
    kitti = _check(kitti_run, open_source(str(kitti_root), sequence="05", frames=KITTI_FRAMES))
    for summary in (tum, kitti):
        assert 1.0 < summary.ratio < FAR_OFF_RATIO / 1.5, summary.line()  # a fit always wins a little
        assert summary.rotation_deg < 0.4 and not summary.far_off
        assert summary.warnings() == []
        assert summary.shift is not None and not summary.shift.better
    assert kitti.pairs >= 140 and tum.pairs >= 110
    assert kitti.rotation_deg < 0.05  # a car's frame-to-frame rotation, against the images


def test_quaternions_in_the_wrong_order_are_far_off(tum_run: list[FrameResult], tum_xyz: Path, tmp_path: Path
                                                    ) -> None:
    summary = _check(tum_run, open_source(str(tum_xyz), frames=TUM_FRAMES, ground_truth=write_wxyz(tum_xyz, tmp_path)))
    assert summary.far_off and summary.ratio > 2 * FAR_OFF_RATIO, summary.line()
    [warning] = summary.warnings()
    assert warning.startswith("the ground truth disagrees with the images") and "quaternion order" in warning


def test_a_clock_offset_is_found_and_applying_it_fixes_it(tum_run: list[FrameResult], tum_xyz: Path,
                                                          tmp_path: Path) -> None:
    shifted = write_shifted(tum_xyz, tmp_path, 0.1)
    summary = _check(tum_run, open_source(str(tum_xyz), frames=TUM_FRAMES, ground_truth=shifted))
    assert summary.shift is not None and summary.shift.better and summary.shift.in_seconds
    assert summary.shift.offset == pytest.approx(0.1, abs=0.03)
    [warning] = summary.warnings()
    assert re.search(r"shifted by \+0\.(0[89]|1[01])\d s .* --gt-time-offset \+0\.(0[89]|1[01])\d$", warning), warning
    applied = _check(tum_run, open_source(str(tum_xyz), frames=TUM_FRAMES, ground_truth=shifted,
                                          gt_time_offset_s=0.1))
    assert applied.warnings() == [] and applied.ratio < summary.ratio / 2


@pytest.mark.parametrize("wrong", ["rows 100 frames later", "the body's poses", "sequence 00's poses"])
def test_kitti_ground_truth_of_other_frames_is_far_off(kitti_run: list[FrameResult], kitti_root: Path,
                                                       tmp_path: Path, wrong: str) -> None:
    poses = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=400)
    if wrong == "rows 100 frames later":
        poses = poses[100:]
    elif wrong == "the body's poses":  # x forward, y left, z up: T_w_body = T_w_cam · T_cam_body
        body = np.eye(4)
        body[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]
        poses = poses @ body
    else:
        poses = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=150)
    source = open_source(str(kitti_root), sequence="05", frames=KITTI_FRAMES)
    check = GroundTruthCheck(rebase_poses(poses[:150]), source.intrinsics)
    for result in kitti_run:
        check(Frame(result.index, result.timestamp, np.zeros((0, 0), np.uint8)), result)
    summary = check.summary()
    assert summary is not None
    assert summary.far_off and summary.ratio > FAR_OFF_RATIO, summary.line()
    assert any("disagrees with the images" in w for w in summary.warnings())


@pytest.fixture
def renumbered(kitti_root: Path, tmp_path: Path) -> Path:
    """KITTI 05 images 100–159 renumbered from 000000, with calib.txt, and no times.txt."""
    folder = link_images(kitti_root, tmp_path / "frames", range(100, 160))
    (folder / "calib.txt").write_text((kitti_root / "sequences" / "05" / "calib.txt").read_text())
    return folder


def test_a_longer_ground_truth_without_times_is_refused(renumbered: Path, kitti_root: Path, tmp_path: Path) -> None:
    gt = kitti_root / "poses" / "05.txt"
    refused = vslam("run", *VO, renumbered, "--gt", gt, "--detail", "off")
    assert refused.returncode == 2 and refused.stdout == ""
    [line] = refused.stderr.strip().splitlines()
    assert "2761 poses for 60 frames and nothing pairs them by time" in line and "--gt-rows A:B" in line
    assert "--frames" in line
    trajectory = tmp_path / "run.txt"
    paired = vslam("run", *VO, renumbered, "--gt", gt, "--gt-rows", "100:160", "--detail", "off", "--trajectory-out",
                   trajectory)
    assert paired.returncode == 0, paired.stderr
    assert "ground truth row by row from row 100 (--gt-rows 100:160" in paired.stdout
    assert "gt check    Sampson" in paired.stdout and "disagrees" not in paired.stderr
    truth = rebase_poses(read_kitti_poses(gt, max_rows=160)[100:160])
    estimate = read_kitti_poses(trajectory)
    length = np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1).sum()
    assert length == pytest.approx(28.1, abs=0.2)  # the stretch's own length, not 51 m of frames 0–59
    assert np.linalg.norm(estimate[-1, :3, 3] - truth[-1, :3, 3]) < 0.05 * length


@pytest.mark.parametrize(("args", "message"), [
    (("--gt-rows", "100:150"), "--gt-rows 100:150 holds 50 rows for 60 frames"),
    (("--gt-rows", "2800:"), "--gt-rows 2800:2860: "),
    (("--gt-rows", "x"), "--gt-rows 'x': expected A:B"),
    (("--gt-time-offset", "0.1"), "--gt-time-offset does not apply here"),
])
def test_pairing_options_that_cannot_apply_are_refused(renumbered: Path, kitti_root: Path, args: tuple[str, ...],
                                                       message: str) -> None:
    result = vslam("run", *VO, renumbered, "--gt", kitti_root / "poses" / "05.txt", *args, "--detail", "off")
    assert result.returncode == 2 and message in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_kitti_and_time_matched_sources_refuse_what_does_not_apply(kitti_root: Path, tum_xyz: Path) -> None:
    kitti = vslam("run", *VO, kitti_root, "--sequence", "05", "--frames", "0:5", "--gt-time-offset", "0.1",
                  "--detail", "off")
    assert kitti.returncode == 2 and "--gt-time-offset does not apply here" in kitti.stderr
    tum = vslam("run", *VO, tum_xyz, "--gt", tum_xyz / "groundtruth.txt", "--gt-rows", "0:200", "--detail", "off")
    assert tum.returncode == 2 and "--gt-rows does not apply here" in tum.stderr


def _run(tum_xyz: Path, tmp_path: Path, gt: Path, *extra: str) -> tuple[str, str, dict[str, Any]]:
    """`vslam run` on TUM fr1 xyz frames 0:60 with `gt` (and `extra` options): its stdout, stderr, and the
    `gt_check` of `vslam inspect --json` on its recording (whose text `inspect` states the same). Half the frames
    of `tum_run`: the check's figures on 0:120 are tested above, here what the CLI says and records (60 frames: two
    windows, the wrong order and the 0.1 s shift found as on 120; ~7 CPU-s less over the three runs)."""
    rrd = tmp_path / f"{gt.stem}{len(extra)}.rrd"
    result = vslam("run", *VO, tum_xyz, "--gt", gt, "--frames", "0:60", "--detail", "summary", "-o", rrd, *extra)
    assert result.returncode == 0, result.stderr
    report = vslam("inspect", rrd, "--json")
    assert report.returncode == 0, report.stderr
    check = json.loads(report.stdout)["gt_check"]
    text = vslam("inspect", rrd).stdout
    assert f"gt check    {check['line']}" in text
    assert all(f"            warning: {warning}" in text for warning in check["warnings"])
    ratios = [v[0] for v in read_entity(rrd, "/metrics/gt_check/sampson_ratio")["Scalars:scalars"].to_list()]
    assert len(ratios) == check["frames"]  # one value a scored frame, the series the figures come from
    return result.stdout, result.stderr, check


def test_cli_warns_in_one_line_and_records_the_check(tum_xyz: Path, tmp_path: Path) -> None:
    stdout, stderr, check = _run(tum_xyz, tmp_path, write_wxyz(tum_xyz, tmp_path))
    warnings = [line for line in stderr.splitlines() if "ground truth" in line]
    assert len(warnings) == 1 and "disagrees with the images" in warnings[0]
    assert "gt check    Sampson" in stdout
    assert check["far_off"] is True and check["ratio"] > FAR_OFF_RATIO and check["frames"] >= 50
    assert len(check["warnings"]) == 1 and "quaternion order" in check["warnings"][0]
    assert [(w["first"], w["last"]) for w in check["windows"]] == [(0, 49), (50, 59)]

    stdout, stderr, check = _run(tum_xyz, tmp_path, write_shifted(tum_xyz, tmp_path, 0.1))
    warnings = [line for line in stderr.splitlines() if "ground truth" in line]
    assert len(warnings) == 1 and re.search(r"--gt-time-offset \+0\.(0[89]|1[01])\d$", warnings[0]), warnings
    assert len(check["warnings"]) == 1 and "--gt-time-offset +0." in check["warnings"][0]

    stdout, stderr, check = _run(tum_xyz, tmp_path, write_shifted(tum_xyz, tmp_path, 0.1), "--gt-time-offset", "0.1")
    assert "the ground truth's clock +0.100 s from the frames' (--gt-time-offset)" in stdout
    assert "ground truth" not in stderr and check["warnings"] == [] and check["far_off"] is False


def test_rows_a_few_frames_off_are_found(kitti_run: list[FrameResult], kitti_root: Path) -> None:
    """A KITTI-format ground truth paired row by row whose rows start 5 frames late (a car driving steadily: only
    the turns tell them apart): the rows to use are found, and the message points to --gt-rows."""
    poses = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=200)[5:155]
    source = open_source(str(kitti_root), sequence="05", frames=KITTI_FRAMES)
    check = GroundTruthCheck(rebase_poses(poses), source.intrinsics, by_time=False)
    for result in kitti_run:
        check(Frame(result.index, result.timestamp, np.zeros((0, 0), np.uint8)), result)
    summary = check.summary()
    assert summary is not None and summary.shift is not None and summary.shift.better
    assert summary.shift.frames == -5
    [warning] = summary.warnings()
    assert "frame i with row i-5" in warning and "--gt-rows A:B" in warning


def test_eval_warns_about_the_ground_truth_it_scores_against(tum_xyz: Path, tmp_path: Path) -> None:
    result = vslam("eval", tum_xyz, "--gt", write_wxyz(tum_xyz, tmp_path), "--frames", "0:60", "--scale", "none")
    assert result.returncode == 0, result.stderr
    [warning] = [line for line in result.stderr.splitlines() if "ground truth" in line]
    assert warning.startswith("warning: tum-rgbd-rgbd_dataset_freiburg1_xyz: the ground truth disagrees")


def test_a_car_s_clock_one_frame_off_is_found(kitti_run: list[FrameResult], kitti_root: Path, tmp_path: Path
                                              ) -> None:
    """KITTI 05's frames (times.txt) with a TUM ground truth whose stamps are 0.1 s early, about one frame: below
    the far-off ratio, but its turns fit much better shifted back, and the warning says by how much."""
    folder = kitti_root / "sequences" / "05"
    times = np.loadtxt(folder / "times.txt")
    times = np.concatenate([times, times[-1] + np.median(np.diff(times)) * np.arange(1, 101)])
    gt = tmp_path / "early.tum"
    write_tum_poses(gt, times - 0.1, read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=len(times)))
    source = open_source(str(folder / "image_0"), frames=KITTI_FRAMES, ground_truth=gt)
    assert source.ground_truth is not None and (source.gt_matching or "").startswith("matched by time")
    check = GroundTruthCheck(source.ground_truth, source.intrinsics, by_time=True)
    for result in kitti_run:
        check(Frame(result.index, result.timestamp, np.zeros((0, 0), np.uint8)), result)
    summary = check.summary()
    assert summary is not None and summary.shift is not None and summary.shift.better
    assert summary.shift.offset == pytest.approx(-0.1, abs=0.02)
    [warning] = summary.warnings()
    assert re.search(r"--gt-time-offset -0\.(09|10)\d$", warning), warning
