"""Motion across frames too degraded to track normally (blurred, dark, washed out): dead reckoning through
a gap (both backends), so a turn taken while the camera was blind is not lost.

The engine's health checks refuse such frames for tracking and mapping, but the scene is still in them at
low spatial frequencies: with the contrast normalised and both images brought to the same blur, Shi–Tomasi
corners tracked by a large-window pyramidal KLT between consecutive frames give an essential matrix whose
rotation, refined on its inliers, is good to 0.05° a frame on average on KITTI at 5 % brightness and to
0.2–0.3° with σ = 6 px blur (a rare pair up to 3°), where the turn itself is 1–4° a frame; the direction of
the step is good to ~1.3° (dark) and ~4° (blurred; median). Images are (H, W) uint8 grey; the motion is
T_prev_cur = [R | t] with X_prev = R·X_cur + t, |t| = 1.
"""

from __future__ import annotations

import cv2
import numpy as np

from vslam_core.geometry import (
    chirality_check,
    invert_pose,
    normalise_points,
    pose_matrix,
    refine_relative_pose,
    rotation_angle,
)
from vslam_core.lens import undistort_pairs
from vslam_core.quality import sharpness
from vslam_core.scale import ScaleProvider, TwoView
from vslam_core.sources.base import CameraIntrinsics

_CORNERS = 400
_WINDOW_PX = 31
_LEVELS = 4
_MIN_INLIERS = 30
_SHARPNESS_RATIO = 2.0
_BLUR_SIGMAS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)


def _normalised(image: np.ndarray) -> np.ndarray:
    """The image with zero-mean, fixed-spread contrast (a dark frame's few grey levels stretched out)."""
    values = image.astype(np.float32)
    values = (values - values.mean()) / (values.std() + 1e-6) * 40.0 + 128.0
    return np.clip(values, 0, 255).astype(np.uint8)


def _matched_blur(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two images with the sharper one blurred (Gaussian, the least of `_BLUR_SIGMAS` that suffices) until it
    is no sharper than the other, when one is over `_SHARPNESS_RATIO` times as sharp: KLT compares patches, and
    a blurred frame and the sharp one after it differ at every corner (2.5-3.5° of rotation error on KITTI)."""
    sharp_a, sharp_b = sharpness(a), sharpness(b)
    if max(sharp_a, sharp_b) <= _SHARPNESS_RATIO * min(sharp_a, sharp_b):
        return a, b
    sharper, target = (a, sharp_b) if sharp_a > sharp_b else (b, sharp_a)
    for sigma in _BLUR_SIGMAS:
        blurred = cv2.GaussianBlur(sharper, (0, 0), sigma)
        if sharpness(blurred) <= target:
            break
    return (blurred, b) if sharp_a > sharp_b else (a, blurred)


def degraded_motion(previous: np.ndarray, current: np.ndarray,
                    camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray] | None:
    """(R (3, 3), unit t (3,)) from `previous` to `current`, or None when too few corners agree. The corners
    are tracked on the raw images; through a distorted lens their pixels are undistorted (vslam_core/lens.py)
    before the essential matrix."""
    a, b = _matched_blur(_normalised(previous), _normalised(current))
    corners = cv2.goodFeaturesToTrack(a, _CORNERS, 0.01, 15)
    if corners is None or len(corners) < _MIN_INLIERS:
        return None
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(a, b, corners, None, winSize=(_WINDOW_PX, _WINDOW_PX),
                                                  maxLevel=_LEVELS)
    ok = status.reshape(-1) == 1
    p_prev, p_cur = corners.reshape(-1, 2)[ok].astype(np.float64), tracked.reshape(-1, 2)[ok].astype(np.float64)
    p_prev, p_cur = undistort_pairs(p_prev, p_cur, camera)
    K = camera.K  # noqa: N806
    if len(p_cur) < _MIN_INLIERS:
        return None
    essential, mask = cv2.findEssentialMat(p_cur, p_prev, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    if essential is None or essential.shape != (3, 3) or not np.all(np.isfinite(essential)):
        return None
    inliers = mask.reshape(-1).astype(bool)
    if inliers.sum() < _MIN_INLIERS:
        return None
    x_cur, x_prev = normalise_points(p_cur[inliers], K), normalise_points(p_prev[inliers], K)
    candidates, best = chirality_check(essential, x_cur, x_prev)
    if candidates[best].in_front < _MIN_INLIERS:
        return None
    # robust Sampson refinement on the inliers, as for tracked frames (a 1 px Cauchy scale)
    return refine_relative_pose(candidates[best].rotation, candidates[best].translation, x_cur, x_prev,
                                1.0 / float(K[0, 0]))


# A motion measured across a dead-reckoned gap must agree in rotation with dead reckoning within the latter's
# drift (0.05-0.3° a frame on KITTI, above), and is never required to come closer than 2°.
_DRIFT_DEG_PER_FRAME = 0.3
_AGREEMENT_DEG = 2.0
# A dead-reckoned step whose rotation is this far from the step before it is taken for the rotation–translation
# ambiguity's other solution (blurred frames in a turn: KITTI 00 197 -> 198 through a strong lens, 1.6° of yaw
# the wrong way and the car sliding sideways, where it turned 2.6°), and the step before it is repeated. A car's
# turn rate changes by well under 1° from one frame to the next (KITTI 00's sharpest turn: 0.2°).
STEP_DISAGREEMENT_DEG = 1.5


def steady(motion: tuple[np.ndarray, np.ndarray], before: tuple[np.ndarray, np.ndarray] | None,
           max_deg: float = STEP_DISAGREEMENT_DEG) -> tuple[np.ndarray, np.ndarray]:
    """A dead-reckoned step (R (3, 3), unit t (3,)), or the step `before` it (e.g. the one into the frame it
    starts from) when their rotations differ by more than `max_deg`."""
    if before is None or np.degrees(rotation_angle(before[0].T @ motion[0])) <= max_deg:
        return motion
    return before


def unit_step(T_a: np.ndarray, T_b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:  # noqa: N803
    """(R, unit t) of the motion between two (4, 4) poses T_world_cam (T_a⁻¹·T_b); None without translation."""
    step = invert_pose(T_a) @ T_b
    length = float(np.linalg.norm(step[:3, 3]))
    return (step[:3, :3], step[:3, 3] / length) if length > 0 else None


class DeadReckoning:
    """Where dead reckoning continues from: the last pose given out and the last readable image (usable or
    degraded), and whether the frames since the keyframe were dead-reckoned (a gap)."""

    def __init__(self, camera: CameraIntrinsics, scale: ScaleProvider, enabled: bool = True) -> None:
        self._camera = camera
        self._scale = scale
        self.enabled = enabled
        self.T_world_cam = np.eye(4)  # the last frame's pose, measured, dead-reckoned or held
        self._image: np.ndarray | None = None
        self._position = -1
        self._before: tuple[int, np.ndarray] | None = None  # (position, T_world_cam) of the frame remembered before
        self.in_gap = False

    def remember(self, image: np.ndarray, T_world_cam: np.ndarray, position: int) -> None:  # noqa: N803
        """This readable frame's image and pose are where the next dead reckoning starts."""
        self._before = (self._position, self.T_world_cam)
        self.T_world_cam = T_world_cam.copy()
        self._image, self._position = image, position

    def reckon(self, image: np.ndarray, position: int) -> np.ndarray | None:
        """(4, 4) T_world_cam of the frame at run `position` from the last readable one: rotation and direction
        from the two images (`degraded_motion`, `steady` against the step before), step length from the scale
        source. None when disabled or when the images give no motion."""
        if not self.enabled or self._image is None:
            return None
        motion = degraded_motion(self._image, image, self._camera)
        if motion is None:
            return None
        before = None  # the step into the frame it starts from, when both are consecutive
        if self._before is not None and self._before[0] == self._position - 1 and position == self._position + 1:
            before = unit_step(self._before[1], self.T_world_cam)
        rotation, direction = steady(motion, before)
        empty = np.zeros((0, 3))
        step, _ = self._scale.step_length(TwoView(self._position, position, empty, empty[:, :2]))
        return self.T_world_cam @ pose_matrix(rotation, step * direction)


def agrees(R_world_measured: np.ndarray, T_world_reckoned: np.ndarray, frames: int) -> bool:  # noqa: N803
    """Whether a rotation measured over `frames` frames lies within dead reckoning's drift of the reckoned one."""
    angle = np.degrees(rotation_angle(R_world_measured.T @ T_world_reckoned[:3, :3]))
    return bool(angle <= max(_AGREEMENT_DEG, _DRIFT_DEG_PER_FRAME * frames))
