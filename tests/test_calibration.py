"""`read_calibration`: ROS camera_info, Kalibr camchain / EuRoC sensor.yaml, OpenCV FileStorage YAML/XML and
KITTI calib.txt files, detected from their content; every bad file is a one-line SourceError naming it."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.errors import SourceError
from vslam_core.sources.calibration_files import read_calibration

EUROC_SENSOR_YAML = """%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""

KALIBR_CAMCHAIN = """cam0:
  T_cam_imu:
  - [-0.9995250378696743, 0.029615343885863205, -0.008522328211654736, 0.04727988224914392]
  - [0.0075019185074052044, -0.03439736061393144, -0.9993800792498829, -0.047443232143367084]
  - [-0.02989013031643309, -0.998969345370175, 0.03415885127385616, -0.0681999605066297]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
    0.00020293673591811182]
  distortion_model: equidistant
  intrinsics: [190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504]
  resolution: [512, 512]
  rostopic: /cam0/image_raw
cam1:
  camera_model: pinhole
  distortion_coeffs: [0.0034003170790442797, 0.001766278153469831, -0.00266312569781606,
    0.0003299517423931039]
  distortion_model: equidistant
  intrinsics: [190.44236969414825, 190.4344384721956, 252.59949716835982, 254.91723064636983]
  resolution: [512, 512]
  rostopic: /cam1/image_raw
"""

ROS_CAMERA_INFO = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [476.7030836014194, 0, 400.5, 0, 476.7030836014194, 300.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.337392, 0.0968, 0.000872, -0.000463, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [476.7030836014194, 0, 400.5, -33.36921585209936, 0, 476.7030836014194, 300.5, 0, 0, 0, 1, 0]
"""

KITTI_CALIB = """P0: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 0.000000000000e+00 0.000000000000e+00 \
7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 \
0.000000000000e+00
P1: 7.188560000000e+02 0.000000000000e+00 6.071928000000e+02 -3.861448000000e+02 0.000000000000e+00 \
7.188560000000e+02 1.852157000000e+02 0.000000000000e+00 0.000000000000e+00 0.000000000000e+00 1.000000000000e+00 \
0.000000000000e+00
"""

OPENCV_CLASSIC_YAML = """%YAML:1.0
---
calibration_time: "Mon 01 Jan 2024 12:00:00 CET"
image_width: 1280
image_height: 720
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.1556072719327040e+02, 0., 6.4390429839547862e+02, 0.,
       9.1541319123791424e+02, 3.6236727013588929e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 1.1245e-01, -2.4538e-01, 1.2e-04, -3.0e-04, 1.0823e-01 ]
"""


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def write_opencv(path: Path, nodes: dict[str, object]) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in nodes.items():
        storage.write(key, value)
    storage.release()
    return path


def test_euroc_sensor_yaml(tmp_path: Path) -> None:
    path = write(tmp_path, "sensor.yaml", EUROC_SENSOR_YAML)
    camera = read_calibration(path)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (458.654, 457.296, 367.215, 248.375)
    assert camera.model == "plumb_bob"
    assert camera.coefficients == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    assert (camera.width, camera.height) == (752, 480)
    assert camera.origin == f"{path} (EuRoC sensor.yaml)"


def test_kalibr_camchain_takes_cam0(tmp_path: Path) -> None:
    path = write(tmp_path, "camchain-imucam.yaml", KALIBR_CAMCHAIN)
    camera = read_calibration(path)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (
        190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504)
    assert camera.model == "equidistant"
    assert camera.coefficients == (0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
                                   0.00020293673591811182)
    assert (camera.width, camera.height) == (512, 512)
    assert camera.origin == f"{path} (Kalibr camchain, cam0 of 2)"


def test_kalibr_single_fov_camera(tmp_path: Path) -> None:
    text = ("cam0:\n  camera_model: pinhole\n  intrinsics: [0.535719308086809, 0.669566858850269, 0.493248545285398,"
            " 0.500408664348414]\n  distortion_model: fov\n  distortion_coeffs: [0.897966326944875]\n"
            "  resolution: [1280, 1024]\n")
    camera = read_calibration(write(tmp_path, "camchain.yaml", text))
    assert camera.model == "fov" and camera.coefficients == (0.897966326944875,)
    assert camera.origin.endswith("(Kalibr camchain, cam0)")


def test_ros_camera_info(tmp_path: Path) -> None:
    path = write(tmp_path, "ost.yaml", ROS_CAMERA_INFO)
    camera = read_calibration(path)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (476.7030836014194, 476.7030836014194, 400.5, 300.5)
    assert camera.model == "plumb_bob"
    assert camera.coefficients == (-0.337392, 0.0968, 0.000872, -0.000463, 0.0)
    assert (camera.width, camera.height) == (640, 480)
    assert camera.origin == f"{path} (ROS camera_info)"


def test_format_comes_from_the_content_not_the_extension(tmp_path: Path) -> None:
    assert read_calibration(write(tmp_path, "camera.txt", ROS_CAMERA_INFO)).origin.endswith("(ROS camera_info)")
    kitti = read_calibration(write(tmp_path, "calib.yaml", KITTI_CALIB))
    assert kitti.origin.endswith("(KITTI calib.txt)")
    xml = write_opencv(tmp_path / "cam.xml", {"K": np.eye(3) * [500, 500, 1]})
    renamed = tmp_path / "cam.yaml"
    xml.rename(renamed)
    assert read_calibration(renamed).origin.endswith("(OpenCV FileStorage XML)")


def test_ros2_camera_info_message_dump(tmp_path: Path) -> None:
    text = ("header:\n  stamp:\n    sec: 0\n    nanosec: 0\n  frame_id: camera\nheight: 480\nwidth: 640\n"
            "distortion_model: plumb_bob\nd: [0.1, -0.2, 0.001, 0.002, 0.0]\n"
            "k: [500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0]\n"
            "r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]\n"
            "p: [500.0, 0.0, 320.0, 0.0, 0.0, 501.0, 240.0, 0.0, 0.0, 0.0, 1.0, 0.0]\n---\n")
    camera = read_calibration(write(tmp_path, "camera_info.yaml", text))
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (500, 501, 320, 240, 640, 480)
    assert camera.coefficients == (0.1, -0.2, 0.001, 0.002, 0.0)
    assert camera.origin.endswith("(ROS CameraInfo message)")


def test_kitti_calib_txt(tmp_path: Path) -> None:
    path = write(tmp_path, "calib.txt", KITTI_CALIB)
    camera = read_calibration(path)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (718.856, 718.856, 607.1928, 185.2157)
    assert camera.model == "none" and camera.coefficients == ()
    assert (camera.width, camera.height) == (0, 0)
    assert camera.origin == f"{path} (KITTI calib.txt)"


def test_opencv_yaml_written_by_filestorage(tmp_path: Path) -> None:
    K = np.array([[910.5, 0.0, 640.25], [0.0, 911.75, 360.5], [0.0, 0.0, 1.0]])  # noqa: N806
    D = np.array([[0.11, -0.24, 0.0012, -0.0003, 0.1]])  # noqa: N806
    path = write_opencv(tmp_path / "calib.yaml",
                        {"image_width": 1280, "image_height": 720, "camera_matrix": K, "distortion_coefficients": D})
    camera = read_calibration(path)
    np.testing.assert_array_equal(camera.K, K)
    assert camera.model == "plumb_bob" and camera.coefficients == tuple(D.ravel())
    assert (camera.width, camera.height) == (1280, 720)
    assert camera.origin == f"{path} (OpenCV FileStorage YAML)"


def test_opencv_classic_yaml_header(tmp_path: Path) -> None:
    camera = read_calibration(write(tmp_path, "out_camera_data.yml", OPENCV_CLASSIC_YAML))
    assert (camera.fx, camera.cy) == (915.5607271932704, 362.36727013588929)
    assert camera.coefficients == (0.11245, -0.24538, 0.00012, -0.0003, 0.10823)
    assert (camera.width, camera.height) == (1280, 720)


def test_opencv_xml_rational_and_fisheye(tmp_path: Path) -> None:
    K = np.array([[600.0, 0.0, 320.0], [0.0, 601.0, 240.0], [0.0, 0.0, 1.0]])  # noqa: N806
    rational = np.array([0.1, -0.2, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002])
    path = write_opencv(tmp_path / "calib.xml", {"cameraMatrix": K, "distCoeffs": rational})
    camera = read_calibration(path)
    assert camera.model == "rational_polynomial" and camera.coefficients == tuple(rational)
    assert (camera.width, camera.height) == (0, 0)
    assert camera.origin == f"{path} (OpenCV FileStorage XML)"

    fisheye = np.array([[0.02], [-0.01], [0.003], [-0.0004]])
    path = write_opencv(tmp_path / "fisheye.xml", {"K": K, "D": fisheye, "distortion_model": "fisheye"})
    camera = read_calibration(path)
    assert camera.model == "equidistant" and camera.coefficients == tuple(fisheye.ravel())


def test_opencv_xml_without_header(tmp_path: Path) -> None:
    text = ("<opencv_storage>\n<K type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt>\n"
            "<data>500. 0. 320. 0. 500. 240. 0. 0. 1.</data></K>\n<image_width>640</image_width>\n"
            "<image_height>480</image_height>\n</opencv_storage>\n")
    camera = read_calibration(write(tmp_path, "k.xml", text))
    assert (camera.fx, camera.cx, camera.width, camera.height, camera.model) == (500, 320, 640, 480, "none")


@pytest.mark.parametrize("suffix", ["yaml", "xml"])
@pytest.mark.parametrize("seed", range(5))
def test_opencv_round_trip(tmp_path: Path, suffix: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    fx, fy = rng.uniform(100, 2000, 2)
    cx, cy = rng.uniform(100, 1000, 2)
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])  # noqa: N806
    D = rng.normal(0, 0.1, (1, int(rng.choice([4, 5, 8]))))  # noqa: N806
    width, height = (int(v) for v in rng.integers(64, 4096, 2))
    path = write_opencv(tmp_path / f"random.{suffix}",
                        {"image_width": width, "image_height": height, "camera_matrix": K, "dist_coeffs": D})
    camera = read_calibration(path)
    np.testing.assert_array_equal(camera.K, K)
    assert camera.coefficients == tuple(D.ravel())
    assert camera.model == ("rational_polynomial" if D.size == 8 else "plumb_bob")
    assert (camera.width, camera.height) == (width, height)


ROS_TEMPLATE = ("image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: {K}\n"
                "distortion_model: {model}\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {D}\n")
GOOD_K = "[500, 0, 320, 0, 500, 240, 0, 0, 1]"
GOOD_D = "[0.1, -0.2, 0.0, 0.0, 0.0]"


BAD_FILES = [
    ("empty.yaml", "", "not a calibration file, it holds no keys"),
    ("notes.txt", "just some notes about the camera\n", "not a calibration file, it holds no keys"),
    ("broken.yaml", "camera_matrix: [1, 2\nfoo: }\n", "not a calibration file, not YAML/XML (line"),
    ("other.yaml", "sensor_type: imu\nrate_hz: 200\n", "no camera matrix or camera model (keys: sensor_type, rate_hz"),
    ("zero.yaml", ROS_TEMPLATE.format(K="[0, 0, 320, 0, 0, 240, 0, 0, 1]", model="plumb_bob", D=GOOD_D),
     "(ROS camera_info): the camera matrix has no valid focal length (fx=0, fy=0)"),
    ("negative.yaml", ROS_TEMPLATE.format(K="[-500, 0, 320, 0, 500, 240, 0, 0, 1]", model="plumb_bob", D=GOOD_D),
     "no valid focal length (fx=-500"),
    ("model.yaml", ROS_TEMPLATE.format(K=GOOD_K, model="mei", D=GOOD_D), "unknown distortion model 'mei'"),
    ("count.yaml", ROS_TEMPLATE.format(K=GOOD_K, model="equidistant", D=GOOD_D),
     "distortion model equidistant needs 4 coefficients, got 5"),
    ("short_k.yaml", ROS_TEMPLATE.format(K="[500, 0, 320, 0, 500, 240]", model="plumb_bob", D=GOOD_D),
     "camera_matrix needs 9 numbers (3x3), got 6"),
    ("transposed.yaml", ROS_TEMPLATE.format(K="[500, 0, 0, 0, 500, 0, 320, 240, 1]", model="plumb_bob", D=GOOD_D),
     "camera_matrix is not [fx 0 cx; 0 fy cy; 0 0 1]"),
    ("text_k.yaml", ROS_TEMPLATE.format(K="[500, 0, 320, 0, five, 240, 0, 0, 1]", model="plumb_bob", D=GOOD_D),
     "camera_matrix holds something that is not a number"),
    ("nodata.yaml", "camera_matrix:\n  rows: 3\n  cols: 3\n", "camera_matrix has no 'data'"),
    ("nodist.yaml", "camera_matrix:\n  data: " + GOOD_K + "\ndistortion_model: plumb_bob\n",
     "distortion_model 'plumb_bob' but no distortion coefficients"),
    ("size.yaml", "camera_matrix:\n  data: " + GOOD_K + "\nimage_width: 640.5\n",
     "image width 640.5 is not a whole number of pixels"),
    ("omni.yaml", "cam0:\n  camera_model: omni\n  intrinsics: [0.8, 460, 459, 367, 248]\n",
     "(Kalibr camchain, cam0): camera_model 'omni' is not supported (only pinhole"),
    ("kalibr3.yaml", "cam0:\n  camera_model: pinhole\n  intrinsics: [460, 459, 367]\n",
     "intrinsics needs 4 numbers [fu, fv, pu, pv] for a pinhole camera, got 3"),
    ("nointr.yaml", "sensor_type: camera\ncamera_model: pinhole\nresolution: [752, 480]\n",
     "(EuRoC sensor.yaml): no 'intrinsics'"),
    ("resolution.yaml", "cam0:\n  intrinsics: [460, 459, 367, 248]\n  resolution: [752]\n",
     "resolution must be [width, height]"),
    ("kalibr_model.yaml", "cam0:\n  intrinsics: [460, 459, 367, 248]\n  distortion_model: ds\n"
     "  distortion_coeffs: [0.5]\n", "unknown distortion model 'ds'"),
    ("twelve.yaml", "camera_matrix:\n  data: " + GOOD_K + "\nD: [" + ", ".join(["0.01"] * 12) + "]\n",
     "12 distortion coefficients and no distortion_model"),
    ("bad.xml", '<?xml version="1.0"?>\n<opencv_storage>\n<K>oops\n', "cannot parse OpenCV FileStorage XML"),
    ("bad_tag.yml", "%YAML:1.0\nK: !!opencv-matrix\n  rows: 3\n  data: [1, 2\n",
     "cannot parse OpenCV FileStorage YAML (line"),
    ("p0.txt", "P0: 718.856 0 607.1928 0 0 718.856 185.2157\n",
     "P0 needs 12 numbers (3x4 matrix), found 7 (read as KITTI"),
]


@pytest.mark.parametrize(("name", "text", "expected"), BAD_FILES, ids=[case[0] for case in BAD_FILES])
def test_bad_files(tmp_path: Path, name: str, text: str, expected: str) -> None:
    path = write(tmp_path, name, text)
    with pytest.raises(SourceError) as caught:
        read_calibration(path)
    message = str(caught.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert expected in message


def test_unreadable_files(tmp_path: Path) -> None:
    (tmp_path / "image.png").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00")
    for path, expected in [
        (tmp_path / "missing.yaml", "calibration file not found (--calib reads ROS camera_info YAML, Kalibr camchain"),
        (tmp_path, "is a folder, not a calibration file"),
        (tmp_path / "image.png", "not a calibration file, not text"),
    ]:
        with pytest.raises(SourceError) as caught:
            read_calibration(path)
        message = str(caught.value)
        assert "\n" not in message and message.startswith(str(path)) and expected in message


def test_unknown_format_lists_the_formats(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r"--calib reads ROS camera_info YAML, Kalibr camchain or EuRoC sensor\.yaml, "
                                          r"OpenCV FileStorage YAML/XML, KITTI calib\.txt"):
        read_calibration(write(tmp_path, "notes.txt", "hello\n"))
