"""The map backend's per-frame re-finding of landmarks: local-map tracking by projection and guided relocalisation.

`MapTracking` (tracking.py) calls, per frame: `start_frame` (the frame's image and time), then
`track` on a frame with a pose (the local map's landmarks no live track follows, re-found in a small window
around their projection: vslam_core/mapping/local_map.py) or `relocalise` on a frame whose tracks were lost
(vslam_core/mapping/relocalisation.py), then `end_frame` with the frame's final pose (the motion model).
The frame's FAST corners are detected once, when first needed. `search` is the frame's last search, for its
result (`MapFrame.local_map`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from vslam_core.coasting import steady, unit_step
from vslam_core.config import MapConfig, TrackerConfig
from vslam_core.mapping.local_map import FrameCorners, LocalMapSearcher, local_keyframes, refind_by_flow
from vslam_core.mapping.local_mapping import LocalMapping
from vslam_core.mapping.map import Map
from vslam_core.mapping.map_search import Check, count_in_view, search_map
from vslam_core.mapping.pnp import project
from vslam_core.mapping.relocalisation import MotionModel, bridged_prediction, relocalise_guided
from vslam_core.results import LocalMapSearch, PnPEstimate, PnPFailure, Relocalisation
from vslam_core.sources.base import CameraIntrinsics, Frame

INTERVALS = 10  # frame intervals remembered
MISSING_FACTOR = 1.5  # an interval this much longer than usual: frames are missing


class MapRefinding:
    """Re-finds the map's landmarks in each frame (see the module docstring)."""

    def __init__(self, camera: CameraIntrinsics, config: MapConfig, searcher: LocalMapSearcher,
                 tracker: TrackerConfig) -> None:
        self._camera = camera
        self._tracker = tracker
        self._config = config
        self._searcher = searcher
        self._motion = MotionModel()
        self._image: np.ndarray | None = None
        self._time = 0.0
        self._started = False  # a frame has been seen (the first has no previous one)
        self._previous_time: float | None = None
        self._intervals: list[float] = []  # the last few intervals between consecutive frames
        self._corners: FrameCorners | None = None
        self._posed: tuple[np.ndarray, np.ndarray] | None = None  # the last posed frame's image and pose
        self.search: LocalMapSearch | None = None

    def start_frame(self, frame: Frame) -> None:
        """A new frame: its time is its timestamp (seconds), or its index in the source without a clock, so
        frames missing from the log lengthen the motion model's prediction."""
        self._image = frame.image
        # the first frame has no interval: taking the initial 0.0 as its predecessor put a 0 s interval in the
        # history of every run that starts at time 0, and from then on every frame looked like frames missing
        self._previous_time = self._time if self._started else None
        self._started = True
        self._time = float(frame.timestamp) if frame.timestamp is not None else float(frame.index)
        self._corners = None
        self.search = None

    def end_frame(self, T_world_cam: np.ndarray | None) -> None:  # noqa: N803
        """The frame's final pose (None for a frame whose pose was held)."""
        if self._previous_time is not None and self._time > self._previous_time and not self.frames_missing():
            self._intervals = [*self._intervals[-(INTERVALS - 1):], self._time - self._previous_time]
        if T_world_cam is not None and self._image is not None:
            self._motion.update(self._time, T_world_cam)
            self._posed = (self._image, T_world_cam.copy())

    def frames_missing(self) -> bool:
        """Frames are missing before this one: the time since the previous frame is over `MISSING_FACTOR`
        times the median of the last intervals (a log with dropped frames; the clock says so)."""
        if self._previous_time is None or not self._intervals:
            return False
        return self._time - self._previous_time > MISSING_FACTOR * float(np.median(self._intervals))

    def predicted_pose(self) -> np.ndarray | None:
        """(4, 4) T_world_cam the motion model predicts for this frame; None before it has two poses."""
        return self._motion.predict(self._time)

    def trusted_motion(self, T_world_last: np.ndarray, rotation: np.ndarray, direction: np.ndarray,  # noqa: N803
                       max_disagreement_deg: float, first: bool) -> tuple[np.ndarray, np.ndarray]:
        """A dead-reckoned motion from the last posed frame (T_world_last (4, 4)): (3, 3) `rotation` and unit (3,)
        `direction`; on a gap's `first` frame the motion model's own for this frame's time instead when its
        rotation is over `max_disagreement_deg` from the prediction's, on the others the step before it
        (`coasting.steady`: the model's trend fitted on dead-reckoned poses fed back into itself and ran away)."""
        if not first:
            return steady((rotation, direction), self._motion.last_step(), max_disagreement_deg)
        predicted = self._motion.predict(self._time)
        if predicted is None:
            return rotation, direction
        expected = unit_step(T_world_last, predicted)
        return steady((rotation, direction), expected, max_disagreement_deg)

    def bridge(self, length: float | None) -> np.ndarray | None:
        """(4, 4) pose of a frame after frames missing from the log that nothing else could place: the motion
        model's prediction at this frame's time (relocalisation.MotionModel: the turn rate's trend over the
        gap) with its rotation and direction measured from the last posed frame's image when they can be
        (relocalisation.bridged_prediction: KLT from where the predicted rotation puts its corners, the
        essential matrix); the step from that frame `length` long (None: the model's). None before the
        motion model has two poses."""
        predicted = self._motion.predict(self._time)
        if predicted is None or self._image is None or self._posed is None:
            return None
        bridged = bridged_prediction(self._posed[0], self._image, self._posed[1], predicted, self._camera)
        step = np.linalg.inv(self._posed[1]) @ bridged
        if length is not None:
            step[:3, 3] *= length / max(float(np.linalg.norm(step[:3, 3])), 1e-12)
        return np.asarray(self._posed[1] @ step)

    def _frame_corners(self) -> FrameCorners:
        if self._corners is None:
            assert self._image is not None, "start_frame first"
            self._corners = self._searcher.corners(self._image)
        return self._corners

    def track(self, mapping: LocalMapping, reference: int, segment: int, T_world_cam: np.ndarray,  # noqa: N803
              exclude: set[int]) -> PnPEstimate:
        """Landmarks of the local map around keyframe `reference` that no live track follows (`exclude`),
        re-found near their projection with the frame's pose (local_map.refind_by_flow): (L,) ids at (L, 2)
        ideal pixels, inliers where they agree with the pose (only those are linked to new tracks)."""
        assert self._image is not None, "start_frame first"
        world = mapping.map
        keyframe_ids = local_keyframes(world, reference, segment, self._config.local_map_keyframes)
        search, agrees = refind_by_flow(world, mapping.keyframe_images, self._image, keyframe_ids, T_world_cam,
                                        self._camera, self._config, self._tracker, mapping.describer, exclude)
        self.search = search
        found = search.found_mask
        return PnPEstimate(search.landmark_ids[found], search.found_pixels[found], search.projected[found],
                           agrees[found], T_world_cam)

    def search_map(self, world: Map, reference: int, segment: int, predicted: np.ndarray, previous: np.ndarray,
                   tracked: tuple[np.ndarray, np.ndarray], seed: tuple[int, ...], check: Check,
                   origin: np.ndarray | None = None) -> PnPEstimate:
        """PnP on the `tracked` landmarks ((T,) ids, (T, 2) ideal pixels) failed: the local map around keyframe
        `reference` searched by projection from `predicted` (the last pose `previous`; `origin`, the pose a
        two-view prediction's step is measured from) in widening windows and PnP solved again (map_search.py).
        The estimate has a pose when its `failure` is None."""
        keyframe_ids = local_keyframes(world, reference, segment, self._config.local_map_keyframes)
        estimate, search = search_map(self._searcher, world, self._frame_corners(), keyframe_ids, predicted, previous,
                                      tracked, self._camera.K, self._config, seed, check, origin)
        self.search = search
        return estimate

    def in_view(self, world: Map, reference: int, segment: int, predicted: np.ndarray | None,
                tracked: PnPEstimate | None) -> PnPEstimate | None:
        """The `tracked` estimate (PnP failed) with the local map's landmarks the `predicted` pose puts in the
        image counted (`in_view`), and `too_few_in_view` when they are fewer than PnP needs (no search)."""
        if tracked is None or predicted is None:
            return tracked
        keyframe_ids = local_keyframes(world, reference, segment, self._config.local_map_keyframes)
        count = count_in_view(world, keyframe_ids, predicted, self._camera.K, self._image_size())
        failure = PnPFailure.TOO_FEW_IN_VIEW if count < self._config.pnp_min_landmarks else tracked.failure
        return replace(tracked, in_view=count, failure=failure)

    def _image_size(self) -> tuple[int, int]:
        assert self._image is not None, "start_frame first"
        return self._image.shape[1], self._image.shape[0]

    def relocalise(self, world: Map, reference: int, segment: int,
                   seed: tuple[int, ...]) -> tuple[Relocalisation, PnPEstimate | None]:
        """Guided relocalisation (relocalisation.py) against the local map around keyframe `reference`, from
        the motion model's prediction at this frame's time. The estimate is None when it fails (or before the
        motion model has two poses)."""
        predicted = self._motion.predict(self._time)
        if predicted is None or self._image is None or self._posed is None:
            return Relocalisation(False, None, 0, 0, 0), None
        predicted = bridged_prediction(self._posed[0], self._image, self._posed[1], predicted, self._camera)
        keyframe_ids = local_keyframes(world, reference, segment, self._config.local_map_keyframes)
        outcome = relocalise_guided(self._searcher, world, self._frame_corners(), keyframe_ids, predicted,
                                    self._camera.K, self._config, seed)
        self.search = outcome.search
        candidates = len(outcome.search.landmark_ids)
        solution = outcome.solution
        if solution is None or solution.T_world_cam is None:
            return Relocalisation(False, None, candidates, len(outcome.landmark_ids), 0), None
        inliers = set(outcome.landmark_ids[solution.inlier_mask].tolist())
        self.search.accepted[:] = outcome.search.found_mask & np.isin(outcome.search.landmark_ids, list(inliers))
        best = max(keyframe_ids, key=lambda k: (len(world.keyframes[k].landmark_ids & inliers), k))
        return (Relocalisation(True, best, candidates, len(outcome.landmark_ids), len(inliers)),
                PnPEstimate(outcome.landmark_ids, outcome.pixels, solution.projected, solution.inlier_mask,
                            solution.T_world_cam))


def suspended_at_keyframe(the_map: Map, suspended: dict[int, int], track_ids: np.ndarray, pixels: np.ndarray,
                          pose: np.ndarray, K: np.ndarray, config: MapConfig  # noqa: N803
                          ) -> tuple[dict[int, int], dict[int, int]]:
    """Tracks PnP rejected (`suspended`: track id → landmark id) whose (N,) ids' (N, 2) ideal pixels in a keyframe
    at `pose` lie within `keyframe_observation_px` of their landmark's projection: the keyframe observes the
    landmark there (BA refines its depth rather than a duplicate landmark being triangulated); within
    `pnp_threshold_px` they are linked again. The others are released (their track may start a new landmark).
    Returns (track id → landmark id observed, track id → landmark id linked again)."""
    rows = [(n, t) for n, t in enumerate(track_ids.tolist()) if suspended.get(t) in the_map.landmarks]
    if not rows:
        return {}, {}
    landmark_ids = [suspended[t] for _, t in rows]
    error = np.linalg.norm(project(the_map.positions(landmark_ids), pose, K) - pixels[[n for n, _ in rows]], axis=1)
    pairs = [(t, m, e) for (_, t), m, e in zip(rows, landmark_ids, error, strict=True)]
    return ({t: m for t, m, e in pairs if e <= config.keyframe_observation_px},
            {t: m for t, m, e in pairs if e <= config.pnp_threshold_px})
