"""Windowed bundle adjustment with gtsam: robust reprojection error over keyframes and landmarks.

Minimises Σ ρ_Huber(‖π(K, T_cam_world·X_j) − z_ij‖ / σ) over the window's keyframe poses and landmark
positions (Triggs et al., "Bundle Adjustment — A Modern Synthesis", 2000, eq. 2 with a robust cost;
gtsam's `GenericProjectionFactorCal3_S2`, Levenberg–Marquardt). Older keyframes that see the window's
landmarks are held fixed (`NonlinearEquality`), which fixes the gauge; their observations constrain only the
landmark (`TriangulationFactorCal3_S2`, the held camera as a constant). The scale source stays in charge:
with a metric scale, the distance between consecutive keyframes enters as a `RangeFactorPose3` with the
scale source's length; with the map's own scale (`--scale none`) two poses are held fixed instead, and the
distance enters at its length before the adjustment, with a sigma of `none_step_sigma` times it. Whatever the
scale, the front end's two-view rotation between consecutive keyframes enters as a `BetweenFactorPose3` whose
translation has no weight (sigma 1e6): a relative-rotation prior.

`solve` is a pure function of a `Problem` (arrays in, arrays out), so it runs the same in this process or
in the run's worker process (`BundleAdjuster`), and the same input always gives the same output. The module
imports numpy and (when solving) gtsam, not OpenCV: with loop closing off the worker process never needs it (its
import costs 0.03–0.18 s of CPU there, when both cores are busiest).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from vslam_core.mapping.worker_process import BackendWorker, ServiceClient


@dataclass(frozen=True)
class Problem:
    """A BA problem. Poses are indexed 0..K+F−1: the K window keyframes first, then the F fixed ones."""

    K: np.ndarray  # (3, 3) camera matrix  # noqa: N815
    poses: np.ndarray  # (K + F, 4, 4) T_world_cam, initial values
    optimised: int  # K: the first K poses are variables, the rest fixed
    points: np.ndarray  # (P, 3) landmark positions, world
    observation_pose: np.ndarray  # (M,) int: which pose sees it
    observation_point: np.ndarray  # (M,) int: which landmark
    observation_pixels: np.ndarray  # (M, 2)
    ranges: np.ndarray  # (R, 4): pose index a, pose index b, distance (m), sigma (m)
    fix_first: int  # window poses held fixed as well (gauge/scale when too few older keyframes exist)
    iterations: int
    huber_px: float
    rotations: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))  # (Q, 2) pose indices a, b
    rotation_measurements: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))  # (Q, 3, 3) R_a_b
    rotation_sigma: float = 0.0  # rad
    rotation_covariances: np.ndarray | None = None  # (Q, 3, 3) rad² of each measurement; None: rotation_sigma


@dataclass(frozen=True)
class Solution:
    poses: np.ndarray  # (K, 4, 4) refined window poses
    points: np.ndarray  # (P, 3) refined landmarks
    errors_before: np.ndarray  # (M,) reprojection error (px) of each observation before
    errors_after: np.ndarray  # (M,) ... and after
    iterations: int
    cost_before: float
    cost_after: float
    milliseconds: float
    rotation_errors_after: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (Q,) deg from each prior


def rotation_errors(poses: np.ndarray, rotations: np.ndarray, measurements: np.ndarray) -> np.ndarray:
    """(Q,) angle (deg) between each measured relative rotation R_a_b and the one the (N, 4, 4) poses give."""
    relative = poses[rotations[:, 0], :3, :3].transpose(0, 2, 1) @ poses[rotations[:, 1], :3, :3]
    cosine = (np.trace(measurements.transpose(0, 2, 1) @ relative, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def reprojection_errors(K: np.ndarray, poses: np.ndarray, points: np.ndarray, pose_index: np.ndarray,  # noqa: N803
                        point_index: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(M,) pixel distance between each observation and its landmark projected by its pose (inf behind)."""
    poses = poses.reshape(-1, 4, 4)
    rotation = poses[pose_index, :3, :3].transpose(0, 2, 1)  # R_cam_world = R_world_camᵀ
    camera = np.einsum("mij,mj->mi", rotation, points[point_index] - poses[pose_index, :3, 3])
    depth = camera[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        projected = camera[:, :2] / depth[:, None] * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
        errors = np.linalg.norm(projected - pixels, axis=1)
    return np.where(depth > 1e-6, errors, np.inf)


def solve(problem: Problem) -> Solution:
    """Levenberg–Marquardt on the factor graph of `problem` (gtsam, sequential Cholesky: measured fastest
    on these graphs), landmarks eliminated before poses (the Schur complement's order).

    Why that order, and held poses out of the landmarks' factors: gtsam eliminates a variable with an equality
    constraint by QR over every factor it touches; when COLAMD picked a held pose before its landmarks, that was
    a dense system over hundreds of landmarks, 10–25 MB for one windowed job on a revisited street (the worker's
    peak: docs/map-backend.md, memory on a revisited street). Eliminated first, a landmark leaves a small factor
    on the window's poses that see it. The solution is the same up to rounding (1e-9 m on those jobs)."""
    import gtsam  # imported here: the worker process and the map backend need it, the rest of vslam does not
    from gtsam.symbol_shorthand import L, X

    start = time.perf_counter()
    K = problem.K  # noqa: N806
    calibration = gtsam.Cal3_S2(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2])
    pixel_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(problem.huber_px), gtsam.noiseModel.Isotropic.Sigma(2, 1.0))
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for i, pose in enumerate(problem.poses):
        initial.insert(X(i), gtsam.Pose3(pose))
        if i >= problem.optimised or i < problem.fix_first:
            graph.add(gtsam.NonlinearEqualityPose3(X(i), gtsam.Pose3(pose)))
    point_keys = [L(j) for j in range(len(problem.points))]
    for key, point in zip(point_keys, problem.points, strict=True):
        initial.insert(key, point)
    pose_keys = [X(i) for i in range(len(problem.poses))]
    held_cameras = {i: gtsam.PinholeCameraCal3_S2(gtsam.Pose3(pose), calibration)
                    for i, pose in enumerate(problem.poses) if i >= problem.optimised or i < problem.fix_first}
    projection, from_held, add = gtsam.GenericProjectionFactorCal3_S2, gtsam.TriangulationFactorCal3_S2, graph.add
    for i, j, pixel in zip(problem.observation_pose.tolist(), problem.observation_point.tolist(),
                           problem.observation_pixels, strict=True):  # the hot loop: ~2.5k factors
        if i in held_cameras:
            add(from_held(held_cameras[i], pixel, pixel_noise, point_keys[j]))
        else:
            add(projection(pixel, pixel_noise, pose_keys[i], point_keys[j], calibration))
    for a, b, distance, sigma in problem.ranges:
        graph.add(gtsam.RangeFactorPose3(X(int(a)), X(int(b)), float(distance),
                                         gtsam.noiseModel.Isotropic.Sigma(1, float(sigma))))
    if len(problem.rotations):
        rotation_noise: gtsam.noiseModel.Base = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([problem.rotation_sigma] * 3 + [1e6] * 3))
        for q, ((a, b), rotation) in enumerate(zip(problem.rotations.tolist(), problem.rotation_measurements,
                                                   strict=True)):
            if problem.rotation_covariances is not None:  # Pose3's tangent: rotation first, translation free
                covariance = np.diag([0.0] * 3 + [1e12] * 3)
                covariance[:3, :3] = problem.rotation_covariances[q]
                rotation_noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
            graph.add(gtsam.BetweenFactorPose3(X(a), X(b), gtsam.Pose3(gtsam.Rot3(rotation), np.zeros(3)),
                                               rotation_noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(problem.iterations)
    params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
    params.setOrdering(gtsam.Ordering.ColamdConstrainedLastNonlinearFactorGraph(graph, pose_keys))  # landmarks first
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    cost_before = optimizer.error()  # the graph's error at `initial`, computed by the optimizer's constructor
    try:
        result = optimizer.optimize()
        iterations = optimizer.iterations()
        cost_after = optimizer.error()  # the graph's error at `result`, computed when LM accepted it
    except RuntimeError:  # an indeterminate system (e.g. a landmark seen along one ray): keep the input
        result, iterations, cost_after = initial, 0, cost_before
    poses = np.array([result.atPose3(X(i)).matrix() for i in range(problem.optimised)]).reshape(-1, 4, 4)
    # the landmarks in key order: L(0), L(1), ... (the only Point3 values), copied in one call
    points = np.asarray(gtsam.utilities.extractPoint3(result), np.float64).reshape(-1, 3)
    all_poses = np.concatenate((poses, problem.poses[problem.optimised:]))
    args = (problem.observation_pose, problem.observation_point, problem.observation_pixels)
    return Solution(
        poses=poses,
        points=points,
        errors_before=reprojection_errors(K, problem.poses, problem.points, *args),
        errors_after=reprojection_errors(K, all_poses, points, *args),
        iterations=int(iterations),
        cost_before=float(cost_before),
        cost_after=float(cost_after),
        milliseconds=(time.perf_counter() - start) * 1000.0,
        rotation_errors_after=rotation_errors(all_poses, problem.rotations, problem.rotation_measurements),
    )


class Solver:
    """The worker process's bundle-adjustment service (`worker_process.BackendWorker`): `solve`, which keeps no
    state."""

    def run(self, problem: Problem) -> Solution:
        return solve(problem)


class BundleAdjuster:
    """Runs `solve` beside tracking. Given the run's worker process, there (gtsam holds the GIL, so a thread
    would stall tracking); otherwise, or once that process is gone, when the result is asked for. Either way a
    problem's solution is collected at a fixed point chosen by the caller, so results do not depend on timing."""

    def __init__(self, worker: BackendWorker | None) -> None:
        self._client: ServiceClient[Problem, Solution] = ServiceClient(worker, "bundle-adjustment", solve, Solver)

    @property
    def busy(self) -> bool:
        return self._client.busy

    def submit(self, problem: Problem) -> None:
        self._client.submit(problem)

    def collect(self) -> tuple[Problem, Solution] | None:
        """The solution of the submitted problem (waiting for it), or None if nothing was submitted."""
        return self._client.collect()
