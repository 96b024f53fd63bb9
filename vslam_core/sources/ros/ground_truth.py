"""Ground truth from a ROS log: a pose topic (PoseStamped, PoseWithCovarianceStamped, Odometry,
TransformStamped) matched to the frames by stamp; poses of a body frame other than the camera's are moved onto
the camera with the fixed transforms of ``/tf_static`` (chained through other frames if need be)."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.ros.messages import bag_errors, bare, stamp_ns
from vslam_core.sources.stamps import ground_truth_at
from vslam_core.trajectory.io import rotation_from_quaternion

TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/TransformStamped",
)


def pose_matrix(position: object, orientation: object) -> np.ndarray:
    """(4, 4) pose of a ``geometry_msgs`` position and orientation; `ValueError` for an invalid quaternion."""
    pose = np.eye(4)
    q = np.array([orientation.x, orientation.y, orientation.z, orientation.w], np.float64)  # type: ignore[attr-defined]
    if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
        raise ValueError("pose with an invalid quaternion")
    pose[:3, :3] = rotation_from_quaternion(q)
    pose[:3, 3] = [position.x, position.y, position.z]  # type: ignore[attr-defined]
    return pose


def transform_matrix(transform: object) -> np.ndarray:
    """(4, 4) of a ``geometry_msgs/Transform`` (translation, rotation)."""
    return pose_matrix(transform.translation, transform.rotation)  # type: ignore[attr-defined]


def topic_ground_truth(
    reader: Any, topics: dict[str, str], gt_topic: str, frame_id: str, frame_stamps: np.ndarray, tolerance_s: float,
    where: str,
) -> tuple[np.ndarray, str, list[str]]:
    """The ground truth of the frames stamped (N,) `frame_stamps` (s) of the camera frame `frame_id` from the pose
    topic `gt_topic` of the opened `reader` (`topics`: name → message type): ((N, 4, 4) T_w_c re-based on the first
    frame, where the poses came from, notes for the user). `SourceError` naming the log (`where`) and the topic."""
    name = gt_topic if gt_topic in topics or gt_topic.startswith("/") else "/" + gt_topic
    if name not in topics:
        raise SourceError(f"{where}: no ground-truth topic {gt_topic} (pose topics: "
                          f"{', '.join(t for t, k in sorted(topics.items()) if k in POSE_TYPES) or 'none'})")
    kind = topics[name]
    if kind not in POSE_TYPES:
        raise SourceError(f"{where}: ground-truth topic {name} is {kind}; expected one of "
                          f"{', '.join(POSE_TYPES)} (or give --gt as TUM camera poses)")
    stamps, poses, body = read_pose_topic(reader, name, kind, where)
    notes = []
    if body is None:
        notes.append(f"{name} ({kind.split('/')[-1]}) names no body frame: its poses are taken as poses of "
                     f"the camera ({frame_id or 'unnamed frame'})")
        label = f"{name} (taken as camera poses)"
    elif body == frame_id:
        label = f"{name} (poses of {body}, the camera frame)"
    else:
        body_cam = static_transform(reader, topics, body, frame_id, where)
        if body_cam is None:
            raise SourceError(f"{where} {name}: the ground truth is of frame {body!r}, the images of {frame_id!r}, "
                              "and /tf_static holds no fixed transform between them: give --gt as TUM camera poses")
        poses = np.einsum("nij,jk->nik", poses, body_cam)
        label = f"{name} (poses of {body} · /tf_static {body}→{frame_id})"
    return ground_truth_at(frame_stamps, stamps, poses, tolerance_s, f"{where} {name}"), label, notes


def read_pose_topic(reader: Any, topic: str, kind: str, where: str) -> tuple[np.ndarray, np.ndarray, str | None]:
    """The poses of a pose topic of type `kind`: ((M,) header stamps in s, (M, 4, 4) poses, the body frame they
    are of, None when the messages do not name one)."""
    stamps: list[int] = []
    poses: list[np.ndarray] = []
    bodies: set[str] = set()
    with bag_errors(where, f"cannot read the ground-truth topic {topic}"):
        connections = [c for c in reader.connections if c.topic == topic]
        for conn, _log_time, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, conn.msgtype)
            stamps.append(stamp_ns(msg.header.stamp))
            if kind.endswith("/PoseStamped"):
                poses.append(pose_matrix(msg.pose.position, msg.pose.orientation))
            elif kind.endswith("/PoseWithCovarianceStamped"):
                poses.append(pose_matrix(msg.pose.pose.position, msg.pose.pose.orientation))
            elif kind.endswith("/Odometry"):
                bodies.add(bare(msg.child_frame_id))
                poses.append(pose_matrix(msg.pose.pose.position, msg.pose.pose.orientation))
            else:
                bodies.add(bare(msg.child_frame_id))
                poses.append(transform_matrix(msg.transform))
    if not poses:
        raise SourceError(f"{where}: the ground-truth topic {topic} holds no message")
    if len(bodies) > 1:
        raise SourceError(f"{where}: the ground-truth topic {topic} mixes the frames {', '.join(sorted(bodies))}")
    body = bodies.pop() if bodies else None
    return np.asarray(stamps, np.float64) / 1e9, np.asarray(poses), body


def static_transform(reader: Any, topics: dict[str, str], source: str, target: str, where: str) -> np.ndarray | None:
    """T_source_target from the fixed transforms of /tf_static (chained through other frames if need be),
    or None when they do not connect the two frames."""
    if topics.get("/tf_static") != TF_TYPE or not target:
        return None
    edges: dict[tuple[str, str], np.ndarray] = {}
    with bag_errors(where, "cannot read /tf_static"):
        connections = [c for c in reader.connections if c.topic == "/tf_static"]
        for conn, _log_time, raw in reader.messages(connections=connections):
            for t in reader.deserialize(raw, conn.msgtype).transforms:
                parent, child = bare(t.header.frame_id), bare(t.child_frame_id)
                edges[(parent, child)] = transform_matrix(t.transform)
    neighbours: dict[str, list[tuple[str, np.ndarray]]] = {}
    for (parent, child), transform in edges.items():
        neighbours.setdefault(parent, []).append((child, transform))
        neighbours.setdefault(child, []).append((parent, np.linalg.inv(transform)))
    reached: dict[str, np.ndarray] = {source: np.eye(4)}
    queue = deque([source])
    while queue:
        frame = queue.popleft()
        for other, transform in neighbours.get(frame, []):
            if other not in reached:
                reached[other] = reached[frame] @ transform
                queue.append(other)
    return reached.get(target)
