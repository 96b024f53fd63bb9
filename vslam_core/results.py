"""The typed per-frame result: every intermediate the engine computed, for the recording and debuggers.

Shapes: M = tracks that reached this frame's tracking step, K = corners detected in this frame,
P = triangulated points. Pixel coordinates are (x right, y down). Poses are 4x4 camera-to-world.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum

import numpy as np

from vslam_core.geometry import CandidatePose


class TrackFate(IntEnum):
    """What happened to a track in this frame (also the class ids of the recording's legend)."""

    LOST = 0  # KLT failed or the point left the image
    FB_REJECTED = 1  # failed the forward–backward check
    NOT_USED = 2  # tracked, but born after the keyframe (no reference position yet)
    RANSAC_OUTLIER = 3
    CHIRALITY_FAILED = 4  # RANSAC inlier, triangulated behind a camera under the chosen pose
    INLIER = 5


class FrameStatus(StrEnum):
    INIT = "init"  # first frame: identity pose, corners detected
    OK = "ok"  # motion estimated, keyframe advanced
    HELD = "held"  # motion not trusted: previous pose kept (see reason)


class Reason(StrEnum):
    """Reason codes of a frame's health (and why a held frame held its pose)."""

    # the pose is held
    UNREADABLE_IMAGE = "unreadable_image"
    IMAGE_TOO_DARK = "image_too_dark"
    IMAGE_TOO_BRIGHT = "image_too_bright"
    IMAGE_BLURRED = "image_blurred"
    TOO_FEW_TRACKS = "too_few_tracks"
    LOW_PARALLAX = "low_parallax"  # too little motion: creeping, or a scene too far away
    STATIONARY = "stationary"  # the image did not move at all: a parked car (or a frozen camera)
    NO_ESSENTIAL = "no_essential_matrix"
    TOO_FEW_INLIERS = "too_few_inliers"
    CHIRALITY = "ambiguous_chirality"
    GAP_MOTION_REJECTED = "gap_motion_rejected"  # the motion measured across a dead-reckoned gap disagreed with it
    # warnings: the frame is used
    IMAGE_NOISY = "image_noisy"
    BRIGHTNESS_JUMP = "brightness_jump"
    FEW_TRACKS = "few_tracks"
    LOW_INLIER_RATIO = "low_inlier_ratio"
    CLOSE_CHIRALITY = "close_chirality"
    ROTATION_DOMINATED = "rotation_dominated"
    SCALE_JUMP = "scale_jump"
    RECOVERED = "recovered_by_matching"  # tracks were lost; the motion was measured by descriptor matching
    STEP_HELD = "step_held"  # the step's direction went against the motion model's: the model's direction used
    SCALE_HELD = "scale_held"  # --scale height: no road plane (or an outlier) this frame; the last scale held
    ROAD_PLANE_DOUBTFUL = "road_plane_doubtful"  # --scale height: the plane was used, but it tilts off the recent
    # planes or its step is off the trend (HeightScale: doubtful_tilt_deg, doubtful_jump)
    # map backend
    TRACKING_LOST = "tracking_lost"  # fail: neither the map nor two-view geometry gave a pose, relocalisation failed
    PNP_REJECTED = "pnp_rejected"  # warn: tracking against the map failed its checks; the two-view pose was used
    TWO_VIEW_OUTVOTED = "two_view_outvoted"  # warn: PnP disagreed with the two-view rotation, agreed with the
    # motion model's prediction, and was used
    RELOCALISED = "relocalised"  # warn: tracking was lost; the pose came from matching the map's landmarks
    NEW_MAP_SEGMENT = "new_map_segment"  # warn: relocalisation failed, a new map was started here
    HEIGHT_OFF_MAP = "height_off_map"  # warn (--scale height): the road plane's step is over `max_jump` off the
    # step of the map's own PnP pose: the road and the map's scale disagree
    COASTED = "coasted"  # the image could not be tracked; its pose is dead-reckoned from the degraded image


#: held for standing still, not for a failure: the pose held is the right answer (health warn, not fail)
STANDING_STILL = frozenset({Reason.STATIONARY, Reason.LOW_PARALLAX})
#: the front end's reasons to hold a frame, which the map backend overrules when it places the frame itself
FRONT_END_HOLDS = frozenset({Reason.TOO_FEW_TRACKS, Reason.LOW_PARALLAX, Reason.STATIONARY, Reason.NO_ESSENTIAL,
                             Reason.TOO_FEW_INLIERS, Reason.CHIRALITY})


class HealthStatus(StrEnum):
    OK = "ok"
    WARN = "warn"  # used, but suspicious
    FAIL = "fail"  # not used: the previous pose is held


@dataclass(frozen=True)
class Health:
    status: HealthStatus
    reasons: tuple[Reason, ...] = ()

    @classmethod
    def of(cls, held: Reason | None, warnings: list[Reason]) -> Health:
        """fail when the pose was held for a failure (standing still only warns), else warn/ok."""
        if held is not None and held not in STANDING_STILL:
            return cls(HealthStatus.FAIL, (held, *warnings))
        reasons = ((held,) if held is not None else ()) + tuple(warnings)
        return cls(HealthStatus.WARN if reasons else HealthStatus.OK, reasons)

    @classmethod
    def under_map(cls, front_end: Reason | None, front_end_reasons: tuple[Reason, ...], placed: bool,
                  warnings: list[Reason]) -> tuple[Reason | None, Health]:
        """A map backend frame's (reason held, health) from the front end's (`front_end` reason, its reasons) and
        the map's `warnings` (a gap's refused motion taken out of them as the reason). Placed by the map, it keeps
        `stationary` (the image did not move at all: a parked car, a frozen camera) as a warning, as vo does; the
        other reasons vo would have held it for are the map's to overrule. Not placed, it is held for the front
        end's failure, or for `tracking_lost` where the front end would only have held it."""
        if placed:
            kept = [r for r in front_end_reasons if r not in FRONT_END_HOLDS or r == Reason.STATIONARY]
            return None, cls.of(None, kept + warnings)
        reason = front_end if front_end is not None else Reason.TRACKING_LOST
        if front_end in FRONT_END_HOLDS and front_end not in STANDING_STILL:
            reason = Reason.TRACKING_LOST
        if Reason.GAP_MOTION_REJECTED in warnings:  # its two-view motion, measured across a gap, was refused
            reason = warnings.pop(warnings.index(Reason.GAP_MOTION_REJECTED))
        return reason, cls.of(reason, [r for r in front_end_reasons if r != front_end] + warnings)


@dataclass(frozen=True)
class ScaleEstimate:
    """How `--scale height` found this frame's step length (current camera frame, metric units)."""

    road_points: np.ndarray  # (R, 3) road points the plane was fitted to (its inliers)
    road_pixels: np.ndarray  # (R, 2) their pixel positions in this frame
    plane_normal: np.ndarray | None  # (3,) unit, pointing down; None when no plane was found
    camera_height: float | None  # the camera's height above that plane
    measured_step: float | None  # known height / height in baselines: this frame's own step length
    step: float  # the step length used, after temporal filtering (or held)
    held: bool  # no plane or an outlier: the filtered trend's step was used instead
    # used, but doubtful: the plane tilts away from the recent planes (a ramp, a crest: the road ahead is not the
    # plane the car stands on) or its step is off the trend by more than half the outlier bound
    doubtful: bool = False


class TrackingMode(StrEnum):
    """Where a frame's pose came from (map backend)."""

    INIT = "init"  # the first frame of a map segment
    TWO_VIEW = "two_view"  # essential matrix from the keyframe: before the map exists, or PnP failed its checks
    # PnP in RANSAC on the landmarks the frame's tracks see, refined on the inliers: its pose (--scale none), or
    # with a scale source the front end's motion when the two rotations agree (mapping/pnp.py metric_pose)
    MAP = "map"
    RELOCALISED = "relocalised"  # tracks were lost: descriptors matched to the map's landmarks, then PnP
    COASTED = "coasted"  # a degraded frame: rotation from its contrast-normalised image, step from the scale source
    LOST = "lost"  # no pose: the previous one is held


class PnPFailure(StrEnum):
    """Why tracking against the map gave no pose (map backend), the first check that failed."""

    TOO_FEW_IN_VIEW = "too_few_in_view"  # fewer of the local map's landmarks project into the image than PnP needs
    TOO_FEW_MATCHED = "too_few_matched"  # enough in view, too few of them tracked or found by the search
    RANSAC = "ransac"  # matched, but RANSAC found no pose with enough inliers (count or ratio)
    DISAGREES = "disagrees"  # a pose, refused: its rotation is off the two-view motion's and the motion model's


@dataclass(frozen=True)
class PnPEstimate:
    """Tracking against the map: L landmarks seen by this frame's tracks (or matched by relocalisation)."""

    landmark_ids: np.ndarray  # (L,) int64
    observed: np.ndarray  # (L, 2) raw image pixel of each in this frame (tracked or matched)
    projected: np.ndarray  # (L, 2) the landmark projected with the pose used, through the lens onto the raw image
    # (NaN where behind the camera); inside the engine both are ideal pinhole pixels until the frame's result
    inlier_mask: np.ndarray  # (L,) bool: RANSAC inliers kept after refinement
    T_world_cam: np.ndarray | None  # (4, 4) the refined PnP pose; None when PnP failed  # noqa: N815
    rejected: str | None = None  # why it was not used, if it was not
    outvoted_two_view: bool = False  # used though the two-view rotation disagreed: it agreed with the motion model
    failure: PnPFailure | None = None  # why no pose came of it (None: a pose, or not a tracking attempt)
    in_view: int = -1  # landmarks of the local map projected into the image by the prediction (-1: not counted)
    found: int = 0  # of the landmark_ids, those the search by projection found (the others were tracked)
    search_radius_px: float = 0.0  # the widest search window tried (half-size; 0: no search)


@dataclass(frozen=True)
class KeyframeInserted:
    """A new keyframe and what local mapping did with it."""

    keyframe_id: int
    position: int  # run position of its frame
    T_world_cam: np.ndarray  # (4, 4) pose at insertion  # noqa: N815
    why: str  # what made this frame a keyframe (parallax, overlap, relocalised, initialisation, ...)
    observed_landmarks: int  # landmarks its tracks see
    new_landmarks: int  # landmarks triangulated with earlier keyframes
    culled_landmarks: int  # landmarks removed (bad reprojection, too few observations)
    min_ray_angle_deg: float = 0.0  # the rays of its new landmarks met at least at this angle (a slow camera's less)


@dataclass(frozen=True)
class BundleAdjusted:
    """One windowed bundle adjustment (gtsam Levenberg–Marquardt, robust reprojection error), applied at
    this frame. K keyframes optimised, F fixed, P landmarks; errors in pixels."""

    keyframe_ids: np.ndarray  # (K,) optimised keyframes (the window)
    keyframe_poses: np.ndarray  # (K, 4, 4) their refined T_world_cam
    fixed_keyframe_ids: np.ndarray  # (F,) older keyframes that see the window's landmarks, held fixed
    landmark_ids: np.ndarray  # (P,)
    landmark_positions: np.ndarray  # (P, 3) refined, world
    landmark_residual_px: np.ndarray  # (P,) mean reprojection error of each landmark after
    iterations: int
    cost_before: float
    cost_after: float
    mean_error_before: float
    max_error_before: float
    mean_error_after: float
    max_error_after: float
    culled: int  # landmarks removed because they reprojected badly after
    milliseconds: float  # solver time (in the background worker when threads > 1)
    factors: int  # projection factors
    # (P,) keyframes observing each landmark when the solution was applied (its lifetime in keyframes)
    landmark_keyframes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    # (Q,) degrees between each pair of consecutive keyframes' rotation and the front end's chained two-view
    # rotation (the BA's relative-rotation priors), after the adjustment
    rotation_errors_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class Relocalisation:
    """An attempt to find a lost frame's pose by matching its ORB descriptors to the map's landmarks."""

    success: bool
    keyframe_id: int | None  # the keyframe that shares the most inliers with this frame
    candidates: int  # landmarks of recent keyframes that were searched
    matches: int  # descriptor matches
    inliers: int  # PnP RANSAC inliers


@dataclass(frozen=True)
class LocalMapSearch:
    """Local-map tracking by projection in one frame (the idea of ORB-SLAM, Mur-Artal et al. 2015, §V-D):
    the S landmarks of the local map that project into the image with the predicted pose, each searched
    for among the frame's FAST corners inside a square window around its projection, by the Hamming distance
    of upright ORB descriptors at several pyramid levels and a ratio test."""

    purpose: str  # "track" (a tracked frame: unlinked landmarks re-found) or "relocalise" (after a gap)
    keyframe_ids: np.ndarray  # (K,) the local map: keyframes covisible with the reference one, and neighbours
    landmark_ids: np.ndarray  # (S,) int64 landmarks projected into the image
    projected: np.ndarray  # (S, 2) their pixels with the predicted pose
    radius_px: np.ndarray  # (S,) half-size of each square search window (the last, widest one tried)
    found_pixels: np.ndarray  # (S, 2) the corner each was matched to; NaN where not re-found
    distance: np.ndarray  # (S,) Hamming distance of the match (-1 where not re-found)
    accepted: np.ndarray  # (S,) bool: re-found and used (agreeing with the pose; linked to a new track)

    @property
    def found_mask(self) -> np.ndarray:
        """(S,) bool: re-found."""
        return np.asarray(np.isfinite(self.found_pixels).all(axis=1))


@dataclass(frozen=True)
class MapView:
    """What the recording draws of the map at a keyframe: the BA window and whatever left it for good."""

    window_ids: np.ndarray  # (K,) keyframes in the optimisation window
    window_poses: np.ndarray  # (K, 4, 4)
    fixed_ids: np.ndarray  # (F,) keyframes held fixed in the last BA
    fixed_poses: np.ndarray  # (F, 4, 4)
    landmark_ids: np.ndarray  # (P,) landmarks seen by the window
    landmark_positions: np.ndarray  # (P, 3)
    landmark_observations: np.ndarray  # (P,) keyframes that observe each
    retired_ids: np.ndarray  # (R,) keyframes that left the window at this keyframe (final poses)
    retired_poses: np.ndarray  # (R, 4, 4)
    retired_landmark_ids: np.ndarray  # (Q,) landmarks no window keyframe sees any more (final positions)
    retired_landmark_positions: np.ndarray  # (Q, 3)
    retired_landmark_observations: np.ndarray  # (Q,)
    keyframe_path: np.ndarray  # (N, 3) every keyframe's position in this segment, refined so far, by keyframe id
    keyframe_path_ids: np.ndarray  # (N,) their keyframe ids, ascending
    landmarks_total: int  # landmarks in the map


@dataclass(frozen=True)
class LoopCandidate:
    """A place the query keyframe may revisit (vslam_core/loop/): found by its bag of words, checked by PnP of
    the query's features against the candidate keyframe's landmarks. M descriptor matches."""

    query_keyframe: int
    query_position: int  # run position of the query keyframe's frame
    candidate_keyframe: int
    candidate_position: int
    score: float  # bag-of-words similarity, 0..1
    matches: int
    inliers: int  # PnP RANSAC inliers
    accepted: bool  # verified and consistent: the loop is closed with it
    why: str  # "accepted", or why not (e.g. "12 inliers < 40", "not consistent yet (1 of 2)")
    query_pixels: np.ndarray  # (M, 2) matched features in the query keyframe's image
    candidate_pixels: np.ndarray  # (M, 2) the matched landmarks' pixels in the candidate keyframe's image (NaN
    # for a landmark only its neighbouring keyframes saw)
    inlier_mask: np.ndarray  # (M,) bool
    T_candidate_query: np.ndarray | None  # (4, 4) the query camera in the candidate's camera frame  # noqa: N815
    query_image: np.ndarray | None = None  # (H, W) uint8 thumbnails (half size) of both keyframes
    candidate_image: np.ndarray | None = None


@dataclass(frozen=True)
class LoopClosed:
    """A loop closed: the pose graph over the segment's K keyframes (odometry edges + the loop edge) optimised,
    the keyframes and their landmarks moved. Found by the search submitted at the keyframe after the query's and
    applied when the one after that is inserted (a fixed point); the poses are the map's when it was applied."""

    query_keyframe: int
    candidate_keyframe: int
    query_position: int
    candidate_position: int
    inliers: int
    similarity: bool  # Sim(3) pose graph (--scale none) rather than SE(3)
    keyframe_ids: np.ndarray  # (K,)
    keyframe_positions: np.ndarray  # (K,) run positions of their frames
    poses_before: np.ndarray  # (K, 4, 4) T_world_cam before the correction
    poses_after: np.ndarray  # (K, 4, 4) and after
    correction_m: np.ndarray  # (K,) distance each keyframe moved
    correction_deg: np.ndarray  # (K,) rotation applied to each
    scales: np.ndarray  # (K,) how much larger each keyframe's neighbourhood became (1 with a metric scale)
    landmarks_moved: int
    milliseconds: float  # pose graph optimisation (in the search) and map update (at the fixed point)


@dataclass(frozen=True)
class LoopStep:
    """What loop closing did at a keyframe: the candidates it checked, the loop it closed, and its cost."""

    candidates: tuple[LoopCandidate, ...] = ()
    closed: LoopClosed | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)  # describe, query, verify, optimise (the search);
    # wait, apply, submit (the tracking thread)


@dataclass(frozen=True)
class MapFrame:
    """The map backend's part of a frame result (None with --backend vo)."""

    mode: TrackingMode
    segment: int  # map segment: a new one starts only when relocalisation fails
    two_view_pose: np.ndarray | None  # (4, 4) T_world_cam from the essential matrix (the checked fallback)
    pnp: PnPEstimate | None
    keyframe: KeyframeInserted | None = None
    bundle_adjustment: BundleAdjusted | None = None  # applied at this frame
    relocalisation: Relocalisation | None = None
    view: MapView | None = None  # at keyframes
    loop: LoopStep | None = None  # at keyframes, with loop closing on
    local_map: LocalMapSearch | None = None  # landmarks projected and searched for in this frame
    # the camera was found moving sideways at this frame (its keyframe steps' median |cos| with the optical axis):
    # the map takes --scale none's settings from here on, with a scale source (map_scale.sideways_camera)
    sideways_share: float | None = None
    # --scale none, a frame placed by its two-view motion: where its step's length came from (map_scale.TwoViewLength:
    # "landmarks", "tracks" of the two frames before, the "last step", the map's "speed"); None otherwise
    step_length: str | None = None


@dataclass(frozen=True)
class FrameResult:
    """Everything the engine knows about one frame."""

    position: int  # 0-based position of the frame in this run
    index: int  # the frame's index in its source
    timestamp: float | None
    T_world_cam: np.ndarray  # (4, 4) pose of this frame  # noqa: N815
    status: FrameStatus
    reason: Reason | None
    keyframe_position: int  # run position of the reference frame the motion was measured from
    image_shape: tuple[int, int]
    # Tracking, frame to frame (M tracks that entered this step)
    track_ids: np.ndarray  # (M,) int64
    track_prev: np.ndarray  # (M, 2) float32 position in the previous frame
    track_cur: np.ndarray  # (M, 2) float32 position in this frame (meaningless where LOST)
    track_age: np.ndarray  # (M,) int32 frames the track has lived, this one included
    track_fate: np.ndarray  # (M,) uint8 TrackFate
    # Detection (after the pose step): K new corners that start tracks in this frame
    new_corner_ids: np.ndarray  # (K,) int64
    new_corners: np.ndarray  # (K, 2) float32
    live_tracks: int  # tracks alive at the end of the frame
    # Two-view geometry (keyframe -> this frame); None / empty when not reached
    essential: np.ndarray | None  # (3, 3)
    candidate_poses: tuple[CandidatePose, ...]  # the four decompositions of E with chirality counts
    chosen_candidate: int | None
    T_key_cur: np.ndarray | None  # (4, 4) scaled relative motion, X_key = R·X_cur + t  # noqa: N815
    points_world: np.ndarray  # (P, 3) triangulated inliers in world coordinates (scaled)
    scale: float | None  # length of this step's translation (metres with gt scale)
    parallax_px: float  # median displacement keyframe -> this frame of the tracks used
    health: Health = Health(HealthStatus.OK)
    scale_estimate: ScaleEstimate | None = None  # with --scale height
    timings_ms: dict[str, float] = field(default_factory=dict)  # stage -> milliseconds
    mapping: MapFrame | None = None  # --backend map: tracking mode, PnP, keyframes, bundle adjustment
    # (3, 3) rad², of T_key_cur's rotation as R·exp([ω]ₓ), from the two-view refinement (`Motion`); else None
    rotation_covariance: np.ndarray | None = None

    @property
    def inlier_count(self) -> int:
        return int(np.count_nonzero(self.track_fate == TrackFate.INLIER))

    def fate_counts(self) -> dict[str, int]:
        counts = np.bincount(self.track_fate, minlength=len(TrackFate))  # one pass, not one per fate
        return {fate.name.lower(): int(counts[fate]) for fate in TrackFate}


def elapsed_ms(start: float) -> float:
    """Milliseconds since `start` (a `time.perf_counter()` reading): an entry of a result's `timings_ms`."""
    return (time.perf_counter() - start) * 1000.0
