"""Synthetic street: the road centreline and the camera path along it (map frame M: x east, y north, z up)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ROAD_HALF_WIDTH = 3.5  # metres, as all lengths here
SIDEWALK_HALF_WIDTH = 5.0
_LANE_OFFSET = -1.6  # camera's lateral offset from the centreline (+ = left): the right lane
START_S = 20.0  # arc length of the first camera position (buildings exist behind it)
CENTRELINE_STEP = 0.25


@dataclass(frozen=True)
class Centreline:
    """Road centreline sampled every `CENTRELINE_STEP` metres of arc length (map frame, z = 0).

    s: (M,) arc length; xy: (M, 2) positions; heading: (M,) radians counter-clockwise from map x;
    curvature: (M,) 1/m, positive = turning left.
    """

    s: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray
    closed: bool = False  # a loop: arc lengths wrap around at s[-1]

    def frame_at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(n,) arc lengths -> positions (n, 2), headings (n,), left unit normals (n, 2)."""
        if self.closed:
            s = np.mod(s, self.s[-1])
        xy = np.stack([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])], axis=1)
        heading = np.interp(s, self.s, self.heading)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        return xy, heading, normal

    def curvature_at(self, s: float) -> float:
        """Curvature (1/m) at arc length s."""
        if self.closed:
            s = s % float(self.s[-1])
        return float(np.interp(s, self.s, self.curvature))


def make_centreline(length: float, rng: np.random.Generator) -> Centreline:
    """A smooth road of the given length: straights and 60..90 degree curves, alternating left/right.

    Curvature ramps in and out smoothly (sin^2), so the heading is smooth; the tightest radius is ~28 m.
    """
    plan = [
        (35.0, 0.0),
        (60.0, 90.0),
        (45.0, 0.0),
        (70.0, -90.0),
        (35.0, 0.0),
        (50.0, 60.0),
        (40.0, 0.0),
        (60.0, -75.0),
    ]  # (segment length m, heading change deg)
    s = np.arange(0.0, length + CENTRELINE_STEP, CENTRELINE_STEP)
    curvature = np.zeros_like(s)
    start, k = 0.0, 0
    while start < length:
        seg_len, angle = plan[k % len(plan)]
        seg_len *= rng.uniform(0.9, 1.1)
        if angle != 0.0:
            total = math.radians(angle) * rng.uniform(0.85, 1.05)
            t = (s - start) / seg_len
            inside = (t >= 0.0) & (t < 1.0)
            ramp = 0.25  # sin^2 ramps over the first and last quarter, constant in between
            shape = np.sin(0.5 * np.pi * np.minimum(np.minimum(t, 1.0 - t) / ramp, 1.0)) ** 2
            curvature[inside] = total / (seg_len * (1.0 - ramp)) * shape[inside]
        start += seg_len
        k += 1
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * CENTRELINE_STEP)])
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    steps = 0.5 * (direction[1:] + direction[:-1]) * CENTRELINE_STEP
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return Centreline(s=s, xy=xy, heading=heading, curvature=curvature)


LOOP_PLAN = ((110.0, 0.0), (70.0, 90.0), (50.0, 0.0), (70.0, 90.0)) * 2  # around a block: 600 m

#: Length of each corner of `DRIVE_PLAN` (a 90° turn with sin^2 ramps): it cuts this share of it off each side.
_DRIVE_CORNER = 50.0
_CORNER_CUT = 0.605437922 * _DRIVE_CORNER  # forward (= sideways) displacement of one corner, measured
#: The long drive's circuit: an L-shaped pair of blocks, 300 m east, 200 north, 150 west, 150 north (a right
#: turn), 150 west, 350 south, the corners rounded: five left turns and one right, 1237 m a lap.
DRIVE_PLAN = tuple(segment for side, turn in ((300.0, 90.0), (200.0, 90.0), (150.0, -90.0), (150.0, 90.0),
                                             (150.0, 90.0), (350.0, 90.0))
                   for segment in ((side - 2 * _CORNER_CUT, 0.0), (_DRIVE_CORNER, turn)))


def make_loop_centreline(plan: tuple[tuple[float, float], ...] = LOOP_PLAN) -> Centreline:
    """A closed road around a block (rounded rectangle, four left turns of exactly 90 degrees with the
    sin^2 curvature ramps of `make_centreline`): opposite sides are equal, so it ends where it starts.
    Arc lengths wrap around (`Centreline.closed`)."""
    length = sum(seg_len for seg_len, _ in plan)
    s = np.arange(0.0, length + CENTRELINE_STEP / 2, CENTRELINE_STEP)
    curvature = np.zeros_like(s)
    start = 0.0
    for seg_len, angle in plan:
        if angle != 0.0:
            t = (s - start) / seg_len
            inside = (t >= 0.0) & (t < 1.0)
            ramp = 0.25
            shape = np.sin(0.5 * np.pi * np.minimum(np.minimum(t, 1.0 - t) / ramp, 1.0)) ** 2
            curvature[inside] = math.radians(angle) / (seg_len * (1.0 - ramp)) * shape[inside]
        start += seg_len
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * CENTRELINE_STEP)])
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    steps = 0.5 * (direction[1:] + direction[:-1]) * CENTRELINE_STEP
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return Centreline(s=s, xy=xy, heading=heading, curvature=curvature, closed=True)


def _rotation_x(angle: float) -> np.ndarray:
    """(3, 3) rotation about x by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_z(angle: float) -> np.ndarray:
    """(3, 3) rotation about z by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_path(line: Centreline, n_frames: int, camera_height: float, rng: np.random.Generator,
                pace: np.ndarray | None = None) -> np.ndarray:
    """Camera poses T_m_c (n_frames, 4, 4) in the map frame.

    The camera follows the right lane at `camera_height` above the road (z = 0), looking along the road
    tangent, with speed 0.83..1.17 m/frame (measured along its own lane; times `pace` (n_frames,) when given)
    and pitch/roll oscillations.
    """
    phase = rng.uniform(0.0, 2.0 * np.pi, 5)
    i = np.arange(n_frames, dtype=np.float64)
    speed = 1.0 + 0.12 * np.sin(2 * np.pi * i / 83 + phase[0]) + 0.05 * np.sin(2 * np.pi * i / 19 + phase[1])
    if pace is not None:
        speed = speed * pace
    pitch = np.radians(0.6) * np.sin(2 * np.pi * i / 41 + phase[2]) + np.radians(0.2) * np.sin(
        2 * np.pi * i / 11 + phase[3]
    )
    roll = np.radians(0.6) * np.sin(2 * np.pi * i / 29 + phase[4])
    arc = np.empty(n_frames)
    arc[0] = START_S
    for k in range(1, n_frames):  # lane arc length = (1 - offset * curvature) * centreline arc length
        arc[k] = arc[k - 1] + speed[k - 1] / (1.0 - _LANE_OFFSET * line.curvature_at(arc[k - 1]))
    xy, heading, normal = line.frame_at(arc)
    return _lane_poses(xy + _LANE_OFFSET * normal, heading, pitch, roll, np.full(n_frames, camera_height))


def drive_path(line: Centreline, n_frames: int, camera_height: float, rng: np.random.Generator) -> np.ndarray:
    """Camera poses T_m_c (n_frames, 4, 4) of a long drive round and round `line` (a closed circuit) at changing
    speeds: `camera_path`'s times a pace that swings between 0.55 and 1.45 (periods 1300 and 470 frames), so
    the car covers 0.45..1.7 m a frame (4.5..17 m/s at 10 Hz) and passes every place at several speeds."""
    i = np.arange(n_frames, dtype=np.float64)
    pace = 1.0 + 0.3 * np.sin(2 * np.pi * i / 1300) + 0.15 * np.sin(2 * np.pi * i / 470 + 1.0)
    return camera_path(line, n_frames, camera_height, rng, pace)


def _lane_poses(position: np.ndarray, heading: np.ndarray, pitch: np.ndarray, roll: np.ndarray,
                height: np.ndarray) -> np.ndarray:
    """(N, 4, 4) T_m_c of cameras at (N, 2) map positions and (N,) heights above the road, looking along (N,)
    headings (radians), pitched and rolled by (N,) angles."""
    poses = np.tile(np.eye(4), (len(position), 1, 1))
    for k in range(len(position)):
        c, s = math.cos(heading[k]), math.sin(heading[k])
        # Columns: camera x (right), y (down), z (forward) in map coordinates.
        base = np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])
        poses[k, :3, :3] = base @ _rotation_x(pitch[k]) @ _rotation_z(roll[k])
        poses[k, :3, 3] = (position[k, 0], position[k, 1], height[k])
    return poses


#: A person walking along the street with a hand-held camera: metres a frame (at 30 Hz, ~1.35 m/s).
WALK_STEP = 0.045


def walk_path(line: Centreline, n_frames: int, camera_height: float, rng: np.random.Generator) -> np.ndarray:
    """Camera poses T_m_c (n_frames, 4, 4) of a hand-held camera carried along the right lane at a walk.

    The low-parallax, rotation-dominated motion of hand-held sequences (TUM RGB-D, EuRoC): the camera moves
    `WALK_STEP` (±20 %) a frame, bobs 2 cm with each step (period 15 frames), and swings about its centre,
    yaw ±14° (periods 70 and 23 frames), pitch ±7° (53, 17) and roll ±3° (61): up to ~2° of rotation a
    frame, while it moves only a few centimetres.
    """
    phase = rng.uniform(0.0, 2.0 * np.pi, 7)
    i = np.arange(n_frames, dtype=np.float64)
    speed = WALK_STEP * (1.0 + 0.2 * np.sin(2 * np.pi * i / 97 + phase[0]))
    yaw = np.radians(10.0) * np.sin(2 * np.pi * i / 70 + phase[1]) + np.radians(4.0) * np.sin(
        2 * np.pi * i / 23 + phase[2])
    pitch = np.radians(5.0) * np.sin(2 * np.pi * i / 53 + phase[3]) + np.radians(2.0) * np.sin(
        2 * np.pi * i / 17 + phase[4])
    roll = np.radians(3.0) * np.sin(2 * np.pi * i / 61 + phase[5])
    bob = 0.02 * np.sin(2 * np.pi * i / 15 + phase[6])
    arc = START_S + np.concatenate(([0.0], np.cumsum(speed[:-1])))
    xy, heading, normal = line.frame_at(arc)
    return _lane_poses(xy + _LANE_OFFSET * normal, heading + yaw, pitch, roll, camera_height + bob)
