"""Camera calibrations: the model names of ROS, Kalibr and OpenCV, and a CameraInfo's fields, as one
`CameraIntrinsics` (pinhole K + lens distortion + where it came from)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import DISTORTION_COEFFICIENTS, CameraIntrinsics, DistortionModel

#: Every spelling of a distortion model we accept (lower case) → our model name.
MODEL_ALIASES: dict[str, DistortionModel] = {
    "": "none", "none": "none", "pinhole": "none",
    "plumb_bob": "plumb_bob", "radtan": "plumb_bob", "radial-tangential": "plumb_bob", "brown": "plumb_bob",
    "rational_polynomial": "rational_polynomial",
    "equidistant": "equidistant", "fisheye": "equidistant", "kannala_brandt": "equidistant",
    "kannala-brandt": "equidistant",
    "fov": "fov",
}


def distortion_model(name: str, where: str) -> DistortionModel:
    """Our name for a distortion model called `name` by ROS, Kalibr or OpenCV; `SourceError` if unknown."""
    model = MODEL_ALIASES.get(name.strip().lower())
    if model is None:
        known = ", ".join(sorted(k for k in MODEL_ALIASES if k))
        raise SourceError(f"{where}: unknown distortion model {name!r} (known: {known})")
    return model


def make_intrinsics(
    K: Sequence[float] | np.ndarray,  # noqa: N803
    model_name: str,
    coefficients: Sequence[float] | np.ndarray,
    width: int,
    height: int,
    origin: str,
) -> CameraIntrinsics:
    """`CameraIntrinsics` from a 3×3 K (9 numbers, row-major, or fx fy cx cy), a model name in any accepted
    spelling and its coefficients; checked (positive focal lengths, finite values, the model's coefficient
    count: plumb_bob's trailing zeros beyond k3, as ROS writes them, are dropped). `origin` names the file
    or topic, for the recording and for every error message."""
    values = np.asarray(K, np.float64).ravel()
    if len(values) == 9:
        fx, fy, cx, cy = values[0], values[4], values[2], values[5]
    elif len(values) == 4:
        fx, fy, cx, cy = values
    else:
        raise SourceError(f"{origin}: the camera matrix needs 9 numbers (or fx fy cx cy), got {len(values)}")
    if not np.all(np.isfinite(values)) or fx <= 0 or fy <= 0:
        raise SourceError(f"{origin}: the camera matrix has no valid focal length (fx={fx:g}, fy={fy:g}); is the "
                          "camera calibrated?")
    model = distortion_model(model_name, origin)
    coeffs = [float(c) for c in np.asarray(coefficients, np.float64).ravel()]
    if not all(np.isfinite(coeffs)):
        raise SourceError(f"{origin}: the distortion coefficients are not all finite")
    if model == "none" and any(coeffs):
        raise SourceError(f"{origin}: distortion model {model_name!r} with non-zero coefficients")
    if model == "none":
        coeffs = []
    elif model == "plumb_bob" and len(coeffs) > 5 and not any(coeffs[5:]):
        coeffs = coeffs[:5]
    elif model == "rational_polynomial" and len(coeffs) > 8 and not any(coeffs[8:]):
        coeffs = coeffs[:8]
    if len(coeffs) not in DISTORTION_COEFFICIENTS[model]:
        allowed = " or ".join(map(str, DISTORTION_COEFFICIENTS[model]))
        raise SourceError(f"{origin}: distortion model {model} needs {allowed} coefficients, got {len(coeffs)}")
    return CameraIntrinsics(float(fx), float(fy), float(cx), float(cy), int(width), int(height), model,
                            tuple(coeffs), origin)


def describe_calibration(camera: CameraIntrinsics) -> dict[str, str]:
    """The calibration as run properties (``calibration_*``), e.g. for the recording and `vslam inspect`."""
    return {
        "calibration_model": camera.model,
        "calibration_K": f"fx {camera.fx:g} fy {camera.fy:g} cx {camera.cx:g} cy {camera.cy:g}",
        "calibration_coefficients": " ".join(f"{c:.9g}" for c in camera.coefficients) or "-",
        "calibration_size": f"{camera.width}x{camera.height}",
        "calibration_origin": camera.origin or "-",
    }


def camera_line(camera: CameraIntrinsics) -> str:
    """The calibration and where it came from, in one line: ``fx 718.856 fy 718.856 cx 607.193 cy 185.216,
    1241x376, lens none, from seq/calib.txt (KITTI calib.txt)``."""
    lens = camera.model + (f" [{' '.join(f'{c:.6g}' for c in camera.coefficients)}]" if camera.distorted else "")
    return (f"fx {camera.fx:.6g} fy {camera.fy:.6g} cx {camera.cx:.6g} cy {camera.cy:.6g}, {camera.width}x"
            f"{camera.height}, lens {lens}, from {camera.origin or 'unknown'}")
