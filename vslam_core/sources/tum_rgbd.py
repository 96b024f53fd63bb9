"""TUM RGB-D sequences (Sturm, Engelhard, Endres, Burgard, Cremers, "A Benchmark for the Evaluation of RGB-D SLAM
Systems", IROS 2012), and any folder in their layout: the colour frames, monocular (the depth images are not used).

Layout::

    SEQ/rgb.txt            ``timestamp filename`` a line (seconds; ``rgb/<timestamp>.png``), ``#`` comments
    SEQ/rgb/*.png          colour frames (640x480 in the benchmark), converted to grey
    SEQ/groundtruth.txt    ``timestamp tx ty tz qx qy qz qw``: the colour camera's optical centre in the
                           motion-capture frame (T_world_cam), 100 Hz, matched to the frames by time
    SEQ/accelerometer.txt  ``timestamp ax ay az`` (m/s², the Kinect's accelerometer), optional: recorded per frame
    SEQ/calibration.txt    ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` one line (plumb_bob), optional (not in TUM's downloads)
    SEQ/depth.txt, depth/  registered depth images: not used

Ground truth is interpolated at each frame's stamp between the two motion-capture rows around it (translation
linearly, rotation by slerp), as TUM's own tools do; a frame in a gap wider than the allowed one is refused.
Frames are the rows of ``rgb.txt`` in stamp order (the file's own order in the benchmark; rows out of order are put
in order, with a note). The camera comes from ``--calib`` / ``--intrinsics`` when given, else from the folder's
``calibration.txt``, else from the folder's name when it names one of the benchmark's three Kinects
(``rgbd_dataset_freiburg1_xyz`` → freiburg1), with the colour cameras' calibration the benchmark publishes (its
"File Formats" page rounds it to 0.1 px; these are the unrounded values that ORB-SLAM's TUM1/2/3 settings and other
public tools carry; plumb_bob k1 k2 p1 p2 k3). freiburg3's colour images are undistorted already (its coefficients
are zero). A folder whose name names no Freiburg camera is refused without a calibration: a guessed focal length
would silently scale every rotation.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, FrameRange, safe_name
from vslam_core.sources.folder import complete_intrinsics
from vslam_core.sources.kitti import (
    BadFramePolicy,
    ImageFilesSource,
    first_image,
    orientation_notes,
    select,
    sixteen_bit_property,
)
from vslam_core.sources.stamps import (
    DEFAULT_GT_MAX_GAP_S,
    interpolated_ground_truth,
    parse_stamp,
    read_tum_ground_truth,
    stamp_problems,
    stamped_lines,
)

#: The benchmark's colour cameras: fx fy cx cy (pixels) and plumb_bob k1 k2 p1 p2 k3, for 640x480 frames.
FREIBURG_CAMERAS: dict[str, tuple[tuple[float, float, float, float], tuple[float, ...]]] = {
    "freiburg1": ((517.306408, 516.469215, 318.643040, 255.313989),
                  (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)),
    "freiburg2": ((520.908620, 521.007327, 325.141442, 249.701764),
                  (0.231222, -0.784899, -0.003257, -0.000105, 0.917205)),
    "freiburg3": ((535.4, 539.2, 320.1, 247.6), (0.0, 0.0, 0.0, 0.0, 0.0)),
}
FREIBURG_SIZE = (640, 480)
GROUND_TRUTH_FILE = "groundtruth.txt"
CALIBRATION_FILE = "calibration.txt"
ACCELEROMETER_FILE = "accelerometer.txt"
#: The Kinect's accelerometer axes in the colour camera's (x right, y down, z forward): (ax, ay, -az) is gravity
#: in the camera frame. Fitted on fr1_xyz and fr1_desk against the motion capture's vertical (median 5.5° apart,
#: hand accelerations and the mocap's own tilt included; every other signed axis order is further off).
ACCELEROMETER_TO_CAMERA = np.diag([1.0, 1.0, -1.0])


def sequence_folder(path: str | Path) -> Path | None:
    """The sequence folder of a TUM RGB-D layout given the folder or its ``rgb/`` folder (None otherwise)."""
    folder = Path(path)
    for candidate in (folder, folder.parent) if folder.name == "rgb" else (folder,):
        if (candidate / "rgb.txt").is_file() and (candidate / "rgb").is_dir():
            return candidate
    return None


def is_tum_rgbd(path: str | Path) -> bool:
    """True when `path` is a TUM RGB-D sequence (or its ``rgb/`` folder): ``rgb.txt`` beside ``rgb/``."""
    return sequence_folder(path) is not None


def read_frame_list(path: Path) -> tuple[np.ndarray, list[Path]]:
    """``rgb.txt``: ((N,) timestamps in seconds, (N,) image paths relative to its folder), in the file's order.
    `SourceError` naming the file and line for a malformed line or a missing image."""
    stamps: list[float] = []
    files: list[Path] = []
    for number, stripped, fields in stamped_lines(path, "the frame list"):
        if len(fields) != 2:
            raise SourceError(f"{path}:{number}: expected 'timestamp filename', found {stripped[:60]!r}")
        stamps.append(parse_stamp(path, number, fields[0]))
        file = path.parent / fields[1]
        if not file.is_file():
            raise SourceError(f"{path}:{number}: {fields[1]} not found")
        files.append(file)
    if not files:
        raise SourceError(f"{path}: no frames listed")
    return np.asarray(stamps, np.float64), files


def freiburg_camera(folder: Path) -> CameraIntrinsics | None:
    """The benchmark's published calibration of the Kinect the folder's name names (``freiburg1``..``3``), or
    None when it names none (or more than one)."""
    name = folder.resolve().name
    named = set(re.findall(r"freiburg([123])", name, flags=re.IGNORECASE))
    if len(named) != 1:
        return None
    camera = f"freiburg{named.pop()}"
    (fx, fy, cx, cy), coefficients = FREIBURG_CAMERAS[camera]
    return CameraIntrinsics(fx, fy, cx, cy, *FREIBURG_SIZE, "plumb_bob", coefficients,
                            f"TUM RGB-D {camera} published calibration (camera named by the folder {name!r})")


def folder_calibration(folder: Path) -> CameraIntrinsics | None:
    """The folder's ``calibration.txt`` (one line ``fx fy cx cy`` [``k1 k2 p1 p2`` [``k3``]], plumb_bob, ``#``
    comments; the image size from the images), or None when there is none; `SourceError` naming the file and
    line when it holds anything else."""
    path = folder / CALIBRATION_FILE
    if not path.is_file():
        return None
    rows = list(stamped_lines(path, "the calibration"))
    if len(rows) != 1 or len(rows[0][2]) not in (4, 8, 9):
        where = f"{path}:{rows[0][0]}" if rows else str(path)
        raise SourceError(f"{where}: expected one line 'fx fy cx cy [k1 k2 p1 p2 [k3]]'")
    number, _, fields = rows[0]
    try:
        values = [float(v) for v in fields]
    except ValueError:
        raise SourceError(f"{path}:{number}: not numbers: {' '.join(fields)[:60]!r}") from None
    if not all(np.isfinite(values)) or min(values[:4]) <= 0:
        raise SourceError(f"{path}:{number}: fx fy cx cy must be finite and positive")
    coefficients = tuple(values[4:])
    fx, fy, cx, cy = values[:4]
    return CameraIntrinsics(fx, fy, cx, cy, 0, 0, "plumb_bob" if coefficients else "none", coefficients,
                            f"{path.name} (the folder's, plumb_bob)" if coefficients else path.name)


def read_accelerometer(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``accelerometer.txt``: ((M,) stamps in seconds, (M, 3) gravity in the camera frame, m/s²: the readings
    turned by `ACCELEROMETER_TO_CAMERA`), in stamp order; `SourceError` naming the file and line when
    malformed."""
    stamps, readings = [], []
    for number, stripped, fields in stamped_lines(path, "the accelerometer"):
        if len(fields) != 4:
            raise SourceError(f"{path}:{number}: expected 'timestamp ax ay az', found {stripped[:60]!r}")
        stamps.append(parse_stamp(path, number, fields[0]))
        try:
            readings.append([float(v) for v in fields[1:]])
        except ValueError:
            raise SourceError(f"{path}:{number}: not numbers: {stripped[:60]!r}") from None
    order = np.argsort(np.asarray(stamps), kind="stable")
    gravity = np.asarray(readings, np.float64).reshape(-1, 3) @ ACCELEROMETER_TO_CAMERA.T
    return np.asarray(stamps, np.float64)[order], gravity[order]


def gravity_per_frame(stamps: np.ndarray, gravity: np.ndarray, frame_times: np.ndarray,
                      indices: list[int]) -> dict[int, np.ndarray]:
    """Source frame index -> (3,) the mean of the (M, 3) readings stamped in the frame's interval (after the
    previous frame's stamp, up to its own; the first frame: the 33 ms before it), for the selected `indices`
    of every frame's `frame_times`; a frame without a reading in its interval has none."""
    values: dict[int, np.ndarray] = {}
    for i in indices:
        start = frame_times[i - 1] if i > 0 else frame_times[i] - 1.0 / 30.0
        inside = (stamps > start) & (stamps <= frame_times[i])
        if inside.any():
            values[i] = gravity[inside].mean(axis=0)
    return values


class TumRgbdSource(ImageFilesSource):
    """The colour frames of a TUM RGB-D sequence (see the module docstring), as grey frames.

    path: the sequence folder (or its ``rgb/`` folder). camera: the calibration (``--calib`` / ``--intrinsics``;
    a 0x0 size is filled from the images), else the folder's ``calibration.txt``, else the Freiburg camera the
    folder's name names. frames: the selection over the rows of ``rgb.txt``. ground_truth: a TUM file of camera
    poses T_w_c instead of the folder's ``groundtruth.txt``; either is interpolated at the frames' stamps between
    rows at most `gt_max_gap_s` apart (`interpolated_ground_truth`); with neither, ``ground_truth`` is None.
    ``gravity_by_frame``: the accelerometer per frame (`gravity_per_frame`), empty without one."""

    _times: np.ndarray

    def __init__(
        self,
        path: str | Path,
        camera: CameraIntrinsics | None = None,
        frames: FrameRange | None = None,
        ground_truth: str | Path | None = None,
        gt_max_gap_s: float = DEFAULT_GT_MAX_GAP_S,
        on_bad_frame: BadFramePolicy = "fail",
        gt_time_offset_s: float = 0.0,
    ):
        self._on_bad_frame = on_bad_frame
        given = Path(path)
        folder = sequence_folder(given)
        if folder is None:
            raise SourceError(f"{given}: not a TUM RGB-D sequence (needs rgb.txt and rgb/)")
        self.folder = folder
        stamps, files = read_frame_list(folder / "rgb.txt")
        order = np.argsort(stamps, kind="stable")  # rgb.txt is in time order; if not, its stamps decide
        self._times, self._files = stamps[order], [files[i] for i in order]
        self._indices = select(frames, len(self._files), folder)
        self._size, self._shift = first_image(self._files, self._indices, on_bad_frame, folder)
        self.notes: list[str] = [f"{folder / 'rgb.txt'}: {note}" for note in stamp_problems(stamps)]
        self.notes += orientation_notes(self._files, self._indices, self._size)
        if (folder / "depth.txt").is_file() or (folder / "depth").is_dir():
            self.notes.append("depth images not used: vslam is monocular (the colour frames only)")

        chosen = camera or folder_calibration(folder) or freiburg_camera(folder)
        if chosen is None:
            raise SourceError(f"{folder}: a TUM RGB-D folder without {CALIBRATION_FILE} whose name names no Freiburg "
                              "camera (freiburg1, 2 or 3): give --calib FILE or --intrinsics fx,fy,cx,cy")
        self._intrinsics = complete_intrinsics(chosen, self._size[0], self._size[1], folder,
                                               scalable=camera is not None)  # the published one: no --calib-scale

        self.properties: dict[str, str] = {"dataset": "TUM RGB-D", "frame_order": "rgb.txt's stamps",
                                           **sixteen_bit_property(self._shift)}
        default = folder / GROUND_TRUTH_FILE
        gt_file = Path(ground_truth) if ground_truth is not None else default if default.is_file() else None
        self._ground_truth, self.gt_matching = None, None
        self.properties["ground_truth"] = "none"
        if gt_file is not None:
            gt_stamps, gt_poses = read_tum_ground_truth(gt_file)
            self.properties["ground_truth"] = f"{gt_file.name} (TUM, camera poses)"
            self._ground_truth, self.gt_matching = interpolated_ground_truth(
                self._times[np.asarray(self._indices)] + gt_time_offset_s, gt_stamps, gt_poses, gt_max_gap_s,
                f"{folder} ({gt_file.name})", self._indices)
            if gt_time_offset_s:
                self.gt_matching += (f", the ground truth's clock {gt_time_offset_s:+.3f} s from the frames' "
                                     "(--gt-time-offset)")
        accelerometer = folder / ACCELEROMETER_FILE
        self.gravity_by_frame: dict[int, np.ndarray] = {}
        if accelerometer.is_file():
            self.gravity_by_frame = gravity_per_frame(*read_accelerometer(accelerometer), self._times, self._indices)
            self.properties["accelerometer"] = (f"{ACCELEROMETER_FILE}: gravity in the camera frame (x right, y down, "
                                                "z forward) = (ax, ay, -az), the mean over each frame's interval")
        self._name = "tum-rgbd-" + safe_name(folder.resolve().name, "sequence")

    def __repr__(self) -> str:
        return f"TumRgbdSource({str(self.folder)!r}, frames={len(self)})"
