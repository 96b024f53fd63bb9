"""Camera pose from 2-D–3-D correspondences: PnP in RANSAC, refined on the inliers; and the pose a frame PnP
placed takes when a scale source gives its step's length (`metric_pose`).

Points: (L, 3) world landmarks and (L, 2) pixels. Poses are camera-to-world (4, 4).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.config import MapConfig
from vslam_core.geometry import invert_pose, pose_matrix, rotation_angle
from vslam_core.lens import distort_pixels
from vslam_core.results import LocalMapSearch, PnPEstimate, PnPFailure
from vslam_core.sources.base import CameraIntrinsics


@dataclass(frozen=True)
class PnPSolution:
    T_world_cam: np.ndarray | None  # (4, 4); None when no pose was found  # noqa: N815
    inlier_mask: np.ndarray  # (L,) bool, after refinement
    projected: np.ndarray  # (L, 2) the landmarks projected with the pose (NaN behind the camera or without one)


def project(points: np.ndarray, T_world_cam: np.ndarray, K: np.ndarray) -> np.ndarray:  # noqa: N803
    """(L, 2) pixels of (L, 3) world points seen from `T_world_cam`; NaN rows behind the camera."""
    T_cam_world = invert_pose(T_world_cam)  # noqa: N806
    camera = points @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        pixels = camera[:, :2] / camera[:, 2:3] * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
    pixels[camera[:, 2] <= 1e-6] = np.nan
    return np.asarray(pixels)


def solve_pnp(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, threshold_px: float, iterations: int,  # noqa: N803
              seed: tuple[int, ...]) -> PnPSolution:
    """P3P (Kneip et al. 2011) minimal solutions in RANSAC (cv2.solvePnPRansac), then Levenberg–Marquardt on
    the inliers' reprojection error (cv2.solvePnPRefineLM), then the inliers re-counted with the refined pose.
    `seed` fixes the sample order (OpenCV's RANSAC draws from a fixed generator, so the order is the seed)."""
    empty = PnPSolution(None, np.zeros(len(points), bool), np.full((len(points), 2), np.nan))
    if len(points) < 6:
        return empty
    order = np.random.default_rng(seed).permutation(len(points))
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points[order].astype(np.float64), pixels[order].astype(np.float64), K, None, iterationsCount=iterations,
        reprojectionError=threshold_px, confidence=0.999, flags=cv2.SOLVEPNP_P3P)
    if not ok or inliers is None or len(inliers) < 6:
        return empty
    chosen = order[inliers.reshape(-1)]
    rvec, tvec = cv2.solvePnPRefineLM(points[chosen].astype(np.float64), pixels[chosen].astype(np.float64), K, None,
                                      rvec, tvec)
    rotation, _ = cv2.Rodrigues(rvec)
    T_world_cam = invert_pose(pose_matrix(rotation, tvec.reshape(3)))  # noqa: N806
    if not np.all(np.isfinite(T_world_cam)):
        return empty
    projected = project(points, T_world_cam, K)
    with np.errstate(invalid="ignore"):
        inlier_mask = np.linalg.norm(projected - pixels, axis=1) <= threshold_px
    return PnPSolution(T_world_cam, inlier_mask, projected)


def check_pnp(solution: PnPSolution, pnp_motion: np.ndarray | None, T_key_cur: np.ndarray | None,  # noqa: N803
              predicted: Callable[[], np.ndarray | None],
              cfg: MapConfig) -> tuple[str | None, bool, PnPFailure | None]:
    """Why a PnP pose is not trusted, if it is not; whether it outvoted the two-view rotation; the failure.
    `pnp_motion`: (4, 4) PnP's pose relative to the front end's keyframe (None without a two-view pose),
    `T_key_cur` the two-view motion from it, `predicted` the motion model's pose (asked only when needed)."""
    inliers = int(solution.inlier_mask.sum())
    if solution.T_world_cam is None or inliers < cfg.pnp_min_inliers:
        return ("no PnP solution" if solution.T_world_cam is None else f"{inliers} inliers"), False, \
            PnPFailure.RANSAC
    ratio = inliers / len(solution.inlier_mask)
    low = ratio < cfg.pnp_min_inlier_ratio  # usable only when it agrees with the two-view direction
    if ratio < min(cfg.pnp_min_inlier_ratio, cfg.low_ratio_pnp_min_ratio) or (
            low and not _same_direction(pnp_motion, T_key_cur, cfg.low_ratio_direction_deg)):
        return f"inlier ratio {ratio:.2f}", False, PnPFailure.RANSAC
    if pnp_motion is not None and T_key_cur is not None:
        disagreement = np.degrees(rotation_angle(pnp_motion[:3, :3].T @ T_key_cur[:3, :3]))
        if disagreement > cfg.max_rotation_disagreement_deg:
            # two against one: PnP agreeing with the motion model outvotes a two-view rotation over a short
            # baseline (reversing, 1 frame from the keyframe: the essential matrix's rotation was 2-4° off)
            model = predicted()
            if model is None or np.degrees(rotation_angle(model[:3, :3].T @ solution.T_world_cam[:3, :3])) \
                    > cfg.max_rotation_disagreement_deg:
                return f"rotation {disagreement:.1f}° from the two-view motion", False, PnPFailure.DISAGREES
            return None, True, None
    return None, False, None


def _same_direction(pnp_motion: np.ndarray | None, T_key_cur: np.ndarray | None,  # noqa: N803
                    limit_deg: float) -> bool:
    """PnP's step from the keyframe and the two-view step point the same way, within `limit_deg` (a PnP pose
    on a low inlier ratio must agree with the images' own motion)."""
    if pnp_motion is None or T_key_cur is None:
        return False
    a, b = pnp_motion[:3, 3], T_key_cur[:3, 3]
    norms = float(np.linalg.norm(a) * np.linalg.norm(b))
    return norms > 0 and math.degrees(math.acos(float(np.clip(a @ b / norms, -1.0, 1.0)))) <= limit_deg


def metric_pose(pnp_pose: np.ndarray, two_view: np.ndarray | None, T_world_key: np.ndarray,  # noqa: N803
                step_length: float, agreement_deg: float) -> np.ndarray:
    """(4, 4) T_world_cam of a frame PnP placed, with a scale source (gt, height) giving `step_length`, the
    distance from the front end's keyframe (pose `T_world_key`). The front end's motion from that keyframe
    (`two_view`: T_world_key · T_key_cur, already at that length) when its rotation agrees with PnP's within
    `agreement_deg`: frame to frame it is far steadier than PnP against triangulated landmarks (KITTI 00 and 05:
    relative pose error from each frame to the next 1.5 cm and 0.040° against 2.5 cm and 0.065°), and it is
    chained from a pose the map placed. Otherwise (a two-view rotation 1-3° off over a short baseline, or none)
    PnP's pose with its step from the keyframe scaled to `step_length`: the map's scale never overrides the
    scale source."""
    if two_view is not None and np.degrees(rotation_angle(two_view[:3, :3].T @ pnp_pose[:3, :3])) <= agreement_deg:
        return two_view
    step = invert_pose(T_world_key) @ pnp_pose
    length = float(np.linalg.norm(step[:3, 3]))
    if length < 1e-9:
        return pnp_pose
    step[:3, 3] *= step_length / length
    return np.asarray(T_world_key @ step)


def at_raw_pixels(estimate: PnPEstimate | None, lens: CameraIntrinsics) -> PnPEstimate | None:
    """The estimate with its observed and projected pixels (ideal pinhole pixels inside the engine) on the raw
    image of `lens`, where overlays are drawn."""
    if estimate is None or not lens.distorted:
        return estimate
    return replace(estimate, observed=distort_pixels(estimate.observed, lens),
                   projected=distort_pixels(estimate.projected, lens))


def search_at_raw_pixels(search: LocalMapSearch | None, lens: CameraIntrinsics) -> LocalMapSearch | None:
    """The frame's local-map search with its pixels on the raw image of `lens`, where overlays are drawn."""
    if search is None or not lens.distorted:
        return search
    return replace(search, projected=distort_pixels(search.projected, lens),
                   found_pixels=distort_pixels(search.found_pixels, lens))
