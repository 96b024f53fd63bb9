"""`vslam eval` on an image folder: the camera from --intrinsics or --calib (issue 12, item 11)."""

from __future__ import annotations

import shutil
from pathlib import Path

import polars as pl
import pytest
from cli_helpers import vslam

from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses

ROOT = Path(__file__).resolve().parents[1]
KITTI_00 = "718.856 718.856 607.1928 185.2157"


@pytest.fixture()
def image_folder(kitti_root: Path, tmp_path: Path) -> tuple[Path, Path]:
    """20 KITTI 00 images in a folder with no calib.txt near it, and their ground truth."""
    folder = tmp_path / "images"
    folder.mkdir()
    for image in sorted((kitti_root / "sequences" / "00" / "image_0").iterdir())[:20]:
        shutil.copy(image, folder / image.name)
    gt = tmp_path / "gt.txt"
    write_kitti_poses(gt, read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=20))
    return folder, gt


@pytest.mark.kitti
def test_eval_takes_intrinsics_and_calib_for_an_image_folder(image_folder: tuple[Path, Path], kitti_root: Path,
                                                             tmp_path: Path) -> None:
    folder, gt = image_folder
    missing = vslam("eval", folder, "--gt", gt)
    assert missing.returncode == 2 and "--intrinsics" in missing.stderr and "Traceback" not in missing.stderr
    fx, fy, cx, cy = KITTI_00.split()
    with_intrinsics = vslam("eval", folder, "--gt", gt, "--intrinsics", f"{fx},{fy},{cx},{cy}", "--report",
                            tmp_path / "a", "--detail", "off")
    assert with_intrinsics.returncode == 0, with_intrinsics.stderr
    with_calib = vslam("eval", folder, "--gt", gt, "--calib", kitti_root / "sequences" / "00" / "calib.txt",
                       "--report", tmp_path / "b", "--detail", "off")
    assert with_calib.returncode == 0, with_calib.stderr
    a, b = (pl.read_csv(tmp_path / name / "metrics.csv").row(0, named=True) for name in "ab")
    assert a["frames"] == b["frames"] == 20
    assert a["ate_sim3"] == pytest.approx(b["ate_sim3"], rel=1e-3)  # the same camera, given two ways


def test_eval_refuses_intrinsics_where_they_do_not_apply(tmp_path: Path) -> None:
    trajectory = vslam("eval", "--trajectory", "a.txt", "--gt", "b.txt", "--intrinsics", "1,1,1,1")
    assert trajectory.returncode == 2 and "do not apply to --trajectory" in trajectory.stderr
    kitti = vslam("eval", "kitti", "--sequences", "00", "--calib", "calib.txt")
    assert kitti.returncode == 2 and "do not apply to KITTI --sequences" in kitti.stderr
