"""RosbagSource: ROS 1 .bag, ROS 2 bags (MCAP, sqlite3) and bare .mcap files made in the tests from real KITTI
frames re-imaged through known lenses (tests/ros_logs.py), plus small synthetic logs for the edge cases."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from ros_logs import (
    LOGS,
    KittiClip,
    LensLog,
    LogWriter,
    Reimager,
    jpeg,
    kitti_clip,
    make_reimager,
    write_lens_log,
)

from vslam_core.errors import SourceError
from vslam_core.lens import undistort_pixels
from vslam_core.sources.base import CameraIntrinsics, FrameRange, rebase_poses
from vslam_core.sources.ros import bag as rosbag
from vslam_core.sources.ros.bag import RosbagSource

FRAMES = range(0, 40)
STAMP0 = 1_700_000_000_000_000_000


@pytest.fixture(scope="module")
def clip(kitti_root: Path) -> KittiClip:
    return kitti_clip(kitti_root, "00", FRAMES)


@pytest.fixture(scope="module")
def lens_logs(clip: KittiClip, tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[LensLog, Reimager]]:
    out = tmp_path_factory.mktemp("lens_logs")
    logs = {}
    reimagers: dict[tuple[str, tuple[float, ...]], Reimager] = {}
    for name, (_kind, model, coefficients, *_rest) in LOGS.items():
        key = (model, coefficients)
        if key not in reimagers:
            reimagers[key] = make_reimager(clip.camera, model, coefficients)
        logs[name] = (write_lens_log(name, clip, out, reimagers[key]), reimagers[key])
    return logs


def check_one_line(excinfo: pytest.ExceptionInfo[SourceError]) -> str:
    text = str(excinfo.value)
    assert "\n" not in text and text.strip() == text
    return text


# --------------------------------------------------------------------------------------------------
# the KITTI logs


def test_the_lenses_bend_the_frames_visibly(lens_logs: dict[str, tuple[LensLog, Reimager]]) -> None:
    for log, _ in lens_logs.values():
        camera = log.camera
        corners = np.array([[0.0, 0.0], [camera.width - 1, 0.0], [0.0, camera.height - 1],
                            [camera.width - 1, camera.height - 1]])
        shift = np.linalg.norm(undistort_pixels(corners, camera) - corners, axis=1)
        assert shift.min() > 25, (log.path.name, shift)


@pytest.mark.parametrize("name", list(LOGS))
def test_frames_are_the_reimaged_kitti_frames(name: str, lens_logs: dict[str, tuple[LensLog, Reimager]],
                                               clip: KittiClip) -> None:
    log, reimager = lens_logs[name]
    source = RosbagSource(log.path)
    assert len(source) == len(FRAMES) and source.indices == list(range(len(FRAMES)))
    frames = list(source)
    np.testing.assert_allclose([f.timestamp for f in frames], clip.stamps_ns / 1e9, atol=1e-6)
    assert [f.index for f in frames] == list(range(len(FRAMES)))
    for frame, kitti in zip(frames, clip.images(), strict=True):
        expected = reimager(kitti)
        assert frame.image.dtype == np.uint8 and frame.image.shape == expected.shape and frame.defect is None
        if log.topic.endswith("compressed"):
            difference = np.abs(frame.image.astype(int) - expected)
            assert difference.mean() < 1.5 and np.percentile(difference, 99) < 8
        else:
            np.testing.assert_array_equal(frame.image, expected)
    camera = source.intrinsics
    assert (camera.model, camera.width, camera.height) == (log.camera.model, 1241, 376)
    np.testing.assert_allclose(camera.coefficients, log.camera.coefficients)
    np.testing.assert_allclose(camera.K, log.camera.K)
    info_topic = LOGS[name][4]
    assert camera.origin == f"CameraInfo {info_topic}"
    expected_format = {"mcap": "ros2 bag (mcap)", "ros1": "ros1 bag", "sqlite3": "ros2 bag (sqlite3)"}[log.kind]
    assert source.properties["log_format"] == expected_format
    assert source.properties["topic"] == log.topic and source.properties["stamps"] == "header"
    assert source.properties["first_stamp"] == "1700000000.000000000"
    assert source.properties["frame_id"] == "camera"
    assert source.notes == [] and source.camera_height is None and source.ground_truth is None
    assert source.name == f"{name}-{log.topic.strip('/').replace('/', '_')}"


def test_a_bare_mcap_file_is_read(lens_logs: dict[str, tuple[LensLog, Reimager]]) -> None:
    log, _ = lens_logs["mcap-plumb_bob"]
    (file,) = log.path.glob("*.mcap")
    source = RosbagSource(file, frames=FrameRange(0, 3))
    assert source.properties["log_format"] == "mcap" and len(list(source)) == 3


@pytest.mark.parametrize("name", list(LOGS))
def test_tum_ground_truth_is_matched_by_stamp_and_rebased(name: str, lens_logs: dict[str, tuple[LensLog, Reimager]],
                                                          clip: KittiClip) -> None:
    log, _ = lens_logs[name]
    source = RosbagSource(log.path, ground_truth=log.gt_path, frames=FrameRange(10, 30, 2))
    assert source.indices == list(range(10, 30, 2))
    gt = source.ground_truth
    assert gt is not None and gt.shape == (10, 4, 4)
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(gt, rebase_poses(clip.poses[10:30:2]), atol=1e-6)
    stamps = [f.timestamp for f in source]
    np.testing.assert_allclose(stamps, clip.stamps_ns[10:30:2] / 1e9, atol=1e-6)


def test_ground_truth_too_far_in_time_is_refused(lens_logs: dict[str, tuple[LensLog, Reimager]],
                                                 tmp_path: Path) -> None:
    log, _ = lens_logs["ros1-equidistant"]
    rows = [line.split() for line in log.gt_path.read_text().splitlines()]
    shifted = tmp_path / "late.tum"
    shifted.write_text("".join(" ".join([f"{float(r[0]) + 0.05:.6f}", *r[1:]]) + "\n" for r in rows))
    with pytest.raises(SourceError, match="no ground-truth pose within 10 ms of frame 0") as excinfo:
        RosbagSource(log.path, ground_truth=shifted)
    check_one_line(excinfo)
    assert RosbagSource(log.path, ground_truth=shifted, gt_tolerance_s=0.06).ground_truth is not None


def test_gt_topic_odometry_is_moved_onto_the_camera_with_tf_static(
        lens_logs: dict[str, tuple[LensLog, Reimager]], clip: KittiClip) -> None:
    log, _ = lens_logs["mcap-plumb_bob"]
    source = RosbagSource(log.path, gt_topic="/gt/odom", frames=FrameRange(5, 25))
    assert source.ground_truth is not None
    np.testing.assert_allclose(source.ground_truth, rebase_poses(clip.poses[5:25]), atol=1e-5)
    assert "base_link" in source.properties["ground_truth"] and "/tf_static" in source.properties["ground_truth"]


def test_gt_topic_pose_stamped_is_taken_as_camera_poses(lens_logs: dict[str, tuple[LensLog, Reimager]],
                                                        clip: KittiClip) -> None:
    log, _ = lens_logs["mcap-plumb_bob"]
    source = RosbagSource(log.path, gt_topic="/gt/pose")  # stamped 2 ms after the frames: within 10 ms
    assert source.ground_truth is not None
    np.testing.assert_allclose(source.ground_truth, rebase_poses(clip.poses), atol=1e-6)
    assert any("PoseStamped" in note and "camera" in note for note in source.notes)


def test_gt_topic_errors(lens_logs: dict[str, tuple[LensLog, Reimager]]) -> None:
    log, _ = lens_logs["mcap-plumb_bob"]
    with pytest.raises(SourceError, match="no ground-truth topic /gt/nothing") as excinfo:
        RosbagSource(log.path, gt_topic="/gt/nothing")
    assert "/gt/odom" in check_one_line(excinfo)
    with pytest.raises(SourceError, match="ground-truth topic /cam/camera_info is sensor_msgs/msg/CameraInfo"):
        RosbagSource(log.path, gt_topic="/cam/camera_info")
    with pytest.raises(SourceError, match="not both"):
        RosbagSource(log.path, gt_topic="/gt/odom", ground_truth=log.gt_path)


def test_calibration_argument_overrides_the_camera_info(lens_logs: dict[str, tuple[LensLog, Reimager]]) -> None:
    log, _ = lens_logs["ros1-equidistant"]
    given = CameraIntrinsics(800.0, 800.0, 600.0, 180.0, 0, 0, "plumb_bob", (0.1, 0.0, 0.0, 0.0), "calib.yaml")
    source = RosbagSource(log.path, calibration=given, frames=FrameRange(0, 2))
    assert source.intrinsics.origin == "calib.yaml" and source.intrinsics.model == "plumb_bob"
    assert (source.intrinsics.width, source.intrinsics.height) == (1241, 376)
    wrong = CameraIntrinsics(800.0, 800.0, 600.0, 180.0, 640, 480)
    with pytest.raises(SourceError, match="images are 1241x376 but the intrinsics are for 640x480"):
        RosbagSource(log.path, calibration=wrong)


def test_a_truncated_ros1_bag_is_refused_in_one_line(lens_logs: dict[str, tuple[LensLog, Reimager]],
                                                      tmp_path: Path) -> None:
    bag = lens_logs["ros1-equidistant"][0].path
    half = tmp_path / "half.bag"
    half.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(SourceError, match="half.bag: cannot open the log") as excinfo:
        RosbagSource(half)
    check_one_line(excinfo)


def test_a_truncated_mcap_yields_the_frames_before_the_cut(lens_logs: dict[str, tuple[LensLog, Reimager]],
                                                           tmp_path: Path) -> None:
    """Issue 24 item 11: the complete chunks before the cut are read as a stream; their frames are the log's."""
    (mcap,) = lens_logs["mcap-plumb_bob"][0].path.glob("*.mcap")
    half_mcap = tmp_path / "half.mcap"
    half_mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    source = RosbagSource(half_mcap)
    frames = list(source)
    assert 5 <= len(frames) < len(FRAMES)
    for frame, whole in zip(frames, RosbagSource(mcap, frames=FrameRange(0, len(frames))), strict=True):
        assert frame.timestamp == whole.timestamp and np.array_equal(frame.image, whole.image)
    (note,) = source.notes
    assert note.startswith(f"{half_mcap}: the log is cut short") and f"{len(frames)} of {source.topic}" in note
    assert source.properties["recovered"].endswith(f"of {half_mcap.stat().st_size}")
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(mcap.read_bytes()[:100])  # not even a message before the cut
    with pytest.raises(SourceError, match="stub.mcap: the log is cut short .* no message before the cut") as excinfo:
        RosbagSource(stub)
    check_one_line(excinfo)


# --------------------------------------------------------------------------------------------------
# small synthetic logs


def texture(width: int = 48, height: int = 32, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (height, width), np.uint8), (3, 3), 0)


CAMERA = CameraIntrinsics(40.0, 40.0, 24.0, 16.0, 48, 32, "plumb_bob", (-0.1, 0.01, 0.0, 0.0, 0.0))


def write_log(path: Path, kind: str, stamps_ms: list[int] | None = None, topic: str = "/cam/image_raw",
              info: CameraIntrinsics | None = CAMERA, encoding: str = "mono8", images: list[np.ndarray] | None = None,
              **info_options: object) -> Path:
    """A small log of `images` (default 6 textures) stamped STAMP0 + stamps_ms, received 1 ms later in the
    order given, with a CameraInfo on /cam/camera_info."""
    images = images if images is not None else [texture(seed=i) for i in range(6)]
    stamps_ms = stamps_ms if stamps_ms is not None else [100 * i for i in range(len(images))]
    with LogWriter(path, kind) as log:  # type: ignore[arg-type]
        for i, (ms, image) in enumerate(zip(stamps_ms, images, strict=True)):
            stamp = STAMP0 + ms * 1_000_000
            received = STAMP0 + (i + 1) * 1_000_000
            if info is not None:
                log.write("/cam/camera_info", received, log.camera_info(stamp, "camera", info, **info_options))
            log.write(topic, received, log.image(stamp, "camera", image, encoding))
    return path


@pytest.fixture(params=["ros1", "mcap", "sqlite3"])
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


def log_path(tmp_path: Path, kind: str, name: str = "log") -> Path:
    return tmp_path / (f"{name}.bag" if kind == "ros1" else name)


def test_out_of_order_stamps_are_noted_and_reordered(tmp_path: Path, kind: str,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    images = [texture(seed=i) for i in range(6)]
    path = write_log(log_path(tmp_path, kind), kind, [0, 200, 100, 300, 500, 400], images=images)
    source = RosbagSource(path)
    assert any("out of stamp order" in note for note in source.notes)
    expected_order = [0, 2, 1, 3, 5, 4]
    frames = list(source)
    assert [f.timestamp for f in frames] == pytest.approx([STAMP0 / 1e9 + 0.1 * i for i in range(6)])
    for frame, arrival in zip(frames, expected_order, strict=True):
        np.testing.assert_array_equal(frame.image, images[arrival])
    monkeypatch.setattr(rosbag, "REORDER_LIMIT", 0)  # the seek-per-frame path gives the same frames
    again = list(RosbagSource(path, frames=FrameRange(1, 5)))
    for frame, arrival in zip(again, expected_order[1:5], strict=True):
        np.testing.assert_array_equal(frame.image, images[arrival])


def test_duplicate_stamps_are_noted(tmp_path: Path) -> None:
    source = RosbagSource(write_log(tmp_path / "dup", "mcap", [0, 100, 100, 200, 300, 400]))
    assert any("repeat an earlier stamp" in note for note in source.notes) and len(list(source)) == 6


def test_zero_header_stamps_fall_back_to_receive_time(tmp_path: Path) -> None:
    source = RosbagSource(write_log(tmp_path / "zero.bag", "ros1", [-STAMP0 // 1_000_000] * 6))
    assert source.properties["stamps"] == "receive time"
    assert any("receive (log) times are used" in note for note in source.notes)
    assert [f.timestamp for f in source] == pytest.approx([STAMP0 / 1e9 + 0.001 * (i + 1) for i in range(6)])


def test_frame_selection(tmp_path: Path) -> None:
    path = write_log(tmp_path / "sel", "sqlite3")
    source = RosbagSource(path, frames=FrameRange(1, 6, 2))
    assert source.indices == [1, 3, 5] and len(source) == 3
    assert [f.index for f in source] == [1, 3, 5]
    with pytest.raises(SourceError, match="selects no frame, the source has 6 frames"):
        RosbagSource(path, frames=FrameRange(6, 9))


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "rgba8", "bgra8"])
def test_colour_encodings_become_grey(tmp_path: Path, encoding: str) -> None:
    rgb = np.dstack([texture(seed=1), texture(seed=2), texture(seed=3)])
    pixels = rgb if encoding.startswith("rgb") else rgb[:, :, ::-1]
    if encoding.endswith("a8"):
        pixels = np.dstack([pixels, np.full(rgb.shape[:2], 255, np.uint8)])
    path = write_log(tmp_path / encoding, "mcap", images=[pixels] * 2, encoding=encoding)
    frame = next(iter(RosbagSource(path)))
    np.testing.assert_array_equal(frame.image, cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_encodings_are_demosaiced_to_grey(tmp_path: Path, pattern: str) -> None:
    colour = {"r": 200, "g": 60, "b": 10}
    mosaic = np.zeros((32, 48), np.uint8)
    for (dy, dx), letter in zip([(0, 0), (0, 1), (1, 0), (1, 1)], pattern, strict=True):
        mosaic[dy::2, dx::2] = colour[letter]
    path = write_log(tmp_path / f"{pattern}.bag", "ros1", images=[mosaic] * 2,
                     encoding=f"bayer_{pattern}8")
    image = next(iter(RosbagSource(path))).image
    grey = 0.299 * 200 + 0.587 * 60 + 0.114 * 10  # 95.8; with red and blue swapped it would be 60
    assert abs(float(np.median(image[4:-4, 4:-4])) - grey) < 3


@pytest.mark.parametrize("bigendian", [False, True])
def test_mono16_is_shifted_to_8_bits_by_the_first_frames_depth(tmp_path: Path, bigendian: bool) -> None:
    values = (texture().astype(np.uint16) * 16 + 7)  # 12-bit data
    values[0, 0] = 4095
    pixels = values.astype(">u2" if bigendian else "<u2")
    brighter = np.full_like(pixels, 8000)  # beyond 12 bits later on: clipped, not rescaled
    path = tmp_path / f"m16{bigendian}"
    with LogWriter(path, "mcap") as log:
        for i, image in enumerate([pixels, brighter]):
            stamp = STAMP0 + i * 100_000_000
            log.write("/cam/camera_info", stamp, log.camera_info(stamp, "camera", CAMERA))
            log.write("/cam/image_raw", stamp, log.image(stamp, "camera", image, "mono16", bigendian=bigendian))
    source = RosbagSource(path)
    first, second = list(source)
    np.testing.assert_array_equal(first.image, (values >> 4).astype(np.uint8))
    assert (second.image == 255).all()
    assert source.properties["mono16"].startswith(">> 4 bits")


@pytest.mark.parametrize("encoding", ["32FC1", "yuv422"])
def test_unsupported_encodings_are_refused_at_construction(tmp_path: Path, encoding: str) -> None:
    pixels = np.zeros((32, 48 * (4 if encoding == "32FC1" else 2)), np.uint8)
    path = write_log(tmp_path / "enc", "mcap", images=[pixels] * 2, encoding=encoding, info=None)
    with pytest.raises(SourceError, match=f"image encoding '{encoding}' is not supported") as excinfo:
        RosbagSource(path, calibration=CAMERA)
    assert "mono8, mono16, rgb8" in check_one_line(excinfo)


def test_compressed_images_decode_to_grey(tmp_path: Path) -> None:
    images = [texture(seed=i) for i in range(3)]
    path = tmp_path / "png"
    with LogWriter(path, "sqlite3") as log:
        for i, image in enumerate(images):
            stamp = STAMP0 + i * 100_000_000
            png = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))[1].tobytes()
            log.write("/cam/image/compressed", stamp, log.compressed(stamp, "camera", png, "bgr8; png compressed bgr8"))
    source = RosbagSource(path, calibration=CAMERA)
    assert source.properties["encoding"] == "png compressed bgr8"
    for frame, image in zip(source, images, strict=True):
        np.testing.assert_array_equal(frame.image, image)


def test_topic_selection(tmp_path: Path) -> None:
    path = tmp_path / "two"
    with LogWriter(path, "mcap") as log:
        for topic in ("/left/image_raw", "/right/image_raw"):
            log.write(topic, STAMP0, log.image(STAMP0, "camera", texture()))
        log.write("/imu", STAMP0, log.pose_stamped(STAMP0, "world", np.eye(4)))
    with pytest.raises(SourceError) as excinfo:
        RosbagSource(path, calibration=CAMERA)
    assert check_one_line(excinfo) == (f"{path}: 2 image topics (/left/image_raw, /right/image_raw): pick one with "
                                       "--topic")
    assert RosbagSource(path, topic="/right/image_raw", calibration=CAMERA).topic == "/right/image_raw"
    assert RosbagSource(path, topic="left/image_raw", calibration=CAMERA).topic == "/left/image_raw"
    with pytest.raises(SourceError, match="no topic /middle/image_raw \\(image topics: /left/image_raw, "):
        RosbagSource(path, topic="/middle/image_raw", calibration=CAMERA)
    with pytest.raises(SourceError, match="topic /imu is geometry_msgs/msg/PoseStamped, not an image"):
        RosbagSource(path, topic="/imu", calibration=CAMERA)


def test_a_log_without_image_topics_lists_its_topics(tmp_path: Path) -> None:
    path = tmp_path / "none.bag"
    with LogWriter(path, "ros1") as log:
        log.write("/gps/pose", STAMP0, log.pose_stamped(STAMP0, "world", np.eye(4)))
    with pytest.raises(SourceError) as excinfo:
        RosbagSource(path)
    assert check_one_line(excinfo) == (f"{path}: no image topic (sensor_msgs/Image or CompressedImage); the log has "
                                       "1 topics: /gps/pose (geometry_msgs/PoseStamped)")


def test_missing_calibration_asks_for_calib(tmp_path: Path, kind: str) -> None:
    path = write_log(log_path(tmp_path, kind), kind, info=None)
    with pytest.raises(SourceError, match="no sensor_msgs/CameraInfo for /cam/image_raw .*pass --calib FILE "
                                          "\\(or --intrinsics\\)") as excinfo:
        RosbagSource(path)
    check_one_line(excinfo)


def test_camera_info_with_zero_k_is_refused(tmp_path: Path, kind: str) -> None:
    path = write_log(log_path(tmp_path, kind), kind, K=np.zeros(9))
    with pytest.raises(SourceError, match="CameraInfo /cam/camera_info: the camera matrix has no valid focal "
                                          "length") as excinfo:
        RosbagSource(path)
    check_one_line(excinfo)


def test_camera_info_with_unknown_model_is_refused(tmp_path: Path) -> None:
    path = write_log(tmp_path / "model", "mcap", model="double_sphere")
    with pytest.raises(SourceError, match="CameraInfo /cam/camera_info: unknown distortion model "
                                          "'double_sphere'") as excinfo:
        RosbagSource(path)
    check_one_line(excinfo)


def test_camera_info_of_another_size_is_refused(tmp_path: Path) -> None:
    other = CameraIntrinsics(40.0, 40.0, 24.0, 16.0, 640, 480)
    path = write_log(tmp_path / "size", "mcap", info=other)
    with pytest.raises(SourceError, match="/cam/camera_info is for 640x480 images but /cam/image_raw's are 48x32"):
        RosbagSource(path)


def test_camera_info_in_the_parent_namespace_and_ros1_fields(tmp_path: Path) -> None:
    path = write_log(tmp_path / "ns.bag", "ros1", topic="/cam/left/image_raw")
    # /cam/left/camera_info does not exist: /cam/camera_info is used
    source = RosbagSource(path)
    assert source.intrinsics.origin == "CameraInfo /cam/camera_info"
    assert source.intrinsics.coefficients == pytest.approx(CAMERA.coefficients)


def test_bad_paths_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="ROS log not found"):
        RosbagSource(tmp_path / "nothing.bag")
    (tmp_path / "folder").mkdir()
    with pytest.raises(SourceError, match="not a ROS 2 bag folder \\(no metadata.yaml\\)"):
        RosbagSource(tmp_path / "folder")
    (tmp_path / "video.mp4").write_bytes(b"x")
    with pytest.raises(SourceError, match="not a ROS log"):
        RosbagSource(tmp_path / "video.mp4")
    rng = np.random.default_rng(0)
    for name in ("noise.bag", "noise.mcap", "noise.db3", "empty.bag"):
        (tmp_path / name).write_bytes(rng.bytes(0 if name.startswith("empty") else 5000))
        with pytest.raises(SourceError, match=f"{name}: cannot open the log") as excinfo:
            RosbagSource(tmp_path / name)
        check_one_line(excinfo)


def corrupt_log(path: Path, kind: str) -> tuple[Path, list[np.ndarray]]:
    """6 frames, the 4th (index 3) a message cut short and the 5th of another size."""
    images = [texture(seed=i) for i in range(6)]
    images[4] = texture(64, 32, seed=4)
    with LogWriter(path, kind) as log:  # type: ignore[arg-type]
        for i, image in enumerate(images):
            stamp = STAMP0 + i * 100_000_000
            log.write("/cam/camera_info", stamp, log.camera_info(stamp, "camera", CAMERA))
            msg = log.image(stamp, "camera", image)
            raw = (log.typestore.serialize_ros1 if log.ros1 else log.typestore.serialize_cdr)(msg, msg.__msgtype__)
            log.write_raw("/cam/image_raw", msg.__msgtype__, stamp, bytes(raw[: len(raw) // 2]) if i == 3 else raw)
    return path, images


def test_a_corrupt_frame_mid_run(tmp_path: Path, kind: str) -> None:
    path, images = corrupt_log(log_path(tmp_path, kind), kind)
    source = RosbagSource(path)
    frames = []
    with pytest.raises(SourceError, match="frame 3 of /cam/image_raw \\(message 3, stamp 1700000000.300000000\\)") \
            as excinfo:
        frames.extend(source)
    check_one_line(excinfo)
    assert len(frames) == 3
    skipping = list(RosbagSource(path, on_bad_frame="skip"))
    assert [f.defect is not None for f in skipping] == [False, False, False, True, True, False]
    assert "image is 64x32, the first frame is 48x32" in str(skipping[4].defect)
    assert skipping[3].image.shape == (32, 48) and not skipping[3].image.any()
    np.testing.assert_array_equal(skipping[5].image, images[5])


def test_jpeg_frames_are_close_to_their_source(tmp_path: Path) -> None:
    image = texture(seed=9)
    path = tmp_path / "jpg"
    with LogWriter(path, "mcap") as log:
        log.write("/cam/image_raw/compressed", STAMP0, log.compressed(STAMP0, "camera", jpeg(image)))
        log.write("/cam/camera_info", STAMP0, log.camera_info(STAMP0, "camera", CAMERA))
    frame = next(iter(RosbagSource(path)))
    assert np.abs(frame.image.astype(int) - image).mean() < 3
