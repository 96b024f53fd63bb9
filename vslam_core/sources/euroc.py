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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange
from vslam_core.sources.calibration import make_intrinsics
from vslam_core.sources.kitti import BadFramePolicy, first_image_size, read_frame, select
from vslam_core.sources.stamps import DEFAULT_GT_TOLERANCE_S, ground_truth_at, nearest_in_time, stamp_problems

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


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "sequence"


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
    line for a malformed row or a quaternion that is not of unit length."""
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
    return np.asarray(stamps, np.int64), poses


def _scalar(text: str) -> Any:
    """A YAML scalar as int, float or string (quotes removed)."""
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "'\"":
        return text[1:-1]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def parse_simple_yaml(text: str) -> dict[str, Any]:
    """The subset of YAML that sensor.yaml files use: ``key: value`` mappings nested by indentation,
    scalars, and ``[a, b, …]`` flow lists (which may span lines); ``#`` comments; ``%YAML`` / ``---``
    lines ignored. Used when PyYAML is not installed."""
    logical: list[tuple[int, str]] = []
    pending = ""
    indent = 0
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].rstrip()
        if not pending and (not line.strip() or line.lstrip().startswith(("%", "---"))):
            continue
        if not pending:
            indent = len(line) - len(line.lstrip())
        pending = f"{pending} {line.strip()}" if pending else line.strip()
        if pending.count("[") <= pending.count("]"):
            logical.append((indent, pending))
            pending = ""
    if pending:
        logical.append((indent, pending))
    root: dict[str, Any] = {}
    stack: list[tuple[int, dict[str, Any]]] = [(-1, root)]
    for indent, line in logical:
        key, colon, value = line.partition(":")
        if not colon:
            raise SourceError(f"cannot parse YAML line {line[:60]!r} (expected 'key: value')")
        while stack[-1][0] >= indent:
            stack.pop()
        mapping = stack[-1][1]
        value = value.strip()
        if not value:
            child: dict[str, Any] = {}
            mapping[key.strip()] = child
            stack.append((indent, child))
        elif value.startswith("["):
            inner = value.strip("[]").strip()
            mapping[key.strip()] = [_scalar(v) for v in inner.split(",") if v.strip()] if inner else []
        else:
            mapping[key.strip()] = _scalar(value)
    return root


def _parse_yaml(text: str) -> Any:
    """PyYAML's safe_load when PyYAML is installed, else `parse_simple_yaml`."""
    try:
        import yaml
    except ImportError:
        return parse_simple_yaml(text)
    return yaml.safe_load(text)


def load_yaml(path: Path) -> dict[str, Any]:
    """A small YAML file as a dict: with PyYAML when it is installed, else with `parse_simple_yaml`. OpenCV's
    ``%YAML:1.0`` first line (which PyYAML refuses) is dropped. `SourceError` naming the file on failure."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SourceError(f"{path}: camera calibration not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    text = "\n".join("" if line.startswith("%YAML") else line for line in text.splitlines())
    try:
        data = _parse_yaml(text)
    except SourceError as exc:
        raise SourceError(f"{path}: {exc}") from None
    except Exception as exc:  # any YAML error becomes one line naming the file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
        raise SourceError(f"{path}: not valid YAML ({first})") from None
    if not isinstance(data, dict):
        raise SourceError(f"{path}: expected a YAML mapping of calibration keys")
    return data


def _numbers(data: dict[str, Any], key: str, count: int | None, path: Path) -> list[float]:
    """``data[key]`` as a list of floats (``count`` of them when given); `SourceError` naming the key."""
    value = data.get(key)
    if isinstance(value, dict):
        value = value.get("data")
    if not isinstance(value, list):
        raise SourceError(f"{path}: no '{key}' list")
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        raise SourceError(f"{path}: '{key}' holds something that is not a number") from None
    if count is not None and len(numbers) != count:
        raise SourceError(f"{path}: '{key}' needs {count} numbers, found {len(numbers)}")
    if not all(np.isfinite(numbers)):
        raise SourceError(f"{path}: '{key}' holds a non-finite value")
    return numbers


def read_sensor_yaml(path: Path) -> tuple[CameraIntrinsics, np.ndarray]:
    """An EuRoC camera's ``sensor.yaml``: (intrinsics of the ``resolution`` size, (4, 4) T_BS = the camera's
    pose in the body frame). Only ``camera_model: pinhole`` (or none given) is accepted."""
    data = load_yaml(path)
    camera_model = str(data.get("camera_model", "pinhole")).strip().lower()
    if camera_model != "pinhole":
        raise SourceError(f"{path}: camera_model {camera_model!r} is not supported (only pinhole)")
    fu, fv, cu, cv = _numbers(data, "intrinsics", 4, path)
    width, height = _numbers(data, "resolution", 2, path)
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise SourceError(f"{path}: 'resolution' must be two positive integers (width, height)")
    model = str(data.get("distortion_model", "none") or "none")
    coefficients = _numbers(data, "distortion_coefficients", None, path) if "distortion_coefficients" in data else []
    intrinsics = make_intrinsics([fu, fv, cu, cv], model, coefficients, int(width), int(height), str(path))
    t_bs = np.asarray(_numbers(data, "T_BS", 16, path)).reshape(4, 4)
    rotation = t_bs[:3, :3]
    if (np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or np.linalg.det(rotation) < 0
            or not np.allclose(t_bs[3], [0.0, 0.0, 0.0, 1.0])):
        raise SourceError(f"{path}: T_BS is not a rigid transform (rotation + translation, last row 0 0 0 1)")
    return intrinsics, t_bs


def read_tum_ground_truth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM trajectory (``timestamp tx ty tz qx qy qz qw``, spaces or commas): ((M,) stamps in seconds,
    (M, 4, 4) poses). Rows holding NaN (frames without a pose, as in TUM monoVO's groundtruthSync.txt) are
    left out; any other malformed row, or no pose at all, is a `SourceError` naming the file (and line)."""
    if not path.is_file():
        raise SourceError(f"{path}: ground-truth file not found")
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read the ground truth ({exc.__class__.__name__})") from None
    rows: list[list[float]] = []
    numbers: list[int] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = stripped.replace(",", " ").split()
        if len(fields) != 8:
            raise SourceError(f"{path}:{number}: expected 8 numbers (timestamp tx ty tz qx qy qz qw), found "
                              f"{len(fields)}")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise SourceError(f"{path}:{number}: not a number in {stripped[:60]!r}") from None
        if all(np.isfinite(values)):
            rows.append(values)
            numbers.append(number)
    if not rows:
        raise SourceError(f"{path}: the ground truth holds no pose")
    table = np.asarray(rows, np.float64)
    norms = np.linalg.norm(table[:, 4:8], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-2):
        bad = int(np.argmax(np.abs(norms - 1.0) > 1e-2))
        raise SourceError(f"{path}:{numbers[bad]}: quaternion is not of unit length (|q| = {norms[bad]:.4g})")
    poses = np.tile(np.eye(4), (len(table), 1, 1))
    poses[:, :3, :3] = rotations_from_quaternions(table[:, [7, 4, 5, 6]])
    poses[:, :3, 3] = table[:, 1:4]
    return table[:, 0].copy(), poses


def _runs(indices: np.ndarray) -> list[tuple[int, int]]:
    """Sorted source indices as (START, END) runs of consecutive indices (END exclusive)."""
    if len(indices) == 0:
        return []
    breaks = np.flatnonzero(np.diff(indices) != 1)
    starts = np.concatenate([[indices[0]], indices[breaks + 1]])
    ends = np.concatenate([indices[breaks], [indices[-1]]]) + 1
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def require_ground_truth(
    frame_stamps: np.ndarray, indices: list[int], gt_stamps: np.ndarray, tolerance_s: float, label: str,
    where: object,
) -> None:
    """`SourceError` when a selected frame has no ground-truth pose within `tolerance_s`, saying which frames
    (START:END runs) do have one, so the user can choose --frames inside them (a ground truth that starts
    after the images, or covers only the start and end of a sequence, is common).

    `frame_stamps` are every frame's stamps (s, frame order), `indices` the selected ones."""
    _, close = nearest_in_time(frame_stamps, gt_stamps, tolerance_s)
    selected = close[np.asarray(indices)]
    if selected.all():
        return
    first = indices[int(np.argmin(selected))]
    span = f"the ground truth spans {np.min(gt_stamps):.3f}–{np.max(gt_stamps):.3f} s"
    runs = _runs(np.flatnonzero(close))
    if not runs:
        raise SourceError(
            f"{where}: no frame has a ground-truth pose within {tolerance_s * 1000:g} ms in {label} ({span}, "
            f"the frames {frame_stamps.min():.3f}–{frame_stamps.max():.3f} s): is it this sequence's ground truth?")
    shown = ", ".join(f"{a}:{b}" for a, b in runs[:4]) + (", …" if len(runs) > 4 else "")
    raise SourceError(
        f"{where}: {int((~selected).sum())} of the {len(indices)} selected frames have no ground-truth pose within "
        f"{tolerance_s * 1000:g} ms in {label} (first: frame {first} at {frame_stamps[first]:.3f} s; {span}); "
        f"frames {shown} have one: choose --frames inside them")


# --------------------------------------------------------------------------------------------------
# the source


class EurocSource:
    """Frames of one camera of an EuRoC/ASL sequence.

    path: the sequence's root folder (holding ``mav0/``) or its ``mav0`` folder. camera: ``cam0`` (default)
    or ``cam1``. frames: the selection over the rows of ``data.csv`` (default all). ground_truth: a TUM file
    of *camera* poses T_w_c (used as is, matched by timestamp) instead of ``state_groundtruth_estimate0``
    (body poses, turned into camera poses with T_BS); with neither, ``ground_truth`` is None. gt_tolerance_s:
    how far (s) the nearest ground-truth stamp may be from a frame's. on_bad_frame: an image that is missing
    or cannot be read fails the run (``"fail"``, a missing one already when the source is opened) or becomes
    a placeholder frame with a `Frame.defect` (``"skip"``).
    """

    def __init__(
        self,
        path: str | Path,
        camera: str = "cam0",
        frames: FrameRange | None = None,
        ground_truth: str | Path | None = None,
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        on_bad_frame: BadFramePolicy = "fail",
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
        self._stamps = stamps_ns / 1e9
        self._indices = select(frames, len(self._files), self.folder)
        self.notes: list[str] = [f"{self.folder / 'data.csv'}: {note}" for note in stamp_problems(self._stamps)]
        self._check_missing()
        self._size = first_image_size(self._files, self._indices, on_bad_frame, self.folder)

        intrinsics, self.t_bs = read_sensor_yaml(self.folder / "sensor.yaml")
        if (intrinsics.width, intrinsics.height) != self._size:
            raise SourceError(
                f"{self.folder / 'sensor.yaml'}: resolution {intrinsics.width}x{intrinsics.height} but the images "
                f"are {self._size[0]}x{self._size[1]}")
        self._intrinsics = intrinsics

        self._ground_truth, label = self._read_ground_truth(ground_truth, gt_tolerance_s)
        sequence = mav0.resolve().parent.name if mav0.name == "mav0" else mav0.resolve().name
        self._name = f"euroc-{_safe(sequence)}-{self.camera}"
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
            gt_file = Path(override)
            gt_stamps, gt_poses = read_tum_ground_truth(gt_file)
            label = f"{gt_file.name} (TUM, camera poses)"
        else:
            gt_file = self.mav0 / GROUND_TRUTH_FOLDER / "data.csv"
            if not gt_file.is_file():
                return None, "none"
            stamps_ns, body = read_body_ground_truth(gt_file)
            gt_stamps, gt_poses = stamps_ns / 1e9, body @ self.t_bs
            label = f"{GROUND_TRUTH_FOLDER} (body poses × T_BS)"
        require_ground_truth(self._stamps, self._indices, gt_stamps, tolerance_s, label, self.folder)
        poses = ground_truth_at(self._stamps[np.asarray(self._indices)], gt_stamps, gt_poses, tolerance_s,
                                f"{self.folder} ({label})")
        return poses, label

    @property
    def name(self) -> str:
        return self._name

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def ground_truth(self) -> np.ndarray | None:
        """(N, 4, 4) T_w_c of the selected frames (first = identity), or None."""
        return None if self._ground_truth is None else self._ground_truth.copy()

    @property
    def camera_height(self) -> None:
        return None

    @property
    def indices(self) -> list[int]:
        """The selected source indices (rows of data.csv)."""
        return list(self._indices)

    @property
    def files(self) -> list[Path]:
        """Every image file named by data.csv, in frame order (source index i = files[i])."""
        return list(self._files)

    @property
    def stamps(self) -> np.ndarray:
        """(len(files),) timestamps in seconds of every frame, in frame order."""
        return self._stamps.copy()

    def __len__(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[Frame]:
        for index in self._indices:
            yield read_frame(index, self._files[index], self._size, float(self._stamps[index]), self._on_bad_frame)

    def __repr__(self) -> str:
        return f"EurocSource({str(self.mav0)!r}, camera={self.camera!r}, frames={len(self)})"
