"""Loop closing pieces (vslam_core/loop/): the bag of binary words, the pose graph, the map snapshot format."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vslam_core.config import LoopConfig
from vslam_core.geometry import invert_pose, pose_matrix
from vslam_core.loop.pose_graph import LoopEdge, optimise
from vslam_core.loop.vocabulary import BinaryVocabulary, similarity


def _descriptors(seed: int, count: int = 400) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (count, 32), dtype=np.uint8)


def test_vocabulary_tells_places_apart() -> None:
    """The same descriptors with a few bits flipped score far above other descriptors."""
    documents = [_descriptors(s) for s in range(4)]
    vocabulary = BinaryVocabulary.build(documents, 128, seed=0)
    assert vocabulary.words.shape == (128, 32)
    noisy = documents[1].copy()
    noisy[:, 0] ^= 0b00000101  # two bits of every descriptor flipped
    vectors = np.array([vocabulary.vector(d) for d in documents])
    scores = similarity(vocabulary.vector(noisy), vectors)
    assert np.argmax(scores) == 1
    assert scores[1] > 0.8 and scores[1] - np.delete(scores, 1).max() > 0.3  # random bits: the tree splits them evenly
    assert similarity(vectors[0], vectors[0]) == pytest.approx(1.0)
    again = BinaryVocabulary.build(documents, 128, seed=0)  # deterministic
    np.testing.assert_array_equal(again.words, vocabulary.words)


def _circle(count: int) -> np.ndarray:
    """(count, 4, 4) poses on a 10 m circle, the camera turning about y."""
    poses = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        rotation = cv2.Rodrigues(np.array([0.0, angle, 0.0]))[0]
        poses.append(pose_matrix(rotation, 10 * np.array([np.sin(angle), 0.0, np.cos(angle) - 1.0])))
    return np.array(poses)


def _drifted(truth: np.ndarray, yaw_deg: float, scale: float) -> np.ndarray:
    """The same relative motions with a yaw bias and a step length factor added to each: odometry drift."""
    bias = pose_matrix(cv2.Rodrigues(np.array([0.0, np.radians(yaw_deg), 0.0]))[0], np.zeros(3))
    poses = [truth[0]]
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        step = invert_pose(a) @ b
        step[:3, 3] *= scale
        poses.append(poses[-1] @ step @ bias)
    return np.array(poses)


@pytest.mark.parametrize("similarity_graph", [False, True])
def test_pose_graph_closes_the_loop(similarity_graph: bool) -> None:
    """Keyframes drifting around a circle: the loop edge (the truth between the last and the first) pulls
    the last keyframe back onto the truth and spreads the correction along the chain."""
    truth = _circle(24)
    drifted = _drifted(truth, 0.5, 1.0 if not similarity_graph else 1.02)
    loop = LoopEdge(0, 23, invert_pose(truth[0]) @ truth[23], 1.0)
    # edges as uncertain as this drift (0.5° a keyframe; the metric default assumes a car's, 0.05°)
    config = LoopConfig(odometry_sigma_deg=0.5, odometry_sigma_m=0.1)
    corrected, scales = optimise(drifted, [loop], config, similarity_graph)
    before = np.linalg.norm(drifted[:, :3, 3] - truth[:, :3, 3], axis=1)
    after = np.linalg.norm(corrected[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert before[-1] > 1.0
    assert after[-1] < 0.1 * before[-1]
    assert after.max() < 0.6 * before.max()
    np.testing.assert_allclose(corrected[0], drifted[0], atol=1e-6)  # the gauge: the first keyframe stays
    if similarity_graph:
        assert not np.allclose(scales, 1.0)  # the steps were 2 % too long: Sim(3) nodes rescale them
    else:
        assert (scales == 1.0).all()


def test_similarity_pose_graph_corrects_scale_drift() -> None:
    """--scale none: the k-th step is 1.02^k times too long (the map's unit shrinks along the run). The loop
    edge, measured in the candidate's units with the scale between the two keyframes' maps (candidate units per
    query unit), brings the last keyframe back and gives it that scale."""
    truth = _circle(24)
    poses = [truth[0]]
    for k, (a, b) in enumerate(zip(truth[:-1], truth[1:], strict=True)):
        step = invert_pose(a) @ b
        step[:3, 3] *= 1.02**k
        poses.append(poses[-1] @ step)
    drifted = np.array(poses)
    scale = 1.0 / 1.02**22  # at the query a true metre is 1.02^22 of its map's units
    loop = LoopEdge(0, 23, invert_pose(truth[0]) @ truth[23], scale)
    corrected, scales = optimise(drifted, [loop], LoopConfig(), True)
    before = np.linalg.norm(drifted[:, :3, 3] - truth[:, :3, 3], axis=1)
    after = np.linalg.norm(corrected[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert before[-1] > 5.0 and after[-1] < 0.01 * before[-1]
    assert after.max() < 0.05 * before.max()  # every keyframe, not only the loop's ends (measured 0.18 of 5.9 m)
    assert scales[-1] == pytest.approx(scale, rel=0.05)
