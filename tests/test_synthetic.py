"""Tests of the synthetic street source: API, determinism, ground truth, texture and geometric consistency."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.errors import SourceError
from vslam_core.geometry import rotation_angle
from vslam_core.sources.base import FrameRange, FrameSource
from vslam_core.sources.synthetic import SyntheticStreet, frame_cache
from vslam_core.sources.synthetic.street import _panorama, _world

pytestmark = pytest.mark.usefixtures("no_render_cache")  # the renderer itself under test: every frame rendered


@pytest.fixture(scope="module")
def street() -> SyntheticStreet:
    return SyntheticStreet()


@pytest.fixture(scope="module")
def frames_0_1(street: SyntheticStreet) -> tuple[np.ndarray, np.ndarray]:
    return street.render(0), street.render(1)


def _heading_deg(pose: np.ndarray) -> float:
    """Heading of the camera's forward axis in the world x-z plane (degrees)."""
    forward = pose[:3, 2]
    return math.degrees(math.atan2(forward[0], forward[2]))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def _project(k: np.ndarray, pose_w_c: np.ndarray, point_w: np.ndarray) -> np.ndarray:
    """Pixel (2,) of a world point seen by a camera with pose T_w_c."""
    t_c_w = np.linalg.inv(pose_w_c)
    p = t_c_w[:3, :3] @ point_w + t_c_w[:3, 3]
    assert p[2] > 0
    uvw = k @ p
    return uvw[:2] / uvw[2]


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a = a.astype(np.float64) - a.mean()
    b = b.astype(np.float64) - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum() + 1e-12))


def test_implements_frame_source(street: SyntheticStreet) -> None:
    assert isinstance(street, FrameSource)
    assert street.name == "synthetic-street"
    intr = street.intrinsics
    assert (intr.width, intr.height) == (1241, 376)
    assert intr.fx == pytest.approx(718.856) and intr.fy == pytest.approx(718.856)
    assert (intr.cx, intr.cy) == pytest.approx((607.1928, 185.2157))
    assert len(street) == 300
    assert street.camera_height == pytest.approx(1.65)


def test_frames_shapes_dtypes_and_timestamps() -> None:
    source = SyntheticStreet(n_frames=20, frames=FrameRange(0, 2))
    frames = list(source)
    assert [f.index for f in frames] == [0, 1]
    assert [f.timestamp for f in frames] == pytest.approx([0.0, 0.1])
    for frame in frames:
        assert frame.image.shape == (376, 1241)
        assert frame.image.dtype == np.uint8
        assert frame.image.std() > 20  # not blank


def test_deterministic() -> None:
    a = SyntheticStreet(n_frames=40, frames=FrameRange(30, 32), seed=3)
    first = [frame.image for frame in a]  # the scene is built on the first render
    _world.cache_clear()  # the scene built again, not shared
    b = SyntheticStreet(n_frames=40, frames=FrameRange(30, 32), seed=3)
    np.testing.assert_array_equal(a.ground_truth, b.ground_truth)
    for image, frame in zip(first, b, strict=True):
        np.testing.assert_array_equal(image, frame.image)
    other = SyntheticStreet(n_frames=40, frames=FrameRange(30, 32), seed=4)
    assert not np.array_equal(other.render(30), a.render(30))


def test_shorter_run_is_a_prefix_of_a_longer_one(street: SyntheticStreet) -> None:
    short = SyntheticStreet(n_frames=50)
    np.testing.assert_allclose(short.ground_truth, street.ground_truth[:50], atol=1e-9)


def test_ground_truth_is_proper(street: SyntheticStreet) -> None:
    gt = street.ground_truth
    assert gt.shape == (300, 4, 4) and gt.dtype == np.float64
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    rot = gt[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", rot, rot), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-9)
    np.testing.assert_array_equal(gt[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (300, 4)))
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    assert steps.min() >= 0.7 and steps.max() <= 1.3
    assert steps.std() > 0.02  # the speed varies


def test_path_turns_pitches_and_rolls(street: SyntheticStreet) -> None:
    gt = street.ground_truth
    headings = np.unwrap(np.radians([_heading_deg(p) for p in gt]))
    assert np.degrees(headings.max() - headings.min()) > 45.0
    assert np.degrees(np.abs(np.diff(headings)).sum()) > 150.0  # left and right curves
    # Pitch and roll relative to the road plane, whose normal is known in the world frame.
    up_w = street.ground_plane[:3]
    up_c = np.einsum("nji,j->ni", gt[:, :3, :3], up_w)  # the road normal in each camera frame
    pitch = np.degrees(np.arctan2(up_c[:, 2], -up_c[:, 1]))
    roll = np.degrees(np.arctan2(up_c[:, 0], -up_c[:, 1]))
    for angle in (pitch, roll):
        assert 0.2 < np.abs(angle).max() < 1.5
    # The camera stays camera_height above the road: n . c + d = height for every camera centre c.
    heights = gt[:, :3, 3] @ up_w + street.ground_plane[3]
    np.testing.assert_allclose(heights, street.camera_height, atol=1e-9)


def test_the_walk_route_is_a_hand_held_camera() -> None:
    """`route="walk"`: 30 Hz, a few centimetres a frame, swinging about its centre (up to ~2° a frame), bobbing
    2 cm above the camera height; its frames render like the street's."""
    walk = SyntheticStreet(route="walk", frames=FrameRange(0, 90))
    frames = [frame for _, frame in zip(range(2), walk, strict=False)]
    assert frames[1].timestamp - frames[0].timestamp == pytest.approx(1 / 30)
    assert frames[0].image.shape == (walk.intrinsics.height, walk.intrinsics.width)
    assert frames[0].image.dtype == np.uint8 and frames[0].image.std() > 20  # a textured street, not a blank
    gt = walk.ground_truth
    steps = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    assert steps.min() > 0.03 and steps.max() < 0.06
    turns = np.degrees([rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in zip(gt[:-1], gt[1:], strict=True)])
    assert turns.mean() > 0.5 and 1.5 < turns.max() < 3.0  # rotation-dominated: ~20 px of flow a frame
    heights = gt[:, :3, 3] @ walk.ground_plane[:3] + walk.ground_plane[3]  # each camera's, from the first's plane
    assert np.abs(heights - walk.camera_height).max() == pytest.approx(0.02, abs=1e-3)  # the bob of each step


def test_the_drive_route_is_a_whole_drive_with_revisits_at_changing_speeds() -> None:
    """`route="drive"`: KITTI 00's 4541 frames at 10 Hz, lap after lap round a closed circuit of two blocks
    (five left turns and one right), at 0.45..1.7 m a frame: every place is passed three times or more, at
    different speeds; more frames than an open street allows, since the scene is the circuit's."""
    drive = SyntheticStreet(route="drive")
    assert len(drive) == 4541
    gt = drive.ground_truth
    position = gt[:, :3, 3]
    steps = np.linalg.norm(np.diff(position, axis=0), axis=1)
    assert 0.4 < steps.min() < 0.55 and 1.6 < steps.max() < 1.8 and 4400 < steps.sum() < 4900
    near_start = np.linalg.norm(position - position[0], axis=1) < 2.0
    laps = np.flatnonzero(near_start[1:] & ~near_start[:-1])  # re-entries into the start's 2 m
    assert len(laps) >= 3
    assert not np.isclose(steps[laps[0]], steps[laps[1]], rtol=0.1)  # the same place at another speed
    yaw = np.degrees(np.unwrap(np.arctan2(gt[:, 0, 2], gt[:, 2, 2])))  # heading about the world's vertical (RDF y)
    assert abs(yaw[-1] - yaw[0]) / 360 == pytest.approx(steps.sum() / 1237, rel=0.05)  # one turn a lap
    turning = np.diff(yaw)
    assert (turning > 0.8).sum() > 100 and (turning < -0.8).sum() > 20  # the left turns, and the right one
    assert SyntheticStreet(route="drive", n_frames=12000).ground_truth.shape == (12000, 4, 4)
    with pytest.raises(SourceError, match="n_frames must be in 1..2000 on route street"):
        SyntheticStreet(route="street", n_frames=4541)


def test_frame_range_selection(street: SyntheticStreet) -> None:
    selected = SyntheticStreet(frames=FrameRange(10, 20, 2))
    assert len(selected) == 5
    assert selected.indices == [10, 12, 14, 16, 18]
    gt = selected.ground_truth
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    full = street.ground_truth
    expected = np.linalg.inv(full[10]) @ full[[10, 12, 14, 16, 18]]
    np.testing.assert_allclose(gt, expected, atol=1e-9)
    first = next(iter(selected))
    assert first.index == 10 and first.timestamp == pytest.approx(1.0)
    np.testing.assert_array_equal(first.image, street.render(10))


def test_end_past_the_last_frame_is_clamped_an_empty_range_raises() -> None:
    """The one frame-range rule (a Python slice's): END is clamped; only a range selecting nothing fails."""
    assert SyntheticStreet(n_frames=20, frames=FrameRange(15, 21)).indices == [15, 16, 17, 18, 19]
    assert len(SyntheticStreet(n_frames=20, frames=FrameRange(None, 400))) == 20
    with pytest.raises(SourceError, match="selects no frame"):
        SyntheticStreet(n_frames=20, frames=FrameRange(20, None))


def test_fast_corners_everywhere(frames_0_1: tuple[np.ndarray, np.ndarray]) -> None:
    image = frames_0_1[0]
    corners = cv2.FastFeatureDetector_create(threshold=20).detect(image)
    assert len(corners) >= 1000
    x = np.array([c.pt[0] for c in corners])
    per_strip = np.histogram(x, bins=8, range=(0, image.shape[1]))[0]
    assert (per_strip >= 20).sum() >= 6, per_strip


def test_road_points_project_onto_matching_texture(street: SyntheticStreet) -> None:
    """Road points of frame 10 (pixel rays cut with the true road plane) seen again in frame 11.

    The road is foreshortened differently in the two frames, so frame 11 is first warped into frame 10 by
    the road-plane homography made of the ground-truth motion; the patches around each road point must
    then match, and must match worse when the ground-truth motion is perturbed.
    """
    selected = SyntheticStreet(frames=FrameRange(10, 12))
    gt, plane = selected.ground_truth, selected.ground_plane
    k = selected.intrinsics.K
    img0, img1 = street.render(10), street.render(11)
    t_1_0 = np.linalg.inv(gt[1]) @ gt[0]  # X_1 = R X_0 + t

    def road_homography(t_1_0: np.ndarray) -> np.ndarray:
        """Frame-10 pixel -> frame-11 pixel for points on the plane n.X + d = 0 (frame-10 coordinates)."""
        rot, trans = t_1_0[:3, :3], t_1_0[:3, 3]
        return k @ (rot - np.outer(trans, plane[:3]) / plane[3]) @ np.linalg.inv(k)

    pixels = [(560, 300), (640, 280), (520, 330), (700, 320), (600, 250), (450, 270), (800, 300)]

    def patch_scores(h: np.ndarray) -> list[float]:
        size = (img0.shape[1], img0.shape[0])
        warped = cv2.warpPerspective(img1, h, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        return [_ncc(img0[v - 7 : v + 8, u - 7 : u + 8], warped[v - 7 : v + 8, u - 7 : u + 8]) for u, v in pixels]

    h_true = road_homography(t_1_0)
    for u, v in pixels:  # the homography agrees with projecting the 3-D road point with the pose
        ray = np.linalg.inv(k) @ np.array([u, v, 1.0])
        point = ray * (-plane[3] / float(plane[:3] @ ray))  # on the road, frame-10 (= world) coordinates
        u1, v1 = _project(k, gt[1], point)
        assert 10 < u1 < img1.shape[1] - 10 and 10 < v1 < img1.shape[0] - 10
        mapped = h_true @ np.array([u, v, 1.0])
        np.testing.assert_allclose(mapped[:2] / mapped[2], (u1, v1), atol=1e-6)
    good = patch_scores(h_true)
    assert min(good) > 0.8, good
    perturbed = t_1_0.copy()
    perturbed[:3, 3] *= 1.15  # 15% too long a step: the road points land a few pixels off
    worse = patch_scores(road_homography(perturbed))
    assert np.mean(worse) < np.mean(good) - 0.2, (good, worse)


def test_essential_matrix_recovers_true_direction(
    street: SyntheticStreet, frames_0_1: tuple[np.ndarray, np.ndarray]
) -> None:
    img0, img1 = frames_0_1
    k = street.intrinsics.K
    corners = cv2.FastFeatureDetector_create(threshold=20).detect(img0)
    p0 = np.array([c.pt for c in corners], np.float32).reshape(-1, 1, 2)
    p1, status, _ = cv2.calcOpticalFlowPyrLK(
        img0,
        img1,
        p0,
        None,
        winSize=(21, 21),
        maxLevel=3,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
    )
    ok = status.ravel() == 1
    prev, cur = p0[ok].reshape(-1, 2), p1[ok].reshape(-1, 2)
    assert len(prev) > 500
    e, _ = cv2.findEssentialMat(cur, prev, k, method=cv2.RANSAC, prob=0.999, threshold=1.0)
    _, _, t, _ = cv2.recoverPose(e, cur, prev, k)  # X_prev = R X_cur + t: T_prev_cur
    gt = street.ground_truth
    t_true = (np.linalg.inv(gt[0]) @ gt[1])[:3, 3]
    assert _angle_deg(t.ravel(), t_true) < 3.0


def test_frame_cache_gives_the_rendered_frames_and_is_read_back(monkeypatch: pytest.MonkeyPatch,
                                                                tmp_path: Path) -> None:
    """`VSLAM_SYNTHETIC_CACHE`: a frame is written once rendered, byte for byte the uncached render; a later
    street reads it back (a planted file is what it returns); an unreadable file is rendered again; another
    renderer version uses another folder."""
    uncached = SyntheticStreet(n_frames=20, frames=FrameRange(3, 5), resolution=0.25)
    expected = [frame.image for frame in uncached]
    monkeypatch.setenv(frame_cache.ENVIRONMENT, str(tmp_path))
    written = [frame.image for frame in SyntheticStreet(n_frames=20, frames=FrameRange(3, 5), resolution=0.25)]
    for image, reference in zip(written, expected, strict=True):
        np.testing.assert_array_equal(image, reference)
    folder = tmp_path / frame_cache.renderer_version()
    files = sorted(p.name for p in folder.iterdir())
    assert files == [f"street-seed0-n20-h1.65-310x94-f179.714-{index:05d}.npy" for index in (3, 4)]
    planted = np.full_like(expected[0], 7)
    np.save(folder / files[0], planted)
    (folder / files[1]).write_bytes(b"cut")  # unreadable: rendered again and rewritten
    again = SyntheticStreet(n_frames=20, frames=FrameRange(3, 5), resolution=0.25)
    np.testing.assert_array_equal(again.render(3), planted)
    np.testing.assert_array_equal(again.render(4), expected[1])
    np.testing.assert_array_equal(np.load(folder / files[1]), expected[1])
    assert not list(folder.glob(".frame-*"))  # no temporary file left
    # the scene the frames are rendered from is kept beside them: a process without it in memory builds it and
    # writes it, a later one reads it back (the file is not written again), one finding it unreadable builds it
    # again; the same pixels each time (frame 5 is in no cache)
    scenes = tmp_path / f"scenes-{frame_cache.renderer_version()}"
    stored = scenes / "street-seed0-n20.npz"
    images, writes = [], []
    for damage in (None, None, b"cut"):
        if damage is not None:
            stored.write_bytes(damage)
        _world.cache_clear()
        _panorama.cache_clear()
        (folder / f"street-seed0-n20-h1.65-310x94-f179.714-{5:05d}.npy").unlink(missing_ok=True)
        images.append(SyntheticStreet(n_frames=20, frames=FrameRange(5, 6), resolution=0.25).render(5))
        assert sorted(p.name for p in scenes.iterdir()) == ["panorama-seed0-f179.714.npz", stored.name]
        writes.append(stored.stat().st_mtime_ns)
    assert writes[1] == writes[0] and frame_cache.load_arrays(stored) is not None
    for image in images:
        np.testing.assert_array_equal(image, uncached._render(5))
    monkeypatch.setattr(frame_cache, "renderer_version", lambda: "another")
    np.testing.assert_array_equal(SyntheticStreet(n_frames=20, frames=FrameRange(3, 4), resolution=0.25).render(3),
                                  expected[0])
    assert (tmp_path / "another" / files[0]).exists()
