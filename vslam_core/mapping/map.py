"""The map: keyframes and landmarks (plain data and queries; no optimisation code here).

World frame: the camera frame of the first frame (x right, y down, z forward, metres with a metric scale
source). Poses are camera-to-world `T_world_cam` (4, 4). Pixels are (x right, y down).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam_core.geometry import interpolate_pose, invert_pose

# a keyframe within this many of the map's keyframe spacings of an older one, looking the same way within
# COVERED_ANGLE_DEG, is at a place the map knows (`covering`: keyframe culling; the loop search's covered places)
COVERED_SPACINGS = 1.0
COVERED_ANGLE_DEG = 30.0


@dataclass
class Keyframe:
    """A frame kept in the map: its pose and the tracks it saw (N tracks)."""

    id: int
    position: int  # run position of its frame
    segment: int  # map segment it belongs to
    T_world_cam: np.ndarray  # (4, 4), refined by bundle adjustment  # noqa: N815
    track_ids: np.ndarray  # (N,) int64 tracks alive at this keyframe
    pixels: np.ndarray  # (N, 2) float32 their positions
    metric_step: float | None  # distance from the previous keyframe given by the scale source (None: unit scale)
    chained_rotation: np.ndarray | None = None  # (3, 3) R_previous_this by the front end's two-view chain
    chained_covariance: np.ndarray | None = None  # (3, 3) rad², of chained_rotation (as R·exp([ω]ₓ))
    landmark_ids: set[int] = field(default_factory=set)  # landmarks observed here


@dataclass
class Landmark:
    """A 3-D point triangulated across keyframes."""

    id: int
    position: np.ndarray  # (3,) world
    observations: dict[int, np.ndarray]  # keyframe id -> (2,) pixel
    descriptor: np.ndarray | None  # (32,) uint8 ORB descriptor from the latest keyframe that saw it
    first_keyframe: int
    last_keyframe: int

    @property
    def observation_count(self) -> int:
        return len(self.observations)


class Map:
    """Keyframes (in insertion order) and landmarks, with the queries tracking and mapping need."""

    def __init__(self) -> None:
        self.keyframes: dict[int, Keyframe] = {}
        self.landmarks: dict[int, Landmark] = {}
        # keyframes at either end of a loop edge the pose graph holds: never culled (ORB-SLAM's rule, a keyframe with
        # loop edges is not erased): a later loop's correction would otherwise run round the whole older pass
        self.loop_keyframes: set[int] = set()
        self._next_keyframe = 0
        self._next_landmark = 0

    def add_keyframe(self, position: int, segment: int, T_world_cam: np.ndarray, track_ids: np.ndarray,  # noqa: N803
                     pixels: np.ndarray, metric_step: float | None,
                     chained_rotation: tuple[np.ndarray, np.ndarray] | None = None) -> Keyframe:
        """`chained_rotation`: R_previous_this by the front end's two-view chain and its covariance."""
        rotation, covariance = chained_rotation if chained_rotation is not None else (None, None)
        keyframe = Keyframe(self._next_keyframe, position, segment, T_world_cam.copy(), track_ids, pixels, metric_step,
                            chained_rotation=rotation, chained_covariance=covariance)
        self.keyframes[keyframe.id] = keyframe
        self._next_keyframe += 1
        return keyframe

    def add_landmark(self, position: np.ndarray, observations: dict[int, np.ndarray]) -> Landmark:
        first, last = min(observations), max(observations)
        landmark = Landmark(self._next_landmark, position, observations, None, first, last)
        self.landmarks[landmark.id] = landmark
        for keyframe_id in observations:
            self.keyframes[keyframe_id].landmark_ids.add(landmark.id)
        self._next_landmark += 1
        return landmark

    def observe(self, landmark_id: int, keyframe_id: int, pixel: np.ndarray) -> None:
        landmark = self.landmarks[landmark_id]
        landmark.observations[keyframe_id] = pixel
        landmark.last_keyframe = max(landmark.last_keyframe, keyframe_id)
        self.keyframes[keyframe_id].landmark_ids.add(landmark_id)

    def remove_observation(self, landmark_id: int, keyframe_id: int) -> None:
        landmark = self.landmarks[landmark_id]
        landmark.observations.pop(keyframe_id, None)
        if landmark.observations:
            landmark.last_keyframe = max(landmark.observations)
        self.keyframes[keyframe_id].landmark_ids.discard(landmark_id)

    def remove_landmark(self, landmark_id: int) -> None:
        landmark = self.landmarks.pop(landmark_id)
        for keyframe_id in landmark.observations:
            self.keyframes[keyframe_id].landmark_ids.discard(landmark_id)

    def remove_keyframe(self, keyframe_id: int, keep: set[int]) -> int:
        """Remove a keyframe and its observations; landmarks left with fewer than two observations are removed
        too, unless in `keep` (tracked now) and still observed. Returns how many landmarks were removed."""
        keyframe = self.keyframes.pop(keyframe_id)
        removed = 0
        for landmark_id in keyframe.landmark_ids:
            landmark = self.landmarks[landmark_id]
            del landmark.observations[keyframe_id]
            if landmark.observations:
                landmark.first_keyframe, landmark.last_keyframe = min(landmark.observations), max(landmark.observations)
            if not landmark.observations or (landmark.observation_count < 2 and landmark_id not in keep):
                self.remove_landmark(landmark_id)
                removed += 1
        return removed

    def recent_keyframes(self, count: int, segment: int) -> list[Keyframe]:
        """The last `count` keyframes of a segment, oldest first."""
        recent: list[Keyframe] = []
        for keyframe_id in reversed(self.keyframes):
            keyframe = self.keyframes[keyframe_id]
            if keyframe.segment != segment or len(recent) == count:
                break
            recent.append(keyframe)
        return recent[::-1]

    def landmarks_seen_by(self, keyframes: list[Keyframe]) -> list[int]:
        """Ids of the landmarks any of the keyframes observes, ascending."""
        seen: set[int] = set()
        for keyframe in keyframes:
            seen |= keyframe.landmark_ids
        return sorted(seen)

    def positions(self, landmark_ids: list[int] | np.ndarray) -> np.ndarray:
        """(P, 3) positions of the landmarks."""
        landmarks = self.landmarks
        positions = [landmarks[i].position for i in np.asarray(landmark_ids, np.int64).tolist()]
        return np.concatenate(positions, dtype=np.float64).reshape(-1, 3) if positions else np.zeros((0, 3))


def redundant(map_: Map, keyframe_id: int, observers: int, scale: float) -> float:
    """Share of a keyframe's landmarks that at least `observers` other keyframes see at the same or a finer scale
    (ORB-SLAM's keyframe culling, Mur-Artal et al. 2015, sec. V-E, with distances for pyramid levels: another
    keyframe at most `scale` times farther from the landmark). 0 for a keyframe without landmarks."""
    keyframe = map_.keyframes[keyframe_id]
    if not keyframe.landmark_ids:
        return 0.0
    landmarks = [map_.landmarks[i] for i in keyframe.landmark_ids]
    others = [k for landmark in landmarks for k in landmark.observations if k != keyframe_id]
    owner = np.repeat(np.arange(len(landmarks)), [len(landmark.observations) - 1 for landmark in landmarks])
    points = np.array([landmark.position for landmark in landmarks]).reshape(-1, 3)
    centres = np.array([map_.keyframes[k].T_world_cam[:3, 3] for k in others]).reshape(-1, 3)
    own = np.linalg.norm(points - keyframe.T_world_cam[:3, 3], axis=1)  # (L,) distances from this keyframe
    finer = np.linalg.norm(points[owner] - centres, axis=1) <= scale * own[owner]
    return float(np.mean(np.bincount(owner[finer], minlength=len(landmarks)) >= observers))


def median_spacing(positions: np.ndarray) -> float:
    """Median distance between consecutive (N, 3) keyframe positions (the map's own units); 0 for fewer than 2."""
    return float(np.median(np.linalg.norm(np.diff(positions, axis=0), axis=1))) if len(positions) > 1 else 0.0


def at_place(poses: np.ndarray, query: np.ndarray, spacing: float, spacings: float = COVERED_SPACINGS,
             angle_deg: float = COVERED_ANGLE_DEG) -> np.ndarray:
    """(N,) bool: which of the (N, 4, 4) T_world_cam `poses` are where the (4, 4) `query` is: within `spacings` x
    `spacing` of it (spacings, not metres: the same rule in the map's own units with --scale none), their optical
    axes within `angle_deg` of its. The rule of keyframe culling (`covering`) and of the loop search's covered
    places (vslam_core/loop/search.py)."""
    near = np.linalg.norm(poses[:, :3, 3] - query[:3, 3], axis=1) <= spacings * spacing
    same_way = poses[:, :3, 2] @ query[:3, 2] >= np.cos(np.radians(angle_deg))
    return near & same_way


def covering(map_: Map, keyframe_id: int, older_by: int, spacings: float, angle_deg: float) -> int | None:
    """An older keyframe of the same segment (at least `older_by` ids before) where this one is (`at_place`, with
    the segment's median keyframe spacing); the nearest, None if none."""
    keyframe = map_.keyframes[keyframe_id]
    ids = [k.id for k in map_.keyframes.values() if k.segment == keyframe.segment]
    if len(ids) < 3:
        return None
    poses = np.array([map_.keyframes[k].T_world_cam for k in ids])
    spacing = median_spacing(poses[:, :3, 3])
    older = np.array(ids) <= keyframe_id - older_by
    near = np.flatnonzero(older & at_place(poses, keyframe.T_world_cam, spacing, spacings, angle_deg))
    if spacing <= 0.0 or not len(near):
        return None
    distance = np.linalg.norm(poses[near, :3, 3] - keyframe.T_world_cam[:3, 3], axis=1)
    return ids[int(near[np.argmin(distance)])]


class NextKeyframeAnchors:
    """Each keyframe's pose relative to the next keyframe of its segment, as it was when that one was made
    (keyframe id -> (next keyframe's id, (4, 4) T_next_this)), so that the frames tracked between the two follow
    the refinements of both.

    Tracking stores every frame relative to the newest keyframe when it was tracked; bundle adjustment, loop closing
    and the end's adjustment then move the keyframes, and a frame moved rigidly with the earlier one alone keeps the
    error the later one's refinement removed: on TUM fr1_desk the two-view steps of frames 1-9 put the keyframe at
    frame 10 9 cm off, which the adjustments took back to 2 cm, while frames 3-9 stayed 3-9 cm off. `pose` blends
    the frame's pose by each of the two (`geometry.interpolate_pose`) by where it lies between them, as a loop
    closure's correction is spread along the frames it spans; a frame after the newest keyframe, or one whose
    keyframes were culled since, keeps its one anchor. One pose a keyframe, none a frame: memory follows the map.
    (ORB-SLAM stores each frame relative to its reference keyframe alone.)"""

    def __init__(self) -> None:
        self.anchors: dict[int, tuple[int, np.ndarray]] = {}

    def keyframe_made(self, map_: Map, previous_id: int, keyframe_id: int) -> None:
        """Keyframe `keyframe_id` was made after `previous_id` (both at their poses now); the culled keyframes'
        entries are forgotten."""
        for culled in [k for k in self.anchors if k not in map_.keyframes]:
            del self.anchors[culled]
        previous, keyframe = map_.keyframes.get(previous_id), map_.keyframes[keyframe_id]
        if previous is not None and previous.segment == keyframe.segment:
            self.anchors[previous_id] = (keyframe_id, invert_pose(keyframe.T_world_cam) @ previous.T_world_cam)

    def segment_started(self, map_: Map, segment: int) -> None:
        """The keyframes of `segment` anchored again, each to the next, at their poses now: its map's start moved
        them (`map_scale.place_attempts`)."""
        ids = [k.id for k in map_.keyframes.values() if k.segment == segment]
        for previous, later in zip(ids, ids[1:], strict=False):
            self.keyframe_made(map_, previous, later)

    def pose(self, map_: Map, position: int, anchor: tuple[int, np.ndarray] | None, pose: np.ndarray) -> np.ndarray:
        """(4, 4) the refined pose of the frame at run `position`: `pose`, the one its own `anchor` (keyframe id,
        T_key_frame) gives, blended with the next keyframe's when the frame lies between the two."""
        if anchor is None or (link := self.anchors.get(anchor[0])) is None:
            return pose
        first, second = map_.keyframes.get(anchor[0]), map_.keyframes.get(link[0])
        if first is None or second is None or not first.position <= position <= second.position \
                or first.position == second.position:
            return pose
        fraction = (position - first.position) / (second.position - first.position)
        return interpolate_pose(pose, second.T_world_cam @ link[1] @ anchor[1], fraction)
