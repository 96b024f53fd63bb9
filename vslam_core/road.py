"""The road plane under the camera, from triangulated points (pure numpy; no ground truth).

Frames: current camera frame, x right, y down, z forward; a plane is nᵀ·X = h with a unit normal n
pointing down (n_y > 0) and h > 0 the camera's height above it, in the units of the points (the
two-view baseline, for the engine). Scale from a known camera height H is then H / h per baseline
(Kitt, Geiger & Lategahn 2010, "Visual odometry based on stereo image sequences with RANSAC-based
outlier rejection scheme"; the monocular variant is VISO2-M's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vslam_core.config import HeightScaleConfig
from vslam_core.errors import GeometryError


@dataclass(frozen=True)
class RoadPlane:
    """A plane nᵀ·X = height fitted to road points (current camera frame)."""

    normal: np.ndarray  # (3,) unit, pointing down (y > 0)
    height: float  # camera height above the plane, in the points' units
    inliers: np.ndarray  # (M,) bool over the points given to the fit

    @property
    def tilt_deg(self) -> float:
        """Angle between the normal and the camera's down axis."""
        return float(np.degrees(np.arccos(np.clip(self.normal[1], -1.0, 1.0))))


@dataclass(frozen=True)
class RoadBand:
    """Where the lane ahead appears in the image: `top` px and below, within `half_width` px of `centre_x`
    (the principal point's column), i.e. from `road_top_deg` below the optical axis down to the image bottom and
    `road_half_width_deg` either side of it (a pinhole: ``f · tan(angle)`` pixels)."""

    centre_x: float
    half_width: float
    top: float

    @classmethod
    def of(cls, K: np.ndarray, config: HeightScaleConfig) -> RoadBand:  # noqa: N803
        half_width = float(K[0, 0]) * math.tan(math.radians(config.road_half_width_deg))
        top = float(K[1, 2]) + float(K[1, 1]) * math.tan(math.radians(config.road_top_deg))
        return cls(float(K[0, 2]), half_width, top)

    def contains(self, pixels: np.ndarray) -> np.ndarray:
        """(N,) bool for (N, 2) pixel positions."""
        return np.asarray((pixels[:, 1] > self.top) & (np.abs(pixels[:, 0] - self.centre_x) < self.half_width))

    def rectangle(self, image_shape: tuple[int, int]) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) of the band in whole pixels, clipped to an (H, W) image."""
        height, width = image_shape
        return (int(max(self.centre_x - self.half_width, 0)), int(min(self.top, height)),
                int(min(self.centre_x + self.half_width, width)), height)


def road_region(pixels: np.ndarray, points: np.ndarray, K: np.ndarray, config: HeightScaleConfig) -> np.ndarray:  # noqa: N803
    """(N,) bool: points that may lie on the road in front of the car, from their (N, 2) pixel positions
    (inside the `RoadBand`: the lane ahead, under the horizon) and their (N, 3) positions (below the
    camera, in front of it)."""
    if pixels.shape != (len(points), 2) or points.shape[1:] != (3,):
        raise GeometryError(f"road_region: expected (N, 2) pixels and (N, 3) points, got {pixels.shape}, "
                            f"{points.shape}")
    with np.errstate(invalid="ignore"):
        return RoadBand.of(K, config).contains(pixels) & (points[:, 1] > 0) & (points[:, 2] > 0)


def fit_road_plane(points: np.ndarray, config: HeightScaleConfig, rng: np.random.Generator) -> RoadPlane | None:
    """RANSAC over 3-point planes whose normal is within `max_tilt_deg` of straight down and which pass
    below the camera; an inlier lies within `inlier_fraction` · h of the plane (relative, since the
    points' units are unknown). The winner is refit to its inliers by least squares (smallest singular
    vector). Returns None when fewer than `min_road_points` points or inliers support a plane."""
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise GeometryError(f"fit_road_plane: expected finite (N, 3) points, got shape {points.shape}")
    if len(points) < max(config.min_road_points, 3):
        return None
    min_down = np.cos(np.radians(config.max_tilt_deg))
    samples = rng.integers(0, len(points), size=(config.ransac_iterations, 3))
    a, b, c = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    ok = lengths > 1e-12
    normals[ok] /= lengths[ok, None]
    normals *= np.where(normals[:, 1:2] < 0, -1.0, 1.0)  # point down
    heights = np.einsum("ij,ij->i", normals, a)
    ok &= (normals[:, 1] >= min_down) & (heights > 0)
    if not ok.any():
        return None
    # (iterations, N) distances of every point to every hypothesis, relative to its height
    distances = np.abs(normals[ok] @ points.T - heights[ok, None])
    support = (distances < config.inlier_fraction * heights[ok, None]).sum(axis=1)
    best = int(np.argmax(support))
    inliers = distances[best] < config.inlier_fraction * heights[ok][best]
    if inliers.sum() < config.min_road_points:
        return None
    normal, height = _least_squares_plane(points[inliers])
    if normal[1] < min_down or height <= 0:
        return None
    final = np.abs(points @ normal - height) < config.inlier_fraction * height
    return RoadPlane(normal, float(height), final)


def _least_squares_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Total-least-squares plane through (M, 3) points: (unit normal pointing down, distance from origin)."""
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][2]
    if normal[1] < 0:
        normal = -normal
    return normal, float(normal @ centre)


def plane_homography(K: np.ndarray, rotation: np.ndarray, translation: np.ndarray, normal: np.ndarray,  # noqa: N803
                     height: float) -> np.ndarray:
    """(3, 3) H taking a pixel of the previous frame that lies on the plane nᵀ·X = height (previous camera
    frame) to its pixel in the current frame, for the motion X_prev = R·X_cur + t (`two_view`'s convention; t in
    the plane's units). From X_cur = Rᵀ·(X_prev − t) and nᵀ·X_prev / height = 1 on the plane:
    H = K·Rᵀ·(I − t·nᵀ / height)·K⁻¹ (Hartley & Zisserman 2004, result 13.1, the plane-induced homography)."""
    if height <= 0:
        raise GeometryError(f"plane_homography: the plane must lie below the camera (height {height})")
    return K @ rotation.T @ (np.eye(3) - np.outer(translation, normal) / height) @ np.linalg.inv(K)
