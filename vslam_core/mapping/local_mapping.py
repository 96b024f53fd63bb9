"""Local mapping: keyframe insertion, landmark creation and culling, windowed bundle adjustment.

Landmarks come from tracks: a KLT track seen at two keyframes whose rays meet at a large enough angle is
triangulated (midpoint, then checked by reprojection into both) and observed by every keyframe that saw
it. Each keyframe hands the BA window (its last `ba_window` keyframes) to the `BundleAdjuster`; the
solution is applied when the next keyframe arrives, a fixed point, so the same input always gives the
same map however long the solver took. Memory stays bounded: a landmark that leaves the window seen by
fewer than `min_observations` keyframes is dropped, as is every observation that reprojects badly after BA,
and a landmark none of the last `map_keyframes` keyframes sees is forgotten. The keyframe leaving the window is
culled when an older keyframe is at its place (a revisit; `_cull`), so the map's keyframes follow the place, not
the time; ORB-SLAM's rule (most of its landmarks seen well by three other keyframes) is there, off by default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from vslam_core.config import MapConfig, ScaleSource
from vslam_core.geometry import (
    in_front_with_parallax,
    invert_pose,
    normalise_points,
    orthonormalise,
    triangulate_each,
)
from vslam_core.lens import distort_pixels
from vslam_core.mapping.bundle_adjustment import BundleAdjuster, Problem, Solution
from vslam_core.mapping.map import COVERED_ANGLE_DEG, COVERED_SPACINGS, Keyframe, Map, covering, redundant
from vslam_core.mapping.worker_process import BackendWorker
from vslam_core.results import BundleAdjusted, KeyframeInserted, MapView
from vslam_core.sources.base import CameraIntrinsics

DESCRIPTOR_PATCH = 31.0  # ORB's patch size: the keypoint size of a landmark's descriptor
KEYFRAME_IMAGES = 20  # the newest keyframes keep their image: landmarks are re-found from it by KLT (local_map.py)


@dataclass(frozen=True)
class _Submitted:
    """What a submitted BA problem's indices refer to."""

    keyframe_ids: list[int]  # window, then fixed
    optimised: int
    landmark_ids: np.ndarray  # (P,)


class LocalMapping:
    """Owns the map; tracking hands it keyframes and reads landmarks back."""

    def __init__(self, camera: CameraIntrinsics, config: MapConfig, scale: ScaleSource,
                 worker: BackendWorker | None) -> None:
        """Pixels handed in are ideal pinhole pixels of the camera's K; a distorted lens places them on the raw
        image for the descriptors. Bundle adjustment runs in `worker` if given, else when it is collected."""
        self.map = Map()
        self._camera = camera
        self._K = camera.K
        self._config = config
        self._scale = scale
        self._adjuster = BundleAdjuster(worker)
        self._submitted: _Submitted | None = None
        self._sightings: dict[int, list[tuple[int, np.ndarray]]] = {}  # track id -> (keyframe id, pixel)s
        # upright ORB descriptors at level 0 (the car's camera hardly rolls): landmarks and relocalisation
        self.describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
        self._window: list[int] = []  # keyframe ids of the current BA window
        self.keyframe_images: dict[int, np.ndarray] = {}  # the newest KEYFRAME_IMAGES keyframes' (H, W) images
        # keyframes culled at the last insertion: id -> (the keyframe its frames now follow, (4, 4) T_anchor_culled)
        self.culled: dict[int, tuple[int, np.ndarray]] = {}

    def use_settings(self, config: MapConfig) -> None:
        """These settings from the next keyframe on (a camera found to move sideways: `map_scale.sideways_camera`)."""
        self._config = config

    # -- bundle adjustment ---------------------------------------------------------------------------------

    def collect_bundle_adjustment(self) -> tuple[BundleAdjusted, np.ndarray] | None:
        """Apply the pending BA solution to the map. Returns what it did and the correction
        T_new·T_old⁻¹ (4, 4) of the newest keyframe, for the frames tracked since; None if none was pending."""
        collected = self._adjuster.collect()
        submitted, self._submitted = self._submitted, None
        if collected is None or submitted is None:
            return None
        problem, solution = collected
        newest = self.map.keyframes[submitted.keyframe_ids[submitted.optimised - 1]]
        correction = solution.poses[submitted.optimised - 1] @ invert_pose(newest.T_world_cam)
        for keyframe_id, pose in zip(submitted.keyframe_ids[: submitted.optimised], solution.poses, strict=True):
            self.map.keyframes[keyframe_id].T_world_cam = orthonormalise(pose)
        lifetimes = np.array([len(self.map.landmarks[int(i)].observations) if int(i) in self.map.landmarks else 0
                              for i in submitted.landmark_ids], np.int64)  # keyframes tying each, before culling
        culled = self._apply_landmarks(problem, solution, submitted)
        finite = np.isfinite(solution.errors_before) & np.isfinite(solution.errors_after)
        before, after = solution.errors_before[finite], solution.errors_after[finite]
        residual = _mean_per_landmark(solution.errors_after, problem.observation_point, len(submitted.landmark_ids))
        return BundleAdjusted(
            keyframe_ids=np.array(submitted.keyframe_ids[: submitted.optimised], np.int64),
            keyframe_poses=solution.poses,
            fixed_keyframe_ids=np.array(submitted.keyframe_ids[submitted.optimised:], np.int64),
            landmark_ids=submitted.landmark_ids,
            landmark_positions=solution.points,
            landmark_residual_px=residual,
            iterations=solution.iterations,
            cost_before=solution.cost_before,
            cost_after=solution.cost_after,
            mean_error_before=float(before.mean()) if len(before) else 0.0,
            max_error_before=float(before.max()) if len(before) else 0.0,
            mean_error_after=float(after.mean()) if len(after) else 0.0,
            max_error_after=float(after.max()) if len(after) else 0.0,
            culled=culled,
            milliseconds=solution.milliseconds,
            factors=len(problem.observation_pose),
            landmark_keyframes=lifetimes,
            rotation_errors_deg=solution.rotation_errors_after,
        ), correction

    def _apply_landmarks(self, problem: Problem, solution: Solution, submitted: _Submitted) -> int:
        """Move the landmarks to their refined positions; drop observations that reproject badly (and
        landmarks left with fewer than two). Returns the number of landmarks removed."""
        landmarks = self.map.landmarks
        for landmark_id, position in zip(submitted.landmark_ids, solution.points, strict=True):
            if int(landmark_id) in landmarks:
                landmarks[int(landmark_id)].position = position
        culled = 0
        bad = ~(solution.errors_after <= self._config.cull_reprojection_px)
        for pose_index, point_index in zip(problem.observation_pose[bad], problem.observation_point[bad], strict=True):
            landmark_id = int(submitted.landmark_ids[point_index])
            if landmark_id not in landmarks:
                continue
            self.map.remove_observation(landmark_id, submitted.keyframe_ids[pose_index])
            if landmarks[landmark_id].observation_count < 2:
                self.map.remove_landmark(landmark_id)
                culled += 1
        return culled

    def _submit(self, segment: int) -> None:
        """Hand the newest window of `segment` to the bundle adjuster."""
        cfg = self._config
        window = self.map.recent_keyframes(cfg.ba_window, segment)
        self._window = [k.id for k in window]
        if len(window) < 2:
            return
        landmarks = self.map.landmarks
        landmark_ids = self.map.landmarks_seen_by(window)
        if len(landmark_ids) > cfg.ba_max_landmarks:  # the best-observed ones (ties: the older)
            counts = np.array([landmarks[i].observation_count for i in landmark_ids])
            keep = np.sort(np.argsort(-counts, kind="stable")[: cfg.ba_max_landmarks])
            landmark_ids = [landmark_ids[i] for i in keep]
        observations = [landmarks[i].observations for i in landmark_ids]
        older = sorted(set().union(*observations) - set(self._window))
        fixed = older[-cfg.ba_max_fixed:] if cfg.ba_max_fixed > 0 else []
        keyframe_ids = self._window + fixed
        index = {k: n for n, k in enumerate(keyframe_ids)}
        pose_index, point_index, kept = _window_observations(observations, keyframe_ids)
        if not len(kept):
            return
        in_problem = pose_index >= 0
        pixels = np.array([pixel for seen in observations for pixel in seen.values()], np.float64).reshape(-1, 2)
        kept_ids = [landmark_ids[i] for i in kept.tolist()]
        ranges = []
        for keyframe in window:  # consecutive keyframes (ids are consecutive) that are both in the problem
            previous = keyframe.id - 1
            prior = distance_prior(self.map, keyframe.id, previous, self._config, self._scale) \
                if previous in index else None
            if prior is not None:
                ranges.append((index[previous], index[keyframe.id], *prior))
        gauge = 2 if self._scale == "none" or not ranges else 1
        problem = Problem(
            K=self._K,
            poses=np.array([self.map.keyframes[k].T_world_cam for k in keyframe_ids]),
            optimised=len(self._window),
            points=self.map.positions(kept_ids),
            observation_pose=pose_index[in_problem],
            observation_point=point_index[in_problem],
            observation_pixels=pixels[in_problem],
            ranges=np.array(ranges, np.float64).reshape(-1, 4),
            fix_first=max(gauge - len(fixed), 0),
            iterations=cfg.ba_iterations,
            huber_px=cfg.ba_huber_px,
            **rotation_priors(self.map, index, cfg),
        )
        self._submitted = _Submitted(keyframe_ids, len(self._window), np.array(kept_ids, np.int64))
        self._adjuster.submit(problem)

    # -- keyframes and landmarks ---------------------------------------------------------------------------

    def insert_keyframe(
        self, position: int, segment: int, T_world_cam: np.ndarray, track_ids: np.ndarray,  # noqa: N803
        pixels: np.ndarray, image: np.ndarray, metric_step: float | None, why: str,
        track_landmarks: dict[int, int], refound: dict[int, np.ndarray] | None = None,
        landmark_config: MapConfig | None = None, chained_rotation: tuple[np.ndarray, np.ndarray] | None = None,
        triangulated: Callable[[Map, Keyframe, dict[int, int]], None] | None = None,
    ) -> tuple[KeyframeInserted, dict[int, int], MapView]:
        """Add a keyframe seeing (N,) tracks at (N, 2) pixels; `track_landmarks` links live tracks to
        landmarks; `refound` maps landmarks re-found in this frame without a track to their (2,) pixel (they
        are observed too; `landmark_config`: other settings for its new landmarks); `triangulated` is called with
        the new track → landmark links before bundle adjustment is submitted (`map_scale.place_attempts`). Returns
        the event, the new track → landmark links, and what to draw of the map."""
        assert self._submitted is None, "collect the pending bundle adjustment first"
        keyframe = self.map.add_keyframe(position, segment, T_world_cam, track_ids, pixels, metric_step,
                                         chained_rotation)
        observed = []
        for track_id, pixel in zip(track_ids.tolist(), pixels, strict=True):
            landmark_id = track_landmarks.get(track_id)
            if landmark_id is not None and landmark_id in self.map.landmarks:
                self.map.observe(landmark_id, keyframe.id, pixel)
                observed.append(landmark_id)
            else:
                self._sightings.setdefault(track_id, []).append((keyframe.id, pixel))
        for landmark_id, pixel in (refound or {}).items():
            if landmark_id in self.map.landmarks and keyframe.id not in self.map.landmarks[landmark_id].observations:
                self.map.observe(landmark_id, keyframe.id, pixel)
                observed.append(landmark_id)
        alive = set(track_ids.tolist())
        self._sightings = {t: s for t, s in self._sightings.items()
                           if t in alive and self.map.keyframes[s[0][0]].segment == segment}
        settings = landmark_config or self._config
        links = self._triangulate(keyframe, settings)
        if triangulated is not None:
            triangulated(self.map, keyframe, links)
        self._describe(keyframe, image)
        self.keyframe_images[keyframe.id] = image
        self.keyframe_images.pop(keyframe.id - KEYFRAME_IMAGES, None)
        previous_window = self._window
        alive_landmarks = set(track_landmarks.values()) | set(links.values())
        culled = self._cull(segment, alive_landmarks)
        self._submit(segment)
        culled += self._retire([k for k in previous_window if k not in self._window], alive_landmarks)
        culled += self._forget(keyframe.id - self._config.map_keyframes, alive_landmarks)
        event = KeyframeInserted(keyframe.id, position, keyframe.T_world_cam.copy(), why, len(observed), len(links),
                                 culled, settings.min_triangulation_deg)
        return event, links, self._view(previous_window)

    def _triangulate(self, keyframe: Keyframe, config: MapConfig) -> dict[int, int]:
        """New landmarks from tracks seen at an earlier keyframe and at this one (first sighting to now:
        the longest baseline), all pairs in one call. Returns track id → new landmark id."""
        by_first: dict[int, list[int]] = {}
        for track_id, sightings in self._sightings.items():
            if len(sightings) >= 2 and sightings[-1][0] == keyframe.id:
                by_first.setdefault(sightings[0][0], []).append(track_id)
        track_ids: list[int] = []
        poses = []  # T_first_cur of each track's pair
        for first_id, tracks in sorted(by_first.items()):
            T_first_cur = invert_pose(self.map.keyframes[first_id].T_world_cam) @ keyframe.T_world_cam  # noqa: N806
            if np.linalg.norm(T_first_cur[:3, 3]) >= 1e-9:
                track_ids += tracks
                poses += [T_first_cur] * len(tracks)
        if not track_ids:
            return {}
        T_first_cur = np.array(poses)  # (N, 4, 4)  # noqa: N806
        p_first = np.array([self._sightings[t][0][1] for t in track_ids], np.float64)
        p_cur = np.array([self._sightings[t][-1][1] for t in track_ids], np.float64)
        points_cur = triangulate_each(T_first_cur[:, :3, :3], T_first_cur[:, :3, 3], normalise_points(p_cur, self._K),
                                      normalise_points(p_first, self._K))
        good = well_triangulated(points_cur, T_first_cur, p_cur, p_first, self._K, config)
        world = points_cur @ keyframe.T_world_cam[:3, :3].T + keyframe.T_world_cam[:3, 3]
        links: dict[int, int] = {}
        for n in np.flatnonzero(good):
            track_id = track_ids[n]
            landmark = self.map.add_landmark(world[n], {k: p for k, p in self._sightings.pop(track_id)})
            links[track_id] = landmark.id
        return links

    def _describe(self, keyframe: Keyframe, image: np.ndarray) -> None:
        """Upright ORB descriptors (the car's camera hardly rolls) of the landmarks this keyframe sees, at
        their pixel here: what relocalisation matches against."""
        landmark_ids = sorted(keyframe.landmark_ids)
        if not landmark_ids:
            return
        ideal = np.array([self.map.landmarks[i].observations[keyframe.id] for i in landmark_ids], np.float64)
        raw = distort_pixels(ideal, self._camera) if self._camera.distorted else ideal
        keypoints = [cv2.KeyPoint(float(p[0]), float(p[1]), DESCRIPTOR_PATCH, 0.0, 0.0, 0, i)
                     for i, p in zip(landmark_ids, raw, strict=True)]
        described, descriptors = self.describer.compute(image, keypoints)
        if descriptors is None:
            return
        for keypoint, descriptor in zip(described, descriptors, strict=True):
            self.map.landmarks[keypoint.class_id].descriptor = descriptor

    def _retire(self, keyframe_ids: list[int], alive_landmarks: set[int]) -> int:
        """Keyframes leaving the window: their landmarks seen by fewer than `min_observations` keyframes
        and no longer tracked are dropped. Returns how many."""
        culled = 0
        window = set(self._window)
        for keyframe_id in (k for k in keyframe_ids if k in self.map.keyframes):  # (a culled one is gone)
            for landmark_id in list(self.map.keyframes[keyframe_id].landmark_ids):
                landmark = self.map.landmarks.get(landmark_id)
                if (landmark is not None and landmark.observation_count < self._config.min_observations
                        and landmark_id not in alive_landmarks and not window & landmark.observations.keys()):
                    self.map.remove_landmark(landmark_id)
                    culled += 1
        return culled

    def _cull(self, segment: int, alive_landmarks: set[int]) -> int:
        """Remove the keyframe bundle adjustment has just stopped holding (it left the window and then the
        `ba_max_fixed` keyframes behind it, which BA holds fixed) if it is redundant: an older keyframe at its place
        (`covering`; its frames then follow that one) or `cull_redundant_share` of its landmarks seen by
        `cull_observers` others at the same or a finer scale (`redundant`; its frames follow the keyframe before
        it). Never one of a segment's first two keyframes (the gauge), nor one holding a loop edge
        (`Map.loop_keyframes`). Records what it culled in `culled`; returns the landmarks removed with it (left with
        one observation and not tracked). Culled at the window's edge, the window lost the fixed keyframes that tie
        it to the keyframes before it (synthetic drive seed 2: ATE after Sim(3) 0.54 -> 1.02 m, docs/map-backend.md)."""
        self.culled = {}
        cfg, keyframes = self._config, self.map.keyframes
        held = cfg.ba_window + cfg.ba_max_fixed
        recent = self.map.recent_keyframes(held + 1, segment)
        if len(recent) <= held or recent[0].id in self.map.loop_keyframes:
            return 0
        keyframe_id = recent[0].id
        before = [k for k in keyframes.values() if k.segment == segment and k.id < keyframe_id]
        if len(before) < 2:
            return 0
        anchor = covering(self.map, keyframe_id, cfg.cull_separation, COVERED_SPACINGS, COVERED_ANGLE_DEG) \
            if cfg.cull_revisits else None
        if anchor is None and cfg.cull_redundant_share > 0 and \
                redundant(self.map, keyframe_id, cfg.cull_observers, cfg.cull_scale) >= cfg.cull_redundant_share:
            anchor = before[-1].id
        if anchor is None:
            return 0
        self.culled[keyframe_id] = (anchor, invert_pose(keyframes[anchor].T_world_cam)
                                    @ keyframes[keyframe_id].T_world_cam)
        removed = self.map.remove_keyframe(keyframe_id, alive_landmarks)
        if (successor := keyframes.get(keyframe_id + 1)) is not None:
            successor.metric_step = None  # measured from the culled keyframe: no distance prior to the one before
        self.keyframe_images.pop(keyframe_id, None)
        sightings = {t: [(k, p) for k, p in seen if k != keyframe_id] for t, seen in self._sightings.items()}
        self._sightings = {t: seen for t, seen in sightings.items() if seen}
        return removed

    def _forget(self, keyframe_id: int, alive_landmarks: set[int]) -> int:
        """Landmarks no keyframe after `keyframe_id` (the one `map_keyframes` behind the newest) sees and no
        track follows are dropped, and that keyframe releases its track list (its pose stays). Keeps memory
        bounded over a long drive. Returns how many landmarks were dropped."""
        keyframe = self.map.keyframes.get(keyframe_id)
        if keyframe is None:
            return 0
        forgotten = [i for i, landmark in self.map.landmarks.items()
                     if landmark.last_keyframe <= keyframe_id and i not in alive_landmarks]
        for landmark_id in forgotten:
            self.map.remove_landmark(landmark_id)
        # copies, not views (a view of no rows keeps the whole array alive), and the landmark sets rebuilt: a set
        # keeps the table it grew to however many it still holds (~16 KB a keyframe, for the whole run)
        keyframe.track_ids = keyframe.track_ids[:0].copy()
        keyframe.pixels = keyframe.pixels[:0].copy()
        for old in (keyframe, self.map.keyframes.get(keyframe_id - self._config.map_keyframes)):
            if old is not None:
                old.landmark_ids = set(old.landmark_ids)
        return len(forgotten)

    def _view(self, previous_window: list[int]) -> MapView:
        """The window, its landmarks, and what left the window at this keyframe (for the recording)."""
        keyframes = self.map.keyframes
        window = self._window
        fixed = self._submitted.keyframe_ids[self._submitted.optimised:] if self._submitted else []
        previous_window = [k for k in previous_window if k in keyframes]  # a culled keyframe is not drawn
        retired = [k for k in previous_window if k not in window]
        landmark_ids = self.map.landmarks_seen_by([keyframes[k] for k in window])
        previous_landmarks = self.map.landmarks_seen_by([keyframes[k] for k in previous_window])
        retired_landmarks = sorted(set(previous_landmarks) - set(landmark_ids))
        retired_landmarks = [i for i in retired_landmarks if i in self.map.landmarks]
        segment = keyframes[window[-1]].segment if window else 0
        path = sorted((k for k in keyframes.values() if k.segment == segment), key=lambda k: k.id)

        def poses(ids: list[int]) -> np.ndarray:
            return np.array([keyframes[k].T_world_cam for k in ids]).reshape(-1, 4, 4)

        def observations(ids: list[int]) -> np.ndarray:
            return np.array([self.map.landmarks[i].observation_count for i in ids], np.int64)

        return MapView(
            window_ids=np.array(window, np.int64), window_poses=poses(window),
            fixed_ids=np.array(fixed, np.int64), fixed_poses=poses(fixed),
            landmark_ids=np.array(landmark_ids, np.int64), landmark_positions=self.map.positions(landmark_ids),
            landmark_observations=observations(landmark_ids),
            retired_ids=np.array(retired, np.int64), retired_poses=poses(retired),
            retired_landmark_ids=np.array(retired_landmarks, np.int64),
            retired_landmark_positions=self.map.positions(retired_landmarks),
            retired_landmark_observations=observations(retired_landmarks),
            keyframe_path=np.array([k.T_world_cam[:3, 3] for k in path]).reshape(-1, 3),
            keyframe_path_ids=np.array([k.id for k in path], np.int64),
            landmarks_total=len(self.map.landmarks),
        )


def distance_prior(map_: Map, keyframe_id: int, previous: int, config: MapConfig, scale: ScaleSource,
                   ) -> tuple[float, float] | None:
    """(distance, sigma) between a keyframe and the one before it for BA (windowed or global): the scale source's
    length, or with --scale none their distance before this adjustment (σ `none_step_sigma` of it: BA left free
    lengthened the map's steps); None: no prior."""
    keyframe = map_.keyframes[keyframe_id]
    if scale == "none":
        if config.none_step_sigma <= 0:
            return None
        step = float(np.linalg.norm(keyframe.T_world_cam[:3, 3] - map_.keyframes[previous].T_world_cam[:3, 3]))
        return step, max(config.none_step_sigma * step, 1e-9)
    if keyframe.metric_step is None:
        return None
    step = keyframe.metric_step
    return step, config.scale_sigma_gt if scale == "gt" else max(config.scale_sigma_height * step, 1e-3)


def rotation_priors(map_: Map, index: dict[int, int], config: MapConfig) -> dict[str, Any]:
    """A BA problem's relative-rotation priors (`Problem.rotations`, `rotation_measurements`, `rotation_sigma`):
    the front end's chained two-view rotation (`Keyframe.chained_rotation`) between each keyframe of the problem
    (`index`: keyframe id -> pose index) and the one before it, when both are in the problem, with a sigma of
    `rotation_prior_deg` (0: none; `map_scale.for_scale` sets it for `--scale none`). The essential matrix's
    rotation rests on every track, far points included, where PnP and BA see only the landmarks, whose rays had
    to meet at an angle: on KITTI 05 0:300 the map's keyframes drifted 0.13° in yaw in 35 frames where the front
    end's chain drifted 0.01° (docs/map-backend.md)."""
    keyframes = [k for k in index if k - 1 in index and map_.keyframes[k].chained_rotation is not None] \
        if config.rotation_prior_deg > 0 else []
    sigma = float(np.radians(config.rotation_prior_deg))
    covariances = None
    if config.rotation_prior_inflation > 0:
        chained = np.array([c if (c := map_.keyframes[k].chained_covariance) is not None else np.zeros((3, 3))
                            for k in keyframes]).reshape(-1, 3, 3)
        variances, axes = np.linalg.eigh(chained)
        excess = np.clip(variances - np.radians(config.rotation_prior_floor_deg) ** 2, 0.0,
                         np.radians(config.rotation_prior_cap_deg) ** 2 / config.rotation_prior_inflation**2)
        covariances = sigma**2 * np.eye(3) + config.rotation_prior_inflation**2 * np.einsum(
            "qij,qj,qkj->qik", axes, excess, axes)
    return {"rotations": np.array([(index[k - 1], index[k]) for k in keyframes], np.int64).reshape(-1, 2),
            "rotation_measurements": np.array([map_.keyframes[k].chained_rotation for k in keyframes],
                                              np.float64).reshape(-1, 3, 3),
            "rotation_sigma": sigma, "rotation_covariances": covariances}


def _window_observations(observations: list[dict[int, np.ndarray]], keyframe_ids: list[int],
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The BA problem's observations among every observation of L landmarks (`observations`, landmark by
    landmark in dict order: O in all): (O,) index in `keyframe_ids` of each observation's keyframe (−1: not in
    the problem, or its landmark is seen by fewer than two of the problem's keyframes and is left out), (O,) its
    landmark's index among the landmarks kept, and the (P,) indices of the kept landmarks in `observations`."""
    counts = np.array([len(seen) for seen in observations], np.int64)
    seen_by = np.fromiter((k for seen in observations for k in seen), np.int64, int(counts.sum()))
    slot = np.full(max(int(seen_by.max(initial=0)), max(keyframe_ids)) + 1, -1, np.int64)
    slot[keyframe_ids] = np.arange(len(keyframe_ids))
    pose_index = slot[seen_by]
    landmark = np.repeat(np.arange(len(observations)), counts)
    in_problem = np.bincount(landmark[pose_index >= 0], minlength=len(observations))
    kept = np.flatnonzero(in_problem >= 2)
    point = np.cumsum(in_problem >= 2) - 1
    pose_index[in_problem[landmark] < 2] = -1
    return pose_index, point[landmark], kept


def well_triangulated(points_cur: np.ndarray, T_first_cur: np.ndarray, p_cur: np.ndarray,  # noqa: N803
                      p_first: np.ndarray, K: np.ndarray, config: MapConfig) -> np.ndarray:  # noqa: N803
    """(N,) bool: which of (N, 3) points, triangulated in the current camera from (N, 2) ideal pixels `p_cur` and
    `p_first` of a first keyframe, make landmarks: in front of both cameras, rays meeting at
    `min_triangulation_deg` or more, and reprojecting within `max_reprojection_px` into both keyframes.
    `T_first_cur` (N, 4, 4): each point's pair of cameras."""
    points_first = np.einsum("nij,nj->ni", T_first_cur[:, :3, :3], points_cur) + T_first_cur[:, :3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        error_cur = _project_error(points_cur, p_cur, K)
        error_first = _project_error(points_first, p_first, K)
        return np.asarray(
            in_front_with_parallax(points_cur, points_first, T_first_cur[:, :3, 3], config.min_triangulation_deg)
            & (error_cur <= config.max_reprojection_px) & (error_first <= config.max_reprojection_px)
        )


def _project_error(points: np.ndarray, pixels: np.ndarray, K: np.ndarray) -> np.ndarray:  # noqa: N803
    """(N,) pixel distance between (N, 3) camera-frame points projected by K and (N, 2) pixels."""
    projected = points[:, :2] / points[:, 2:3] * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
    return np.asarray(np.linalg.norm(projected - pixels, axis=1))


def _mean_per_landmark(errors: np.ndarray, point_index: np.ndarray, count: int) -> np.ndarray:
    """(count,) mean of the finite per-observation errors of each landmark."""
    finite = np.isfinite(errors)
    total = np.bincount(point_index[finite], errors[finite], minlength=count)
    seen = np.bincount(point_index[finite], minlength=count)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen > 0, total / np.maximum(seen, 1), np.nan)


def reanchor(culled: dict[int, tuple[int, np.ndarray]], *relatives: dict[int, tuple[int, np.ndarray]]) -> None:
    """Frames stored relative to culled keyframes (each of `relatives`: run position -> (keyframe id, (4, 4)
    T_key_frame), in place) follow the keyframe each culled one names (`LocalMapping.culled`: (anchor id,
    T_anchor_culled)); their poses are unchanged by it."""
    if not culled:
        return
    for relative in relatives:
        for position, (keyframe_id, T_key_frame) in relative.items():  # noqa: N806
            if keyframe_id in culled:
                anchor, T_anchor_culled = culled[keyframe_id]  # noqa: N806
                relative[position] = (anchor, T_anchor_culled @ T_key_frame)
