"""Localisation's second pass: the prior map's landmarks re-found by projection, then the pose refined on them.

Descriptor matching against every landmark in view (localisation.py) finds a first pose from the matches that
pass Lowe's ratio test. With that pose each landmark in view is projected into the frame and takes the frame
feature nearest in descriptor within `radius_px` of its projection (Hamming distance at most `max_hamming`;
each feature used once, by the landmark it matches best), as ORB-SLAM's tracking of the local map does (Mur-Artal
et al., "ORB-SLAM", T-RO 2015, sec. V-D). The pose is then refined by Levenberg–Marquardt on the reprojection
error of all those correspondences (cv2.solvePnPRefineLM: motion-only bundle adjustment), twice: the second
time on the correspondences within `threshold_px` after the first.
"""

from __future__ import annotations

import cv2
import numpy as np

from vslam_core.geometry import invert_pose, pose_matrix
from vslam_core.mapping.pnp import PnPSolution, project

RADIUS_PX = 6.0
MAX_HAMMING = 64  # of 256 bits
REFINE_ROUNDS = 2


def match_by_projection(projected: np.ndarray, landmark_descriptors: np.ndarray, pixels: np.ndarray,
                        descriptors: np.ndarray, radius_px: float = RADIUS_PX,
                        max_hamming: int = MAX_HAMMING) -> tuple[np.ndarray, np.ndarray]:
    """(M,) landmark and (M,) feature indices: each of the (L, 2) projected landmarks (NaN: not in view) with
    (L, 32) uint8 descriptors matched to the (F, 2) frame features with (F, 32) descriptors near it."""
    empty = np.zeros(0, np.int64)
    visible = np.flatnonzero(np.all(np.isfinite(projected), axis=1))
    if not len(visible) or not len(pixels):
        return empty, empty
    from scipy.spatial import cKDTree  # here: scipy takes ~0.5 s to import, and only map runs need it

    near = cKDTree(pixels).query_ball_point(projected[visible], radius_px)
    pairs = [(landmark, feature) for landmark, features in zip(visible.tolist(), near, strict=True)
             for feature in features]
    if not pairs:
        return empty, empty
    landmark_index, feature_index = (np.array(column, np.int64) for column in zip(*pairs, strict=True))
    distance = np.unpackbits(landmark_descriptors[landmark_index] ^ descriptors[feature_index], axis=1).sum(axis=1)
    good = distance <= max_hamming
    landmark_index, feature_index, distance = landmark_index[good], feature_index[good], distance[good]
    order = np.lexsort((feature_index, landmark_index, distance))  # best first; ties: lower indices
    used_landmarks: set[int] = set()
    used_features: set[int] = set()
    kept = []
    for n in order.tolist():
        landmark, feature = int(landmark_index[n]), int(feature_index[n])
        if landmark in used_landmarks or feature in used_features:
            continue
        used_landmarks.add(landmark)
        used_features.add(feature)
        kept.append(n)
    kept_index = np.array(sorted(kept, key=lambda n: int(landmark_index[n])), np.int64)
    return landmark_index[kept_index], feature_index[kept_index]


def refine_pose(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray,  # noqa: N803
                threshold_px: float) -> PnPSolution:
    """Levenberg–Marquardt on the reprojection error of (M, 3) world points at (M, 2) pixels from the initial
    pose, `REFINE_ROUNDS` times, each round on the correspondences within `threshold_px` of the pose before."""
    pose = T_world_cam
    inlier_mask = np.ones(len(points), bool)
    for _ in range(REFINE_ROUNDS):
        if inlier_mask.sum() < 6:
            return PnPSolution(None, inlier_mask, np.full((len(points), 2), np.nan))
        T_cam_world = invert_pose(pose)  # noqa: N806
        rvec, _ = cv2.Rodrigues(T_cam_world[:3, :3])
        rvec, tvec = cv2.solvePnPRefineLM(points[inlier_mask].astype(np.float64),
                                          pixels[inlier_mask].astype(np.float64), K, None, rvec,
                                          T_cam_world[:3, 3].reshape(3, 1).copy())
        rotation, _ = cv2.Rodrigues(rvec)
        pose = invert_pose(pose_matrix(rotation, tvec.reshape(3)))
        projected = project(points, pose, K)
        with np.errstate(invalid="ignore"):
            inlier_mask = np.linalg.norm(projected - pixels, axis=1) <= threshold_px
    if not np.all(np.isfinite(pose)):
        return PnPSolution(None, inlier_mask, np.full((len(points), 2), np.nan))
    return PnPSolution(pose, inlier_mask, project(points, pose, K))
