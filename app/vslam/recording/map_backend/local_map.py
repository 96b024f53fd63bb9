"""Entities of the map backend's local-map tracking by projection and its landmark lifetimes.

    /world/camera/image/local_map/projected   Points2D: the local map's landmarks projected with the
                                        predicted pose, class not re-found / re-found (off the pose: only
                                        observed by a keyframe made now) / linked (re-found within the PnP
                                        threshold: a new track follows it) (landmark_id and descriptor
                                        distance on hover in full detail); a row every frame of the map
                                        backend (empty without a search)
    /world/camera/image/local_map/windows     Boxes2D: the square search window around each projection
                                        (same classes)
    /world/camera/image/local_map/refound     LineStrips2D: projection → where the landmark was re-found
                                        (same classes)
    /local_map                          AnyValues per frame: search ("track", "relocalise", "map_search" or ""),
                                        keyframes (of the local map), projected, refound, linked, radius_px
    /map/landmark_lifetimes             AnyValues per bundle adjustment, one instance per bin: keyframes (how
                                        many keyframes observe a landmark) and landmarks (how many of the
                                        BA's landmarks are observed by that many): the histogram of
                                        landmark lifetimes

Detail levels: summary logs `/local_map` and the lifetimes; standard adds the image overlays; full adds
per-landmark hover values.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from vslam.recording.columns import ColumnBuffer, Part, kept_per_row
from vslam.recording.levels import Detail
from vslam_core.results import BundleAdjusted, LocalMapSearch
from vslam_core.sources.base import Frame

NOT_REFOUND, REFOUND, LINKED = 0, 1, 2
LOCAL_MAP_STYLE = {NOT_REFOUND: ("projected, not re-found", (150, 150, 255)),
                   REFOUND: ("re-found, off the pose (keyframe observation only)", (255, 170, 40)),
                   LINKED: ("re-found and linked to a track", (40, 220, 60))}
IMAGE_ENTITIES = ("/world/camera/image/local_map/projected", "/world/camera/image/local_map/windows",
                  "/world/camera/image/local_map/refound")


def log_static(rec: rr.RecordingStream, detail: Detail) -> None:
    """Annotation classes and styles of the local-map overlays."""
    if detail == Detail.SUMMARY:
        return
    classes = rr.AnnotationContext([(class_id, label, colour) for class_id, (label, colour) in LOCAL_MAP_STYLE.items()])
    # no class labels on the frame (the legend names the colours): a frame with few of them would show them all
    rec.log(IMAGE_ENTITIES[0], classes, rr.Points2D.from_fields(radii=2.0, show_labels=False), static=True)
    rec.log(IMAGE_ENTITIES[1], classes, rr.Boxes2D.from_fields(radii=0.5, show_labels=False), static=True)
    rec.log(IMAGE_ENTITIES[2], classes, rr.LineStrips2D.from_fields(radii=0.8, show_labels=False), static=True)


def log_searches(columns: ColumnBuffer, frames: list[Frame], searches: list[LocalMapSearch | None],
                 detail: Detail) -> None:
    """The frames' searches (empty rows for a frame without one), recorded together."""
    if not frames:
        return
    done = [s for s in searches if s is not None]
    found = np.concatenate([np.zeros(0, bool)] + [s.found_mask for s in done])
    columns.add_values("/local_map", frames, rr.AnyValues.columns,
                       search=[s.purpose if s is not None else "" for s in searches],
                       keyframes=[len(s.keyframe_ids) if s is not None else 0 for s in searches],
                       projected=[len(s.landmark_ids) if s is not None else 0 for s in searches],
                       refound=[int(s.found_mask.sum()) if s is not None else 0 for s in searches],
                       linked=[int(s.accepted.sum()) if s is not None else 0 for s in searches],
                       radius_px=[float(s.radius_px.max()) if s is not None and len(s.radius_px) else 0.0
                                  for s in searches])
    if detail == Detail.SUMMARY:
        return
    counts = [len(s.landmark_ids) if s is not None else 0 for s in searches]
    projected = np.concatenate([np.zeros((0, 2))] + [s.projected.reshape(-1, 2) for s in done]).astype(np.float32)
    radius = np.concatenate([np.zeros(0)] + [s.radius_px for s in done]).astype(np.float32)
    pixels = np.concatenate([np.zeros((0, 2))] + [s.found_pixels.reshape(-1, 2) for s in done]).astype(np.float32)
    accepted = np.concatenate([np.zeros(0, bool)] + [s.accepted for s in done])
    classes = np.where(accepted, LINKED, np.where(found, REFOUND, NOT_REFOUND)).astype(np.uint16)
    points: list[Part] = [(rr.Points2D.columns, {"positions": projected, "class_ids": classes})]
    if detail == Detail.FULL:
        ids = np.concatenate([np.zeros(0, np.int64)] + [s.landmark_ids for s in done]).astype(np.uint32)
        distance = np.concatenate([np.zeros(0, np.int64)] + [s.distance for s in done]).astype(np.int32)
        points.append((rr.AnyValues.columns, {"landmark_id": ids, "distance": distance}))
    columns.add_rows(IMAGE_ENTITIES[0], frames, *points, lengths=[counts] * len(points))
    columns.add_rows(IMAGE_ENTITIES[1], frames, (rr.Boxes2D.columns, {
        "centers": projected, "half_sizes": np.repeat(radius[:, None], 2, axis=1), "class_ids": classes}),
        lengths=[counts])
    strips = np.stack([projected[found], pixels[found]], axis=1)  # (n, 2, 2): ~100x faster than a list
    lines = kept_per_row(counts, found)
    columns.add_rows(IMAGE_ENTITIES[2], frames, (rr.LineStrips2D.columns, {
        "strips": strips, "class_ids": classes[found]}), lengths=[lines])


def lifetime_histogram(landmark_keyframes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B,) keyframe counts 0..max and (B,) number of landmarks observed by each count."""
    counts = np.bincount(np.asarray(landmark_keyframes, np.int64))
    return np.arange(len(counts), dtype=np.uint16), counts.astype(np.uint32)


def log_lifetimes(columns: ColumnBuffer, frame: Frame, ba: BundleAdjusted) -> None:
    """The histogram of keyframes per landmark of one bundle adjustment."""
    keyframes, landmarks = lifetime_histogram(ba.landmark_keyframes)
    columns.add("/map/landmark_lifetimes", frame,
                (rr.AnyValues.columns, {"keyframes": keyframes, "landmarks": landmarks}), batch=True)
