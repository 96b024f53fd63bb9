"""Local-map tracking by projection: landmarks that left the image are found again where the pose says they are.

The idea of ORB-SLAM's "track local map" (Mur-Artal, Montiel and Tardós, "ORB-SLAM: a Versatile and Accurate
Monocular SLAM System", IEEE T-RO 2015, §V-D), written from the paper:

1. the local map: the keyframes that share the most landmarks with the reference keyframe (covisibility,
   `local_keyframes`), their neighbours in time, and the landmarks any of them sees;
2. each landmark with a descriptor is projected with the predicted pose (`T_world_cam`, camera-to-world,
   pinhole `K`) and kept if it lands in the image in front of the camera;
3. it is searched for among the frame's FAST corners inside a square window of half-size `radius` around
   its projection, by the Hamming distance between its upright ORB descriptor (taken at a keyframe, level 0)
   and the corner's described at several pyramid levels (`describe_levels`: the landmark seen closer than at
   its keyframe matches a coarser level), with a distance bound and Lowe's ratio test inside the window;
   a corner goes to the landmark it matches best.

On a tracked frame the landmarks are not snapped to FAST corners (`refind_by_flow`): a landmark is a KLT
track's point, a median 1.5 px from the nearest FAST corner on KITTI, and a corner a few pixels off made 87 %
of the re-found landmarks PnP outliers at the next frame (measured on 05 0:150: median 4.3 px from the
projection with the tracked pose, 14 % within 2 px). Instead the landmark's pixel in the last keyframe that
observed it is tracked by pyramidal Lucas–Kanade into the frame, starting at its projection, checked
forward–backward and by descriptor distance, and kept only where it agrees with the tracked pose
(`pnp_threshold_px`): a re-found landmark can never pull the next frame's pose away from what the live tracks say.

Pixels are (x right, y down), (N, 2) float64 ideal pinhole pixels of K unless named raw (on the distorted image,
vslam_core/lens.py). Descriptors are (32,) uint8 (256 bits).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from vslam_core.config import MapConfig, TrackerConfig
from vslam_core.lens import distort_pixels, undistort_pixels
from vslam_core.mapping.local_mapping import DESCRIPTOR_PATCH
from vslam_core.mapping.map import Map
from vslam_core.mapping.pnp import project
from vslam_core.results import LocalMapSearch
from vslam_core.sources.base import CameraIntrinsics

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


@dataclass
class FrameCorners:
    """FAST corners of one frame, described lazily (only those inside a search window are)."""

    image: np.ndarray  # (H, W) uint8
    pixels: np.ndarray  # (C, 2) float64 ideal pixels
    raw: np.ndarray  # (C, 2) float64 the same corners on the raw image (where they are described)
    tree: cKDTree  # over `pixels`
    pyramid: list[np.ndarray] = field(default_factory=list)  # level l: the image scaled by 1/scale^l (built lazily)


def local_keyframes(world: Map, reference_id: int, segment: int, count: int) -> list[int]:
    """Keyframe ids of the local map around `reference_id`: the reference, the `count` keyframes of the
    segment sharing the most landmarks with it (ties: the newer), each one's neighbours in time (id ± 1),
    and the two newest keyframes of the segment. Ascending."""
    keyframes = world.keyframes
    reference = keyframes.get(reference_id)
    if reference is None:
        return []
    shared: dict[int, int] = {}
    for landmark_id in reference.landmark_ids:
        landmark = world.landmarks.get(landmark_id)
        if landmark is None:
            continue
        for keyframe_id in landmark.observations:
            if keyframe_id != reference_id:
                shared[keyframe_id] = shared.get(keyframe_id, 0) + 1
    covisible = sorted(shared, key=lambda k: (-shared[k], -k))[:count]
    chosen = {reference_id, *covisible}
    for keyframe_id in list(chosen):
        chosen |= {keyframe_id - 1, keyframe_id + 1}
    chosen |= {k.id for k in world.recent_keyframes(2, segment)}
    return sorted(k for k in chosen if k in keyframes and keyframes[k].segment == segment)


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Bitwise Hamming distances of (..., 32) uint8 descriptors, broadcast over the leading axes."""
    words_a = np.ascontiguousarray(a).view(np.uint64)  # (..., 4): popcount of 64-bit words
    words_b = np.ascontiguousarray(b).view(np.uint64)
    return np.asarray(np.bitwise_count(np.bitwise_xor(words_a, words_b)).sum(axis=-1, dtype=np.int32))


class LocalMapSearcher:
    """Projects the local map into a frame and re-finds its landmarks among the frame's corners."""

    def __init__(self, camera: CameraIntrinsics, config: MapConfig) -> None:
        self._camera = camera
        self._K = camera.K
        self._config = config
        self._fast = cv2.FastFeatureDetector_create(threshold=config.reloc_fast_threshold)
        self._describer = cv2.ORB_create(nlevels=1, edgeThreshold=int(DESCRIPTOR_PATCH),
                                         patchSize=int(DESCRIPTOR_PATCH))

    def corners(self, image: np.ndarray) -> FrameCorners:
        """The frame's FAST corners (the detector tracks and landmarks are born from, at the relocalisation
        threshold)."""
        from scipy.spatial import cKDTree  # here: scipy takes ~0.5 s to import, and only map runs need it

        raw = cv2.KeyPoint_convert(self._fast.detect(image, None)).astype(np.float64).reshape(-1, 2)
        pixels = undistort_pixels(raw, self._camera)
        return FrameCorners(image, pixels, raw, cKDTree(pixels if len(pixels) else np.zeros((1, 2)) - 1e9))

    def describe_levels(self, corners: FrameCorners, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Upright ORB descriptors of (N, 2) raw pixels at each of L pyramid levels: (N, L, 32) uint8 and an
        (N, L) bool mask of the ones described (level l: the image scaled by 1/scale^l, as ORB's own pyramid
        with INTER_LINEAR; a pixel closer to that level's border than ORB's patch is not)."""
        levels, scale = self._config.local_map_levels, self._config.local_map_scale
        descriptors = np.zeros((len(pixels), levels, 32), np.uint8)
        valid = np.zeros((len(pixels), levels), bool)
        for level in range(levels):
            if len(corners.pyramid) <= level:
                height, width = corners.image.shape[:2]
                size = (round(width / scale**level), round(height / scale**level))
                corners.pyramid.append(corners.image if level == 0 else
                                       cv2.resize(corners.image, size, interpolation=cv2.INTER_LINEAR))
            image = corners.pyramid[level]
            at_level = pixels / scale**level
            border = DESCRIPTOR_PATCH + 1.0  # ORB's own border test rounds: one pixel to spare
            inside = np.flatnonzero((at_level[:, 0] >= border) & (at_level[:, 0] < image.shape[1] - border)
                                    & (at_level[:, 1] >= border) & (at_level[:, 1] < image.shape[0] - border))
            if not len(inside):
                continue
            keypoints = cv2.KeyPoint_convert(at_level[inside].astype(np.float32), DESCRIPTOR_PATCH)
            described, computed = self._describer.compute(image, keypoints)
            if computed is None or len(described) != len(inside):  # ORB kept every one inside the border
                continue
            descriptors[inside, level] = computed
            valid[inside, level] = True
        return descriptors, valid

    def search(self, world: Map, corners: FrameCorners, keyframe_ids: list[int], T_world_cam: np.ndarray,  # noqa: N803
               radius: float, exclude: set[int], purpose: str,
               along: tuple[np.ndarray, float] | None = None) -> LocalMapSearch:
        """Project the landmarks of `keyframe_ids` (except `exclude`) with `T_world_cam` and search each in a
        window of half-size `radius` px. Matches have distance ≤ `local_map_max_distance` and pass the ratio
        test against the window's second-best corner; a corner is kept by its best landmark only.

        With `along` = (T_world_origin, f) only the step's length from the origin is uncertain (the rotation and
        direction measured from the images): each landmark is searched within `radius` px of the segment its
        projection sweeps as the step's length goes from (1 − f) to (1 + f) times `T_world_cam`'s (an epipolar
        segment), so the ratio test compares the few corners near where it can be, not a wide square's."""
        cfg = self._config
        seen: set[int] = set()
        for keyframe_id in keyframe_ids:
            seen |= world.keyframes[keyframe_id].landmark_ids
        landmark_ids = np.array(sorted(i for i in seen - exclude if world.landmarks[i].descriptor is not None),
                                np.int64)
        height, width = corners.image.shape[:2]
        projected = project(world.positions(landmark_ids), T_world_cam, self._K).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            inside = ((projected[:, 0] >= 0) & (projected[:, 0] < width) & (projected[:, 1] >= 0)
                      & (projected[:, 1] < height))
        landmark_ids, projected = landmark_ids[inside], projected[inside]
        found = np.full((len(landmark_ids), 2), np.nan)
        distance = np.full(len(landmark_ids), -1, np.int64)
        result = LocalMapSearch(purpose, np.array(keyframe_ids, np.int64), landmark_ids, projected,
                                np.full(len(landmark_ids), float(radius)), found, distance,
                                np.zeros(len(landmark_ids), bool))
        if not len(landmark_ids) or not len(corners.pixels):
            return result
        if along is None:
            candidates = corners.tree.query_ball_point(projected, r=radius, p=np.inf)
        else:
            candidates, reach = _near_segments(corners, world.positions(landmark_ids), T_world_cam, along, radius,
                                               self._K)
            result.radius_px[:] = reach
        pair_landmark = np.repeat(np.arange(len(landmark_ids)), [len(c) for c in candidates])
        pair_corner = np.array([c for cs in candidates for c in cs], np.int64)
        if not len(pair_corner):
            return result
        described = np.unique(pair_corner)
        descriptors, valid = self.describe_levels(corners, corners.raw[described])
        row = np.searchsorted(described, pair_corner)
        landmark_descriptors = np.array([world.landmarks[int(i)].descriptor for i in landmark_ids])
        per_level = hamming(descriptors[row], landmark_descriptors[pair_landmark][:, None, :])
        pair_distance = np.where(valid[row], per_level, 1 << 16).min(axis=1)
        rivals = None if along is None or cfg.search_rival_px <= 0 else (corners.pixels, cfg.search_rival_px)
        best_corner, best_distance = _best_in_window(pair_landmark, pair_corner, pair_distance, len(landmark_ids),
                                                     cfg.local_map_ratio, cfg.local_map_max_distance, rivals)
        order = np.argsort(best_distance, kind="stable")
        order = order[best_corner[order] >= 0]
        _, first = np.unique(best_corner[order], return_index=True)  # a corner goes to its best landmark
        chosen = order[first]
        found[chosen] = corners.pixels[best_corner[chosen]]
        distance[chosen] = best_distance[chosen]
        return result


def _near_segments(corners: FrameCorners, positions: np.ndarray, T_world_cam: np.ndarray,  # noqa: N803
                   along: tuple[np.ndarray, float], band: float, K: np.ndarray) -> tuple[list[list[int]], np.ndarray]:  # noqa: N803
    """Per landmark at (S, 3) `positions`, the corners within `band` px of the segment its projection sweeps
    as the step from `along`'s origin to `T_world_cam` is scaled by 1 ∓ f (`LocalMapSearcher.search`), and
    (S,) how far from the projection they may lie (half the segment plus the band)."""
    origin, fraction = along
    ends = []
    for factor in (1.0 - fraction, 1.0 + fraction):
        pose = T_world_cam.copy()
        pose[:3, 3] = origin[:3, 3] + factor * (T_world_cam[:3, 3] - origin[:3, 3])
        ends.append(project(positions, pose, K).reshape(-1, 2))
    start, end = ends
    projected = project(positions, T_world_cam, K).reshape(-1, 2)
    ok = np.isfinite(start).all(axis=1) & np.isfinite(end).all(axis=1)
    start, end = np.where(ok[:, None], start, projected), np.where(ok[:, None], end, projected)
    middle, half = (start + end) / 2, np.linalg.norm(end - start, axis=1) / 2
    reach = half + band
    candidates = corners.tree.query_ball_point(middle, r=reach)
    kept: list[list[int]] = []
    for n, near in enumerate(candidates):
        if not near:
            kept.append([])
            continue
        points = corners.pixels[np.array(near, np.int64)]
        axis = end[n] - start[n]
        length2 = float(axis @ axis)
        t = np.clip((points - start[n]) @ axis / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(points))
        off = np.linalg.norm(points - (start[n] + t[:, None] * axis), axis=1)
        kept.append([c for c, o in zip(near, off, strict=True) if o <= band])
    return kept, reach


def _best_in_window(pair_landmark: np.ndarray, pair_corner: np.ndarray, pair_distance: np.ndarray, count: int,
                    ratio: float, max_distance: int, rivals: tuple[np.ndarray, float] | None = None,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per landmark, the corner of its window with the smallest distance if that is ≤ `max_distance` and below
    `ratio` × the second smallest (when there is one). With `rivals` = ((C, 2) corner pixels, r) the second
    is the best among corners more than r px from the best one: FAST fires on neighbouring pixels of one
    structure, whose descriptors are alike, and such a pair is no ambiguity about where the landmark is.
    Returns (count,) corner index (−1: none) and distance."""
    if rivals is not None:
        return _best_apart(pair_landmark, pair_corner, pair_distance, count, ratio, max_distance, *rivals)
    order = np.lexsort((pair_distance, pair_landmark))
    landmark, corner, dist = pair_landmark[order], pair_corner[order], pair_distance[order]
    first = np.ones(len(landmark), bool)
    first[1:] = landmark[1:] != landmark[:-1]
    second = np.zeros(len(landmark), bool)
    second[1:] = first[:-1] & ~first[1:]
    best_corner = np.full(count, -1, np.int64)
    best_distance = np.full(count, 1 << 16, np.int64)
    second_distance = np.full(count, 1 << 16, np.int64)
    best_corner[landmark[first]] = corner[first]
    best_distance[landmark[first]] = dist[first]
    second_distance[landmark[second]] = dist[second]
    good = (best_distance <= max_distance) & (best_distance < ratio * second_distance)
    best_corner[~good] = -1
    return best_corner, best_distance


def refind_by_flow(world: Map, keyframe_images: dict[int, np.ndarray], image: np.ndarray, keyframe_ids: list[int],
                   T_world_cam: np.ndarray, camera: CameraIntrinsics, config: MapConfig, tracker: TrackerConfig,
                   describer: cv2.ORB, exclude: set[int]) -> tuple[LocalMapSearch, np.ndarray]:
    """Landmarks of `keyframe_ids` (except `exclude`) re-found in this frame's (H, W) uint8 `image` with the
    tracked pose `T_world_cam` (module docstring). Each landmark inside the image is tracked by pyramidal LK
    from its pixel in the newest keyframe that observed it and has an image in `keyframe_images`, starting at
    its projection; kept when the backward track returns within `tracker.fb_threshold_px`, it lies within
    `local_map_radius_px` of its projection (the search window), its upright ORB descriptor is within
    `local_map_max_distance` of the landmark's. Returns the search (found pixels ideal) and the (S,) mask
    of the found ones that agree with the pose: reprojection error ≤ `pnp_threshold_px`."""
    seen: set[int] = set()
    for keyframe_id in keyframe_ids:
        seen |= world.keyframes[keyframe_id].landmark_ids
    landmarks = world.landmarks
    sources = {i: max((k for k in landmarks[i].observations if k in keyframe_images), default=-1)
               for i in seen - exclude if landmarks[i].descriptor is not None}
    landmark_ids = np.array(sorted(i for i, k in sources.items() if k >= 0), np.int64)
    height, width = image.shape[:2]
    projected = project(world.positions(landmark_ids), T_world_cam, camera.K).reshape(-1, 2)
    margin = DESCRIPTOR_PATCH / 2 + 1.0
    with np.errstate(invalid="ignore"):
        inside = ((projected[:, 0] >= margin) & (projected[:, 0] < width - margin) & (projected[:, 1] >= margin)
                  & (projected[:, 1] < height - margin))
    landmark_ids, projected = landmark_ids[inside], projected[inside]
    found = np.full((len(landmark_ids), 2), np.nan)
    distance = np.full(len(landmark_ids), -1, np.int64)
    radius = config.local_map_radius_px
    search = LocalMapSearch("track", np.array(keyframe_ids, np.int64), landmark_ids, projected,
                            np.full(len(landmark_ids), float(radius)), found, distance,
                            np.zeros(len(landmark_ids), bool))
    if not len(landmark_ids):
        return search, np.zeros(0, bool)

    def to_raw(pixels: np.ndarray) -> np.ndarray:
        return distort_pixels(pixels, camera) if camera.distorted else pixels

    source_of = np.array([sources[int(i)] for i in landmark_ids], np.int64)
    window = (tracker.window_px, tracker.window_px)
    for keyframe_id in np.unique(source_of):
        rows = np.flatnonzero(source_of == keyframe_id)
        start = to_raw(np.array([landmarks[int(i)].observations[int(keyframe_id)] for i in landmark_ids[rows]]))
        start = start.astype(np.float32).reshape(-1, 1, 2)
        guess = to_raw(projected[rows]).astype(np.float32).reshape(-1, 1, 2)
        previous = keyframe_images[int(keyframe_id)]
        ahead, ok, _ = cv2.calcOpticalFlowPyrLK(previous, image, start, guess.copy(), winSize=window,
                                                maxLevel=tracker.predicted_max_level,
                                                flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        back, ok_back, _ = cv2.calcOpticalFlowPyrLK(image, previous, ahead, start.copy(), winSize=window,
                                                    maxLevel=tracker.predicted_max_level,
                                                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        good = (ok.reshape(-1) == 1) & (ok_back.reshape(-1) == 1) & (
            np.linalg.norm((back - start).reshape(-1, 2), axis=1) <= tracker.fb_threshold_px)
        ideal = undistort_pixels(ahead.reshape(-1, 2).astype(np.float64), camera)
        good &= np.abs(ideal - projected[rows]).max(axis=1) <= radius
        found[rows[good]] = ideal[good]
    described = np.flatnonzero(np.isfinite(found[:, 0]))
    if len(described):
        raw = to_raw(found[described])
        keypoints = [cv2.KeyPoint(float(p[0]), float(p[1]), DESCRIPTOR_PATCH, 0.0, 0.0, 0, int(n))
                     for n, p in zip(described, raw, strict=True)]
        keypoints, descriptors = describer.compute(image, keypoints)
        kept = np.zeros(len(landmark_ids), bool)
        if descriptors is not None:
            rows = np.array([k.class_id for k in keypoints], np.int64)
            reference = np.array([landmarks[int(i)].descriptor for i in landmark_ids[rows]])
            distance[rows] = hamming(descriptors, reference)
            kept[rows] = distance[rows] <= config.local_map_max_distance
        found[~kept] = np.nan
        distance[~kept] = -1
    with np.errstate(invalid="ignore"):
        agrees = np.linalg.norm(found - projected, axis=1) <= config.pnp_threshold_px
    search.accepted[:] = agrees
    return search, agrees


def _best_apart(pair_landmark: np.ndarray, pair_corner: np.ndarray, pair_distance: np.ndarray, count: int,
                ratio: float, max_distance: int, pixels: np.ndarray, apart: float) -> tuple[np.ndarray, np.ndarray]:
    """`_best_in_window` with the ratio taken against corners more than `apart` px from the best one."""
    order = np.lexsort((pair_distance, pair_landmark))
    landmark, corner, dist = pair_landmark[order], pair_corner[order], pair_distance[order]
    first = np.ones(len(landmark), bool)
    first[1:] = landmark[1:] != landmark[:-1]
    best_corner = np.full(count, -1, np.int64)
    best_distance = np.full(count, 1 << 16, np.int64)
    best_corner[landmark[first]] = corner[first]
    best_distance[landmark[first]] = dist[first]
    far = np.linalg.norm(pixels[corner] - pixels[best_corner[landmark]], axis=1) > apart
    second_distance = np.full(count, 1 << 16, np.int64)
    np.minimum.at(second_distance, landmark[far], dist[far])
    good = (best_distance <= max_distance) & (best_distance < ratio * second_distance)
    best_corner[~good] = -1
    return best_corner, best_distance
