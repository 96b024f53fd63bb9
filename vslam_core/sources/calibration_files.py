"""``--calib FILE``: a camera calibration file of any common format, read as one `CameraIntrinsics`.

The format is detected from the content, not the extension:

* ROS ``camera_info`` YAML (camera_calibration / camera_info_manager: ``camera_matrix {rows, cols, data}``,
  ``distortion_model``, ``distortion_coefficients``, ``image_width``/``image_height``; a dumped CameraInfo
  message with ``K``/``D``/``width``/``height`` is read too);
* Kalibr camchain YAML (``cam0: {camera_model: pinhole, intrinsics: [fu, fv, pu, pv], distortion_model,
  distortion_coeffs, resolution}``; cam0 is used when there are several cameras) and the EuRoC
  ``sensor.yaml`` (the same keys at the top level, ``distortion_coefficients``);
* OpenCV FileStorage YAML (``%YAML:1.0``, ``!!opencv-matrix``) or XML (``<opencv_storage>``), read with
  ``cv2.FileStorage``: ``camera_matrix``/``cameraMatrix``/``K``, ``distortion_coefficients``/``dist_coeffs``/
  ``distCoeffs``/``D``, optional ``image_width``/``image_height`` and ``distortion_model`` (otherwise
  plumb_bob for 4 or 5 coefficients, rational_polynomial for 8);
* KITTI ``calib.txt`` (the ``P0:`` line; a rectified camera, model none).

Extrinsics (``T_cam_imu``, ``T_BS``) and ROS's rectification/projection matrices are not read (`load_yaml` and
`number_list` give them to a caller that wants them, e.g. `read_sensor_yaml`). Every problem
is a one-line `SourceError` naming the file and the format it was read as (or the formats accepted).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import yaml

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics
from vslam_core.sources.calibration import make_intrinsics
from vslam_core.sources.kitti import read_p0_intrinsics

FORMATS = "ROS camera_info YAML, Kalibr camchain or EuRoC sensor.yaml, OpenCV FileStorage YAML/XML, KITTI calib.txt"
MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "k")
DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "d")
#: OpenCV's distortion vectors by length, when the file names no model (12 and 14 are not supported).
OPENCV_MODELS = {0: "none", 4: "plumb_bob", 5: "plumb_bob", 8: "rational_polynomial"}


def read_calibration(path: Path) -> CameraIntrinsics:
    """The camera of a calibration file (see the module docstring for the formats). Width and height are 0
    when the file does not state them; ``origin`` is the path as given plus the format, e.g.
    ``calib.yaml (ROS camera_info)``. Raises a one-line `SourceError` for a missing or unreadable file, an
    unknown format, missing keys or invalid values."""
    text = _read_text(path)
    if re.search(r"^\s*P0\s*:", text, re.MULTILINE):
        try:
            fx, fy, cx, cy = read_p0_intrinsics(path)
        except SourceError as exc:
            raise SourceError(f"{exc} (read as KITTI calib.txt)") from None
        return make_intrinsics([fx, fy, cx, cy], "none", [], 0, 0, f"{path} (KITTI calib.txt)")
    data, opencv = _load(path, text)
    if not isinstance(data, dict):
        raise SourceError(f"{path}: not a calibration file, it holds no keys (--calib reads {FORMATS})")
    cameras = sorted((k for k in data if re.fullmatch(r"cam\d+", str(k)) and isinstance(data[k], dict)),
                     key=lambda k: int(k[3:]))
    if cameras:
        label = f"Kalibr camchain, {cameras[0]}" + (f" of {len(cameras)}" if len(cameras) > 1 else "")
        return _read_kalibr(data[cameras[0]], f"{path} ({label})")
    if "camera_model" in data or "intrinsics" in data:
        label = "EuRoC sensor.yaml" if "T_BS" in data or "sensor_type" in data else "Kalibr camera"
        return _read_kalibr(data, f"{path} ({label})")
    if any(k in data for k in MATRIX_KEYS):
        if opencv:
            label = f"OpenCV FileStorage {opencv}"
        elif "camera_matrix" in data:
            label = "ROS camera_info"
        elif "K" in data or "k" in data:
            label = "ROS CameraInfo message"
        else:
            label = "OpenCV-style YAML"
        return _read_matrix_file(data, f"{path} ({label})")
    keys = ", ".join(map(str, list(data)[:8])) or "none"
    raise SourceError(f"{path}: not a calibration file, no camera matrix or camera model (keys: {keys}; --calib "
                      f"reads {FORMATS})")


def load_yaml(path: Path) -> dict[str, Any]:
    """A YAML calibration file (OpenCV's ``%YAML:1.0`` header and FileStorage YAML/XML included) as plain Python
    values, loaded as `read_calibration` loads it: for the keys it does not read, e.g. EuRoC's ``T_BS``. A
    one-line `SourceError` naming the file when it cannot be read or parsed, or holds no keys."""
    data, _ = _load(path, _read_text(path))
    if not isinstance(data, dict):
        raise SourceError(f"{path}: not a calibration file, it holds no keys (--calib reads {FORMATS})")
    return data


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise SourceError(f"{path}: calibration file not found (--calib reads {FORMATS})") from None
    except IsADirectoryError:
        raise SourceError(f"{path}: is a folder, not a calibration file (--calib reads {FORMATS})") from None
    except UnicodeDecodeError:
        raise SourceError(f"{path}: not a calibration file, not text (--calib reads {FORMATS})") from None
    except OSError as exc:
        raise SourceError(f"{path}: cannot read calibration file ({exc.__class__.__name__})") from None


def _load(path: Path, text: str) -> tuple[Any, str]:
    """The file as plain Python values, and ``"YAML"``/``"XML"`` when it was read with cv2.FileStorage
    (OpenCV's tags and ``%YAML:1.0`` header, which PyYAML rejects) or ``""`` when with PyYAML."""
    stripped = text.lstrip()
    if stripped.startswith("<"):
        if not stripped.startswith("<?xml"):  # cv2 guesses the format from the header, even in memory
            stripped = '<?xml version="1.0"?>\n' + stripped
        return _load_opencv(path, stripped, "XML"), "XML"
    if "!!opencv-matrix" in text:
        return _load_opencv(path, text, "YAML"), "YAML"
    plain = re.sub(r"\A\s*%YAML:[^\n]*\n", "", text)  # OpenCV's header; the rest may be standard YAML
    try:
        documents = [d for d in yaml.safe_load_all(plain) if d is not None]
    except yaml.YAMLError as exc:
        if stripped.startswith("%YAML"):
            return _load_opencv(path, text, "YAML"), "YAML"
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or exc.__class__.__name__
        raise SourceError(f"{path}: not a calibration file, not YAML/XML ({where}{problem}; --calib reads "
                          f"{FORMATS})") from None
    return (documents[0] if documents else None), ""


def _load_opencv(path: Path, text: str, kind: str) -> Any:
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        return _node_value(storage.root()) if storage.isOpened() else None
    except (cv2.error, SystemError) as exc:
        message = str(exc.__cause__ or exc).strip().splitlines()[-1]
        found = re.search(r"\((\d+)\): ([^']*)'?\s*$", message)
        detail = f"line {found[1]}: {found[2].strip()}" if found else "parse error"
        raise SourceError(f"{path}: cannot parse OpenCV FileStorage {kind} ({detail})") from None


def _node_value(node: Any) -> Any:
    """A cv2.FileNode as plain Python: maps → dict, sequences → list, an opencv-matrix → {rows, cols, data}."""
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "dt", "data"} <= set(keys):
            matrix = node.mat()
            if matrix is not None:
                return {"rows": matrix.shape[0], "cols": matrix.shape[1], "data": matrix.ravel().tolist()}
        return {key: _node_value(node.getNode(key)) for key in keys}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def number_list(value: Any, what: str, origin: str) -> list[float]:
    """The numbers of a list, a nested list, a ``{rows, cols, data}`` matrix or a space-separated string (a
    `SourceError` naming `origin` and `what` otherwise)."""
    if isinstance(value, dict):
        if "data" not in value:
            raise SourceError(f"{origin}: {what} has no 'data'")
        value = value["data"]
    if isinstance(value, str):
        value = value.replace(",", " ").split()
    elif isinstance(value, int | float) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, list | tuple):
        raise SourceError(f"{origin}: {what} is not a list of numbers")
    flat: list[Any] = [v for row in value for v in (row if isinstance(row, list | tuple) else [row])]
    try:
        if any(isinstance(v, bool) for v in flat):
            raise ValueError
        return [float(v) for v in flat]
    except (TypeError, ValueError):
        raise SourceError(f"{origin}: {what} holds something that is not a number") from None


def _size(value: Any, what: str, origin: str) -> int:
    if value is None:
        return 0
    try:
        if isinstance(value, bool) or not isinstance(value, int | float | str):
            raise ValueError
        number = float(value)
        if number != int(number) or number < 0:
            raise ValueError
    except (ValueError, OverflowError):
        raise SourceError(f"{origin}: {what} {value!r} is not a whole number of pixels") from None
    return int(number)


def _read_kalibr(camera: dict[str, Any], origin: str) -> CameraIntrinsics:
    """A Kalibr camera block (camchain ``camN`` or a EuRoC sensor.yaml): pinhole intrinsics fu fv pu pv."""
    model = str(camera.get("camera_model", "pinhole"))
    if model.strip().lower() != "pinhole":
        raise SourceError(f"{origin}: camera_model {model!r} is not supported (only pinhole; Kalibr's omni, ds and "
                          "eucm are not)")
    if "intrinsics" not in camera:
        raise SourceError(f"{origin}: no 'intrinsics' (expected [fu, fv, pu, pv])")
    intrinsics = number_list(camera["intrinsics"], "intrinsics", origin)
    if len(intrinsics) != 4:
        raise SourceError(f"{origin}: intrinsics needs 4 numbers [fu, fv, pu, pv] for a pinhole camera, got "
                          f"{len(intrinsics)}")
    coefficients = camera.get("distortion_coeffs", camera.get("distortion_coefficients"))
    distortion = camera.get("distortion_model")
    if distortion is None and coefficients:
        raise SourceError(f"{origin}: distortion coefficients without a distortion_model")
    width = height = 0
    resolution = camera.get("resolution")
    if resolution is not None:
        if not isinstance(resolution, list | tuple) or len(resolution) != 2:
            raise SourceError(f"{origin}: resolution must be [width, height], got {resolution!r}")
        width, height = (_size(v, "resolution", origin) for v in resolution)
    values = [] if coefficients is None else number_list(coefficients, "distortion coefficients", origin)
    return make_intrinsics(intrinsics, str(distortion or "none"), values, width, height, origin)


def _read_matrix_file(data: dict[str, Any], origin: str) -> CameraIntrinsics:
    """ROS camera_info / CameraInfo message / OpenCV FileStorage: a 3×3 camera matrix and a distortion vector."""
    matrix_key = next(k for k in MATRIX_KEYS if k in data)
    K = number_list(data[matrix_key], matrix_key, origin)  # noqa: N806
    if len(K) != 9:
        raise SourceError(f"{origin}: {matrix_key} needs 9 numbers (3x3), got {len(K)}")
    if K[6:] != [0.0, 0.0, 1.0] or abs(K[1]) > 1e-6 * abs(K[0]) or K[3] != 0.0:
        shown = " ".join(f"{v:g}" for v in K)
        raise SourceError(f"{origin}: {matrix_key} is not [fx 0 cx; 0 fy cy; 0 0 1] (got {shown}; transposed or "
                          "skewed?)")
    distortion_key = next((k for k in DISTORTION_KEYS if k in data), None)
    coefficients = [] if distortion_key is None else number_list(data[distortion_key], distortion_key, origin)
    model = data.get("distortion_model")
    if model is None:
        inferred = OPENCV_MODELS.get(len(coefficients))
        if inferred is None:
            raise SourceError(f"{origin}: {len(coefficients)} distortion coefficients and no distortion_model "
                              "(4 or 5 are read as plumb_bob, 8 as rational_polynomial)")
        model = inferred
    elif not isinstance(model, str):
        raise SourceError(f"{origin}: distortion_model {model!r} is not a name")
    elif distortion_key is None and model.strip().lower() not in ("", "none", "pinhole"):
        raise SourceError(f"{origin}: distortion_model {model!r} but no distortion coefficients "
                          f"({', '.join(DISTORTION_KEYS[:4])})")
    width = _size(data.get("image_width", data.get("width")), "image width", origin)
    height = _size(data.get("image_height", data.get("height")), "image height", origin)
    return make_intrinsics(K, model, coefficients, width, height, origin)
