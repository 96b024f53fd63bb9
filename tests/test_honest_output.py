"""What the CLI prints is the truth about its input (issue 24): user text verbatim (no Rich markup or emoji
codes, item 9), the calibration used and where it came from (items 5 and 14), warnings for inputs that are valid
but almost surely a mistake, and one-line errors naming the option to use (item 14)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import vslam, vslam_here

from vslam.rrd.provenance import read_properties

#: `:100:` is Rich's emoji code for 💯; `[red]` is markup
TRICKY = ":100:[red]x"


def _no_rewriting(result: object, *texts: str) -> None:
    stderr, stdout = result.stderr, result.stdout  # type: ignore[attr-defined]
    for text in texts:
        assert text in stderr + stdout, (stdout, stderr)
    assert "💯" not in stderr + stdout


def test_user_text_is_printed_verbatim_in_errors(tmp_path: Path) -> None:
    run = vslam_here("run", "--frames", "0:100:2:5")
    assert run.returncode == 2
    _no_rewriting(run, "'0:100:2:5'")
    crop = vslam_here("crop", tmp_path / "x.rrd", "--frames", "0:100:2", "-o", tmp_path / "y.rrd")
    assert crop.returncode == 2
    _no_rewriting(crop, "'0:100:2'")
    evaluated = vslam_here("eval", "--frames", "0:100:2:1")
    assert evaluated.returncode == 2
    _no_rewriting(evaluated, "'0:100:2:1'")
    manifest = tmp_path / "logs.csv"
    manifest.write_text("name,source,frames\na,synthetic,0:100:2:9\n")
    batch = vslam_here("eval", "--manifest", manifest, "--report", tmp_path / "report")
    assert batch.returncode == 2
    _no_rewriting(batch, "'0:100:2:9'")
    path = tmp_path / f"{TRICKY}.rrd"
    inspected = vslam_here("inspect", path)
    assert inspected.returncode == 2
    _no_rewriting(inspected, f"{path}: no such recording")
    missing = vslam_here("run", str(tmp_path / TRICKY))
    _no_rewriting(missing, f"{tmp_path / TRICKY}: no such file or folder")


def test_paths_in_results_are_printed_verbatim(tmp_path: Path) -> None:
    output = tmp_path / f"{TRICKY}.rrd"
    trajectory = tmp_path / f"{TRICKY}.txt"
    result = vslam("run", "--frames", "0:3", "-o", output, "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    _no_rewriting(result, f"recording   {output}", f"trajectory  {trajectory}")
    inspected = vslam("inspect", output)
    assert inspected.returncode == 0, inspected.stderr
    _no_rewriting(inspected)
    cropped = tmp_path / f"{TRICKY}-crop.rrd"
    crop = vslam("crop", output, "--frames", "1:3", "-o", cropped)
    assert crop.returncode == 0, crop.stderr
    _no_rewriting(crop, f"{cropped}: frames 1..2")


@pytest.fixture()
def folder_with_calib_above(kitti_root: Path, tmp_path: Path) -> Path:
    """Five KITTI 00 frames (links) in seq/images, KITTI's calib.txt in seq/ (found by searching)."""
    images = tmp_path / "seq" / "images"
    images.mkdir(parents=True)
    for image in sorted((kitti_root / "sequences" / "00" / "image_0").iterdir())[:5]:
        (images / image.name).symlink_to(image)
    (tmp_path / "seq" / "calib.txt").write_text((kitti_root / "sequences" / "00" / "calib.txt").read_text())
    return images


@pytest.mark.kitti
def test_the_summary_says_which_calibration_and_from_where(folder_with_calib_above: Path, kitti_root: Path,
                                                            tmp_path: Path) -> None:
    found = vslam("run", folder_with_calib_above, "--detail", "off")
    assert found.returncode == 0, found.stderr
    calib = folder_with_calib_above.parent / "calib.txt"
    assert f"warning: camera calibration not given: using {calib}, found beside the images" in found.stderr
    assert (f"camera      fx 718.856 fy 718.856 cx 607.193 cy 185.216, 1241x376, lens none, from {calib} (KITTI "
            "calib.txt), found beside the images") in found.stdout
    given = vslam("run", folder_with_calib_above, "--calib", calib, "--detail", "off")
    assert given.returncode == 0 and "warning" not in given.stderr, given.stderr
    assert f"from {calib} (KITTI calib.txt)\n" in given.stdout
    kitti = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:3", "-o", tmp_path / "k.rrd")
    assert kitti.returncode == 0, kitti.stderr
    kitti_calib = kitti_root / "sequences" / "00" / "calib.txt"
    assert f"from {kitti_calib} (KITTI calib.txt)" in kitti.stdout
    inspected = vslam("inspect", tmp_path / "k.rrd")  # the recording says so too (it said `from -`)
    assert f"from {kitti_calib} (KITTI calib.txt)" in inspected.stdout and "from -" not in inspected.stdout
    matching = read_properties(tmp_path / "k.rrd", "/__properties/run")["gt_matching"]
    assert matching == "row by row (line i of 00.txt is image i)" and f"ground truth {matching}" in kitti.stdout


@pytest.mark.kitti
def test_kitti_root_without_sequence_names_the_option(kitti_root: Path) -> None:
    result = vslam_here("run", kitti_root)
    assert result.returncode == 2 and "(e.g. --sequence 00)" in result.stderr


def test_one_frame_and_a_one_pixel_focal_length_are_warned_about() -> None:
    result = vslam("run", "--frames", "0:300:1000", "--detail", "off")
    assert "warning: the selection holds one frame (0)" in result.stderr, result.stderr
    folder_run = vslam("run", "--frames", "0:2", "--detail", "off")
    assert "warning" not in folder_run.stderr, folder_run.stderr


@pytest.mark.kitti
def test_a_focal_length_of_one_pixel_is_warned_about(folder_with_calib_above: Path) -> None:
    result = vslam("run", folder_with_calib_above, "--intrinsics", "1,1,607,185", "--detail", "off", "--frames",
                   "0:2")
    assert "warning: focal length fx 1 px gives a 179.8° field of view across 1241 px" in result.stderr, result.stderr
    fine = vslam("run", folder_with_calib_above, "--intrinsics", "718.856,718.856,607.1928,185.2157", "--detail",
                 "off", "--frames", "0:2")
    assert "warning" not in fine.stderr, fine.stderr


def test_one_file_for_both_outputs_is_refused(tmp_path: Path) -> None:
    result = vslam_here("run", "-o", tmp_path / "x.rrd", "--trajectory-out", tmp_path / "x.rrd")
    assert result.returncode == 2
    assert f"--output {tmp_path / 'x.rrd'} and --trajectory-out {tmp_path / 'x.rrd'} are the same file" in result.stderr
    assert "another run" not in result.stderr and not (tmp_path / "x.rrd").exists()


def test_a_config_with_a_utf8_bom_is_read(tmp_path: Path) -> None:
    config = tmp_path / "engine.toml"
    config.write_bytes("\ufeff# saved by a Windows editor\n[pose]\nmin_inliers = 25\n".encode())
    result = vslam("run", "--config", config, "--frames", "0:2", "--detail", "off")
    assert result.returncode == 0, result.stderr
    bad = tmp_path / "bad.toml"
    bad.write_bytes("\ufeff[pose]\nmin_inliers = -1\n".encode())
    refused = vslam_here("run", "--config", bad, "--frames", "0:2", "--detail", "off")
    assert refused.returncode == 2 and "pose.min_inliers" in refused.stderr and "line 1" not in refused.stderr


def test_a_device_is_not_called_missing() -> None:
    result = vslam_here("inspect", "/dev/null")
    assert result.returncode == 2 and "error: /dev/null: not a file" in result.stderr, result.stderr
