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


#: The principal point of a real camera lies near the image centre (KITTI 49 % / 49 %, TUM fr1 50 % / 53 %, EuRoC
#: 49 % / 52 % of width / height). Outside the middle 60 % of an axis the intrinsics are taken for another image
#: size (a refusal: half-resolution KITTI frames with the full-size intrinsics put it at 98 % / 99 %); outside
#: the middle 40 % of one axis only, for a crop or another size (a warning).
CENTRE_REFUSED = 0.6
CENTRE_WARNED = 0.4
#: Both axes off centre by one common factor (the frames resized, the intrinsics not): a refusal from this factor
#: on (its inverse for smaller frames; the principal point then at ≤ 42 % or ≥ 60 % of both axes), when the two
#: axes agree within `RESIZE_AGREEMENT`. Real cameras imply 0.94-1.02 (KITTI 1.02 / 1.01, TUM fr1 1.00 / 0.94).
RESIZED_FROM = 1.2
RESIZE_AGREEMENT = 0.05
#: Image size ratios `--calib-scale` is suggested for (frames resized by a common factor, within 3 %).
COMMON_SCALES = (1 / 8, 1 / 4, 1 / 3, 1 / 2, 2 / 3, 3 / 4, 4 / 3, 3 / 2, 2.0, 3.0, 4.0, 8.0)


def scale_calibration(camera: CameraIntrinsics, factor: float) -> CameraIntrinsics:
    """The calibration of the same camera for images resized by `factor` (``--calib-scale``): focal lengths times
    `factor`, the principal point ``(c + 0.5) · factor − 0.5`` (pixel centres at integers, the image's corner at
    −0.5 staying put), a stated size times `factor` (a `SourceError` when that is not whole pixels). The lens
    model works in normalised coordinates: its coefficients do not change."""
    width, height = camera.width * factor, camera.height * factor
    if abs(width - round(width)) > 1e-6 or abs(height - round(height)) > 1e-6:
        raise SourceError(f"--calib-scale {factor:g}: the calibration's {camera.width}x{camera.height} times "
                          f"{factor:g} is {width:g}x{height:g}, not whole pixels")
    origin = f"{camera.origin or 'the calibration'}, scaled x{factor:g} by --calib-scale"
    return CameraIntrinsics(camera.fx * factor, camera.fy * factor, (camera.cx + 0.5) * factor - 0.5,
                            (camera.cy + 0.5) * factor - 0.5, round(width), round(height), camera.model,
                            camera.coefficients, origin)


def exact_scale(frames: tuple[int, int], calibrated: tuple[int, int]) -> float | None:
    """The common factor frames (width, height) = factor × calibrated (width, height), or None when there is none
    (the two axes scaled differently, or a size unknown)."""
    if min(*frames, *calibrated) <= 0:
        return None
    factor = frames[0] / calibrated[0]
    return factor if abs(calibrated[1] * factor - frames[1]) < 1e-6 else None


def scale_hint(factor: float | None) -> str:
    """`` (--calib-scale F scales it, if the frames are resized copies of the calibrated camera's)`` for a
    factor, else ''."""
    return "" if factor is None else (f" (if the frames are resized copies of the calibrated camera's, "
                                      f"--calib-scale {factor:.6g} scales the calibration)")


def _implied_scale(camera: CameraIntrinsics) -> float | None:
    """The factor frames = factor × calibrated size that would put the principal point at the centre of both axes
    (``width / (2 (cx + 0.5))``, likewise down), when the two axes agree on it within `RESIZE_AGREEMENT`; else
    None."""
    if camera.cx <= -0.5 or camera.cy <= -0.5:
        return None
    across = camera.width / (2.0 * (camera.cx + 0.5))
    down = camera.height / (2.0 * (camera.cy + 0.5))
    if abs(across / down - 1.0) > RESIZE_AGREEMENT:
        return None
    return float(np.sqrt(across * down))


def _resize_hint(factor: float | None) -> str:
    """`scale_hint` for the nearest of `COMMON_SCALES` within 3 % of `factor`, else ''."""
    if factor is None:
        return ""
    common = min(COMMON_SCALES, key=lambda c: abs(np.log(factor / c)))
    return scale_hint(common) if abs(factor / common - 1.0) < 0.03 else ""


def _resized(factor: float | None) -> bool:
    return factor is not None and max(factor, 1.0 / factor) >= RESIZED_FROM


def _off_centre(camera: CameraIntrinsics, middle: float) -> bool:
    """The principal point lies outside the middle `middle` share of either axis."""
    low, high = (1.0 - middle) / 2.0, (1.0 + middle) / 2.0
    return not (low <= camera.cx / camera.width <= high and low <= camera.cy / camera.height <= high)


def _where(camera: CameraIntrinsics) -> str:
    return (f"the principal point ({camera.cx:g}, {camera.cy:g}) lies at {camera.cx / camera.width:.0%} / "
            f"{camera.cy / camera.height:.0%} of the {camera.width}x{camera.height} frames' width / height")


def principal_point_problem(camera: CameraIntrinsics) -> str | None:
    """A refusal in one line when the principal point lies outside the middle `CENTRE_REFUSED` of the frames, or
    both axes put it off centre by one resize factor of `RESIZED_FROM` or more (the intrinsics are for another
    image size, or for the frames turned); else None."""
    if camera.width <= 0 or camera.height <= 0:
        return None
    factor = _implied_scale(camera)
    where = f"(from {camera.origin or 'unknown'}){_resize_hint(factor)}"
    if _off_centre(camera, CENTRE_REFUSED):
        return (f"{_where(camera)}, outside their middle {CENTRE_REFUSED:.0%}: the intrinsics are not for frames of "
                f"this size {where}")
    if _resized(factor):
        assert factor is not None
        size = f"{round(camera.width / factor)}x{round(camera.height / factor)}"
        return (f"{_where(camera)}, not near their centre but where the centre of {size} frames is (both axes "
                f"agree): the intrinsics are not for frames of this size {where}")
    return None


def principal_point_warning(camera: CameraIntrinsics) -> str | None:
    """A warning in one line when the principal point lies outside the middle `CENTRE_WARNED` of the frames but is
    not refused (`principal_point_problem`: e.g. one axis off centre, a crop), else None."""
    if camera.width <= 0 or camera.height <= 0 or not _off_centre(camera, CENTRE_WARNED):
        return None
    if principal_point_problem(camera) is not None:
        return None  # refused instead
    return (f"{_where(camera)}, outside their middle {CENTRE_WARNED:.0%}: are the intrinsics for frames of this "
            f"size (a crop, or another resolution)?")
