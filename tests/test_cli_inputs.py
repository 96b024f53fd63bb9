"""Issue 12 ("nothing lost in CI or on a bad day"): bad values, ignored options, runs that track nothing,
help and version, progress without a terminal, third-party noise. Each check is the CLI's exit code and
its message, as a user (or a CI log) sees them."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import cv2
import pytest
from cli_helpers import vslam, vslam_here
from kitti_runs import link_images

ROOT = Path(__file__).resolve().parents[1]
INTRINSICS = "718.856,718.856,607.1928,185.2157"


def error_lines(result: subprocess.CompletedProcess[str]) -> list[str]:
    return [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("progress ")]


def assert_one_line_error(result: subprocess.CompletedProcess[str], *fragments: str, code: int = 2) -> str:
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr
    lines = error_lines(result)
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def image_folder(kitti_root: Path, tmp_path: Path) -> Path:
    return link_images(kitti_root, tmp_path / "images", range(4), sequence="00")


# ------------------------------------------------------------------------- item 4: ranges, CLI side


@pytest.mark.parametrize(
    ("toml", "fragment"),
    [
        ("[tracker]\nwindow_px = -5\n", "config key 'tracker.window_px': -5 is out of range [3, 101]"),
        ("[tracker]\nmax_level = -1\n", "config key 'tracker.max_level': -1 is out of range [0, 10]"),
        ("[detector]\nredetect_below = 900\n", "redetect_below must not exceed target_tracks"),
    ],
)
def test_out_of_range_config_is_refused_before_the_run(tmp_path: Path, toml: str, fragment: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(toml)
    result = vslam_here("run", "--config", config, "--frames", "0:5", "--detail", "off")
    assert_one_line_error(result, str(config), fragment)
    assert result.stdout == ""


@pytest.mark.parametrize("metres", ["0.001", "-1", "200"])
def test_camera_height_option_is_range_checked(metres: str) -> None:
    result = vslam_here("run", "--scale", "height", "--camera-height", metres, "--detail", "off")
    assert_one_line_error(result, f"--camera-height {float(metres):g}", "out of range 0 or [0.1, 100]")


# ------------------------------------------------------------------------------ item 5: --port


@pytest.mark.parametrize("port", ["80000", "-1", "65536", "0"])
def test_port_outside_1_to_65535_is_one_line(tmp_path: Path, port: str) -> None:
    result = vslam_here("open", tmp_path / "any.rrd", "--web", "--port", port)  # checked before the file
    assert_one_line_error(result, f"--web-port {port}: give a TCP port in 1..65535 (or leave it out for a free one)")


def test_port_that_is_not_a_number_is_one_line(tmp_path: Path) -> None:
    result = vslam_here("open", tmp_path / "any.rrd", "--web", "--port", "http")
    assert_one_line_error(result, "'--port'", "open --help")


# ------------------------------------------------------------------ item 6: options never ignored


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--frames", "0:10", "--inject", "dark@50"], "--inject dark@50: no selected frame is affected (the run "
                                                      "reads frames 0..9)"),
        (["--frames", "0:10:2", "--inject", "blur@3"], "reads frames 0..8, step 2"),
        (["--gt", "poses.txt"], "--gt does not apply here: the synthetic street"),
        (["--sequence", "00"], "--sequence does not apply here: the synthetic street"),
        (["--intrinsics", INTRINSICS], "--intrinsics does not apply here: the synthetic street"),
        (["-o", "x.rrd", "--detail", "off"], "--output x.rrd: --detail off writes no recording"),
    ],
)
def test_options_that_would_be_ignored_are_refused(args: list[str], fragment: str, tmp_path: Path) -> None:
    result = vslam_here("run", *args, cwd=tmp_path)
    assert_one_line_error(result, fragment)
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.kitti
@pytest.mark.parametrize("option", [["--intrinsics", INTRINSICS], ["--calib", "calib.txt"], ["--gt", "p.txt"]])
def test_kitti_source_refuses_intrinsics_calib_and_gt(kitti_root: Path, option: list[str]) -> None:
    result = vslam_here("run", kitti_root, "--sequence", "00", "--frames", "0:5", "--detail", "off", *option)
    assert_one_line_error(result, f"{option[0]} does not apply here: a KITTI sequence has its own calib.txt")


def test_eval_refuses_sequences_on_the_synthetic_street() -> None:
    result = vslam_here("eval", "synthetic", "--sequences", "00", "--frames", "0:5")
    assert_one_line_error(result, "does not apply here: the synthetic street")


@pytest.mark.kitti
def test_image_folder_refuses_a_sequence(image_folder: Path) -> None:
    result = vslam_here("run", image_folder, "--intrinsics", INTRINSICS, "--sequence", "00", "--detail", "off")
    assert_one_line_error(result, "--sequence does not apply here", "is not a KITTI dataset root")


# ------------------------------------------------------- item 7: nothing tracked, implausible inputs


@pytest.mark.kitti
@pytest.mark.parametrize("scale", ["gt", "none"])  # none: the scoring's Sim(3) of an estimate that never moved
def test_a_run_that_tracks_no_frame_exits_3_and_keeps_its_outputs(kitti_root: Path, tmp_path: Path,
                                                                   scale: str) -> None:
    rrd, trajectory = tmp_path / "dark.rrd", tmp_path / "dark.txt"
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:40", "--inject", "dark@0:39",
                   "--scale", scale, "--detail", "summary", "-o", rrd, "--trajectory-out", trajectory)
    line = assert_one_line_error(result, "no frame could be tracked", "40 of 40 frames", "image_too_dark",
                                 code=3)
    assert "outputs were written" in line
    assert rrd.is_file() and len(trajectory.read_text().splitlines()) == 40
    assert "frames      40" in result.stdout  # the summary is still printed


@pytest.mark.kitti
def test_a_run_that_tracks_some_frames_exits_0(kitti_root: Path) -> None:
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:12", "--inject", "dark@0:5",
                   "--detail", "off")
    assert result.returncode == 0, result.stderr
    assert error_lines(result) == []


@pytest.mark.kitti
def test_principal_point_outside_the_image_is_refused(image_folder: Path) -> None:
    result = vslam("run", image_folder, "--intrinsics", "718.9,718.9,2000,185.2", "--scale", "none",
                   "--detail", "off")
    assert result.returncode == 2, result.stderr
    assert error_lines(result) == ["error: the principal point (2000, 185.2) lies at 161% / 49% of the 1241x376 "
                                   "frames' width / height, outside their middle 60%: the intrinsics are not for "
                                   "frames of this size (from --intrinsics)"]


@pytest.mark.kitti
def test_camera_height_over_10_m_warns(kitti_root: Path) -> None:
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:5", "--scale", "height",
                   "--camera-height", "16.5", "--detail", "off")
    assert result.returncode == 0, result.stderr
    assert error_lines(result) == ["warning: camera height 16.5 m above the road: implausible for a car (over 10 m; "
                                   "is it in metres?)"]


# --------------------------------------------------------------------------- item 12: help, version


def test_version() -> None:
    result = vslam_here("--version")
    assert result.returncode == 0 and result.stderr == ""
    assert re.fullmatch(r"vslam \d+\.\d+\.\d+\S* \(OpenCV \S+, Rerun \S+, Python \S+\)\n", result.stdout)


@pytest.mark.parametrize("command", [[], ["run"], ["eval"], ["open"], ["inspect"]])
def test_dash_h_is_help_with_defaults_and_no_bool_hint(command: list[str]) -> None:
    short, long = vslam_here(*command, "-h"), vslam_here(*command, "--help")
    assert short.returncode == long.returncode == 0 and short.stdout == long.stdout
    assert short.stdout.startswith("Usage: ")  # no blank first line, no box
    assert "<bool>" not in short.stdout and "╭" not in short.stdout


def test_help_shows_the_defaults_rich_used_to_eat() -> None:
    run_help = " ".join(vslam_here("run", "--help").stdout.split())
    assert "[default: gt when the source has ground truth]" in run_help  # --scale
    assert "[default: the source's own: KITTI 1.65 m, the synthetic street's]" in run_help  # --camera-height
    assert "[default: recordings/<source>_<frames>_<time>-<run id>.rrd]" in run_help  # --output
    assert "[default: standard]" in run_help  # --detail; --jpeg-quality:
    assert "[default: 30 at standard, where they are stored at half size; 40 at full] [1<=x<=100]" in run_help
    assert "[default: from the columns]" in " ".join(vslam_here("eval", "--help").stdout.split())  # eval --format


def test_unknown_option_is_one_line() -> None:
    assert_one_line_error(vslam_here("run", "--frame", "0:5"), "No such option: --frame", "run --help")


# ---------------------------------------------------------------------- item 13: CI logs, noise


def test_plain_progress_every_5_percent_or_10_seconds() -> None:
    from vslam.runs.progress import PlainProgress

    lines: list[str] = []
    now = [0.0]
    progress = PlainProgress("kitti-00", 200, lines.append, clock=lambda: now[0])
    for _ in range(200):
        now[0] += 0.05
        progress.advance()
    assert len(lines) == 20  # every 10 frames = 5 %
    assert re.fullmatch(r"progress kitti-00: frame 10/200 \(5 %\), 20.0 frames/s, ETA 0:(09|10)", lines[0])
    assert lines[-1].startswith("progress kitti-00: frame 200/200 (100 %)")
    lines.clear()
    slow = PlainProgress("video-x", 10_000, lines.append, clock=lambda: now[0])
    for _ in range(30):
        now[0] += 1.0
        slow.advance()
    assert [line.split(":")[1].split(",")[0] for line in lines] == [" frame 10/10000 (0 %)",
                                                                    " frame 20/10000 (0 %)",
                                                                    " frame 30/10000 (0 %)"]


@pytest.mark.kitti
def test_progress_goes_to_stderr_and_stdout_stays_clean(kitti_root: Path) -> None:
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:40", "--detail", "off")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("frames      40 ")  # no blank first line, no progress
    progress = [line for line in result.stderr.splitlines() if line.strip()]
    assert progress and all(line.startswith("progress kitti-00: frame ") for line in progress), result.stderr
    assert progress[-1].startswith("progress kitti-00: frame 40/40 (100 %)")
    assert 2 <= len(progress) <= 21


def _video_from_kitti(kitti_root: Path, path: Path, frames: int = 20) -> Path:
    images = sorted((kitti_root / "sequences" / "00" / "image_0").glob("*.png"))[:frames]
    first = cv2.imread(str(images[0]))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (first.shape[1], first.shape[0]))
    for image in images:
        writer.write(cv2.imread(str(image)))
    writer.release()
    return path


@pytest.mark.kitti
def test_truncated_video_is_one_line_without_ffmpeg_noise(kitti_root: Path, tmp_path: Path) -> None:
    video = _video_from_kitti(kitti_root, tmp_path / "drive.mp4")
    truncated = tmp_path / "cut.mp4"
    truncated.write_bytes(video.read_bytes()[: video.stat().st_size // 2])  # the moov atom is at the end
    result = vslam("run", truncated, "--intrinsics", INTRINSICS, "--scale", "none", "--detail", "off")
    assert_one_line_error(result, str(truncated), "cannot open the video")
    assert "moov" not in result.stderr and "@ 0x" not in result.stderr

    result = vslam("run", video, "--intrinsics", INTRINSICS, "--scale", "none", "--detail", "off")
    assert result.returncode == 0, result.stderr
    assert all(line.startswith("progress video-drive: ") for line in result.stderr.splitlines() if line.strip())


@pytest.mark.parametrize("option", [["--inject", "dark@1"], ["--camera-height", "1.5"]])  # --frames: a window
def test_eval_of_a_trajectory_file_refuses_engine_options(tmp_path: Path, option: list[str]) -> None:
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    result = vslam_here("eval", "--trajectory", poses, "--gt", poses, *option)
    assert_one_line_error(result, f"{option[0]} applies to runs of the engine: it does not apply to --trajectory")
