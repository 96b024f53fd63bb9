"""Issue 55, items 3-5: the input's geometry checked against the frames. Each wrong input is built here from real
frames (KITTI 00, the TUM fr1_xyz frames of ../shared/data/tum) with real writers: half-size frames with the full-size
intrinsics or calibration file, JPEGs with an EXIF Orientation tag, an MP4 with a 90° display matrix, frames upscaled
to a 4000-px camera."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from cli_helpers import vslam

from vslam.batch.manifest import ManifestError, read_manifest
from vslam.rrd.read import read_entity
from vslam.runs import input_warnings
from vslam_core.config import EngineConfig, pixel_scale
from vslam_core.errors import SourceError
from vslam_core.pipeline import run_odometry
from vslam_core.quality import image_stats
from vslam_core.sources.base import FrameRange
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.image_files import exif_orientation
from vslam_core.sources.open import open_source
from vslam_core.sources.video import VideoSource

KITTI_00 = "718.856,718.856,607.1928,185.2157"  # KITTI 00's P0, for its 1241x376 frames


def kitti_frames(root: Path, count: int, sequence: str = "00") -> list[np.ndarray]:
    return [cv2.imread(str(root / "sequences" / sequence / "image_0" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
            for i in range(count)]


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith("progress ")]


def write_folder(folder: Path, frames: list[np.ndarray], suffix: str = ".png") -> Path:
    folder.mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:06d}{suffix}"), frame)
    return folder


def ros_yaml(path: Path, size: tuple[int, int], fx: float, fy: float, cx: float, cy: float) -> Path:
    path.write_text(f"image_width: {size[0]}\nimage_height: {size[1]}\ncamera_matrix: {{rows: 3, cols: 3, data: "
                    f"[{fx}, 0, {cx}, 0, {fy}, {cy}, 0, 0, 1]}}\ndistortion_model: plumb_bob\n"
                    "distortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n")
    return path


# ------------------------------------------------------------------ item 3: intrinsics against the image


@pytest.mark.kitti
def test_half_size_frames_with_full_size_intrinsics_are_refused(kitti_root: Path, tmp_path: Path) -> None:
    half = [cv2.resize(f, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for f in kitti_frames(kitti_root, 2)]
    folder = write_folder(tmp_path / "half", half)  # 620x188: the principal point at 98 % / 99 %
    result = vslam("run", folder, "--intrinsics", KITTI_00, "--detail", "off")
    assert result.returncode == 2, result.stderr
    assert error_lines(result.stderr) == [
        "error: the principal point (607.193, 185.216) lies at 98% / 99% of the 620x188 frames' width / height, "
        "outside their middle 60%: the intrinsics are not for frames of this size (from --intrinsics) (if the frames "
        "are resized copies of the calibrated camera's, --calib-scale 0.5 scales the calibration)"]
    source = open_source(str(folder), intrinsics=KITTI_00, calib_scale=0.5)
    k = source.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx((359.428, 359.428, 303.3464, 92.35785))
    assert k.origin == "--intrinsics, scaled x0.5 by --calib-scale"


@pytest.mark.kitti
def test_a_calibration_file_for_another_size_is_refused_naming_both(kitti_root: Path, tmp_path: Path) -> None:
    half = [cv2.resize(f, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA) for f in kitti_frames(kitti_root, 3)]
    half = [f[:, :620] for f in half]  # 620x188 = exactly half of 1240x376
    folder = write_folder(tmp_path / "half", half)
    calib = ros_yaml(tmp_path / "cam.yaml", (1240, 376), 718.856, 718.856, 607.1928, 185.2157)
    refused = vslam("run", folder, "--calib", calib, "--detail", "off")
    assert refused.returncode == 2, refused.stderr
    assert error_lines(refused.stderr) == [
        f"error: {folder}: images are 620x188 but the intrinsics are for 1240x376 ({calib} (ROS camera_info)) (if the "
        "frames are resized copies of the calibrated camera's, --calib-scale 0.5 scales the calibration)"]
    scaled = vslam("run", folder, "--calib", calib, "--calib-scale", "0.5", "--detail", "off")
    assert scaled.returncode == 0, scaled.stderr
    assert f"camera      fx 359.428 fy 359.428 cx 303.346 cy 92.3578, 620x188, lens plumb_bob, from {calib} (ROS " \
           "camera_info), scaled x0.5 by --calib-scale" in scaled.stdout
    odd = vslam("run", folder, "--calib", calib, "--calib-scale", "0.3", "--detail", "off")
    assert error_lines(odd.stderr) == ["error: --calib-scale 0.3: the calibration's 1240x376 times 0.3 is 372x112.8, "
                                       "not whole pixels"]
    kitti = vslam("run", kitti_root, "--sequence", "00", "--calib-scale", "0.5", "--detail", "off")
    assert error_lines(kitti.stderr)[0].startswith("error: --calib-scale does not apply here: a KITTI sequence")


@pytest.mark.kitti
def test_frames_resized_by_less_than_the_middle_60_percent_shows_are_refused_too(kitti_root: Path, tmp_path: Path
                                                                                ) -> None:
    frames = kitti_frames(kitti_root, 2)
    double = write_folder(tmp_path / "double", [cv2.resize(f, (2482, 752)) for f in frames])  # 24 % / 25 %
    with pytest.raises(SourceError) as refused:
        open_source(str(double), intrinsics=KITTI_00)
    assert str(refused.value) == (
        "the principal point (607.193, 185.216) lies at 24% / 25% of the 2482x752 frames' width / height, not near "
        "their centre but where the centre of 1221x370 frames is (both axes agree): the intrinsics are not for frames "
        "of this size (from --intrinsics) (if the frames are resized copies of the calibrated camera's, "
        "--calib-scale 2 scales the calibration)")
    larger = write_folder(tmp_path / "larger", [cv2.resize(f, (1551, 470)) for f in frames])  # 1.25x: 39 % / 39 %
    with pytest.raises(SourceError, match=r"lies at 39% / 39% .* where the centre of 1221x370 frames is"):
        open_source(str(larger), intrinsics=KITTI_00)
    right = open_source(str(double), intrinsics=KITTI_00, calib_scale=2.0)
    assert input_warnings(right, EngineConfig()) == []
    # the left 400 columns cut off, the intrinsics not moved: one axis off centre (a crop), warned only
    cropped = write_folder(tmp_path / "cropped", [f[:, 400:] for f in frames])
    source = open_source(str(cropped), intrinsics=KITTI_00)
    assert input_warnings(source, EngineConfig()) == [
        "the principal point (607.193, 185.216) lies at 72% / 49% of the 841x376 frames' width / height, outside "
        "their middle 40%: are the intrinsics for frames of this size (a crop, or another resolution)?"]


def test_a_manifest_row_may_resize_its_calibration(tmp_path: Path) -> None:
    (tmp_path / "cam.yaml").write_text("K: [1, 0, 1, 0, 1, 1, 0, 0, 1]\n")
    manifest = tmp_path / "logs.csv"
    manifest.write_text("name,source,calib,calib_scale\nhalf,synthetic,cam.yaml,0.5\nplain,synthetic,cam.yaml,\n")
    half, plain = read_manifest(manifest)
    assert (half.calib_scale, plain.calib_scale) == (0.5, None)
    manifest.write_text("name,source,calib,calib_scale\nhalf,synthetic,cam.yaml,half\n")
    with pytest.raises(ManifestError, match="calib_scale 'half' is not a number"):
        read_manifest(manifest)


@pytest.mark.kitti
def test_tum_frames_at_half_size_with_their_640x480_calibration(tum_root: Path, tmp_path: Path) -> None:
    rgb = tum_root / "rgbd_dataset_freiburg1_xyz" / "rgb"
    files = sorted(rgb.iterdir())[:2]
    frames = [cv2.resize(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), (320, 240), interpolation=cv2.INTER_AREA)
              for f in files]
    folder = write_folder(tmp_path / "tum_half", frames)
    calib = ros_yaml(tmp_path / "fr1.yaml", (640, 480), 517.306408, 516.469215, 318.643040, 255.313989)
    with pytest.raises(SourceError, match=r"images are 320x240 but the intrinsics are for 640x480 .*--calib-scale 0.5"):
        open_source(str(folder), calib=calib)
    scaled = open_source(str(folder), calib=calib, calib_scale=0.5).intrinsics
    assert (scaled.width, scaled.height) == (320, 240) and scaled.fx == pytest.approx(258.653204)
    full = open_source(str(tum_root / "rgbd_dataset_freiburg1_xyz"), frames=FrameRange(0, 2))
    assert input_warnings(full, EngineConfig()) == []  # the real camera: centred, nothing to say


# ------------------------------------------------------------------ item 4: orientation flags


def exif_jpeg(image: np.ndarray, orientation: int) -> bytes:
    """A JPEG of `image` with an APP1 Exif segment holding one IFD0 entry, Orientation (0x0112, SHORT)."""
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    tiff = b"MM\x00\x2a" + struct.pack(">IH", 8, 1) + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + bytes(4)
    app1 = b"Exif\x00\x00" + tiff
    data = encoded.tobytes()
    return data[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + data[2:]


@pytest.mark.kitti
def test_exif_orientation_is_not_applied_and_is_said(kitti_root: Path, tmp_path: Path) -> None:
    frames = kitti_frames(kitti_root, 3)
    folder = tmp_path / "phone"
    folder.mkdir()
    for i, frame in enumerate(frames):
        (folder / f"{i:06d}.jpg").write_bytes(exif_jpeg(frame, 6))
    data = (folder / "000000.jpg").read_bytes()
    assert exif_orientation(data) == 6
    shown = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert shown.shape == (1241, 376)  # OpenCV turns it by default: the input really is flagged
    source = ImageFolderSource(folder, intrinsics=open_source(str(folder), intrinsics=KITTI_00).intrinsics)
    images = [frame.image for frame in source]
    assert images[0].shape == (376, 1241) and (source.intrinsics.width, source.intrinsics.height) == (1241, 376)
    assert np.array_equal(images[0], cv2.rotate(shown, cv2.ROTATE_90_COUNTERCLOCKWISE))  # the stored pixels
    rrd = tmp_path / "phone.rrd"
    result = vslam("run", folder, "--intrinsics", KITTI_00, "--detail", "standard", "-o", rrd)
    assert result.returncode == 0, result.stderr
    recorded = read_entity(rrd, "/world/camera/image")["EncodedImage:blob"].to_list()[0][0]
    recorded_image = cv2.imdecode(np.frombuffer(bytes(recorded), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert recorded_image.shape == (188, 620)  # the recording shows the pixels the engine used, at half size
    half = cv2.resize(images[0], (620, 188), interpolation=cv2.INTER_AREA)
    assert np.abs(recorded_image.astype(int) - half.astype(int)).mean() < 8  # JPEG twice (q95, q30); turned: ~40
    assert error_lines(result.stderr) == [
        "warning: 000000.jpg: EXIF Orientation 6 (rotated 90° clockwise) ignored: the frames are read as the sensor "
        "stored them, 1241x376, the calibration's pixels (a viewer would show them turned)"]
    assert "frames      3 (0 held" in result.stdout

    # a PNG's eXIf chunk (little-endian, Orientation 3): the same shape turned 180°, OpenCV turns it by default too
    png = cv2.imencode(".png", frames[0])[1].tobytes()
    tiff = b"II\x2a\x00" + struct.pack("<IH", 8, 1) + struct.pack("<HHIHH", 0x0112, 3, 1, 3, 0) + bytes(4)
    chunk = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    upside_down = tmp_path / "upside_down"
    upside_down.mkdir()
    (upside_down / "000000.png").write_bytes(png[:33] + chunk + png[33:])  # after the signature and IHDR
    shown = cv2.imread(str(upside_down / "000000.png"), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(shown, cv2.rotate(frames[0], cv2.ROTATE_180))
    flagged = open_source(str(upside_down), intrinsics=KITTI_00)
    assert np.array_equal(next(iter(flagged)).image, frames[0])
    warning = input_warnings(flagged, EngineConfig())[0]
    assert warning.startswith("000000.png: EXIF Orientation 3 (rotated 180°) ignored"), warning


@pytest.mark.kitti
def test_a_video_display_matrix_is_not_applied_and_is_said(kitti_root: Path, tmp_path: Path) -> None:
    frames = [f[:, :1240] for f in kitti_frames(kitti_root, 3)]  # even sizes for yuv420p
    path = tmp_path / "portrait.mp4"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = 1240, 376, "yuv420p"
        for frame in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="gray")))
        container.mux(stream.encode())
    # a phone's portrait video: the track header's matrix turns the stored frames 90° for display
    data = bytearray(path.read_bytes())
    at = data.find(b"tkhd")
    matrix = at + 8 + (32 if data[at + 4] == 1 else 20) + 16  # after version/flags, times and ids, reserved, layer…
    data[matrix:matrix + 36] = struct.pack(">9i", 0, 65536, 0, -65536, 0, 0, 0, 0, 0x40000000)
    path.write_bytes(bytes(data))
    capture = cv2.VideoCapture(str(path))
    ok, shown = capture.read()
    capture.release()
    assert ok and shown.shape[:2] == (1240, 376)  # OpenCV turns it by default: the input really is flagged
    source = VideoSource(path, open_source(str(path), intrinsics="718.856,718.856,607.1928,185.2157").intrinsics)
    assert [frame.image.shape for frame in source] == [(376, 1240)] * 3
    assert source.notes == ["portrait.mp4: the container says to show the frames rotated 90° (a display matrix): not "
                            "applied, the frames are read as the sensor stored them, 1240x376, the calibration's "
                            "pixels"]


# ------------------------------------------------------------------ item 5: pixel sizes that scale with the camera


@pytest.mark.kitti
def test_a_4000_px_camera_is_judged_and_tracked_as_a_1241_px_one(kitti_root: Path, tmp_path: Path) -> None:
    # KITTI 05 (1226x370, P0 707.091 601.887 183.11) upscaled 3.26x, bilinear: the issue's 4000x1207 camera
    frames = [cv2.resize(f, (4000, 1207), interpolation=cv2.INTER_LINEAR) for f in kitti_frames(kitti_root, 5, "05")]
    for frame in frames:  # the old measure, at half size: every frame under the blur gate
        half = cv2.resize(frame, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        assert cv2.Laplacian(half, cv2.CV_32F).var() < EngineConfig().health.blur_sharpness
        assert image_stats(frame).sharpness > 5 * EngineConfig().health.blur_sharpness
    folder = write_folder(tmp_path / "big", frames, ".bmp")  # lossless, and quick to write at this size
    sx, sy = 4000 / 1226, 1207 / 370
    intrinsics = f"{707.091 * sx},{707.091 * sy},{602.387 * sx - 0.5},{183.61 * sy - 0.5}"
    source = open_source(str(folder), intrinsics=intrinsics)
    run = run_odometry(source, EngineConfig().with_scale("none"))
    assert run.held == 0 and run.held_reasons == {}
    scaled = EngineConfig().for_image_width(4000)
    assert (scaled.detector.min_distance_px, scaled.tracker.max_level, scaled.tracker.predicted_max_level) == (26, 5, 3)
    assert EngineConfig().for_image_width(1241) == EngineConfig() and pixel_scale(640) == 1.0
