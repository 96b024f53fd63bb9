"""Loop closing's memory follows the place, not the time (issue 56): driven over the same places again, the
place database keeps per keyframe only its bag of words, its landmarks and a JPEG thumbnail (the features of a
keyframe already searched for are dropped), revisits are still recognised from it, and tracking's side keeps
only the few recent places it still reads unless the map is to be saved; a keyframe the map has forgotten
releases its tracks and its landmark table; a keyframe an older place was verified against is not kept as a
place (a street driven again adds no places)."""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest

from vslam_core.config import EngineConfig, LoopConfig
from vslam_core.loop.closing import LoopClosing
from vslam_core.loop.places import NEIGHBOURS, KeyframePlace, PlaceDatabase, unpack_thumbnail
from vslam_core.mapping.local_mapping import LocalMapping
from vslam_core.mapping.map import Map
from vslam_core.sources.base import CameraIntrinsics

CAMERA = CameraIntrinsics(700.0, 700.0, 320.0, 120.0, 640, 240)
PLACES = 12  # distinct places, driven twice: keyframes PLACES.. revisit keyframes 0..
CONFIG = EngineConfig(backend="map", loop=LoopConfig(min_separation_keyframes=PLACES - 2))


def _image(place: int) -> np.ndarray:
    """A (240, 640) uint8 view of its own: random blobs, smoothed."""
    rng = np.random.default_rng(place)
    return cv2.GaussianBlur((rng.random((240, 640)) * 255).astype(np.uint8), (5, 5), 1.5)


def _drive(keep_places: bool, spacing: float = 0.0) -> tuple[LoopClosing, list[list[int]], list[int]]:
    """Keyframes of the places 0..PLACES-1 then the same places again, searched in this process; place p is
    `spacing` * p metres along x (0: every keyframe at the origin). Returns the loop closing, the candidates of
    each search, and the place database's bytes after each search."""
    loop = LoopClosing(CAMERA, CONFIG, None)
    loop.keep_places = keep_places
    map_ = Map()
    found: list[list[int]] = []
    stored: list[int] = []
    for n in range(2 * PLACES):
        pose = np.eye(4)
        pose[0, 3] = spacing * (n % PLACES)
        keyframe = map_.add_keyframe(n, 0, pose, np.zeros(0, np.int64), np.zeros((0, 2), np.float32), None)
        loop.submit(keyframe.id, _image(n % PLACES))
        collected = loop.collect(map_)
        if collected is not None:
            found.append([c.candidate_keyframe for c in collected[0].candidates])
            stored.append(_bytes(_database(loop)))
    return loop, found, stored


def _database(loop: LoopClosing) -> PlaceDatabase:
    local = loop._worker._local  # the search runs in this process (no worker)
    assert local is not None
    return local.database


def _bytes(database: PlaceDatabase) -> int:
    """What the database holds: each place's arrays and the words matrix (its capacity)."""
    arrays = [a for p in database.places.values() for a in (p.pixels, p.descriptors, p.points_cam, p.point_pixels,
                                                            p.point_descriptors, p.point_ids, p.thumbnail,
                                                            p.words if p.words is not None else np.zeros(0))]
    return sum(a.nbytes for a in arrays) + database._rows.nbytes


@pytest.fixture(scope="module")
def drive() -> tuple[LoopClosing, list[list[int]], list[int]]:
    return _drive(keep_places=False)


def test_revisited_places_are_still_recognised_from_the_compact_store(drive) -> None:
    _, found, _ = drive
    # search n (of keyframe n) revisits place n - PLACES: it is the best-scoring candidate
    revisits = [(n, candidates) for n, candidates in enumerate(found) if n >= PLACES]
    assert revisits
    assert all(candidates and candidates[0] == n - PLACES for n, candidates in revisits), revisits


def test_searched_keyframes_keep_no_features_and_a_small_thumbnail(drive) -> None:
    loop, _, stored = drive
    database = _database(loop)
    newest = max(database.places)
    older = [p for k, p in database.places.items() if k < newest]
    assert older and all(len(p.descriptors) == 0 and len(p.pixels) == 0 for p in older)
    assert all(p.thumbnail.ndim == 1 and p.thumbnail.nbytes < 120 * 320 for p in older)  # JPEG, not raw
    assert unpack_thumbnail(older[0].thumbnail).shape == (120, 320)
    # bytes per keyframe on the second pass (revisits): a few KB each (words 8 KB + a JPEG), not the ~80 KB
    # of raw features and thumbnail
    per_keyframe = (stored[-1] - stored[PLACES - 1]) / (len(stored) - PLACES)
    assert per_keyframe < 40_000, per_keyframe


def test_tracking_keeps_only_recent_places_unless_the_map_is_saved(drive) -> None:
    loop, _, _ = drive
    settled = CONFIG.map.ba_window + CONFIG.map.ba_max_fixed + 1
    assert len(loop.places) <= settled + 2
    kept, _, _ = _drive(keep_places=True)
    assert len(kept.places) == 2 * PLACES  # every keyframe submitted


def test_a_forgotten_keyframe_releases_its_tracks_and_its_landmark_table() -> None:
    """A keyframe `map_keyframes` behind the newest keeps its pose only: no view keeping its (N,) track arrays
    alive, and a landmark set no larger than what it still holds (a set never shrinks by itself)."""
    mapping = LocalMapping(CAMERA, CONFIG.map, "gt", None)
    world = mapping.map
    tracks = np.arange(2000, dtype=np.int64)
    keyframe = world.add_keyframe(0, 0, np.eye(4), tracks, np.zeros((2000, 2), np.float32), None)
    for n in range(400):
        world.add_landmark(np.array([0.0, 0.0, 10.0 + n]), {keyframe.id: np.zeros(2)})
    full = sys.getsizeof(keyframe.landmark_ids)
    mapping._forget(keyframe.id, alive_landmarks={0})  # landmark 0 is still tracked: it stays
    assert keyframe.landmark_ids == {0}
    assert sys.getsizeof(keyframe.landmark_ids) < full / 20
    assert len(keyframe.track_ids) == 0 and keyframe.track_ids.base is None and keyframe.pixels.base is None


def _place(keyframe_id: int, view: int) -> KeyframePlace:
    """A keyframe seeing place `view`: its 300 random descriptors with a few bits flipped per keyframe."""
    descriptors = np.random.default_rng(view).integers(0, 256, (300, 32), dtype=np.uint8)
    descriptors[:, 0] ^= np.random.default_rng(1000 + keyframe_id).integers(0, 4, 300, dtype=np.uint8)
    empty = np.zeros((0, 2), np.float32)
    return KeyframePlace(keyframe_id, keyframe_id, 0, empty, descriptors, np.zeros(0, np.int64), np.zeros((0, 3)),
                         empty, np.zeros((0, 32), np.uint8), np.zeros((24, 64), np.uint8))


def test_covered_places_are_dropped_and_the_first_pass_stays_the_candidate() -> None:
    """Three passes over PLACES places; each revisiting keyframe is covered (as when its verification passes):
    the database ends with the first pass and the last few queries only, its words matrix with as many rows,
    and the third pass still finds each place's first-pass keyframe first."""
    database = PlaceDatabase(CONFIG.loop, seed=0)
    found = []
    for keyframe_id in range(3 * PLACES):
        query = _place(keyframe_id, keyframe_id % PLACES)
        database.add(query)
        candidates = database.candidates(query)
        found.append(candidates[0][0] if candidates else None)
        if keyframe_id >= PLACES:
            database.cover(keyframe_id)
        database.compact(keyframe_id)
        database.prune(keyframe_id)
    newest = 3 * PLACES - 1
    assert sorted(database.places) == list(range(PLACES)) + list(range(newest - NEIGHBOURS, newest + 1))
    assert database._ids == sorted(database.places) and len(database._matrix) == len(database.places)
    assert found[2 * PLACES:] == list(range(PLACES)), found  # the third pass: the first pass's keyframe each time


def test_a_keyframe_where_a_stored_place_lies_is_not_kept(drive) -> None:
    """The same drive with the keyframes 2 m apart, the second pass at the first pass's poses (no landmarks: no
    verification passes, so only the poses say the places are known): the second pass's places are dropped
    and each still finds its first-pass place first. At the origin (spacing 0) nothing is dropped."""
    loop, found, _ = _drive(keep_places=False, spacing=2.0)
    newest = 2 * PLACES - 2  # the last keyframe's search is submitted, not collected (the run did not finish)
    assert sorted(_database(loop).places) == list(range(PLACES)) + list(range(newest - NEIGHBOURS, newest + 1))
    assert [c[0] for c in found[PLACES:]] == list(range(PLACES - 1))
    assert len(_database(drive[0]).places) == newest + 1  # every keyframe searched
