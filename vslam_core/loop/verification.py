"""Geometric verification of a loop candidate: the query keyframe's features matched to the candidate
keyframe's landmarks (upright ORB, mutual nearest with Lowe's ratio test), then PnP in RANSAC (P3P, Kneip et
al. 2011, refined on the inliers; vslam_core/mapping/pnp.py) in the candidate's camera frame. With unit scale
(--scale none) the scale between the two keyframes' maps is measured from the landmarks both see; a candidate
whose scale cannot be measured is rejected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam_core.config import LoopConfig
from vslam_core.features import match_descriptors
from vslam_core.geometry import invert_pose
from vslam_core.lens import undistort_pixels
from vslam_core.loop.places import KeyframePlace
from vslam_core.mapping.pnp import solve_pnp
from vslam_core.sources.base import CameraIntrinsics

#: A landmark matched between query and candidate measures the scale if its two positions are this close in
#: direction from the query camera.
SAME_RAY_DEG = 2.0
#: Landmarks on the same ray needed to measure a loop edge's scale (--scale none).
MIN_SCALE_LANDMARKS = 5


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


def verify(query: KeyframePlace, candidate: KeyframePlace, camera: CameraIntrinsics, config: LoopConfig,
           seed: tuple[int, ...], metric: bool) -> Verification:
    """PnP of the query's features against the candidate's landmarks, with the inlier checks of `config`. The
    query's features are raw pixels of its image: through a distorted lens they are undistorted for the PnP (the
    landmarks are in ideal pinhole geometry; a feature outside the lens's usable field is no match)."""
    query_index, train_index = match_descriptors(query.descriptors, candidate.point_descriptors, config.match_ratio)
    query_pixels = query.pixels[query_index].astype(np.float64).reshape(-1, 2)
    ideal_pixels = undistort_pixels(query_pixels, camera)
    usable = np.isfinite(ideal_pixels).all(axis=1)
    if not usable.all():
        query_index, train_index = query_index[usable], train_index[usable]
        query_pixels, ideal_pixels = query_pixels[usable], ideal_pixels[usable]
    candidate_pixels = candidate.point_pixels[train_index].astype(np.float64).reshape(-1, 2)
    none = np.zeros(len(query_index), bool)
    if len(query_index) < config.min_inliers:
        return Verification(query_pixels, candidate_pixels, none, None, 1.0,
                            f"{len(query_index)} matches < {config.min_inliers}")
    solution = solve_pnp(candidate.points_cam[train_index], ideal_pixels, camera.K, config.pnp_threshold_px,
                         config.pnp_iterations, seed)
    inliers = int(solution.inlier_mask.sum())
    if solution.T_world_cam is None or inliers < config.min_inliers:
        return Verification(query_pixels, candidate_pixels, solution.inlier_mask, None, 1.0,
                            f"{inliers} inliers < {config.min_inliers}")
    if inliers < config.min_inlier_ratio * len(query_index):
        return Verification(query_pixels, candidate_pixels, solution.inlier_mask, None, 1.0,
                            f"inlier ratio {inliers / len(query_index):.2f} < {config.min_inlier_ratio}")
    scale = 1.0 if metric else map_scale(query, candidate, solution.T_world_cam, config.match_ratio)
    if scale is None:
        return Verification(query_pixels, candidate_pixels, solution.inlier_mask, None, 1.0,
                            f"scale not measured: < {MIN_SCALE_LANDMARKS} shared landmarks on the same rays")
    return Verification(query_pixels, candidate_pixels, solution.inlier_mask, solution.T_world_cam, scale, None)


def map_scale(query: KeyframePlace, candidate: KeyframePlace, T_candidate_query: np.ndarray,  # noqa: N803
              ratio: float) -> float | None:
    """Candidate map units per query map unit, from landmarks matched between the two keyframes: the median
    ratio of their distances from the query camera (candidate's seen through the PnP pose, query's own), over
    the matches whose two positions lie on the same ray from the query camera (within `SAME_RAY_DEG`): a true
    match differs only in depth, by the scale, so the ray test drops wrong matches before the median (the 3-D
    counterpart of the scale of a Sim(3) loop edge; Strasdat et al., RSS 2010, sec. IV). None when fewer than
    `MIN_SCALE_LANDMARKS` pass: the loop edge's scale is then unknown, and a guessed 1 would pull the graph."""
    query_index, train_index = match_descriptors(query.point_descriptors, candidate.point_descriptors, ratio)
    T_query_candidate = invert_pose(T_candidate_query)  # noqa: N806
    seen = candidate.points_cam[train_index] @ T_query_candidate[:3, :3].T + T_query_candidate[:3, 3]
    own = query.points_cam[query_index]
    own_distance, seen_distance = np.linalg.norm(own, axis=1), np.linalg.norm(seen, axis=1)
    cosine = np.einsum("ij,ij->i", own, seen) / np.maximum(own_distance * seen_distance, 1e-12)
    same_ray = (own_distance > 1e-6) & (seen[:, 2] > 0) & (cosine > np.cos(np.radians(SAME_RAY_DEG)))
    if same_ray.sum() < MIN_SCALE_LANDMARKS:
        return None
    return float(np.median(seen_distance[same_ray] / own_distance[same_ray]))
