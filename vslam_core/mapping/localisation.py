"""Localisation in a map saved by an earlier run (`vslam run SOURCE --map PATH`), the map left unchanged.

Per frame: upright ORB features (as the map's landmarks were described) → the prior map's landmarks that
should be in view from the predicted pose (the last pose, moved by the last motion; within `VIEW_RANGE_M`, in
front, inside the image) matched by descriptor (mutual nearest, Lowe's ratio) → PnP in RANSAC refined on the
inliers (vslam_core/mapping/pnp.py) in the map's frame (`MAP`); if too few matches pass the ratio test, the
landmarks in view are matched to the features near their projection from the predicted pose, then PnP again
(`MAP`). Without a prediction, or when both fail: the prior keyframes most alike by bag of words (vocabulary
built from the map's own features) give the landmarks to match (`RELOCALISED`). A pose far from the prediction
is rejected. The pose found is then refined on every landmark in view re-found by projection
(vslam_core/mapping/localisation_refine.py). A frame neither places keeps the last pose and is flagged held
(`LOST`).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.features import match_descriptors
from vslam_core.geometry import invert_pose
from vslam_core.lens import undistort_pixels
from vslam_core.loop.places import describe_image
from vslam_core.loop.vocabulary import BinaryVocabulary, similarity
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH
from vslam_core.mapping.localisation_refine import RADIUS_PX, match_by_projection, refine_pose
from vslam_core.mapping.pnp import at_raw_pixels, project, solve_pnp
from vslam_core.results import (
    FrameResult,
    FrameStatus,
    Health,
    MapFrame,
    PnPEstimate,
    Reason,
    TrackingMode,
    elapsed_ms,
)
from vslam_core.sources.base import CameraIntrinsics, Frame

if TYPE_CHECKING:
    from vslam_core.mapping.storage import StoredMap

FEATURES = 2000  # strongest FAST corners described per frame
VIEW_RANGE_M = 80.0  # landmarks farther than this from the predicted camera are not searched
PREDICTION_FRAMES = 5  # a prediction older than this many frames is not trusted: place recognition instead
PLACES_SEARCHED = 3  # most alike keyframes whose landmarks are matched when relocalising
MAX_JUMP_M = 2.0  # a pose this far (per frame since the last localised one) from the prediction is rejected
GUIDED_RADIUS_PX = 15.0  # search window about a landmark's projection from the predicted pose (constant velocity)


class MapLocalisation:
    """Localises each frame in a prior map (a `StoredMap`); the engine of `vslam run --map`."""

    def __init__(self, intrinsics: CameraIntrinsics, config: EngineConfig, prior: StoredMap) -> None:
        self.config = config
        self.prior = prior
        self._lens = intrinsics  # features are found on raw pixels; PnP and projections on ideal ones (lens.py)
        self._K = intrinsics.K
        self._size = (intrinsics.width, intrinsics.height)
        self._describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
        self._position = 0
        self._last_pose: np.ndarray | None = None
        self._motion = np.eye(4)
        self._since_localised = 10**9
        self.localised = 0
        documents = [prior.feature_descriptors[prior.feature_keyframes == k] for k in prior.keyframe_ids]
        documents = [d for d in documents if len(d)]
        self._vocabulary = (BinaryVocabulary.build(documents, config.loop.vocabulary_words, config.pose.seed)
                            if documents else None)
        self._words = (np.array([self._vocabulary.vector(prior.feature_descriptors[prior.feature_keyframes == k])
                                 for k in prior.keyframe_ids]) if self._vocabulary is not None else None)
        self._seen_by = {int(k): prior.observation_landmarks[prior.observation_keyframes == k]
                         for k in prior.keyframe_ids}
        self._row = {int(i): n for n, i in enumerate(prior.landmark_ids.tolist())}

    def close(self) -> None:
        pass

    def process(self, frame: Frame) -> FrameResult:
        clock = time.perf_counter()
        raw, descriptors = describe_image(frame.image, FEATURES, self.config.map.reloc_fast_threshold,
                                          self._describer)
        pixels = undistort_pixels(raw, self._lens)
        usable = np.isfinite(pixels).all(axis=1)  # outside a strong lens's usable field: no ideal pixel
        pixels, descriptors = pixels[usable], descriptors[usable]
        timings = {"describe": elapsed_ms(clock)}
        clock = time.perf_counter()
        estimate, mode = None, TrackingMode.LOST
        predicted = None
        if self._last_pose is not None and self._since_localised <= PREDICTION_FRAMES:
            predicted = self._last_pose @ np.linalg.matrix_power(self._motion, self._since_localised)
            in_view = self._in_view(predicted)
            estimate = self._checked(self._localise(pixels, descriptors, in_view, 0), predicted)
            if estimate is None or estimate.rejected is not None:
                estimate = self._checked(self._guided(pixels, descriptors, in_view, predicted,
                                                      self.config.map.pnp_min_inliers, 2), predicted)
            mode = TrackingMode.MAP
        if estimate is None or estimate.rejected is not None:
            estimate = self._checked(self._localise(pixels, descriptors, self._recognised(descriptors), 1), predicted)
            mode = TrackingMode.RELOCALISED
            if estimate is not None and estimate.rejected is not None and estimate.T_world_cam is not None:
                # too few inliers to trust alone: as many landmarks near their projection from it must agree
                estimate = self._checked(self._guided(pixels, descriptors, self._in_view(estimate.T_world_cam),
                                                      estimate.T_world_cam, self.config.map.reloc_min_inliers, 3),
                                         predicted)
        timings["pnp"] = elapsed_ms(clock)
        found = estimate is not None and estimate.rejected is None and estimate.T_world_cam is not None
        if found:
            assert estimate is not None and estimate.T_world_cam is not None
            estimate = self._refined(estimate, pixels, descriptors)
            assert estimate.T_world_cam is not None
            pose = estimate.T_world_cam
            if self._last_pose is not None and self._since_localised == 1:
                self._motion = invert_pose(self._last_pose) @ pose
            self._last_pose, self._since_localised = pose, 1
            self.localised += 1
        else:
            mode = TrackingMode.LOST
            pose = self._last_pose.copy() if self._last_pose is not None else np.eye(4)
            self._since_localised += 1
        result = self._result(frame, pose, found, mode, estimate, pixels, timings)
        self._position += 1
        return result

    def _checked(self, estimate: PnPEstimate | None, predicted: np.ndarray | None) -> PnPEstimate | None:
        """The estimate, rejected if it lands more than `MAX_JUMP_M` per frame since the last localised one
        away from the predicted pose (a PnP on wrong matches)."""
        if estimate is None or estimate.rejected is not None or estimate.T_world_cam is None or predicted is None:
            return estimate
        jump = float(np.linalg.norm(estimate.T_world_cam[:3, 3] - predicted[:3, 3]))
        if jump > MAX_JUMP_M * self._since_localised:
            return replace(estimate, rejected=f"{jump:.1f} m from the predicted pose")
        return estimate

    def _refined(self, estimate: PnPEstimate, pixels: np.ndarray, descriptors: np.ndarray) -> PnPEstimate:
        """The pose refined on every landmark in view re-found by projection (localisation_refine.py); the
        first estimate if that gives fewer inliers."""
        assert estimate.T_world_cam is not None
        rows, observed = self._by_projection(self._in_view(estimate.T_world_cam), estimate.T_world_cam, pixels,
                                             descriptors, RADIUS_PX)
        if len(rows) < self.config.map.pnp_min_inliers:
            return estimate
        solution = refine_pose(self.prior.landmark_positions[rows], observed, self._K, estimate.T_world_cam,
                               self.config.map.reloc_threshold_px)
        if solution.T_world_cam is None or solution.inlier_mask.sum() < estimate.inlier_mask.sum():
            return estimate
        return PnPEstimate(self.prior.landmark_ids[rows], observed, solution.projected, solution.inlier_mask,
                           solution.T_world_cam)

    def _by_projection(self, landmarks: np.ndarray, T_world_cam: np.ndarray, pixels: np.ndarray,  # noqa: N803
                       descriptors: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
        """The (M,) prior landmarks (indices, among `landmarks`) matched to a frame feature within `radius_px`
        of their projection from `T_world_cam` (localisation_refine.match_by_projection), and those features'
        (M, 2) ideal pixels."""
        which, feature = match_by_projection(project(self.prior.landmark_positions[landmarks], T_world_cam, self._K),
                                             self.prior.landmark_descriptors[landmarks], pixels, descriptors,
                                             radius_px)
        return landmarks[which], pixels[feature].astype(np.float64).reshape(-1, 2)

    def _guided(self, pixels: np.ndarray, descriptors: np.ndarray, in_view: np.ndarray, predicted: np.ndarray,
                needed: int, attempt: int) -> PnPEstimate | None:
        """PnP on the landmarks `in_view` of the `predicted` pose matched to the features near their projection
        (`GUIDED_RADIUS_PX`), with at least `needed` inliers: ORB-SLAM's tracking with the motion model
        (Mur-Artal et al. 2015, sec. V-B) where matching against every landmark in view leaves too few matches
        through Lowe's ratio test, and its check of a relocalisation by projection (sec. V-C) where a pose
        from bag of words has too few inliers to be trusted alone."""
        if len(in_view) < self.config.map.pnp_min_landmarks or not len(descriptors):
            return None
        rows, observed = self._by_projection(in_view, predicted, pixels, descriptors, GUIDED_RADIUS_PX)
        return self._solved(rows, observed, needed, attempt, " by projection")

    def _in_view(self, T_world_cam: np.ndarray) -> np.ndarray:  # noqa: N803
        """Indices of the prior landmarks in front of the camera, within range, projecting into the image."""
        positions = self.prior.landmark_positions
        centre = T_world_cam[:3, 3]
        near = np.flatnonzero(np.linalg.norm(positions - centre, axis=1) < VIEW_RANGE_M)
        projected = project(positions[near], T_world_cam, self._K)
        width, height = self._size
        with np.errstate(invalid="ignore"):
            inside = ((projected[:, 0] >= 0) & (projected[:, 0] < width) & (projected[:, 1] >= 0)
                      & (projected[:, 1] < height))
        return near[inside]

    def _recognised(self, descriptors: np.ndarray) -> np.ndarray:
        """Indices of the landmarks seen by the `PLACES_SEARCHED` prior keyframes most alike this frame, and of
        those in view of the most alike one."""
        if self._vocabulary is None or self._words is None or not len(descriptors):
            return np.zeros(0, np.int64)
        scores = similarity(self._vocabulary.vector(descriptors), self._words)
        best = np.argsort(-scores, kind="stable")[:PLACES_SEARCHED]
        ids = np.unique(np.concatenate([self._seen_by[int(self.prior.keyframe_ids[b])] for b in best]))
        seen = np.array([self._row[int(i)] for i in ids.tolist() if int(i) in self._row], np.int64)
        return np.union1d(seen, self._in_view(self.prior.poses[best[0]]))  # and all in view of the best one

    def _localise(self, pixels: np.ndarray, descriptors: np.ndarray, landmarks: np.ndarray,
                  attempt: int) -> PnPEstimate | None:
        """PnP of this frame's features matched to the given prior landmarks (indices), with the map
        backend's thresholds: its PnP inlier count when matching from the predicted pose (attempt 0, the pose
        then checked against the prediction), its relocalisation count otherwise. None when there is nothing
        to match."""
        cfg = self.config.map
        if len(landmarks) < cfg.pnp_min_landmarks or not len(descriptors):
            return None
        query, train = match_descriptors(descriptors, self.prior.landmark_descriptors[landmarks], cfg.reloc_ratio)
        needed = cfg.pnp_min_inliers if attempt == 0 else cfg.reloc_min_inliers  # with a prediction (checked)
        return self._solved(landmarks[train], pixels[query].astype(np.float64).reshape(-1, 2), needed, attempt, "")

    def _solved(self, rows: np.ndarray, observed: np.ndarray, needed: int, attempt: int, how: str) -> PnPEstimate:
        """PnP in RANSAC of the (M,) prior landmarks (indices) at the (M, 2) ideal pixels, rejected (saying
        why, `how` they were matched) with fewer than `needed` matches or inliers."""
        cfg = self.config.map
        ids = self.prior.landmark_ids[rows]
        if len(rows) < needed:
            return PnPEstimate(ids, observed, np.full_like(observed, np.nan), np.zeros(len(rows), bool), None,
                               f"{len(rows)} matches{how}")
        solution = solve_pnp(self.prior.landmark_positions[rows], observed, self._K, cfg.reloc_threshold_px,
                             cfg.reloc_iterations, (self.config.pose.seed, self._position, attempt))
        inliers = int(solution.inlier_mask.sum())
        rejected = None
        if solution.T_world_cam is None or inliers < needed:
            rejected = f"{inliers} inliers{how}"
        return PnPEstimate(ids, observed, solution.projected, solution.inlier_mask, solution.T_world_cam, rejected)

    def _result(self, frame: Frame, pose: np.ndarray, found: bool, mode: TrackingMode,
                estimate: PnPEstimate | None, pixels: np.ndarray, timings: dict[str, float]) -> FrameResult:
        empty2 = np.zeros((0, 2), np.float32)
        reason = None if found else Reason.TRACKING_LOST
        return FrameResult(
            position=self._position, index=frame.index, timestamp=frame.timestamp, T_world_cam=pose,
            status=FrameStatus.OK if found else FrameStatus.HELD, reason=reason, keyframe_position=self._position,
            image_shape=(int(frame.image.shape[0]), int(frame.image.shape[1])),
            track_ids=np.zeros(0, np.int64), track_prev=empty2, track_cur=empty2, track_age=np.zeros(0, np.int32),
            track_fate=np.zeros(0, np.uint8), new_corner_ids=np.zeros(0, np.int64), new_corners=empty2,
            live_tracks=0, essential=None, candidate_poses=(), chosen_candidate=None, T_key_cur=None,
            points_world=np.zeros((0, 3)), scale=None, parallax_px=0.0,
            health=Health.of(reason, [Reason.RELOCALISED] if found and mode == TrackingMode.RELOCALISED else []),
            timings_ms=timings,
            mapping=MapFrame(mode, 0, None, at_raw_pixels(estimate, self._lens)),
        )
