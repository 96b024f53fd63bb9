"""Loop search's fast paths give exactly what the slower code they replaced gave, on a real KITTI frame: the
keyframe's upright ORB features (keypoints from `cv2.KeyPoint_convert`, angle -1) and the vocabulary's nearest
word (numpy popcount instead of OpenCV's brute-force matcher, ties included)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.features import match_descriptors
from vslam_core.loop.places import _strongest, describe_image
from vslam_core.loop.vocabulary import BinaryVocabulary, nearest
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH


@pytest.fixture(scope="module")
def described(kitti_root: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A KITTI 05 frame and its 1000 strongest corners' ((F, 2) pixels, (F, 32) descriptors)."""
    image = cv2.imread(str(kitti_root / "sequences" / "05" / "image_0" / "000100.png"), cv2.IMREAD_GRAYSCALE)
    describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
    pixels, descriptors = describe_image(image, 1000, 15, describer)
    return image, pixels, descriptors


def test_features_are_upright_orb(described: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """The same descriptors as keypoints built one by one with angle 0 at the same pixels."""
    image, pixels, descriptors = described
    assert 900 <= len(pixels) <= 1000  # corners too close to the border are not described
    describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
    upright = [cv2.KeyPoint(float(x), float(y), DESCRIPTOR_PATCH, 0.0, 0.0, 0) for x, y in pixels]
    kept, expected = describer.compute(image, upright)
    assert len(kept) == len(pixels)
    np.testing.assert_array_equal(descriptors, expected)
    turned = [cv2.KeyPoint(float(x), float(y), DESCRIPTOR_PATCH, 45.0, 0.0, 0) for x, y in pixels]
    assert (describer.compute(image, turned)[1] != expected).any(axis=1).mean() > 0.9  # the angle does count


def test_nearest_word_is_the_matchers(described: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """Nearest centre (ties: the first) as OpenCV's brute-force Hamming matcher finds it, and the tree's words
    are each descriptor's nearest in its nearest branch."""
    _, _, descriptors = described
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    for centres in (descriptors[:32], descriptors[::7][:100], np.repeat(descriptors[:20], 2, axis=0)):
        expected = np.zeros(len(descriptors), np.int64)
        for match in matcher.match(descriptors, centres):
            expected[match.queryIdx] = match.trainIdx
        np.testing.assert_array_equal(nearest(descriptors, centres), expected)  # the repeated centres: ties
    vocabulary = BinaryVocabulary.build([descriptors[:500], descriptors[500:]], 256, seed=0)
    branch = nearest(descriptors, vocabulary.branches)
    words = vocabulary.assign(descriptors)
    for n in range(0, len(descriptors), 37):
        start, stop = int(vocabulary.offsets[branch[n]]), int(vocabulary.offsets[branch[n] + 1])
        assert words[n] == start + nearest(descriptors[n:n + 1], vocabulary.words[start:stop])[0]


def _matched_both_ways(query: np.ndarray, train: np.ndarray, ratio: float) -> list[tuple[int, int]]:
    """Mutual ratio-test matches the plain way: OpenCV's matcher, query to train (2 nearest) and train to query."""
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    backward = {p[0].queryIdx: p[0].trainIdx for p in matcher.knnMatch(train, query, k=1) if p}
    return [(m.queryIdx, m.trainIdx) for m, n in matcher.knnMatch(query, train, k=2)
            if m.distance < ratio * n.distance and backward.get(m.trainIdx) == m.queryIdx]


def test_mutual_matches_are_the_matchers(kitti_root: Path,
                                         described: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """`match_descriptors` (one pass, then back only from the chosen train descriptors) gives the matches of the
    matcher run both ways in full: a frame 3 frames on, the same frame (ties: each descriptor twice), none."""
    _, _, descriptors = described
    image = cv2.imread(str(kitti_root / "sequences" / "05" / "image_0" / "000103.png"), cv2.IMREAD_GRAYSCALE)
    describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
    _, later = describe_image(image, 1000, 15, describer)
    for train in (later, later[:300], np.repeat(descriptors[:400], 2, axis=0), descriptors[::-1]):
        for ratio in (0.8, 0.95):
            query_index, train_index = match_descriptors(descriptors, train, ratio)
            expected = _matched_both_ways(descriptors, train, ratio)
            assert list(zip(query_index.tolist(), train_index.tolist(), strict=True)) == expected
    assert len(match_descriptors(descriptors, later, 0.8)[0]) > 100
    assert len(match_descriptors(descriptors[:1], later, 0.8)[0]) == 0


def _described_in_full(image: np.ndarray, count: int, fast_threshold: int) -> tuple[np.ndarray, np.ndarray]:
    """`describe_image` the plain way: every corner at the configured threshold, the strongest `count` of them
    (ties: row-major order) described."""
    corners = cv2.FastFeatureDetector_create(threshold=fast_threshold).detect(image, None)
    points = cv2.KeyPoint_convert(corners).reshape(-1, 2)
    response = np.array([c.response for c in corners], np.float32)
    order = np.lexsort((points[:, 0], points[:, 1], -response))[:count]
    describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
    keypoints, descriptors = describer.compute(image, cv2.KeyPoint_convert(points[order], DESCRIPTOR_PATCH))
    return cv2.KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2), descriptors


def test_corners_preselected_at_a_higher_threshold_are_the_strongest_at_the_configured_one(kitti_root: Path) -> None:
    """The first detection above the threshold changes nothing: the same features as every corner at the
    configured threshold, on real frames of 00 and 05 (the preselection enough: 1000 corners), with more corners
    asked for than the higher threshold finds (the fallback), and on a dark frame with too few corners for either."""
    describer = cv2.ORB_create(edgeThreshold=int(DESCRIPTOR_PATCH), patchSize=int(DESCRIPTOR_PATCH))
    images = [cv2.imread(str(kitti_root / "sequences" / sequence / "image_0" / f"{index:06d}.png"),
                         cv2.IMREAD_GRAYSCALE) for sequence, index in (("00", 0), ("00", 120), ("05", 140))]
    dark = (images[0] // 6).astype(np.uint8)
    preselected = cv2.FastFeatureDetector_create(threshold=25).detect(images[1], None)
    for image, count in [(image, 1000) for image in images] + [(images[1], len(preselected) + 500), (dark, 1000)]:
        pixels, descriptors = describe_image(image, count, 15, describer)
        expected_pixels, expected_descriptors = _described_in_full(image, count, 15)
        assert len(pixels) > 100
        np.testing.assert_array_equal(pixels, expected_pixels)
        np.testing.assert_array_equal(descriptors, expected_descriptors)
    assert len(cv2.FastFeatureDetector_create(threshold=25).detect(dark, None)) < 1000  # the fallback was taken


def test_strongest_corners_ties_in_row_major_order() -> None:
    """The strongest corners, equal responses taken row by row, whatever order the corners come in."""
    rng = np.random.default_rng(0)
    points = np.array([(x, y) for y in range(30) for x in range(40)], np.float32)  # row-major, as FAST gives
    response = rng.integers(10, 20, len(points)).astype(np.float32)  # many ties
    expected = np.lexsort((points[:, 0], points[:, 1], -response))[:100]
    np.testing.assert_array_equal(_strongest(points, response, 100), expected)
    shuffled = rng.permutation(len(points))
    chosen = _strongest(points[shuffled], response[shuffled], 100)
    np.testing.assert_array_equal(shuffled[chosen], expected)
