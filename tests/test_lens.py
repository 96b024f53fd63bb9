"""vslam_core.lens: the lens models' closed forms against OpenCV's, undistortion round trips, the usable
border of strong lenses, and the engine's use of ideal pixels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vslam_core.lens import (
    distort_pixels,
    inside_mask,
    undistort_pixels,
    undistortion_maps,
    valid_pixel_mask,
)
from vslam_core.sources.base import CameraIntrinsics
from vslam_core.sources.calibration import make_intrinsics

SIZE = (1241, 376)
LENSES = {
    "plumb_bob": (-0.28, 0.07, 1e-4, -2e-4, 0.0),
    "rational_polynomial": (-0.3, 0.1, 1e-3, -5e-4, 0.0, 0.01, 0.002, 0.0),
    "equidistant": (0.08, -0.02, 0.005, -0.001),
    "fov": (0.9,),
}


def lens(model: str, focal: float = 700.0) -> CameraIntrinsics:
    return CameraIntrinsics(focal, focal * 1.01, 620.3, 187.9, *SIZE, model, LENSES[model])  # type: ignore[arg-type]


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_distortion_matches_opencv_project_points(model: str) -> None:
    """The closed form of the Brown–Conrady models is OpenCV's (cv2.projectPoints of rays at z = 1)."""
    camera = lens(model)
    rng = np.random.default_rng(0)
    ideal = rng.uniform([100, 30], [1140, 346], (500, 2))
    rays = np.column_stack(((ideal - [camera.cx, camera.cy]) / [camera.fx, camera.fy], np.ones(len(ideal))))
    expected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera.K, np.array(camera.coefficients))
    np.testing.assert_allclose(distort_pixels(ideal, camera), expected.reshape(-1, 2), atol=1e-9)


def test_equidistant_matches_opencv_fisheye() -> None:
    camera = lens("equidistant")
    rng = np.random.default_rng(1)
    ideal = rng.uniform([0, 0], SIZE, (500, 2))
    normalised = ((ideal - [camera.cx, camera.cy]) / [camera.fx, camera.fy]).reshape(-1, 1, 2)
    expected = cv2.fisheye.distortPoints(normalised, camera.K, np.array(camera.coefficients))
    np.testing.assert_allclose(distort_pixels(ideal, camera), expected.reshape(-1, 2), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(model=st.sampled_from(sorted(LENSES)), x=st.floats(0, SIZE[0] - 1), y=st.floats(0, SIZE[1] - 1))
def test_undistort_inverts_distort_inside_the_usable_lens(model: str, x: float, y: float) -> None:
    camera = lens(model)
    mask = valid_pixel_mask(camera)
    raw = np.array([[x, y]])
    if not inside_mask(raw, mask)[0]:
        return  # a folded border pixel has no trustworthy ideal position
    ideal = undistort_pixels(raw, camera)
    np.testing.assert_allclose(distort_pixels(ideal, camera), raw, atol=1e-6)


def test_a_pinhole_camera_passes_points_through() -> None:
    camera = CameraIntrinsics(700.0, 700.0, 620.0, 188.0, *SIZE)
    points = np.array([[0.0, 0.0], [1240.0, 375.0], [620.5, 10.25]])
    np.testing.assert_array_equal(undistort_pixels(points, camera), points)
    np.testing.assert_array_equal(distort_pixels(points, camera), points)
    assert valid_pixel_mask(camera) is None
    assert not camera.distorted


def test_a_strong_lens_has_its_folded_border_masked() -> None:
    """k1 = −0.3 at a short focal length folds in the image corners: they are masked, the centre is not."""
    camera = CameraIntrinsics(500.0, 500.0, 620.0, 188.0, *SIZE, "plumb_bob", (-0.3, 0.1, 0.001, -0.0005, -0.02))
    mask = valid_pixel_mask(camera)
    assert mask is not None and mask.shape == (SIZE[1], SIZE[0])
    assert mask[188, 620] == 255
    assert mask[0, 0] == 0 and mask[-1, -1] == 0
    usable = np.argwhere(mask > 0)[:, ::-1].astype(np.float64)
    sample = usable[np.random.default_rng(2).choice(len(usable), 2000)]
    back = distort_pixels(undistort_pixels(sample, camera), camera)
    assert np.max(np.linalg.norm(back - sample, axis=1)) < 0.15  # every usable pixel round-trips


def test_undistortion_maps_straighten_a_distorted_line() -> None:
    """A straight line of the pinhole, drawn through the lens and remapped with the maps, is straight again."""
    camera = lens("plumb_bob")
    raw = np.zeros((SIZE[1], SIZE[0]), np.uint8)
    ideal_line = np.column_stack((np.linspace(150, 1090, 2000), np.full(2000, 40.0)))
    for x, y in np.round(distort_pixels(ideal_line, camera)).astype(int):
        cv2.circle(raw, (int(x), int(y)), 1, 255, -1)
    undistorted = cv2.remap(raw, *undistortion_maps(camera), cv2.INTER_LINEAR)
    rows = np.argwhere(undistorted[:, 200:1040] > 64)[:, 0]
    assert abs(np.median(rows) - 40) <= 1 and rows.max() - rows.min() <= 4


@pytest.mark.parametrize(
    ("name", "coefficients", "model", "kept"),
    [("radtan", [0.1, 0.01, 0.0, 0.0], "plumb_bob", 4), ("fisheye", [0.1, 0.0, 0.0, 0.0], "equidistant", 4),
     ("plumb_bob", [0.1, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "plumb_bob", 5)],  # ROS's 8 with zeros beyond k3
)
def test_model_spellings_and_trailing_zeros(name: str, coefficients: list[float], model: str, kept: int) -> None:
    camera = make_intrinsics([700, 0, 620, 0, 700, 188, 0, 0, 1], name, coefficients, *SIZE, "test")
    assert camera.model == model
    assert len(camera.coefficients) == kept
