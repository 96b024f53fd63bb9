"""Dead reckoning through degraded frames (vslam_core/coasting.py) on real KITTI 00 frames: the rotation between
consecutive frames from blurred and dark images, against the ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.coasting import DeadReckoning, agrees, degraded_motion, steady, unit_step
from vslam_core.geometry import pose_matrix, rotation_angle, so3_exp
from vslam_core.scale import GroundTruthScale
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.io import read_kitti_poses

TURN = (198, 207)  # KITTI 00: the car turns 2.8° and 3.9° between these frames and the next


def blurred(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image, (0, 0), 6.0)  # as --inject blur


def dark(image: np.ndarray) -> np.ndarray:
    return (image.astype(np.float32) * 0.05).astype(np.uint8)  # as --inject dark


class Kitti00:
    def __init__(self, root: Path) -> None:
        self.camera = KittiSource(root, "00").intrinsics
        self.gt = read_kitti_poses(root / "poses" / "00.txt")  # (N, 4, 4), indexed by frame
        self._images = root / "sequences" / "00" / "image_0"
        self._read: dict[int, np.ndarray] = {}  # each frame decoded once per module (~60 frames, 0.5 MB each)

    def image(self, index: int) -> np.ndarray:
        if index not in self._read:
            self._read[index] = cv2.imread(str(self._images / f"{index:06d}.png"), cv2.IMREAD_GRAYSCALE)
        return self._read[index].copy()


@pytest.fixture(scope="module")
def kitti00(kitti_root: Path) -> Kitti00:
    return Kitti00(kitti_root)


def rotation_error_deg(gt: np.ndarray, first: int, rotation: np.ndarray) -> float:
    r_gt = gt[first, :3, :3].T @ gt[first + 1, :3, :3]
    return float(np.degrees(rotation_angle(r_gt.T @ rotation)))


PAIRS = [*range(93, 127, 3), *range(191, 218, 3)]  # KITTI 00's two turns, 1-4° a frame: 22 frame pairs
DEGRADE = {"sharp": None, "blurred": blurred, "dark": dark}


@pytest.mark.kitti
@pytest.mark.parametrize(("first_kind", "second_kind", "mean_deg", "worst_deg"), [
    ("blurred", "blurred", 0.25, 1.5),
    ("sharp", "blurred", 0.4, 3.5),  # into a gap
    ("blurred", "sharp", 0.4, 3.5),  # out of it: 2.5° and 3.5° off at frames 198 and 207 without matching the blur
    ("dark", "dark", 0.1, 0.2),
    ("sharp", "dark", 0.1, 0.2),
    ("dark", "sharp", 0.1, 0.2),
])
def test_rotation_through_degraded_frames(kitti00: Kitti00, first_kind: str, second_kind: str, mean_deg: float,
                                          worst_deg: float) -> None:
    """Frame-to-frame rotation from degraded images against the ground truth (measured: blurred 0.18-0.32° on
    average, dark 0.05°), every pair giving a motion."""
    errors = []
    for first in PAIRS:
        images = [kitti00.image(first), kitti00.image(first + 1)]
        for k, kind in enumerate((first_kind, second_kind)):
            degrade = DEGRADE[kind]
            if degrade is not None:
                images[k] = degrade(images[k])
        motion = degraded_motion(images[0], images[1], kitti00.camera)
        assert motion is not None, first
        errors.append(rotation_error_deg(kitti00.gt, first, motion[0]))
    assert np.mean(errors) < mean_deg and max(errors) < worst_deg, (np.mean(errors), max(errors))


@pytest.mark.kitti
def test_dead_reckoning_chains_from_the_last_readable_frame(kitti00: Kitti00) -> None:
    first, gt = TURN[1], kitti00.gt
    reckoning = DeadReckoning(kitti00.camera, GroundTruthScale(gt))
    assert reckoning.reckon(kitti00.image(first), first) is None  # nothing to continue from yet
    reckoning.remember(kitti00.image(first), gt[first], first)
    pose = reckoning.reckon(dark(kitti00.image(first + 1)), first + 1)
    assert pose is not None  # the step's direction from a dark frame is good to ~1.4° (blurred: ~5°)
    assert np.linalg.norm(pose[:3, 3] - gt[first + 1, :3, 3]) < 0.05  # metres, in a 0.45 m step (its length: gt)
    assert np.degrees(rotation_angle(gt[first + 1, :3, :3].T @ pose[:3, :3])) < 0.3
    disabled = DeadReckoning(kitti00.camera, GroundTruthScale(gt), enabled=False)
    disabled.remember(kitti00.image(first), gt[first], first)
    assert disabled.reckon(kitti00.image(first + 1), first + 1) is None


def test_agreement_allows_dead_reckoning_its_drift() -> None:
    def turned(deg: float) -> np.ndarray:
        return pose_matrix(cv2.Rodrigues(np.array([0.0, np.radians(deg), 0.0]))[0], np.zeros(3))

    assert agrees(np.eye(3), turned(1.9), frames=2)  # never stricter than 2°
    assert not agrees(np.eye(3), turned(2.1), frames=2)
    assert agrees(np.eye(3), turned(3.5), frames=12)  # 0.3° a frame since the keyframe
    assert not agrees(np.eye(3), turned(6.7), frames=12)  # the wrong match after a blurred turn on KITTI 00


def test_a_step_far_from_the_one_before_repeats_it() -> None:
    """`steady`: a dead-reckoned step within 1.5° of rotation of the step before it is kept, one farther away gives
    way to that step; without a step before, the measured one is kept. `unit_step` is the motion between two
    poses with a unit translation."""
    before = unit_step(np.eye(4), pose_matrix(so3_exp(np.radians([0.0, -2.4, 0.0])), np.array([0.0, 0.0, 0.9])))
    assert before is not None
    np.testing.assert_allclose(before[1], [0.0, 0.0, 1.0])
    close = (so3_exp(np.radians([0.0, -3.5, 0.0])), np.array([0.0, 0.0, 1.0]))
    turned = (so3_exp(np.radians([0.0, 1.6, 0.0])), np.array([-0.86, 0.0, 0.5]))
    assert steady(close, before) is close
    assert steady(turned, before) is before
    assert steady(turned, None) is turned
    assert unit_step(np.eye(4), np.eye(4)) is None

