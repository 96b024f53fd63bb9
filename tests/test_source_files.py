"""Issue 24, the inputs engineers bring from their own disks, through the CLI as they run it: image names without
zero padding (natural order), 16-bit PNGs of 12-bit data, ground truth with a broken row, paths that are not
UTF-8, a cut-short MCAP, and macOS / hidden / empty files among the frames. Every folder, bag and file is made
here from real KITTI frames."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import vslam, vslam_here
from ros_logs import kitti_clip, write_lens_log
from test_cli_inputs import assert_one_line_error, error_lines

from vslam.rrd.provenance import PROPERTIES, read_properties

#: KITTI 05's camera (its calib.txt P0); KITTI 00's first 150 frames disagree with their ground truth.
INTRINSICS = "707.0912,707.0912,601.8873,183.1104"
NOT_UTF8 = os.fsdecode(b"caf\xe9")  # "café" in Latin-1: the byte 0xE9 alone is not UTF-8


def kitti_frame(kitti_root: Path, i: int) -> Path:
    return kitti_root / "sequences" / "05" / "image_0" / f"{i:06d}.png"


def kitti_poses(kitti_root: Path, count: int) -> np.ndarray:
    """The first `count` rows of KITTI 05's poses file, (count, 12)."""
    return np.loadtxt(kitti_root / "poses" / "05.txt", max_rows=count)


def frame_folder(kitti_root: Path, folder: Path, count: int, name: str = "{i:06d}.png") -> Path:
    folder.mkdir(parents=True)
    for i in range(count):
        (folder / name.format(i=i)).symlink_to(kitti_frame(kitti_root, i))
    return folder


def summary_value(result: subprocess.CompletedProcess[str], key: str) -> str:
    match = re.search(rf"^{key}\s+(.+)$", result.stdout, re.MULTILINE)
    assert match, result.stdout
    return match.group(1)


def paper_rms(result: subprocess.CompletedProcess[str]) -> float:
    return float(summary_value(result, "paper RMS").split()[0])


# ------------------------------------------------------------------------- item 2: natural order


@pytest.mark.kitti
def test_names_without_zero_padding_are_read_in_natural_order(kitti_root: Path, tmp_path: Path) -> None:
    folder = frame_folder(kitti_root, tmp_path / "frames", 20, "f_{i}.png")  # f_0 … f_19: text order puts f_10 first
    gt = tmp_path / "gt.txt"
    np.savetxt(gt, kitti_poses(kitti_root, 20))
    rrd = tmp_path / "run.rrd"
    result = vslam("run", folder, "--intrinsics", INTRINSICS, "--gt", gt, "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr
    assert paper_rms(result) < 0.2  # natural order: 0.03 m; text order (f_0, f_1, f_10, …, f_19, f_2, …): 0.79 m
    shown = vslam("inspect", rrd)
    assert shown.returncode == 0, shown.stderr
    assert ("order       natural name order (numbers in names compared as numbers): f_2.png before f_10.png"
            in shown.stdout.splitlines())


# ------------------------------------------------------------------------- item 3: 16-bit PNGs


@pytest.mark.kitti
def test_12_bit_data_in_16_bit_pngs_is_scaled_by_the_bits_used(kitti_root: Path, tmp_path: Path) -> None:
    """12-bit frames made from the 8-bit ones (v << 4 | v >> 4, as a 12-bit sensor's full range): scaled back by
    the 12 bits used, they are the 8-bit frames exactly, so the run is the 8-bit run, pose for pose."""
    eight = frame_folder(kitti_root, tmp_path / "eight", 12)
    twelve = tmp_path / "twelve"
    twelve.mkdir()
    for i in range(12):
        grey = cv2.imread(str(kitti_frame(kitti_root, i)), cv2.IMREAD_GRAYSCALE).astype(np.uint16)
        assert cv2.imwrite(str(twelve / f"{i:06d}.png"), (grey << 4) | (grey >> 4))
    runs = {}
    outputs: dict[str, list[str | Path]] = {"eight": ["--detail", "off"], "twelve": ["-o", tmp_path / "12.rrd"]}
    for name, folder in (("eight", eight), ("twelve", twelve)):
        trajectory = tmp_path / f"{name}.txt"
        result = vslam("run", folder, "--intrinsics", INTRINSICS, *outputs[name], "--trajectory-out", trajectory)
        assert result.returncode == 0, result.stderr  # before: exit 3, 12 of 12 frames image_too_dark
        assert summary_value(result, "frames") == "12 (0 held the previous pose)"
        runs[name] = trajectory.read_text()
    assert runs["twelve"] == runs["eight"]
    properties = read_properties(tmp_path / "12.rrd", f"{PROPERTIES}/run")
    assert properties["sixteen_bit"] == "12-bit data in 16-bit images: >> 4 bits (from the first frame's range)"


# ------------------------------------------------------------------------- item 4: broken ground truth


@pytest.mark.kitti
def test_a_ground_truth_row_a_billion_metres_away_is_refused_naming_its_line(kitti_root: Path,
                                                                              tmp_path: Path) -> None:
    folder = frame_folder(kitti_root, tmp_path / "frames", 20)
    poses = kitti_poses(kitti_root, 20)
    poses[10, 11] = -1e9  # line 11: z = -1e9 m
    gt = tmp_path / "gt.txt"
    np.savetxt(gt, poses)
    # with --scale gt (the default with ground truth) that row would set the scale; before: exit 0, t_err 4.6e8 %
    for run in (vslam, vslam_here):
        scale = "gt" if run is vslam else "none"
        result = run("run", folder, "--intrinsics", INTRINSICS, "--gt", gt, "--scale", scale, "--detail", "off")
        line = assert_one_line_error(result, f"{gt}:11: ground truth jumps 1e+09 m from line 10")
        assert "no car moves faster than 100 m/s" in line
        assert "frames" not in result.stdout
    other_system = tmp_path / "other.txt"  # another system's trajectory scored against that ground truth
    np.savetxt(other_system, kitti_poses(kitti_root, 20))
    result = vslam_here("eval", "--trajectory", other_system, "--gt", gt)
    assert_one_line_error(result, f"{gt}:11: ground truth jumps 1e+09 m from line 10")


@pytest.mark.kitti
def test_ground_truth_steps_are_judged_at_the_frame_rate(kitti_root: Path, tmp_path: Path) -> None:
    """A 15 m shift from frame 10 on: 150 m/s at KITTI's 10 Hz (times.txt beside the frames) is refused; a single
    row 15 m off the path is refused without a clock too."""
    folder = frame_folder(kitti_root, tmp_path / "frames", 20)
    times = (kitti_root / "sequences" / "05" / "times.txt").read_text().splitlines()[:20]
    (folder / "times.txt").write_text("\n".join(times) + "\n")
    shifted = kitti_poses(kitti_root, 20)
    shifted[10:, 3] += 15.0
    gt = tmp_path / "shifted.txt"
    np.savetxt(gt, shifted)
    result = vslam_here("run", folder, "--intrinsics", INTRINSICS, "--gt", gt, "--detail", "off")
    assert_one_line_error(result, f"{gt}:11: ground truth jumps 15", "m/s; no car moves faster than 100 m/s")
    (folder / "times.txt").unlink()
    spike = kitti_poses(kitti_root, 20)
    spike[10, 3] += 15.0
    np.savetxt(gt, spike)
    result = vslam_here("run", folder, "--intrinsics", INTRINSICS, "--gt", gt, "--detail", "off")
    assert_one_line_error(result, f"{gt}:11: ground truth lies 15", "m off the path: lines 10 and 12 around it")


# ------------------------------------------------------------------------- item 7: paths that are not UTF-8


@pytest.mark.kitti
def test_a_folder_whose_path_is_not_utf8_is_read(kitti_root: Path, tmp_path: Path) -> None:
    folder = frame_folder(kitti_root, tmp_path / NOT_UTF8, 8)
    rrd = tmp_path / "run.rrd"
    result = vslam("run", folder, "--intrinsics", INTRINSICS, "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr  # before: exit 139 (a segfault in cv2.imread), no message
    assert summary_value(result, "frames") == "8 (0 held the previous pose)"
    source_path = read_properties(rrd, f"{PROPERTIES}/run")["source_path"]
    assert source_path == str(tmp_path / "caf\\xe9")  # the byte kept, written as an escape


@pytest.mark.kitti
def test_outputs_and_videos_whose_path_is_not_utf8_are_refused_in_one_line(kitti_root: Path, tmp_path: Path) -> None:
    folder = frame_folder(kitti_root, tmp_path / "frames", 4)
    out = tmp_path / "out"
    result = vslam_here("run", folder, "--intrinsics", INTRINSICS, "-o", out / f"{NOT_UTF8}.rrd")
    assert_one_line_error(result, f"{out}/caf\\xe9.rrd: a recording path must be valid UTF-8")
    assert not out.exists()  # before: a UnicodeEncodeError traceback and a 0-byte .rrd
    video_folder = tmp_path / NOT_UTF8
    video_folder.mkdir()
    writer = cv2.VideoWriter(str(tmp_path / "drive.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (1241, 376), False)
    for i in range(4):
        writer.write(cv2.imread(str(kitti_frame(kitti_root, i)), cv2.IMREAD_GRAYSCALE))
    writer.release()
    (tmp_path / "drive.avi").rename(video_folder / "drive.avi")
    result = vslam("run", video_folder / "drive.avi", "--intrinsics", INTRINSICS, "--detail", "off")
    assert_one_line_error(result, f"{tmp_path}/caf\\xe9/drive.avi: OpenCV cannot open a video whose path is not valid "
                                  "UTF-8")  # before: exit 139


# ------------------------------------------------------------------------- item 11: a cut-short MCAP


@pytest.mark.kitti
def test_a_cut_short_mcap_runs_on_the_messages_before_the_cut(kitti_root: Path, tmp_path: Path) -> None:
    log = write_lens_log("mcap-plumb_bob", kitti_clip(kitti_root, "05", range(0, 20)), tmp_path / "logs")
    (whole,) = log.path.glob("*.mcap")
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 6 // 10])  # the recorder killed at 60 %
    rrd = tmp_path / "run.rrd"
    result = vslam("run", cut, "--gt", log.gt_path, "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr  # before: exit 2, "cannot open the log … File end magic is invalid"
    (warning,) = error_lines(result)
    frames = int(summary_value(result, "frames").split()[0])
    assert 5 <= frames < 20
    assert warning.startswith(f"warning: {cut}: the log is cut short (no MCAP summary: the recorder was killed?); "
                              "recovered ")
    assert f"({frames} of {log.topic}, the last at log time " in warning and warning.endswith("running on them")
    assert paper_rms(result) < 0.5
    shown = vslam("inspect", rrd)
    assert "cut short: recovered " in shown.stdout and f"of {cut.stat().st_size}" in shown.stdout
    # the bag folder of a recorder killed before it wrote metadata.yaml: its one .mcap is the log
    (whole.parent / "metadata.yaml").unlink()
    whole.write_bytes(cut.read_bytes())
    result = vslam("run", whole.parent, "--detail", "off")
    assert result.returncode == 0, result.stderr  # before: exit 2, "no images (.png, …) in the image folder"
    (warning,) = error_lines(result)
    assert warning.startswith(f"warning: {whole}: the log is cut short")
    assert summary_value(result, "frames") == f"{frames} (0 held the previous pose)"


# ------------------------------------------------------------------------- item 12: files that are not frames


@pytest.mark.kitti
def test_macos_hidden_and_empty_files_are_skipped_with_one_warning(kitti_root: Path, tmp_path: Path) -> None:
    folder = frame_folder(kitti_root, tmp_path / "frames", 10)
    for i in range(10):  # what a Mac leaves on a FAT / exFAT / network drive: a 4 kB resource fork per file
        (folder / f"._{i:06d}.png").write_bytes(b"\x00\x05\x16\x07" + bytes(4092))
    (folder / ".preview.png").symlink_to(kitti_frame(kitti_root, 50))
    (folder / "000010.png").write_bytes(b"")  # a copy that was interrupted
    result = vslam("run", folder, "--intrinsics", INTRINSICS, "--detail", "off")
    assert result.returncode == 0, result.stderr  # before: exit 2, "._000000.png: cannot read image"
    assert error_lines(result) == [f"warning: {folder}: skipped 12 image files that are not frames (10 macOS '._' "
                                   "AppleDouble files, 1 hidden file, 1 empty file)"]
    assert summary_value(result, "frames") == "10 (0 held the previous pose)"
