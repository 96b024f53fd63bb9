"""Motion across frames too degraded to track normally (blurred, dark, washed out): the map backend's
dead reckoning through a gap, so a turn taken while the camera was blind is not lost.

The engine's health checks refuse such frames for tracking and mapping, but the scene is still in them at
low spatial frequencies: with the contrast normalised, Shi–Tomasi corners tracked by a large-window
pyramidal KLT between consecutive frames give an essential matrix whose rotation is good to ~0.1° per
frame on KITTI (σ = 6 px blur or 5 % brightness), where the turn itself is 1–4° per frame. Images are
(H, W) uint8 grey; the motion is T_prev_cur = [R | t] with X_prev = R·X_cur + t, |t| = 1.
"""

from __future__ import annotations

import cv2
import numpy as np

from vslam_core.geometry import chirality_check, normalise_points

_CORNERS = 400
_WINDOW_PX = 31
_LEVELS = 4
_MIN_INLIERS = 30


def _normalised(image: np.ndarray) -> np.ndarray:
    """The image with zero-mean, fixed-spread contrast (a dark frame's few grey levels stretched out)."""
    values = image.astype(np.float32)
    values = (values - values.mean()) / (values.std() + 1e-6) * 40.0 + 128.0
    return np.clip(values, 0, 255).astype(np.uint8)


def degraded_motion(previous: np.ndarray, current: np.ndarray, K: np.ndarray  # noqa: N803
                    ) -> tuple[np.ndarray, np.ndarray] | None:
    """(R (3, 3), unit t (3,)) from `previous` to `current`, or None when too few corners agree."""
    a, b = _normalised(previous), _normalised(current)
    corners = cv2.goodFeaturesToTrack(a, _CORNERS, 0.01, 15)
    if corners is None or len(corners) < _MIN_INLIERS:
        return None
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(a, b, corners, None, winSize=(_WINDOW_PX, _WINDOW_PX),
                                                  maxLevel=_LEVELS)
    ok = status.reshape(-1) == 1
    p_prev, p_cur = corners.reshape(-1, 2)[ok].astype(np.float64), tracked.reshape(-1, 2)[ok].astype(np.float64)
    if len(p_cur) < _MIN_INLIERS:
        return None
    essential, mask = cv2.findEssentialMat(p_cur, p_prev, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    if essential is None or essential.shape != (3, 3) or not np.all(np.isfinite(essential)):
        return None
    inliers = mask.reshape(-1).astype(bool)
    if inliers.sum() < _MIN_INLIERS:
        return None
    candidates, best = chirality_check(essential, normalise_points(p_cur[inliers], K),
                                       normalise_points(p_prev[inliers], K))
    if candidates[best].in_front < _MIN_INLIERS:
        return None
    return candidates[best].rotation, candidates[best].translation
