"""The map's own scale with `--scale none`: step lengths in map units, never unit steps.

Without a scale source, a monocular map has one arbitrary scale, fixed when it was initialised (the first
keyframes are chained at one unit a frame) and carried on by PnP against its landmarks and by landmarks
triangulated from poses in that scale (Strasdat et al., "Scale drift-aware large scale monocular SLAM",
RSS 2010, sec. I: the scale is a gauge freedom that only drifts, it is not measured per frame). Where a
frame's pose cannot come from the map (PnP failed its checks, a dead-reckoned frame), the essential matrix
still gives the direction of its step; `MapSpeed` gives the length: the recent speed of the camera in map
units (the median step over the last `frames` frames with a pose), times the frames since the keyframe the
step is measured from. A constant-velocity prior, as the motion model of ORB-SLAM's tracking (Mur-Artal et
al. 2015, sec. V-B) predicts a frame from the last two.

`MapSpeed` is a `ScaleProvider` (vslam_core/scale.py): the map backend hands it to the odometry front end and
to dead reckoning in place of `UnitScale`, and tells it every frame's pose (`observe`).

With a scale source the map takes its steps' lengths from it (`pnp_pose`, `metric_step`: the BA's range priors),
except with `--scale height` on a frame without a road plane, where it keeps its own scale, as without one
(`height_unmeasured`). The map's other settings follow the scale source (`for_scale`), and with one, the camera's
motion too: a camera moving sideways takes `--scale none`'s (`sideways_camera`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from vslam_core.config import EngineConfig, MapConfig, ScaleSource
from vslam_core.geometry import (
    in_front_with_parallax,
    invert_pose,
    normalise_points,
    pose_matrix,
    rotation_angle,
    triangulate,
    triangulate_each,
)
from vslam_core.lens import undistort_pixels
from vslam_core.mapping.local_mapping import well_triangulated
from vslam_core.mapping.map import Keyframe, Map
from vslam_core.mapping.map_search import fitted_step, fitted_two_view, rescale_step
from vslam_core.mapping.pnp import metric_pose, solve_pnp
from vslam_core.results import FrameResult, KeyframeInserted, PnPEstimate, Reason, ScaleEstimate, TrackFate
from vslam_core.scale import ScaleProvider, TwoView
from vslam_core.sources.base import CameraIntrinsics
from vslam_core.two_view import derotated_parallax, two_view_motion

#: Why a keyframe was made when it starts a map (segment): it is the map's start only with enough landmarks.
STARTING_REASONS = ("initialisation", "re-initialisation", "new map segment")
#: Steps whose median is the speed.
SPEED_FRAMES = 5
#: Speed (map units a frame) before any step is known: the map's first baseline is one unit a frame.
INITIAL_SPEED = 1.0


class MapSpeed:
    """Step lengths in the map's units from the camera's recent speed (see the module docstring)."""

    name: ScaleSource = "none"

    def __init__(self, frames: int = SPEED_FRAMES) -> None:
        self._last: tuple[int, np.ndarray] | None = None  # (run position, camera centre) of the last pose
        self._speeds: deque[float] = deque(maxlen=frames)  # map units a frame

    def observe(self, position: int, T_world_cam: np.ndarray, measured: bool) -> None:  # noqa: N803
        """The pose of the frame at run `position`. Only `measured` poses (from the map) give a speed; the
        others (held, chained from the speed itself) only move the reference point."""
        centre = T_world_cam[:3, 3].copy()
        if measured and self._last is not None and position > self._last[0]:
            self._speeds.append(float(np.linalg.norm(centre - self._last[1])) / (position - self._last[0]))
        self._last = (position, centre)

    def move(self, S: np.ndarray) -> None:  # noqa: N803
        """A loop correction moved the world by the (4, 4) similarity S: the speeds are s times larger."""
        scale = float(np.cbrt(np.linalg.det(S[:3, :3])))
        self._speeds = deque((scale * v for v in self._speeds), maxlen=self._speeds.maxlen)
        if self._last is not None:
            self._last = (self._last[0], S[:3, :3] @ self._last[1] + S[:3, 3])

    @property
    def speed(self) -> float:
        """Map units a frame: the median of the recent measured speeds (`INITIAL_SPEED` before any)."""
        return float(np.median(self._speeds)) if self._speeds else INITIAL_SPEED

    def step_length(self, view: TwoView) -> tuple[float, ScaleEstimate | None]:
        """The length of the step keyframe → current frame: the speed times the frames between them."""
        return self.speed * max(view.cur_position - view.key_position, 1), None


class TwoViewLength:
    """--scale none: the length of a step the map could not place (PnP failed: a turn at a low frame rate), from
    the images rather than `MapSpeed`'s constant speed, which a car leaving a turn outruns (KITTI 05 0:300:2: the
    step over the truth's fell 1.05 → 0.64 over 10 frames placed at the map's last speed, and PnP kept that scale
    to the end). In turn: the landmarks the frame still sees (`map_search.fitted_two_view`, off by default); the
    relative scale of monocular odometry (Nistér et al., "Visual odometry", CVPR 2004, §4.2; Scaramuzza &
    Fraundorfer, "Visual Odometry, Part I", 2011, §V): the tracks the two frames before it saw triangulate points
    in the map's units, and the step's length is the one that reprojects them onto the frame
    (`map_search.fit_step_length`: rotation and direction from the images, the length by one-point RANSAC); when
    too few points agree, the last step's length (a constant velocity from the last two poses, as ORB-SLAM's
    motion model) rather than the median of the last measured ones; else the map's speed (`two_view` as given)."""

    def __init__(self, K: np.ndarray, lens: CameraIntrinsics) -> None:  # noqa: N803
        self._K, self._lens = K, lens
        # a frame's position, (M,) track ids, (M, 2) raw pixels in the frame before it, and its timestamp
        self._previous: tuple[int, np.ndarray, np.ndarray, float | None] | None = None

    def place(self, two_view: np.ndarray, vo: FrameResult, pnp: PnPEstimate | None, world: Map,
              pose_of: Callable[[int], np.ndarray], held: set[int], config: MapConfig) -> tuple[np.ndarray, str]:
        """(4, 4) T_world_cam of the frame `vo`, whose `two_view` pose is its motion from its keyframe
        (`vo.T_key_cur`) at the map's speed, with its step's length measured as above; and where that length came
        from: "landmarks", "tracks", "last step" or "speed". `pose_of`: an earlier frame's pose; `held`: the
        positions of frames that had none."""
        if pnp is not None and vo.T_key_cur is not None and \
                (fitted := fitted_two_view(world, pose_of(vo.keyframe_position), vo.T_key_cur, pnp, self._K,
                                           config)) is not None:
            return fitted, "landmarks"
        relative = self._relative(vo, pose_of, held, config)
        return (two_view, "speed") if relative is None else relative

    def remember(self, vo: FrameResult) -> None:
        self._previous = (vo.position, vo.track_ids, vo.track_prev, vo.timestamp)

    def _relative(self, vo: FrameResult, pose_of: Callable[[int], np.ndarray], held: set[int],
                  config: MapConfig) -> tuple[np.ndarray, str] | None:
        """The relative scale's pose, or the last step's, and which; None (the map's speed) when off, when the frame
        is under `relative_step_min_interval_s` after the one before, or when either frame before it had no pose."""
        previous, position = self._previous, vo.position
        if config.relative_step_min_points <= 0 or vo.T_key_cur is None or previous is None or \
                previous[0] != position - 1 or {position - 1, position - 2} & held:
            return None
        if vo.timestamp is not None and previous[3] is not None and \
                vo.timestamp - previous[3] < config.relative_step_min_interval_s:
            return None  # a constant speed holds over so short an interval: the map's
        T_world_a, T_world_b, T_world_key = pose_of(position - 2), pose_of(position - 1), pose_of(vo.keyframe_position)  # noqa: N806
        alive = np.flatnonzero(vo.track_fate >= TrackFate.NOT_USED)
        _, mine, theirs = np.intersect1d(vo.track_ids[alive], previous[1], assume_unique=True, return_indices=True)
        a, b, cur = (undistort_pixels(pixels, self._lens) for pixels in
                     (previous[2][theirs], vo.track_prev[alive[mine]], vo.track_cur[alive[mine]]))
        points, rows = triangulated_points(T_world_a, T_world_b, normalise_points(a, self._K),
                                           normalise_points(b, self._K), config.relative_step_min_deg)
        enough = config.relative_step_min_points
        if len(points) >= enough and (fitted := fitted_step(T_world_key, vo.T_key_cur, points, cur[rows], self._K,
                                                            config, enough)) is not None:
            return fitted, "tracks"
        last = float(np.linalg.norm(T_world_b[:3, 3] - T_world_a[:3, 3]))
        return np.asarray(T_world_key @ rescale_step(vo.T_key_cur, last * (position - vo.keyframe_position))), \
            "last step"


def triangulated_points(T_world_a: np.ndarray, T_world_b: np.ndarray, a: np.ndarray, b: np.ndarray,  # noqa: N803
                        min_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The (P, 3) world points of the (N, 2) normalised correspondences `a`, `b` of two posed frames (midpoint
    triangulation, `geometry.triangulate`) that lie in front of both and whose rays meet at `min_deg` or more,
    and the (P,) rows of those correspondences."""
    T_a_b = invert_pose(T_world_a) @ T_world_b  # noqa: N806
    rotation, translation = T_a_b[:3, :3], T_a_b[:3, 3]
    if len(a) == 0 or np.linalg.norm(translation) < 1e-12:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    in_b = triangulate(rotation, translation, b, a)
    kept = in_front_with_parallax(in_b, in_b @ rotation.T + translation, translation, min_deg)
    return in_b[kept] @ T_world_b[:3, :3].T + T_world_b[:3, 3], np.flatnonzero(kept)


def for_scale(config: MapConfig, scale: ScaleSource) -> MapConfig:
    """The map's settings under this scale source. With `none` nothing outside the map holds the scale, so a
    landmark's depth must be well conditioned (rays meeting at `none_min_triangulation_deg`) and bundle
    adjustment must converge (`none_ba_iterations`): on KITTI 05 0:300 these took the Sim(3)-aligned t_err
    from 8.6 % to 6.7 % and 7.0 % (6.4 % together with keyframes spaced by translation parallax). The front
    end's rotations are held more loosely (`none_rotation_prior_deg`: at the metric sources' 0.01° loop closing
    made two of five routes worse, docs/map-backend-history.md); a revisit's keyframes are not culled
    (`none_cull_revisits`). The map is adjusted as a whole when the run ends (`none_adjust_at_end`)."""
    if scale != "none":
        return config
    return replace(config, min_triangulation_deg=config.none_min_triangulation_deg,
                   ba_iterations=config.none_ba_iterations, rotation_prior_deg=config.none_rotation_prior_deg,
                   rotation_prior_inflation=config.none_rotation_prior_inflation,
                   pnp_min_inlier_ratio=config.none_pnp_min_inlier_ratio,
                   low_ratio_pnp_min_ratio=config.none_low_ratio_pnp_min_ratio,
                   starving_keyframes=config.none_starving_keyframes, cull_revisits=config.none_cull_revisits,
                   map_search=config.map_search or config.none_map_search,
                   adjust_at_end=config.none_adjust_at_end)


def forward_share(map_: Map, newest: int | None = None, min_step_depth: float = 0.0) -> float | None:
    """Median over consecutive keyframes of a segment (the `newest` keyframes only, if given) of |cos| between the
    step and the earlier keyframe's optical axis (z): ~1 for a car or a walk ahead, 0.25-0.39 for the hand-held
    TUM frames. A step shorter than `min_step_depth` times the median depth of the earlier keyframe's landmarks (a
    standstill: its direction is noise) does not count; None when no step counts."""
    keyframes = list(map_.keyframes.values())[-(newest or 0):]
    shares = []
    for before, after in zip(keyframes, keyframes[1:], strict=False):
        step = before.T_world_cam[:3, :3].T @ (after.T_world_cam[:3, 3] - before.T_world_cam[:3, 3])  # in `before`
        length = float(np.linalg.norm(step))
        depth = median_depth(map_, before) if min_step_depth > 0 else None
        if before.segment == after.segment and length > 1e-9 and (depth is None or length >= min_step_depth * depth):
            shares.append(abs(float(step[2])) / length)
    return float(np.median(shares)) if shares else None


def sideways_camera(map_: Map, config: MapConfig, scale: ScaleSource) -> float | None:
    """With a scale source, at each keyframe once the map holds `sideways_keyframes`: the `forward_share` of the
    newest `sideways_keyframes` (a standstill's steps left out, `sideways_min_step_depth`). At most
    `sideways_forward_share` the camera moves sideways (a hand-held camera at a desk): a one-frame baseline cannot
    tell a turn from a slide there, and the windows' bundle adjustment is what recovers the turn (docs/method.md),
    so the map takes `--scale none`'s settings from then on (`for_scale`: rotations held loosely where ambiguous,
    landmarks from well-conditioned rays, converged windows, the map adjusted as a whole at the end), the steps'
    lengths still the scale source's. None: not yet (or no step counted), or off (`sideways_as_none`)."""
    if scale == "none" or not config.sideways_as_none or len(map_.keyframes) < config.sideways_keyframes:
        return None
    return forward_share(map_, config.sideways_keyframes, config.sideways_min_step_depth)


def front_end_config(config: EngineConfig, map_config: MapConfig) -> EngineConfig:
    """The front end's settings under the map (`map_config`, `for_scale`'s): each frame's refined two-view
    rotation comes with its covariance when bundle adjustment's rotation prior uses it (or may: a camera moving
    sideways takes `--scale none`'s prior, `sideways_camera`)."""
    if map_config.rotation_prior_inflation <= 0 and not (config.scale != "none" and map_config.sideways_as_none):
        return config
    return replace(config, pose=replace(config.pose, rotation_covariance=True))


def translation_parallax(T_world_key: np.ndarray, T_world_cur: np.ndarray, pixels_cur: np.ndarray,  # noqa: N803
                         pixels_key: np.ndarray, K: np.ndarray) -> float:  # noqa: N803
    """Median distance (px) between (N, 2) keyframe pixels and the (N, 2) current pixels moved by the rotation
    between the two poses alone (a point at infinity: x_key ∝ K·R_key_cur·K⁻¹·x_cur): the parallax the
    translation caused, which is what conditions a triangulation. Pixels are ideal pinhole pixels."""
    return derotated_parallax(T_world_key[:3, :3].T @ T_world_cur[:3, :3], pixels_cur, pixels_key, K)


def initialisation(config: EngineConfig, K: np.ndarray, T_world_key: np.ndarray,  # noqa: N803
                   T_world_cam: np.ndarray, pixels: np.ndarray, key_pixels: np.ndarray,  # noqa: N803
                   close_chirality: bool, waited: int, chain_measured: bool) -> tuple[str, np.ndarray, bool] | None:
    """--scale none, before the map has landmarks: the next keyframe's baseline sets the map's scale, so it
    waits for a well-conditioned two-view reconstruction from the last keyframe: a translation parallax
    (rotation removed) of `init_parallax_px` between the (N, 2) ideal `pixels` of the keyframe's tracks now and
    their `key_pixels`, and an unambiguous chirality (`close_chirality`: the front end's, this frame). Pure
    rotation and too short a baseline leave the translation, and so the scale, undetermined (Mur-Artal et al.,
    "ORB-SLAM", 2015, sec. IV, which likewise waits for parallax before it initialises).

    A camera whose median track never gets that parallax (a slow hand-held camera seeing far façades and sky)
    starts once it has `waited` frames
    (`init_wait_frames`) from the two views alone: the essential matrix of the keyframe's tracks and this
    frame, unambiguous, with `init_min_landmarks` of its points triangulated as landmarks
    (`local_mapping.well_triangulated`: rays meeting at `min_triangulation_deg`). Its keyframe is then placed
    by that motion rather than by the chain of short steps (unless each of them was measured:
    `chain_measured`), as far from the last keyframe as the chain (the map's units so far). When the points'
    median depth is more than `slow_depth_frames` frames of travel (a slow camera), rays meeting at
    `slow_min_triangulation_deg` make its landmarks (`slow_camera`).

    Returns None while it waits, else the keyframe's reason, its pose and whether the camera is slow. If the
    keyframe's tracks are lost first, initialisation starts again from this frame, at its own pose `T_world_cam`."""
    cfg = config.map
    if len(pixels) < cfg.pnp_min_landmarks:
        return "re-initialisation: tracks lost", T_world_cam, False
    parallax = translation_parallax(T_world_key, T_world_cam, pixels, key_pixels, K)
    if parallax >= cfg.init_parallax_px and not close_chirality:
        return f"initialisation: parallax {parallax:.0f} px", T_world_cam, False
    if waited < cfg.init_wait_frames:
        return None
    order = np.random.default_rng((config.pose.seed, waited, 3)).permutation(len(pixels))
    motion = two_view_motion(pixels, key_pixels, K, config, order, {})
    if (motion.reason is not None or motion.rotation is None or motion.translation is None
            or motion.close_chirality(config.health.ambiguous_chirality)):
        return None
    chained = T_world_key[:3, :3].T @ T_world_cam[:3, :3]
    if np.degrees(rotation_angle(chained.T @ motion.rotation)) > cfg.max_rotation_disagreement_deg:
        return None  # low parallax lets rotation and translation trade off (bas-relief): the chain's is trusted
    T_key_cur = pose_matrix(motion.rotation, motion.translation)  # noqa: N806
    inliers = motion.inlier_mask if motion.inlier_mask is not None else np.ones(len(pixels), bool)
    x_cur, x_key = normalise_points(pixels[inliers], K), normalise_points(key_pixels[inliers], K)
    points = triangulate(motion.rotation, motion.translation, x_cur, x_key)  # in baselines of `waited` frames
    depths = points[np.isfinite(points[:, 2]), 2]  # rows of parallel rays are NaN
    slow = bool(len(depths)) and float(np.median(depths)) * waited > cfg.slow_depth_frames
    landmarks = int(well_triangulated(points, np.broadcast_to(T_key_cur, (len(points), 4, 4)), pixels[inliers],
                                      key_pixels[inliers], K, landmark_settings(cfg, slow)).sum())
    if landmarks < cfg.init_min_landmarks:
        return None
    why = f"initialisation: two views {waited} frames apart, {landmarks} landmarks"
    if chain_measured:
        return why, T_world_cam, slow
    length = float(np.linalg.norm(T_world_cam[:3, 3] - T_world_key[:3, 3]))
    return why, T_world_key @ pose_matrix(motion.rotation, max(length, 1e-6) * motion.translation), slow


def slow_camera(the_map: Map, keyframe_id: int, speed: float, config: MapConfig) -> bool:
    """--scale none: whether the landmarks a keyframe observes lie at a median depth of more than
    `slow_depth_frames` frames of travel at `speed` (map units a frame). A hand-held camera moves
    1/100-1/400 of its scene's depth a frame, a car 1/10-1/50: the rays of a slow camera's landmarks rarely
    meet at `none_min_triangulation_deg` (3.5°), and without new landmarks its map starves. Scale-free: depth
    and speed are both in the map's units."""
    keyframe = the_map.keyframes[keyframe_id]
    depth = median_depth(the_map, keyframe)
    return depth is not None and depth > config.slow_depth_frames * speed


def median_depth(the_map: Map, keyframe: Keyframe) -> float | None:
    """Median depth of the landmarks `keyframe` observes, in its camera; None when it observes none."""
    ids = np.array([i for i in keyframe.landmark_ids if i in the_map.landmarks], np.int64)
    if not len(ids):
        return None
    T_cam_world = invert_pose(keyframe.T_world_cam)  # noqa: N806
    return float(np.median(the_map.positions(ids) @ T_cam_world[2, :3] + T_cam_world[2, 3]))


def landmark_settings(config: MapConfig, slow: bool, starving: bool = False) -> MapConfig:
    """The map's settings for new landmarks: rays meeting at `slow_min_triangulation_deg` for a slow camera, at
    no more than `starving_min_triangulation_deg` at a keyframe made because the frame saw too few landmarks."""
    if slow:
        return replace(config, min_triangulation_deg=config.slow_min_triangulation_deg)
    if starving and config.starving_min_triangulation_deg > 0:
        return replace(config, min_triangulation_deg=min(config.min_triangulation_deg,
                                                         config.starving_min_triangulation_deg))
    return config


def initialised(config: MapConfig, keyframe: KeyframeInserted) -> bool:
    """--scale none: whether this keyframe starts the map. An initialisation keyframe does when its two-view
    reconstruction triangulated `init_min_landmarks` landmarks (ORB-SLAM likewise rejects an initialisation with
    too few triangulated points, Mur-Artal et al. 2015, sec. IV-4): with fewer, rotation-dominated motion or a
    poor relative pose, tracking would have too little map to place frames by PnP, so the next keyframe tries
    again. So does the first keyframe of a new map segment; one made for another reason (tracking, relocalised
    into the map) finds the map started."""
    if not keyframe.why.startswith(STARTING_REASONS):
        return True
    return keyframe.new_landmarks >= config.init_min_landmarks


class FramesBeforeMap:
    """--scale none: the frames tracked while the map waits for its initialisation, with their tracks. Until
    then their poses are chained from the front end's short steps at the map's guessed speed; once the map
    starts, `place` measures them by PnP
    against its first landmarks, which their tracks saw (ORB-SLAM outputs no pose at all before it initialises;
    these frames get one in the map's own scale)."""

    def __init__(self) -> None:
        self._frames: list[tuple[int, np.ndarray, np.ndarray]] = []  # (run position, (T,) track ids, (T, 2) px)
        self.placed = 0  # frames `place` placed over the run (the summary's: their tracking-time mode says two-view)

    def add(self, position: int, track_ids: np.ndarray, pixels: np.ndarray, min_shared: int) -> None:
        """A frame with a pose before the map started: its live tracks at their (T, 2) ideal pixels. The frames
        kept that share fewer than `min_shared` (`pnp_min_landmarks`) of these tracks are forgotten: tracks only
        die, so `place` could never link them to that many landmarks (memory follows the tracks, however long
        the map waits)."""
        self._frames = [f for f in self._frames if np.isin(f[1], track_ids).sum() >= min_shared]
        self._frames.append((position, track_ids.copy(), pixels.copy()))

    def clear(self) -> None:
        self._frames = []

    def place(self, links: dict[int, int], the_map: Map, relative: dict[int, tuple[int, np.ndarray]],
              K: np.ndarray, config: MapConfig, seed: int) -> None:  # noqa: N803
        """Each frame kept that PnP places against the landmarks the map started with (`links`: track id ->
        landmark id), with tracking's thresholds, is stored at that pose relative to its keyframe (`relative`: run
        position -> (keyframe id, (4, 4) T_key_frame), as tracking stored it); the frames are then forgotten."""
        positions = {i: the_map.landmarks[i].position for i in links.values()}
        for position, track_ids, pixels in self._frames:
            linked = np.array([t in links for t in track_ids.tolist()], bool)
            if linked.sum() < config.pnp_min_landmarks:
                continue
            points = np.array([positions[links[t]] for t in track_ids[linked].tolist()])
            placed = placed_by_pnp(points, pixels[linked], K, config, (seed, position, 4))
            if placed is not None:
                key = the_map.keyframes[relative[position][0]]
                relative[position] = (key.id, invert_pose(key.T_world_cam) @ placed)
                self.placed += 1
        self.clear()


def place_attempts(the_map: Map, keyframe: Keyframe, links: dict[int, int], K: np.ndarray,  # noqa: N803
                   config: MapConfig, seed: int) -> None:
    """--scale none, at the keyframe that starts the map (`keyframe`; `links`: track id -> the landmarks it
    triangulated): the segment's keyframes made by earlier attempts (too few landmarks) sit where the front end's
    chain put them, at the map's guessed speed, and so do the landmarks first seen there. A car pulling away
    outruns the guess: on KITTI 05 from frame 150 at every 3rd frame the attempt's keyframe (5th frame) lay 9 %
    further from the first than the new landmarks say, and the map carried it (t_err 1.95 % where every frame
    gives 0.90). Each such keyframe is placed by PnP against the new landmarks it saw that were triangulated
    without it (from the segment's first keyframe to this one), with tracking's thresholds, and the landmarks
    first or last seen at a keyframe moved are triangulated again between those two.

    Left where they are: the segment's first keyframe (the gauge); an attempt one frame after it, whose one
    chained step is the map's unit with no change of speed to miss (placed anyway, KITTI 00 0:300:3's came out
    3 % short and the run drifted more, at four seeds of four); and an attempt whose rays to those landmarks meet
    the first keyframe's at a median under `attempt_min_ray_angle_deg`, too short a baseline for PnP to measure
    along (a hand-held start, 1.7-1.8 deg on TUM fr1_xyz: placed anyway, one run in four went 1.3 -> 3.9 cm)."""
    if len(links) < config.init_min_landmarks:
        return  # the attempt failed too (`initialised`)
    started = set(links.values())
    earlier = [k for k in the_map.keyframes.values() if k.segment == keyframe.segment and k.id != keyframe.id]
    moved: set[int] = set()
    for attempt in (k for k in earlier[1:] if k.position - earlier[0].position > 1):
        ids = sorted(i for i in started & attempt.landmark_ids if the_map.landmarks[i].first_keyframe != attempt.id)
        if len(ids) < config.pnp_min_landmarks:
            continue
        points = the_map.positions(ids)
        if median_ray_angle(points, earlier[0].T_world_cam, attempt.T_world_cam) < config.attempt_min_ray_angle_deg:
            continue  # too short a baseline from the first keyframe for PnP to measure (a hand-held start)
        pixels = np.array([the_map.landmarks[i].observations[attempt.id] for i in ids])
        placed = placed_by_pnp(points, pixels, K, config, (seed, attempt.position, 5))
        if placed is not None:
            attempt.T_world_cam = placed
            moved.add(attempt.id)
    retriangulate(the_map, moved, K, config)


def placed_by_pnp(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, config: MapConfig,  # noqa: N803
                  seed: tuple[int, ...]) -> np.ndarray | None:
    """(4, 4) T_world_cam PnP gives from (N, 3) landmarks seen at (N, 2) ideal pixels, when it keeps tracking's
    `pnp_min_inliers` and `pnp_min_inlier_ratio` of them (a frame or keyframe placed when the map starts); else None."""
    solution = solve_pnp(points, pixels, K, config.pnp_threshold_px, config.pnp_iterations, seed)
    inliers = int(solution.inlier_mask.sum())
    enough = inliers >= max(config.pnp_min_inliers, config.pnp_min_inlier_ratio * len(points))
    return solution.T_world_cam if solution.T_world_cam is not None and enough else None


def median_ray_angle(points: np.ndarray, T_world_a: np.ndarray, T_world_b: np.ndarray) -> float:  # noqa: N803
    """Median angle (degrees) at which the rays from two camera centres (poses (4, 4)) meet at (N, 3) world points."""
    rays_a, rays_b = points - T_world_a[:3, 3], points - T_world_b[:3, 3]
    cosines = np.sum(rays_a * rays_b, axis=1) / (np.linalg.norm(rays_a, axis=1) * np.linalg.norm(rays_b, axis=1))
    return float(np.degrees(np.median(np.arccos(np.clip(cosines, -1.0, 1.0)))))


def retriangulate(the_map: Map, moved: set[int], K: np.ndarray, config: MapConfig) -> None:  # noqa: N803
    """The landmarks whose first or last keyframe is in `moved` triangulated again between those two keyframes
    (midpoint), where the point is still in front of both and reprojects within `max_reprojection_px` into both;
    the others keep their position."""
    landmarks = [the_map.landmarks[i] for i in sorted({i for k in moved for i in the_map.keyframes[k].landmark_ids})]
    pairs = [(m, min(m.observations), max(m.observations)) for m in landmarks]
    pairs = [(m, first, last) for m, first, last in pairs if first != last and {first, last} & moved]
    if not pairs:
        return
    T_world_last = np.array([the_map.keyframes[last].T_world_cam for _, _, last in pairs])  # noqa: N806
    T_first_last = np.array([invert_pose(the_map.keyframes[first].T_world_cam) @ the_map.keyframes[last].T_world_cam
                             for _, first, last in pairs])  # noqa: N806
    p_first = np.array([m.observations[first] for m, first, _ in pairs], np.float64)
    p_last = np.array([m.observations[last] for m, _, last in pairs], np.float64)
    points = triangulate_each(T_first_last[:, :3, :3], T_first_last[:, :3, 3], normalise_points(p_last, K),
                              normalise_points(p_first, K))  # in each pair's last camera
    good = well_triangulated(points, T_first_last, p_last, p_first, K, replace(config, min_triangulation_deg=0.0))
    world = np.einsum("nij,nj->ni", T_world_last[:, :3, :3], points) + T_world_last[:, :3, 3]
    for (landmark, _, _), position, ok in zip(pairs, world, good, strict=True):
        if ok:
            landmark.position = position


def height_unmeasured(scale: ScaleSource, frame: FrameResult) -> bool:
    """--scale height: the front end measured no step length for this frame (no road plane, or one over
    `max_jump` off the trend: `scale_held`), so its step is the trend's extrapolation. The map then keeps its own
    scale for the frame (PnP's pose, in the landmarks' scale) and gives bundle adjustment no range prior from it.
    On KITTI 00 150:300:2 the extrapolated trend ran to 40-60 % of the true step over stretches without a plane,
    and held to 5 % in bundle adjustment it shrank the map (17 % short at the end), which kept the shrunk scale
    after the road came back; `vo` forgets it at the next plane (9 % short)."""
    return scale == "height" and frame.scale_estimate is not None and frame.scale_estimate.held


def height_off_map(frame: FrameResult, pnp_pose: np.ndarray, T_world_key: np.ndarray,  # noqa: N803
                   config: EngineConfig) -> list[Reason]:
    """--scale height, a frame PnP placed (pose (4, 4)): `height_off_map` when the step its road plane measured
    from the front end's keyframe (pose `T_world_key`) is over `height.max_jump` off PnP's step, in the map's own
    scale (a plane the trend rejected is `scale_held` already); else no reason."""
    estimate = frame.scale_estimate
    if estimate is None or estimate.held or estimate.measured_step is None:
        return []
    length = float(np.linalg.norm((invert_pose(T_world_key) @ pnp_pose)[:3, 3]))
    off = length > 1e-9 and abs(estimate.measured_step / length - 1) > config.height.max_jump
    return [Reason.HEIGHT_OFF_MAP] if off else []


def pnp_pose(config: EngineConfig, map_config: MapConfig, frame: FrameResult, pnp: PnPEstimate,
             two_view: np.ndarray | None, T_world_key: np.ndarray) -> tuple[np.ndarray, list[Reason]]:  # noqa: N803
    """The (4, 4) pose of a `frame` PnP placed (`pnp.T_world_cam`, checked), and its warnings: PnP's own pose with
    --scale none or when the height was not measured (`height_unmeasured`), else the front end's motion from its
    keyframe (pose `T_world_key`; `two_view` = T_world_key · T_key_cur) at the scale source's length
    (`pnp.metric_pose`); `two_view_outvoted`, `height_off_map`."""
    assert pnp.T_world_cam is not None
    pose = pnp.T_world_cam
    if config.scale != "none" and frame.scale is not None and not height_unmeasured(config.scale, frame):
        pose = metric_pose(pose, None if pnp.outvoted_two_view else two_view, T_world_key, frame.scale,
                           map_config.front_end_agreement_deg)
    warnings = [Reason.TWO_VIEW_OUTVOTED] if pnp.outvoted_two_view else []
    return pose, warnings + height_off_map(frame, pnp.T_world_cam, T_world_key, config)


def metric_step(scale: ScaleSource, provider: ScaleProvider, previous: Keyframe | None, position: int,
                pose: np.ndarray, frame: FrameResult | None = None) -> float | None:
    """Distance of the frame at run `position` (pose (4, 4)) from the `previous` keyframe by the scale source (the
    BA's range prior): gt's own, height's as tracked when the front end measured this `frame`'s step; None for
    --scale none, without a keyframe, or with height unmeasured (`height_unmeasured`)."""
    if scale == "none" or previous is None or (frame is not None and height_unmeasured(scale, frame)):
        return None
    if scale == "gt":
        empty = np.zeros((0, 3))
        return provider.step_length(TwoView(previous.position, position, empty, empty[:, :2]))[0]
    return float(np.linalg.norm(pose[:3, 3] - previous.T_world_cam[:3, 3]))
