"""TUM RGB-D folders (`TumRgbdSource`): built in tmp_path from real KITTI 05 frames and poses (never written into
the repository), colour PNGs listed in rgb.txt, the ground truth at three times the frame rate."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import VO, vslam

from vslam_core.errors import SourceError
from vslam_core.sources.base import FrameRange, rebase_poses
from vslam_core.sources.kitti import read_p0_intrinsics, read_times
from vslam_core.sources.open import open_source
from vslam_core.sources.tum_rgbd import FREIBURG_CAMERAS, TumRgbdSource, is_tum_rgbd
from vslam_core.trajectory.io import read_kitti_poses, tum_line
from vslam_core.trajectory.metrics import ate

pytestmark = pytest.mark.kitti

SEQ = "05"
COUNT = 60
T0 = 1305031102.175304  # a TUM-like absolute clock (seconds)


def kitti_calib(kitti_root: Path) -> Path:
    return kitti_root / "sequences" / SEQ / "calib.txt"


def make_tum_rgbd(root: Path, kitti_root: Path, count: int = COUNT, size: tuple[int, int] | None = None) -> Path:
    """A TUM RGB-D sequence from KITTI 05's first `count` frames: rgb/<stamp>.png (colour; cropped and padded to
    `size` if given), rgb.txt with the benchmark's comment lines, depth/ left empty, groundtruth.txt with a row
    at each frame's time and two rows between frames (positions interpolated, the rotation of the earlier
    frame), in a world frame where the first pose is not the identity."""
    folder = kitti_root / "sequences" / SEQ
    stamps = T0 + np.asarray(read_times(folder / "times.txt", count))
    poses = read_kitti_poses(kitti_root / "poses" / f"{SEQ}.txt", max_rows=count)
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    lines = ["# color images", "# file: 'rgbd_dataset.bag'", "# timestamp filename"]
    for i, stamp in enumerate(stamps):
        image = cv2.imread(str(folder / "image_0" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        if size is not None:
            crop = image[: size[1], : size[0]]
            image = cv2.copyMakeBorder(crop, 0, size[1] - crop.shape[0], 0, size[0] - crop.shape[1],
                                       cv2.BORDER_REPLICATE)
        name = f"rgb/{stamp:.6f}.png"
        cv2.imwrite(str(root / name), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
        lines.append(f"{stamp:.6f} {name}")
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    world = np.eye(4)
    world[:3, 3] = [1.5, -0.3, 2.0]
    rows = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for i in range(count):
        for k in range(3):
            nxt = poses[min(i + 1, count - 1)]
            pose = poses[i].copy()
            pose[:3, 3] += (nxt[:3, 3] - poses[i][:3, 3]) * k / 3
            rows.append(tum_line(stamps[i] + k * (stamps[min(i + 1, count - 1)] - stamps[i]) / 3,
                                 world @ _orthonormal(pose)).rstrip("\n"))
    (root / "groundtruth.txt").write_text("\n".join(rows) + "\n")
    return root


def _orthonormal(pose: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(pose[:3, :3])
    out = pose.copy()
    out[:3, :3] = u @ vt
    return out


def test_frames_stamps_and_ground_truth_by_time(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_rgbd(tmp_path / "office_walk", kitti_root)
    fx, fy, cx, cy = read_p0_intrinsics(kitti_calib(kitti_root))
    for path in (root, root / "rgb"):
        assert is_tum_rgbd(path)
        source = open_source(str(path), calib=kitti_calib(kitti_root), frames=FrameRange.parse("10:40"))
        assert isinstance(source, TumRgbdSource)
        assert source.name == "tum-rgbd-office_walk" and len(source) == 30
        camera = source.intrinsics
        size = (camera.width, camera.height)
        assert (camera.fx, camera.fy, camera.cx, camera.cy, *size) == (fx, fy, cx, cy, 1226, 370)  # KITTI 05
        assert source.gt_matching is not None
        assert source.gt_matching.startswith("matched by time, interpolated (translation linear, rotation slerp)")
        assert "30 of 30 frames, gaps up to 100 ms allowed" in source.gt_matching
        assert source.properties["dataset"] == "TUM RGB-D"
        assert any("depth images not used" in note for note in source.notes)
    kitti = read_kitti_poses(kitti_root / "poses" / f"{SEQ}.txt", max_rows=COUNT)
    expected = rebase_poses(np.array([_orthonormal(p) for p in kitti[10:40]]))
    np.testing.assert_allclose(source.ground_truth, expected, atol=1e-6)
    frames = list(source)
    stamps = T0 + np.asarray(read_times(kitti_root / "sequences" / SEQ / "times.txt", COUNT))
    assert [f.index for f in frames] == list(range(10, 40))
    assert frames[0].timestamp == pytest.approx(stamps[10], abs=1e-6)
    grey = cv2.imread(str(kitti_root / "sequences" / SEQ / "image_0" / "000010.png"), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(frames[0].image, grey)  # colour PNG back to the grey frame it was made from


def test_published_freiburg_calibration_from_the_folder_name(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_rgbd(tmp_path / "rgbd_dataset_freiburg1_desk", kitti_root, count=3, size=(640, 480))
    source = open_source(str(root))
    camera = source.intrinsics
    (fx, fy, cx, cy), coefficients = FREIBURG_CAMERAS["freiburg1"]
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (fx, fy, cx, cy, 640, 480)
    assert camera.model == "plumb_bob" and camera.coefficients == coefficients and camera.distorted
    assert "freiburg1 published calibration" in camera.origin and "rgbd_dataset_freiburg1_desk" in camera.origin
    given = open_source(str(root), intrinsics="500,500,320,240")  # the user's calibration wins
    assert (given.intrinsics.fx, given.intrinsics.model) == (500.0, "none")
    fr3 = make_tum_rgbd(tmp_path / "rgbd_dataset_freiburg3_long_office", kitti_root, count=3, size=(640, 480))
    assert not open_source(str(fr3)).intrinsics.distorted  # freiburg3's colour frames come undistorted


def test_rows_out_of_stamp_order_are_put_in_order_with_a_note(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_rgbd(tmp_path / "shuffled", kitti_root, count=6)
    lines = (root / "rgb.txt").read_text().splitlines()
    (root / "rgb.txt").write_text("\n".join(lines[:3] + [lines[4], lines[3]] + lines[5:]) + "\n")  # rows 0 and 1
    source = open_source(str(root), calib=kitti_calib(kitti_root))
    assert np.all(np.diff(source.file_times) > 0) and source.files[0].name < source.files[1].name
    assert any("out of stamp order" in note and "used in stamp order" in note for note in source.notes)


def test_a_byte_order_mark_is_not_part_of_the_frame_list(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_rgbd(tmp_path / "edited_on_windows", kitti_root, count=4)
    (root / "rgb.txt").write_text((root / "rgb.txt").read_text(), encoding="utf-8-sig")  # as Notepad saves it
    assert len(open_source(str(root), calib=kitti_calib(kitti_root))) == 4


def test_refusals_are_one_line(tmp_path: Path, kitti_root: Path) -> None:
    plain = make_tum_rgbd(tmp_path / "my_sequence", kitti_root, count=3)
    with pytest.raises(SourceError, match=r"names no Freiburg camera .*--calib FILE or --intrinsics") as caught:
        open_source(str(plain))
    assert "\n" not in str(caught.value)
    wrong_size = make_tum_rgbd(tmp_path / "rgbd_dataset_freiburg2_pioneer", kitti_root, count=3)
    with pytest.raises(SourceError, match=r"images are 1226x370 but the intrinsics are for 640x480"):
        open_source(str(wrong_size))
    (plain / "rgb.txt").write_text("# timestamp filename\n1.0 rgb/missing.png\n")
    with pytest.raises(SourceError, match=r"rgb.txt:2: rgb/missing.png not found"):
        open_source(str(plain), intrinsics="500,500,320,240")


def test_cli_run_on_a_tum_rgbd_folder(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_rgbd(tmp_path / "walk", kitti_root)
    trajectory = tmp_path / "walk.txt"
    result = vslam("run", *VO, root, "--calib", kitti_calib(kitti_root), "-o", tmp_path / "walk.rrd",
                   "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    assert "matched by time, interpolated (translation linear, rotation slerp)" in result.stdout
    assert "60 of 60 frames" in result.stdout
    ground_truth = open_source(str(root), calib=kitti_calib(kitti_root)).ground_truth
    estimate = read_kitti_poses(trajectory)  # KITTI 05 0:60, 51 m: measured 0.23 m / 0.03 m
    assert ate(ground_truth, estimate, "none") < 0.5 and ate(ground_truth, estimate, "sim3") < 0.1
    refused = vslam("run", make_tum_rgbd(tmp_path / "unnamed", kitti_root, count=3), "-o", tmp_path / "x.rrd")
    assert refused.returncode == 2
    assert refused.stderr.strip().count("\n") == 0 and "names no Freiburg camera" in refused.stderr
