"""Ground truth is paired with the frames by time whenever both sides have a clock, for every source (issue 24,
item 1): an image folder with ``times.txt`` and a TUM ground truth at twice the camera's rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import VO, vslam, vslam_here
from scipy.spatial.transform import Rotation, Slerp

from vslam_core.sources.base import rebase_poses
from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses, write_tum_poses
from vslam_core.trajectory.metrics import paper_rms_error

FRAMES = 100


def _twice_the_rate(times: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(2N-1,) stamps and poses: every frame's, and one half-way between each two (translation linear,
    rotation slerp), as a ground-truth system logging at twice the camera's rate would."""
    half = (times[:-1] + times[1:]) / 2
    stamps = np.concatenate([times, half])
    rotations = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(stamps)
    centres = np.stack([np.interp(stamps, times, poses[:, i, 3]) for i in range(3)], axis=1)
    order = np.argsort(stamps)
    dense = np.tile(np.eye(4), (len(stamps), 1, 1))
    dense[:, :3, :3] = rotations.as_matrix()
    dense[:, :3, 3] = centres
    return stamps[order], dense[order]


@pytest.fixture(scope="module")
def timed_folder(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """KITTI 05 frames 0..99 (links) in a folder with their times.txt and calib.txt beside them, a TUM ground
    truth at twice the frame rate on the same clock, and the same poses as KITTI rows (one per frame)."""
    base = tmp_path_factory.mktemp("timed")
    sequence = kitti_root / "sequences" / "05"
    folder = base / "images"
    folder.mkdir()
    for image in sorted((sequence / "image_0").iterdir())[:FRAMES]:
        (folder / image.name).symlink_to(image)
    times = np.loadtxt(sequence / "times.txt")[:FRAMES]
    (folder / "times.txt").write_text("".join(f"{t:.6e}\n" for t in times))
    poses = read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=FRAMES)
    stamps, dense = _twice_the_rate(times, poses)
    write_tum_poses(base / "gt.tum", stamps, dense)
    write_kitti_poses(base / "gt.txt", poses)
    return {"folder": folder, "tum": base / "gt.tum", "kitti": base / "gt.txt", "calib": sequence / "calib.txt",
            "base": base}


@pytest.mark.kitti
def test_tum_ground_truth_at_twice_the_rate_is_matched_by_time(timed_folder: dict[str, Path],
                                                               kitti_root: Path) -> None:
    trajectory = timed_folder["base"] / "estimate.txt"
    result = vslam("run", *VO, timed_folder["folder"], "--calib", timed_folder["calib"], "--gt", timed_folder["tum"],
                   "--detail", "off", "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    truth = rebase_poses(read_kitti_poses(kitti_root / "poses" / "05.txt", max_rows=FRAMES))
    estimate = read_kitti_poses(trajectory)
    # scaled by the ground truth of the right frames, the estimate covers the whole path (row by row, the
    # scale came from poses half a frame apart: half the distance, RMS ~20 m)
    travelled = np.linalg.norm(estimate[-1, :3, 3]), np.linalg.norm(truth[-1, :3, 3])
    assert travelled[0] == pytest.approx(travelled[1], rel=0.05)
    assert paper_rms_error(truth, estimate) < 2.0
    assert f"ground truth matched by time, {FRAMES} of {FRAMES} frames, tolerance 10 ms" in result.stdout


@pytest.mark.kitti
def test_one_clock_and_different_counts_are_refused(timed_folder: dict[str, Path], kitti_root: Path) -> None:
    # frames with a clock, ground truth without one and 4541 rows for 200 frames: refused
    kitti = vslam_here("run", timed_folder["folder"], "--calib", timed_folder["calib"], "--gt",
                       kitti_root / "poses" / "05.txt", "--detail", "off")
    assert kitti.returncode == 2 and "cannot be matched by time" in kitti.stderr and kitti.stderr.count("\n") == 1
    # the TUM file for frames without a clock (a folder without times.txt): refused
    bare = timed_folder["base"] / "bare"
    bare.mkdir(exist_ok=True)
    for image in sorted(timed_folder["folder"].glob("*.png"))[:20]:
        if not (bare / image.name).exists():
            (bare / image.name).symlink_to(image.resolve())
    tum = vslam_here("run", bare, "--calib", timed_folder["calib"], "--gt", timed_folder["tum"], "--detail", "off")
    assert tum.returncode == 2 and "frames without timestamps" in tum.stderr
    assert tum.stderr.count("\n") == 1


@pytest.mark.kitti
def test_gt_tolerance_is_refused_where_nothing_is_matched_by_time(timed_folder: dict[str, Path],
                                                                   kitti_root: Path) -> None:
    kitti = vslam_here("run", kitti_root, "--sequence", "05", "--frames", "0:5", "--gt-tolerance", "5")
    assert kitti.returncode == 2 and "--gt-tolerance does not apply here" in kitti.stderr
    assert "row by row" in kitti.stderr
    synthetic = vslam_here("run", "--gt-tolerance", "5", "--detail", "off")
    assert synthetic.returncode == 2 and "--gt-tolerance does not apply here" in synthetic.stderr
    rows = vslam_here("run", timed_folder["folder"], "--calib", timed_folder["calib"], "--gt-tolerance", "5",
                      "--detail", "off")
    assert rows.returncode == 2 and "there is no ground truth" in rows.stderr
    evaluated = vslam_here("eval", kitti_root, "--sequences", "05", "--gt-tolerance", "5")
    assert evaluated.returncode == 2 and "--gt-tolerance does not apply here" in evaluated.stderr


@pytest.mark.kitti
def test_row_by_row_is_said_in_the_summary(timed_folder: dict[str, Path]) -> None:
    result = vslam("run", *VO, timed_folder["folder"], "--calib", timed_folder["calib"], "--gt", timed_folder["kitti"],
                   "--frames", "0:10", "--detail", "off")
    assert result.returncode == 0, result.stderr
    assert "ground truth row by row" in result.stdout


def test_a_video_with_container_times_is_matched_by_time(tmp_path: Path) -> None:
    """A 10 fps video (container times 0, 0.1, …) and a TUM ground truth at 20 Hz: each frame gets the pose
    logged at its own time, not row i (the same rule as an image folder with times.txt)."""
    import cv2

    from vslam_core.sources.base import FrameRange
    from vslam_core.sources.folder import PartialIntrinsics
    from vslam_core.sources.video import VideoSource

    video = tmp_path / "drive.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (160, 120), False)
    for i in range(6):
        writer.write(np.full((120, 160), 20 * (i + 1), np.uint8))
    writer.release()
    stamps = np.arange(12) * 0.05
    poses = np.tile(np.eye(4), (12, 1, 1))
    poses[:, 2, 3] = stamps * 10.0  # 10 m/s forward: z = 10 t
    write_tum_poses(tmp_path / "gt.tum", stamps, poses)
    source = VideoSource(video, PartialIntrinsics(100.0, 100.0, 80.0, 60.0), frames=FrameRange(1, 6),
                         ground_truth=tmp_path / "gt.tum")
    assert source.gt_matching == "matched by time, 5 of 5 frames, tolerance 10 ms"
    assert source.ground_truth is not None
    np.testing.assert_allclose(source.ground_truth[:, 2, 3], np.arange(5) * 1.0, atol=1e-9)  # row by row: 0.5 m
