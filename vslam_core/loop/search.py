"""Loop search: the part of loop closing that runs off the tracking path (vslam_core/loop/worker.py).

A `SearchJob` is a snapshot taken by tracking at a keyframe insertion (the keyframe's image and its landmarks in
its camera frame, the segment's keyframe poses); `LoopSearch.run` describes the keyframe (`places`), searches
the older keyframes for it, verifies the candidates (`verification`), checks consistency over consecutive
keyframes and, once a loop is accepted, optimises the pose graph of the snapshot (`pose_graph`). It never
touches the map: the `SearchResult` holds the optimised poses, and tracking applies them to the map at a fixed
point (vslam_core/loop/closing.py). Jobs are handled one at a time, in the order submitted, so the result of a
job depends only on the jobs before it, never on timing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose
from vslam_core.lens import distort_pixels
from vslam_core.loop.places import KeyframePlace, PlaceDatabase, describe_image, unpack_thumbnail
from vslam_core.loop.pose_graph import LoopEdge, optimise
from vslam_core.loop.verification import Verification, verify
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH
from vslam_core.mapping.map import at_place, median_spacing  # covered: not kept as a place
from vslam_core.results import LoopCandidate, elapsed_ms
from vslam_core.sources.base import CameraIntrinsics

CONSISTENT_KEYFRAMES = 5  # verified candidates of consecutive queries are this close (keyframe ids) to agree
NEIGHBOURS = 2  # keyframes on each side of a candidate whose landmarks join its verification


@dataclass(frozen=True)
class SearchJob:
    """One keyframe to search for, as tracking saw it when it submitted the job. L landmarks, K keyframes."""

    keyframe_id: int
    position: int  # run position of its frame
    segment: int
    image: np.ndarray  # (H, W) uint8
    point_ids: np.ndarray  # (L,) int64
    points_cam: np.ndarray  # (L, 3) its landmarks in its camera frame
    point_pixels: np.ndarray  # (L, 2) where it saw them
    point_descriptors: np.ndarray  # (L, 32) uint8
    graph_ids: np.ndarray  # (K,) the segment's keyframes, oldest first (the query last)
    graph_positions: np.ndarray  # (K,) their frames' run positions
    graph_poses: np.ndarray  # (K, 4, 4) their T_world_cam
    refreshed: tuple[int, np.ndarray] | None = None  # an older keyframe's (L', 3) points_cam once BA settled them
    final: bool = False  # the run's last keyframe, searched when the run ends: no cooldown applies
    culled: tuple[int, ...] = ()  # keyframes culled from the map since the last job: their places and loop edges go


@dataclass(frozen=True)
class GraphSolution:
    """The pose graph optimised after a loop was accepted: the job's K keyframes before and after."""

    query_keyframe: int
    candidate_keyframe: int
    query_position: int
    candidate_position: int
    inliers: int
    similarity: bool  # Sim(3) (--scale none) rather than SE(3)
    keyframe_ids: np.ndarray  # (K,)
    poses_before: np.ndarray  # (K, 4, 4) the job's snapshot
    poses_after: np.ndarray  # (K, 4, 4)
    scales: np.ndarray  # (K,) scale of each node's neighbourhood (1 for SE(3))


@dataclass(frozen=True)
class SearchResult:
    """What a job found. F features of the query keyframe."""

    keyframe_id: int
    pixels: np.ndarray  # (F, 2) float32 its features (kept in the saved map)
    descriptors: np.ndarray  # (F, 32) uint8
    candidates: tuple[LoopCandidate, ...]
    graph: GraphSolution | None
    timings_ms: dict[str, float]  # describe, query, verify, optimise (in the worker)


class LoopSearch:
    """The place database and the loop-acceptance state; `run` handles one job."""

    def __init__(self, camera: CameraIntrinsics, config: EngineConfig) -> None:
        """Keyframes are described on raw images; through a distorted lens their features are undistorted for
        verification."""
        self._camera = camera
        self._config = config.loop
        self._seed = config.pose.seed
        self._metric = config.scale != "none"
        # its own describer, like the map's landmarks' (local_mapping.py): never shared with the tracking thread
        self._describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
        self.database = PlaceDatabase(config.loop, config.pose.seed)
        self._streak: list[tuple[int, int]] = []  # (query, candidate) verified on consecutive keyframes
        self._last_closed = -(10**9)
        self._edges: list[tuple[int, int, np.ndarray, float]] = []  # (candidate, query, T_candidate_query, scale)
        self._poses: dict[int, np.ndarray] = {}  # keyframe id -> T_world_cam, as of the latest job

    def run(self, job: SearchJob) -> SearchResult:
        timings: dict[str, float] = {}
        clock = time.perf_counter()
        self._poses = dict(zip(job.graph_ids.tolist(), job.graph_poses, strict=True))
        if job.culled:
            self.database.remove(set(job.culled))
            self._edges = [edge for edge in self._edges if edge[0] not in job.culled and edge[1] not in job.culled]
        if job.refreshed is not None and job.refreshed[0] in self.database.places:
            self.database.places[job.refreshed[0]].points_cam = job.refreshed[1]
        query = self._place(job)
        timings["describe"] = elapsed_ms(clock)
        clock = time.perf_counter()
        self.database.add(query)  # its words first (the search never returns the query: min separation)
        found = self.database.candidates(query)
        timings["query"] = elapsed_ms(clock)
        clock = time.perf_counter()
        checked = [(candidate, score, verify(query, self._with_neighbours(candidate), self._camera, self._config,
                                             (self._seed, query.position, candidate, 2), self._metric))
                   for candidate, score in found]
        timings["verify"] = elapsed_ms(clock)
        best = max((c for c in checked if c[2].rejected is None), key=lambda c: (c[2].inliers, -c[0]), default=None)
        if best is not None or self._near_stored_place(job):  # the query need not be kept as a place
            self.database.cover(query.keyframe_id)
        accepted, why = self._consistent(query.keyframe_id, best[0] if best is not None else None, job.final)
        chosen = best[0] if accepted and best is not None else None
        candidates = tuple(self._candidate(query, candidate, score, result, candidate == chosen,
                                           why if chosen is None or candidate == chosen
                                           else "another candidate had more inliers")
                           for candidate, score, result in checked)
        graph = None
        if accepted and best is not None:
            clock = time.perf_counter()
            graph = self._optimise(job, query, best[0], best[2])
            timings["optimise"] = elapsed_ms(clock)
        pixels, descriptors = query.pixels, query.descriptors
        self.database.compact(query.keyframe_id)  # after its verification: its features go back with the result
        self.database.prune(query.keyframe_id)
        return SearchResult(job.keyframe_id, pixels, descriptors, candidates, graph, timings)

    # -- steps ------------------------------------------------------------------------------------------------

    def _place(self, job: SearchJob) -> KeyframePlace:
        pixels, descriptors = describe_image(job.image, self._config.features, self._config.fast_threshold,
                                             self._describer)
        return KeyframePlace(
            keyframe_id=job.keyframe_id, position=job.position, segment=job.segment, pixels=pixels,
            descriptors=descriptors, point_ids=job.point_ids, points_cam=job.points_cam,
            point_pixels=job.point_pixels, point_descriptors=job.point_descriptors,
            thumbnail=cv2.resize(job.image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))

    def _with_neighbours(self, candidate: int) -> KeyframePlace:
        """The candidate's place with the landmarks of its `NEIGHBOURS` keyframes on each side added (moved into
        its camera frame by the snapshot's poses; each landmark once): more correspondences for the loop edge."""
        place = self.database.places[candidate]
        T_cam_world = invert_pose(self._poses[candidate])  # noqa: N806
        seen = set(place.point_ids.tolist())
        points, pixels, descriptors, ids = [place.points_cam], [place.point_pixels], [place.point_descriptors], \
            [place.point_ids]
        for other_id in range(candidate - NEIGHBOURS, candidate + NEIGHBOURS + 1):
            other = self.database.places.get(other_id)
            pose = self._poses.get(other_id)
            if other is None or pose is None or other_id == candidate or other.segment != place.segment:
                continue
            new = np.array([i not in seen for i in other.point_ids.tolist()], bool)
            seen |= set(other.point_ids[new].tolist())
            T = T_cam_world @ pose  # noqa: N806
            points.append(other.points_cam[new] @ T[:3, :3].T + T[:3, 3])
            pixels.append(np.full((int(new.sum()), 2), np.nan, np.float32))  # not seen in the candidate's image
            descriptors.append(other.point_descriptors[new])
            ids.append(other.point_ids[new])
        return replace(place, points_cam=np.concatenate(points), point_pixels=np.concatenate(pixels),
                       point_descriptors=np.concatenate(descriptors), point_ids=np.concatenate(ids))

    def _near_stored_place(self, job: SearchJob) -> bool:
        """Whether an older stored place (at least `min_separation_keyframes` before the query, not itself covered)
        lies within `COVERED_SPACINGS` median keyframe spacings of the query, its optical axis within
        `COVERED_ANGLE_DEG` (the job's poses: tracking's, loop corrections included). Spacings, not metres: the
        same rule in the map's units with --scale none."""
        positions = job.graph_poses[:, :3, 3]
        if len(positions) < 3:
            return False
        spacing = median_spacing(positions)
        stored = self.database.uncovered(job.keyframe_id - self._config.min_separation_keyframes, job.segment)
        poses = np.array([self._poses[k] for k in stored if k in self._poses]).reshape(-1, 4, 4)
        if not len(poses) or spacing <= 0.0:
            return False
        return bool(np.any(at_place(poses, job.graph_poses[-1], spacing)))

    def _consistent(self, query: int, candidate: int | None, final: bool) -> tuple[bool, str]:
        """Track verified places over consecutive keyframes: accept the `consistency`-th in a row, unless a loop
        was closed within `cooldown_keyframes` (its correction is still settling into tracking's map) and this
        is not the run's `final` keyframe (no tracking is left to disturb)."""
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
        if query - self._last_closed < cfg.cooldown_keyframes and not final:
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
            query_pixels=result.query_pixels, candidate_pixels=self._raw(result.candidate_pixels),
            inlier_mask=result.inlier_mask, T_candidate_query=result.T_candidate_query,
            query_image=unpack_thumbnail(query.thumbnail), candidate_image=unpack_thumbnail(place.thumbnail))

    def _raw(self, ideal: np.ndarray) -> np.ndarray:
        """(M, 2) ideal pixels (the map's observations) on the raw image, where overlays are drawn (NaN stays)."""
        return distort_pixels(ideal, self._camera) if self._camera.distorted else ideal

    def _rescale_edges(self, index: dict[int, int], scales: np.ndarray) -> None:
        """After a Sim(3) correction the map around node i is s_i times larger (it is applied at the fixed point,
        always): a loop edge measured before is restated in the new units, its translation (candidate units)
        times s_candidate and its scale times s_candidate / s_query. Without this the next optimisation, which
        starts from the corrected poses, would apply the same scale correction again (it compounded over the 8
        loops of the KITTI 05 revisit)."""
        restated = []
        for candidate, query, T, scale in self._edges:  # noqa: N806
            if candidate in index and query in index:
                s_candidate, s_query = float(scales[index[candidate]]), float(scales[index[query]])
                T, scale = _rescaled(T, s_candidate), scale * s_candidate / s_query  # noqa: N806
            restated.append((candidate, query, T, scale))
        self._edges = restated

    def _optimise(self, job: SearchJob, query: KeyframePlace, candidate: int, result: Verification) -> GraphSolution:
        """The pose graph of the job's keyframes with every loop edge accepted so far."""
        assert result.T_candidate_query is not None
        index = {k: n for n, k in enumerate(job.graph_ids.tolist())}
        self._edges.append((candidate, query.keyframe_id, result.T_candidate_query, result.scale))
        edges = [LoopEdge(index[a], index[b], T, scale) for a, b, T, scale in self._edges if a in index and b in index]
        after, scales = optimise(job.graph_poses, edges, self._config, similarity=not self._metric)
        if not self._metric:
            self._rescale_edges(index, scales)
        return GraphSolution(
            query_keyframe=query.keyframe_id, candidate_keyframe=candidate, query_position=query.position,
            candidate_position=self.database.places[candidate].position, inliers=result.inliers,
            similarity=not self._metric, keyframe_ids=job.graph_ids, poses_before=job.graph_poses,
            poses_after=after, scales=scales)


def _rescaled(T: np.ndarray, scale: float) -> np.ndarray:  # noqa: N803
    """(4, 4) the rigid motion with its translation multiplied by `scale`."""
    moved = T.copy()
    moved[:3, 3] *= scale
    return moved
