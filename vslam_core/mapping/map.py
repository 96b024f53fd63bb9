"""The map: keyframes and landmarks (plain data and queries; no optimisation code here).

World frame: the camera frame of the first frame (x right, y down, z forward, metres with a metric scale
source). Poses are camera-to-world `T_world_cam` (4, 4). Pixels are (x right, y down).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
        self._next_keyframe = 0
        self._next_landmark = 0

    def add_keyframe(self, position: int, segment: int, T_world_cam: np.ndarray, track_ids: np.ndarray,  # noqa: N803
                     pixels: np.ndarray, metric_step: float | None,
                     chained_rotation: np.ndarray | None = None) -> Keyframe:
        keyframe = Keyframe(self._next_keyframe, position, segment, T_world_cam.copy(), track_ids, pixels, metric_step,
                            chained_rotation=chained_rotation)
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
