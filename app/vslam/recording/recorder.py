"""`Recorder`: one run's `.rrd` file, and the entities of the odometry front end (both backends)."""

from __future__ import annotations

import re
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import rerun as rr

import vslam_core
from vslam.common import (
    OutputError,
    RecordingError,
    flatten,
    has_footer,
    markdown_table,
    metrics_row,
    write_failure,
)
from vslam.recording.columns import FLUSH_FRAMES, NO_IMAGE, ColumnBuffer, Part, add_event
from vslam.recording.drift import DriftRecording
from vslam.recording.layout import UNDISTORTED, blueprint
from vslam.recording.levels import Detail, ImageCodec
from vslam.recording.map import MapRecording
from vslam.recording.metrics import METRICS, STAGES, frame_metrics
from vslam.recording.schema import SCHEMA_VERSION
from vslam.recording.scored import log_scored, scored_line
from vslam.recording.stream import StreamStopped, close_stream, flush_or_stop, log_world, open_stream, pinhole
from vslam.recording.styles import (
    AXIS_COLOURS,
    CANDIDATE_COLOURS,
    FATE_STYLE,
    HEALTH_LEVEL_LINES,
    HEALTH_LEVELS_ROOT,
    LEGEND_ENTITY,
    NEW_CORNER_COLOUR,
    ROAD_COLOUR,
    overlay_legend,
)
from vslam_core.config import EngineConfig
from vslam_core.geometry import invert_pose
from vslam_core.lens import distort_pixels, undistortion_maps
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, FrameStatus, HealthStatus, Reason, TrackFate
from vslam_core.sources.base import Frame, FrameSource, describe_indices, shown_path, source_properties
from vslam_core.sources.calibration import describe_calibration

if TYPE_CHECKING:
    from vslam.recording.video import VideoEntity


#: How often (seconds) to check that Rerun's writer thread is still writing: a full disk stops the run this soon.
WRITE_CHECK_S = 1.0


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
        image_codec: ImageCodec = ImageCodec.JPEG,
        external: bool = False,
        live_url: str | None = None,
    ) -> None:
        """`external`: the frames come from another pipeline through the logging API (`vslam.log`), not from
        vslam's engine: no engine config is stated, and its own series (``/metrics/custom/*``) get a plot."""
        if detail == Detail.OFF:
            raise ValueError("detail 'off' writes no recording: do not build a Recorder")
        self.path = path
        self.detail = detail
        self._jpeg_quality = jpeg_quality
        # with a second core, frames are JPEG-encoded beside the engine (cv2.imencode releases the GIL)
        self._encoder = ThreadPoolExecutor(1, thread_name_prefix="vslam-jpeg") if config.threads > 1 else None
        self._gt = source.ground_truth
        self._gt_buffer: np.ndarray | None = None  # `extend_ground_truth`: room for more
        self._name = properties.get("name", source.name)
        self._source_name = source.name
        self._scale = config.scale
        # the map refines every pose after it was tracked: its errors are logged when the run ends, of the poses
        # it ended with (the ones scored: `vslam.recording.scored`)
        self._errors_at_end = config.backend == "map"
        # each frame's own error against the ground truth (drift attribution)
        self._drift = (DriftRecording(source.ground_truth, online=config.scale != "none" and not self._errors_at_end)
                       if source.ground_truth is not None else None)
        self._previous_position: np.ndarray | None = None
        self._frames = 0
        self._failed = False  # Rerun's writer stopped (full disk): reported once
        self._stuck = False  # …and a flush of it never returned: the stream must not be touched again
        self._checked_at = time.monotonic()
        undistorted = source.intrinsics.distorted and detail == Detail.FULL
        layout = blueprint(map_backend=config.backend == "map", image=detail in (Detail.FULL, Detail.STANDARD),
                           road_scale=config.scale == "height", ground_truth=source.ground_truth is not None,
                           undistorted=undistorted, own_series=external)
        self._rec = open_stream(path, properties.get("recording_id"), layout, properties.get("name", source.name),
                                live_url)
        self._columns = ColumnBuffer(self._rec)
        self._properties = {**properties, **describe_calibration(source.intrinsics), **source_properties(source),
                            "detail": str(detail), "schema_version": str(SCHEMA_VERSION)}
        # a path that is not UTF-8 (lone surrogates) cannot be stored: keep its bytes as \xff escapes
        self._properties = {k: shown_path(v) if isinstance(v, str) else v for k, v in self._properties.items()}
        self._rec.send_property("run", rr.AnyValues(**self._properties))  # type: ignore[arg-type]
        if not external:
            self._rec.send_property("config", rr.AnyValues(**flatten(config.to_dict())))
        self._intrinsics = source.intrinsics
        # a distorted lens at full detail: also the frame as the pinhole sees it (the 3-D view's geometry)
        self._undistort = undistortion_maps(source.intrinsics) if undistorted else None
        self._log_static(source)
        # --image-codec av1/h264: the frames as video streams (encoded beside the engine with a second core)
        self._videos: dict[str, VideoEntity] = {}
        if image_codec != ImageCodec.JPEG and detail in (Detail.FULL, Detail.STANDARD):
            from vslam.recording.video import VideoEntity  # here: a JPEG run never loads the encoder's module

            entities = ["/world/camera/image"] + ([UNDISTORTED] if self._undistort is not None else [])
            self._videos = {e: VideoEntity(self._rec, e, image_codec, self._encoder) for e in entities}
        # the map backend's entities (statics logged here; nothing at all is logged with the odometry backend)
        self._map = (MapRecording(self._rec, self._columns, source.intrinsics, detail, self._gt)
                     if config.backend == "map" else None)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Send the buffered columns, flush and write the footer; the file is valid afterwards. Raises
        `OutputError` if the file could not be written (full disk): it keeps what was written."""
        try:
            if not self._failed:  # after a write error nothing more reaches the file
                self._columns.flush()
                for video in self._videos.values():
                    video.flush(final=True)
                self._check_written()
        finally:
            if self._encoder is not None:
                self._encoder.shutdown(cancel_futures=True)
            close_stream(self._rec, self._stuck)
        if not self._failed and not has_footer(self.path):  # the footer itself did not fit
            raise OutputError(write_failure(self.path))

    def _check_written(self) -> None:
        """Wait until Rerun's writer thread has written what was sent (`flush_or_stop`); stop the run if not."""
        if self._failed:
            return
        self._checked_at = time.monotonic()
        try:
            flush_or_stop(self._rec, self.path)
        except StreamStopped as exc:
            self._failed, self._stuck = True, exc.stuck
            raise

    def finish(self, run: RunResult, stopped: str | None) -> None:
        """Log the run's verdict (metrics table against ground truth, when there is one) and close. `stopped`
        says why a run ended early (interrupted, bad input): the run properties and the recording name are
        then re-logged to say which frames the file really holds (``frames``, ``frame_count``, ``stopped``), as
        they are when the frame count was not known up front (the logging API, `vslam.log`)."""
        try:
            if stopped is not None or self._properties.get("frame_count") != str(run.frames):
                self._restate_frames(run, stopped)
            if self._map is not None and run.loops_at_end and run.indices:  # at the last frame's time
                self._map.log_loops_at_end(Frame(run.indices[-1], run.timestamps[-1], NO_IMAGE), run.frames - 1,
                                           run.loops_at_end)
            lines = [f"# {self._name}", "", f"{run.frames} frames, {run.held_summary}"
                     + (f" — {stopped}" if stopped else "")]
            if (placed := run.placed_summary(self._scale)) is not None:
                lines += ["", f"Placed: {placed}."]
            if self._gt is not None and run.frames > 2:
                row = metrics_row(self._source_name, self._gt[: run.frames], run.pose_array(), self._scale)
                lines += ["", markdown_table([row]), "", scored_line(run, self._scale)]
                scored = log_scored(self._rec, self._gt[: run.frames], run, self._scale, self._errors_at_end)
                if self._scale == "none":
                    lines += ["", "Every number is of the estimate after Sim(3) alignment onto the ground truth "
                              "(--scale none: no metric scale; "
                              + ("the map's own scale)." if self._map is not None else "unit steps).")]
                if self._drift is not None:
                    lines += ["", *self._drift.finish(self._rec, self._columns, scored)]
            self._rec.log("/report", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN),
                          static=True)
            self._log_health_levels(run)
        finally:
            self.close()

    def _log_health_levels(self, run: RunResult) -> None:
        """The health plot's levels by name: a constant line at 0 (ok), 1 (warn) and 2 (fail) from the first
        to the last frame (`HEALTH_LEVEL_LINES`)."""
        if not run.indices:
            return
        ends = [int(run.indices[0]), int(run.indices[-1])]
        for name, _, value, _ in HEALTH_LEVEL_LINES:
            self._rec.send_columns(f"{HEALTH_LEVELS_ROOT}/{name}", indexes=[rr.TimeColumn("frame", sequence=ends)],
                                   columns=rr.Scalars.columns(scalars=[value, value]))

    def _restate_frames(self, run: RunResult, stopped: str | None) -> None:
        """Static properties are last-write-wins: re-log them with the frames actually processed."""
        held = describe_indices(list(run.indices))
        properties = {**self._properties, "frames": held, "frame_count": str(run.frames),
                      **({"stopped": stopped} if stopped is not None else {})}
        self._name = re.sub(r"\bframes \S+", f"frames {held}", self._name, count=1)
        properties["name"] = self._name
        self._rec.send_recording_name(self._name)
        self._rec.send_property("run", rr.AnyValues(**properties))  # type: ignore[arg-type]

    def _log_static(self, source: FrameSource) -> None:
        """Pinhole, legend, and every style that does not change from frame to frame (logged once)."""
        rec = self._rec
        intr = source.intrinsics
        log_world(rec, intr)
        if self._undistort is not None:
            rec.log(UNDISTORTED, pinhole(intr), static=True)
        rec.log(
            "/world/camera/image/flow",
            rr.AnnotationContext([(int(f), label, colour) for f, (label, colour) in FATE_STYLE.items()]),
            rr.Arrows2D.from_fields(radii=0.6),
            static=True,
        )
        rec.log("/world/camera/image/corners", rr.Points2D.from_fields(radii=2.0, colors=NEW_CORNER_COLOUR),
                static=True)
        if self.detail in (Detail.FULL, Detail.STANDARD):
            rec.log(LEGEND_ENTITY, rr.TextDocument(overlay_legend(road=self._scale == "height"),
                                                   media_type=rr.MediaType.MARKDOWN), static=True)
        for name, legend, _, colour in HEALTH_LEVEL_LINES:
            rec.log(f"{HEALTH_LEVELS_ROOT}/{name}", rr.SeriesLines(names=legend, colors=colour, widths=0.5),
                    static=True)
        rec.log("/world/points", rr.Points3D.from_fields(radii=0.05, colors=(200, 200, 200)), static=True)
        rec.log("/world/road/points", rr.Points3D.from_fields(radii=0.07, colors=ROAD_COLOUR), static=True)
        rec.log("/world/road/plane", rr.LineStrips3D.from_fields(radii=0.03, colors=ROAD_COLOUR), static=True)
        rec.log("/world/camera/image/road", rr.Points2D.from_fields(radii=3.0, colors=ROAD_COLOUR), static=True)
        rec.log("/world/candidates", rr.Points3D.from_fields(colors=CANDIDATE_COLOURS),
                rr.Arrows3D.from_fields(colors=AXIS_COLOURS * len(CANDIDATE_COLOURS), radii=0.02), static=True)
        for group, series in METRICS.items():
            for name, (legend, colour) in series.items():
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)

    def log_static(self, entity: str, *archetypes: Any) -> None:
        """Log something that holds for the whole run (e.g. the prior map of `vslam run --map`)."""
        self._rec.log(entity, *archetypes, static=True)

    def log_frame(self, frame: Frame, result: FrameResult, unreported: frozenset[str] = frozenset()) -> None:
        """Buffer everything about one frame for the `frame` timeline (and `time`, when known).

        `unreported`: what the frame's producer did not report (another pipeline's frames, `vslam.log`): names of
        `METRICS` series (and ``record``: the recorder's own time, which is not the producer's), left out rather
        than recorded as zero; ``status`` also leaves out the frame's ``/health`` row. A frame whose
        `frame.image` is empty (0×0) records no image."""
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
        self._log_metrics(frame, result, unreported)
        self._log_events(frame, result)
        if result.mapping is not None:
            if self._map is None:
                self._map = MapRecording(self._rec, columns, self._intrinsics, self.detail, self._gt)
            self._map.log_frame(frame, result, result.mapping)
        if "status" not in unreported:
            columns.add("/health", frame, (rr.AnyValues.columns, {"status": str(result.health.status),
                                                                  "reasons": ",".join(result.health.reasons)}))
        timings = dict(result.timings_ms, record=(time.perf_counter() - start) * 1000.0)
        for stage in STAGES:
            if stage in timings and stage not in unreported:
                columns.add_scalar(f"/metrics/timing_ms/{stage}", frame, timings[stage])
        self._frames += 1
        if self._frames % FLUSH_FRAMES == 0:
            columns.flush()
            for video in self._videos.values():
                video.flush()
            self._check_written()
        elif time.monotonic() - self._checked_at > WRITE_CHECK_S:  # images are sent every ~1 MiB
            self._check_written()

    def log_series(self, frame: Frame, values: dict[str, float]) -> None:
        """Series of the frame's producer beyond `METRICS` (another pipeline's own, `vslam.log`):
        ``/metrics/custom/<name>``, plotted together."""
        for name, value in values.items():
            self._columns.add_scalar(f"/metrics/custom/{name}", frame, float(value))

    def extend_ground_truth(self, T_world_cam: np.ndarray) -> None:  # noqa: N803
        """Append the next frame's (4, 4) ground-truth pose, for producers that learn it frame by frame
        (`vslam.log`): the recorder was opened with an empty (0, 4, 4) ground truth. Amortised O(1)."""
        if self._gt is None:
            raise ValueError("this recording was opened without ground truth")
        count = len(self._gt)
        if self._gt_buffer is None or count == len(self._gt_buffer):
            grown = np.empty((max(64, 2 * count), 4, 4))
            grown[:count] = self._gt
            self._gt_buffer = grown
        self._gt_buffer[count] = T_world_cam
        self._gt = self._gt_buffer[: count + 1]
        if self._drift is not None:
            self._drift.gt = self._gt

    def _log_image_and_tracks(self, frame: Frame, result: FrameResult) -> None:
        columns = self._columns
        images = {"/world/camera/image": frame.image} if frame.image.size else {}
        if self._undistort is not None and frame.image.size:
            images[UNDISTORTED] = cv2.remap(frame.image, *self._undistort, cv2.INTER_LINEAR)
        for entity, image in images.items():
            if self._videos:
                self._videos[entity].add(frame, image)
                continue
            jpeg: bytes | Future[bytes] = (self._encoder.submit(self._encode, image) if self._encoder is not None
                                           else self._encode(image))
            columns.add(entity, frame, (rr.EncodedImage.columns, {"blob": jpeg, "media_type": "image/jpeg"}))
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
            pixels = distort_pixels(estimate.road_pixels, self._intrinsics)  # ideal → raw image pixels
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

    def _log_metrics(self, frame: Frame, result: FrameResult, unreported: frozenset[str]) -> None:
        values = {name: value for name, value in frame_metrics(result, self._gt).items() if name not in unreported}
        if self._scale == "none" or self._errors_at_end:  # logged at the end, of the scored poses
            values.pop("position_m", None)  # --scale none: unit steps against metres (aligned at the end)
        if self._errors_at_end:
            values.pop("heading_deg", None)
        for group, series in METRICS.items():
            for name in series:
                if name in values and group not in ("timing_ms", "drift"):  # drift: its own names
                    self._columns.add_scalar(f"/metrics/{group}/{name}", frame, values[name])
        if self._drift is not None:  # this frame's own error against the ground truth
            health = result.health
            drift = self._drift.frame_values(frame, result.position, result.T_world_cam, str(health.status),
                                             ",".join(health.reasons))
            for name, value in drift.items():
                self._columns.add_scalar(f"/metrics/drift/{name}", frame, value)

    def _log_events(self, frame: Frame, result: FrameResult) -> None:
        def event(text: str, level: str) -> None:
            add_event(self._columns, frame, text, level)

        if result.status == FrameStatus.INIT:
            event(f"initialised with {len(result.new_corners)} corners", "INFO")
        elif len(result.new_corners):
            event(f"re-detected {len(result.new_corners)} corners", "DEBUG")
        health = result.health
        if health.status != HealthStatus.OK:
            what = "used"
            if result.status == FrameStatus.HELD:
                what = "dead-reckoned" if Reason.COASTED in health.reasons else "pose held"
            event(f"{health.status} ({what}): " + ", ".join(health.reasons),
                  "ERROR" if health.status == HealthStatus.FAIL else "WARN")


def road_outline(normal: np.ndarray, height: float, half_width: float = 2.0, near: float = 4.0,
                 far: float = 20.0) -> np.ndarray:
    """(5, 3) closed outline of the plane nᵀ·X = height (camera frame) over x ∈ ±half_width, z ∈ [near, far]
    metres: the patch of road ahead that the plane describes."""
    corners = []
    for x, z in ((-half_width, near), (half_width, near), (half_width, far), (-half_width, far), (-half_width, near)):
        y = (height - normal[0] * x - normal[2] * z) / normal[1]
        corners.append((x, y, z))
    return np.array(corners)


def version_properties() -> dict[str, str]:
    return {"vslam_version": vslam_core.__version__, "opencv_version": cv2.__version__,
            "rerun_version": rr.__version__}
