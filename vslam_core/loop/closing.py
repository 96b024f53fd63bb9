"""Loop closing: at each keyframe insertion (a fixed point, so runs stay deterministic), the previous keyframe
is described, searched for among older keyframes (`places`), its candidates verified (`verification`), and
once a place is verified on `consistency` consecutive keyframes the pose graph is optimised (`pose_graph`):
the segment's keyframes move, their landmarks with them, and tracking carries on from the corrected newest
keyframe (frames are stored relative to their keyframes, so every pose written after the run is corrected).
"""

from __future__ import annotations

import importlib
import threading
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose, orthonormalise, rotation_angle
from vslam_core.loop.places import EMPTY_DESCRIPTORS, KeyframePlace, PlaceDatabase, describe_image
from vslam_core.loop.pose_graph import LoopEdge, optimise
from vslam_core.loop.verification import Verification, verify
from vslam_core.mapping.map import Map
from vslam_core.results import LoopCandidate, LoopClosed, LoopStep

CONSISTENT_KEYFRAMES = 5  # verified candidates of consecutive queries are this close (keyframe ids) to agree
NEIGHBOURS = 2  # keyframes on each side of a candidate whose landmarks join its verification


@dataclass
class _Pending:
    keyframe_id: int
    image: np.ndarray


class LoopClosing:
    """Place recognition, verification and pose-graph correction over the map's keyframes."""

    def __init__(self, K: np.ndarray, config: EngineConfig, describer: cv2.ORB) -> None:  # noqa: N803
        self._K = K
        self._config = config.loop
        self._seed = config.pose.seed
        self._metric = config.scale != "none"
        self._settled = config.map.ba_window + config.map.ba_max_fixed + 1  # keyframes after which BA is done
        self._describer = describer
        self.database = PlaceDatabase(config.loop, config.pose.seed)
        self._pending: _Pending | None = None
        self._streak: list[tuple[int, int]] = []  # (query, candidate) verified on consecutive keyframes
        self._last_closed = -(10**9)
        self.closed: list[LoopClosed] = []
        self._edges: list[tuple[int, int, np.ndarray, float]] = []  # (candidate, query, T_candidate_query, scale)
        # gtsam is imported on the first closure: start importing it now, beside tracking (once, a few seconds)
        threading.Thread(target=importlib.import_module, args=("gtsam",), name="vslam-gtsam-import",
                         daemon=True).start()

    def submit(self, keyframe_id: int, image: np.ndarray) -> None:
        """A keyframe was inserted: it is handled at the next insertion (after its bundle adjustment)."""
        self._pending = _Pending(keyframe_id, image)

    def collect(self, map_: Map) -> tuple[LoopStep, np.ndarray | None] | None:
        """Handle the pending keyframe (the map's newest): returns what was done and, if a loop was closed, the
        correction T_new·T_old⁻¹ (4, 4) of that keyframe, for the frames tracked since. None if none pending."""
        pending, self._pending = self._pending, None
        if pending is None or pending.keyframe_id not in map_.keyframes:
            return None
        timings: dict[str, float] = {}
        clock = time.perf_counter()
        query = self._place(map_, pending)
        self._refresh(map_, pending.keyframe_id - self._settled)
        timings["describe"] = _lap(clock)
        clock = time.perf_counter()
        self.database.add(query)  # its words first (the search never returns the query: min separation)
        found = self.database.candidates(query)
        timings["query"] = _lap(clock)
        clock = time.perf_counter()
        checked = [(candidate, score, verify(query, self._with_neighbours(map_, candidate), self._K, self._config,
                                             (self._seed, query.position, candidate, 2), self._metric))
                   for candidate, score in found]
        timings["verify"] = _lap(clock)
        best = max((c for c in checked if c[2].rejected is None), key=lambda c: (c[2].inliers, -c[0]), default=None)
        accepted, why = self._consistent(query.keyframe_id, best[0] if best is not None else None)
        chosen = best[0] if accepted and best is not None else None
        candidates = tuple(self._candidate(query, candidate, score, result, candidate == chosen,
                                           why if chosen is None or candidate == chosen
                                           else "another candidate had more inliers")
                           for candidate, score, result in checked)
        if not accepted or best is None:
            return LoopStep(candidates, None, timings), None
        clock = time.perf_counter()
        closed, correction = self._close(map_, query, best[0], best[2])
        timings["optimise"] = _lap(clock)
        self.closed.append(closed)
        return LoopStep(candidates, closed, timings), correction

    def finish(self, map_: Map) -> None:
        """Describe the pending keyframe without searching (the run ended): the database holds every keyframe."""
        pending, self._pending = self._pending, None
        if pending is not None and pending.keyframe_id in map_.keyframes:
            self.database.add(self._place(map_, pending))

    # -- steps ------------------------------------------------------------------------------------------------

    def _place(self, map_: Map, pending: _Pending) -> KeyframePlace:
        """The keyframe's features and its landmarks in its camera frame."""
        keyframe = map_.keyframes[pending.keyframe_id]
        pixels, descriptors = describe_image(pending.image, self._config.features, self._config.fast_threshold,
                                             self._describer)
        landmark_ids = [i for i in sorted(keyframe.landmark_ids) if map_.landmarks[i].descriptor is not None]
        T_cam_world = invert_pose(keyframe.T_world_cam)  # noqa: N806
        world = map_.positions(landmark_ids)
        return KeyframePlace(
            keyframe_id=keyframe.id, position=keyframe.position, segment=keyframe.segment, pixels=pixels,
            descriptors=descriptors, point_ids=np.array(landmark_ids, np.int64),
            points_cam=world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3],
            point_pixels=np.array([map_.landmarks[i].observations[keyframe.id] for i in landmark_ids],
                                  np.float32).reshape(-1, 2),
            point_descriptors=(np.array([map_.landmarks[i].descriptor for i in landmark_ids], np.uint8)
                               if landmark_ids else EMPTY_DESCRIPTORS),
            thumbnail=cv2.resize(pending.image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA),
        )

    def _refresh(self, map_: Map, keyframe_id: int) -> None:
        """Re-read a keyframe's landmarks into its place once bundle adjustment no longer moves them (it left the
        window and the fixed keyframes): verification then uses their refined positions."""
        place = self.database.places.get(keyframe_id)
        keyframe = map_.keyframes.get(keyframe_id)
        if place is None or keyframe is None:
            return
        T_cam_world = invert_pose(keyframe.T_world_cam)  # noqa: N806
        for n, landmark_id in enumerate(place.point_ids.tolist()):
            landmark = map_.landmarks.get(landmark_id)
            if landmark is not None:
                place.points_cam[n] = T_cam_world[:3, :3] @ landmark.position + T_cam_world[:3, 3]

    def _with_neighbours(self, map_: Map, candidate: int) -> KeyframePlace:
        """The candidate's place with the landmarks of its `NEIGHBOURS` keyframes on each side added (moved into
        its camera frame by the map's poses; each landmark once): more correspondences for the loop edge."""
        place = self.database.places[candidate]
        T_cam_world = invert_pose(map_.keyframes[candidate].T_world_cam)  # noqa: N806
        seen = set(place.point_ids.tolist())
        points, pixels, descriptors, ids = [place.points_cam], [place.point_pixels], [place.point_descriptors], \
            [place.point_ids]
        for other_id in range(candidate - NEIGHBOURS, candidate + NEIGHBOURS + 1):
            other = self.database.places.get(other_id)
            keyframe = map_.keyframes.get(other_id)
            if other is None or keyframe is None or other_id == candidate or other.segment != place.segment:
                continue
            new = np.array([i not in seen for i in other.point_ids.tolist()], bool)
            seen |= set(other.point_ids[new].tolist())
            T = T_cam_world @ keyframe.T_world_cam  # noqa: N806
            points.append(other.points_cam[new] @ T[:3, :3].T + T[:3, 3])
            pixels.append(np.full((int(new.sum()), 2), np.nan, np.float32))  # not seen in the candidate's image
            descriptors.append(other.point_descriptors[new])
            ids.append(other.point_ids[new])
        return replace(place, points_cam=np.concatenate(points), point_pixels=np.concatenate(pixels),
                       point_descriptors=np.concatenate(descriptors), point_ids=np.concatenate(ids))

    def _consistent(self, query: int, candidate: int | None) -> tuple[bool, str]:
        """Track verified places over consecutive keyframes: accept the `consistency`-th in a row."""
        cfg = self._config
        if candidate is None:
            self._streak = []
            return False, "not verified"
        previous = self._streak[-1] if self._streak else None
        if previous is None or previous[0] != query - 1 or abs(previous[1] - candidate) > CONSISTENT_KEYFRAMES:
            self._streak = []
        self._streak.append((query, candidate))
        if len(self._streak) < cfg.consistency:
            return False, f"not consistent yet ({len(self._streak)} of {cfg.consistency} keyframes)"
        if query - self._last_closed < cfg.cooldown_keyframes:
            return False, f"a loop was closed {query - self._last_closed} keyframes ago"
        self._last_closed = query
        self._streak = []
        return True, "accepted"

    def _candidate(self, query: KeyframePlace, candidate: int, score: float, result: Verification, accepted: bool,
                   why: str) -> LoopCandidate:
        place = self.database.places[candidate]
        return LoopCandidate(
            query_keyframe=query.keyframe_id, query_position=query.position, candidate_keyframe=candidate,
            candidate_position=place.position, score=score, matches=len(result.inlier_mask), inliers=result.inliers,
            accepted=accepted, why=result.rejected if result.rejected is not None else why,
            query_pixels=result.query_pixels, candidate_pixels=result.candidate_pixels,
            inlier_mask=result.inlier_mask, T_candidate_query=result.T_candidate_query,
            query_image=query.thumbnail, candidate_image=place.thumbnail)

    def _close(self, map_: Map, query: KeyframePlace, candidate: int,
               result: Verification) -> tuple[LoopClosed, np.ndarray]:
        """Optimise the pose graph of the query's segment and move its keyframes and landmarks."""
        assert result.T_candidate_query is not None
        start = time.perf_counter()
        ids = [k.id for k in map_.keyframes.values() if k.segment == query.segment]
        index = {k: n for n, k in enumerate(ids)}
        before = np.array([map_.keyframes[k].T_world_cam for k in ids])
        similarity = not self._metric
        self._edges.append((candidate, query.keyframe_id, result.T_candidate_query, result.scale))
        edges = [LoopEdge(index[a], index[b], T, scale) for a, b, T, scale in self._edges if a in index and b in index]
        after, scales = optimise(before, edges, self._config, similarity)
        after = np.array([orthonormalise(p) for p in after])
        moved = _move_landmarks(map_, index, before, after, scales)
        for k, pose in zip(ids, after, strict=True):
            map_.keyframes[k].T_world_cam = pose
        newest = index[query.keyframe_id]
        correction = after[newest] @ invert_pose(before[newest])
        closed = LoopClosed(
            query_keyframe=query.keyframe_id, candidate_keyframe=candidate, query_position=query.position,
            candidate_position=self.database.places[candidate].position, inliers=result.inliers,
            similarity=similarity, keyframe_ids=np.array(ids, np.int64),
            keyframe_positions=np.array([map_.keyframes[k].position for k in ids], np.int64),
            poses_before=before, poses_after=after,
            correction_m=np.linalg.norm(after[:, :3, 3] - before[:, :3, 3], axis=1),
            correction_deg=np.degrees([rotation_angle(a[:3, :3] @ b[:3, :3].T) for a, b in zip(after, before,
                                                                                                 strict=True)]),
            landmarks_moved=moved, milliseconds=_lap(start))
        return closed, correction


def _move_landmarks(map_: Map, index: dict[int, int], before: np.ndarray, after: np.ndarray,
                    scales: np.ndarray) -> int:
    """Move each landmark with the newest of its keyframes in the graph: X ← s·R'·Rᵀ(X − t) + t' (a rigid
    motion when s = 1). Returns how many moved."""
    moved = 0
    for landmark in map_.landmarks.values():
        seen = [k for k in landmark.observations if k in index]
        if not seen:
            continue
        n = index[max(seen)]
        local = before[n, :3, :3].T @ (landmark.position - before[n, :3, 3])
        landmark.position = scales[n] * after[n, :3, :3] @ local + after[n, :3, 3]
        moved += 1
    return moved


def _lap(start: float) -> float:
    return (time.perf_counter() - start) * 1000.0
