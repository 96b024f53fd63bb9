"""EuRoC MAV / ASL dataset folders (one camera of a sequence, with the body ground truth as camera poses).

Layout (the ASL format of the EuRoC MAV dataset, Burri et al., IJRR 2016)::

    ROOT/mav0/cam0/data/<stamp>.png            images, 8-bit grey (752x480 in EuRoC)
    ROOT/mav0/cam0/data.csv                    ``#timestamp [ns],filename``: one row per image, in frame order
    ROOT/mav0/cam0/sensor.yaml                 ``intrinsics: [fu, fv, cu, cv]``, ``distortion_model``,
                                               ``distortion_coefficients``, ``resolution: [w, h]``, ``T_BS``
    ROOT/mav0/cam1/…                           the second camera, same layout
    ROOT/mav0/state_groundtruth_estimate0/data.csv
                                               ``#timestamp, p_RS_R_x [m], p_RS_R_y, p_RS_R_z, q_RS_w, q_RS_x,
                                               q_RS_y, q_RS_z, v…, b…``: the body (IMU) pose in the world R

Conventions: ``T_BS`` (sensor.yaml, 4x4 row-major under ``data``) is the camera's pose in the body frame
(it maps camera coordinates to body coordinates), so a camera pose is T_R_cam = T_R_body · T_BS. Frame i
is row i of ``data.csv``; its timestamp is the row's nanoseconds / 1e9 (seconds, the dataset's clock). The
ground truth is matched to the frames by time (nearest pose within a tolerance, 10 ms by default; EuRoC's is
200 Hz) and re-based on the first selected frame.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np

from vslam_core.errors import SourceError, TrajectoryFormatError
from vslam_core.sources.base import CameraIntrinsics, FrameRange, safe_name
from vslam_core.sources.calibration_files import load_yaml, number_list, read_calibration
from vslam_core.sources.kitti import BadFramePolicy, ImageFilesSource, first_image, orientation_notes, select
from vslam_core.sources.stamps import (
    DEFAULT_GT_TOLERANCE_S,
    matched_by_time,
    selected_ground_truth,
    stamp_problems,
    tum_camera_poses,
)
from vslam_core.trajectory.io import check_ground_truth_steps

GROUND_TRUTH_FOLDER = "state_groundtruth_estimate0"
_CAMERA_NAME = re.compile(r"cam\d+")


# --------------------------------------------------------------------------------------------------
# layout


def find_mav0(path: str | Path) -> Path | None:
    """The ``mav0`` folder of an EuRoC/ASL sequence given its root folder or the ``mav0`` folder itself
    (None when `path` is neither)."""
    folder = Path(path)
    if (folder / "mav0").is_dir():
        return folder / "mav0"
    if folder.is_dir() and (folder.name == "mav0" or (folder / "cam0" / "data.csv").is_file()):
        return folder
    return None


def is_euroc(path: str | Path) -> bool:
    """True when `path` is an EuRoC/ASL sequence: a folder holding ``mav0/``, or a ``mav0`` folder (or one
    holding ``cam0/data.csv``). Such a folder is then opened with `EurocSource`, which names what is missing."""
    return find_mav0(path) is not None


def _cameras(mav0: Path) -> list[str]:
    """The camera folders (``cam0``, ``cam1``, …) of a ``mav0`` folder, sorted."""
    return sorted(p.name for p in mav0.iterdir() if p.is_dir() and _CAMERA_NAME.fullmatch(p.name))


# --------------------------------------------------------------------------------------------------
# readers


def read_frame_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """``data.csv`` of a camera: ((N,) int64 nanosecond stamps, N file names), in file order. `SourceError`
    naming the file (and line) when it is missing, malformed or empty."""
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise SourceError(f"{path}: frame list not found (expected '#timestamp [ns],filename' rows)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read the frame list ({exc.__class__.__name__})") from None
    stamps: list[int] = []
    names: list[str] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if len(fields) != 2 or not fields[1]:
            raise SourceError(f"{path}:{number}: expected 'timestamp [ns],filename', found {stripped[:60]!r}")
        try:
            stamps.append(int(fields[0]))
        except ValueError:
            raise SourceError(f"{path}:{number}: timestamp {fields[0][:30]!r} is not an integer (ns)") from None
        names.append(fields[1])
    if not names:
        raise SourceError(f"{path}: the frame list names no image")
    return np.asarray(stamps, np.int64), names


def rotations_from_quaternions(wxyz: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z; normalised here) -> (N, 3, 3) rotation matrices."""
    q = wxyz / np.linalg.norm(wxyz, axis=1, keepdims=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )


def read_body_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``state_groundtruth_estimate0/data.csv``: ((M,) int64 nanosecond stamps, (M, 4, 4) T_R_body). Only
    the first 8 columns (stamp, position, quaternion w x y z) are used. `SourceError` naming the file and
    line for a malformed row, a quaternion that is not of unit length or a jump (`check_ground_truth_steps`)."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read the ground truth ({exc.__class__.__name__})") from None
    stamps: list[int] = []
    values: list[list[float]] = []
    numbers: list[int] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = stripped.split(",")
        if len(fields) < 8:
            raise SourceError(f"{path}:{number}: expected at least 8 comma-separated values (timestamp, "
                              f"p_RS_R xyz, q_RS wxyz), found {len(fields)}")
        try:
            stamps.append(int(fields[0]))
            values.append([float(f) for f in fields[1:8]])
        except ValueError:
            raise SourceError(f"{path}:{number}: not a number in {stripped[:60]!r}") from None
        numbers.append(number)
    if not stamps:
        raise SourceError(f"{path}: the ground truth holds no pose")
    table = np.asarray(values, np.float64)
    if not np.all(np.isfinite(table)):
        bad = int(np.argmax(~np.isfinite(table).all(axis=1)))
        raise SourceError(f"{path}:{numbers[bad]}: non-finite value")
    norms = np.linalg.norm(table[:, 3:7], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-2):
        bad = int(np.argmax(np.abs(norms - 1.0) > 1e-2))
        raise SourceError(f"{path}:{numbers[bad]}: quaternion q_RS is not of unit length (|q| = {norms[bad]:.4g})")
    poses = np.tile(np.eye(4), (len(table), 1, 1))
    poses[:, :3, :3] = rotations_from_quaternions(table[:, 3:7])
    poses[:, :3, 3] = table[:, :3]
    try:
        check_ground_truth_steps(path, poses, np.asarray(stamps, np.float64) / 1e9, lines=numbers)
    except TrajectoryFormatError as exc:
        raise SourceError(str(exc)) from None
    return np.asarray(stamps, np.int64), poses


def read_sensor_yaml(path: Path) -> tuple[CameraIntrinsics, np.ndarray]:
    """An EuRoC camera's ``sensor.yaml``: (intrinsics of the ``resolution`` size, read with `read_calibration`,
    ``origin`` the path; (4, 4) T_BS = the camera's pose in the body frame). Only ``camera_model: pinhole`` (or
    none given) is accepted. Every problem is a one-line `SourceError` naming the file."""
    if not path.exists():
        raise SourceError(f"{path}: camera calibration not found")
    intrinsics = read_calibration(path)
    if (intrinsics.width, intrinsics.height) == (0, 0):
        raise SourceError(f"{path}: no 'resolution' [width, height]")
    data = load_yaml(path)
    if "T_BS" not in data:
        raise SourceError(f"{path}: no 'T_BS' (the camera's pose in the body frame, 4x4)")
    values = number_list(data["T_BS"], "T_BS", str(path))
    if len(values) != 16 or not all(np.isfinite(values)):
        raise SourceError(f"{path}: 'T_BS' needs 16 finite numbers (4x4, row-major), found {len(values)} numbers")
    t_bs = np.asarray(values).reshape(4, 4)
    rotation = t_bs[:3, :3]
    if (np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or np.linalg.det(rotation) < 0
            or not np.allclose(t_bs[3], [0.0, 0.0, 0.0, 1.0])):
        raise SourceError(f"{path}: T_BS is not a rigid transform (rotation + translation, last row 0 0 0 1)")
    return replace(intrinsics, origin=str(path)), t_bs


# --------------------------------------------------------------------------------------------------
# the source


class EurocSource(ImageFilesSource):
    """Frames of one camera of an EuRoC/ASL sequence.

    path: the sequence's root folder (holding ``mav0/``) or its ``mav0`` folder. camera: ``cam0`` (default)
    or ``cam1``. frames: the selection over the rows of ``data.csv`` (default all). ground_truth: a TUM file
    of *camera* poses T_w_c (used as is, matched by timestamp) instead of ``state_groundtruth_estimate0``
    (body poses, turned into camera poses with T_BS); with neither, ``ground_truth`` is None. gt_tolerance_s:
    how far (s) the nearest ground-truth stamp may be from a frame's. on_bad_frame: an image that is missing
    or cannot be read fails the run (``"fail"``, a missing one already when the source is opened) or becomes
    a placeholder frame with a `Frame.defect` (``"skip"``). ``indices`` are rows of ``data.csv``.
    """

    _times: np.ndarray

    def __init__(
        self,
        path: str | Path,
        camera: str = "cam0",
        frames: FrameRange | None = None,
        ground_truth: str | Path | None = None,
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        on_bad_frame: BadFramePolicy = "fail",
        gt_time_offset_s: float = 0.0,
    ):
        self._on_bad_frame = on_bad_frame
        root = Path(path)
        if not root.exists():
            raise SourceError(f"{root}: EuRoC folder not found")
        mav0 = find_mav0(root)
        if mav0 is None:
            raise SourceError(f"{root}: not an EuRoC/ASL sequence (no mav0/ folder)")
        self.mav0 = mav0
        self.camera = camera.strip()
        if not _CAMERA_NAME.fullmatch(self.camera):
            raise SourceError(f"{mav0}: camera {camera!r} is not a camera name (cam0, cam1, …)")
        self.folder = mav0 / self.camera
        if not self.folder.is_dir():
            cameras = ", ".join(_cameras(mav0)) or "none"
            raise SourceError(f"{mav0}: no camera {self.camera} in this sequence (cameras: {cameras})")

        stamps_ns, names = read_frame_list(self.folder / "data.csv")
        self._files = [self.folder / "data" / name for name in names]
        self._times = stamps_ns / 1e9
        self._indices = select(frames, len(self._files), self.folder)
        self.notes: list[str] = [f"{self.folder / 'data.csv'}: {note}" for note in stamp_problems(self._times)]
        self._check_missing()
        self._size, self._shift = first_image(self._files, self._indices, on_bad_frame, self.folder)
        self.notes += orientation_notes(self._files, self._indices, self._size)

        intrinsics, self.t_bs = read_sensor_yaml(self.folder / "sensor.yaml")
        if (intrinsics.width, intrinsics.height) != self._size:
            raise SourceError(
                f"{self.folder / 'sensor.yaml'}: resolution {intrinsics.width}x{intrinsics.height} but the images "
                f"are {self._size[0]}x{self._size[1]}")
        self._intrinsics = intrinsics

        self._gt_offset_s = gt_time_offset_s
        self._ground_truth, label = self._read_ground_truth(ground_truth, gt_tolerance_s)
        self.gt_matching = None if self._ground_truth is None else matched_by_time(len(self._indices), gt_tolerance_s,
                                                                                   gt_time_offset_s)
        sequence = mav0.resolve().parent.name if mav0.name == "mav0" else mav0.resolve().name
        self._name = f"euroc-{safe_name(sequence, 'sequence')}-{self.camera}"
        self.properties: dict[str, str] = {"dataset": "EuRoC", "camera": self.camera, "ground_truth": label}

    def _check_missing(self) -> None:
        """Images named in data.csv that do not exist: an error now with ``fail``, a note with ``skip``."""
        missing = [i for i in self._indices if not self._files[i].is_file()]
        if not missing:
            return
        if self._on_bad_frame == "fail":
            raise SourceError(
                f"{self._files[missing[0]]}: image named in data.csv not found (frame {missing[0]}; "
                f"{len(missing)} of the {len(self._indices)} selected frames are missing)")
        self.notes.append(f"{len(missing)} of the selected images named in {self.folder / 'data.csv'} are missing "
                          f"(first: frame {missing[0]}); they are skipped as bad frames")

    def _read_ground_truth(self, override: str | Path | None, tolerance_s: float) -> tuple[np.ndarray | None, str]:
        """The selected frames' T_w_c (re-based) and a description of where they came from."""
        if override is not None:
            return tum_camera_poses(Path(override), self._times, self._indices, tolerance_s, self.folder,
                                    self._gt_offset_s)
        gt_file = self.mav0 / GROUND_TRUTH_FOLDER / "data.csv"
        if not gt_file.is_file():
            return None, "none"
        stamps_ns, body = read_body_ground_truth(gt_file)
        gt_stamps, gt_poses = stamps_ns / 1e9, body @ self.t_bs
        label = f"{GROUND_TRUTH_FOLDER} (body poses × T_BS)"
        return selected_ground_truth(self._times, self._indices, gt_stamps, gt_poses, tolerance_s, label,
                                     self.folder, self._gt_offset_s), label

    @property
    def stamps(self) -> np.ndarray:
        """(len(files),) timestamps in seconds of every frame, in frame order."""
        return self._times.copy()

    def __repr__(self) -> str:
        return f"EurocSource({str(self.mav0)!r}, camera={self.camera!r}, frames={len(self)})"
