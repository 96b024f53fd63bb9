"""The odometry engine: one frame in, one `FrameResult` out (pure computation, no I/O, no Rerun).

Corners and tracks live on the raw image (`FrameResult.track_*` are raw pixels); with a distorted lens the
two-view geometry works on their ideal pinhole pixels (`vslam_core.lens`), so `pixels_cur` and the road
pixels of the scale estimate are ideal pixels too.

Per frame: KLT-track the live tracks (forward–backward checked) → 5-point essential matrix in RANSAC
between the keyframe and this frame → the four candidate poses and their chirality counts → (refined)
winner → scale → T_w_cur = T_w_key · T_key_cur → re-detect FAST corners where tracks are missing.
The keyframe is the last frame whose motion was accepted (an option, ``pose.keyframe_parallax_px``, off by
default: only with enough parallax once the rotation is removed; with less, the frame is placed but the next
one is measured from the same keyframe); a frame that cannot be trusted (too little parallax, too
few inliers, …) keeps the previous pose, and the next frame is measured from the keyframe with a longer
baseline. A frame too degraded to track (blurred, dark, washed out), or one whose tracks are lost, is
dead-reckoned from its contrast-normalised image (`vslam_core.coasting`, flagged `coasted`) rather
than held, so that a turn taken while the camera was blind is not lost.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.coasting import DeadReckoning, agrees
from vslam_core.config import EngineConfig
from vslam_core.features import detect_corners, fill_flow, grid_coverage, match_features, track_points
from vslam_core.geometry import (
    pose_matrix,
)
from vslam_core.lens import inside_mask, undistort_pixels, valid_pixel_mask
from vslam_core.quality import ImageStats, image_stats
from vslam_core.results import FrameResult, FrameStatus, Health, Reason, ScaleEstimate, TrackFate, elapsed_ms
from vslam_core.road import RoadBand, plane_homography
from vslam_core.scale import ScaleProvider, TwoView
from vslam_core.sources.base import CameraIntrinsics, Frame
from vslam_core.two_view import Motion, two_view_motion


@dataclass
class _Tracks:
    """Live tracks as parallel arrays (struct of arrays, N tracks)."""

    ids: np.ndarray  # (N,) int64
    points: np.ndarray  # (N, 2) float32, position in the last processed frame
    ages: np.ndarray  # (N,) int32
    key_points: np.ndarray  # (N, 2) float32, position in the keyframe; NaN if born after it
    flow: np.ndarray  # (N, 2) float32, motion over the last tracked step; NaN if born in the last frame

    @classmethod
    def empty(cls) -> _Tracks:
        return cls(np.zeros(0, np.int64), np.zeros((0, 2), np.float32), np.zeros(0, np.int32),
                   np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32))

    def __len__(self) -> int:
        return len(self.ids)


ROAD_PLANE_MAX_AGE = 10  # frames a road plane predicts the road's tracks for after it was found


class Odometry:
    """Monocular visual odometry over a stream of frames from one camera."""

    def __init__(self, intrinsics: CameraIntrinsics, config: EngineConfig, scale: ScaleProvider,
                 coast: bool = True) -> None:
        """coast: dead-reckon frames tracking cannot place (off under the map backend, which coasts itself)."""
        cv2.setNumThreads(config.threads)
        self.config = config
        self.intrinsics = intrinsics
        self._K = intrinsics.K
        self._usable = valid_pixel_mask(intrinsics)  # None: every raw pixel can be undistorted
        self._road_band = RoadBand.of(self._K, config.height)  # where --scale height looks for the road
        self._scale = scale
        self._tracks = _Tracks.empty()
        self._next_id = 0
        self._previous: np.ndarray | None = None  # last usable image
        # (position, R, unit t) of the last step measured from the frame before it
        self._last_motion: tuple[int, np.ndarray, np.ndarray] | None = None
        # (position, (3,) unit normal, camera height) of the last road plane found, and the last step's length
        self._last_plane: tuple[int, np.ndarray, float] | None = None
        self._last_step_length = 0.0
        self._held_steps = (-2, 0)  # the last frame whose step direction was held, and how many in a row before it
        self._previous_position = -1  # its run position
        self._position = 0
        self._key_position = 0
        self._T_w_key = np.eye(4)
        self._key_image: np.ndarray | None = None
        self._last_mean: float | None = None  # grey level of the last usable frame
        self._last_step: tuple[float, float] | None = None  # (step length, de-rotated parallax) last accepted
        # Dead reckoning through frames tracking cannot place (through the lens: on ideal pixels)
        self._reckoning = DeadReckoning(intrinsics, scale, enabled=coast)

    def process(self, frame: Frame) -> FrameResult:
        """Estimate this frame's pose from the previous ones."""
        cfg = self.config
        timings: dict[str, float] = {}
        image = frame.image
        stats = image_stats(image)
        unusable = self._unusable(frame, stats)
        if unusable is not None:
            return self._skip(frame, unusable)
        warnings = self._image_warnings(stats)
        tracks = self._tracks
        fate = np.full(len(tracks), TrackFate.LOST, np.uint8)
        tracked = tracks.points.copy()
        motion, parallax = Motion(), 0.0
        T_w_cur, T_key_cur, scale = self._T_w_key.copy(), None, None  # noqa: N806
        scale_estimate: ScaleEstimate | None = None
        points_world = np.zeros((0, 3))
        keyframe_used = self._key_position

        lost = False
        if self._previous is None:
            status = FrameStatus.INIT
        else:
            clock = time.perf_counter()
            # constant image velocity predicts where a track is now, unless unusable frames came between
            predicted = None
            if self._previous_position == self._position - 1:
                grid = (cfg.detector.grid_rows, cfg.detector.grid_cols)
                predicted = tracks.points + fill_flow(tracks.flow, tracks.points, image.shape, grid)
            tracked, ok, fb_error = track_points(self._previous, image, tracks.points, cfg.tracker, predicted)
            self._track_on_the_road(image, tracks.points, tracked, ok, fb_error)
            ok &= inside_mask(tracked, self._usable)  # a track entering a lens's unusable border ends there
            survived = ok & (fb_error <= cfg.tracker.fb_threshold_px)
            used = survived & ~np.isnan(tracks.key_points[:, 0])
            fate[ok & ~survived] = TrackFate.FB_REJECTED
            fate[survived] = TrackFate.NOT_USED  # until the two-view step classifies the used ones
            timings["track"] = elapsed_ms(clock)

            motion, parallax = self._estimate_motion(self._ideal(tracked[used]), self._ideal(tracks.key_points[used]),
                                                     timings)
            if motion.inlier_mask is not None:
                fate[used] = motion.fates()
            lost = motion.reason == Reason.TOO_FEW_TRACKS
            if lost and self._key_image is not None:
                # Tracks were lost (a gap of unusable frames, a sudden jump): match descriptors against the
                # keyframe instead, so the motion over the gap is measured rather than dropped.
                motion, parallax = self._match_keyframe(image, timings)
                if motion.reason is None:
                    warnings.append(Reason.RECOVERED)
                else:
                    motion = replace(motion, reason=Reason.TOO_FEW_TRACKS)
            # After a dead-reckoned gap the keyframe lies many frames back. A motion measured across the gap
            # (from the few tracks that survived it, or from descriptor matches) can be far off: it must agree
            # with dead reckoning, else tracking starts afresh here; a frame not measured is dead-reckoned and
            # the next one is measured from the keyframe again.
            in_gap = self._reckoning.in_gap
            coasted = self._reckoning.reckon(image, self._position) if lost or in_gap else None
            if coasted is not None and in_gap and motion.reason is None and motion.rotation is not None and not \
                    agrees(self._T_w_key[:3, :3] @ motion.rotation, coasted, self._position - self._key_position):
                motion = replace(motion, reason=Reason.GAP_MOTION_REJECTED)
                lost = True
            if motion.reason is None and motion.rotation is not None and motion.translation is not None:
                status = FrameStatus.OK
                motion = self._hold_reversed(motion, warnings)
                assert motion.rotation is not None and motion.translation is not None  # kept by the hold
                view = TwoView(self._key_position, self._position,
                               motion.points_cur if motion.points_cur is not None else np.zeros((0, 3)),
                               motion.pixels_cur if motion.pixels_cur is not None else np.zeros((0, 2)))
                scale, scale_estimate = self._scale.step_length(view)
                if scale_estimate is not None and scale_estimate.held:
                    warnings.append(Reason.SCALE_HELD)
                elif scale_estimate is not None and scale_estimate.doubtful:
                    warnings.append(Reason.ROAD_PLANE_DOUBTFUL)
                warnings += self._motion_warnings(motion, int(used.sum()), scale)
                T_key_cur = pose_matrix(motion.rotation, scale * motion.translation)  # noqa: N806
                self._last_motion = (self._position, motion.rotation, motion.translation) \
                    if self._key_position == self._position - 1 else None
                self._last_step_length = scale
                if scale_estimate is not None and scale_estimate.plane_normal is not None \
                        and scale_estimate.camera_height is not None:
                    self._last_plane = (self._position, scale_estimate.plane_normal, scale_estimate.camera_height)
                T_w_cur = self._T_w_key @ T_key_cur  # noqa: N806
                if motion.points_cur is not None:
                    points_world = (scale * motion.points_cur) @ T_w_cur[:3, :3].T + T_w_cur[:3, 3]
            else:
                status = FrameStatus.HELD
                T_w_cur = coasted if coasted is not None else self._held_pose()  # noqa: N806
                if coasted is not None:
                    warnings.append(Reason.COASTED)

            # Surviving tracks go on; RANSAC outliers (moving objects, bad tracks) are dropped.
            keep = fate >= TrackFate.NOT_USED
            if cfg.pose.drop_outliers:
                keep &= fate != TrackFate.RANSAC_OUTLIER
            self._tracks = _Tracks(tracks.ids[keep], tracked[keep], tracks.ages[keep] + 1, tracks.key_points[keep],
                                   tracked[keep] - tracks.points[keep])

        # The keyframe advances on every accepted frame that moved far enough from it (`_short_step`), and when
        # the tracks were lost (tracking starts afresh from this frame, with its pose measured by matching or,
        # failing that, held); other frames keep it, so the next frame is measured over a longer baseline.
        if (status != FrameStatus.HELD and not self._short_step(motion)) or lost:
            if lost:
                self._tracks = _Tracks.empty()
            self._reckoning.in_gap = False
            self._T_w_key = T_w_cur
            self._key_position = self._position
            self._key_image = image
            self._tracks.key_points = self._tracks.points.copy()

        new_ids, new_corners = self._replenish(image, timings)
        result = FrameResult(
            position=self._position,
            index=frame.index,
            timestamp=frame.timestamp,
            T_world_cam=T_w_cur,
            status=status,
            reason=motion.reason,
            keyframe_position=keyframe_used,
            image_shape=(int(image.shape[0]), int(image.shape[1])),
            track_ids=tracks.ids,
            track_prev=tracks.points,
            track_cur=tracked,
            track_age=tracks.ages + 1,
            track_fate=fate,
            new_corner_ids=new_ids,
            new_corners=new_corners,
            live_tracks=len(self._tracks),
            essential=motion.essential,
            candidate_poses=motion.candidates,
            chosen_candidate=motion.chosen,
            T_key_cur=T_key_cur,
            rotation_covariance=motion.rotation_covariance if T_key_cur is not None else None,
            points_world=points_world,
            scale=scale,
            scale_estimate=scale_estimate,
            parallax_px=parallax,
            health=Health.of(motion.reason, warnings),
            timings_ms=timings,
        )
        self._previous = image
        self._previous_position = self._position
        self._last_mean = stats.mean
        self._reckoning.remember(image, T_w_cur, self._position)
        self._position += 1
        return result

    def close(self) -> None:
        """Nothing to release (the map backend's engine has a worker process)."""

    # -- what the map backend (vslam_core/mapping/tracking.py) reads and sets between frames --------------

    @property
    def key_position(self) -> int:
        """Run position of the frame the next motion is measured from."""
        return self._key_position

    def set_keyframe_pose(self, T_world_key: np.ndarray) -> None:  # noqa: N803
        """Chain the next motions from this pose of the keyframe (the map's, refined)."""
        self._T_w_key = T_world_key.copy()

    def rebase_keyframe(self) -> None:
        """Measure the next motion from the last usable frame (its pose placed by the caller, e.g. by
        relocalisation), not from an older keyframe the tracks no longer reach."""
        if self._previous is None:
            return
        self._key_position = self._previous_position
        self._key_image = self._previous
        self._tracks.key_points = self._tracks.points.copy()

    def live_tracks(self) -> tuple[np.ndarray, np.ndarray]:
        """(N,) ids and (N, 2) float32 positions, in the last processed frame, of the tracks alive now."""
        return self._tracks.ids, self._tracks.points

    def add_tracks(self, points: np.ndarray) -> np.ndarray:
        """Start tracks at (K, 2) points of the last processed frame (e.g. relocalisation's matches).
        Returns their (K,) ids."""
        return self._append_tracks(points.astype(np.float32), at_keyframe=self._key_position == self._position - 1)

    def _append_tracks(self, points: np.ndarray, at_keyframe: bool) -> np.ndarray:
        """New tracks at (K, 2) float32 points; their keyframe position is known only at the keyframe."""
        tracks = self._tracks
        ids = np.arange(self._next_id, self._next_id + len(points), dtype=np.int64)
        self._next_id += len(points)
        self._tracks = _Tracks(
            np.concatenate((tracks.ids, ids)), np.concatenate((tracks.points, points)),
            np.concatenate((tracks.ages, np.ones(len(points), np.int32))),
            np.concatenate((tracks.key_points, points.copy() if at_keyframe else np.full_like(points, np.nan))),
            np.concatenate((tracks.flow, np.full_like(points, np.nan))),
        )
        return ids

    def _match_keyframe(self, image: np.ndarray, timings: dict[str, float]) -> tuple[Motion, float]:
        """Two-view motion keyframe → this frame from ORB descriptor matches (no tracks needed)."""
        assert self._key_image is not None
        clock = time.perf_counter()
        p_key, p_cur = match_features(self._key_image, image)
        keep = inside_mask(p_key, self._usable) & inside_mask(p_cur, self._usable)
        p_key, p_cur = self._ideal(p_key[keep]), self._ideal(p_cur[keep])
        timings["match"] = elapsed_ms(clock)
        if len(p_cur) < self.config.pose.min_tracks:
            return Motion(reason=Reason.TOO_FEW_TRACKS), 0.0
        parallax = float(np.median(np.linalg.norm(p_cur - p_key, axis=1)))
        order = np.random.default_rng((self.config.pose.seed, self._position)).permutation(len(p_cur))
        return two_view_motion(p_cur, p_key, self._K, self.config, order, timings), parallax

    def _ideal(self, raw: np.ndarray) -> np.ndarray:
        """(N, 2) raw image pixels as float32 ideal pinhole pixels (the lens's distortion removed)."""
        if not self.intrinsics.distorted:
            return raw
        return undistort_pixels(raw, self.intrinsics).astype(np.float32)

    def _unusable(self, frame: Frame, stats: ImageStats) -> Reason | None:
        """Why this frame's image cannot be tracked at all, if so."""
        cfg = self.config.health
        if frame.defect is not None:
            return Reason.UNREADABLE_IMAGE
        if stats.mean < cfg.dark_mean:
            return Reason.IMAGE_TOO_DARK
        if stats.saturated > cfg.bright_saturated:
            return Reason.IMAGE_TOO_BRIGHT
        if stats.sharpness < cfg.blur_sharpness:
            return Reason.IMAGE_BLURRED
        return None

    def _image_warnings(self, stats: ImageStats) -> list[Reason]:
        cfg = self.config.health
        warnings = []
        if stats.noise_sigma > cfg.noise_sigma:
            warnings.append(Reason.IMAGE_NOISY)
        if self._last_mean is not None and abs(stats.mean - self._last_mean) > cfg.brightness_jump:
            warnings.append(Reason.BRIGHTNESS_JUMP)
        return warnings

    def _hold_reversed(self, motion: Motion, warnings: list[Reason]) -> Motion:
        """The motion with its unit translation replaced by the motion model's (the last step's, measured from the
        frame before) when it points against it (cosine < 0; ``pose.hold_reversed_step``), with a `STEP_HELD`
        warning. At 10-30 Hz a true step never turns back between two frames; a low-parallax two-view step often
        does (rotation and translation confused, or a sign vote of noise). Not twice in a row: a real reversal
        (a car that stops and backs up) is taken one frame late (``pose.hold_reversed_frames``). Its points
        (triangulated along the rejected direction) are dropped. `vo` only: the map places its frames by PnP, and
        its fallbacks measured worse with the rule (fr1_desk, ground-truth scale, 3 seeds: 5.0 -> 6.3 cm ATE after
        Sim(3))."""
        last, (held_at, in_a_row) = self._last_motion, self._held_steps
        in_a_row = in_a_row if held_at == self._position - 1 else 0
        if (not self.config.pose.hold_reversed_step or self.config.backend != "vo" or last is None
                or motion.translation is None or not last[0] == self._position - 1 == self._key_position
                or in_a_row >= self.config.pose.hold_reversed_frames or float(motion.translation @ last[2]) >= 0.0):
            return motion
        self._held_steps = (self._position, in_a_row + 1)
        warnings.append(Reason.STEP_HELD)
        return replace(motion, translation=last[2].copy(), points_cur=np.zeros((0, 3)), pixels_cur=np.zeros((0, 2)))

    def _short_step(self, motion: Motion) -> bool:
        """An accepted step too short to be the next keyframe (``pose.keyframe_parallax_px``, `vo`): its pose is
        kept, and the next frame is measured from the same keyframe, over a longer baseline."""
        return self.config.backend == "vo" and motion.derotated_parallax < self.config.pose.keyframe_parallax_px

    def _motion_warnings(self, motion: Motion, used: int, step: float) -> list[Reason]:
        """Suspicious but accepted motion."""
        cfg = self.config.health
        warnings = []
        if used < cfg.warn_tracks:
            warnings.append(Reason.FEW_TRACKS)
        if motion.inlier_mask is not None and motion.inlier_mask.mean() < cfg.warn_inlier_ratio:
            warnings.append(Reason.LOW_INLIER_RATIO)
        if motion.close_chirality(cfg.ambiguous_chirality):
            warnings.append(Reason.CLOSE_CHIRALITY)
        if motion.derotated_parallax < cfg.rotation_parallax_px:
            warnings.append(Reason.ROTATION_DOMINATED)
        current = (step, motion.derotated_parallax)
        if self._last_step is not None and any(
            min(a, b) > 0 and max(a, b) / min(a, b) > cfg.step_jump
            for a, b in zip(current, self._last_step, strict=True)
        ):
            warnings.append(Reason.SCALE_JUMP)
        self._last_step = current
        return warnings

    def _skip(self, frame: Frame, reason: Reason) -> FrameResult:
        """A frame whose image cannot be used for tracking: no tracks, the next frame is tracked from the last
        usable image. Its pose is dead-reckoned from the degraded image if it is readable, else held."""
        readable = reason != Reason.UNREADABLE_IMAGE
        # dead reckoning continues a trajectory, it does not start one: not before the first usable frame
        coasted = self._reckoning.reckon(frame.image, self._position) if readable and self._previous is not None \
            else None
        pose = coasted if coasted is not None else self._held_pose()
        empty2 = np.zeros((0, 2), np.float32)
        result = FrameResult(
            position=self._position, index=frame.index, timestamp=frame.timestamp,
            T_world_cam=pose, status=FrameStatus.HELD, reason=reason,
            keyframe_position=self._key_position, image_shape=(int(frame.image.shape[0]), int(frame.image.shape[1])),
            track_ids=np.zeros(0, np.int64), track_prev=empty2, track_cur=empty2, track_age=np.zeros(0, np.int32),
            track_fate=np.zeros(0, np.uint8), new_corner_ids=np.zeros(0, np.int64), new_corners=empty2,
            live_tracks=len(self._tracks), essential=None, candidate_poses=(), chosen_candidate=None,
            T_key_cur=None, points_world=np.zeros((0, 3)), scale=None, parallax_px=0.0,
            health=Health.of(reason, [Reason.COASTED] if coasted is not None else []),
        )
        self._reckoning.in_gap |= coasted is not None
        if readable:
            self._reckoning.remember(frame.image, pose, self._position)
        self._position += 1
        return result

    def _held_pose(self) -> np.ndarray:
        """(4, 4) pose of a frame nothing places: the last dead-reckoned one in a gap, else the keyframe's."""
        return (self._reckoning.T_world_cam if self._reckoning.in_gap else self._T_w_key).copy()

    def _estimate_motion(
        self, p_cur: np.ndarray, p_key: np.ndarray, timings: dict[str, float]
    ) -> tuple[Motion, float]:
        """Motion keyframe → current frame from (N, 2) matched points, and the median parallax (px)."""
        cfg = self.config.pose
        if len(p_cur) < cfg.min_tracks:
            return Motion(reason=Reason.TOO_FEW_TRACKS), 0.0
        parallax = float(np.median(np.linalg.norm(p_cur - p_key, axis=1)))
        if parallax < cfg.stationary_px:
            return Motion(reason=Reason.STATIONARY), parallax
        if parallax < cfg.min_parallax_px:
            return Motion(reason=Reason.LOW_PARALLAX), parallax
        order = np.random.default_rng((self.config.pose.seed, self._position)).permutation(len(p_cur))
        # constant velocity: the last step's motion, when it was measured from the frame before it
        last = self._last_motion
        prior = last[1:] if last is not None and last[0] == self._position - 1 == self._key_position else None
        return two_view_motion(p_cur, p_key, self._K, self.config, order, timings, prior), parallax

    def _track_on_the_road(self, image: np.ndarray, points: np.ndarray, tracked: np.ndarray, ok: np.ndarray,
                           fb_error: np.ndarray) -> None:
        """With --scale height: the road band's tracks that KLT lost or the forward–backward check rejected are
        tracked again, in place, from the previous frame warped by the homography of the last road plane (found
        at most `ROAD_PLANE_MAX_AGE` frames ago) under the last step's motion (constant velocity; pinhole cameras
        only). At every 3rd KITTI frame the lane's texture grows 30–130 % between frames (the warp's magnification
        in the band), which a translation-only window does not follow. A track that passed is left alone (warping
        them all cost accuracy at every frame, docs/matrix.md)."""
        plane, last = self._last_plane, self._last_motion
        if plane is None or last is None or self._previous is None or self.intrinsics.distorted:
            return
        if self._position - plane[0] > ROAD_PLANE_MAX_AGE or last[0] != self._position - 1 \
                or self._previous_position != self._position - 1 or self._last_step_length <= 0 or plane[2] <= 0:
            return
        threshold = self.config.tracker.fb_threshold_px
        again = self._road_band.contains(points) & ~(ok & (fb_error <= threshold))
        if not again.any():
            return
        # the plane's height in the last step's baselines: the translation predicted for this step has length 1
        H = plane_homography(self._K, last[1], last[2].reshape(3), plane[1],  # noqa: N806
                             plane[2] / self._last_step_length)
        start = cv2.perspectiveTransform(points[again].reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
        height, width = image.shape[:2]
        inside = np.all(np.isfinite(start), axis=1) & (start[:, 0] >= 0) & (start[:, 0] < width) \
            & (start[:, 1] >= 0) & (start[:, 1] < height)
        if not inside.any():
            return
        start = start[inside].astype(np.float32)
        warped = cv2.warpPerspective(self._previous, H, (width, height), flags=cv2.INTER_LINEAR)
        moved, moved_ok, moved_fb = track_points(warped, image, start, self.config.tracker, start)
        better = moved_ok & (moved_fb <= threshold)
        rows = np.flatnonzero(again)[inside][better]
        tracked[rows], ok[rows], fb_error[rows] = moved[better], True, moved_fb[better]

    def _road_corners(self, image: np.ndarray, existing: np.ndarray) -> np.ndarray:
        """With --scale height: FAST corners (a lower threshold) in the road band ahead while it holds fewer
        than `road_tracks` tracks, so every frame has road points for the plane fit."""
        cfg = self.config.height
        x0, y0, x1, y1 = self._road_band.rectangle(image.shape)
        inside = (existing[:, 0] >= x0) & (existing[:, 0] < x1) & (existing[:, 1] >= y0)
        wanted = cfg.road_tracks - int(inside.sum())
        if wanted <= 0 or x1 <= x0 or y0 >= y1:
            return np.zeros((0, 2), np.float32)
        detector = replace(self.config.detector, fast_threshold=cfg.road_fast_threshold, grid_rows=2, grid_cols=4)
        return detect_corners(image, existing, wanted, detector, region=(x0, y0, x1, y1), usable=self._usable)

    def _replenish(self, image: np.ndarray, timings: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Detect new corners away from live tracks when too few are left, or when they cover too little of the
        image (then a quarter of `target_tracks`, up to 1.25 x `target_tracks` live); they start new tracks."""
        cfg = self.config.detector
        clock = time.perf_counter()
        tracks = self._tracks
        corners = np.zeros((0, 2), np.float32)
        if len(tracks) < cfg.redetect_below or self._previous is None:
            corners = detect_corners(image, tracks.points, cfg.target_tracks - len(tracks), cfg, usable=self._usable)
        elif grid_coverage(tracks.points, image.shape, cfg) < cfg.min_coverage:
            wanted = min(cfg.target_tracks // 4, cfg.target_tracks + cfg.target_tracks // 4 - len(tracks))
            corners = detect_corners(image, tracks.points, wanted, cfg, usable=self._usable)
        if self.config.scale == "height":
            corners = np.concatenate((corners, self._road_corners(image, np.concatenate((tracks.points, corners)))))
        if not len(corners):
            return np.zeros(0, np.int64), corners
        ids = self._append_tracks(corners, at_keyframe=self._key_position == self._position)
        timings["detect"] = elapsed_ms(clock)
        return ids, corners
