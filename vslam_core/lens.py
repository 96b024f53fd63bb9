"""Lens distortion: raw image pixels ↔ ideal pinhole pixels (pure computation, no I/O).

FAST and KLT run on the raw (distorted) image; the geometry (essential matrix, triangulation, PnP) works on
*ideal* pixels, the positions an undistorted pinhole camera with the same K would see. `undistort_pixels`
goes raw → ideal with OpenCV's iterative solvers under a tight termination criterion (the default 5
iterations leave pixel-level errors at the border of strong lenses); `distort_pixels` goes ideal → raw with
the closed-form models below, so the two cross-check each other.

Models (x, y: ideal normalised coordinates, r² = x² + y²; Brown–Conrady as in OpenCV's calib3d docs, and
the equidistant fisheye of Kannala & Brandt, "A generic camera model and calibration method for
conventional, wide-angle, and fish-eye lenses", PAMI 2006, eq. 6 with four terms):

- ``plumb_bob`` (k1 k2 p1 p2 [k3]) and ``rational_polynomial`` (k1 k2 p1 p2 k3 k4 k5 k6):
  x' = x·(1 + k1 r² + k2 r⁴ + k3 r⁶)/(1 + k4 r² + k5 r⁴ + k6 r⁶) + 2 p1 x y + p2 (r² + 2x²), and likewise y'.
- ``equidistant`` (k1 k2 k3 k4): θ = atan r, θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), x' = (θ_d / r)·x.
- ``fov`` (ω), Devernay & Faugeras, "Straight lines have to be straight", MVA 2001, eq. 13–14:
  r_d = atan(2 r tan(ω/2)) / ω, x' = (r_d / r)·x; inverted in closed form, r = tan(r_d ω) / (2 tan(ω/2)).

A strong lens is not invertible everywhere: near its border the model folds or the ray leaves the half
space in front of the camera. `valid_pixel_mask` marks the raw pixels whose undistortion is trustworthy
(it re-distorts onto itself and the ray is less than `MAX_RAY_ANGLE_DEG` off the axis); no corner is
detected and no track is kept outside it.
"""

from __future__ import annotations

import cv2
import numpy as np

from vslam_core.sources.base import CameraIntrinsics

#: Rays further off the optical axis than this are not used: their ideal pinhole pixels run off to infinity.
MAX_RAY_ANGLE_DEG = 75.0
#: A raw pixel whose undistortion re-distorts further than this from itself is outside the usable lens.
ROUND_TRIP_TOLERANCE_PX = 0.1
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)


def undistort_pixels(raw: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """(N, 2) raw image pixels → (N, 2) float64 ideal pixels of the pinhole K (same array values when the
    camera has no distortion)."""
    points = np.asarray(raw, np.float64).reshape(-1, 2)
    if not camera.distorted or len(points) == 0:
        return points.copy()
    K = camera.K  # noqa: N806
    coefficients = np.asarray(camera.coefficients, np.float64)
    if camera.model == "fov":
        return _undistort_fov(points, camera)
    if camera.model == "equidistant":
        ideal = cv2.fisheye.undistortPoints(points.reshape(-1, 1, 2), K, coefficients, R=np.eye(3), P=K,
                                            criteria=_CRITERIA)
    else:
        ideal = cv2.undistortPoints(points.reshape(-1, 1, 2), K, coefficients, R=None, P=K, criteria=_CRITERIA)
    return ideal.reshape(-1, 2)


def undistort_pairs(a: np.ndarray, b: np.ndarray, camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Matched (N, 2) raw pixels `a` and `b` → their float64 ideal pixels, without the pairs where either lies
    outside the lens's usable field (no ideal pixel); `a` and `b` themselves when the camera has no distortion."""
    if not camera.distorted:
        return a, b
    a, b = undistort_pixels(a, camera), undistort_pixels(b, camera)
    finite = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    return a[finite], b[finite]


def distort_normalised(xy: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """(N, 2) ideal normalised coordinates → (N, 2) distorted normalised coordinates (the models above)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if not camera.distorted:
        return xy.copy()
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    c = list(camera.coefficients)
    if camera.model == "fov":
        (omega,) = c
        r = np.sqrt(r2)
        factor = np.divide(np.arctan(2 * r * np.tan(omega / 2)) / omega, r, out=np.ones_like(r), where=r > 1e-12)
        return np.column_stack((x * factor, y * factor))
    if camera.model == "equidistant":
        k1, k2, k3, k4 = c
        r = np.sqrt(r2)
        theta = np.arctan(r)
        theta2 = theta * theta
        theta_d = theta * (1 + theta2 * (k1 + theta2 * (k2 + theta2 * (k3 + theta2 * k4))))
        factor = np.divide(theta_d, r, out=np.ones_like(r), where=r > 1e-12)
        return np.column_stack((x * factor, y * factor))
    c += [0.0] * (8 - len(c))
    k1, k2, p1, p2, k3, k4, k5, k6 = c
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack((xd, yd))


def _undistort_fov(raw: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """The FOV model's closed-form inverse; rays at or beyond 90° come out as NaN."""
    (omega,) = camera.coefficients
    focal = np.array([camera.fx, camera.fy])
    centre = np.array([camera.cx, camera.cy])
    xy = (raw - centre) / focal
    r_d = np.linalg.norm(xy, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(r_d * omega < np.pi / 2, np.tan(r_d * omega) / (2 * np.tan(omega / 2)), np.nan)
        factor = np.where(r_d > 1e-12, r / np.where(r_d > 1e-12, r_d, 1.0), omega / (2 * np.tan(omega / 2)))
    return xy * factor[:, None] * focal + centre


def distort_pixels(ideal: np.ndarray, camera: CameraIntrinsics) -> np.ndarray:
    """(N, 2) ideal pixels of the pinhole K → (N, 2) float64 raw image pixels."""
    ideal = np.asarray(ideal, np.float64).reshape(-1, 2)
    focal = np.array([camera.fx, camera.fy])
    centre = np.array([camera.cx, camera.cy])
    return distort_normalised((ideal - centre) / focal, camera) * focal + centre


def valid_pixel_mask(camera: CameraIntrinsics, step: int = 4) -> np.ndarray | None:
    """(H, W) uint8 mask (255 = usable) of the raw pixels whose undistortion is trustworthy, evaluated on a
    grid every `step` pixels; None when every pixel is usable (always for an undistorted camera)."""
    if not camera.distorted:
        return None
    ys, xs = np.mgrid[0:camera.height + step:step, 0:camera.width + step:step]
    grid = np.column_stack((xs.ravel(), ys.ravel())).astype(np.float64)
    ideal = undistort_pixels(grid, camera)
    normalised = (ideal - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    angle = np.degrees(np.arctan(np.linalg.norm(normalised, axis=1)))
    back = distort_pixels(ideal, camera)
    good = np.isfinite(ideal).all(axis=1) & (angle < MAX_RAY_ANGLE_DEG)
    good &= np.linalg.norm(back - grid, axis=1) < ROUND_TRIP_TOLERANCE_PX
    if good.all():
        return None
    coarse = good.reshape(xs.shape).astype(np.uint8) * 255
    # a coarse cell is usable only if all four of its grid corners are
    cell = cv2.erode(coarse, np.ones((2, 2), np.uint8), anchor=(0, 0))
    full = cv2.resize(cell, (xs.shape[1] * step, xs.shape[0] * step), interpolation=cv2.INTER_NEAREST)
    return np.ascontiguousarray(full[:camera.height, :camera.width])


def inside_mask(points: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """(N,) bool: which (N, 2) raw pixels lie on usable pixels of `mask` (all of them when mask is None)."""
    if mask is None:
        return np.ones(len(points), bool)
    height, width = mask.shape
    pixels = np.round(np.asarray(points, np.float64)).astype(np.int64)
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
    ok = np.zeros(len(points), bool)
    ok[inside] = mask[pixels[inside, 1], pixels[inside, 0]] > 0
    return ok


def undistortion_maps(camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) float32 x and y maps for ``cv2.remap``: where each pixel of the ideal pinhole image (same K and
    size) lies in the raw image. Remapping a raw frame with them gives the frame the 3-D view's pinhole sees."""
    ys, xs = np.mgrid[0:camera.height, 0:camera.width]
    raw = distort_pixels(np.column_stack((xs.ravel(), ys.ravel())), camera).astype(np.float32)
    return raw[:, 0].reshape(xs.shape), raw[:, 1].reshape(xs.shape)
