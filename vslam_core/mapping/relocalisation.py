"""Relocalisation across a gap, guided by the motion model: the local map projected where the car should be.

After frames the log does not contain (dropped), or frames nothing could be measured on (blurred, dark), the
KLT tracks no longer reach the map. The motion model (`MotionModel`: constant velocity, the turn rate's trend)
extrapolates the last poses to the frame's timestamp (the gap's length comes from the clock, so absent frames
need not exist);
the local map's landmarks are projected with that prediction and searched for in a window around each
projection (vslam_core/mapping/local_map.py, descriptors at several pyramid levels), and the matches go to
PnP in RANSAC. Across a gap the prediction's rotation and direction are first measured from the images
(`gap_motion`: KLT from where the predicted rotation puts the last posed frame's corners, or multi-scale
ORB matches, and the essential matrix). When too few are found, or PnP finds too few inliers, the window
doubles (`reloc_widenings` times from `reloc_radius_px`): a larger gap or a sharper turn than predicted is
searched for further out.
Once a pose is found, the local map is searched again with it in the narrow tracking window and PnP refined
on everything re-found (ORB-SLAM's relocalisation does the same, Mur-Artal et al. 2015, §V-C).

Poses are camera-to-world `T_world_cam` (4, 4); times in seconds (or frame indices without a clock).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.coasting import unit_step
from vslam_core.config import MapConfig
from vslam_core.features import match_descriptors
from vslam_core.geometry import invert_pose, pose_matrix, rotation_angle, so3_exp, so3_log
from vslam_core.lens import distort_pixels, undistort_pairs, undistort_pixels
from vslam_core.mapping.local_map import FrameCorners, LocalMapSearcher
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH
from vslam_core.mapping.map import Map
from vslam_core.mapping.pnp import PnPSolution, solve_pnp
from vslam_core.results import LocalMapSearch, PnPEstimate, Relocalisation
from vslam_core.sources.base import CameraIntrinsics

HISTORY = 5  # poses the motion model keeps: the turn rate's trend is fitted over their intervals


class MotionModel:
    """Constant velocity from the last two poses, with the turn rate's linear trend over the last few.

    Through a turn the rotation rate changes over a gap of several frames (KITTI 00 frames 199 → 208: 2.8°
    a frame before, 32.8° over the next 9, not 25°), so the rotation is integrated from the rate's trend
    along the last rotation axis (a constant angular acceleration fitted by least squares to the rates of
    the last `HISTORY` − 1 intervals), stopped where the rate would change sign (a turn ends, it does not
    reverse); the translation is the last step's, continued for the gap and turned by half the gap's
    rotation (the chord of a circular arc)."""

    def __init__(self) -> None:
        self._last: list[tuple[float, np.ndarray]] = []  # up to HISTORY (time, T_world_cam), oldest first

    def update(self, time: float, T_world_cam: np.ndarray) -> None:  # noqa: N803
        """A frame's final pose at `time` (later than every earlier one)."""
        self._last = [*self._last[-(HISTORY - 1):], (time, T_world_cam.copy())]

    def last_step(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(R, unit t) of the motion between the last two poses; None before two (or without translation)."""
        return unit_step(self._last[-2][1], self._last[-1][1]) if len(self._last) >= 2 else None

    def predict(self, time: float) -> np.ndarray | None:
        """(4, 4) pose at `time`: the last motion (T_a⁻¹·T_b between the last two poses) continued for
        (time − t_b)/(t_b − t_a) of itself, its rotation by the turn rate's trend (class docstring). None
        before two poses."""
        if len(self._last) < 2:
            return None
        (time_a, pose_a), (time_b, pose_b) = self._last[-2:]
        if time_b <= time_a:
            return pose_b.copy()
        motion = np.linalg.inv(pose_a) @ pose_b
        fraction = (time - time_b) / (time_b - time_a)
        rotation = self._rotation(time)
        step = np.eye(4)
        step[:3, :3] = so3_exp(rotation)
        half = so3_exp(0.5 * rotation - 0.5 * so3_log(motion[:3, :3]) * min(fraction, 1.0))
        step[:3, 3] = half @ (fraction * motion[:3, 3])
        return np.asarray(pose_b @ step)

    def _rotation(self, time: float) -> np.ndarray:
        """(3,) rotation vector from the last pose's time to `time`: a turn about the camera's y axis (down:
        the car's vertical), ∫ max(ω(s), 0) ds with the turn rate ω linear in time (least squares over the
        intervals kept), signed as the last interval's rate. Pitch and roll are not continued: a car's
        oscillate on its suspension and do not accumulate (KITTI 00 frames 195–199 pitch at −0.3° a frame,
        frames 199–208 at +0.1°)."""
        middles, rates = [], []
        for (t0, p0), (t1, p1) in zip(self._last, self._last[1:], strict=False):
            if t1 > t0:
                middles.append(0.5 * (t0 + t1))
                rates.append(float(so3_log(p0[:3, :3].T @ p1[:3, :3])[1]) / (t1 - t0))
        if not rates:
            return np.zeros(3)
        time_b, sign = self._last[-1][0], 1.0 if rates[-1] >= 0 else -1.0
        omega = abs(rates[-1])
        slope = float(np.polyfit(np.array(middles), sign * np.array(rates), 1)[0]) if len(rates) >= 3 else 0.0
        middle = middles[-1]
        end = time if slope >= 0 else min(time, middle - omega / slope)  # where the rate would reach zero
        end = max(end, time_b)
        angle = omega * (end - time_b) + 0.5 * slope * ((end - middle) ** 2 - (time_b - middle) ** 2)
        return np.array([0.0, sign * angle, 0.0])


GUESS_MIN_INLIERS = 12  # a first pose from a wide window: enough to search again narrowly (then reloc_min_inliers)
# fewer inliers than reloc_min_inliers are enough when the pose agrees with the prediction measured from the
# images (an independent check): a sharp turn leaves few of the local map's landmarks in view
AGREEING_MIN_INLIERS = 20
AGREEING_DEG = 5.0
GAP_CORNERS = 500  # Shi–Tomasi corners of the last posed frame tracked across the gap
GAP_WINDOW_PX = 31
GAP_LEVELS = 4  # KLT pyramid levels: with the predicted rotation removed, ~100 px of error is still reached
GAP_MIN_INLIERS = 30
GAP_MAX_CORRECTION_DEG = 20.0  # the measured rotation may differ this much from the predicted one
GAP_YAW_OFFSETS_DEG = (0.0, -6.0, 6.0, -12.0, 12.0, -18.0, 18.0)  # turn-rate errors tried around the prediction


GAP_ORB_FEATURES = 3000  # multi-scale ORB features of each image when KLT cannot bridge the gap
GAP_ORB_RATIO = 0.8


def gap_motion(previous: np.ndarray, current: np.ndarray, lens: CameraIntrinsics,
               predicted: np.ndarray) -> np.ndarray | None:
    """Relative motion T_prev_cur (4, 4), |t| = 1, from the last posed frame's (H, W) uint8 image to this
    one across a gap: Shi–Tomasi corners of `previous` tracked by pyramidal KLT from where the predicted
    motion `predicted` (T_prev_cur) puts them if they were far away (the rotation's homography K·Rᵀ·K⁻¹),
    checked forward–backward; when too few survive (a long gap: the view has turned and moved too far),
    multi-scale ORB matches (8 levels, scale 1.2: KITTI 05 frames 129 → 140, 33.7° of turn, gave 79 inliers
    where KLT kept 2). Then the 5-point essential matrix in RANSAC (Nistér 2004, cv2.findEssentialMat) and
    its decomposition. None when too few inliers remain, or the rotation is implausible. Images are raw (the
    `lens`'s); the geometry is on ideal pixels of its pinhole K (vslam_core/lens.py)."""
    K = lens.K  # noqa: N806
    corners = cv2.goodFeaturesToTrack(previous, GAP_CORNERS, 0.01, 10)
    best: tuple[int, np.ndarray, np.ndarray] | None = None
    p_prev = corners.reshape(-1, 2).astype(np.float32) if corners is not None else np.zeros((0, 2), np.float32)
    for offset in GAP_YAW_OFFSETS_DEG if len(p_prev) >= GAP_MIN_INLIERS else ():
        # the turn rate may have changed during the gap: the most consistent
        rotation = predicted[:3, :3] @ so3_exp(np.array([0.0, np.radians(offset), 0.0]))
        p_cur, good = _track_from(previous, current, p_prev, K @ rotation.T @ np.linalg.inv(K), lens)
        if best is None or int(good.sum()) > best[0]:
            best = (int(good.sum()), p_cur, good)
    motion = _essential_motion(best[1][best[2]], p_prev[best[2]], lens, predicted) \
        if best is not None and best[0] >= GAP_MIN_INLIERS else None
    if motion is None:
        motion = _essential_motion(*_orb_matches(previous, current), lens, predicted)
    return motion


def _orb_matches(previous: np.ndarray, current: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 2) pixels in `current` and in `previous` of multi-scale ORB matches (Lowe's ratio test)."""
    orb = cv2.ORB_create(nfeatures=GAP_ORB_FEATURES, scaleFactor=1.2, nlevels=8, fastThreshold=10)
    key_prev, described_prev = orb.detectAndCompute(previous, None)
    key_cur, described_cur = orb.detectAndCompute(current, None)
    if described_prev is None or described_cur is None or len(described_cur) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(described_prev, described_cur, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < GAP_ORB_RATIO * p[1].distance]
    return (np.array([key_cur[m.trainIdx].pt for m in good], np.float64).reshape(-1, 2),
            np.array([key_prev[m.queryIdx].pt for m in good], np.float64).reshape(-1, 2))


def _essential_motion(p_cur: np.ndarray, p_prev: np.ndarray, lens: CameraIntrinsics,
                      predicted: np.ndarray) -> np.ndarray | None:
    """T_prev_cur (4, 4), |t| = 1, from (N, 2) matched raw pixels by the essential matrix in RANSAC (on their
    ideal pixels); None with fewer than `GAP_MIN_INLIERS` inliers or a rotation over `GAP_MAX_CORRECTION_DEG`
    from `predicted`'s."""
    K = lens.K  # noqa: N806
    p_cur, p_prev = undistort_pairs(p_cur, p_prev, lens)
    if len(p_cur) < GAP_MIN_INLIERS:
        return None
    essential, mask = cv2.findEssentialMat(p_cur, p_prev, K, cv2.RANSAC, 0.999, 1.0)
    if essential is None or essential.shape != (3, 3) or mask is None or int(mask.sum()) < GAP_MIN_INLIERS:
        return None
    inliers, rotation, translation, _ = cv2.recoverPose(essential, p_cur, p_prev, K, mask=mask)
    if inliers < GAP_MIN_INLIERS:
        return None
    if np.degrees(rotation_angle(rotation.T @ predicted[:3, :3])) > GAP_MAX_CORRECTION_DEG:
        return None
    return pose_matrix(rotation, translation.reshape(3) / max(float(np.linalg.norm(translation)), 1e-12))


def _track_from(previous: np.ndarray, current: np.ndarray, p_prev: np.ndarray, homography: np.ndarray,
                lens: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """KLT of (N, 2) float32 raw points from `previous` to `current`, starting where `homography` (3, 3, on
    ideal pixels) puts them through the lens: (N, 2) tracked points and an (N,) mask of those consistent
    forward–backward within 1 px."""
    ideal = undistort_pixels(p_prev, lens).astype(np.float32) if lens.distorted else p_prev
    guess = cv2.perspectiveTransform(ideal[None], homography)[0]
    guess = (distort_pixels(guess, lens) if lens.distorted else guess).astype(np.float32)
    window = (GAP_WINDOW_PX, GAP_WINDOW_PX)
    p_cur, ok, _ = cv2.calcOpticalFlowPyrLK(previous, current, p_prev, guess, winSize=window, maxLevel=GAP_LEVELS,
                                            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    back, ok_back, _ = cv2.calcOpticalFlowPyrLK(current, previous, p_cur, p_prev.copy(), winSize=window,
                                                maxLevel=GAP_LEVELS, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    good = (ok.reshape(-1).astype(bool) & ok_back.reshape(-1).astype(bool)
            & (np.linalg.norm(back - p_prev, axis=1) < 1.0))
    return p_cur, good


def bridged_prediction(previous_image: np.ndarray, image: np.ndarray, T_world_previous: np.ndarray,  # noqa: N803
                       predicted: np.ndarray, lens: CameraIntrinsics) -> np.ndarray:
    """The motion model's prediction (4, 4) with its rotation and direction replaced by the ones measured
    across the gap (`gap_motion`), the step length kept; the prediction itself when nothing is measured."""
    T_prev_pred = invert_pose(T_world_previous) @ predicted  # noqa: N806
    measured = gap_motion(previous_image, image, lens, T_prev_pred)
    if measured is None:
        return predicted
    measured[:3, 3] *= float(np.linalg.norm(T_prev_pred[:3, 3]))
    return np.asarray(T_world_previous @ measured)


@dataclass(frozen=True)
class GuidedRelocalisation:
    """The outcome: the last search (the widest window tried, or the refining one), and the PnP pose."""

    search: LocalMapSearch
    solution: PnPSolution | None  # None: not found
    landmark_ids: np.ndarray  # (L,) landmarks given to the final PnP
    pixels: np.ndarray  # (L, 2) where they were found
    attempts: int  # windows tried


def relocalise_guided(searcher: LocalMapSearcher, world: Map, corners: FrameCorners, keyframe_ids: list[int],
                      predicted: np.ndarray, K: np.ndarray, config: MapConfig,  # noqa: N803
                      seed: tuple[int, ...]) -> GuidedRelocalisation:
    """Search the local map around `predicted` in widening windows until PnP finds `reloc_min_inliers`
    inliers, then search again with that pose in the tracking window and refine (module docstring)."""
    radius = config.reloc_radius_px
    search = searcher.search(world, corners, keyframe_ids, predicted, radius, set(), "relocalise")
    for attempt in range(1, config.reloc_widenings + 2):
        if attempt > 1:
            radius *= 2.0
            search = searcher.search(world, corners, keyframe_ids, predicted, radius, set(), "relocalise")
        solution, _, _ = _pnp_on(search, world, K, config, seed + (attempt,), GUESS_MIN_INLIERS)
        if solution is None or solution.T_world_cam is None:
            continue
        refined = searcher.search(world, corners, keyframe_ids, solution.T_world_cam, config.local_map_radius_px,
                                  set(), "relocalise")
        better, ids, pixels = _pnp_on(refined, world, K, config, seed + (attempt, 0), AGREEING_MIN_INLIERS)
        if better is not None and better.T_world_cam is not None and (
                int(better.inlier_mask.sum()) >= config.reloc_min_inliers
                or np.degrees(rotation_angle(better.T_world_cam[:3, :3].T @ predicted[:3, :3])) <= AGREEING_DEG):
            return GuidedRelocalisation(refined, better, ids, pixels, attempt)
    return GuidedRelocalisation(search, None, np.zeros(0, np.int64), np.zeros((0, 2)), config.reloc_widenings + 1)


def _pnp_on(search: LocalMapSearch, world: Map, K: np.ndarray, config: MapConfig,  # noqa: N803
            seed: tuple[int, ...], minimum: int) -> tuple[PnPSolution | None, np.ndarray, np.ndarray]:
    """PnP on a search's matches if there are enough; the solution only if it has `minimum` inliers."""
    found = search.found_mask
    ids, pixels = search.landmark_ids[found], search.found_pixels[found]
    if len(ids) < minimum:
        return None, ids, pixels
    solution = solve_pnp(world.positions(ids), pixels, K, config.reloc_threshold_px, config.reloc_iterations, seed)
    if solution.T_world_cam is None or int(solution.inlier_mask.sum()) < minimum:
        return None, ids, pixels
    return solution, ids, pixels


def relocalise_by_descriptors(map_: Map, segment: int, image: np.ndarray, describer: cv2.ORB,
                              lens: CameraIntrinsics, config: MapConfig,
                              seed: tuple[int, ...]) -> tuple[Relocalisation, PnPEstimate | None, np.ndarray]:
    """Unguided relocalisation: upright ORB descriptors of the (H, W) image's FAST corners (like the ones tracks,
    and so landmarks, are born at, described like the landmarks) matched to the landmarks of the segment's
    `reloc_keyframes` recent keyframes, then PnP in RANSAC. Returns the attempt, the estimate on success, and
    the (M, 2) float32 raw pixels of its PnP inliers (where tracks can start)."""
    no_pixels = np.zeros((0, 2), np.float32)
    recent = map_.recent_keyframes(config.reloc_keyframes, segment)
    landmarks = map_.landmarks
    candidates = [i for i in map_.landmarks_seen_by(recent) if landmarks[i].descriptor is not None]
    corners = cv2.FastFeatureDetector_create(threshold=config.reloc_fast_threshold).detect(image, None)
    keypoints = [cv2.KeyPoint(k.pt[0], k.pt[1], DESCRIPTOR_PATCH, 0.0, k.response, 0) for k in corners]
    keypoints, descriptors = describer.compute(image, keypoints)
    failed = Relocalisation(False, None, len(candidates), 0, 0)
    if descriptors is None or len(candidates) < config.pnp_min_landmarks:
        return failed, None, no_pixels
    train = np.array([landmarks[i].descriptor for i in candidates])
    query_index, train_index = match_descriptors(descriptors, train, config.reloc_ratio)
    failed = replace(failed, matches=len(query_index))
    if len(query_index) < config.reloc_min_inliers:
        return failed, None, no_pixels
    landmark_ids = np.array(candidates, np.int64)[train_index]
    raw = np.array([keypoints[i].pt for i in query_index], np.float64).reshape(-1, 2)
    pixels = undistort_pixels(raw, lens)
    solution = solve_pnp(map_.positions(landmark_ids), pixels, lens.K, config.reloc_threshold_px,
                         config.reloc_iterations, seed)
    inliers = int(solution.inlier_mask.sum())
    if solution.T_world_cam is None or inliers < config.reloc_min_inliers:
        return replace(failed, inliers=inliers), None, no_pixels
    found = set(landmark_ids[solution.inlier_mask].tolist())
    best = max(recent, key=lambda k: (len(k.landmark_ids & found), k.id))
    return (Relocalisation(True, best.id, len(candidates), len(query_index), inliers),
            PnPEstimate(landmark_ids, pixels, solution.projected, solution.inlier_mask, solution.T_world_cam),
            raw[solution.inlier_mask].astype(np.float32))
