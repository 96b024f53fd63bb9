"""Tracking against the map: the `map` backend's per-frame step.

Per frame: KLT tracks and the 5-point motion from the keyframe (vslam_core/engine.py) → the landmarks linked
to surviving tracks (and, with `map.local_map_tracking`, landmarks re-found by projection: refinding.py) →
PnP in RANSAC refined on the inliers (`MAP`: with none its pose, in the map's own scale, map_scale.py; with
gt or height the front end's motion it confirmed, pnp.metric_pose); failing that, the local map searched by
projection (map_search.py; why it failed: `PnPEstimate.failure`) → else the two-view pose (`TWO_VIEW`; with none
its length from the tracks of the two frames before, map_scale.TwoViewLength) → tracks
lost: relocalisation against recent keyframes (`RELOCALISED`), failing that a new map segment. Tracks live on
raw pixels; PnP, landmarks and BA on ideal pinhole pixels (vslam_core/lens.py). A frame the health checks
refuse is dead-reckoned (`COASTED`, vslam_core/coasting.py); one nothing can place keeps the last pose (`LOST`).
Keyframes go to local mapping; the pending bundle adjustment and loop search are applied then (deterministic)."""

from __future__ import annotations

import time
from dataclasses import replace
from functools import partial

import numpy as np

from vslam_core.coasting import agrees, degraded_motion
from vslam_core.config import EngineConfig
from vslam_core.engine import Odometry
from vslam_core.geometry import interpolate_gaps, invert_pose, orthonormalise, pose_matrix
from vslam_core.lens import distort_pixels, undistort_pixels
from vslam_core.loop.closing import LoopClosing, rescale_relative
from vslam_core.mapping.global_adjustment import GlobalAdjusted, adjust_at_end
from vslam_core.mapping.local_map import LocalMapSearcher
from vslam_core.mapping.local_mapping import LocalMapping, reanchor
from vslam_core.mapping.map import NextKeyframeAnchors
from vslam_core.mapping.map_scale import (
    FramesBeforeMap,
    MapSpeed,
    TwoViewLength,
    for_scale,
    front_end_config,
    initialisation,
    initialised,
    landmark_settings,
    metric_step,
    place_attempts,
    pnp_pose,
    sideways_camera,
    slow_camera,
    translation_parallax,
)
from vslam_core.mapping.pnp import PnPSolution, at_raw_pixels, check_pnp, search_at_raw_pixels, solve_pnp
from vslam_core.mapping.refinding import MapRefinding, suspended_at_keyframe
from vslam_core.mapping.relocalisation import relocalise_by_descriptors
from vslam_core.mapping.worker_process import BackendWorker
from vslam_core.results import (
    BundleAdjusted,
    FrameResult,
    FrameStatus,
    Health,
    KeyframeInserted,
    LoopStep,
    MapFrame,
    PnPEstimate,
    PnPFailure,
    Reason,
    Relocalisation,
    TrackFate,
    TrackingMode,
    elapsed_ms,
)
from vslam_core.scale import ScaleProvider, TwoView
from vslam_core.sources.base import CameraIntrinsics, Frame
from vslam_core.two_view import RotationChain

UNUSABLE_IMAGE = {Reason.UNREADABLE_IMAGE, Reason.IMAGE_TOO_DARK, Reason.IMAGE_TOO_BRIGHT, Reason.IMAGE_BLURRED}
COAST_DISAGREEMENT_DEG = 1.5  # a dead-reckoned rotation this far from the motion model's is not trusted


class MapTracking:
    """Monocular SLAM over a stream of frames: tracking against a map of keyframes and landmarks."""

    def __init__(self, intrinsics: CameraIntrinsics, config: EngineConfig, scale: ScaleProvider) -> None:
        self._lens = intrinsics  # tracks are on raw pixels; the map's geometry on ideal ones (vslam_core/lens.py)
        self.config, self.settings, self._K = config, for_scale(config.map, config.scale), intrinsics.K
        # --scale none: steps the map cannot place take their length from the images (TwoViewLength) or the map's
        # speed, never unit steps
        self._speed = MapSpeed() if config.scale == "none" else None
        self._two_view_length = TwoViewLength(self._K, self._lens)
        self._slow = False  # --scale none: a slow camera (map_scale.slow_camera), its landmarks at a smaller angle
        self._scale: ScaleProvider = self._speed if self._speed is not None else scale
        # coasting is done here, with the map; BA and the loop search in one worker process beside (2 threads)
        self._odometry = Odometry(intrinsics, front_end_config(config, self.settings), self._scale, coast=False)
        self._worker = BackendWorker() if config.threads > 1 else None
        self.mapping = LocalMapping(intrinsics, self.settings, config.scale, self._worker)
        self._links: dict[int, int] = {}  # live track id -> landmark id
        self._suspended: dict[int, int] = {}  # tracks PnP rejected -> their landmark (observed at keyframes only)
        self._segment = 0
        self._reference = -1  # newest keyframe id
        self._relative: dict[int, tuple[int, np.ndarray]] = {}  # run position -> (keyframe id, T_key_frame)
        self._next_anchors = NextKeyframeAnchors()  # ... and to the keyframe after, for the output poses
        self._last_pose = np.eye(4)
        self._since_keyframe = 0
        self._gap = False  # unusable frames since the last one with a pose
        self._previous_image: np.ndarray | None = None  # the last frame's image, usable or not
        self._posed_position = -1  # run position of the last frame with a pose
        self._held: set[int] = set()  # run positions whose pose was held (no tracking, no relocalisation)
        self._segment_lost = False  # relocalisation failed: a new segment starts at the next frame with a pose
        self._initialised = False  # --scale none: the segment's map was started by a well-conditioned two-view
        self.before_map = FramesBeforeMap()  # --scale none: the frames tracked while it waits for that
        self.loop = LoopClosing(intrinsics, config, self._worker) if config.loop.enabled else None
        self.loops_at_end: list[LoopStep] = []  # what the loop searches collected when the run ended did
        self.adjusted_at_end: GlobalAdjusted | str | None = None  # the adjustment as the run completed, or why not
        # (run position, forward share): a camera moving sideways, --scale none's `settings` since (sideways_camera)
        self.sideways: tuple[int, float] | None = None
        self._refound: dict[int, np.ndarray] = {}  # landmark id -> ideal pixel: re-found, for a keyframe now
        self._chain = RotationChain()  # the front end's rotations, a prior between keyframes in BA
        self._step_length: str | None = None  # --scale none: where this two-view step's length came from
        self.refinding = MapRefinding(intrinsics, self.settings, LocalMapSearcher(intrinsics, self.settings),
                                      config.tracker)

    def close(self) -> None:
        if self._worker is not None:
            self._worker.close()

    def refined_poses(self, count: int, adjust: bool = False) -> list[np.ndarray]:
        """(4, 4) poses of the first `count` frames, each moved with its keyframe by every refinement since it was
        tracked (the pending adjustment first; with `adjust`, a run that completed, then `map.adjust_at_end`'s). A gap
        of held frames is filled by interpolating across it: once the motion across the gap is known, that is the
        best estimate of where the car was (the frames stay flagged in their results)."""
        if self.mapping.collect_bundle_adjustment() is not None:
            self._odometry.set_keyframe_pose(self.pose_of(self._odometry.key_position))
        if self.loop is not None:
            finished = self.loop.finish(self.mapping.map)
            self.loops_at_end += [step for step, _ in finished]
            for step, correction in finished:  # the last loop searches' loops, if any, move the keyframes too
                self._follow_loop(step, correction)
        if adjust and self.adjusted_at_end is None:
            self.adjusted_at_end = adjust_at_end(self.mapping.map, self._K, self.settings, self.config.scale)
        return interpolate_gaps([self._next_anchors.pose(self.mapping.map, p, self._relative.get(p), self.pose_of(p))
                                 for p in range(count)], self._held)

    def _follow_loop(self, step: LoopStep, correction: np.ndarray | None) -> None:
        """The loop `step` closed, if any (its (4, 4) correction of the newest keyframe given): with --scale none
        the frames stored relative to their keyframes and the map's speed follow the keyframes' new scales."""
        if correction is not None and step.closed is not None:
            rescale_relative(step.closed, self._relative, self._next_anchors.anchors)
            if self._speed is not None:
                self._speed.move(correction)

    def pose_of(self, position: int) -> np.ndarray:
        """(4, 4) pose of an earlier frame, moved with its keyframe by every refinement since."""
        entry = self._relative.get(position)
        keyframe = self.mapping.map.keyframes.get(entry[0]) if entry is not None else None
        return self._last_pose.copy() if entry is None or keyframe is None else keyframe.T_world_cam @ entry[1]

    def process(self, frame: Frame) -> FrameResult:
        self.refinding.start_frame(frame)
        self._refound = {}
        vo = self._odometry.process(frame)
        timings = vo.timings_ms
        if vo.status == FrameStatus.INIT:
            return self._finish(frame, vo, np.eye(4), TrackingMode.INIT, None, None, [], "initialisation")
        if vo.reason in UNUSABLE_IMAGE:
            coasted, self._gap = self._coast(frame.image, vo.position, checked=not self._gap), True
            return self._finish(frame, vo, coasted, TrackingMode.COASTED if coasted is not None else TrackingMode.LOST,
                                None, None, [Reason.COASTED] if coasted is not None else [], None)
        clock = time.perf_counter()
        two_view = self.pose_of(vo.keyframe_position) @ vo.T_key_cur if vo.T_key_cur is not None else None
        alive = vo.track_fate >= TrackFate.NOT_USED
        pnp = self._track_map(vo.position, vo.track_ids[alive], vo.track_cur[alive], two_view, vo)
        missing = self.refinding.frames_missing()  # the clock says frames are absent from the log
        lost_tracks = vo.reason == Reason.TOO_FEW_TRACKS or Reason.RECOVERED in vo.health.reasons or missing
        if (pnp is None or pnp.failure is not None) and not (lost_tracks or self._gap) and self._has_map():
            pnp = self._search_map(vo, two_view, pnp)
        timings["pnp"] = elapsed_ms(clock)
        warnings: list[Reason] = []
        relocalisation = None
        pose, mode, why = None, TrackingMode.LOST, None
        if pnp is not None and pnp.rejected is None and pnp.T_world_cam is not None:
            mode = TrackingMode.MAP  # --scale none (or height without a plane): PnP's pose, in the map's scale
            pose, flagged = pnp_pose(self.config, self.settings, vo, pnp, two_view, self.pose_of(vo.keyframe_position))
            warnings += flagged
        elif self._has_map() and (lost_tracks or self._gap):
            clock = time.perf_counter()
            relocalisation, found = self.refinding.relocalise(self.mapping.map, self._reference, self._segment,
                                                              (self.config.pose.seed, vo.position)) \
                if self.settings.local_map_tracking else (None, None)
            if found is not None:
                self._link_found(found)
            else:
                relocalisation, found = self.relocalise(frame.image, vo.position)
            timings["relocalise"] = elapsed_ms(clock)
            if found is not None:
                pnp, pose, mode, why = found, found.T_world_cam, TrackingMode.RELOCALISED, "relocalised"
                warnings.append(Reason.RELOCALISED)
        reckoned = None
        if pose is None and self._gap and two_view is not None:  # measured across the gap: it must agree, as in vo
            reckoned = self._coast(frame.image, vo.position)
            if reckoned is not None and not agrees(two_view[:3, :3], reckoned, vo.position - vo.keyframe_position):
                warnings.append(Reason.GAP_MOTION_REJECTED)
        if pose is None and two_view is not None and Reason.GAP_MOTION_REJECTED not in warnings:
            mode, ready = TrackingMode.TWO_VIEW, self._speed is not None and self._initialised
            pose, self._step_length = self._two_view_length.place(
                two_view, vo, pnp, self.mapping.map, self.pose_of, self._held, self.settings) \
                if ready else (two_view, "speed")
            if pnp is not None and self._has_map():
                warnings.append(Reason.PNP_REJECTED)
        if pose is None and (self._gap or missing):  # the first frame after a gap that nothing else could place
            pose = reckoned if reckoned is not None else \
                self._coast(frame.image, vo.position) if self._gap else self._bridge(vo.position)
            if pose is not None:
                mode = TrackingMode.COASTED
                warnings.append(Reason.COASTED)
        if (self.settings.local_map_tracking and pose is not None and mode in (TrackingMode.MAP, TrackingMode.TWO_VIEW)
                and self._has_map()):
            clock = time.perf_counter()
            refound = self.refinding.track(self.mapping, self._reference, self._segment, pose,
                                           set(self._links.values()) | set(self._suspended.values()))
            self._link_found(refound)
            error = np.linalg.norm(refound.observed - refound.projected, axis=1)  # off the pose: a keyframe
            close = (error <= self.settings.keyframe_observation_px) & ~refound.inlier_mask  # made now observes it
            self._refound = dict(zip(refound.landmark_ids[close].tolist(), refound.observed[close], strict=True))
            timings["local_map"] = elapsed_ms(clock)
        if relocalisation is not None:
            self._segment_lost = not relocalisation.success
            if self._segment_lost:
                self._links.clear()
                self._suspended.clear()
        if self._segment_lost and pose is not None:
            # the old map cannot be reached from here: a new one starts, at a frame that has a pose (a held
            # frame keeps trying to relocalise instead, and its stale pose never becomes a keyframe)
            self._segment += 1
            self._segment_lost, self._initialised = False, False
            warnings.append(Reason.NEW_MAP_SEGMENT)
            why = "new map segment"
        return self._finish(frame, vo, pose, mode, pnp, relocalisation, warnings, why, two_view)

    # -- tracking against the map ---------------------------------------------------------------------------

    def _has_map(self) -> bool:
        """The current segment has landmarks to track or relocalise against."""
        return self._reference >= 0 and any(
            self.mapping.map.keyframes[k].landmark_ids
            for k in (k.id for k in self.mapping.map.recent_keyframes(2, self._segment)))

    def _track_map(self, position: int, track_ids: np.ndarray, pixels: np.ndarray, two_view: np.ndarray | None,
                   vo: FrameResult) -> PnPEstimate | None:
        """PnP on the landmarks the (N,) tracks at (N, 2) pixels are linked to, with its checks; None before
        the map has landmarks. Outlier tracks lose their link."""
        cfg = self.settings
        landmarks = self.mapping.map.landmarks
        rows = [(n, self._links[t]) for n, t in enumerate(track_ids.tolist())
                if t in self._links and self._links[t] in landmarks]
        if not rows and not self._links:
            return None
        landmark_ids = np.array([landmark for _, landmark in rows], np.int64)
        observed = undistort_pixels(pixels[np.array([n for n, _ in rows], np.int64)], self._lens)
        if len(rows) < cfg.pnp_min_landmarks:
            return PnPEstimate(landmark_ids, observed, np.full_like(observed, np.nan), np.zeros(len(rows), bool),
                               None, f"only {len(rows)} landmarks tracked", failure=PnPFailure.TOO_FEW_MATCHED)
        solution = solve_pnp(self.mapping.map.positions(landmark_ids), observed, self._K, cfg.pnp_threshold_px,
                             cfg.pnp_iterations, (self.config.pose.seed, position))
        rejected, outvoted, failure = self._check_pnp(solution, two_view, vo)
        if rejected is None:
            self._unlink_outliers(landmark_ids, solution.inlier_mask)
        return PnPEstimate(landmark_ids, observed, solution.projected, solution.inlier_mask, solution.T_world_cam,
                           rejected, outvoted, failure)

    def _unlink_outliers(self, landmark_ids: np.ndarray, inlier_mask: np.ndarray) -> None:
        """Tracks linked to the (L,) landmarks PnP did not keep lose their link (suspended: local_map_tracking)."""
        outliers = set(landmark_ids[~inlier_mask[:len(landmark_ids)]].tolist())
        for track_id, landmark_id in [(t, m) for t, m in self._links.items() if m in outliers]:
            del self._links[track_id]
            if self.settings.local_map_tracking:
                self._suspended[track_id] = landmark_id

    def _search_map(self, vo: FrameResult, two_view: np.ndarray | None,
                    tracked: PnPEstimate | None) -> PnPEstimate | None:
        """PnP on the `tracked` landmarks failed: the local map searched by projection (map_search.py)."""
        predicted = two_view if two_view is not None else self.refinding.predicted_pose()
        if predicted is None or not self.settings.map_search:  # off: only the landmarks in view counted, if any tracked
            return self.refinding.in_view(self.mapping.map, self._reference, self._segment, predicted, tracked)
        ids, pixels = (tracked.landmark_ids, tracked.observed) if tracked else (np.zeros(0, np.int64), np.zeros((0, 2)))
        origin = self.pose_of(vo.keyframe_position) if two_view is not None else None
        estimate = self.refinding.search_map(self.mapping.map, self._reference, self._segment, predicted,
                                             self._last_pose, (ids, pixels), (self.config.pose.seed, vo.position, 2),
                                             lambda solution: self._check_pnp(solution, two_view, vo), origin)
        if estimate.failure is None:  # outliers unlinked; landmarks found and kept start tracks linked to them
            self._unlink_outliers(ids, estimate.inlier_mask)
            found = np.arange(len(estimate.landmark_ids)) >= len(ids)
            self._link_found(replace(estimate, inlier_mask=estimate.inlier_mask & found))
        return estimate

    def _link_found(self, found: PnPEstimate) -> None:
        """Start a track at each landmark re-found in this frame (PnP inliers when it has a pose) and link it,
        so the landmark is tracked on and observed by the next keyframe."""
        keep = found.inlier_mask
        raw = distort_pixels(found.observed[keep], self._lens) if self._lens.distorted else found.observed[keep]
        new_tracks = self._odometry.add_tracks(raw.astype(np.float32))
        self._links.update(zip(new_tracks.tolist(), found.landmark_ids[keep].tolist(), strict=True))

    def _check_pnp(self, solution: PnPSolution, two_view: np.ndarray | None,
                   vo: FrameResult) -> tuple[str | None, bool, PnPFailure | None]:
        """Why a PnP pose is not trusted, if it is not; whether it outvoted the two-view rotation; the failure."""
        motion = (invert_pose(self.pose_of(vo.keyframe_position)) @ solution.T_world_cam
                  if solution.T_world_cam is not None and two_view is not None else None)
        return check_pnp(solution, motion, vo.T_key_cur, self.refinding.predicted_pose, self.settings)

    def relocalise(self, image: np.ndarray, position: int) -> tuple[Relocalisation, PnPEstimate | None]:
        """Unguided relocalisation against the segment's recent keyframes (`relocalise_by_descriptors`). Returns
        the attempt and, on success, the estimate (its matched corners start tracks linked to their landmarks)."""
        attempt, found, raw = relocalise_by_descriptors(self.mapping.map, self._segment, image, self.mapping.describer,
                                                        self._lens, self.settings, (self.config.pose.seed, position, 1))
        if found is not None:
            new_tracks = self._odometry.add_tracks(raw)
            self._links.update(zip(new_tracks.tolist(), found.landmark_ids[found.inlier_mask].tolist(), strict=True))
        return attempt, found

    def _coast(self, image: np.ndarray, position: int, checked: bool = False) -> np.ndarray | None:
        """Dead reckoning from the previous frame: the rotation and direction the degraded images still give
        (vslam_core/coasting.py), the step length from the scale source; None if they give none. A rotation over
        `COAST_DISAGREEMENT_DEG` from the motion model's gives way to it: its prediction on a gap's first frame
        (`checked`: the model's last poses are measured ones), else the step before (`refinding.trusted_motion`)."""
        if self._previous_image is None or self._reference < 0:
            return None
        motion = degraded_motion(self._previous_image, image, self._lens)
        if motion is None:
            return None
        rotation, direction = self.refinding.trusted_motion(self._last_pose, *motion, COAST_DISAGREEMENT_DEG, checked)
        step, _ = self._scale.step_length(TwoView(position - 1, position, np.zeros((0, 3)), np.zeros((0, 2))))
        return self._last_pose @ pose_matrix(rotation, step * direction)

    def _bridge(self, position: int) -> np.ndarray | None:
        """Dead reckoning across frames missing from the log (refinding.bridge); with `--scale gt` the step from
        the last frame with a pose has the ground truth's length (other sources: the motion model's)."""
        known = self.config.scale == "gt" and self._posed_position >= 0
        empty = TwoView(self._posed_position, position, np.zeros((0, 3)), np.zeros((0, 2)))
        return self.refinding.bridge(self._scale.step_length(empty)[0] if known else None)

    # -- keyframes and the result ---------------------------------------------------------------------------

    def _keyframe_reason(self, vo: FrameResult, pnp: PnPEstimate | None,
                         pose: np.ndarray) -> tuple[str | None, np.ndarray]:
        """What makes this tracked frame a keyframe, if anything, and the pose to insert it at: its own, or with
        --scale none the one the map's initialisation measured from the last keyframe."""
        cfg = self.settings
        reference = self.mapping.map.keyframes[self._reference]
        alive = vo.track_fate >= TrackFate.NOT_USED
        _, in_reference, in_frame = np.intersect1d(reference.track_ids, vo.track_ids[alive], assume_unique=True,
                                                   return_indices=True)
        if self._speed is not None and not self._initialised:
            started = initialisation(replace(self.config, map=cfg), self._K, reference.T_world_cam, pose,
                                     undistort_pixels(vo.track_cur[alive][in_frame], self._lens),
                                     reference.pixels[in_reference],
                                     Reason.CLOSE_CHIRALITY in vo.health.reasons, vo.position - reference.position,
                                     not any(p in self._held for p in range(reference.position, vo.position)))
            if started is None:
                return None, pose
            why, pose, self._slow = started
            return why, pose
        if self._since_keyframe >= cfg.keyframe_max_frames:
            return f"{self._since_keyframe} frames", pose
        if (cfg.map_search or cfg.starving_keyframes) and pnp and \
                pnp.failure in (PnPFailure.TOO_FEW_IN_VIEW, PnPFailure.TOO_FEW_MATCHED):
            return f"map: {pnp.failure}", pose  # new landmarks while tracks overlap the last keyframe's
        if len(in_frame):
            pixels = undistort_pixels(vo.track_cur[alive][in_frame], self._lens)
            parallax = translation_parallax(reference.T_world_cam, pose, pixels, reference.pixels[in_reference],
                                            self._K)
            if parallax >= cfg.keyframe_parallax_px:
                return f"parallax {parallax:.0f} px", pose
        if pnp is not None and pnp.T_world_cam is not None and reference.landmark_ids:
            tracked = set(pnp.landmark_ids[pnp.inlier_mask].tolist())
            if len(tracked) < cfg.keyframe_min_landmarks:
                return f"{len(tracked)} landmarks tracked", pose
            overlap = len(tracked & reference.landmark_ids) / len(reference.landmark_ids)
            if overlap < cfg.keyframe_overlap:
                return f"overlap {overlap:.2f}", pose
        return None, pose

    def _finish(self, frame: Frame, vo: FrameResult, pose: np.ndarray | None, mode: TrackingMode,
                pnp: PnPEstimate | None, relocalisation: Relocalisation | None, warnings: list[Reason],
                why: str | None, two_view: np.ndarray | None = None) -> FrameResult:
        """Keyframe insertion when due, the pose stored relative to its keyframe, the front end re-anchored."""
        held = pose is None
        own = mode in (TrackingMode.MAP, TrackingMode.TWO_VIEW) and Reason.TWO_VIEW_OUTVOTED not in warnings
        self._chain.extend(vo.position, vo.keyframe_position,  # a rotation not the front end's starts a new chain
                           vo.T_key_cur[:3, :3] if not held and own and vo.T_key_cur is not None else None,
                           vo.rotation_covariance)
        reference = self.mapping.map.keyframes[self._reference].position if self._reference >= 0 else vo.position
        self._chain.forget_before(min(vo.keyframe_position, reference))
        if pose is None:
            pose = self._last_pose.copy()
            self._held.add(vo.position)
        else:
            pose = orthonormalise(pose)
            if mode != TrackingMode.COASTED or vo.reason not in UNUSABLE_IMAGE:
                self._gap = False
        self._since_keyframe += 1
        if not held and why is None and mode in (TrackingMode.MAP, TrackingMode.TWO_VIEW):
            why, pose = self._keyframe_reason(vo, pnp, pose)
        keyframe = view = None
        bundle: BundleAdjusted | None = None
        loop: LoopStep | None = None
        if why is not None:
            clock = time.perf_counter()
            collected = self.mapping.collect_bundle_adjustment()
            if collected is not None:
                bundle, correction = collected
                pose = orthonormalise(correction @ pose)
            if self.loop is not None and (looped := self.loop.collect(self.mapping.map)) is not None:
                loop, loop_correction = looped  # the previous keyframe's loop search, after its BA
                if loop_correction is not None:
                    pose = orthonormalise(loop_correction @ pose)  # a similarity with --scale none
                    self._follow_loop(loop, loop_correction)
            track_ids, raw = self._odometry.live_tracks()
            pixels = undistort_pixels(raw, self._lens)
            tied, relinked = suspended_at_keyframe(self.mapping.map, self._suspended, track_ids, pixels, pose, self._K,
                                                   self.settings)
            self._links.update(relinked)
            keyframe, links, view = self.mapping.insert_keyframe(
                vo.position, self._segment, pose, track_ids, pixels, frame.image,
                metric_step(self.config.scale, self._scale, self.mapping.map.keyframes.get(self._reference),
                            vo.position, pose, vo),
                why, {**self._links, **tied}, self._refound,
                landmark_settings(self.settings, self._slow, starving=why.startswith("map:")),
                self._chain.between(self.mapping.map.keyframes[self._reference].position, vo.position)
                if self._reference >= 0 else None, None if self._speed is None or self._initialised else
                partial(place_attempts, K=self._K, config=self.settings, seed=self.config.pose.seed))
            reanchor(self.mapping.culled, self._relative, self._next_anchors.anchors)  # (a culled keyframe's frames)
            live, landmarks = set(track_ids.tolist()), self.mapping.map.landmarks
            self._links = {t: m for t, m in {**self._links, **links}.items() if t in live and m in landmarks}
            self._suspended = {t: m for t, m in tied.items() if t not in self._links and m in landmarks}
            self._next_anchors.keyframe_made(self.mapping.map, self._reference, keyframe.keyframe_id)
            self._reference = keyframe.keyframe_id
            self._since_keyframe = 0
            self._start_map(keyframe, links)
            self._decide_motion(vo.position)
            if self._speed is not None and self._initialised:
                self._slow = slow_camera(self.mapping.map, keyframe.keyframe_id, self._speed.speed, self.settings)
            if self.loop is not None:
                self.loop.forget(list(self.mapping.culled))
                self.loop.submit(keyframe.keyframe_id, frame.image)
            vo.timings_ms["mapping"] = elapsed_ms(clock)
        if self._reference >= 0:
            self._relative[vo.position] = (self._reference,
                                           invert_pose(self.mapping.map.keyframes[self._reference].T_world_cam) @ pose)
        self._last_pose = pose
        self._posed_position = self._posed_position if held else vo.position
        if self._speed is not None and not held:
            step_fitted = (mode == TrackingMode.TWO_VIEW and self._step_length == "landmarks"
                           and self.settings.step_fit_speed)
            self._speed.observe(vo.position, pose, mode in (TrackingMode.MAP, TrackingMode.RELOCALISED) or step_fitted)
            if not self._initialised and keyframe is None:
                alive = vo.track_fate >= TrackFate.NOT_USED
                pixels = undistort_pixels(vo.track_cur[alive], self._lens)
                self.before_map.add(vo.position, vo.track_ids[alive], pixels, self.settings.pnp_min_landmarks)
        self._previous_image = frame.image
        self._two_view_length.remember(vo)
        self.refinding.end_frame(None if held else pose)
        if mode in (TrackingMode.COASTED, TrackingMode.RELOCALISED) and vo.reason not in UNUSABLE_IMAGE:
            self._odometry.rebase_keyframe()  # the front end measures the next frame from this one
        self._odometry.set_keyframe_pose(self.pose_of(self._odometry.key_position))
        search = search_at_raw_pixels(self.refinding.search, self._lens)
        return self._result(vo, pose, held, mode, warnings, two_view,
                            MapFrame(mode, self._segment, two_view, at_raw_pixels(pnp, self._lens), keyframe, bundle,
                                     relocalisation, view, loop, search,
                                     self.sideways[1] if self.sideways and self.sideways[0] == vo.position else None,
                                     self._step_length if mode == TrackingMode.TWO_VIEW and self._speed else None))

    def _decide_motion(self, position: int) -> None:
        """With a scale source, once the map has enough keyframes: a camera moving sideways takes --scale none's
        map settings from here on (`map_scale.sideways_camera`)."""
        if self.sideways is None and (share := sideways_camera(self.mapping.map, self.settings, self.config.scale)) \
                is not None and share <= self.settings.sideways_forward_share:
            self.sideways, self.settings = (position, share), for_scale(self.settings, "none")
            self.mapping.use_settings(self.settings)

    def _start_map(self, keyframe: KeyframeInserted, links: dict[int, int]) -> None:
        """--scale none: did this keyframe start the segment's map? Then the frames tracked since the segment's
        first keyframe (the attempts' too) are placed against its first landmarks (`FramesBeforeMap`)."""
        if self._initialised or not initialised(self.settings, keyframe):
            if not keyframe.why.startswith("initialisation"):  # an attempt's frames wait for the map's start
                self.before_map.clear()
            return
        self._initialised = True
        self._next_anchors.segment_started(self.mapping.map, self._segment)  # (attempts moved: `place_attempts`)
        self.before_map.place(links, self.mapping.map, self._relative, self._K, self.settings, self.config.pose.seed)

    def _result(self, vo: FrameResult, pose: np.ndarray, held: bool, mode: TrackingMode, warnings: list[Reason],
                two_view: np.ndarray | None, mapping: MapFrame) -> FrameResult:
        """The front end's result with the pose used, its health, and the map's part."""
        points_world = vo.points_world
        if two_view is not None and len(points_world):  # the front end's points, moved with the pose used
            moved = pose @ invert_pose(two_view)
            points_world = points_world @ moved[:3, :3].T + moved[:3, 3]
        placed = not held and mode != TrackingMode.COASTED  # else no pose of its own measured: flagged as held
        reason, health = Health.under_map(vo.reason, vo.health.reasons, placed, warnings)
        status = FrameStatus.HELD if not placed else FrameStatus.INIT if mode == TrackingMode.INIT else FrameStatus.OK
        return replace(vo, T_world_cam=pose, status=status, reason=reason, points_world=points_world, health=health,
                       mapping=mapping)
