"""Geometric verification of a loop candidate: the query keyframe's features matched to the candidate
keyframe's landmarks (upright ORB, mutual nearest with Lowe's ratio test), then PnP in RANSAC (P3P, Kneip et
al. 2011, refined on the inliers; vslam_core/mapping/pnp.py) in the candidate's camera frame. With unit scale
(--scale none) the scale between the two keyframes' maps is measured from the landmarks both see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam_core.config import LoopConfig
from vslam_core.features import match_descriptors
from vslam_core.geometry import invert_pose
from vslam_core.loop.places import KeyframePlace
from vslam_core.mapping.pnp import solve_pnp


@dataclass(frozen=True)
class Verification:
    """The outcome for one candidate. M matches."""

    query_pixels: np.ndarray  # (M, 2)
    candidate_pixels: np.ndarray  # (M, 2)
    inlier_mask: np.ndarray  # (M,) bool
    T_candidate_query: np.ndarray | None  # (4, 4)  # noqa: N815
    scale: float  # candidate map units per query map unit (1 with a metric scale)
    rejected: str | None  # why it failed, if it did

    @property
    def inliers(self) -> int:
        return int(self.inlier_mask.sum())


def verify(query: KeyframePlace, candidate: KeyframePlace, K: np.ndarray, config: LoopConfig,  # noqa: N803
           seed: tuple[int, ...], metric: bool) -> Verification:
    """PnP of the query's features against the candidate's landmarks, with the inlier checks of `config`."""
    query_index, train_index = match_descriptors(query.descriptors, candidate.point_descriptors, config.match_ratio)
    query_pixels = query.pixels[query_index].astype(np.float64).reshape(-1, 2)
    candidate_pixels = candidate.point_pixels[train_index].astype(np.float64).reshape(-1, 2)
    none = np.zeros(len(query_index), bool)
    if len(query_index) < config.min_inliers:
        return Verification(query_pixels, candidate_pixels, none, None, 1.0,
                            f"{len(query_index)} matches < {config.min_inliers}")
    solution = solve_pnp(candidate.points_cam[train_index], query_pixels, K, config.pnp_threshold_px,
                         config.pnp_iterations, seed)
    inliers = int(solution.inlier_mask.sum())
    if solution.T_world_cam is None or inliers < config.min_inliers:
        return Verification(query_pixels, candidate_pixels, solution.inlier_mask, None, 1.0,
                            f"{inliers} inliers < {config.min_inliers}")
    if inliers < config.min_inlier_ratio * len(query_index):
        return Verification(query_pixels, candidate_pixels, solution.inlier_mask, None, 1.0,
                            f"inlier ratio {inliers / len(query_index):.2f} < {config.min_inlier_ratio}")
    scale = 1.0 if metric else map_scale(query, candidate, solution.T_world_cam, config.match_ratio)
    return Verification(query_pixels, candidate_pixels, solution.inlier_mask, solution.T_world_cam, scale, None)


def map_scale(query: KeyframePlace, candidate: KeyframePlace, T_candidate_query: np.ndarray,  # noqa: N803
              ratio: float) -> float:
    """Candidate map units per query map unit: the median ratio of the distances from the query camera to
    landmarks matched between the two keyframes (candidate's seen through the PnP pose, query's own). 1 when
    fewer than 5 landmarks match."""
    query_index, train_index = match_descriptors(query.point_descriptors, candidate.point_descriptors, ratio)
    if len(query_index) < 5:
        return 1.0
    T_query_candidate = invert_pose(T_candidate_query)  # noqa: N806
    in_query = candidate.points_cam[train_index] @ T_query_candidate[:3, :3].T + T_query_candidate[:3, 3]
    own = np.linalg.norm(query.points_cam[query_index], axis=1)
    seen = np.linalg.norm(in_query, axis=1)
    valid = (own > 1e-6) & (in_query[:, 2] > 0)
    if valid.sum() < 5:
        return 1.0
    return float(np.median(seen[valid] / own[valid]))
