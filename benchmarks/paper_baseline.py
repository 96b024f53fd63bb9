"""The published method's configuration as a yardstick, written the straightforward way (mono-vo style)
but with correct pose chaining: FAST (threshold 20) → KLT 21x21, maxLevel 3 → findEssentialMat (RANSAC,
p 0.999, 1 px) → recoverPose → T_w_cur = T_w_prev · T_prev_cur with the ground-truth step length;
re-detect from scratch when fewer than 2000 tracks remain. Single-threaded.

Not part of the product: vslam's own engine lives in vslam_core. This is what it is measured against.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from vslam_core.sources.base import FrameSource

KLT_WINDOW = (21, 21)
KLT_MAX_LEVEL = 3
KLT_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)


@dataclass
class BaselineRun:
    poses: np.ndarray  # (N, 4, 4) T_w_c
    seconds: float
    stage_ms: dict[str, float] = field(default_factory=dict)  # total ms per stage


def _detect(image: np.ndarray) -> np.ndarray:
    keypoints = cv2.FastFeatureDetector_create(threshold=20, nonmaxSuppression=True).detect(image)
    return np.array([kp.pt for kp in keypoints], np.float32).reshape(-1, 2)


def _track(prev: np.ndarray, cur: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    moved, status, _ = cv2.calcOpticalFlowPyrLK(prev, cur, points.reshape(-1, 1, 2), None, winSize=KLT_WINDOW,
                                                maxLevel=KLT_MAX_LEVEL, criteria=KLT_CRITERIA)
    moved = moved.reshape(-1, 2)
    h, w = cur.shape
    ok = status.ravel().astype(bool) & (moved[:, 0] >= 0) & (moved[:, 1] >= 0) & (moved[:, 0] < w) & (moved[:, 1] < h)
    return points[ok], moved[ok]


def run_paper_configuration(source: FrameSource, seed: int = 0) -> BaselineRun:
    """One pose per frame of `source` (which must have ground truth). `seed` shuffles the correspondences
    before RANSAC (OpenCV's RANSAC draws from a fixed RNG, so the input order acts as its seed)."""
    cv2.setNumThreads(1)
    gt = source.ground_truth
    if gt is None:
        raise ValueError("the paper configuration takes its scale from ground truth")
    K = source.intrinsics.K  # noqa: N806
    stage = {"decode": 0.0, "detect": 0.0, "track": 0.0, "essential": 0.0, "chirality": 0.0}
    poses = [np.eye(4)]
    pose = np.eye(4)
    previous: np.ndarray | None = None
    points = np.zeros((0, 2), np.float32)
    start = time.perf_counter()
    iterator = iter(source)
    for position in range(len(source)):
        t = time.perf_counter()
        image = next(iterator).image
        stage["decode"] += time.perf_counter() - t
        if previous is None:
            t = time.perf_counter()
            points = _detect(image)
            stage["detect"] += time.perf_counter() - t
            previous = image
            continue
        t = time.perf_counter()
        p_prev, p_cur = _track(previous, image, points)
        stage["track"] += time.perf_counter() - t
        if len(p_cur) >= 5:
            t = time.perf_counter()
            order = np.random.default_rng((seed, position)).permutation(len(p_cur))
            E, mask = cv2.findEssentialMat(p_cur[order], p_prev[order], K, method=cv2.RANSAC, prob=0.999,  # noqa: N806
                                           threshold=1.0)
            stage["essential"] += time.perf_counter() - t
            t = time.perf_counter()
            if E is not None and E.shape == (3, 3):
                _, R, tvec, _ = cv2.recoverPose(E, p_cur[order], p_prev[order], K, mask=mask)  # noqa: N806
                scale = float(np.linalg.norm(gt[position, :3, 3] - gt[position - 1, :3, 3]))
                if scale > 0.1:
                    step = np.eye(4)
                    step[:3, :3] = R
                    step[:3, 3] = scale * tvec.ravel()
                    pose = pose @ step  # correct order: T_w_cur = T_w_prev · T_prev_cur
            stage["chirality"] += time.perf_counter() - t
        poses.append(pose.copy())
        points = p_cur
        if len(points) < 2000:
            t = time.perf_counter()
            points = _detect(image)
            stage["detect"] += time.perf_counter() - t
        previous = image
    seconds = time.perf_counter() - start
    return BaselineRun(np.array(poses), seconds, {k: 1000 * v for k, v in stage.items()})
