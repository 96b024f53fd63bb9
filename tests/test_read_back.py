"""What a recording says when read back (issue 54): ground truth paired with the poses by FRAME (never by row),
whether or not the first frame has vslam's zero-length segment; the pipeline and backend of a `vslam.log`
recording; a cropped file's verdict marked as the whole run's; `eval --trajectory` of a window that does not
start at frame 0 scored against its own frames (ATE ≈ 0 for a perfect trajectory) or refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from cli_helpers import vslam

from vslam.log import CameraIntrinsics, FrameLog
from vslam_core.trajectory.io import read_kitti_poses

FRAMES = 20
OFFSET = np.array([0.1, 0.0, 0.2])  # the estimate is the ground truth moved by this, from frame 1 on


def plain_recording(path: Path, first_segment: bool, angles: bool, start: int = 0) -> tuple[Path, float]:
    """A plain-SDK recording of frames start..start+19 with position errors (and the angle series when `angles`),
    the ground truth logged as the schema says, with or without the first frame's zero-length segment; and the
    true paper RMS (x–z) of its estimate."""
    rec = rr.RecordingStream("my-vo")
    rec.save(path)
    rec.send_property("run", rr.AnyValues(schema_version="1", name="my-vo", source="kitti-05",
                                          frames=f"{start}:{start + FRAMES}", frame_count=str(FRAMES)))
    truth = [np.array([0.1 * i, 0.0, 1.0 * i]) for i in range(FRAMES)]
    errors = []
    for i in range(FRAMES):
        rec.set_time("frame", sequence=start + i)
        estimate = truth[i] + OFFSET * (i > 0)
        errors.append(estimate - truth[i])
        rec.log("/world/camera", rr.Transform3D(translation=estimate, mat3x3=np.eye(3)))
        if i > 0 or first_segment:
            rec.log("/world/trajectory/ground_truth", rr.LineStrips3D([[truth[max(i - 1, 0)], truth[i]]]))
        rec.log("/metrics/error/position_m", rr.Scalars(float(np.linalg.norm(errors[-1]))))
        if angles:
            rec.log("/metrics/angle_error/heading_deg", rr.Scalars(0.5))
            rec.log("/metrics/angle_error/translation_direction_deg", rr.Scalars(1.0))
    rec.flush()
    rec.disconnect()
    xz = np.array(errors)[:, [0, 2]]
    return path, float(np.sqrt(np.mean(np.sum(xz**2, axis=1))))


@pytest.mark.parametrize("first_segment", [True, False])
@pytest.mark.parametrize("angles", [True, False])
def test_paper_rms_pairs_ground_truth_by_frame(first_segment: bool, angles: bool, tmp_path: Path) -> None:
    path, true_rms = plain_recording(tmp_path / "run.rrd", first_segment, angles, start=7)
    assert vslam("check", path).returncode == 0
    result = vslam("inspect", path, "--json")
    assert result.returncode == 0, result.stderr
    accuracy = json.loads(result.stdout)["accuracy"]
    assert accuracy["paper_rms_m"] == pytest.approx(true_rms, abs=1e-6)  # 0.22 m (row pairing: ~1.2 m)
    assert accuracy["final_position_error_m"] == pytest.approx(float(np.linalg.norm(OFFSET)), abs=1e-6)
    assert accuracy["final_heading_error_deg"] == (0.5 if angles else None)
    text = vslam("inspect", path).stdout
    assert f"paper RMS (x–z) {true_rms:.2f} m" in text and ("heading error" in text) == angles


def test_a_framelog_recording_names_its_pipeline_and_a_crop_marks_its_verdict(tmp_path: Path) -> None:
    camera = CameraIntrinsics(fx=70.0, fy=70.0, cx=32.0, cy=24.0, width=64, height=48)
    path = tmp_path / "run.rrd"
    with FrameLog(path, camera=camera, source="kitti-05", pipeline="my-vo", detail="summary") as log:
        for i in range(30):
            pose, truth = np.eye(4), np.eye(4)
            pose[2, 3], truth[2, 3] = 1.02 * i, 1.0 * i
            log.frame(i, pose=pose, gt=truth)
    report = json.loads(vslam("inspect", path, "--json").stdout)
    assert report["properties"]["pipeline"] == "my-vo" and report["properties"]["backend"] == "external"
    assert report["report_metrics"] is not None and report["report_metrics_cropped"] is False
    text = vslam("inspect", path).stdout
    assert "backend external" in text and "pipeline    my-vo (logged with vslam.log" in text
    assert vslam("crop", path, "--frames", "10:20", "-o", tmp_path / "crop.rrd").returncode == 0
    cropped = json.loads(vslam("inspect", tmp_path / "crop.rrd", "--json").stdout)
    assert cropped["report_metrics_cropped"] is True and cropped["report_metrics_frames"] == "0:30"
    assert "verdict     /report (t_err, ATE …) is of frames 0:30, the run before crop" in \
        vslam("inspect", tmp_path / "crop.rrd").stdout


@pytest.fixture(scope="module")
def perfect_window(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A perfect trajectory (estimate = ground truth) of KITTI 05 frames 50..149 written by `FrameLog(trajectory=
    …)` in KITTI and TUM (times since the window's start), and its recording."""
    folder = tmp_path_factory.mktemp("window")
    gt = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=150)
    times = np.loadtxt(kitti_root / "sequences" / "05" / "times.txt")
    camera = CameraIntrinsics(fx=707.09, fy=707.09, cx=601.89, cy=183.11, width=1226, height=370)
    for fmt in ("kitti", "tum"):
        with FrameLog(folder / f"{fmt}.rrd", camera=camera, source="kitti-05", pipeline="perfect", detail="summary",
                      trajectory=folder / f"window.{fmt}", trajectory_format=fmt) as log:
            for i in range(50, 150):
                log.frame(i, pose=gt[i], time=float(times[i] - times[50]), gt=gt[i])
    return {"kitti": folder / "window.kitti", "tum": folder / "window.tum", "rrd": folder / "tum.rrd",
            "gt": kitti_root / "poses" / "05.txt", "times": kitti_root / "sequences" / "05" / "times.txt"}


WINDOW_CASES = {  # extra arguments → None: refused in one line, else the method of pairing
    ("kitti",): None,
    ("kitti", "--match", "rows"): None,
    ("kitti", "--frames", "50:150"): "frame",
    ("kitti", "--frames", "50:150", "--match", "rows"): "frame",
    ("tum",): "frame",  # its header names the frames
    ("tum", "--gt-times"): "frame",
    ("tum", "--gt-times", "--match", "timestamps"): "timestamp",  # times since frame 50
    ("tum", "--gt-times", "--frames", "50:150"): "timestamp",
    ("rrd",): "frame",  # the recording's frame timeline
    ("rrd", "--gt-times", "--match", "timestamps"): "timestamp",
}


@pytest.mark.kitti
@pytest.mark.parametrize("case", list(WINDOW_CASES), ids=[" ".join(c) for c in WINDOW_CASES])
def test_a_perfect_window_scores_zero_or_is_refused(case: tuple[str, ...], perfect_window: dict[str, Path]) -> None:
    args = [a if a != "--gt-times" else f"--gt-times={perfect_window['times']}" for a in case[1:]]
    result = vslam("eval", "--trajectory", perfect_window[case[0]], "--gt", perfect_window["gt"], *args, "--json")
    expected = WINDOW_CASES[case]
    if expected is None:
        assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert "--frames A:B" in result.stderr
        return
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    row = data["sequences"][0]
    print(f"{' '.join(case)}: ATE SE3 {row['ate_se3']:.2e} m, Sim3 {row['ate_sim3']:.2e} m; {data['matching']['text']}")
    assert data["matching"]["method"] == expected and data["matching"]["ground_truth_rows"] == "50..149"
    assert row["frames"] == 100 and row["ate_se3"] < 1e-4 and row["ate_sim3"] < 1e-4  # never the 10 m of rows 0..99


def test_window_misuse_is_refused_in_one_line(tmp_path: Path) -> None:
    """Synthetic files: a window past the ground truth, --frames with a TUM ground truth (rows are stamps),
    --time-offset without times, a TUM file whose times start on neither clock."""
    from vslam_core.trajectory.io import write_kitti_poses, write_tum_poses

    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, 2, 3] = np.arange(40.0)
    write_kitti_poses(tmp_path / "gt.txt", poses)
    write_kitti_poses(tmp_path / "est.txt", poses[10:20])
    write_tum_poses(tmp_path / "gt.tum", np.arange(40) * 0.1, poses)
    write_tum_poses(tmp_path / "est.tum", 7.0 + np.arange(10) * 0.1, poses[10:20])
    (tmp_path / "times.txt").write_text("".join(f"{0.1 * i:.6f}\n" for i in range(40)))
    cases = {
        ("est.txt", "gt.txt", "--frames", "35:45"): "is 5 frames",  # clamped like a slice: 35..39
        ("est.txt", "gt.tum", "--frames", "10:20"): "TUM ground truth",
        ("est.txt", "gt.txt", "--time-offset", "1"): "has none",
        ("est.tum", "gt.txt", f"--gt-times={tmp_path / 'times.txt'}", "--frames", "10:20"): "--time-offset",
    }
    for (estimate, gt, *args), message in cases.items():
        result = vslam("eval", "--trajectory", tmp_path / estimate, "--gt", tmp_path / gt, *args)
        assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1, result.stderr
        assert message in result.stderr, result.stderr
    shifted = vslam("eval", "--trajectory", tmp_path / "est.tum", "--gt", tmp_path / "gt.txt", "--gt-times",
                    tmp_path / "times.txt", "--time-offset", "-6", "--json")  # 7.0 s - 6 s = frame 10's 1.0 s
    assert shifted.returncode == 0, shifted.stderr
    data = json.loads(shifted.stdout)
    assert data["matching"]["ground_truth_rows"] == "10..19" and data["sequences"][0]["ate_se3"] < 1e-6
