"""Saving a map and loading it back: a folder of Parquet tables (polars) and a small JSON header.

    header.json          {"format": "vslam-map", "version": 1, "vslam_version", "camera": {fx, fy, cx, cy,
                         width, height, model, coefficients}, "scale": gt|height|none, "source", "frames",
                         "keyframes", "landmarks", "extent_m"}
    keyframes.parquet    keyframe_id, frame_index, segment, T_world_cam (16 floats, row-major 4x4)
    features.parquet     keyframe_id, x, y, descriptor (32 bytes): each keyframe's upright ORB features
    landmarks.parquet    landmark_id, x, y, z (world), descriptor (32 bytes)
    observations.parquet landmark_id, keyframe_id, x, y (pixel in that keyframe)

World frame: the first frame's camera (x right, y down, z forward), metres unless scale is "none". A map is
refused, in one line, when its format version is unknown or its camera differs from the one it is used with.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from vslam_core.errors import SourceError
from vslam_core.loop.places import KeyframePlace
from vslam_core.mapping.map import Map
from vslam_core.sources.base import CameraIntrinsics

FORMAT = "vslam-map"
VERSION = 1
CAMERA_TOLERANCE_PX = 0.5  # intrinsics may differ by this much (rounding in calibration files)


class MapFileError(SourceError):
    """A map folder that cannot be used (missing, unreadable, unknown version, another camera)."""


@dataclass
class StoredMap:
    """A map as saved. K keyframes, F features, L landmarks, O observations."""

    header: dict[str, Any]
    keyframe_ids: np.ndarray  # (K,) int64
    frame_indices: np.ndarray  # (K,) int64 source frame of each keyframe
    segments: np.ndarray  # (K,) int64
    poses: np.ndarray  # (K, 4, 4) T_world_cam
    feature_keyframes: np.ndarray  # (F,) int64
    feature_pixels: np.ndarray  # (F, 2) float32
    feature_descriptors: np.ndarray  # (F, 32) uint8
    landmark_ids: np.ndarray  # (L,) int64
    landmark_positions: np.ndarray  # (L, 3) world
    landmark_descriptors: np.ndarray  # (L, 32) uint8
    observation_landmarks: np.ndarray  # (O,) int64
    observation_keyframes: np.ndarray  # (O,) int64
    observation_pixels: np.ndarray  # (O, 2) float32


def camera_dict(camera: CameraIntrinsics) -> dict[str, Any]:
    return {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "width": camera.width,
            "height": camera.height, "model": camera.model, "coefficients": list(camera.coefficients)}


def extent(positions: np.ndarray) -> list[float]:
    """(3,) size of the axis-aligned box around (N, 3) positions (zeros when empty)."""
    if not len(positions):
        return [0.0, 0.0, 0.0]
    return [float(v) for v in positions.max(axis=0) - positions.min(axis=0)]


def save_map(path: Path, stored: StoredMap) -> None:
    """Write `stored` into the folder `path` (created; an existing map there is refused by the caller)."""
    path.mkdir(parents=True, exist_ok=True)
    pl.DataFrame({
        "keyframe_id": stored.keyframe_ids, "frame_index": stored.frame_indices, "segment": stored.segments,
        "T_world_cam": stored.poses.reshape(-1, 16).tolist(),
    }, schema={"keyframe_id": pl.Int64, "frame_index": pl.Int64, "segment": pl.Int64,
               "T_world_cam": pl.Array(pl.Float64, 16)}).write_parquet(path / "keyframes.parquet")
    pl.DataFrame({
        "keyframe_id": stored.feature_keyframes, "x": stored.feature_pixels[:, 0], "y": stored.feature_pixels[:, 1],
        "descriptor": [bytes(d) for d in stored.feature_descriptors],
    }, schema={"keyframe_id": pl.Int64, "x": pl.Float32, "y": pl.Float32,
               "descriptor": pl.Binary}).write_parquet(path / "features.parquet")
    pl.DataFrame({
        "landmark_id": stored.landmark_ids, "x": stored.landmark_positions[:, 0],
        "y": stored.landmark_positions[:, 1], "z": stored.landmark_positions[:, 2],
        "descriptor": [bytes(d) for d in stored.landmark_descriptors],
    }, schema={"landmark_id": pl.Int64, "x": pl.Float64, "y": pl.Float64, "z": pl.Float64,
               "descriptor": pl.Binary}).write_parquet(path / "landmarks.parquet")
    pl.DataFrame({
        "landmark_id": stored.observation_landmarks, "keyframe_id": stored.observation_keyframes,
        "x": stored.observation_pixels[:, 0], "y": stored.observation_pixels[:, 1],
    }, schema={"landmark_id": pl.Int64, "keyframe_id": pl.Int64, "x": pl.Float32,
               "y": pl.Float32}).write_parquet(path / "observations.parquet")
    header = {**stored.header, "format": FORMAT, "version": VERSION, "keyframes": len(stored.keyframe_ids),
              "landmarks": len(stored.landmark_ids), "extent_m": extent(stored.landmark_positions)}
    (path / "header.json").write_text(json.dumps(header, indent=2) + "\n")


def read_header(path: Path) -> dict[str, Any]:
    """The header of the map folder `path`; `MapFileError` (one line) if it is not a map this version reads."""
    header_file = path / "header.json"
    if not path.is_dir() or not header_file.is_file():
        raise MapFileError(f"{path}: not a map folder (no header.json)")
    try:
        header = json.loads(header_file.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MapFileError(f"{path}: unreadable map header ({exc.__class__.__name__})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise MapFileError(f"{path}: not a vslam map (header format {header.get('format')!r})"
                           if isinstance(header, dict) else f"{path}: not a vslam map")
    if header.get("version") != VERSION:
        raise MapFileError(f"{path}: map format version {header.get('version')!r} is not supported (this vslam "
                           f"reads version {VERSION})")
    return header


def camera_problem(header: dict[str, Any], camera: CameraIntrinsics) -> str | None:
    """Why the map's camera is not `camera`, if it is not."""
    saved = header.get("camera") or {}
    mine = camera_dict(camera)
    if (saved.get("width"), saved.get("height")) != (mine["width"], mine["height"]):
        return (f"the map was made with a {saved.get('width')}x{saved.get('height')} camera, this source's is "
                f"{mine['width']}x{mine['height']}")
    for key in ("fx", "fy", "cx", "cy"):
        if not isinstance(saved.get(key), int | float) or abs(saved[key] - mine[key]) > CAMERA_TOLERANCE_PX:
            return f"the map was made with another camera ({key} {saved.get(key)} vs {mine[key]})"
    if saved.get("model", "none") != mine["model"]:
        return f"the map was made with another lens model ({saved.get('model')} vs {mine['model']})"
    return None


def load_map(path: Path, camera: CameraIntrinsics) -> StoredMap:
    """Read the map folder `path` for use with `camera`; `MapFileError` (one line) if it cannot be."""
    header = read_header(path)
    if (problem := camera_problem(header, camera)) is not None:
        raise MapFileError(f"{path}: {problem}")
    try:
        keyframes = pl.read_parquet(path / "keyframes.parquet")
        features = pl.read_parquet(path / "features.parquet")
        landmarks = pl.read_parquet(path / "landmarks.parquet")
        observations = pl.read_parquet(path / "observations.parquet")
    except (OSError, pl.exceptions.PolarsError) as exc:
        raise MapFileError(f"{path}: unreadable map table ({str(exc).splitlines()[0]})") from None
    return StoredMap(
        header=header,
        keyframe_ids=keyframes["keyframe_id"].to_numpy().astype(np.int64),
        frame_indices=keyframes["frame_index"].to_numpy().astype(np.int64),
        segments=keyframes["segment"].to_numpy().astype(np.int64),
        poses=np.array(keyframes["T_world_cam"].to_list(), np.float64).reshape(-1, 4, 4),
        feature_keyframes=features["keyframe_id"].to_numpy().astype(np.int64),
        feature_pixels=np.stack([features["x"].to_numpy(), features["y"].to_numpy()], axis=1).astype(np.float32),
        feature_descriptors=_descriptors(features["descriptor"]),
        landmark_ids=landmarks["landmark_id"].to_numpy().astype(np.int64),
        landmark_positions=np.stack([landmarks[c].to_numpy() for c in "xyz"], axis=1).astype(np.float64),
        landmark_descriptors=_descriptors(landmarks["descriptor"]),
        observation_landmarks=observations["landmark_id"].to_numpy().astype(np.int64),
        observation_keyframes=observations["keyframe_id"].to_numpy().astype(np.int64),
        observation_pixels=np.stack([observations["x"].to_numpy(), observations["y"].to_numpy()],
                                    axis=1).astype(np.float32),
    )


def _descriptors(column: pl.Series) -> np.ndarray:
    """(N, 32) uint8 from a column of 32-byte values."""
    values = column.to_list()
    if not values:
        return np.zeros((0, 32), np.uint8)
    return np.frombuffer(b"".join(values), np.uint8).reshape(len(values), -1)


def snapshot(map_: Map, places: dict[int, KeyframePlace], frame_indices: list[int],
             header: dict[str, Any]) -> StoredMap:
    """The map as it is after a run: every keyframe with its features (from loop closing's place database),
    the map's landmarks, and the landmarks it forgot to bound its memory (from the keyframes that saw them,
    moved with those keyframes' final poses). `frame_indices`: source frame index of each run position."""
    keyframes = list(map_.keyframes.values())
    landmark_rows: dict[int, tuple[np.ndarray, np.ndarray]] = {
        i: (landmark.position, landmark.descriptor) for i, landmark in map_.landmarks.items()
        if landmark.descriptor is not None}
    observations: dict[tuple[int, int], np.ndarray] = {
        (i, k): pixel for i in landmark_rows for k, pixel in map_.landmarks[i].observations.items()}
    for keyframe_id in sorted(places, reverse=True):  # the newest keyframe that saw a forgotten landmark
        place = places[keyframe_id]
        keyframe = map_.keyframes.get(keyframe_id)
        if keyframe is None:
            continue
        world = place.points_cam @ keyframe.T_world_cam[:3, :3].T + keyframe.T_world_cam[:3, 3]
        for n, landmark_id in enumerate(place.point_ids.tolist()):
            if landmark_id not in map_.landmarks:
                landmark_rows.setdefault(landmark_id, (world[n], place.point_descriptors[n]))
                observations.setdefault((landmark_id, keyframe_id), place.point_pixels[n])
    ids = sorted(landmark_rows)
    pairs = sorted(k for k in observations if k[0] in landmark_rows)
    with_features = [places[k.id] for k in keyframes if k.id in places]
    return StoredMap(
        header=header,
        keyframe_ids=np.array([k.id for k in keyframes], np.int64),
        frame_indices=np.array([frame_indices[k.position] for k in keyframes], np.int64),
        segments=np.array([k.segment for k in keyframes], np.int64),
        poses=np.array([k.T_world_cam for k in keyframes], np.float64).reshape(-1, 4, 4),
        feature_keyframes=np.concatenate([np.full(len(p.pixels), p.keyframe_id, np.int64) for p in with_features]
                                         or [np.zeros(0, np.int64)]),
        feature_pixels=np.concatenate([p.pixels for p in with_features] or [np.zeros((0, 2), np.float32)]),
        feature_descriptors=np.concatenate([p.descriptors for p in with_features] or [np.zeros((0, 32), np.uint8)]),
        landmark_ids=np.array(ids, np.int64),
        landmark_positions=np.array([landmark_rows[i][0] for i in ids], np.float64).reshape(-1, 3),
        landmark_descriptors=np.array([landmark_rows[i][1] for i in ids], np.uint8).reshape(-1, 32),
        observation_landmarks=np.array([i for i, _ in pairs], np.int64),
        observation_keyframes=np.array([k for _, k in pairs], np.int64),
        observation_pixels=np.array([observations[p] for p in pairs], np.float32).reshape(-1, 2),
    )
