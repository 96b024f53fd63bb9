"""The named arrays of the logging API (`vslam.log`): tracks, corners, the four candidate poses and triangulated
points, each checked with a one-line error that says which shape was expected.

Pixels are raw-image pixels (x right, y down); poses follow the schema (T_world_cam, camera axes RDF).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam_core.geometry import CandidatePose

__all__ = ["Candidates", "Corners", "Tracks", "candidate_poses", "corner_arrays", "points_array", "track_arrays"]


@dataclass(frozen=True)
class Tracks:
    """Tracks (or matches) from the previous frame into this one, one row each: `ids` (M,) int (a track keeps
    its id from frame to frame: its age is counted from it), `prev` (M, 2) pixels in the previous frame, `cur`
    (M, 2) pixels in this frame."""

    ids: Any
    prev: Any
    cur: Any


@dataclass(frozen=True)
class Corners:
    """Corners detected in this frame: `px` (K, 2) pixels and, for ``detail="full"`` (shown on hover), `ids`
    (K,) int."""

    px: Any
    ids: Any = None


@dataclass(frozen=True)
class Candidates:
    """The four poses an essential matrix decomposes into, as steps T_prev_cur (X_prev = R·X_cur + t):
    `rotations` (4, 3, 3), unit `translations` (4, 3); `in_front` (4,) int: the points triangulated in front of
    both cameras under each (the chirality check; the margin is the best count minus the second); `chosen`: the
    index the pipeline kept."""

    rotations: Any
    translations: Any
    in_front: Any
    chosen: int

    @classmethod
    def from_opencv(cls, R1: Any, R2: Any, t: Any, in_front: Any, chosen: int) -> Candidates:  # noqa: N803
        """From ``R1, R2, t = cv2.decomposeEssentialMat(E)`` (X_cur = R·X_prev + t), in OpenCV's order
        (R1, t), (R1, −t), (R2, t), (R2, −t); `in_front` and `chosen` in that order."""
        t = np.asarray(t, np.float64).reshape(3)
        pairs = [(R1, t), (R1, -t), (R2, t), (R2, -t)]
        rotations = np.array([np.asarray(r, np.float64).T for r, _ in pairs])
        translations = np.array([-np.asarray(r, np.float64).T @ s for r, s in pairs])
        return cls(rotations, translations, in_front, chosen)


def _array(value: Any, dtype: type, shape: tuple[int | None, ...], what: str, expected: str) -> np.ndarray:
    """`value` as an array of `shape` (None: any length), or a ValueError naming what was expected."""
    try:
        array: np.ndarray = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise ValueError(f"{what}: expected {expected}, got {type(value).__name__}") from None
    if array.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, array.shape, strict=True)):
        raise ValueError(f"{what}: expected {expected}, got shape {array.shape}")
    if np.issubdtype(array.dtype, np.floating) and not np.isfinite(array).all():
        raise ValueError(f"{what}: expected {expected}, got values that are not finite")
    return array


def track_arrays(tracks: Any, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (M,), prev (M, 2), cur (M, 2)) of a `Tracks` or an ``(ids, prev, cur)`` tuple."""
    expected = "Tracks(ids=(M,), prev=(M, 2), cur=(M, 2)) or a tuple (ids, prev, cur)"
    if isinstance(tracks, Tracks):
        ids, prev, cur = tracks.ids, tracks.prev, tracks.cur
    elif isinstance(tracks, tuple | list) and len(tracks) == 3:
        ids, prev, cur = tracks
    else:
        raise ValueError(f"frame {index}: tracks: expected {expected}, got {type(tracks).__name__}")
    what = f"frame {index}: tracks"
    ids = _array(ids, np.int64, (None,), f"{what}.ids", "(M,) integer ids")
    prev = _array(prev, np.float32, (None, 2), f"{what}.prev", "(M, 2) pixels")
    cur = _array(cur, np.float32, (None, 2), f"{what}.cur", "(M, 2) pixels")
    if not len(ids) == len(prev) == len(cur):
        raise ValueError(f"{what}: expected M rows in each of ids, prev and cur, got {len(ids)}, {len(prev)} and "
                         f"{len(cur)}")
    return ids, prev, cur


def corner_arrays(corners: Any, index: int, full: bool) -> tuple[np.ndarray, np.ndarray]:
    """(ids (K,), pixels (K, 2)) of a `Corners`, an ``(ids, pixels)`` tuple or bare (K, 2) pixels; ids are
    needed at detail full (shown on hover)."""
    what = f"frame {index}: corners"
    if isinstance(corners, Corners):
        ids, pixels = corners.ids, corners.px
    elif isinstance(corners, tuple) and len(corners) == 2:
        ids, pixels = corners
    else:
        ids, pixels = None, corners
    named = isinstance(corners, Corners) or ids is not None
    pixels = _array(pixels, np.float32, (None, 2), f"{what}.px" if named else what, "(K, 2) pixels")
    if ids is None:
        if full:
            raise ValueError(f"{what}: detail full shows corner ids: give Corners(px=(K, 2), ids=(K,))")
        return np.zeros(len(pixels), np.int64), pixels
    ids = _array(ids, np.int64, (None,), f"{what}.ids", "(K,) integer ids")
    if len(ids) != len(pixels):
        raise ValueError(f"{what}: expected one id per corner, got {len(ids)} ids for {len(pixels)} pixels")
    return ids, pixels


def candidate_poses(candidates: Any, index: int) -> tuple[tuple[CandidatePose, ...], int]:
    """The engine's four `CandidatePose` and the chosen index, from a `Candidates`."""
    what = f"frame {index}: candidates"
    if not isinstance(candidates, Candidates):
        raise ValueError(f"{what}: expected vslam.log.Candidates(rotations=(4, 3, 3), translations=(4, 3), "
                         f"in_front=(4,), chosen=int), got {type(candidates).__name__}")
    rotations = _array(candidates.rotations, np.float64, (4, 3, 3), f"{what}.rotations", "(4, 3, 3) rotations")
    translations = _array(candidates.translations, np.float64, (4, 3), f"{what}.translations",
                          "(4, 3) unit translations")
    in_front = _array(candidates.in_front, np.int64, (4,), f"{what}.in_front", "(4,) counts")
    if not isinstance(candidates.chosen, int | np.integer) or not 0 <= int(candidates.chosen) < 4:
        raise ValueError(f"{what}.chosen: expected an index 0..3, got {candidates.chosen!r}")
    for k, rotation in enumerate(rotations):
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0:
            raise ValueError(f"{what}.rotations[{k}]: expected a rotation (orthonormal, determinant +1)")
    norms = np.linalg.norm(translations, axis=1, keepdims=True)
    units = translations / np.where(norms > 0, norms, 1.0)
    poses = tuple(CandidatePose(rotations[k], units[k], int(in_front[k])) for k in range(4))
    return poses, int(candidates.chosen)


def points_array(points: Any, index: int) -> np.ndarray:
    """(P, 3) triangulated points in the pipeline's world (metres, or its scale)."""
    return _array(points, np.float64, (None, 3), f"frame {index}: points", "(P, 3) points in the world")
