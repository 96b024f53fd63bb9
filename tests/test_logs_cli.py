"""Issue 13 end to end: drive logs (ROS 1 / ROS 2 MCAP / ROS 2 sqlite3) made from real KITTI frames re-imaged
through known lenses (tests/ros_logs.py) tracked as well as the rectified frames, through the CLI as a user
runs them: `vslam run`, `inspect`, `eval`, bad logs; and `--calib` files on an image folder."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import VO
from kitti_runs import MapRun
from ros_logs import LOGS, LensLog, LogWriter, camera_info_yaml, kitti_clip, make_reimager, write_lens_log
from test_cli_inputs import assert_one_line_error, vslam

from vslam.rrd.provenance import PROPERTIES, read_properties
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult, TrackingMode
from vslam_core.sources.base import CameraIntrinsics, FrameRange, FrameSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.ros.bag import RosbagSource
from vslam_core.trajectory.metrics import kitti_errors

#: KITTI 00 frames 0:150: ~150 m of road, enough for the KITTI metric's 100 m segments.
FRAMES = range(0, 150)


@pytest.fixture(scope="module")
def logs(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, LensLog]:
    clip = kitti_clip(kitti_root, "00", FRAMES)
    out = tmp_path_factory.mktemp("lens_logs")
    reimagers = {}
    written = {}
    for name, (_kind, model, coefficients, *_rest) in LOGS.items():
        if (model, coefficients) not in reimagers:
            reimagers[model, coefficients] = make_reimager(clip.camera, model, coefficients)
        written[name] = write_lens_log(name, clip, out, reimagers[model, coefficients])
    return written


def errors(source: FrameSource) -> tuple[float, float]:
    """KITTI t_err (%) and r_err (°/100 m) of `vo` on `source` (scale from ground truth)."""
    result = RunResult([], [], [])
    run_odometry(source, EngineConfig(backend="vo"), (), result)
    assert source.ground_truth is not None
    return kitti_errors(source.ground_truth, result.pose_array())


@pytest.fixture(scope="module")
def log_errors(logs: dict[str, LensLog]) -> Callable[[str], tuple[float, float]]:
    """`errors` of `vo` on a log of `logs` (read with its lens), each log run once per module."""
    runs: dict[str, tuple[float, float]] = {}

    def of(name: str) -> tuple[float, float]:
        if name not in runs:
            runs[name] = errors(RosbagSource(logs[name].path, ground_truth=logs[name].gt_path))
        return runs[name]

    return of


@pytest.fixture(scope="module")
def rectified(kitti_root: Path) -> tuple[float, float]:
    return errors(KittiSource(kitti_root, sequence="00", frames=FrameRange(FRAMES.start, FRAMES.stop)))


@pytest.mark.kitti
@pytest.mark.parametrize("name", list(LOGS))
def test_a_log_through_a_lens_tracks_as_well_as_the_rectified_frames(
    log_errors: Callable[[str], tuple[float, float]], rectified: tuple[float, float], name: str
) -> None:
    t_err, r_err = log_errors(name)
    t_rect, r_rect = rectified
    assert t_err <= 1.5 * t_rect + 0.5, (t_err, t_rect)
    assert r_err <= 1.5 * r_rect + 0.5, (r_err, r_rect)


@pytest.mark.kitti
def test_ignoring_the_lens_is_clearly_worse(logs: dict[str, LensLog],
                                            log_errors: Callable[[str], tuple[float, float]]) -> None:
    """The same log with its distortion ignored (a pinhole of the same K): the undistortion is what works."""
    log = logs["mcap-plumb_bob"]
    lens = log.camera
    pinhole = CameraIntrinsics(lens.fx, lens.fy, lens.cx, lens.cy, 0, 0, origin="test: lens ignored")
    _, r_model = log_errors("mcap-plumb_bob")
    _, r_ignored = errors(RosbagSource(log.path, ground_truth=log.gt_path, calibration=pinhole))
    assert r_ignored > 3 * r_model, (r_ignored, r_model)  # bent rays turn into rotation drift (0:150: 8.4 vs 1.4)


@pytest.mark.kitti
def test_run_records_the_raw_frame_the_lens_and_the_log(logs: dict[str, LensLog], tmp_path: Path) -> None:
    log = logs["mcap-plumb_bob"]
    rrd = tmp_path / "log.rrd"
    result = vslam("run", *VO, log.path, "--gt", log.gt_path, "--frames", "0:30", "--detail", "full", "-o", rrd)
    assert result.returncode == 0, result.stderr
    run = read_properties(rrd, f"{PROPERTIES}/run")
    assert run["calibration_model"] == "plumb_bob"
    assert run["calibration_coefficients"] == "-0.28 0.07 0.0001 -0.0002 0"
    assert run["calibration_origin"] == "CameraInfo /cam/camera_info"
    assert run["topic"] == "/cam/image_raw/compressed"
    assert run["stamps"] == "header"
    # the undistorted frame, beside the raw one, at detail full
    assert len(read_entity(rrd, "/world/camera/undistorted")) == 30
    # overlays at raw pixel positions: the corners logged on the first frame are FAST corners of the raw image
    corners = read_entity(rrd, "/world/camera/image/corners")
    first = np.array(corners.filter(corners["frame"] == 0)["Points2D:positions"].to_list()[0])
    raw = next(iter(RosbagSource(log.path))).image
    fast = cv2.KeyPoint_convert(cv2.FastFeatureDetector_create(threshold=20).detect(raw))
    nearest = np.min(np.linalg.norm(first[:, None, :] - fast[None, :, :], axis=2), axis=1)
    assert np.median(nearest) < 0.5, np.median(nearest)

    report = vslam("inspect", rrd)
    assert report.returncode == 0, report.stderr
    assert "lens plumb_bob [-0.28 0.07 0.0001 -0.0002 0], from CameraInfo /cam/camera_info" in report.stdout
    assert "topic /cam/image_raw/compressed, stamps header" in report.stdout
    data = json.loads(vslam("inspect", "--json", rrd).stdout)
    assert data["calibration"]["model"] == "plumb_bob"
    assert data["calibration"]["origin"] == "CameraInfo /cam/camera_info"


@pytest.mark.kitti
def test_eval_scores_a_log_against_tum_ground_truth(logs: dict[str, LensLog],
                                                   log_errors: Callable[[str], tuple[float, float]]) -> None:
    log = logs["ros1-equidistant"]
    result = vslam("eval", *VO, log.path, "--gt", log.gt_path, "--json")
    assert result.returncode == 0, result.stderr
    (row,) = json.loads(result.stdout)["sequences"]
    t_err, r_err = log_errors("ros1-equidistant")
    assert row["t_err"] == pytest.approx(t_err, abs=1e-6)
    assert row["r_err"] == pytest.approx(r_err, abs=1e-6)


def map_run(source: FrameSource) -> tuple[float, float, list[FrameResult]]:
    """KITTI t_err and r_err of the map backend on `source` (scale from ground truth), and its results."""
    results: list[FrameResult] = []
    run = run_odometry(source, EngineConfig(backend="map", threads=1), (lambda _, r: results.append(r),))
    assert source.ground_truth is not None
    return (*kitti_errors(source.ground_truth, run.pose_array()), results)


@pytest.mark.kitti
def test_the_map_backend_tracks_a_log_through_a_lens(
    logs: dict[str, LensLog], kitti_00_map_run: MapRun
) -> None:
    """Strong radial–tangential lens: PnP, landmarks and BA on ideal pixels track as well as on the rectified
    frames (the map backend over KITTI 00 0:150, shared with test_mapping.py), and the PnP overlays are drawn
    where the tracks are, on the raw image."""
    log = logs["sqlite3-plumb_bob"]
    t_lens, r_lens, results = map_run(RosbagSource(log.path, ground_truth=log.gt_path))
    _, rectified_poses, rectified_gt = kitti_00_map_run
    assert len(rectified_poses) == len(FRAMES)
    t_rect, r_rect = kitti_errors(rectified_gt, rectified_poses)
    assert t_lens <= 1.5 * t_rect + 0.5, (t_lens, t_rect)
    assert r_lens <= 1.5 * r_rect + 0.5, (r_lens, r_rect)
    mapped = [r for r in results if r.mapping is not None and r.mapping.mode == TrackingMode.MAP]
    assert len(mapped) >= 0.8 * len(FRAMES)
    for result in mapped[::10]:
        assert result.mapping is not None and result.mapping.pnp is not None
        observed = result.mapping.pnp.observed
        tracked = result.track_cur.astype(np.float64)
        nearest = np.min(np.linalg.norm(observed[:, None] - tracked[None], axis=2), axis=1)
        assert np.all(nearest < 1e-3)  # each landmark is drawn at its track's raw pixel
        inliers = result.mapping.pnp.inlier_mask
        residual = np.linalg.norm(result.mapping.pnp.projected[inliers] - observed[inliers], axis=1)
        assert np.median(residual) < 1.5  # projected through the lens, next to the raw pixel


@pytest.mark.kitti
def test_the_map_backend_runs_a_log_through_a_lens_from_the_cli(logs: dict[str, LensLog], tmp_path: Path) -> None:
    result = vslam("run", logs["sqlite3-plumb_bob"].path, "--backend", "map", "--frames", "0:40", "--detail",
                   "summary", "-o", tmp_path / "lens.rrd")
    assert result.returncode == 0, result.stderr
    modes = [v[0] for v in read_entity(tmp_path / "lens.rrd", "/tracking")["mode"].to_list()]
    assert modes.count("map") >= 30, modes


# ------------------------------------------------------------------------------------------- bad logs


def small_log(path: Path, kind: str, image: np.ndarray, *, encoding: str = "mono8", K: np.ndarray | None = None,  # noqa: N803
              model: str | None = None, camera_info: bool = True, image_topic: bool = True) -> Path:
    """A three-frame log of `image` with a CameraInfo (its K or model overridden to make it bad)."""
    camera = CameraIntrinsics(700.0, 700.0, image.shape[1] / 2, image.shape[0] / 2, image.shape[1], image.shape[0])
    with LogWriter(path, kind) as log:  # type: ignore[arg-type]
        for i in range(3):
            stamp = 1_700_000_000_000_000_000 + i * 100_000_000
            if camera_info:
                log.write("/cam/camera_info", stamp, log.camera_info(stamp, "camera", camera, model=model, K=K))
            if image_topic:
                pixels = image if encoding == "mono8" else np.dstack([image] * 3)
                log.write("/cam/image_raw", stamp, log.image(stamp, "camera", pixels, encoding=encoding))
    return path


@pytest.fixture(scope="module")
def grey(kitti_root: Path) -> np.ndarray:
    image = cv2.imread(str(kitti_root / "sequences" / "00" / "image_0" / "000000.png"), cv2.IMREAD_GRAYSCALE)
    return np.ascontiguousarray(image[:200, :400])


@pytest.mark.kitti
@pytest.mark.parametrize(
    ("make", "fragments"),
    [
        (lambda d, g: d / "missing.bag", ("missing.bag: no such file or folder",)),
        (lambda d, g: small_log(d / "info_only.bag", "ros1", g, image_topic=False), ("no image topic",)),
        (lambda d, g: small_log(d / "yuv", "mcap", g, encoding="yuv422"), ("yuv422",)),
        (lambda d, g: small_log(d / "zero_k", "sqlite3", g, K=np.zeros(9)), ("/cam/camera_info",)),
        (lambda d, g: small_log(d / "lens.bag", "ros1", g, model="omnidirectional"), ("omnidirectional",)),
        (lambda d, g: small_log(d / "no_info.bag", "ros1", g, camera_info=False), ("--calib",)),
    ],
    ids=["missing", "no-image-topic", "unknown-encoding", "zero-K", "unknown-distortion", "no-calibration"],
)
def test_a_bad_log_is_one_line_and_exit_2(tmp_path: Path, grey: np.ndarray, make, fragments: tuple[str, ...]) -> None:  # type: ignore[no-untyped-def]
    assert_one_line_error(vslam("run", make(tmp_path, grey), "--detail", "off"), *fragments)


@pytest.mark.kitti
def test_a_truncated_bag_is_one_line_and_exit_2(logs: dict[str, LensLog], tmp_path: Path) -> None:
    whole = logs["ros1-equidistant"].path.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(whole[: len(whole) // 2])
    assert_one_line_error(vslam("run", cut, "--detail", "off"), "cut.bag")
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(bytes(range(256)) * 64)
    assert_one_line_error(vslam("run", garbage, "--detail", "off"), "garbage.mcap")


# ------------------------------------------------------------------------------- --calib on a folder


@pytest.mark.kitti
def test_calib_yaml_gives_an_image_folder_its_lens(logs: dict[str, LensLog], tmp_path: Path) -> None:
    """The same lens frames as PNGs plus a ROS camera_info YAML track like the log they came from."""
    log = logs["sqlite3-plumb_bob"]
    folder = tmp_path / "frames"
    folder.mkdir()
    source = RosbagSource(log.path, frames=FrameRange(0, 30))
    for frame in source:
        cv2.imwrite(str(folder / f"{frame.index:06d}.png"), frame.image)
    calib = tmp_path / "camera.yaml"
    calib.write_text(camera_info_yaml(log.camera))
    kitti_gt = tmp_path / "gt.txt"
    shutil.copy(log.gt_path, kitti_gt)
    trajectory_folder, trajectory_log = tmp_path / "folder.txt", tmp_path / "log.txt"
    first = vslam("run", *VO, folder, "--calib", calib, "--detail", "off", "--scale", "none", "--trajectory-out",
                  trajectory_folder)
    second = vslam("run", *VO, log.path, "--frames", "0:30", "--detail", "off", "--scale", "none", "--trajectory-out",
                   trajectory_log)
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    # lossless frames, the same lens: the same trajectory (deterministic engine)
    np.testing.assert_allclose(np.loadtxt(trajectory_folder), np.loadtxt(trajectory_log), atol=1e-9)
