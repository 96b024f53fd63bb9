"""Loop closing, tracking's side: at each keyframe insertion (a fixed point) the search submitted at the
previous insertion is collected, waiting for it if it is not done, and a loop it accepted is applied to the map;
then the search for the previous keyframe (bundle-adjusted once by now) is submitted
(vslam_core/loop/worker.py runs it beside tracking). A keyframe's search is therefore submitted when the next
keyframe is inserted and collected when the one after that is: the same input always gives the same map.

Applying a loop: the search optimised the pose graph of the keyframes as they were when it was submitted;
each keyframe moves by its own node's correction (a similarity X ← s·R'·Rᵀ(X − t) + t', rigid when s = 1) applied
to its pose as it is now (bundle adjustment may have refined it since), a keyframe inserted since moves with
the newest node, each landmark with the newest keyframe that observes it, and tracking carries on from the
corrected newest keyframe (frames are stored relative to their keyframes, so every pose written after the run is
corrected). With --scale none a node's correction also scales its neighbourhood by s: the frames stored
relative to its keyframes move s times farther from them (`rescale_relative`).
"""

from __future__ import annotations

import time

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose, orthonormalise, rotation_angle
from vslam_core.loop.places import EMPTY_DESCRIPTORS, KeyframePlace
from vslam_core.loop.search import GraphSolution, SearchJob, SearchResult
from vslam_core.loop.worker import LoopWorker
from vslam_core.mapping.map import Map
from vslam_core.mapping.worker_process import BackendWorker
from vslam_core.results import LoopClosed, LoopStep, elapsed_ms
from vslam_core.sources.base import CameraIntrinsics

NO_IMAGE = np.zeros((0, 0), np.uint8)


class LoopClosing:
    """Hands keyframes to the loop search and applies the loops it closes to the map."""

    def __init__(self, camera: CameraIntrinsics, config: EngineConfig, worker: BackendWorker | None) -> None:
        self._config = config.loop
        self._settled = config.map.ba_window + config.map.ba_max_fixed + 1  # keyframes after which BA is done
        self._worker = LoopWorker(camera, config, worker)
        self._waiting: tuple[int, np.ndarray] | None = None  # (keyframe id, image) not submitted yet
        self.places: dict[int, KeyframePlace] = {}  # keyframes searched, with their features (the map file)
        # every keyframe's place is kept only for a saved map (vslam_core/mapping/storage.py `snapshot`); without
        # one, only those `_refresh` still reads: the loop data of tracking's process then follows the place
        self.keep_places = True
        self._culled: list[int] = []  # keyframes culled from the map, for the next job (the worker's places)
        self.loops_closed = 0  # (the loops themselves go out with their frame's result: each holds every pose twice)

    def submit(self, keyframe_id: int, image: np.ndarray) -> None:
        """A keyframe was inserted: its search is submitted at the next insertion (after its bundle adjustment)."""
        self._waiting = (keyframe_id, image)

    def forget(self, keyframe_ids: list[int]) -> None:
        """Keyframes culled from the map: their places go, here and (with the next job) in the search's database."""
        for keyframe_id in keyframe_ids:
            self.places.pop(keyframe_id, None)
        self._culled += keyframe_ids

    def collect(self, map_: Map) -> tuple[LoopStep, np.ndarray | None] | None:
        """At a keyframe insertion, after the bundle adjustment was applied: collect the search submitted at the
        previous insertion (applying its loop, if any), then submit the search for the map's newest keyframe.
        Returns what the collected search did and, if it closed a loop, the correction (4, 4) of the newest
        keyframe for the frames tracked since: T_new·T_old⁻¹, or with --scale none the world similarity
        s·R, t (the caller orthonormalises the corrected pose); None if no search was pending."""
        collected = self._collect(map_)
        clock = time.perf_counter()
        self._start(map_)
        if collected is not None:  # the snapshot and hand-over, in the tracking thread
            collected[0].timings_ms["submit"] = elapsed_ms(clock)
        return collected

    def finish(self, map_: Map) -> list[tuple[LoopStep, np.ndarray | None]]:
        """The run ended: collect the last search (its loop is applied), then search for the newest keyframe as
        the final one (no cooldown: vslam_core/loop/search.py) and apply what it closes. Returns what each did and
        the correction of a loop it closed, in order (nothing when called again)."""
        steps = [step for step in (self._collect(map_),) if step is not None]
        self._start(map_, final=True)
        steps += [step for step in (self._collect(map_),) if step is not None]
        return steps

    # -- steps ------------------------------------------------------------------------------------------------

    def _collect(self, map_: Map) -> tuple[LoopStep, np.ndarray | None] | None:
        result = self._worker.collect()
        if result is None:
            return None
        self._keep_features(result)
        timings = {**result.timings_ms, "wait": self._worker.waited_ms}
        if result.graph is None:
            return LoopStep(result.candidates, None, timings), None
        clock = time.perf_counter()
        closed, correction = self._apply(map_, result.graph, result.timings_ms.get("optimise", 0.0))
        timings["apply"] = elapsed_ms(clock)
        self.loops_closed += 1
        return LoopStep(result.candidates, closed, timings), correction

    def _keep_features(self, result: SearchResult) -> None:
        place = self.places.get(result.keyframe_id)
        if place is not None:
            place.pixels, place.descriptors = result.pixels, result.descriptors

    def _start(self, map_: Map, final: bool = False) -> None:
        """Submit the search for the waiting keyframe: a snapshot of it and of its segment's keyframe poses."""
        waiting, self._waiting = self._waiting, None
        if waiting is None or waiting[0] not in map_.keyframes:
            return
        place = self._place(map_, waiting[0])
        self.places[place.keyframe_id] = place
        if not self.keep_places:
            self._drop_places_before(place.keyframe_id - self._settled)
        graph = [k for k in map_.keyframes.values() if k.segment == place.segment and k.id <= place.keyframe_id]
        self._worker.submit(SearchJob(
            keyframe_id=place.keyframe_id, position=place.position, segment=place.segment, image=waiting[1],
            point_ids=place.point_ids, points_cam=place.points_cam, point_pixels=place.point_pixels,
            point_descriptors=place.point_descriptors,
            graph_ids=np.array([k.id for k in graph], np.int64),
            graph_positions=np.array([k.position for k in graph], np.int64),
            graph_poses=np.array([k.T_world_cam for k in graph]).reshape(-1, 4, 4),
            refreshed=self._refresh(map_, place.keyframe_id - self._settled), final=final, culled=tuple(self._culled)))
        self._culled = []

    def _place(self, map_: Map, keyframe_id: int) -> KeyframePlace:
        """The keyframe's landmarks in its camera frame (its features come back with its search)."""
        keyframe = map_.keyframes[keyframe_id]
        landmark_ids = [i for i in sorted(keyframe.landmark_ids) if map_.landmarks[i].descriptor is not None]
        T_cam_world = invert_pose(keyframe.T_world_cam)  # noqa: N806
        world = map_.positions(landmark_ids)
        return KeyframePlace(
            keyframe_id=keyframe.id, position=keyframe.position, segment=keyframe.segment,
            pixels=np.zeros((0, 2), np.float32), descriptors=EMPTY_DESCRIPTORS,
            point_ids=np.array(landmark_ids, np.int64),
            points_cam=world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3],
            point_pixels=np.array([map_.landmarks[i].observations[keyframe.id] for i in landmark_ids],
                                  np.float32).reshape(-1, 2),
            point_descriptors=(np.array([map_.landmarks[i].descriptor for i in landmark_ids], np.uint8)
                               if landmark_ids else EMPTY_DESCRIPTORS),
            thumbnail=NO_IMAGE)

    def _drop_places_before(self, keyframe_id: int) -> None:
        """Forget the places of keyframes older than `keyframe_id` (ids ascend in insertion order)."""
        for old in [k for k in self.places if k < keyframe_id]:
            del self.places[old]

    def _refresh(self, map_: Map, keyframe_id: int) -> tuple[int, np.ndarray] | None:
        """A keyframe's landmarks re-read once bundle adjustment no longer moves them (it left the window and
        the fixed keyframes): verification then uses their refined positions. Returns (keyframe id, (L, 3))."""
        place = self.places.get(keyframe_id)
        keyframe = map_.keyframes.get(keyframe_id)
        if place is None or keyframe is None:
            return None
        T_cam_world = invert_pose(keyframe.T_world_cam)  # noqa: N806
        points = place.points_cam.copy()
        present = np.array([i in map_.landmarks for i in place.point_ids.tolist()], bool)
        world = map_.positions(place.point_ids[present])
        points[present] = world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        place.points_cam = points
        return keyframe_id, points

    def _apply(self, map_: Map, graph: GraphSolution, optimise_ms: float) -> tuple[LoopClosed, np.ndarray]:
        """Move the segment's keyframes and landmarks by the optimised graph (see the module docstring)."""
        start = time.perf_counter()
        segment = map_.keyframes[graph.query_keyframe].segment
        node = {k: n for n, k in enumerate(graph.keyframe_ids.tolist())}
        newest = len(node) - 1
        ids = [k.id for k in map_.keyframes.values() if k.segment == segment]
        node_of = {k: node.get(k, newest) for k in ids}
        similarities = [_similarity(b, a, s) for b, a, s in zip(graph.poses_before, graph.poses_after, graph.scales,
                                                                strict=True)]
        before = np.array([map_.keyframes[k].T_world_cam for k in ids])
        after = np.array([orthonormalise(_moved_pose(similarities[node_of[k]], pose))
                          for k, pose in zip(ids, before, strict=True)])
        moved = 0
        for landmark in map_.landmarks.values():
            seen = [k for k in landmark.observations if k in node_of]
            if seen:
                S = similarities[node_of[max(seen)]]  # noqa: N806
                landmark.position = S[:3, :3] @ landmark.position + S[:3, 3]
                moved += 1
        for k, pose in zip(ids, after, strict=True):
            map_.keyframes[k].T_world_cam = pose
        map_.loop_keyframes |= {graph.query_keyframe, graph.candidate_keyframe}
        scales = np.array([graph.scales[node_of[k]] for k in ids])
        correction = similarities[node_of[ids[-1]]] if graph.similarity else after[-1] @ invert_pose(before[-1])
        closed = LoopClosed(
            query_keyframe=graph.query_keyframe, candidate_keyframe=graph.candidate_keyframe,
            query_position=graph.query_position, candidate_position=graph.candidate_position, inliers=graph.inliers,
            similarity=graph.similarity, keyframe_ids=np.array(ids, np.int64),
            keyframe_positions=np.array([map_.keyframes[k].position for k in ids], np.int64),
            poses_before=before, poses_after=after,
            correction_m=np.linalg.norm(after[:, :3, 3] - before[:, :3, 3], axis=1),
            correction_deg=np.degrees([rotation_angle(a[:3, :3] @ b[:3, :3].T) for a, b in zip(after, before,
                                                                                                 strict=True)]),
            scales=scales, landmarks_moved=moved, milliseconds=optimise_ms + elapsed_ms(start))
        return closed, correction


def rescale_relative(closed: LoopClosed, *relatives: dict[int, tuple[int, np.ndarray]]) -> None:
    """A Sim(3) correction made keyframe k's neighbourhood s_k times larger: the frames stored relative to it
    (each of `relatives`: run position -> (keyframe id, (4, 4) T_key_frame), in place) move s_k times farther."""
    scale_of = dict(zip(closed.keyframe_ids.tolist(), closed.scales.tolist(), strict=True))
    for relative in relatives:
        for position, (keyframe_id, T_key_frame) in relative.items():  # noqa: N806
            scale = scale_of.get(keyframe_id, 1.0)
            if scale != 1.0:
                moved = T_key_frame.copy()
                moved[:3, 3] *= scale
                relative[position] = (keyframe_id, moved)


def _similarity(before: np.ndarray, after: np.ndarray, scale: float) -> np.ndarray:
    """(4, 4) the world motion X ← s·R'·Rᵀ(X − t) + t' that takes a (4, 4) node pose `before` to `after`."""
    rotation = after[:3, :3] @ before[:3, :3].T
    S = np.eye(4)  # noqa: N806
    S[:3, :3] = scale * rotation
    S[:3, 3] = after[:3, 3] - scale * rotation @ before[:3, 3]
    return S


def _moved_pose(S: np.ndarray, pose: np.ndarray) -> np.ndarray:  # noqa: N803
    """(4, 4) a T_world_cam moved by the world similarity S: its centre by S, its orientation by S's rotation."""
    scale = float(np.cbrt(np.linalg.det(S[:3, :3])))
    moved = np.eye(4)
    moved[:3, :3] = S[:3, :3] / scale @ pose[:3, :3]
    moved[:3, 3] = S[:3, :3] @ pose[:3, 3] + S[:3, 3]
    return moved
