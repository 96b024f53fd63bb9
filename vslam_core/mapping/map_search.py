"""Tracking against the map when the frame's tracks see too few landmarks: the local map searched by projection.

With more motion per frame (a 5 Hz camera, a faster car: KITTI at every 2nd or 3rd frame) the KLT tracks linked
to landmarks die faster than keyframes make new ones, and PnP on the tracked landmarks alone fails (KITTI 00
frames 0:300:2, `--scale none`: 61 of 150 frames placed by two-view motion, nearly all "only N landmarks
tracked"). Before such a frame falls back to its two-view motion (`map_search`, ORB-SLAM's "track local map",
Mur-Artal et al. 2015 §V-D, done when it is needed):

1. the pose is predicted: the front end's two-view pose (rotation and direction measured from the images, the
   length from the scale source or the map's speed), else the motion model's;
2. the local map's landmarks no live track follows are projected with it and searched for among the frame's
   FAST corners by upright ORB descriptors described at several pyramid levels (`LocalMapSearcher.search`), in a
   square window whose half-size scales with the predicted motion: `search_motion_fraction` × the median pixel
   displacement of the landmarks by the predicted translation (the step's length is the uncertain part: the
   prediction errs in proportion to it), at least `search_min_radius_px`, at most `MAX_RADIUS_PX`;
3. coarse to fine: PnP in RANSAC on the tracked and the found landmarks (wide window, loose threshold); its pose
   searches again in the narrow tracking window (`local_map_radius_px`) and PnP is solved on what that finds;
   the pose must pass the same checks as a tracked one (`check`);
4. otherwise the window doubles (`search_widenings` times) before the frame takes its two-view pose. A frame
   that sees too few of the map's landmarks (in view or matched) is made a keyframe (tracking.py), so that
   landmarks are triangulated while its tracks still overlap the last keyframe's.

When all fails, the frame takes its two-view motion: its rotation and direction are measured from the images, its
length (--scale none) from the tracks of the two frames before it or the map's recent speed (map_scale.TwoViewLength,
which measures it with `fitted_step` below). With `step_fit_min_inliers` > 0 (off by default) the length
is measured on the few landmarks the frame still sees (`fitted_two_view`): with the rotation R and unit direction
d given, a landmark at X_k (keyframe frame) seen along the ideal ray x constrains the length s by
x × (Rᵀ(X_k − s·d)) = 0, linear in s; one-point RANSAC over the landmarks' own s, refined by least squares on
the inliers (`fit_step_length`). Measured, it does not help yet: in 05's turn at step 3 the fitted lengths came
out 15–25 % under the map speed's (landmarks triangulated from keyframes the two-view guesses had placed), and
fed back as speed the scale collapsed (docs/map-backend.md).

Why it failed is kept in the estimate (`PnPFailure`): too few landmarks in view, too few matched, RANSAC, or
a pose that disagrees with the two-view and predicted rotations. Pixels are (N, 2) ideal pinhole pixels of K;
poses camera-to-world (4, 4).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vslam_core.config import MapConfig
from vslam_core.geometry import invert_pose
from vslam_core.mapping.local_map import FrameCorners, LocalMapSearcher
from vslam_core.mapping.map import Map
from vslam_core.mapping.pnp import PnPSolution, project, solve_pnp
from vslam_core.results import LocalMapSearch, PnPEstimate, PnPFailure

MAX_RADIUS_PX = 128.0  # a window no wider (half-size): beyond it a descriptor search is not local any more
COARSE_MIN_INLIERS = 12  # a first pose from the wide window: enough to search again narrowly
MAX_STEP_FRACTION = 0.95  # a banded search sweeps the step's length over (1 ∓ f) × the predicted, f at most this
PURPOSE = "map_search"  # LocalMapSearch.purpose of these searches

#: the tracking checks of a PnP solution: (why it is refused or None, it outvoted the two-view rotation, failure)
Check = Callable[[PnPSolution], tuple[str | None, bool, PnPFailure | None]]


def initial_radius(world: Map, landmark_ids: list[int], previous: np.ndarray, predicted: np.ndarray,
                   K: np.ndarray, config: MapConfig) -> float:  # noqa: N803
    """Half-size (px) of the first search window: `search_motion_fraction` × the median displacement of the
    landmarks' projections by the predicted translation from the last pose `previous` (its rotation is measured
    from the images, its step length is what is uncertain), within [`search_min_radius_px`, `MAX_RADIUS_PX`]."""
    if not landmark_ids:
        return config.search_min_radius_px
    positions = world.positions(np.array(landmark_ids, np.int64))
    unmoved = predicted.copy()
    unmoved[:3, 3] = previous[:3, 3]
    moved = np.linalg.norm(project(positions, predicted, K) - project(positions, unmoved, K), axis=1)
    moved = moved[np.isfinite(moved)]
    motion = float(np.median(moved)) if len(moved) else 0.0
    return min(max(config.search_min_radius_px, config.search_motion_fraction * motion), MAX_RADIUS_PX)


def count_in_view(world: Map, keyframe_ids: list[int], predicted: np.ndarray, K: np.ndarray,  # noqa: N803
                  size: tuple[int, int]) -> int:
    """How many landmarks of `keyframe_ids` the `predicted` pose projects into a (width, height) image."""
    ids = np.array(sorted({i for k in keyframe_ids for i in world.keyframes[k].landmark_ids}), np.int64)
    pixels = project(world.positions(ids), predicted, K).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        return int(((pixels[:, 0] >= 0) & (pixels[:, 0] < size[0]) & (pixels[:, 1] >= 0)
                    & (pixels[:, 1] < size[1])).sum())


def search_map(searcher: LocalMapSearcher, world: Map, corners: FrameCorners, keyframe_ids: list[int],
               predicted: np.ndarray, previous: np.ndarray, tracked: tuple[np.ndarray, np.ndarray],
               K: np.ndarray, config: MapConfig, seed: tuple[int, ...],  # noqa: N803
               check: Check, origin: np.ndarray | None = None) -> tuple[PnPEstimate, LocalMapSearch | None]:
    """Track the frame against the local map of `keyframe_ids` (module docstring) from the `predicted` pose, with
    `tracked` = ((T,) landmark ids linked to live tracks, (T, 2) their pixels). With `origin` (the keyframe
    pose the predicted step is measured from, its rotation and direction from the images) and
    `search_band_px` > 0, each landmark is searched along the segment its step's length sweeps (`along`).
    Returns the estimate (a pose when `failure` is None; `found` of its landmarks come from the search) and the
    last search made."""
    tracked_ids, tracked_pixels = tracked
    exclude = set(tracked_ids.tolist())
    seen = sorted({i for k in keyframe_ids for i in world.keyframes[k].landmark_ids} - exclude)
    radius = initial_radius(world, seen, previous, predicted, K, config)
    failure, search, best = PnPFailure.TOO_FEW_MATCHED, None, None
    in_view, widest = len(tracked_ids), radius
    banded = origin is not None and config.search_band_px > 0
    for attempt in range(config.search_widenings + 1):
        widest = radius
        if banded:
            assert origin is not None
            fraction = min(config.search_motion_fraction * 2**attempt, MAX_STEP_FRACTION)
            search = searcher.search(world, corners, keyframe_ids, predicted, config.search_band_px, exclude,
                                     PURPOSE, (origin, fraction))
            widest = float(search.radius_px.max()) if len(search.radius_px) else config.search_band_px
        else:
            search = searcher.search(world, corners, keyframe_ids, predicted, radius, exclude, PURPOSE)
        in_view = len(tracked_ids) + len(search.landmark_ids)
        if in_view < config.pnp_min_landmarks:  # a wider window sees no more of the map
            failure = PnPFailure.TOO_FEW_IN_VIEW
            break
        ids, pixels = _matched(search, tracked_ids, tracked_pixels)
        if len(ids) < config.pnp_min_landmarks:
            failure = PnPFailure.TOO_FEW_MATCHED
            radius = min(2.0 * radius, MAX_RADIUS_PX)
            continue
        coarse = solve_pnp(world.positions(ids), pixels, K, config.reloc_threshold_px, config.reloc_iterations,
                           seed + (attempt,))
        if coarse.T_world_cam is None or int(coarse.inlier_mask.sum()) < COARSE_MIN_INLIERS:
            failure = PnPFailure.RANSAC
            radius = min(2.0 * radius, MAX_RADIUS_PX)
            continue
        fine = searcher.search(world, corners, keyframe_ids, coarse.T_world_cam, config.local_map_radius_px, exclude,
                               PURPOSE)
        ids, pixels = _matched(fine, tracked_ids, tracked_pixels)
        solution = solve_pnp(world.positions(ids), pixels, K, config.pnp_threshold_px, config.pnp_iterations,
                             seed + (attempt, 0))
        rejected, outvoted, failure_now = check(solution)
        found = len(ids) - len(tracked_ids)
        estimate = PnPEstimate(ids, pixels, solution.projected, solution.inlier_mask, solution.T_world_cam,
                               rejected, outvoted, failure_now, in_view, found, widest)
        if rejected is None:
            fine.accepted[:] = np.isin(fine.landmark_ids, ids[solution.inlier_mask])
            return estimate, replace_radius(fine, widest)
        best, search, failure = estimate, fine, failure_now or PnPFailure.RANSAC
        radius = min(2.0 * radius, MAX_RADIUS_PX)
    if best is not None:
        return PnPEstimate(best.landmark_ids, best.observed, best.projected, best.inlier_mask, None,
                           best.rejected, False, failure, in_view, best.found, widest), search
    ids, pixels = _matched(search, tracked_ids, tracked_pixels) if search is not None else tracked
    why = {PnPFailure.TOO_FEW_IN_VIEW: f"only {in_view} landmarks in view",
           PnPFailure.TOO_FEW_MATCHED: f"only {len(ids)} landmarks matched",
           PnPFailure.RANSAC: "no PnP solution"}.get(failure, "no PnP solution")
    return PnPEstimate(ids, pixels, np.full_like(pixels, np.nan), np.zeros(len(ids), bool), None, why, False,
                       failure, in_view, len(ids) - len(tracked_ids), widest), search


def replace_radius(search: LocalMapSearch, radius: float) -> LocalMapSearch:
    """The search with the widest window tried recorded as its radius (its matches are the narrow window's)."""
    search.radius_px[:] = radius
    return search


def _matched(search: LocalMapSearch, tracked_ids: np.ndarray,
             tracked_pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) landmark ids and (M, 2) pixels: the tracked ones, then the ones the search found."""
    found = search.found_mask
    return (np.concatenate([tracked_ids, search.landmark_ids[found]]).astype(np.int64),
            np.concatenate([tracked_pixels.reshape(-1, 2), search.found_pixels[found]]))


@dataclass(frozen=True)
class StepFit:
    """A two-view step's length measured against landmarks."""

    length: float  # in the map's units, keyframe to frame
    inliers: int  # landmarks within the threshold at that length
    landmarks: int  # landmarks tried


def _rays(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:  # noqa: N803
    """(L, 3) ideal rays (z = 1) of (L, 2) pixels."""
    return np.column_stack([(pixels[:, 0] - K[0, 2]) / K[0, 0], (pixels[:, 1] - K[1, 2]) / K[1, 1],
                            np.ones(len(pixels))])


def fit_step_length(T_world_key: np.ndarray, T_key_cur: np.ndarray, positions: np.ndarray,  # noqa: N803
                    pixels: np.ndarray, K: np.ndarray, threshold_px: float) -> StepFit | None:  # noqa: N803
    """The length of the step `T_key_cur` (its rotation and direction kept) that best reprojects the (L, 3)
    landmarks onto their (L, 2) observed pixels in the current frame; None without a translation or landmarks."""
    norm = float(np.linalg.norm(T_key_cur[:3, 3]))
    if norm < 1e-12 or len(positions) == 0:
        return None
    rotation, direction = T_key_cur[:3, :3], T_key_cur[:3, 3] / norm
    T_key_world = invert_pose(T_world_key)  # noqa: N806
    in_key = positions @ T_key_world[:3, :3].T + T_key_world[:3, 3]
    a, b = in_key @ rotation, direction @ rotation  # the point in the current camera is a − s·b
    rays = _rays(pixels, K)
    xa, xb = np.cross(rays, a), np.cross(rays, np.broadcast_to(b, rays.shape))
    weight = np.einsum("ij,ij->i", xb, xb)
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.einsum("ij,ij->i", xb, xa) / weight
    candidates = own[np.isfinite(own) & (own > 0)]
    if len(candidates) == 0:
        return None

    def inliers(length: float) -> np.ndarray:
        step = T_key_cur.copy()
        step[:3, 3] = length * direction
        with np.errstate(invalid="ignore"):
            error = np.linalg.norm(project(positions, T_world_key @ step, K) - pixels, axis=1)
            return np.asarray(error <= threshold_px)

    counts = [int(inliers(float(s)).sum()) for s in candidates]
    best = float(candidates[int(np.argmax(counts))])  # the first of the most supported (deterministic)
    mask = inliers(best)
    total = float(weight[mask].sum())
    if total <= 0:
        return None
    refined = float(np.einsum("ij,ij->i", xb[mask], xa[mask]).sum() / total)
    if refined > 0 and inliers(refined).sum() >= mask.sum():
        best, mask = refined, inliers(refined)
    return StepFit(best, int(mask.sum()), len(positions))


def rescale_step(T_key_cur: np.ndarray, length: float) -> np.ndarray:  # noqa: N803
    """(4, 4) the step with its direction and rotation kept, its translation `length` long."""
    step = T_key_cur.copy()
    step[:3, 3] *= length / float(np.linalg.norm(T_key_cur[:3, 3]))
    return step


def fitted_two_view(world: Map, T_world_key: np.ndarray, T_key_cur: np.ndarray, pnp: PnPEstimate,  # noqa: N803
                    K: np.ndarray, config: MapConfig) -> np.ndarray | None:  # noqa: N803
    """--scale none: `fitted_step` on the landmarks `pnp` tried, when `step_fit_min_inliers` of them agree."""
    if config.step_fit_min_inliers <= 0 or len(pnp.landmark_ids) == 0:
        return None
    return fitted_step(T_world_key, T_key_cur, world.positions(pnp.landmark_ids), pnp.observed, K, config,
                       config.step_fit_min_inliers)


def fitted_step(T_world_key: np.ndarray, T_key_cur: np.ndarray, positions: np.ndarray, pixels: np.ndarray,  # noqa: N803
                K: np.ndarray, config: MapConfig, min_inliers: int) -> np.ndarray | None:  # noqa: N803
    """--scale none: (4, 4) T_world_cam of the two-view motion `T_key_cur` from the keyframe at `T_world_key`
    with its length measured on (L, 3) points seen at (L, 2) pixels (`fit_step_length`), when `min_inliers` and
    half of them agree and the length is within `step_fit_max_ratio` of the map speed's guess (`T_key_cur`'s own
    length); else None."""
    fit = fit_step_length(T_world_key, T_key_cur, positions, pixels, K, config.pnp_threshold_px)
    guess = float(np.linalg.norm(T_key_cur[:3, 3]))
    if fit is None or fit.inliers < max(min_inliers, fit.landmarks / 2) or \
            not guess / config.step_fit_max_ratio <= fit.length <= guess * config.step_fit_max_ratio:
        return None
    return np.asarray(T_world_key @ rescale_step(T_key_cur, fit.length))
