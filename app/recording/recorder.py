"""Turn the engine's per-frame results into Rerun entities (the only module that logs to Rerun).

Entity layout (world = camera frame of the first frame, RDF: x right, y down, z forward):

    /world                              ViewCoordinates.RDF (static)
    /world/camera                       Transform3D T_world_cam per frame
    /world/camera/image                 Pinhole (static) + JPEG frame
    /world/camera/image/corners         Points2D: corners detected in this frame (track id on hover)
    /world/camera/image/flow            Arrows2D: previous → current position per track, class = fate,
                                        track id and age on hover (the arrow tips are the tracked corners)
    /world/candidates                   the four (R, t) decompositions of E placed at the keyframe: a point
                                        and three axes each, chirality count and chosen flag on hover
    /world/points                       triangulated inliers of this frame (world coordinates)
    /world/road/points, /world/road/plane   --scale height: the road points the plane was fitted to, and
                                        an outline of that plane ahead of the camera (world coordinates)
    /world/camera/image/road            --scale height: those road points in the image
    /world/trajectory/estimate          one line segment per frame (O(1) per frame)
    /world/trajectory/ground_truth      same, from the source's ground truth
    /metrics/...                        per-frame scalars (tracks, RANSAC, motion, error, timing_ms)
    /events                             text log: initialisation, re-detections, held frames
    /health                             per frame: status ok / fail and reason codes (for `vslam inspect`)
    /report                             static Markdown written at the end: the run's metrics table

Detail levels: full = all of it; standard = no triangulated points and no per-track hover data;
summary = no image and no per-point data (camera pose, trajectories, series, events); off = no file.

Every per-frame row is buffered and sent as columns every `FLUSH_FRAMES` frames and on close: one
`send_columns` per entity instead of one `log` per entity per frame, which cost ~80–200 µs of Python
each (~25 a frame). Styles that never change are logged once, static.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb

import vslam_core
from app.report import markdown_table, metrics_row
from app.rrd import RecordingError
from vslam_core.config import EngineConfig
from vslam_core.geometry import angle_between, invert_pose, rotation_angle
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, FrameStatus, HealthStatus, TrackFate
from vslam_core.sources.base import Frame, FrameSource

APPLICATION_ID = "vslam"
FLUSH_FRAMES = 100  # buffered columns are sent this often (and on close)
FLUSH_BYTES = 2**20  # ... or as soon as one entity holds this much (images, flow): memory stays flat
PENDING_JPEG_BYTES = 64 * 1024  # what a JPEG still being encoded counts as (a KITTI frame at q75: ~61 KB)


class Detail(StrEnum):
    FULL = "full"
    STANDARD = "standard"
    SUMMARY = "summary"
    OFF = "off"


# Legend of the flow arrows: one annotation context, so the viewer explains the colours.
FATE_STYLE: dict[TrackFate, tuple[str, tuple[int, int, int]]] = {
    TrackFate.LOST: ("lost (KLT failed / left image)", (120, 120, 120)),
    TrackFate.FB_REJECTED: ("rejected by forward–backward check", (255, 140, 0)),
    TrackFate.NOT_USED: ("tracked, no keyframe position yet", (80, 160, 255)),
    TrackFate.RANSAC_OUTLIER: ("RANSAC outlier", (230, 30, 30)),
    TrackFate.CHIRALITY_FAILED: ("failed chirality (behind a camera)", (200, 0, 200)),
    TrackFate.INLIER: ("inlier", (40, 220, 60)),
}
NEW_CORNER_COLOUR = (255, 230, 0)
CANDIDATE_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 160), (160, 255, 0)]
ROAD_COLOUR = (255, 120, 220)
AXIS_COLOURS = [(255, 60, 60), (60, 255, 60), (60, 120, 255)]  # x, y, z of each candidate's camera
ESTIMATE_COLOUR = (255, 80, 80)
GROUND_TRUTH_COLOUR = (80, 255, 120)
HEALTH_LEVELS = {HealthStatus.OK: 0, HealthStatus.WARN: 1, HealthStatus.FAIL: 2}
STAGES = ("decode", "track", "essential", "chirality", "detect", "record")

# Per-frame series, logged to /metrics/<group>/<series> only on frames that have a value (no NaN: it
# would make identical runs compare unequal). One plot per group. `vslam inspect` reads them back.
METRICS: dict[str, dict[str, tuple[str, tuple[int, int, int]]]] = {
    "tracks": {
        "alive": ("tracks alive", (40, 120, 255)),
        "new_corners": ("corners detected", NEW_CORNER_COLOUR),
        "fb_rejected": ("forward–backward rejects", (255, 140, 0)),
        "road_points": ("road points in the plane fit (--scale height)", ROAD_COLOUR),
    },
    "ransac": {
        "inliers": ("RANSAC inliers", (40, 220, 60)),
        "chirality_margin": ("chirality margin (best − 2nd)", (200, 0, 200)),
    },
    "ratio": {"inlier_ratio": ("inlier ratio", (40, 220, 60))},
    "health": {"status": ("health: 0 ok, 1 warn, 2 fail", (255, 140, 0))},
    "motion": {"rotation_deg": ("rotation (°)", (255, 200, 0)), "scale": ("step length", (0, 200, 255))},
    "road": {  # --scale height
        "measured_step": ("step from this frame's road plane (m)", (255, 140, 0)),
        "camera_height_m": ("camera height over the plane at the step used (m)", ROAD_COLOUR),
    },
    "error": {"position_m": ("position error (m)", ESTIMATE_COLOUR)},
    "angle_error": {
        "heading_deg": ("heading error (°)", (255, 80, 200)),
        "translation_direction_deg": ("translation direction error (°)", (0, 200, 255)),
    },
    "timing_ms": {
        "decode": ("decode (ms)", (150, 150, 150)),
        "track": ("track (ms)", (40, 120, 255)),
        "essential": ("essential (ms)", (230, 30, 30)),
        "chirality": ("chirality (ms)", (200, 0, 200)),
        "detect": ("detect (ms)", (255, 230, 0)),
        "record": ("record (ms)", (0, 200, 200)),
    },
}


def blueprint() -> rrb.Blueprint:
    """Frame with overlays | 3-D world with trajectories and candidates | metric plots and events."""
    whole_past = rr.VisibleTimeRange(
        "frame", start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="frame", origin="/world/camera/image"),
                rrb.Spatial3DView(
                    name="world",
                    origin="/world",
                    # follow the car from behind and above (RDF: −y is up, −z is behind)
                    eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0],
                                                   tracking_entity="/world/camera"),
                    # the trajectories keep their whole past; everything else shows the current frame
                    overrides={
                        "/world/trajectory/estimate": rrb.VisibleTimeRanges([whole_past]),
                        "/world/trajectory/ground_truth": rrb.VisibleTimeRanges([whole_past]),
                    },
                ),
                row_shares=[1, 2],
            ),
            rrb.Vertical(
                rrb.Grid(
                    rrb.TimeSeriesView(name="tracks", origin="/metrics/tracks"),
                    rrb.TimeSeriesView(name="inliers", origin="/metrics/ransac"),
                    rrb.TimeSeriesView(name="inlier ratio", origin="/metrics/ratio"),
                    rrb.TimeSeriesView(name="health", origin="/metrics/health"),
                    rrb.TimeSeriesView(name="motion", origin="/metrics/motion"),
                    rrb.TimeSeriesView(name="scale from the road", origin="/metrics/road"),
                    rrb.TimeSeriesView(name="position error (m)", origin="/metrics/error"),
                    rrb.TimeSeriesView(name="angle errors (°)", origin="/metrics/angle_error"),
                    rrb.TimeSeriesView(name="timing (ms)", origin="/metrics/timing_ms"),
                    rrb.TextLogView(name="events", origin="/events"),
                    rrb.TextDocumentView(name="report", origin="/report"),
                    grid_columns=2,
                ),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


Part = tuple[Callable[..., Any], dict[str, Any]]  # an archetype's `columns` method and one row's values


@dataclass
class _Rows:
    """Buffered rows of one entity: frame indices, timestamps, and per archetype part the values and, for a
    batch entity, the number of instances in each row."""

    columns: list[Callable[..., Any]]
    batch: bool
    frames: list[int] = field(default_factory=list)
    times: list[float | None] = field(default_factory=list)
    values: list[dict[str, list[Any]]] = field(default_factory=list)
    lengths: list[list[int]] = field(default_factory=list)
    nbytes: int = 0


class _ColumnBuffer:
    """Per-frame rows, sent with one `send_columns` per entity on `flush` (or sooner, once an entity holds
    `FLUSH_BYTES`). A row holds either one value per component (poses, scalars, text) or, with
    `batch=True`, an array of instances per component (points, arrows), which are concatenated and
    partitioned back into rows when sent."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self._rec = rec
        self._rows: dict[str, _Rows] = {}

    def add(self, entity: str, frame: Frame, *parts: Part, batch: bool = False) -> None:
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([columns for columns, _ in parts], batch,
                                              values=[{name: [] for name in v} for _, v in parts],
                                              lengths=[[] for _ in parts])
        rows.frames.append(frame.index)
        rows.times.append(frame.timestamp)
        for buffered, lengths, (_, values) in zip(rows.values, rows.lengths, parts, strict=True):
            for name, value in values.items():
                buffered[name].append(value)
                rows.nbytes += _size(value)
            if batch:
                lengths.append(len(next(iter(values.values()))))
        if rows.nbytes >= FLUSH_BYTES:
            self._send(entity, self._rows.pop(entity))

    def add_scalar(self, entity: str, frame: Frame, value: float) -> None:
        """`add` of one `Scalars` value, without the generic bookkeeping (~20 series per frame)."""
        rows = self._rows.get(entity)
        if rows is None:
            rows = self._rows[entity] = _Rows([rr.Scalars.columns], False, values=[{"scalars": []}], lengths=[[]])
        rows.frames.append(frame.index)
        rows.times.append(frame.timestamp)
        rows.values[0]["scalars"].append(value)

    def flush(self) -> None:
        for entity, rows in self._rows.items():
            self._send(entity, rows)
        self._rows.clear()

    def _send(self, entity: str, rows: _Rows) -> None:
        for values in rows.values:  # wait for values computed in the background (JPEG frames)
            for name, column in values.items():
                values[name] = [v.result() if isinstance(v, Future) else v for v in column]
        indexes = [rr.TimeColumn("frame", sequence=rows.frames)]
        times = [t for t in rows.times if t is not None]
        if len(times) == len(rows.frames):
            indexes.append(rr.TimeColumn("time", duration=times))
        columns = []
        for make, values, lengths in zip(rows.columns, rows.values, rows.lengths, strict=True):
            if rows.batch:
                columns += make(**{name: _concatenate(v) for name, v in values.items()}).partition(lengths)
            else:
                columns += make(**values)
        self._rec.send_columns(entity, indexes=indexes, columns=columns)


def _size(value: Any) -> int:
    """Rough bytes held by one buffered value."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, Future):
        return PENDING_JPEG_BYTES
    return len(value) if isinstance(value, bytes | str | list) else 8


def _concatenate(batches: list[Any]) -> Any:
    """One array (or list, for text) of the instances of all rows. Flat numeric arrays become Arrow
    arrays: `AnyValues.columns` turns a numpy array into a list of one-element lists, ~70x slower."""
    if isinstance(batches[0], np.ndarray):
        values = np.concatenate(batches)
        return pa.array(values) if values.ndim == 1 else values
    return [value for batch in batches for value in batch]


class Recorder:
    """Writes one run to a `.rrd` file. Always `close()` it (or use `with`): that writes the footer."""

    def __init__(
        self,
        path: Path,
        source: FrameSource,
        config: EngineConfig,
        properties: dict[str, str],
        detail: Detail = Detail.FULL,
        jpeg_quality: int = 75,
    ) -> None:
        if detail == Detail.OFF:
            raise ValueError("detail 'off' writes no recording: do not build a Recorder")
        self.path = path
        self.detail = detail
        self._jpeg_quality = jpeg_quality
        # with a second core, frames are JPEG-encoded beside the engine (cv2.imencode releases the GIL)
        self._encoder = ThreadPoolExecutor(1, thread_name_prefix="vslam-jpeg") if config.threads > 1 else None
        self._gt = source.ground_truth
        self._name = properties.get("name", source.name)
        self._source_name = source.name
        self._scale = config.scale
        self._previous_position: np.ndarray | None = None
        self._frames = 0
        # send_properties=False: no wall-clock start time, so two runs of the same input compare equal
        # Fewer, larger chunks than the default (0.2 s / 2 MiB): each chunk carries its own schema, and at
        # ~3 frames a chunk the schemas alone were ~16 KB per frame.
        batcher = rr.ChunkBatcherConfig(flush_tick=1.0, flush_num_bytes=8 * 2**20)
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=properties.get("recording_id"),
                                       send_properties=False, batcher_config=batcher)
        self._rec.set_log_time_enabled(False)  # reproducible files: no wall-clock column
        self._columns = _ColumnBuffer(self._rec)
        self._rec.save(path, default_blueprint=blueprint())
        self._rec.send_recording_name(properties.get("name", source.name))
        self._rec.send_property("run", rr.AnyValues(**properties, detail=str(detail)))  # type: ignore[arg-type]
        self._rec.send_property("config", rr.AnyValues(**_flatten(config.to_dict())))
        self._log_static(source)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Send the buffered columns, flush and write the footer; the file is valid afterwards."""
        try:
            self._columns.flush()
        finally:
            if self._encoder is not None:
                self._encoder.shutdown(cancel_futures=True)
            self._rec.disconnect()

    def finish(self, run: RunResult, interrupted: bool) -> None:
        """Log the run's verdict (metrics table against ground truth, when there is one) and close."""
        try:
            lines = [f"# {self._name}", "", f"{run.frames} frames, {run.held} held the previous pose"
                     + (" — interrupted" if interrupted else "")]
            if self._gt is not None and run.frames > 2:
                row = metrics_row(self._source_name, self._gt[: run.frames], run.pose_array(), self._scale)
                lines += ["", markdown_table([row])]
            self._rec.log("/report", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN),
                          static=True)
        finally:
            self.close()

    def _log_static(self, source: FrameSource) -> None:
        """Pinhole, legend, and every style that does not change from frame to frame (logged once)."""
        rec = self._rec
        intr = source.intrinsics
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
        rec.log(
            "/world/camera/image",
            rr.Pinhole(image_from_camera=intr.K, resolution=[intr.width, intr.height],
                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=1.0),
            static=True,
        )
        rec.log(
            "/world/camera/image/flow",
            rr.AnnotationContext([(int(f), label, colour) for f, (label, colour) in FATE_STYLE.items()]),
            rr.Arrows2D.from_fields(radii=0.6),
            static=True,
        )
        rec.log("/world/camera/image/corners", rr.Points2D.from_fields(radii=2.0, colors=NEW_CORNER_COLOUR),
                static=True)
        rec.log("/world/points", rr.Points3D.from_fields(radii=0.05, colors=(200, 200, 200)), static=True)
        rec.log("/world/road/points", rr.Points3D.from_fields(radii=0.07, colors=ROAD_COLOUR), static=True)
        rec.log("/world/road/plane", rr.LineStrips3D.from_fields(radii=0.03, colors=ROAD_COLOUR), static=True)
        rec.log("/world/camera/image/road", rr.Points2D.from_fields(radii=3.0, colors=ROAD_COLOUR), static=True)
        rec.log("/world/candidates", rr.Points3D.from_fields(colors=CANDIDATE_COLOURS),
                rr.Arrows3D.from_fields(colors=AXIS_COLOURS * len(CANDIDATE_COLOURS), radii=0.02), static=True)
        rec.log("/world/trajectory/estimate", rr.LineStrips3D.from_fields(colors=ESTIMATE_COLOUR, radii=0.12),
                static=True)
        rec.log("/world/trajectory/ground_truth",
                rr.LineStrips3D.from_fields(colors=GROUND_TRUTH_COLOUR, radii=0.06), static=True)
        for group, series in METRICS.items():
            for name, (legend, colour) in series.items():
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)

    def log_frame(self, frame: Frame, result: FrameResult) -> None:
        """Buffer everything about one frame for the `frame` timeline (and `time`, when known)."""
        start = time.perf_counter()
        columns = self._columns
        pose = result.T_world_cam
        columns.add("/world/camera", frame, (rr.Transform3D.columns, {"translation": pose[:3, 3],
                                                                      "mat3x3": pose[:3, :3]}))
        if self.detail in (Detail.FULL, Detail.STANDARD):
            self._log_image_and_tracks(frame, result)
            self._log_candidates(frame, result)
        if self.detail == Detail.FULL:
            points = result.points_world.astype(np.float32)
            columns.add("/world/points", frame, (rr.Points3D.columns, {"positions": points}), batch=True)
        if self._scale == "height":
            self._log_road(frame, result)
        self._log_trajectories(frame, result)
        self._log_metrics(frame, result)
        self._log_events(frame, result)
        columns.add("/health", frame, (rr.AnyValues.columns, {"status": str(result.health.status),
                                                              "reasons": ",".join(result.health.reasons)}))
        timings = dict(result.timings_ms, record=(time.perf_counter() - start) * 1000.0)
        for stage in STAGES:
            if stage in timings:
                columns.add_scalar(f"/metrics/timing_ms/{stage}", frame, timings[stage])
        self._frames += 1
        if self._frames % FLUSH_FRAMES == 0:
            columns.flush()

    def _log_image_and_tracks(self, frame: Frame, result: FrameResult) -> None:
        columns = self._columns
        jpeg: bytes | Future[bytes] = (self._encoder.submit(self._encode, frame.image) if self._encoder is not None
                                       else self._encode(frame.image))
        columns.add("/world/camera/image", frame, (rr.EncodedImage.columns, {"blob": jpeg, "media_type": "image/jpeg"}))
        full = self.detail == Detail.FULL
        corners: list[Part] = [(rr.Points2D.columns, {"positions": result.new_corners})]
        if full:
            corners.append((rr.AnyValues.columns, {"track_id": result.new_corner_ids.astype(np.uint32)}))
        columns.add("/world/camera/image/corners", frame, *corners, batch=True)
        reached = result.track_fate != TrackFate.LOST
        flow: list[Part] = [(rr.Arrows2D.columns, {
            "origins": result.track_prev[reached],
            "vectors": result.track_cur[reached] - result.track_prev[reached],
            "class_ids": result.track_fate[reached].astype(np.uint16),
        })]
        if full:
            flow.append((rr.AnyValues.columns, {"track_id": result.track_ids[reached].astype(np.uint32),
                                                "age": result.track_age[reached].astype(np.uint16)}))
        columns.add("/world/camera/image/flow", frame, *flow, batch=True)

    def _encode(self, image: np.ndarray) -> bytes:
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self._jpeg_quality])
        if not ok:
            raise RecordingError("JPEG encoding of a frame failed")
        return bytes(jpeg.tobytes())

    def _log_candidates(self, frame: Frame, result: FrameResult) -> None:
        """The four candidate poses, each at the keyframe pose moved by its (R, t): a point (the chosen one
        larger, its label listing every chirality count) and the candidate camera's axes. A frame without
        candidates logs an empty row, so the previous frame's do not linger."""
        candidates = result.candidate_poses if result.T_key_cur is not None else ()
        centres, axes = np.zeros((len(candidates), 3)), np.zeros((3 * len(candidates), 3))
        chosen = np.arange(len(candidates)) == result.chosen_candidate
        labels = [""] * len(candidates)
        if candidates:
            assert result.T_key_cur is not None
            T_w_key = result.T_world_cam @ invert_pose(result.T_key_cur)  # noqa: N806
            length = max(float(np.linalg.norm(result.T_key_cur[:3, 3])), 0.5)
            counts = ", ".join(f"#{i}: {c.in_front}" for i, c in enumerate(candidates))
            centres = np.array([T_w_key[:3, :3] @ (length * c.translation) + T_w_key[:3, 3] for c in candidates])
            axes = np.concatenate([(T_w_key[:3, :3] @ c.rotation).T * (0.8 if chosen[i] else 0.4)
                                   for i, c in enumerate(candidates)])
            # (R1, t) and (R2, t) share a centre: one label, on the chosen candidate, lists every count
            labels = [f"chosen #{i} — in front {counts}" if chosen[i] else "" for i in range(len(candidates))]
        self._columns.add(
            "/world/candidates", frame,
            (rr.Points3D.columns, {"positions": centres, "radii": np.where(chosen, 0.15, 0.08), "labels": labels}),
            (rr.Arrows3D.columns, {"origins": np.repeat(centres, 3, axis=0), "vectors": axes}),
            (rr.AnyValues.columns, {"in_front": np.array([c.in_front for c in candidates], np.int64),
                                    "chosen": chosen}),
            batch=True,
        )

    def _log_road(self, frame: Frame, result: FrameResult) -> None:
        """--scale height: the road points and plane behind this frame's step length (empty rows when the
        frame had none, so earlier ones do not linger)."""
        estimate = result.scale_estimate
        pose = result.T_world_cam
        points, pixels, outline = np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 5, 3))
        if estimate is not None:
            points = estimate.road_points @ pose[:3, :3].T + pose[:3, 3]
            pixels = estimate.road_pixels
            if estimate.plane_normal is not None and estimate.camera_height is not None:
                outline = (road_outline(estimate.plane_normal, estimate.camera_height) @ pose[:3, :3].T
                           + pose[:3, 3])[None]
        columns = self._columns
        columns.add("/world/road/points", frame, (rr.Points3D.columns, {"positions": points}), batch=True)
        columns.add("/world/road/plane", frame, (rr.LineStrips3D.columns, {"strips": list(outline)}), batch=True)
        if self.detail in (Detail.FULL, Detail.STANDARD):
            columns.add("/world/camera/image/road", frame, (rr.Points2D.columns, {"positions": pixels}), batch=True)

    def _log_trajectories(self, frame: Frame, result: FrameResult) -> None:
        """One segment per frame for the estimate and the ground truth (never the whole path again)."""
        position = result.T_world_cam[:3, 3]
        previous = self._previous_position if self._previous_position is not None else position
        self._columns.add("/world/trajectory/estimate", frame,
                          (rr.LineStrips3D.columns, {"strips": np.array([previous, position])}))
        if self._gt is not None:
            gt = self._gt[:, :3, 3]
            i = result.position
            self._columns.add("/world/trajectory/ground_truth", frame,
                              (rr.LineStrips3D.columns, {"strips": np.array([gt[max(i - 1, 0)], gt[i]])}))
        self._previous_position = position

    def _log_metrics(self, frame: Frame, result: FrameResult) -> None:
        values = frame_metrics(result, self._gt)
        for group, series in METRICS.items():
            for name in series:
                if name in values and group != "timing_ms":
                    self._columns.add_scalar(f"/metrics/{group}/{name}", frame, values[name])

    def _log_events(self, frame: Frame, result: FrameResult) -> None:
        def event(text: str, level: str) -> None:
            self._columns.add("/events", frame, (rr.TextLog.columns, {"text": f"frame {frame.index}: {text}",
                                                                      "level": level}))

        if result.status == FrameStatus.INIT:
            event(f"initialised with {len(result.new_corners)} corners", "INFO")
        elif len(result.new_corners):
            event(f"re-detected {len(result.new_corners)} corners", "DEBUG")
        health = result.health
        if health.status != HealthStatus.OK:
            what = "pose held" if result.status == FrameStatus.HELD else "used"
            event(f"{health.status} ({what}): " + ", ".join(health.reasons),
                  "ERROR" if health.status == HealthStatus.FAIL else "WARN")


def frame_metrics(result: FrameResult, ground_truth: np.ndarray | None) -> dict[str, float]:
    """The per-frame series of one result (names as in `METRICS`); absent where a frame has no value."""
    counts = result.fate_counts()
    used = counts["ransac_outlier"] + counts["chirality_failed"] + counts["inlier"]
    values: dict[str, float] = {
        "status": HEALTH_LEVELS[result.health.status],
        "alive": result.live_tracks,
        "new_corners": len(result.new_corners),
        "fb_rejected": counts["fb_rejected"],
        "inliers": counts["inlier"],
    }
    if used:
        values["inlier_ratio"] = counts["inlier"] / used
    if len(result.candidate_poses) == 4:
        in_front = sorted((c.in_front for c in result.candidate_poses), reverse=True)
        values["chirality_margin"] = in_front[0] - in_front[1]
    if result.T_key_cur is not None:
        values["rotation_deg"] = float(np.degrees(rotation_angle(result.T_key_cur[:3, :3])))
        values["scale"] = result.scale or 0.0
    estimate = result.scale_estimate
    if estimate is not None:
        values["road_points"] = len(estimate.road_points)
        if estimate.measured_step is not None and estimate.camera_height is not None:
            values["measured_step"] = estimate.measured_step
            values["camera_height_m"] = estimate.camera_height
    if ground_truth is not None:
        gt_pose = ground_truth[result.position]
        values["position_m"] = float(np.linalg.norm(gt_pose[:3, 3] - result.T_world_cam[:3, 3]))
        values["heading_deg"] = float(np.degrees(rotation_angle(gt_pose[:3, :3].T @ result.T_world_cam[:3, :3])))
        if result.T_key_cur is not None:
            gt_step = invert_pose(ground_truth[result.keyframe_position]) @ gt_pose
            values["translation_direction_deg"] = float(
                np.degrees(angle_between(gt_step[:3, 3], result.T_key_cur[:3, 3])))
    return values


def road_outline(normal: np.ndarray, height: float, half_width: float = 2.0, near: float = 4.0,
                 far: float = 20.0) -> np.ndarray:
    """(5, 3) closed outline of the plane nᵀ·X = height (camera frame) over x ∈ ±half_width, z ∈ [near, far]
    metres: the patch of road ahead that the plane describes."""
    corners = []
    for x, z in ((-half_width, near), (half_width, near), (half_width, far), (-half_width, far), (-half_width, near)):
        y = (height - normal[0] * x - normal[2] * z) / normal[1]
        corners.append((x, y, z))
    return np.array(corners)


def _flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"pose": {"seed": 0}} -> {"pose.seed": 0} for recording properties."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def version_properties() -> dict[str, str]:
    return {"vslam_version": vslam_core.__version__, "opencv_version": cv2.__version__,
            "rerun_version": rr.__version__}
