"""Place recognition over past keyframes: what each keyframe keeps for loop closing, and the candidate search.

A keyframe is described by its strongest FAST corners with upright ORB descriptors (like the map's
landmarks, vslam_core/mapping/local_mapping.py) and, once the vocabulary exists, by their bag of words. It also
keeps its landmarks in its own camera frame (positions, pixels, descriptors), which is what a later keyframe
is verified against: camera-frame points stay valid however the keyframe is moved by corrections.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam_core.config import LoopConfig
from vslam_core.loop.vocabulary import BinaryVocabulary, similarity
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH

EMPTY_DESCRIPTORS = np.zeros((0, 32), np.uint8)
PRESELECT_MARGIN = 10  # FAST is first run this much above the configured threshold (describe_image)
NEIGHBOURS = 3  # a query's previous keyframes whose best score sets its candidates' threshold


@dataclass
class KeyframePlace:
    """One keyframe as loop closing sees it. F features, L landmarks."""

    keyframe_id: int
    position: int  # run position of its frame
    segment: int
    pixels: np.ndarray  # (F, 2) float32 feature positions
    descriptors: np.ndarray  # (F, 32) uint8 upright ORB
    point_ids: np.ndarray  # (L,) int64 its landmarks' ids
    points_cam: np.ndarray  # (L, 3) its landmarks in its camera frame
    point_pixels: np.ndarray  # (L, 2) where it saw them
    point_descriptors: np.ndarray  # (L, 32) uint8
    thumbnail: np.ndarray  # (H/2, W/2) uint8 image, or once stored its JPEG bytes as (B,) uint8 (for the recording)
    words: np.ndarray | None = None  # (V,) bag of words, once the vocabulary exists (until it was searched for)


THUMBNAIL_QUALITY = 80  # a stored keyframe's thumbnail: JPEG of it at half its size (KITTI: ~7.5 KB, not 117 KB)


def pack_thumbnail(image: np.ndarray) -> np.ndarray:
    """(4 + B,) uint8: the (H, W) uint8 thumbnail's height and width (two little-endian uint16), then the JPEG
    bytes of it at half that size (an empty one stays empty). A stored keyframe is only ever shown as a loop
    candidate beside its query, whose thumbnail is the full one."""
    if image.size == 0:
        return np.zeros(0, np.uint8)
    small = cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    ok, encoded = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, THUMBNAIL_QUALITY])
    if not ok:
        return np.zeros(0, np.uint8)
    shape = np.array(image.shape, "<u2").view(np.uint8)
    return np.concatenate((shape, np.asarray(encoded, np.uint8).reshape(-1)))


def unpack_thumbnail(stored: np.ndarray) -> np.ndarray:
    """The (H, W) uint8 thumbnail of `pack_thumbnail`'s bytes, scaled back to its size (an image not packed is
    returned as it is)."""
    if stored.ndim == 2:
        return stored
    if stored.size <= 4:
        return np.zeros((0, 0), np.uint8)
    height, width = (int(v) for v in stored[:4].view("<u2"))
    decoded = cv2.imdecode(stored[4:], cv2.IMREAD_GRAYSCALE)
    if decoded is None:
        return np.zeros((0, 0), np.uint8)
    return cv2.resize(decoded, (width, height), interpolation=cv2.INTER_LINEAR)


def describe_image(image: np.ndarray, count: int, fast_threshold: int,
                   describer: cv2.ORB) -> tuple[np.ndarray, np.ndarray]:
    """The `count` strongest FAST corners of a (H, W) uint8 image (ties: row-major order) with upright ORB
    descriptors: ((F, 2) float32 pixels, (F, 32) uint8). The keypoints are made by `cv2.KeyPoint_convert`, whose
    angle is -1: ORB describes it as upright, the same bits as angle 0 (tests/test_loop_describe.py), without a
    Python object built per corner.

    Corners are first detected at a higher threshold (`fast_threshold` + `PRESELECT_MARGIN`): a corner's score
    (Rosten & Drummond 2006, the largest threshold at which it is a corner) does not depend on the threshold it
    was detected at, and non-maximum suppression only lets a corner be suppressed by a neighbour with a higher
    score, which passes any threshold it passes. So when that gives `count` corners or more, they hold exactly the
    `count` strongest the configured threshold gives, and fewer corners are scored and sorted (a KITTI frame:
    ~3 100 at threshold 25 instead of ~5 200 at 15; describing a keyframe of 05: 4.1 → 3.0 ms); otherwise the
    configured threshold is used."""
    corners = cv2.FastFeatureDetector_create(threshold=fast_threshold + PRESELECT_MARGIN).detect(image, None)
    if len(corners) < count:
        corners = cv2.FastFeatureDetector_create(threshold=fast_threshold).detect(image, None)
    if not corners:
        return np.zeros((0, 2), np.float32), EMPTY_DESCRIPTORS
    response = np.array([c.response for c in corners], np.float32)
    points = cv2.KeyPoint_convert(corners)  # (N, 2)
    order = _strongest(points, response, count)
    keypoints, descriptors = describer.compute(image, cv2.KeyPoint_convert(points[order], DESCRIPTOR_PATCH))
    if descriptors is None:
        return np.zeros((0, 2), np.float32), EMPTY_DESCRIPTORS
    return cv2.KeyPoint_convert(keypoints).astype(np.float32).reshape(-1, 2), descriptors


def _strongest(points: np.ndarray, response: np.ndarray, count: int) -> np.ndarray:
    """Indices of the `count` largest of (N,) responses at (N, 2) pixels, ties in row-major order: FAST gives
    its corners row by row, so a stable sort of the responses alone does it (a quarter of the time of sorting by
    response, row and column); corners in another order are put in row-major order first."""
    step = np.diff(points, axis=0)
    row_major = bool(np.all((step[:, 1] > 0) | ((step[:, 1] == 0) & (step[:, 0] > 0))))
    by_position = np.arange(len(points)) if row_major else np.lexsort((points[:, 0], points[:, 1]))
    return by_position[np.argsort(-response[by_position], kind="stable")[:count]]


class PlaceDatabase:
    """The keyframes seen so far, their bags of words, and the search for places a keyframe revisits.

    Kept compact, since it grows with every keyframe of the drive (docs/map-backend.md, memory): once a keyframe
    was searched for (`compact`), it keeps only what a later search uses of it as a candidate (its bag of words,
    its landmarks, a JPEG thumbnail), not its 1000 features (~40 KB): only the query's features are matched."""

    def __init__(self, config: LoopConfig, seed: int) -> None:
        self._config = config
        self._seed = seed
        self.places: dict[int, KeyframePlace] = {}
        self.vocabulary: BinaryVocabulary | None = None
        self._ids: list[int] = []  # keyframes with words, in insertion order
        self._rows = np.zeros((0, 0), np.float32)  # (capacity, V) their words: the first len(_ids) rows used
        self._segments: list[int] = []  # their segments
        self._covered: list[int] = []  # places an older place was verified against, dropped once no query reads them

    @property
    def _matrix(self) -> np.ndarray:
        """(N, V) the words of the keyframes with words."""
        return self._rows[: len(self._ids)]

    def compact(self, keyframe_id: int) -> None:
        """The keyframe was searched for: drop its features once the vocabulary no longer needs them (it is
        built from the first keyframes' features), and keep its thumbnail as JPEG bytes."""
        place = self.places.get(keyframe_id)
        if place is None:
            return
        place.thumbnail = pack_thumbnail(place.thumbnail) if place.thumbnail.ndim == 2 else place.thumbnail
        place.words = None  # its row of the words matrix is what later searches score
        if self.vocabulary is not None:
            for stored in self.places.values():
                if len(stored.descriptors) and stored.keyframe_id <= keyframe_id:
                    stored.pixels, stored.descriptors = stored.pixels[:0].copy(), EMPTY_DESCRIPTORS

    def cover(self, keyframe_id: int) -> None:
        """An older place was verified against this keyframe (its view is already in the database): it will be
        dropped (`prune`), so that a street driven again adds no places; the older place stays the candidate
        of every later pass."""
        if keyframe_id in self.places:
            self._covered.append(keyframe_id)

    def uncovered(self, before: int, segment: int) -> list[int]:
        """Stored places of the segment up to keyframe `before` that no older place covers."""
        covered = set(self._covered)
        return [k for k, p in self.places.items() if k <= before and p.segment == segment and k not in covered]

    def prune(self, newest: int) -> None:
        """Drop the covered places that no later query reads: a query's threshold scores its `NEIGHBOURS`
        previous keyframes, and only places `min_separation_keyframes` older are candidates."""
        self.remove({k for k in self._covered if k < newest - NEIGHBOURS})

    def remove(self, dropped: set[int]) -> None:
        """Drop these keyframes' places (covered, or culled from the map)."""
        dropped &= self.places.keys()
        if not dropped:
            return
        self._covered = [k for k in self._covered if k not in dropped]
        for keyframe_id in dropped:
            del self.places[keyframe_id]
        keep = [n for n, k in enumerate(self._ids) if k not in dropped]
        if len(keep) < len(self._ids):  # rows moved up in order (a copy of the kept rows only)
            self._rows[: len(keep)] = self._rows[keep]
            self._ids = [self._ids[n] for n in keep]
            self._segments = [self._segments[n] for n in keep]

    def add(self, place: KeyframePlace) -> None:
        """Store a keyframe; the vocabulary is built once `vocabulary_keyframes` keyframes are stored."""
        self.places[place.keyframe_id] = place
        cfg = self._config
        if self.vocabulary is None and len(self.places) >= cfg.vocabulary_keyframes:
            documents = [p.descriptors for p in self.places.values() if len(p.descriptors)]
            if sum(len(d) for d in documents) >= 2:
                self.vocabulary = BinaryVocabulary.build(documents, cfg.vocabulary_words, self._seed)
                for stored in self.places.values():
                    self._index(stored)
                return
        if self.vocabulary is not None:
            self._index(place)

    def _index(self, place: KeyframePlace) -> None:
        assert self.vocabulary is not None
        words = self.vocabulary.vector(place.descriptors)
        place.words = words
        if len(self._ids) == len(self._rows):  # full: double (no copy of the whole matrix per keyframe)
            grown = np.zeros((max(2 * len(self._rows), 64), len(words)), np.float32)  # 4 KB a keyframe
            if self._ids:
                grown[: len(self._ids)] = self._matrix
            self._rows = grown
        self._rows[len(self._ids)] = words
        self._ids.append(place.keyframe_id)
        self._segments.append(place.segment)

    def candidates(self, query: KeyframePlace) -> list[tuple[int, float]]:
        """(keyframe id, score) of the best-scoring older keyframes of the query's segment, at least
        `min_separation_keyframes` before it, scoring at least `min_score_ratio` times the query's best score
        with its 3 previous keyframes (how alike consecutive views of one place are here: on a street every
        view shares many words with every other, so only a place more alike than the neighbours counts); best
        first, at most `max_candidates`."""
        cfg = self._config
        if query.words is None or not self._ids:
            return []
        ids = np.array(self._ids, np.int64)
        scores = similarity(query.words, self._matrix)
        neighbours = (ids < query.keyframe_id) & (ids >= query.keyframe_id - NEIGHBOURS)
        if not neighbours.any():
            return []
        threshold = cfg.min_score_ratio * float(scores[neighbours].max())
        segment = np.array(self._segments, np.int64) == query.segment
        eligible = segment & (ids <= query.keyframe_id - cfg.min_separation_keyframes) & (scores >= threshold)
        order = np.flatnonzero(eligible)[np.argsort(-scores[eligible], kind="stable")]
        return [(int(ids[i]), float(scores[i])) for i in order[: cfg.max_candidates]]
