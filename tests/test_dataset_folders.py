"""Dataset-folder sources: EuRoC/ASL (`EurocSource`) and TUM monoVO (`TumMonoSource`), on small folders built
in tmp_path from real KITTI frames and poses (never written into the repository)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.errors import SourceError
from vslam_core.sources.base import Frame, FrameRange, FrameSource, rebase_poses
from vslam_core.sources.euroc import EurocSource, is_euroc, read_sensor_yaml
from vslam_core.sources.kitti import read_p0_intrinsics, read_times
from vslam_core.sources.tum_mono import TumMonoSource, is_tum_mono, read_camera_txt
from vslam_core.trajectory.io import quaternion_from_rotation, read_kitti_poses, tum_line

pytestmark = pytest.mark.kitti

COUNT = 20
SEQ = "00"
T0_NS = 1_403_636_579_000_000_000  # EuRoC-like absolute nanosecond stamps
RADTAN = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
#: TUM monoVO sequence_01's relative FOV calibration (fx fy cx cy omega, fractions of the image size).
TUM_FOV = [0.535719308086809, 0.669566858850269, 0.493248545285398, 0.500408664348414, 0.897966326944875]


# --------------------------------------------------------------------------------------------------
# helpers


def rigid(axis: list[float], angle: float, translation: list[float]) -> np.ndarray:
    """A 4x4 rigid transform: rotation of `angle` about `axis`, then `translation`."""
    transform = np.eye(4)
    rotation, _ = cv2.Rodrigues(np.asarray(axis, np.float64) / np.linalg.norm(axis) * angle)
    transform[:3, :3] = rotation
    transform[:3, 3] = translation
    return transform


#: A camera-in-body extrinsic like EuRoC's cam0 (about 90° about the body's x-ish axis, a few cm off).
T_BS = rigid([0.05, 0.02, 1.0], np.pi / 2, [-0.0216, -0.0647, 0.0098])
#: An arbitrary world frame, so that the first ground-truth pose is not the identity.
WORLD = rigid([0.3, -1.0, 0.2], 0.7, [4.0, -2.5, 1.2])


def orthonormal(poses: np.ndarray) -> np.ndarray:
    """KITTI's rotations have 7 digits (not exactly orthonormal); a quaternion holds only a rotation, so the
    expected camera poses are the nearest true rotations (SVD)."""
    poses = poses.copy()
    for pose in poses:
        u, _, vt = np.linalg.svd(pose[:3, :3])
        pose[:3, :3] = u @ vt
    return poses


def kitti_inputs(kitti_root: Path) -> tuple[list[Path], np.ndarray, np.ndarray]:
    """The first COUNT frames of KITTI 00: image files, (COUNT,) nanosecond stamps, (COUNT, 4, 4) T_w_c."""
    folder = kitti_root / "sequences" / SEQ
    files = [folder / "image_0" / f"{i:06d}.png" for i in range(COUNT)]
    stamps = T0_NS + np.round(np.asarray(read_times(folder / "times.txt", COUNT)) * 1e9).astype(np.int64)
    poses = orthonormal(read_kitti_poses(kitti_root / "poses" / f"{SEQ}.txt", max_rows=COUNT))
    return files, stamps, poses


def sensor_yaml(kitti_root: Path, width: int = 1241, height: int = 376) -> str:
    fx, fy, cx, cy = read_p0_intrinsics(kitti_root / "sequences" / SEQ / "calib.txt")
    rows = ",\n         ".join(", ".join(f"{v:.17g}" for v in row) for row in T_BS)
    return (
        "# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\n\n"
        f"# Sensor extrinsics wrt. the body-frame.\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{rows}]\n\n"
        f"# Camera specific definitions.\nrate_hz: 10\nresolution: [{width}, {height}]\ncamera_model: pinhole\n"
        f"intrinsics: [{fx}, {fy}, {cx}, {cy}] #fu, fv, cu, cv\ndistortion_model: radial-tangential\n"
        f"distortion_coefficients: [{', '.join(map(str, RADTAN))}]\n"
    )


def body_csv_line(stamp_ns: int, camera_pose: np.ndarray) -> str:
    """One state_groundtruth_estimate0 row: the body pose T_w_b = T_w_c · T_BS⁻¹, quaternion w first, then
    velocity and biases (zeros)."""
    body = camera_pose @ np.linalg.inv(T_BS)
    qx, qy, qz, qw = quaternion_from_rotation(body[:3, :3])
    values = [*body[:3, 3], qw, qx, qy, qz] + [0.0] * 9
    return f"{stamp_ns}," + ",".join(f"{v:.17g}" for v in values) + "\n"


def make_euroc(
    root: Path, kitti_root: Path, gt_frames: range | None = range(COUNT), missing: int | None = None
) -> Path:
    """An EuRoC sequence ROOT/mav0/cam0 from KITTI frames; ground truth (body poses × T_BS⁻¹, world WORLD) for
    the frames of `gt_frames` at 2 ms after each frame stamp, plus decoy rows 30 and 60 ms later holding a
    wrong pose, and rows before the first and after the last frame (None: no ground truth folder). `missing`:
    a frame whose image file is left out."""
    files, stamps, poses = kitti_inputs(kitti_root)
    camera = root / "mav0" / "cam0"
    (camera / "data").mkdir(parents=True)
    rows = ["#timestamp [ns],filename\n"]
    for i, (file, stamp) in enumerate(zip(files, stamps, strict=True)):
        if i != missing:
            shutil.copyfile(file, camera / "data" / f"{stamp}.png")
        rows.append(f"{stamp},{stamp}.png\n")
    (camera / "data.csv").write_text("".join(rows))
    (camera / "sensor.yaml").write_text(sensor_yaml(kitti_root))
    if gt_frames is None:
        return root
    decoy = rigid([0.0, 1.0, 0.0], 0.02, [0.05, 0.0, 0.05])  # wrong, yet a motion a vehicle can make
    lines = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
             "v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], "
             "b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n"]
    first, last = gt_frames[0], gt_frames[-1]
    lines.append(body_csv_line(int(stamps[first]) - 50_000_000, WORLD @ decoy @ poses[first]))
    for i in gt_frames:
        pose = WORLD @ poses[i]
        lines.append(body_csv_line(int(stamps[i]) + 2_000_000, pose))
        lines.append(body_csv_line(int(stamps[i]) + 30_000_000, pose @ decoy))
        lines.append(body_csv_line(int(stamps[i]) + 60_000_000, decoy @ pose))
    lines.append(body_csv_line(int(stamps[last]) + 90_000_000, WORLD @ decoy @ poses[last]))
    (root / "mav0" / "state_groundtruth_estimate0").mkdir()
    (root / "mav0" / "state_groundtruth_estimate0" / "data.csv").write_text("".join(lines))
    return root


def make_tum_mono(root: Path, kitti_root: Path, camera_line: str | None = None, size: str = "1241 376") -> Path:
    """A TUM monoVO sequence from KITTI frames: images/00000.png …, times.txt, camera.txt (relative FOV),
    pcalib.txt and vignette.png placeholders."""
    files, stamps, _ = kitti_inputs(kitti_root)
    (root / "images").mkdir(parents=True)
    for i, file in enumerate(files):
        shutil.copyfile(file, root / "images" / f"{i:05d}.png")
    (root / "times.txt").write_text("".join(f"{i:05d} {s / 1e9:.6f} {20.0 + i:.4f}\n" for i, s in enumerate(stamps)))
    line = camera_line if camera_line is not None else " ".join(map(str, TUM_FOV))
    (root / "camera.txt").write_text(f"{line}\n{size}\ncrop\n640 480\n")
    (root / "pcalib.txt").write_text(" ".join(str(i) for i in range(256)) + "\n")
    cv2.imwrite(str(root / "vignette.png"), np.full((376, 1241), 255, np.uint8))
    return root


def gt_of(source: FrameSource) -> np.ndarray:
    gt = source.ground_truth
    assert gt is not None
    return gt


def one_line(exc: pytest.ExceptionInfo[SourceError]) -> str:
    message = str(exc.value)
    assert "\n" not in message, message
    return message


# --------------------------------------------------------------------------------------------------
# EuRoC / ASL


def test_euroc_frames_intrinsics_and_ground_truth(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "MH_01_easy", kitti_root)
    files, stamps, poses = kitti_inputs(kitti_root)
    for path in (root, root / "mav0"):
        assert is_euroc(path)
        source = EurocSource(path)
        assert isinstance(source, FrameSource)
        assert source.name == "euroc-MH_01_easy-cam0" and len(source) == COUNT
        assert source.properties == {"dataset": "EuRoC", "camera": "cam0",
                                     "ground_truth": "state_groundtruth_estimate0 (body poses × T_BS)"}
        assert source.notes == [] and source.camera_height is None
        camera = source.intrinsics
        fx, fy, cx, cy = read_p0_intrinsics(kitti_root / "sequences" / SEQ / "calib.txt")
        assert (camera.fx, camera.fy, camera.cx, camera.cy) == (fx, fy, cx, cy)
        assert (camera.width, camera.height, camera.model) == (1241, 376, "plumb_bob")
        assert camera.coefficients == tuple(RADTAN)
        np.testing.assert_allclose(source.t_bs, T_BS, atol=1e-15)
        gt = source.ground_truth
        assert gt is not None and gt.shape == (COUNT, 4, 4)
        np.testing.assert_allclose(gt, rebase_poses(poses), atol=1e-9)
    frames = list(EurocSource(root))
    assert [f.index for f in frames] == list(range(COUNT))
    for frame, file, stamp in zip(frames, files, stamps, strict=True):
        assert isinstance(frame, Frame) and frame.defect is None
        assert frame.timestamp == stamp / 1e9
        np.testing.assert_array_equal(frame.image, cv2.imread(str(file), cv2.IMREAD_GRAYSCALE))


def test_euroc_frame_selection_rebases_ground_truth(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "V1_01", kitti_root)
    files, _, poses = kitti_inputs(kitti_root)
    source = EurocSource(root, frames=FrameRange.parse("5:15:3"))
    assert source.indices == [5, 8, 11, 14] and len(source) == 4
    np.testing.assert_allclose(gt_of(source), rebase_poses(poses[[5, 8, 11, 14]]), atol=1e-9)
    frames = list(source)
    assert [f.index for f in frames] == [5, 8, 11, 14]
    np.testing.assert_array_equal(frames[1].image, cv2.imread(str(files[8]), cv2.IMREAD_GRAYSCALE))
    assert len(EurocSource(root, frames=FrameRange.parse("15:99"))) == 5  # END clamped
    with pytest.raises(SourceError, match="selects no frame"):
        EurocSource(root, frames=FrameRange.parse("20:30"))


def test_euroc_cameras_and_layout_errors(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "seq", kitti_root, gt_frames=None)
    with pytest.raises(SourceError) as missing_camera:
        EurocSource(root, camera="cam1")
    assert "no camera cam1" in one_line(missing_camera) and "cameras: cam0" in str(missing_camera.value)
    with pytest.raises(SourceError, match="not a camera name"):
        EurocSource(root, camera="imu0")
    shutil.copytree(root / "mav0" / "cam0", root / "mav0" / "cam1")
    second = EurocSource(root, camera="cam1")
    assert second.name == "euroc-seq-cam1" and second.properties["camera"] == "cam1"
    assert second.ground_truth is None and second.properties["ground_truth"] == "none"

    (root / "mav0" / "cam0" / "sensor.yaml").write_text(sensor_yaml(kitti_root, 752, 480))
    with pytest.raises(SourceError, match="resolution 752x480 but the images are 1241x376"):
        EurocSource(root)
    (root / "mav0" / "cam0" / "sensor.yaml").unlink()
    with pytest.raises(SourceError, match="sensor.yaml: camera calibration not found"):
        EurocSource(root)
    (root / "mav0" / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n123;x.png\n")
    with pytest.raises(SourceError, match=r"data.csv:2: expected 'timestamp \[ns\],filename'"):
        EurocSource(root)
    assert not is_euroc(tmp_path) and not is_euroc(kitti_root / "sequences" / SEQ)
    with pytest.raises(SourceError, match="no mav0/ folder"):
        EurocSource(tmp_path)


def test_euroc_missing_image_fails_or_becomes_a_defect(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "seq", kitti_root, missing=7)
    with pytest.raises(SourceError) as failed:
        EurocSource(root)
    message = one_line(failed)
    assert "image named in data.csv not found (frame 7; 1 of the 20 selected frames are missing)" in message
    assert len(EurocSource(root, frames=FrameRange(0, 7))) == 7  # a selection without it is fine
    source = EurocSource(root, on_bad_frame="skip")
    assert source.notes and "1 of the selected images" in source.notes[0]
    frames = list(source)
    assert frames[7].defect is not None and "cannot read image" in frames[7].defect
    assert frames[7].image.shape == (376, 1241) and not frames[7].image.any()
    assert all(f.defect is None for i, f in enumerate(frames) if i != 7)


def test_euroc_ground_truth_must_cover_the_frames(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "seq", kitti_root, gt_frames=range(5, COUNT))
    with pytest.raises(SourceError) as uncovered:
        EurocSource(root)
    message = one_line(uncovered)
    assert "5 of the 20 selected frames have no ground-truth pose within 10 ms" in message
    assert "first: frame 0" in message and "frames 5:20 have one: choose --frames inside them" in message
    _, _, poses = kitti_inputs(kitti_root)
    inside = EurocSource(root, frames=FrameRange.parse("5:"))
    np.testing.assert_allclose(gt_of(inside), rebase_poses(poses[5:]), atol=1e-9)
    # a tolerance tighter than the 2 ms offset leaves no frame with ground truth
    with pytest.raises(SourceError, match="no frame has a ground-truth pose within 1 ms"):
        EurocSource(root, frames=FrameRange.parse("5:"), gt_tolerance_s=0.001)


def test_euroc_tum_ground_truth_override(tmp_path: Path, kitti_root: Path) -> None:
    root = make_euroc(tmp_path / "seq", kitti_root)
    _, stamps, poses = kitti_inputs(kitti_root)
    tum = tmp_path / "camera_poses.txt"
    tum.write_text("".join(tum_line(s / 1e9, WORLD @ p) for s, p in zip(stamps, poses, strict=True)))
    source = EurocSource(root, ground_truth=tum, frames=FrameRange.parse("2:12"))
    assert source.properties["ground_truth"] == "camera_poses.txt (TUM, camera poses)"
    np.testing.assert_allclose(gt_of(source), rebase_poses(poses[2:12]), atol=1e-6)  # TUM: 9 digits
    with pytest.raises(SourceError, match="ground-truth file not found"):
        EurocSource(root, ground_truth=tmp_path / "none.txt")


def test_sensor_yaml_with_opencv_header(tmp_path: Path, kitti_root: Path) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text("%YAML:1.0\n" + sensor_yaml(kitti_root))
    intrinsics, t_bs = read_sensor_yaml(path)
    assert intrinsics.model == "plumb_bob" and intrinsics.origin == str(path)
    assert (intrinsics.width, intrinsics.height) == (1241, 376)
    np.testing.assert_allclose(t_bs, T_BS, atol=1e-15)


@pytest.mark.parametrize(
    ("edit", "error"),
    [
        (lambda text: text.replace("resolution: [1241, 376]\n", ""), "no 'resolution'"),
        (lambda text: text.replace("T_BS:", "T_XX:"), "no 'T_BS'"),
        (lambda text: text.replace("data: [", "data: [2, "), "'T_BS' needs 16 finite numbers"),
        (lambda text: text.replace("data: [", "data: [.nan, ").replace(", 1]", "]"), "'T_BS' needs 16 finite"),
        (lambda text: text.replace("data: [", "data: [2, ").replace(", 1]", "]"), "T_BS is not a rigid transform"),
        (lambda text: text.replace("camera_model: pinhole", "camera_model: omni"), "camera_model 'omni'"),
        (lambda text: text.replace("intrinsics: [", "intrinsics: [1, "), "intrinsics needs 4 numbers"),
        (lambda text: text + "bad: [\n", "not YAML"),
    ],
)
def test_bad_sensor_yaml_is_one_line_naming_the_file(
    tmp_path: Path, kitti_root: Path, edit: Callable[[str], str], error: str
) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(edit(sensor_yaml(kitti_root)))
    with pytest.raises(SourceError) as failed:
        read_sensor_yaml(path)
    message = one_line(failed)
    assert message.startswith(str(path)) and error in message, message


# --------------------------------------------------------------------------------------------------
# TUM monoVO


def test_tum_mono_relative_fov_calibration_and_frames(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_mono(tmp_path / "sequence_01", kitti_root)
    files, stamps, _ = kitti_inputs(kitti_root)
    for path in (root, root / "images"):
        assert is_tum_mono(path)
        source = TumMonoSource(path)
        assert isinstance(source, FrameSource)
        assert source.name == "tum-mono-sequence_01" and len(source) == COUNT
        camera = source.intrinsics
        fx, fy, cx, cy, omega = TUM_FOV
        assert camera.fx == pytest.approx(fx * 1241) and camera.fy == pytest.approx(fy * 376)
        assert camera.cx == pytest.approx(cx * 1241 - 0.5) and camera.cy == pytest.approx(cy * 376 - 0.5)
        assert (camera.width, camera.height, camera.model, camera.coefficients) == (1241, 376, "fov", (omega,))
        assert source.ground_truth is None and source.properties["ground_truth"] == "none"
        assert any("pcalib.txt, vignette.png) not applied" in note for note in source.notes)
    frames = list(TumMonoSource(root, frames=FrameRange.parse("3:9:2")))
    assert [f.index for f in frames] == [3, 5, 7]
    for frame in frames:
        assert frame.timestamp == pytest.approx(stamps[frame.index] / 1e9, abs=1e-6)
        np.testing.assert_array_equal(frame.image, cv2.imread(str(files[frame.index]), cv2.IMREAD_GRAYSCALE))


def test_tum_mono_zip_and_layout_errors(tmp_path: Path, kitti_root: Path) -> None:
    root = make_tum_mono(tmp_path / "sequence_02", kitti_root)
    shutil.make_archive(str(root / "images"), "zip", root / "images")
    shutil.rmtree(root / "images")
    assert is_tum_mono(root)
    with pytest.raises(SourceError) as zipped:
        TumMonoSource(root)
    assert "images.zip: the frames are zipped; unzip them into" in one_line(zipped)
    assert not is_tum_mono(tmp_path) and not is_euroc(root)

    other = make_tum_mono(tmp_path / "sequence_03", kitti_root, size="640 480")
    with pytest.raises(SourceError, match="camera.txt:2: the calibration is for 640x480 images but they are 1241x376"):
        TumMonoSource(other)
    (other / "camera.txt").write_text("Pinhole 400 400 320 240 0\n1241 376\n")
    (other / "times.txt").write_text("00000 1.0 20\n00001 1.1 20\n")
    with pytest.raises(SourceError, match="times.txt: no timestamp for image 00002.png"):
        TumMonoSource(other)


@pytest.mark.parametrize(
    ("line", "model", "coefficients", "pixels"),
    [
        ("0.5 0.6 0.5 0.5 0", "none", (), (620.5, 225.6, 620.0, 187.5)),
        ("FOV 0.5 0.6 0.5 0.5 0.9", "fov", (0.9,), (620.5, 225.6, 620.0, 187.5)),
        ("Pinhole 700 710 620 180 0", "none", (), (700, 710, 620, 180)),
        ("0.5 0.6 0.5 0.5 -0.1 0.01 0.001 0.002", "plumb_bob", (-0.1, 0.01, 0.001, 0.002), None),
        ("RadTan 700 710 620 180 -0.1 0.01 0.001 0.002", "plumb_bob", (-0.1, 0.01, 0.001, 0.002), None),
        ("EquiDistant 700 710 620 180 0.1 0.01 0.001 0.0001", "equidistant", (0.1, 0.01, 0.001, 0.0001), None),
        ("KannalaBrandt 700 710 620 180 0.1 0.01 0.001 0.0001", "equidistant", (0.1, 0.01, 0.001, 0.0001), None),
    ],
)
def test_camera_txt_forms(
    tmp_path: Path, line: str, model: str, coefficients: tuple[float, ...],
    pixels: tuple[float, float, float, float] | None,
) -> None:
    path = tmp_path / "camera.txt"
    path.write_text(f"{line}\n1241 376\n0 0 0 0 0\n1241 376\n")
    camera = read_camera_txt(path)
    assert (camera.model, camera.coefficients, camera.width, camera.height) == (model, coefficients, 1241, 376)
    if pixels is not None:
        np.testing.assert_allclose((camera.fx, camera.fy, camera.cx, camera.cy), pixels)


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("Omni 1 2 3 4 5\n1241 376\n", "unknown camera model 'Omni'"),
        ("FOV 1 2 3 4\n1241 376\n", "FOV needs 5 numbers"),
        ("1 2 3\n1241 376\n", "expected 'fx fy cx cy omega'"),
        ("0.5 0.6 0.5 0.5 0.9\n", "'width height' on line 2"),
        ("0.5 0.6 0.5 0.5 0.9\n1241\n", "camera.txt:2: expected the image size"),
        ("0.5 0.6 x 0.5 0.9\n1241 376\n", "camera.txt:1: the lens line holds something that is not a number"),
    ],
)
def test_camera_txt_errors(tmp_path: Path, text: str, error: str) -> None:
    path = tmp_path / "camera.txt"
    path.write_text(text)
    with pytest.raises(SourceError, match=error):
        read_camera_txt(path)


def test_tum_mono_ground_truth_with_start_and_end_segments(tmp_path: Path, kitti_root: Path) -> None:
    """groundtruthSync.txt style: a line a frame, NaN where there is no pose (here frames 6..15)."""
    root = make_tum_mono(tmp_path / "sequence_04", kitti_root)
    _, stamps, poses = kitti_inputs(kitti_root)
    lines = []
    for i, (stamp, pose) in enumerate(zip(stamps, poses, strict=True)):
        lines.append(tum_line(stamp / 1e9, WORLD @ pose) if i < 6 or i >= 16 else f"{stamp / 1e9:.6f}" + " NaN" * 7
                     + "\n")
    gt = root / "groundtruthSync.txt"
    gt.write_text("".join(lines))
    with pytest.raises(SourceError) as uncovered:
        TumMonoSource(root, ground_truth=gt)
    message = one_line(uncovered)
    assert "10 of the 20 selected frames have no ground-truth pose" in message
    assert "frames 0:6, 16:20 have one" in message
    start = TumMonoSource(root, ground_truth=gt, frames=FrameRange.parse("1:6"))
    assert start.properties["ground_truth"] == "groundtruthSync.txt (TUM, camera poses)"
    np.testing.assert_allclose(gt_of(start), rebase_poses(poses[1:6]), atol=1e-6)
