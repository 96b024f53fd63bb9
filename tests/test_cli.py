"""`vslam run` as a user runs it: exit codes, messages, files written, recording content."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import VO, InterruptedRun, interrupt_kitti_run, vslam, vslam_here

from vslam.recording import HALF_SIZE_JPEG_QUALITY
from vslam.rrd.provenance import PROPERTIES, read_properties
from vslam.rrd.read import read_entity, read_events
from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import TrackFate
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.io import read_kitti_poses, read_tum_poses

ROOT = Path(__file__).resolve().parents[1]


def assert_clean_error(result: subprocess.CompletedProcess[str], *fragments: str) -> None:
    """Non-zero exit, one line on stderr naming the problem (besides progress lines), no traceback."""
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("progress ")]
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def verify(path: Path) -> None:
    check = subprocess.run(["rerun", "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr


@pytest.fixture(scope="module")
def kitti_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    out = tmp_path_factory.mktemp("run")
    rrd, trajectory = out / "00.rrd", out / "00.txt"
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:40", "-o", rrd, "--trajectory-out",
                   trajectory, "--backend", "vo")  # its poses are the engine's as tracked (the map refines them)
    assert result.returncode == 0, result.stderr
    return rrd, trajectory, result.stdout


@pytest.mark.kitti
def test_run_on_kitti_writes_a_valid_recording_and_one_pose_per_frame(
    kitti_run: tuple[Path, Path, str], kitti_root: Path
) -> None:
    rrd, trajectory, stdout = kitti_run
    verify(rrd)
    poses = read_kitti_poses(trajectory)
    assert poses.shape == (40, 4, 4)
    assert np.allclose(poses[0], np.eye(4))
    assert "frames      40" in stdout and "frames/s" in stdout and "paper RMS" in stdout

    # The recording holds what the engine computed (same input, same config: same numbers).
    source = KittiSource(kitti_root, sequence="00", frames=FrameRange(0, 40))
    results = []
    run_odometry(source, EngineConfig(backend="vo"), sinks=(lambda _f, r: results.append(r),))
    assert np.allclose(poses, np.array([r.T_world_cam for r in results]), atol=1e-6)

    corners = read_entity(rrd, "/world/camera/image/corners")
    assert corners["frame"].to_list() == list(range(40))
    assert np.allclose(np.array(corners["Points2D:positions"][0].to_list()), results[0].new_corners)

    flow = read_entity(rrd, "/world/camera/image/flow").filter(frame=10)
    classes = np.array(flow["Arrows2D:class_ids"][0].to_list())
    fates = results[10].track_fate[results[10].track_fate != TrackFate.LOST]
    assert np.array_equal(np.sort(classes), np.sort(fates))
    assert (classes == TrackFate.INLIER).sum() == results[10].inlier_count

    # the default detail is standard (issue 56): no 3-D points or hover values; the frames at half size, JPEG q30,
    # drawn (linear filtering) over the pinhole's whole image plane
    assert read_properties(rrd, f"{PROPERTIES}/run")["detail"] == "standard"
    assert read_entity(rrd, "/world/points").is_empty() and "track_id" not in flow.columns
    images = read_entity(rrd, "/world/camera/image")
    blob = np.frombuffer(bytes(images.filter(frame=10)["EncodedImage:blob"][0].to_list()[0]), np.uint8)
    source_image = next(f.image for f in KittiSource(kitti_root, sequence="00", frames=FrameRange(10, 11)))
    half = cv2.resize(source_image, (620, 188), interpolation=cv2.INTER_AREA)
    assert blob.tobytes() == cv2.imencode(".jpg", half, [cv2.IMWRITE_JPEG_QUALITY, HALF_SIZE_JPEG_QUALITY])[1].tobytes()
    drawn = read_entity(rrd, "/world/camera/image", static=True)
    assert np.allclose(drawn["InstancePoses3D:scales"][0].to_list(), [[1241 / 620, 2.0, 1.0]])
    assert drawn["EncodedImage:magnification_filter"][0].to_list() == [2]  # Linear
    shown = cv2.resize(cv2.imdecode(blob, cv2.IMREAD_GRAYSCALE), (1241, 376), interpolation=cv2.INTER_LINEAR)
    error = shown.astype(float) - source_image
    assert 26.0 <= 10 * np.log10(255**2 / np.mean(error**2)) <= 29.0  # PSNR, dB: the figure docs/recordings.md gives

    camera = read_entity(rrd, "/world/camera")
    assert len(camera) == 40
    assert np.allclose(np.array(camera["Transform3D:translation"][-1].to_list()).ravel(),
                       results[-1].T_world_cam[:3, 3], atol=1e-5)
    for entity in ("/world/trajectory/estimate", "/world/trajectory/ground_truth", "/world/camera/image"):
        assert len(read_entity(rrd, entity)) == 40, entity


@pytest.mark.kitti
def test_existing_output_is_never_replaced_without_force(kitti_run: tuple[Path, Path, str], kitti_root: Path) -> None:
    rrd, trajectory, _ = kitti_run
    before = rrd.read_bytes()
    result = vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "0:5", "-o", rrd)
    assert_clean_error(result, str(rrd), "--force")
    assert rrd.read_bytes() == before
    other = rrd.with_name("other.rrd")
    result = vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "0:5", "-o", other, "--trajectory-out",
                   trajectory)
    assert_clean_error(result, str(trajectory), "--force")
    assert not other.exists()  # nothing is started when an output would be refused


@pytest.mark.kitti
def test_force_replaces_and_tum_output_carries_timestamps(kitti_root: Path, tmp_path: Path) -> None:
    trajectory = tmp_path / "t.tum"
    trajectory.write_text("old\n")
    result = vslam("run", *VO, kitti_root, "--sequence", "05", "--frames", "10:20", "--detail", "off",
                   "--trajectory-out", trajectory, "--trajectory-format", "tum", "--force")
    assert result.returncode == 0, result.stderr
    stamps, poses = read_tum_poses(trajectory)
    assert len(poses) == 10
    times = np.loadtxt(kitti_root / "sequences" / "05" / "times.txt")
    assert np.allclose(stamps, times[10:20], atol=1e-6)


@pytest.mark.kitti
@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["--frames", "400:999"], ["selects no frame", "300"]),
        (["--frames", "abc"], ["--frames"]),
        (["--scale", "gt", "--sequence", "07"], ["sequence 07 not found"]),
    ],
)
def test_bad_kitti_arguments_give_one_line_errors(kitti_root: Path, tmp_path: Path, args: list[str],
                                                  fragments: list[str]) -> None:
    full = ["run", *VO, kitti_root, *(["--sequence", "00"] if "--sequence" not in args else []), *args,
            "-o", tmp_path / "x.rrd"]
    assert_clean_error(vslam_here(*full), *fragments)
    assert not (tmp_path / "x.rrd").exists()


def test_missing_source_and_gt_scale_without_ground_truth(tmp_path: Path) -> None:
    assert_clean_error(vslam_here("run", tmp_path / "nowhere", "-o", tmp_path / "a.rrd"), "nowhere")
    folder = tmp_path / "images"
    folder.mkdir()
    import cv2

    for i in range(3):
        cv2.imwrite(str(folder / f"{i:06d}.png"), np.full((64, 96), 100 + i, np.uint8))
    assert_clean_error(vslam_here("run", folder, "--intrinsics", "100,100,48,32", "--scale", "gt", "-o",
                             tmp_path / "b.rrd"), "ground truth")
    assert_clean_error(vslam_here("run", folder, "-o", tmp_path / "b.rrd"), "intrinsics")


def test_bad_config_names_the_key_and_file(tmp_path: Path) -> None:
    config = tmp_path / "bad.toml"
    config.write_text("[tracker]\nwindow = 21\n")
    assert_clean_error(vslam_here("run", "--config", config, "-o", tmp_path / "a.rrd"), "tracker.window", str(config))


def test_output_must_be_rrd_and_its_folder_creatable(tmp_path: Path) -> None:
    assert_clean_error(vslam_here("run", "-o", tmp_path / "a.txt"), ".rrd")
    blocker = tmp_path / "file"
    blocker.write_text("a file where a folder should be")
    assert_clean_error(vslam_here("run", "-o", blocker / "a.rrd"), "cannot create output folder")


@pytest.mark.kitti
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupted_run_finalises_recording_and_trajectory(kitti_root: Path, tmp_path: Path, signum: int,
                                                            code: int, request: pytest.FixtureRequest) -> None:
    interrupted: InterruptedRun = (request.getfixturevalue("interrupted_kitti_run") if signum == signal.SIGINT
                                   else interrupt_kitti_run(kitti_root, tmp_path, signum))  # SIGINT: conftest.py
    rrd, trajectory, returncode, stderr = (interrupted.recording, interrupted.trajectory, interrupted.returncode,
                                           interrupted.stderr)
    assert returncode == code, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    verify(rrd)
    poses = read_kitti_poses(trajectory)
    assert 1 <= len(poses) < 300
    assert f"after {len(poses)} frames" in stderr
    assert read_entity(rrd, "/world/camera")["frame"].to_list() == list(range(len(poses)))  # every frame processed


@pytest.mark.kitti
def test_crop_command_keeps_the_frames_and_refuses_to_overwrite(kitti_run: tuple[Path, Path, str],
                                                                tmp_path: Path) -> None:
    rrd, _, _ = kitti_run
    cropped = tmp_path / "bug.rrd"
    result = vslam("crop", rrd, "--frames", "10:20", "-o", cropped)
    assert result.returncode == 0, result.stderr
    assert "frames 10..19 (10 frames)" in result.stdout
    verify(cropped)
    assert read_entity(cropped, "/world/camera")["frame"].to_list() == list(range(10, 20))
    before = cropped.read_bytes()
    assert_clean_error(vslam_here("crop", rrd, "--frames", "10:20", "-o", cropped), "--force")
    assert cropped.read_bytes() == before
    assert_clean_error(vslam_here("crop", rrd, "--frames", "100:120", "-o", tmp_path / "x.rrd"), "select no frame")
    assert_clean_error(vslam_here("crop", rrd, "--frames", "10:20:2", "-o", tmp_path / "x.rrd"), "START:END", "no STEP")
    assert_clean_error(vslam_here("crop", tmp_path / "none.rrd", "--frames", "1:2", "-o", tmp_path / "x.rrd"),
                       "no such recording")


@pytest.mark.kitti
def test_compare_command_prints_the_differences(kitti_run: tuple[Path, Path, str], kitti_root: Path,
                                                tmp_path: Path) -> None:
    rrd, _, _ = kitti_run
    config = tmp_path / "b.toml"
    config.write_text("[detector]\nfast_threshold = 40\n")
    other = tmp_path / "b.rrd"
    assert vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "0:40", "--config", config, "-o",
                 other).returncode == 0
    both = tmp_path / "ab.rrd"
    result = vslam("compare", rrd, other, "-o", both, "--labels", "before,after")
    assert result.returncode == 0, result.stderr
    verify(both)
    line = next(ln for ln in result.stdout.splitlines() if ln.startswith("frames.count"))
    assert line.split()[1:4] == ["40", "40", "+0"]
    assert any(ln.startswith("series.corners_detected.mean") for ln in result.stdout.splitlines())
    assert len(read_entity(both, "/a/world/camera")) == len(read_entity(both, "/b/world/camera")) == 40
    assert_clean_error(vslam_here("compare", rrd, other, "-o", both), "--force")
    assert_clean_error(vslam_here("compare", rrd, other, "-o", tmp_path / "x.rrd", "--labels", "same,same"), "--labels")


@pytest.fixture(scope="module")
def corrupt_sequence(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A KITTI-layout copy of 00 frames 0–29 (in a temp folder) whose frame 12 is a corrupt file."""
    import shutil

    root = tmp_path_factory.mktemp("corrupt")
    images = root / "sequences" / "00" / "image_0"
    images.mkdir(parents=True)
    for i in range(30):
        shutil.copy(kitti_root / "sequences" / "00" / "image_0" / f"{i:06d}.png", images / f"{i:06d}.png")
    (images / "000012.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 100)
    shutil.copy(kitti_root / "sequences" / "00" / "calib.txt", root / "sequences" / "00" / "calib.txt")
    (root / "poses").mkdir()
    shutil.copy(kitti_root / "poses" / "00.txt", root / "poses" / "00.txt")
    return root


@pytest.mark.kitti
def test_corrupt_image_fails_naming_the_file_and_keeps_the_recording(corrupt_sequence: Path, tmp_path: Path) -> None:
    rrd, trajectory = tmp_path / "fail.rrd", tmp_path / "fail.txt"
    # a process of its own: the shipped 2 threads, the error raised in the decoding thread (conftest gives one)
    result = vslam("run", corrupt_sequence, "--sequence", "00", "-o", rrd, "--trajectory-out", trajectory,
                   process=True)
    assert_clean_error(result, "000012.png", "cannot read image")
    verify(rrd)  # finalised, with the frames before the bad one
    assert len(read_entity(rrd, "/world/camera")) == 12
    assert len(read_kitti_poses(trajectory)) == 12


@pytest.mark.kitti
def test_corrupt_image_is_skipped_with_an_event(corrupt_sequence: Path, tmp_path: Path) -> None:
    rrd, trajectory = tmp_path / "skip.rrd", tmp_path / "skip.txt"
    result = vslam("run", corrupt_sequence, "--sequence", "00", "-o", rrd, "--trajectory-out", trajectory,
                   "--on-bad-frame", "skip", "--backend", "vo")  # vo holds the pose (the map refines it)
    assert result.returncode == 0, result.stderr
    poses = read_kitti_poses(trajectory)
    assert len(poses) == 30 and np.allclose(poses[12], poses[11])  # the pose is held over the bad frame
    texts = [text for _, _, text in read_events(rrd)]
    assert any(t.startswith("frame 12: fail") and "unreadable_image" in t for t in texts)
    inspect = json.loads(vslam("inspect", rrd, "--json").stdout)
    assert inspect["flagged"] == [{"start": 12, "end": 12, "status": "fail", "reasons": ["unreadable_image"]}]


@pytest.mark.kitti
def test_bad_recordings_are_one_line_errors_for_every_command(kitti_run: tuple[Path, Path, str],
                                                              tmp_path: Path) -> None:
    rrd, _, _ = kitti_run
    # cut within its first few KB, before any camera row (a cut later is read to its last whole frame:
    # tests/test_outputs.py): no command but crop can use it
    truncated = tmp_path / "truncated.rrd"
    truncated.write_bytes(rrd.read_bytes()[:3000])
    garbage = tmp_path / "garbage.rrd"
    garbage.write_text("not a recording")
    missing = tmp_path / "missing.rrd"
    for bad in (truncated, garbage, missing):
        for args in (["inspect", bad], ["snapshot", bad, "--frame", "1", "--out", tmp_path / "shots"],
                     ["open", bad, "--web"], ["compare", bad, rrd, "-o", tmp_path / "ab.rrd"],
                     *([] if bad is truncated else [["crop", bad, "--frames", "1:3", "-o", tmp_path / "c.rrd"]])):
            # the viewer commands in their own process: were a bad file accepted, they would start one
            result = vslam(*args) if args[0] in ("snapshot", "open") else vslam_here(*args)
            assert result.returncode == 2, (args, result.stderr)
            assert "Traceback" not in result.stderr and str(bad) in result.stderr, (args, result.stderr)
            assert len(result.stderr.strip().splitlines()) == 1, (args, result.stderr)
