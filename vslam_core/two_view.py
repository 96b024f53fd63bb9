"""The two-view step: the motion between the keyframe and the current frame from matched points.

5-point essential matrix in RANSAC → its four candidate poses → chirality (the candidate with most
triangulated points in front of both cameras) → refinement on the inliers. Points are (N, 2) ideal pinhole
pixels; the translation is a unit vector (its length is the scale source's job). Pure computation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import (
    CandidatePose,
    chirality_check,
    in_front_mask,
    normalise_points,
    refine_relative_pose,
    relative_pose_covariance,
    robust_sampson_cost,
    rotation_angle,
    triangulate,
)
from vslam_core.results import Reason, TrackFate, elapsed_ms

# a prior within 0.5° of rotation and 5° of translation direction of RANSAC's pose lies in its basin of the cost
PRIOR_SAME_BASIN = (math.radians(0.5), math.radians(5.0))


@dataclass(frozen=True)
class Motion:
    """Outcome of the two-view step between keyframe and current frame."""

    essential: np.ndarray | None = None
    inlier_mask: np.ndarray | None = None  # over the used correspondences
    candidates: tuple[CandidatePose, ...] = ()
    chosen: int | None = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None  # unit
    in_front: np.ndarray | None = None  # over the used correspondences
    points_cur: np.ndarray | None = None  # (P, 3) in front, current frame, unit baseline
    pixels_cur: np.ndarray | None = None  # (P, 2) their pixel positions in the current frame
    derotated_parallax: float = 0.0  # median inlier parallax (px) left once the rotation is removed
    rotation_covariance: np.ndarray | None = None  # (3, 3) rad² of `rotation` (as R·exp([ω]ₓ)), refined only
    reason: Reason | None = None

    def fates(self) -> np.ndarray:
        """TrackFate of each used correspondence (needs `inlier_mask`)."""
        assert self.inlier_mask is not None
        inlier = np.where(self.in_front, TrackFate.INLIER, TrackFate.CHIRALITY_FAILED) \
            if self.in_front is not None else TrackFate.NOT_USED
        return np.where(self.inlier_mask, inlier, TrackFate.RANSAC_OUTLIER).astype(np.uint8)

    def close_chirality(self, ratio: float) -> bool:
        """The runner-up of the candidate poses has more than `ratio` of the winner's points in front: the
        chirality hardly tells them apart."""
        counts = sorted((c.in_front for c in self.candidates), reverse=True)
        return len(counts) > 1 and counts[1] > ratio * counts[0]


def two_view_motion(
    p_cur: np.ndarray, p_key: np.ndarray, K: np.ndarray, config: EngineConfig, order: np.ndarray,  # noqa: N803
    timings: dict[str, float], prior: tuple[np.ndarray, np.ndarray] | None = None,
) -> Motion:
    """Motion keyframe → current frame from (N, 2) matched ideal pixels: the essential matrix by the 5-point
    algorithm in RANSAC (Nistér 2004), its four candidate poses, the one with most points in front
    (chirality), refined on the robust Sampson error of the inliers.

    `order` (N,) is a permutation of the correspondences: OpenCV's RANSAC draws from a fixed RNG, so the input
    order is the seed. `timings` gets the stages' milliseconds (``essential``, ``chirality``). `prior` (R, unit t),
    e.g. the last step's motion, is a second starting point of the refinement (`_better_of`).
    """
    cfg = config.pose
    clock = time.perf_counter()
    essential, shuffled_mask = find_essential(p_cur[order], p_key[order], K, config)
    timings["essential"] = elapsed_ms(clock)
    clock = time.perf_counter()
    if essential is None or shuffled_mask is None:
        return Motion(reason=Reason.NO_ESSENTIAL)
    inlier_mask = np.zeros(len(p_cur), bool)
    inlier_mask[order] = shuffled_mask
    if inlier_mask.sum() < cfg.min_inliers:
        return Motion(essential=essential, inlier_mask=inlier_mask, reason=Reason.TOO_FEW_INLIERS)
    x_cur = normalise_points(p_cur, K)
    x_key = normalise_points(p_key, K)
    candidates, best = chirality_check(essential, x_cur[inlier_mask], x_key[inlier_mask],
                                       cfg.chirality_max_depth)
    if candidates[best].in_front < cfg.min_inliers:  # a step short for its scene's depth: let farther points vote
        candidates, best = chirality_check(essential, x_cur[inlier_mask], x_key[inlier_mask],
                                           cfg.chirality_far_depth)
    rotation, translation = candidates[best].rotation, candidates[best].translation
    if candidates[best].in_front < cfg.min_inliers:
        timings["chirality"] = elapsed_ms(clock)
        return Motion(essential=essential, inlier_mask=inlier_mask, candidates=tuple(candidates),
                       chosen=best, reason=Reason.CHIRALITY)
    covariance = None
    if cfg.refine:
        focal = 0.5 * (K[0, 0] + K[1, 1])
        rotation, translation = refine_relative_pose(
            rotation, translation, x_cur[inlier_mask], x_key[inlier_mask],
            robust_scale=cfg.ransac_threshold_px / focal,
        )
        if prior is not None:
            rotation, translation = _better_of(rotation, translation, prior, x_cur[inlier_mask], x_key[inlier_mask],
                                               cfg.ransac_threshold_px / focal)
        if cfg.rotation_covariance:
            covariance = relative_pose_covariance(rotation, translation, x_cur[inlier_mask], x_key[inlier_mask],
                                                  cfg.ransac_threshold_px / focal)
    derotated = derotated_parallax(rotation, p_cur[inlier_mask], p_key[inlier_mask], K)
    points = triangulate(rotation, translation, x_cur, x_key)
    # A track fails chirality only if it lands behind a camera; far points are fine, just not shown.
    in_front = in_front_mask(rotation, translation, points, np.inf)
    # The Sampson cost is blind to the sign of t: a refinement started from the prior can end reversed.
    flipped = -points  # the points of (R, -t): midpoints scale with t
    flipped_in_front = in_front_mask(rotation, -translation, flipped, np.inf)
    if (flipped_in_front & inlier_mask).sum() > (in_front & inlier_mask).sum():
        translation, points, in_front = -translation, flipped, flipped_in_front
    near = in_front_mask(rotation, translation, points, cfg.chirality_max_depth)
    timings["chirality"] = elapsed_ms(clock)
    return Motion(
        essential=essential,
        inlier_mask=inlier_mask,
        candidates=tuple(candidates),
        chosen=best,
        rotation=rotation,
        translation=translation,
        in_front=in_front,
        points_cur=points[inlier_mask & near],
        pixels_cur=p_cur[inlier_mask & near],
        derotated_parallax=derotated,
        rotation_covariance=covariance[:3, :3] if covariance is not None else None,
    )


def _better_of(rotation: np.ndarray, translation: np.ndarray, prior: tuple[np.ndarray, np.ndarray],
               x_cur: np.ndarray, x_key: np.ndarray, robust_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC's refined pose, or the prior (R, unit t) refined on the same inliers if it reaches a lower cost.

    Where the field of view is narrow and the motion turns, a rotation and a sideways translation move the
    image alike (the rotation–translation ambiguity, Daniilidis & Spetsakis 1997), and the robust Sampson cost
    has more than one minimum: RANSAC can settle in the wrong one (KITTI 05's turn through a 640x200 crop:
    2.2° too much rotation a frame, the car sliding 40° sideways). A prior as close as `PRIOR_SAME_BASIN` to
    RANSAC's pose refines to the same minimum (KITTI 00/05 0:300: always), so it is only refined when farther."""
    if rotation_angle(rotation.T @ prior[0]) <= PRIOR_SAME_BASIN[0] and \
            float(np.dot(translation, prior[1])) >= math.cos(PRIOR_SAME_BASIN[1]):
        return rotation, translation
    r_prior, t_prior = refine_relative_pose(prior[0], prior[1], x_cur, x_key, robust_scale=robust_scale)
    if robust_sampson_cost(r_prior, t_prior, x_cur, x_key, robust_scale) < \
            robust_sampson_cost(rotation, translation, x_cur, x_key, robust_scale):
        return r_prior, t_prior
    return rotation, translation


def find_essential(
    p_cur: np.ndarray, p_key: np.ndarray, K: np.ndarray, config: EngineConfig  # noqa: N803
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """cv2.findEssentialMat(p_cur, p_key) with the configured robust estimator. Returns (E (3, 3), inlier
    mask (N,) bool), or (None, None) when no model was found."""
    cfg = config.pose
    if len(p_cur) < 5:
        return None, None
    a = p_cur.astype(np.float64)
    b = p_key.astype(np.float64)
    if cfg.ransac_method == "magsac":
        params = cv2.UsacParams()
        params.confidence = cfg.ransac_probability
        params.threshold = cfg.ransac_threshold_px
        params.maxIterations = cfg.ransac_max_iterations
        params.randomGeneratorState = cfg.seed
        params.sampler = cv2.SAMPLING_UNIFORM
        params.score = cv2.SCORE_METHOD_MAGSAC
        params.loMethod = cv2.LOCAL_OPTIM_SIGMA
        params.loIterations = 10
        params.loSampleSize = 20
        params.final_polisher = cv2.MAGSAC
        params.final_polisher_iterations = 10
        params.isParallel = False
        essential, mask = cv2.findEssentialMat(a, b, K, K, np.zeros((1, 5)), np.zeros((1, 5)), params)
    else:
        essential, mask = cv2.findEssentialMat(
            a, b, K, method=cv2.RANSAC, prob=cfg.ransac_probability, threshold=cfg.ransac_threshold_px,
            maxIters=cfg.ransac_max_iterations,
        )
    if essential is None or mask is None or essential.shape[0] < 3 or not np.all(np.isfinite(essential[:3])):
        return None, None  # no model, or a degenerate one (OpenCV can return NaN for 5 collinear points)
    return essential[:3, :3], mask.reshape(-1).astype(bool)


class RotationChain:
    """The front end's two-view rotations chained frame by frame: each frame's rotation from its front-end
    keyframe times that keyframe's chained rotation, so any two frames of one chain have a relative rotation
    measured by essential matrices alone (all tracks, far points included) and never by the map. A frame
    whose rotation is not the front end's starts a new chain; frames before `forget_before` are dropped.

    Each link also carries its rotation's covariance (`Motion.rotation_covariance`, rad², as R·exp([ω]ₓ)),
    propagated to first order along the links (R_ac = R_ab·R_bc: Σ_ac = R_bcᵀ·Σ_ab·R_bc + Σ_bc), so that a
    prior between two frames is as loose as the steps between them were ambiguous."""

    def __init__(self) -> None:
        # run position -> (chain id, (3, 3) R_chain_cam, (3, 3) its covariance, the position it was measured from)
        self._chain: dict[int, tuple[int, np.ndarray, np.ndarray, int]] = {}

    def extend(self, position: int, key_position: int, R_key_cur: np.ndarray | None,  # noqa: N803
               covariance: np.ndarray | None = None) -> None:
        """Frame `position`'s rotation from the front end's keyframe at `key_position` and its (3, 3)
        covariance (None: not known, taken as exact); None: a new chain."""
        start = self._chain.get(key_position)
        if R_key_cur is None or start is None:
            self._chain[position] = (position, np.eye(3), np.zeros((3, 3)), -1)
        else:
            step = covariance if covariance is not None else np.zeros((3, 3))
            self._chain[position] = (start[0], start[1] @ R_key_cur, R_key_cur.T @ start[2] @ R_key_cur + step,
                                     key_position)

    def between(self, before: int, after: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(3, 3) R_before_after and its (3, 3) covariance if one chain links the two frames, else None. The
        covariance is that of the links from the last frame both were measured through (zero when that frame was
        forgotten: the prior's own sigma alone)."""
        first, second = self._chain.get(before), self._chain.get(after)
        if first is None or second is None or first[0] != second[0]:
            return None
        rotation = first[1].T @ second[1]
        common = self._common(before, after)
        if common is None:
            return rotation, np.zeros((3, 3))
        R_chain_common, covariance_common = self._chain[common][1:3]  # noqa: N806
        hops = []
        for R_chain_cam, covariance in (first[1:3], second[1:3]):  # noqa: N806
            R_common_cam = R_chain_common.T @ R_chain_cam  # noqa: N806
            hops.append(covariance - R_common_cam.T @ covariance_common @ R_common_cam)
        covariance = rotation.T @ hops[0] @ rotation + hops[1]
        return rotation, 0.5 * (covariance + covariance.T)

    def _common(self, before: int, after: int) -> int | None:
        """The latest frame both frames' rotations were measured through (None: forgotten)."""
        ancestors = set()
        position = before
        while position in self._chain:
            ancestors.add(position)
            position = self._chain[position][3]
        position = after
        while position in self._chain:
            if position in ancestors:
                return position
            position = self._chain[position][3]
        return None

    def forget_before(self, position: int) -> None:
        """Drop the frames before `position`, but not the one `position` was measured from (a later frame's
        rotation relative to `position` runs through it)."""
        parent = self._chain[position][3] if position in self._chain else -1
        for old in [p for p in self._chain if p < (parent if parent >= 0 else position)]:
            del self._chain[old]


def derotated_parallax(rotation: np.ndarray, p_cur: np.ndarray, p_key: np.ndarray, K: np.ndarray) -> float:  # noqa: N803
    """Median distance (px) between the (N, 2) keyframe points and the current points moved by the rotation
    alone (x_key ∝ K·R·K⁻¹·x_cur for X_key = R·X_cur + t at infinity): the parallax translation caused."""
    homogeneous = np.column_stack((p_cur, np.ones(len(p_cur))))
    moved = homogeneous @ (K @ rotation @ np.linalg.inv(K)).T
    predicted = moved[:, :2] / moved[:, 2:3]
    return float(np.median(np.linalg.norm(predicted - p_key, axis=1))) if len(p_cur) else 0.0
