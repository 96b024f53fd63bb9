"""Pose-graph optimisation after a loop closure (gtsam, Levenberg–Marquardt).

Nodes: the segment's K keyframes (T_world_cam). Edges: consecutive keyframes' relative poses as they are in
the map (odometry) and the verified loop edge. With a metric scale the nodes are SE(3) and the edges
`BetweenFactorPose3`; with unit scale (--scale none) the scale drifts too, so nodes and edges are Sim(3)
(`BetweenFactorSimilarity3`; Strasdat et al., "Scale Drift-Aware Large Scale Monocular SLAM", RSS 2010). The
oldest keyframe is held fixed (the gauge).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam_core.config import LoopConfig
from vslam_core.geometry import invert_pose


@dataclass(frozen=True)
class LoopEdge:
    """The verified loop: node `candidate` sees node `query` at T_candidate_query (translation in the
    candidate's units), `scale` candidate units per query unit."""

    candidate: int  # node index
    query: int
    T_candidate_query: np.ndarray  # (4, 4)  # noqa: N815
    scale: float


def optimise(poses: np.ndarray, loops: list[LoopEdge], config: LoopConfig,
             similarity: bool) -> tuple[np.ndarray, np.ndarray]:
    """(K, 4, 4) corrected T_world_cam and (K,) scale of each node's neighbourhood (1 for SE(3)) from (K, 4, 4)
    keyframe poses in chain order and the loop edges (every loop closed so far, so later closures keep the
    earlier ones)."""
    import gtsam  # as in bundle_adjustment: only the map backend needs it
    from gtsam.symbol_shorthand import X

    rotation, translation = (np.radians(config.none_odometry_sigma_deg), config.none_odometry_sigma_m) if similarity \
        else (np.radians(config.odometry_sigma_deg), config.odometry_sigma_m)
    loop_rotation, loop_translation = np.radians(config.loop_sigma_deg), config.loop_sigma_m
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    node: Any
    between: Any
    equality: Any
    if similarity:
        odometry_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([rotation] * 3 + [translation] * 3 + [0.05]))
        loop_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([loop_rotation] * 3 + [loop_translation] * 3 + [0.01]))

        def node(T: np.ndarray, s: float = 1.0) -> Any:  # noqa: N803
            # gtsam's Similarity3(R, t, s) maps x to s·(R·x + t): the map's x ↦ s·R·x + t is (R, t / s, s)
            return gtsam.Similarity3(gtsam.Rot3(T[:3, :3]), np.asarray(T[:3, 3], np.float64) / s, s)

        between, equality = gtsam.BetweenFactorSimilarity3, gtsam.NonlinearEqualitySimilarity3
    else:
        odometry_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([rotation] * 3 + [translation] * 3))
        loop_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([loop_rotation] * 3 + [loop_translation] * 3))

        def node(T: np.ndarray, s: float = 1.0) -> Any:  # noqa: N803
            return gtsam.Pose3(T)

        between, equality = gtsam.BetweenFactorPose3, gtsam.NonlinearEqualityPose3
    for i, pose in enumerate(poses):
        initial.insert(X(i), node(pose))
        if i > 0:
            graph.add(between(X(i - 1), X(i), node(invert_pose(poses[i - 1]) @ pose), odometry_noise))
    graph.add(equality(X(0), node(poses[0])))
    for loop in loops:
        graph.add(between(X(loop.candidate), X(loop.query), node(loop.T_candidate_query, loop.scale), loop_noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    corrected = np.tile(np.eye(4), (len(poses), 1, 1))
    scales = np.ones(len(poses))
    for i in range(len(poses)):
        if similarity:
            value = result.atSimilarity3(X(i))
            corrected[i, :3, :3] = value.rotation().matrix()
            scales[i] = value.scale()
            corrected[i, :3, 3] = scales[i] * value.translation()  # the camera's centre: s·(R·0 + t)
        else:
            corrected[i] = result.atPose3(X(i)).matrix()
    return corrected, scales
