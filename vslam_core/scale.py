"""Where the length of each estimated translation comes from.

The essential matrix gives the direction of motion only. `gt` takes the length from ground truth, as the
published method does; `none` uses unit steps (a trajectory up to scale); `height` uses no ground truth:
the road plane under the camera, fitted to the frame's triangulated points, puts the camera h baselines
above the road, and the known camera height H makes the step H / h metres, filtered over time.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from vslam_core.config import EngineConfig, HeightScaleConfig, ScaleSource
from vslam_core.errors import ConfigError
from vslam_core.results import ScaleEstimate
from vslam_core.road import RoadPlane, fit_road_plane, road_region


@dataclass(frozen=True)
class TwoView:
    """What a scale source may use about one accepted motion, keyframe → current frame."""

    key_position: int
    cur_position: int
    points: np.ndarray  # (P, 3) triangulated inliers, current camera frame, in baselines (|t| = 1)
    pixels: np.ndarray  # (P, 2) their pixel positions in the current frame


_CAUCHY_RELATIVE = 0.1  # a speed 10 % off the trend gets half weight


class ScaleProvider(Protocol):
    name: ScaleSource

    def step_length(self, view: TwoView) -> tuple[float, ScaleEstimate | None]:
        """Length of the translation keyframe → current frame, and how it was found (height only)."""
        ...


class GroundTruthScale:
    """|t_gt(cur) − t_gt(key)|: the distance between the ground-truth positions of the two frames."""

    name: ScaleSource = "gt"

    def __init__(self, ground_truth: np.ndarray) -> None:
        self._positions = np.asarray(ground_truth)[:, :3, 3]

    def step_length(self, view: TwoView) -> tuple[float, ScaleEstimate | None]:
        return float(np.linalg.norm(self._positions[view.cur_position] - self._positions[view.key_position])), None


class UnitScale:
    """Every accepted step has length 1: the trajectory is known up to one global scale at best."""

    name: ScaleSource = "none"

    def step_length(self, view: TwoView) -> tuple[float, ScaleEstimate | None]:
        return 1.0, None


class HeightScale:
    """Step length from the known camera height over the fitted road plane, filtered over time.

    Each frame with a road plane measures a speed (metres per frame: H / h over the frames since the
    keyframe). The last `window` measured speeds give a robust linear trend (iteratively reweighted least
    squares with Cauchy weights: speed changes smoothly, a trend does not lag while the car accelerates,
    and a wrong plane barely moves it); the step used is the trend at this frame. A frame without a plane,
    or whose measurement lies more than `max_jump` from the trend, is flagged `held`: the trend carries it.
    One whose plane is used but doubtful (more than `doubtful_jump` from the trend, its normal over
    `doubtful_tilt_deg` from the recent planes': a ramp or a crest, or fewer than `doubtful_inliers` inliers) is
    flagged `doubtful`.
    RANSAC is seeded per frame, so the result is deterministic.
    """

    name: ScaleSource = "height"

    def __init__(self, camera_height: float, K: np.ndarray, config: HeightScaleConfig, seed: int) -> None:  # noqa: N803
        self.camera_height = camera_height
        self._K = K
        self._config = config
        self._seed = seed
        self._speeds: deque[tuple[int, float]] = deque(maxlen=config.window)  # (position, metres per frame)
        self._normals: deque[np.ndarray] = deque(maxlen=config.window)  # the recent planes' (3,) normals

    def trend(self, position: int) -> float | None:
        """Speed (metres per frame) the recent measurements give at `position`; None before the first."""
        if not self._speeds:
            return None
        positions = np.array([p for p, _ in self._speeds], float)
        speeds = np.array([v for _, v in self._speeds])
        if len(speeds) < 4:
            return float(np.median(speeds))
        x = positions - position
        design = np.column_stack((np.ones_like(x), x))
        weights = np.ones_like(speeds)
        for _ in range(5):
            sqrt_w = np.sqrt(weights)
            coefficients = np.linalg.lstsq(design * sqrt_w[:, None], speeds * sqrt_w, rcond=None)[0]
            fitted = design @ coefficients
            relative = (speeds - fitted) / np.maximum(np.abs(fitted), 1e-6)
            weights = 1.0 / (1.0 + (relative / _CAUCHY_RELATIVE) ** 2)
        if coefficients[0] <= 0.0:  # the line reached zero past its data (speeds that fell fast): their median
            return float(np.median(speeds))
        return float(coefficients[0])  # the line at `position` (x = 0)

    def step_length(self, view: TwoView) -> tuple[float, ScaleEstimate | None]:
        cfg = self._config
        frames = max(view.cur_position - view.key_position, 1)
        road = road_region(view.pixels, view.points, self._K, cfg)
        road_points, road_pixels = view.points[road], view.pixels[road]
        rng = np.random.default_rng((self._seed, view.cur_position))
        plane = fit_road_plane(road_points, cfg, rng)
        measured = self.camera_height / plane.height if plane is not None else None
        if measured is not None:
            self._speeds.append((view.cur_position, measured / frames))
        speed = self.trend(view.cur_position)
        step = speed * frames if speed is not None else 1.0  # nothing measured yet: a unit step, flagged
        held = measured is None or abs(measured / step - 1) > cfg.max_jump
        doubtful = measured is not None and plane is not None and not held and (
            abs(measured / step - 1) > cfg.doubtful_jump or self._tilted(plane)
            or int(plane.inliers.sum()) < cfg.doubtful_inliers)
        if plane is not None:
            self._normals.append(plane.normal)
        return step, ScaleEstimate(
            road_points=road_points[plane.inliers] * step if plane is not None else np.zeros((0, 3)),
            road_pixels=road_pixels[plane.inliers] if plane is not None else np.zeros((0, 2)),
            plane_normal=plane.normal if plane is not None else None,
            camera_height=plane.height * step if plane is not None else None,
            measured_step=measured,
            step=step,
            held=held,
            doubtful=bool(doubtful),
        )

    def _tilted(self, plane: RoadPlane | None) -> bool:
        """The plane's normal is over `doubtful_tilt_deg` from the median of the recent planes' (at least 3 of
        them): the road ahead bends away from the road under the car, and the height above it is not the car's."""
        if plane is None or len(self._normals) < 3:
            return False
        median = np.median(np.array(self._normals), axis=0)
        median /= np.linalg.norm(median)
        return bool(np.degrees(np.arccos(np.clip(plane.normal @ median, -1.0, 1.0))) > self._config.doubtful_tilt_deg)


def default_camera_height(source_height: float | None, config: EngineConfig) -> float:
    """The configured camera height, else the source's own; an error when neither is known."""
    if config.height.camera_height_m > 0:
        return config.height.camera_height_m
    if source_height is None:
        raise ConfigError("--scale height needs --camera-height METRES (this source has no default)")
    return source_height


def make_scale_provider(
    config: EngineConfig, ground_truth: np.ndarray | None, K: np.ndarray, source_height: float | None  # noqa: N803
) -> ScaleProvider:
    """The provider for a config's scale source; `gt` without ground truth is an error. `height` is never
    given the ground truth."""
    if config.scale == "gt":
        if ground_truth is None:
            raise ConfigError("--scale gt needs ground truth, and this source has none (use --scale height or none)")
        return GroundTruthScale(ground_truth)
    if config.scale == "height":
        return HeightScale(default_camera_height(source_height, config), K, config.height, config.pose.seed)
    return UnitScale()
