"""Property tests: geometry never raises on valid-but-degenerate input and always returns proper
rotations; loaders turn any bytes into a clean `VslamError`; the noise check's fast filter gives what its
3x3 kernel gives."""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vslam_core.config import EngineConfig
from vslam_core.engine import Odometry
from vslam_core.errors import VslamError
from vslam_core.geometry import candidate_poses, chirality_check, normalise_points, refine_relative_pose, so3_exp
from vslam_core.quality import image_stats
from vslam_core.scale import UnitScale
from vslam_core.sources.base import CameraIntrinsics, Frame
from vslam_core.sources.kitti import read_grey_image, read_p0_intrinsics
from vslam_core.trajectory.io import read_kitti_poses, read_tum_poses

K = np.array([[718.856, 0.0, 607.1928], [0.0, 718.856, 185.2157], [0.0, 0.0, 1.0]])


def assert_proper_rotation(rotation: np.ndarray) -> None:
    assert rotation.shape == (3, 3) and np.all(np.isfinite(rotation))
    assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6)
    assert np.linalg.det(rotation) > 0.999


@st.composite
def two_views(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Pixel correspondences of a random scene and motion, including degenerate ones."""
    kind = draw(st.sampled_from(["general", "pure_rotation", "zero_motion", "collinear", "duplicates", "planar"]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    n = draw(st.integers(5, 300))
    rotation = so3_exp(rng.normal(0, 0.05, 3))
    translation = rng.normal(0, 1, 3)
    if kind in ("pure_rotation", "zero_motion"):
        translation = np.zeros(3)
    if kind == "zero_motion":
        rotation = np.eye(3)
    points = np.column_stack((rng.uniform(-10, 10, n), rng.uniform(-3, 3, n), rng.uniform(3, 60, n)))
    if kind == "collinear":
        direction = rng.normal(0, 1, 3)
        points = np.array([0.0, 0.0, 20.0]) + np.outer(rng.uniform(-5, 5, n), direction)
    if kind == "planar":
        points[:, 1] = 1.65
    if kind == "duplicates":
        points[:] = points[0]
    previous = points @ rotation.T + translation
    assume(np.all(points[:, 2] > 0.5) and np.all(previous[:, 2] > 0.5))

    def project(p: np.ndarray) -> np.ndarray:
        uv = (p / p[:, 2:3]) @ K.T
        return uv[:, :2] + rng.normal(0, draw(st.sampled_from([0.0, 0.5, 2.0])), (len(p), 2))

    return project(points), project(previous)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(two_views())
def test_two_view_geometry_never_raises_and_returns_rotations(views: tuple[np.ndarray, np.ndarray]) -> None:
    p_cur, p_prev = views
    essential, mask = cv2.findEssentialMat(p_cur, p_prev, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    if essential is None or essential.shape[0] < 3 or not np.all(np.isfinite(essential[:3])):
        return  # OpenCV found no (finite) model: the engine holds the pose (two_view.find_essential)
    inliers = mask.ravel().astype(bool)
    x_cur, x_prev = normalise_points(p_cur[inliers], K), normalise_points(p_prev[inliers], K)
    for rotation, translation in candidate_poses(essential[:3]):
        assert_proper_rotation(rotation)
        assert abs(np.linalg.norm(translation) - 1) < 1e-9
    candidates, best = chirality_check(essential[:3], x_cur, x_prev)
    assert 0 <= best < 4 and all(0 <= c.in_front <= inliers.sum() for c in candidates)
    rotation, translation = refine_relative_pose(candidates[best].rotation, candidates[best].translation, x_cur,
                                                 x_prev, robust_scale=1 / 718.0)
    assert_proper_rotation(rotation)
    assert abs(np.linalg.norm(translation) - 1) < 1e-9


@settings(max_examples=25, deadline=None)
@given(st.lists(st.sampled_from(["noise", "black", "white", "stripes", "same"]), min_size=2, max_size=6),
       st.integers(0, 1000))
def test_engine_survives_any_sequence_of_odd_images(kinds: list[str], seed: int) -> None:
    """Constant, random, striped or repeated images: one pose per frame, proper rotations, no exception."""
    rng = np.random.default_rng(seed)
    intrinsics = CameraIntrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    engine = Odometry(intrinsics, EngineConfig(scale="none"), UnitScale())
    previous = rng.integers(0, 255, (240, 320), dtype=np.uint8)
    for i, kind in enumerate(kinds):
        image = {
            "noise": rng.integers(0, 255, (240, 320), dtype=np.uint8),
            "black": np.zeros((240, 320), np.uint8),
            "white": np.full((240, 320), 255, np.uint8),
            "stripes": np.tile((np.arange(320) % 16 < 8).astype(np.uint8) * 255, (240, 1)),
            "same": previous,
        }[kind]
        result = engine.process(Frame(i, None, image))
        assert_proper_rotation(result.T_world_cam[:3, :3])
        assert np.all(np.isfinite(result.T_world_cam))
        previous = image


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=400))
def test_loaders_turn_any_bytes_into_a_clean_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "file"
        path.write_bytes(data)
        for load in (read_kitti_poses, read_tum_poses, read_p0_intrinsics, read_grey_image):
            try:
                load(path)  # type: ignore[operator]
            except VslamError as exc:
                assert str(path) in str(exc) and "\n" not in str(exc)


@given(st.integers(0, 2**31 - 1), st.integers(3, 64), st.integers(3, 64), st.booleans())
def test_noise_estimate_is_the_3x3_kernels(seed: int, height: int, width: int, saturated: bool) -> None:
    """`image_stats`' noise sigma (Immerkaer's kernel as two 1-D passes) is the one the 3x3 kernel itself gives,
    on any image, black-and-white ones (the largest responses) included: sqrt(pi/2) / 6 x the lower median of
    |response| over the interior, clipped at 255."""
    rng = np.random.default_rng(seed)
    image = (255 * rng.integers(0, 2, (height, width)) if saturated
             else rng.integers(0, 256, (height, width))).astype(np.uint8)
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    magnitude = np.minimum(np.abs(cv2.filter2D(image, cv2.CV_32F, kernel)[1:-1, 1:-1]), 255).astype(np.int64)
    median = int(np.sort(magnitude.ravel())[(magnitude.size - 1) // 2])
    assert image_stats(image).noise_sigma == float(np.sqrt(np.pi / 2) * median / 6)
