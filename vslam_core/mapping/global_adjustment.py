"""Global bundle adjustment: every keyframe and landmark of the map refined together, once: before the map is
saved (`vslam run --save-map`), so a later drive localises against a self-consistent map, and with --scale none
when a hand-held run completes (`adjust_at_end`), so its trajectory is corrected where the windows left it.

The same factor graph as the windowed BA (vslam_core/mapping/bundle_adjustment.py: robust reprojection errors,
Triggs et al. 2000, eq. 2) over the whole map instead of a window, with its priors kept: each pair of consecutive
keyframes of a segment keeps its `RangeFactorPose3` (the scale source's step length, or with --scale none the
step's length before the adjustment; sigmas as in the windowed BA), and so do the front end's two-view rotations
between consecutive keyframes (`rotation_prior_deg`). The gauge: each segment's first keyframe is held fixed (its
first two with unit scale, which also fix the scale). Afterwards observations that reproject worse than
`cull_reprojection_px` are dropped, and landmarks left with fewer than two observations.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from vslam_core.config import MapConfig, ScaleSource
from vslam_core.geometry import orthonormalise
from vslam_core.mapping.bundle_adjustment import Problem, solve
from vslam_core.mapping.local_mapping import distance_prior, rotation_priors
from vslam_core.mapping.map import Map
from vslam_core.mapping.map_scale import forward_share

GLOBAL_ITERATIONS = 20  # Levenberg–Marquardt iterations
MIN_KEYFRAME_OBSERVATIONS = 10  # a keyframe seeing fewer landmarks is held (a pose needs well over PnP's 3)


@dataclass(frozen=True)
class GlobalAdjusted:
    """What the global adjustment did."""

    keyframes: int  # in the problem
    free: int  # of them, adjusted (the others held)
    landmarks: int
    observations: int
    mean_error_before: float  # px, over the finite reprojection errors
    mean_error_after: float
    culled_observations: int
    culled_landmarks: int
    milliseconds: float


def adjust_map(map_: Map, K: np.ndarray, config: MapConfig, scale: ScaleSource,  # noqa: N803
               iterations: int = GLOBAL_ITERATIONS, max_keyframes: int | None = None) -> GlobalAdjusted | None:
    """Refine every keyframe pose and landmark position of `map_` in place; None if there is nothing to adjust
    (fewer than two keyframes, or no landmark seen twice). A keyframe that sees fewer than
    `MIN_KEYFRAME_OBSERVATIONS` of the landmarks seen twice (its own forgotten with age, `map_keyframes`) is held,
    and so are all but the newest `max_keyframes` of the others (None: no limit), which bounds a long drive's cost."""
    gauge = 2 if scale == "none" else 1
    landmark_ids = [i for i, landmark in map_.landmarks.items() if landmark.observation_count >= 2]
    seen = Counter(k for i in landmark_ids for k in map_.landmarks[i].observations)
    by_segment: dict[int, list[int]] = {}  # the keyframes that see any of them, by segment
    for keyframe in map_.keyframes.values():
        if seen[keyframe.id]:
            by_segment.setdefault(keyframe.segment, []).append(keyframe.id)
    movable = [k for ids in by_segment.values() for k in ids[gauge:] if seen[k] >= MIN_KEYFRAME_OBSERVATIONS]
    free = sorted(movable)[-max_keyframes:] if max_keyframes is not None and len(movable) > max_keyframes \
        else movable
    free_set = set(free)
    fixed = [k for ids in by_segment.values() for k in ids if k not in free_set]
    keyframe_ids = free + fixed  # the problem's first `len(free)` poses are variables, the rest held
    index = {k: n for n, k in enumerate(keyframe_ids)}
    landmark_ids = [i for i in landmark_ids if any(k in free_set for k in map_.landmarks[i].observations)]
    if not free or not landmark_ids:
        return None
    pose_index, point_index, pixels = [], [], []
    for n, landmark_id in enumerate(landmark_ids):
        for keyframe_id, pixel in map_.landmarks[landmark_id].observations.items():
            pose_index.append(index[keyframe_id])
            point_index.append(n)
            pixels.append(pixel)
    problem = Problem(
        K=K, poses=np.array([map_.keyframes[k].T_world_cam for k in keyframe_ids]), optimised=len(free),
        points=map_.positions(landmark_ids), observation_pose=np.array(pose_index, np.int64),
        observation_point=np.array(point_index, np.int64),
        observation_pixels=np.array(pixels, np.float64).reshape(-1, 2),
        ranges=_ranges(map_, index, config, scale), fix_first=0, iterations=iterations,
        huber_px=config.ba_huber_px, **rotation_priors(map_, index, config))
    solution = solve(problem)
    for keyframe_id, pose in zip(free, solution.poses, strict=True):
        map_.keyframes[keyframe_id].T_world_cam = orthonormalise(pose)
    for landmark_id, position in zip(landmark_ids, solution.points, strict=True):
        map_.landmarks[landmark_id].position = position
    culled_observations, culled_landmarks = 0, 0
    bad = ~(solution.errors_after <= config.cull_reprojection_px)
    for pose, point in zip(problem.observation_pose[bad], problem.observation_point[bad], strict=True):
        landmark_id = landmark_ids[point]
        if landmark_id not in map_.landmarks:
            continue
        map_.remove_observation(landmark_id, keyframe_ids[pose])
        culled_observations += 1
        if map_.landmarks[landmark_id].observation_count < 2:
            map_.remove_landmark(landmark_id)
            culled_landmarks += 1
    before, after = solution.errors_before, solution.errors_after
    return GlobalAdjusted(
        keyframes=len(keyframe_ids), free=len(free), landmarks=len(landmark_ids), observations=len(pose_index),
        mean_error_before=float(before[np.isfinite(before)].mean()),
        mean_error_after=float(after[np.isfinite(after)].mean()),
        culled_observations=culled_observations, culled_landmarks=culled_landmarks,
        milliseconds=solution.milliseconds)


def adjust_at_end(map_: Map, K: np.ndarray, config: MapConfig, scale: ScaleSource,  # noqa: N803
                  ) -> GlobalAdjusted | str | None:
    """A run's adjustment once it completed (`config.adjust_at_end`, `for_scale`'s: on with --scale none): the
    newest `adjust_at_end_keyframes` keyframes free, the front end's rotations at `adjust_at_end_rotation_prior_deg`,
    the steps' lengths at `adjust_at_end_step_sigma` (0: free). Only for a camera moving sideways: along the optical
    axis (`forward_share` over `sideways_forward_share`, a car) a step's length and its landmarks' depths trade
    off, and free the steps lengthened together; held, it changed little (docs/map-backend.md). None when off; why,
    when not run."""
    if not config.adjust_at_end:
        return None
    if map_.loop_keyframes:  # no landmark links a loop's two ends: the reprojections would bend it open again
        return "not run: a loop was closed (no landmark links its two ends; the adjustment would bend it open again)"
    share = forward_share(map_, min_step_depth=config.sideways_min_step_depth)
    if share is not None and share > config.sideways_forward_share:
        return (f"not run: the camera moves along its optical axis (median |cos| {share:.2f}; its steps would "
                "lengthen together)")
    held = replace(config, rotation_prior_deg=config.adjust_at_end_rotation_prior_deg or config.rotation_prior_deg,
                   none_step_sigma=config.adjust_at_end_step_sigma)
    return adjust_map(map_, K, held, scale, max_keyframes=config.adjust_at_end_keyframes)


def _ranges(map_: Map, index: dict[int, int], config: MapConfig, scale: ScaleSource) -> np.ndarray:
    """(R, 4) rows (pose a, pose b, distance, sigma): each pair of consecutive keyframes of a segment, both in the
    problem (`index`), held to its distance as the windowed BA holds it (`local_mapping.distance_prior`: the scale
    source's step, or with --scale none the distance before this adjustment at `none_step_sigma` of it; the run's
    own adjustment at the end passes `adjust_at_end_step_sigma`, 0: free)."""
    by_segment: dict[int, list[int]] = {}
    for keyframe in map_.keyframes.values():
        by_segment.setdefault(keyframe.segment, []).append(keyframe.id)
    rows = []
    for ids in by_segment.values():
        for previous, current in zip(ids, ids[1:], strict=False):
            if previous in index and current in index \
                    and (prior := distance_prior(map_, current, previous, config, scale)) is not None:
                rows.append((index[previous], index[current], *prior))
    return np.array(rows, np.float64).reshape(-1, 4)
