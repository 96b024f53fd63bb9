"""The engine's one typed config, with defaults, loadable from TOML.

A TOML file mirrors the dataclasses: top-level keys of `EngineConfig` plus one table per section::

    scale = "gt"
    [detector]
    fast_threshold = 20
    [pose]
    ransac_threshold_px = 0.5

Reading one (`load_config`, `config_from_dict`): `vslam_core/config_file.py`, where unknown keys, wrong types and
values out of their range raise `ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

ScaleSource = Literal["gt", "none", "height"]
RansacMethod = Literal["ransac", "magsac"]
Backend = Literal["vo", "map"]


@dataclass(frozen=True)
class DetectorConfig:
    """FAST corners, spread over the image by grid bucketing and a mask around live tracks."""

    fast_threshold: int = 20
    target_tracks: int = 800  # detect up to this many live tracks
    redetect_below: int = 600  # re-detect when live tracks fall under this
    grid_rows: int = 4
    grid_cols: int = 10
    min_distance_px: int = 8  # no new corner within this distance of a live track
    # re-detect also when live tracks cover less than this share of the grid's cells (a car reversing: its tracks
    # flow to the image centre and are not lost, so their number alone never asks for new ones); 0: off
    min_coverage: float = 0.5


@dataclass(frozen=True)
class TrackerConfig:
    """Pyramidal Lucas–Kanade with a forward–backward check.

    Tracks with a flow history start from where their last flow predicts and search fewer pyramid levels;
    the backward track starts at the original point. Both cut the work per track without losing the
    check: a forward track that went astray does not come back.
    """

    window_px: int = 13
    max_level: int = 3  # OpenCV's maxLevel: pyramid levels above the full image, for tracks without a guess
    predicted_max_level: int = 1  # levels for tracks started at their predicted position; < 0: no prediction
    backward_max_level: int = 0  # levels for the backward track, started at the original point
    max_iterations: int = 10
    epsilon: float = 0.03  # px: stop iterating once an update is smaller
    fb_threshold_px: float = 1.0  # forward–backward round trip must land this close
    border_px: int = 2  # tracks closer than this to the border are dropped
    # when more than this share of the tracks started at their guess fail (a turn whose rate changes: on KITTI at
    # every 3rd frame 30-92 % of a frame's, at every frame up to 22-45 %, on the synthetic street up to 33 %), they
    # are tracked again from the guess with max_level levels (1.0: never; at 0.3 the synthetic street got worse)
    retry_failed_share: float = 0.4


@dataclass(frozen=True)
class PoseConfig:
    """Essential matrix (5-point in RANSAC), chirality, and the checks that reject a frame."""

    ransac_method: RansacMethod = "ransac"
    ransac_probability: float = 0.999
    ransac_threshold_px: float = 1.0
    ransac_max_iterations: int = 1000
    seed: int = 0  # seeds RANSAC through a fixed shuffle of the correspondences
    refine: bool = True  # Gauss–Newton on the Sampson error of the inliers after RANSAC
    # the refined pose's covariance (~0.3 ms a frame), set by the map backend when its rotation prior uses it
    rotation_covariance: bool = False
    drop_outliers: bool = True  # RANSAC outliers stop being tracked
    chirality_max_depth: float = 50.0  # points nearer than this (in baselines) vote in the chirality check
    # ... and when fewer than min_inliers of them vote, points up to this far: a hand-held camera's step is
    # 1/100-1/400 of its scene's depth (with 50 alone the synthetic walk held 63 % of its frames)
    chirality_far_depth: float = 500.0
    # a step measured against the motion model's direction (cosine < 0 with the last step, which at 10-30 Hz
    # never happens on real data) is held to the model's direction instead: a held step costs at most its
    # length, a reversed one twice it. Never two frames in a row: a real reversal is taken on the next frame.
    hold_reversed_step: bool = True
    hold_reversed_frames: int = 1  # ... at most this many frames in a row
    min_tracks: int = 30  # fewer tracks from the keyframe: re-initialise
    min_inliers: int = 20
    min_parallax_px: float = 1.0  # median flow from the keyframe below this: too little motion to measure
    stationary_px: float = 0.05  # median flow below this (KLT's noise): the image did not move, a parked car
    # `vo`: an accepted step whose parallax left once the rotation is removed is below this (px) does not become
    # the keyframe: its pose is placed, and the next frame is measured from the same keyframe over a longer
    # baseline. Chained one-frame steps of a hand-held camera lose rotation about the image's short (x) axis,
    # traded for a sideways step (TUM fr1_desk, 30 Hz, ground-truth scale: 10.7 deg off after 6.6 s, 7.0 with
    # 10 px), but 10 px made KITTI, the synthetic routes and fr1_xyz's ATE worse (docs/method.md): off (0, a
    # keyframe on every accepted step) by default. With --scale none each keyframe step is one unit long.
    keyframe_parallax_px: float = 0.0


@dataclass(frozen=True)
class HeightScaleConfig:
    """`scale = "height"`: step lengths from the camera's known height above the road (vslam_core/road.py)."""

    camera_height_m: float = 0.0  # 0: the source's own (KITTI 1.65 m, the synthetic street's); else required
    # the road band, as angles from the optical axis so that it is the same stretch of road whatever the camera's
    # resolution and focal length (80 and 100 px at KITTI 00's 718.9 px focal length)
    road_top_deg: float = 6.35  # road points lie this far below the principal point or lower (the lane ahead)
    road_half_width_deg: float = 7.92  # ... and at most this far left or right of it
    road_tracks: int = 200  # keep this many tracks in that band (more road points than the whole-image spread)
    road_fast_threshold: int = 7  # FAST threshold there (asphalt has little contrast)
    max_tilt_deg: float = 10.0  # the plane's normal within this of the camera's down axis
    inlier_fraction: float = 0.02  # RANSAC inlier: within this fraction of the camera height of the plane
    ransac_iterations: int = 100
    min_road_points: int = 8  # fewer road points or plane inliers: no estimate this frame
    window: int = 15  # per-frame speeds in the robust trend fit (frames with an estimate)
    max_jump: float = 0.3  # an estimate further than this fraction from the trend is an outlier
    doubtful_jump: float = 0.15  # ... further than this (not an outlier): used, flagged road_plane_doubtful
    doubtful_tilt_deg: float = 3.0  # a plane's normal this far from the median of the recent planes': flagged too
    doubtful_inliers: int = 12  # a plane on fewer inliers than this: flagged too (KITTI: its step 15 % off, median)


@dataclass(frozen=True)
class HealthConfig:
    """When a frame is flagged. fail = the frame cannot be used (pose held); warn = used, but suspicious."""

    dark_mean: float = 20.0  # fail: mean grey level below
    bright_saturated: float = 0.5  # fail: fraction of saturated pixels above
    blur_sharpness: float = 100.0  # fail: variance of the Laplacian below (KITTI frames: 1000–2600)
    noise_sigma: float = 6.0  # warn: estimated sensor noise above (KITTI frames: < 2)
    brightness_jump: float = 25.0  # warn: mean grey level changed more than this since the last frame
    warn_tracks: int = 300  # warn: fewer tracks from the keyframe
    warn_inlier_ratio: float = 0.6  # warn: RANSAC inlier ratio below
    ambiguous_chirality: float = 0.5  # warn: second-best candidate has more than this share of the best's count
    rotation_parallax_px: float = 1.0  # warn: median parallax left once the rotation is removed, below
    step_jump: float = 2.5  # warn: step length or de-rotated parallax changed by more than this factor


@dataclass(frozen=True)
class MapConfig:
    """`backend = "map"`: keyframes, landmarks, tracking against the map, windowed BA, relocalisation."""

    # keyframe selection: a frame becomes a keyframe when any of these holds
    # the median translation parallax (px, the rotation removed: map_scale.translation_parallax) since the last
    # keyframe reaches this; counting the rotation's displacement too made a keyframe of every frame of a turn
    keyframe_parallax_px: float = 30.0
    keyframe_overlap: float = 0.5  # fewer than this share of the last keyframe's landmarks are still tracked
    keyframe_min_landmarks: int = 120  # fewer landmarks tracked than this
    keyframe_max_frames: int = 10  # this many frames since the last keyframe
    # landmarks
    min_triangulation_deg: float = 1.0  # rays of a new landmark meet at least at this angle
    max_reprojection_px: float = 2.0  # a new landmark reprojects this well into both keyframes
    cull_reprojection_px: float = 4.0  # after BA, an observation reprojecting worse than this is dropped
    min_observations: int = 3  # a landmark that leaves the window with fewer keyframes seeing it is culled
    map_keyframes: int = 100  # landmarks none of the last this many keyframes sees are forgotten (memory bound)
    # keyframe culling, of the keyframe bundle adjustment has just stopped holding (local_mapping.py `_cull`: it left
    # the window and the fixed keyframes behind it; a keyframe holding a loop edge is never culled): with
    # cull_revisits it is removed when an older keyframe (cull_separation ids before) is where it is (a street driven
    # again keeps its keyframes), or when at least cull_redundant_share of its landmarks are seen by cull_observers
    # other keyframes at the same or a finer scale (another keyframe at most cull_scale times farther; ORB-SLAM's rule
    # at 0.9, Mur-Artal et al. 2015, sec. V-E). That rule is off (0): at 0.9 it culled 1-19 keyframes of the quick
    # matrix's TUM and synthetic-street runs and made their ATE after Sim(3) 17-23 % worse (docs/map-backend.md); on
    # KITTI a keyframe leaving the window shares only 30-60 % of its landmarks so (the KLT tracks' landmarks live
    # briefly)
    cull_redundant_share: float = 0.0
    cull_observers: int = 3
    cull_scale: float = 1.2
    # on: KITTI 00 driven back and forth grows 13.7-14.2 KB a revisited frame at its peak (19.0-28.6 without); the
    # synthetic drive (frames 0:1500, resolution 0.5, --scale gt, seeds 0-5) keeps its ATE after Sim(3) (0.508 m,
    # 0.501 without; 10-25 m when loop keyframes were culled too and at the window's edge, docs/map-backend.md)
    cull_revisits: bool = True
    # ... with --scale none (off): on KITTI 05 0..149..0 culling the revisit's keyframes took the ATE after Sim(3)
    # from 0.47 to 1.79 m with loop closing, 3.88 to 4.19 m without (the map's scale rests on those keyframes); with
    # the loop keyframes kept and the cull after BA, 0.47 to 0.66 m and 3.88 to 4.30 m
    none_cull_revisits: bool = False
    cull_separation: int = 30
    # tracking against the map
    pnp_min_landmarks: int = 30  # fewer landmarks seen: no PnP (two-view pose or relocalisation)
    pnp_threshold_px: float = 2.0  # RANSAC inlier threshold
    pnp_iterations: int = 100
    pnp_min_inliers: int = 25
    pnp_min_inlier_ratio: float = 0.5
    max_rotation_disagreement_deg: float = 3.0  # PnP and two-view rotation since the keyframe must agree
    # with a scale source a frame PnP places takes the front end's motion if the two rotations agree within this
    # (each is good to ~0.05° frame to frame on KITTI; a two-view rotation 1-3° off keeps PnP's pose)
    front_end_agreement_deg: float = 0.5
    # windowed bundle adjustment
    ba_window: int = 6  # keyframes optimised
    ba_max_fixed: int = 4  # older keyframes seeing the window's landmarks, held fixed (the nearest ones)
    ba_iterations: int = 3
    ba_huber_px: float = 1.5  # Huber threshold of the reprojection error (sigma 1 px)
    ba_max_landmarks: int = 400  # the window's landmarks with the most observations
    # when a run completes, the map's newest adjust_at_end_keyframes keyframes and their landmarks adjusted together
    # once (global_adjustment.py), unless the run closed a loop (it bent the synthetic loop open: 0.04 -> 0.17 m) and
    # only for a camera moving sideways (along its axis free steps lengthened: KITTI 05 0:300 1.4-1.7 -> 3.1-3.3 m).
    # Off with a scale source but for a camera moving sideways (sideways_as_none; for a car gt changed KITTI by
    # -0.003..0 m, height moved its metric scale), on with --scale none (none_adjust_at_end: TUM 3.8 -> 1.9 cm)
    adjust_at_end: bool = False
    none_adjust_at_end: bool = True
    adjust_at_end_keyframes: int = 300
    # ... holding the front end's rotations at this sigma (0: rotation_prior_deg's), inflated where ambiguous as in BA
    adjust_at_end_rotation_prior_deg: float = 0.01
    # ... the steps' lengths at this fraction (0: free; at none_step_sigma's 0.003 TUM's gain was lost)
    adjust_at_end_step_sigma: float = 0.0
    # a camera moving sideways: the median |cos| of its keyframe steps with the optical axis is at most this (a car
    # or a walk ~1, the hand-held TUM frames 0.25-0.39); with a scale source measured at each keyframe over the newest
    # sideways_keyframes, from the map's sideways_keyframes-th on (at the 3rd fr1_desk had not turned sideways yet
    # in 2 of 4 runs; at the 8th its gain halved), a step shorter than sideways_min_step_depth of its landmarks'
    # median depth (a standstill: its direction is noise) left out
    sideways_forward_share: float = 0.7
    sideways_keyframes: int = 5
    sideways_min_step_depth: float = 0.005
    # ... with a scale source such a camera takes --scale none's map settings for good, its steps still the source's:
    # fr1_desk gt final rotation 11.9-14.2 -> 1.9-3.4 deg; on KITTI they cost accuracy (docs/map-backend.md)
    sideways_as_none: bool = True
    # sigma of the front end's chained rotation between keyframes with a scale source (0: none): at 0.05 deg
    # bundle adjustment let the keyframes' yaw drift 0.45 deg in KITTI 05's turn (docs/map-backend-history.md)
    rotation_prior_deg: float = 0.01
    # ... plus, where the chained two-view rotation's own covariance (`RotationChain`) exceeds the square of
    # rotation_prior_floor_deg, that excess times this factor squared (0: off): loose along the direction the two
    # views could not tell from a step sideways (a hand-held camera's pitch), as tight as before elsewhere
    rotation_prior_inflation: float = 0.0
    rotation_prior_floor_deg: float = 0.01
    rotation_prior_cap_deg: float = 0.5  # ... and never looser than this
    # m: keyframe-to-keyframe distance prior with --scale gt (vo takes each step's length exactly; at 1 cm BA let
    # the steps drift: mean ATE after Sim(3) over 36 KITTI runs 0.119 m, at 1-5 mm 0.109-0.110, at 3 cm 0.187)
    scale_sigma_gt: float = 0.003
    scale_sigma_height: float = 0.025  # fraction of the distance with --scale height
    # --scale none: the map's own scale carries the trajectory (vslam_core/mapping/map_scale.py). The first
    # baseline waits for this much translation parallax; then these replace min_triangulation_deg and
    # ba_iterations
    init_parallax_px: float = 20.0
    init_min_landmarks: int = 50  # ... and must triangulate this many landmarks, else it is tried again
    init_wait_frames: int = 10  # ... or, after this many frames without that parallax, on the landmarks alone
    # once one starts the map, an earlier attempt's keyframe is placed against its landmarks when its rays to them
    # meet the first keyframe's at this median angle or more (map_scale.place_attempts)
    attempt_min_ray_angle_deg: float = 2.0
    none_min_triangulation_deg: float = 3.5
    # ... except for a slow camera: its landmarks' median depth is more than this many frames of its travel (a
    # hand-held camera; KITTI and the synthetic street 10-47, the synthetic walk 70-390), whose rays rarely meet
    # at 3.5 deg: there they need this angle (min_triangulation_deg's; the walk's ATE at 2.5 / 2 / 1.5 / 1 deg:
    # 12.4 / 2.8 / 1.9 / 1.2 cm)
    slow_depth_frames: float = 100.0
    slow_min_triangulation_deg: float = 1.0
    none_ba_iterations: int = 10
    # ... and the front end's rotations are held more loosely: at 0.01 deg loop closing made two of five
    # --scale none routes worse and the hand-held walk's ATE after Sim(3) grew from 1.0 to 1.4 cm
    none_rotation_prior_deg: float = 0.05
    none_rotation_prior_inflation: float = 10.0  # rotation_prior_inflation's value with --scale none
    # ... and PnP is used with this inlier ratio. At every 2nd or 3rd KITTI frame, after a turn, half the landmarks
    # a frame matches come from keyframes the two-view motion placed at the map's last speed, and PnP refused 17
    # frames in a row with 20-60 inliers (00 150:300:2 seed 1); 0.35 took KITTI's steps 2-3 from 2.07 / 3.57 to
    # 1.41 / 2.98 % but TUM fr1_xyz seed 1 from 2.3 to 7.4 cm (docs/map-backend.md), so it stays at 0.5
    none_pnp_min_inlier_ratio: float = 0.5
    none_starving_keyframes: bool = True  # starving_keyframes with --scale none
    # a PnP pose with an inlier ratio from low_ratio_pnp_min_ratio up to pnp_min_inlier_ratio is used only when
    # its step from the keyframe points within low_ratio_direction_deg of the two-view step (with --scale none:
    # none_low_ratio_pnp_min_ratio; 1.0: never)
    low_ratio_pnp_min_ratio: float = 1.0
    none_low_ratio_pnp_min_ratio: float = 0.35
    low_ratio_direction_deg: float = 5.0
    # ... and each keyframe-to-keyframe distance enters BA as a prior at its length before the adjustment, with
    # this sigma (a fraction of it; 0: no prior): left free, BA lengthened each step by 0.3-0.5 %, which
    # accumulated into scale drift (KITTI 00/05 Sim(3) t_err mean 3.31 -> 2.70 %, docs/map-backend.md)
    none_step_sigma: float = 0.003
    # relocalisation
    reloc_keyframes: int = 10  # landmarks of this many recent keyframes are searched
    reloc_fast_threshold: int = 15  # FAST corners of the lost frame that are described and matched
    reloc_ratio: float = 0.8  # Lowe's ratio test of the descriptor matches
    reloc_threshold_px: float = 3.0
    reloc_iterations: int = 500
    reloc_min_inliers: int = 30
    # local-map tracking by projection (vslam_core/mapping/local_map.py) and guided relocalisation. Off by
    # default: re-finding landmarks every frame and keeping rejected tracks as keyframe observations did not
    # make KITTI more accurate (--scale none mean 3.32 -> 3.30 %, --scale gt ATE 0.117 -> 0.136 m) and made
    # the synthetic street worse (0.23 -> 0.46 % after Sim(3)); guided relocalisation goes with it (off, it
    # relocalised 00 without frames 106-112 17 deg off, where the code before it passed)
    local_map_tracking: bool = False
    local_map_keyframes: int = 10  # keyframes sharing the most landmarks with the reference one (plus neighbours)
    local_map_radius_px: float = 8.0  # search window half-size around a projection on a tracked frame
    local_map_max_distance: int = 64  # Hamming distance (of 256 bits) of a match at most
    local_map_ratio: float = 0.8  # Lowe's ratio test among the corners of one window
    local_map_levels: int = 3  # pyramid levels the frame's corners are described at (multi-scale)
    local_map_scale: float = 1.2  # scale factor between pyramid levels
    reloc_radius_px: float = 24.0  # first search window half-size around the motion model's prediction
    reloc_widenings: int = 4  # the window doubles this many times before the unguided search
    # PnP on the tracked landmarks failed: the local map searched by projection from the predicted pose before
    # the two-view pose is used (vslam_core/mapping/map_search.py), in a window of half-size
    # max(search_min_radius_px, search_motion_fraction x the predicted pixel motion), doubled search_widenings times.
    # Off by default: on KITTI --scale none at steps 2-3 it took the 150-frame windows' mean from 2.98 to 2.47 %
    # but made 0:300:3 worse (00 15.1 -> 23.8 %; docs/map-backend.md). Off, PnP's failures are still diagnosed.
    map_search: bool = False
    search_min_radius_px: float = 16.0
    search_motion_fraction: float = 0.3
    search_widenings: int = 2
    # ... when the prediction is the two-view pose (rotation and direction measured), each landmark is searched
    # within this many px of the segment its projection sweeps as the step's length goes over (1 -/+ f) x the
    # predicted, f = search_motion_fraction, doubled on each widening; 0: square windows as above
    search_band_px: float = 0.0
    # ... and its ratio test compares the best corner with the best one more than this many px from it (0: with any)
    search_rival_px: float = 0.0
    # map_search with --scale none. Off: on the KITTI rows of the matrix (map, none, seeds 0-1) all rows went 2.14 ->
    # 3.33 % with square windows, 2.93 % with search_band_px = 4, 3.06 % adding search_rival_px = 3: it helps 00
    # 0:150:3 (4.1 -> 2.7-3.1 %) but 00 150:300:3 seed 0 loses its map in the turn (6.8 -> 25-34 %) (map-backend.md)
    none_map_search: bool = False
    # --scale none: a frame placed by its two-view motion takes the step length that best reprojects the landmarks
    # it still sees when this many agree (map_search.fitted_two_view; 0: off), within this factor of the map's speed
    step_fit_min_inliers: int = 0
    step_fit_max_ratio: float = 2.0
    step_fit_speed: bool = False
    # ... else its length from points the two frames before it triangulate when this many agree (the relative scale,
    # map_scale.TwoViewLength), else the last step's; 0: the map's speed
    relative_step_min_points: int = 20
    relative_step_min_deg: float = 1.0  # ... points whose rays meet at this angle or more
    relative_step_min_interval_s: float = 0.15  # ... frames at least this far apart in time (else the map's speed)
    # a frame that sees too few of the map's landmarks (in view or tracked) is made a keyframe, so that landmarks
    # are triangulated while its tracks still overlap the last keyframe's (always so with map_search; with
    # --scale none none_starving_keyframes replaces it: on by default there, off with gt and height, where at
    # step 3 it took the height rows' t_err from 18.1 to 21.8 %, docs/map-backend.md)
    starving_keyframes: bool = False
    starving_min_triangulation_deg: float = 0.0  # > 0: such a keyframe's new landmarks need rays meeting at this
    # a landmark re-found, or followed by a track PnP rejected, this close to its projection (px) is observed by
    # a keyframe made then (for BA only); within pnp_threshold_px it is linked again
    keyframe_observation_px: float = 4.0


@dataclass(frozen=True)
class LoopConfig:
    """`backend = "map"`: loop closing (vslam_core/loop/): place recognition, verification, pose graph."""

    enabled: bool = True
    features: int = 1000  # strongest FAST corners of a keyframe described (upright ORB) for place recognition
    fast_threshold: int = 15
    vocabulary_words: int = 1024  # binary words, built from the run's first keyframes (nothing downloaded)
    vocabulary_keyframes: int = 8  # keyframes whose descriptors build the vocabulary
    min_separation_keyframes: int = 30  # candidates are at least this many keyframes older than the query
    min_score_ratio: float = 1.0  # a candidate scores at least this share of the query's best recent neighbour
    max_candidates: int = 3  # best-scoring candidates verified per keyframe
    match_ratio: float = 0.8  # Lowe's ratio test of the descriptor matches
    pnp_threshold_px: float = 3.0
    pnp_iterations: int = 500
    min_inliers: int = 40  # PnP inliers for a candidate to be verified
    min_inlier_ratio: float = 0.3  # ... and this share of its matches
    consistency: int = 2  # consecutive keyframes that must verify the same place before the loop is closed
    cooldown_keyframes: int = 5  # keyframes after a closed loop before the next may close
    # pose graph: keyframe-to-keyframe edges with a metric scale (gt, height). Of the order of the odometry's own
    # drift between keyframes (KITTI: ~0.01° and ~0.02 m per 3 m): looser, the loop edges bent the whole path
    # (KITTI 05 0..149..0 ATE 0.469 m, vo 0.442 m; with these 0.361 m, docs/map-backend.md)
    odometry_sigma_deg: float = 0.05
    odometry_sigma_m: float = 0.01
    # ... and with --scale none (Sim(3) edges; translation in the map's units)
    none_odometry_sigma_deg: float = 0.5
    none_odometry_sigma_m: float = 0.1
    loop_sigma_deg: float = 0.2  # the loop edge
    loop_sigma_m: float = 0.05


@dataclass(frozen=True)
class EngineConfig:
    """Everything that decides the trajectory. Same config + same input = same trajectory."""

    scale: ScaleSource = "gt"
    backend: Backend = "map"  # vo: frame-to-keyframe odometry; map: keyframes, landmarks, PnP, windowed BA
    threads: int = 2  # CPU threads: ≥ 2 decodes the next frame in the background and lets OpenCV use
    # that many; results are identical for any value (tested)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    pose: PoseConfig = field(default_factory=PoseConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    height: HeightScaleConfig = field(default_factory=HeightScaleConfig)
    map: MapConfig = field(default_factory=MapConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)

    def with_scale(self, scale: ScaleSource) -> EngineConfig:
        return dataclasses.replace(self, scale=scale)

    def with_backend(self, backend: Backend) -> EngineConfig:
        return dataclasses.replace(self, backend=backend)

    def with_camera_height(self, metres: float) -> EngineConfig:
        return dataclasses.replace(self, height=dataclasses.replace(self.height, camera_height_m=metres))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def for_image_width(self, width: int) -> EngineConfig:
        """The config for frames `width` pixels wide: the pixel sizes that describe image content, not
        measurement precision, grow with the camera (`pixel_scale`): the corner spacing times the scale, the
        KLT pyramids ``round(log2 scale)`` levels deeper (the 13-px window then sees at the top level what it
        sees on a 1241-px frame). Identical at or under `REFERENCE_WIDTH_PX` (KITTI, TUM, EuRoC)."""
        factor = pixel_scale(width)
        if factor == 1.0:
            return self
        levels = round(math.log2(factor))
        tracker = dataclasses.replace(
            self.tracker, max_level=self.tracker.max_level + levels,
            predicted_max_level=self.tracker.predicted_max_level + levels if self.tracker.predicted_max_level >= 0
            else self.tracker.predicted_max_level)
        detector = dataclasses.replace(self.detector, min_distance_px=round(self.detector.min_distance_px * factor))
        return dataclasses.replace(self, tracker=tracker, detector=detector)


#: The frame width the pixel-valued defaults were tuned on (KITTI 00's 1241 px): wider frames scale them.
REFERENCE_WIDTH_PX = 1241


def pixel_scale(width: int) -> float:
    """How many times wider than `REFERENCE_WIDTH_PX` frames `width` px wide are, never under 1 (narrower cameras
    keep the defaults they were also checked on: TUM 640 px, EuRoC 752 px)."""
    return max(1.0, width / REFERENCE_WIDTH_PX)


def describe_pixel_scale(config: EngineConfig, width: int) -> str | None:
    """What `EngineConfig.for_image_width` changed for frames `width` px wide, in one line (None when nothing)."""
    factor = pixel_scale(width)
    if factor == 1.0:
        return None
    scaled = config.for_image_width(width)
    return (f"{width} px wide, {factor:.2f}x KITTI's {REFERENCE_WIDTH_PX}: corner spacing "
            f"{scaled.detector.min_distance_px} px, KLT pyramid {scaled.tracker.max_level} levels, image checks "
            "measured 620 px wide")
