"""`Recorder`: one run's `.rrd` file, and the entities of the odometry front end (both backends)."""

from __future__ import annotations

import re
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import rerun as rr

from vslam.common import OutputError, config_columns, has_footer, markdown_table, metrics_row, write_failure
from vslam.recording.columns import FLUSH_FRAMES, FLUSH_SECONDS, NO_IMAGE, ColumnBuffer
from vslam.recording.drift import DriftRecording, FrameTrail
from vslam.recording.front_end import log_candidates, log_events, log_road, log_tracks
from vslam.recording.layout import UNDISTORTED, blueprint
from vslam.recording.levels import DEFAULT_DETAIL, IMAGE_SCALE, Detail, ImageCodec, default_jpeg_quality
from vslam.recording.map_backend import MapRecording
from vslam.recording.metrics import (
    METRICS,
    SENSOR_METRICS,
    STAGES,
    log_series,
)
from vslam.recording.overview import DriveOverview
from vslam.recording.schema import SCHEMA_VERSION
from vslam.recording.scored import log_scored, scored_line
from vslam.recording.stream import (
    StreamStopped,
    close_stream,
    flush_or_stop,
    log_world,
    open_stream,
    pinhole,
)
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
from vslam.recording.video import encode_jpeg
from vslam_core.config import EngineConfig
from vslam_core.lens import undistortion_maps
from vslam_core.pipeline import RunResult
from vslam_core.results import FrameResult, elapsed_ms
from vslam_core.sources.base import (
    Frame,
    FrameSource,
    describe_indices,
    frame_gravity,
    shown_path,
    source_properties,
)
from vslam_core.sources.calibration import describe_calibration
from vslam_core.trajectory.gt_check import GroundTruthCheck

if TYPE_CHECKING:
    from vslam.recording.video import VideoEntity


#: The entity whose row marks a frame as complete in the file (sent last: `ColumnBuffer`); `inspect` counts it.
CAMERA = "/world/camera"

#: Frames the recording thread may lag the engine by (it then waits): memory stays bounded, and a SIGKILL loses
#: at most these frames more than the last flush's ~1.5 s.
MAX_PENDING_FRAMES = 4


class Recorder:
    """Writes one run to a `.rrd` file. Always `close()` it (or use `with`): that writes the footer."""

    def __init__(
        self,
        path: Path,
        source: FrameSource,
        config: EngineConfig,
        properties: dict[str, str],
        detail: Detail = DEFAULT_DETAIL,
        jpeg_quality: int | None = None,
        image_codec: ImageCodec = ImageCodec.JPEG,
        external: bool = False,
        live_url: str | None = None,
        gt_check: GroundTruthCheck | None = None,
        own_plots: tuple[str, ...] = (),
    ) -> None:
        """`external`: the frames come from another pipeline through the logging API (`vslam.log`), not from
        vslam's engine: no engine config is stated, its own series (``/metrics/custom/*``) get a plot (and one
        per name of `own_plots`: ``/metrics/custom/<plot>/*``), its triangulated points are recorded at detail
        standard too."""
        if detail == Detail.OFF:
            raise ValueError("detail 'off' writes no recording: do not build a Recorder")
        self.path = path
        self.detail = detail
        self._external = external
        self._jpeg_quality = jpeg_quality if jpeg_quality is not None else default_jpeg_quality(detail)
        # video streams keep the source's size (their codec, not the size, makes them small)
        self._image_scale = IMAGE_SCALE[detail] if image_codec == ImageCodec.JPEG else 1.0
        # With a second core the engine's frames are recorded by a thread of their own, in order, beside the engine
        # (a frame's result and image are not changed after the engine hands them over: the loop revisit recorded on
        # 1 thread and on 2 compare equal, tests/test_loop_recording.py).
        # Not another pipeline's frames (`vslam.log`): its caller may reuse its arrays once `log_frame` returns.
        self._worker = (ThreadPoolExecutor(1, thread_name_prefix="vslam-record") if config.threads > 1 and not external
                        else None)
        self._pending: deque[Future[None]] = deque()
        # … else frames are JPEG-encoded beside the caller (cv2.imencode releases the GIL); video streams always are
        self._encoder = (ThreadPoolExecutor(1, thread_name_prefix="vslam-jpeg")
                         if config.threads > 1 and (self._worker is None or image_codec != ImageCodec.JPEG) else None)
        self._gt = source.ground_truth
        self._gt_check = gt_check  # a frame sink run before this one: each frame's figures, then the run's
        self._gt_buffer: np.ndarray | None = None  # `extend_ground_truth`: room for more
        self._name = properties.get("name", source.name)
        self._source_name = source.name
        self._scale = config.scale
        # the map refines every pose after it was tracked: its errors are logged when the run ends, of the poses
        # it ended with (the ones scored: `vslam.recording.scored`)
        self._errors_at_end = config.backend == "map"
        # ... and --scale none's position error (unit steps against metres: of the Sim(3)-aligned poses at the end)
        self._errors_logged_at_end = frozenset(
            {"position_m", "heading_deg"} if self._errors_at_end else {"position_m"} if config.scale == "none" else ())
        # each frame's own error against the ground truth (drift attribution)
        self._trail = FrameTrail()  # each frame's index, position and health: for the drift and the overview
        self._drift = (DriftRecording(source.ground_truth, online=config.scale != "none" and not self._errors_at_end,
                                      trail=self._trail) if source.ground_truth is not None else None)
        self._previous_position: np.ndarray | None = None
        # frames (without their image), results and the series each leaves out: drawn at the next flush
        self._pending_rows: list[tuple[Frame, FrameResult, frozenset[str]]] = []
        self._overview = DriveOverview(self._trail)
        self._frames = 0
        self._failed = False  # Rerun's writer stopped (full disk): reported once
        self._stuck = False  # …and a flush of it never returned: the stream must not be touched again
        self._closed = False  # `close` (or `finish`) ran: a second call does nothing
        self._flushed_at = time.monotonic()
        undistorted = source.intrinsics.distorted and detail == Detail.FULL
        layout = blueprint(map_backend=config.backend == "map", image=detail in (Detail.FULL, Detail.STANDARD),
                           road_scale=config.scale == "height", ground_truth=source.ground_truth is not None,
                           undistorted=undistorted, own_series=external, own_plots=own_plots,
                           accelerometer=bool(frame_gravity(source)))
        self._rec = open_stream(path, properties.get("recording_id"), layout, properties.get("name", source.name),
                                live_url)
        self._columns = ColumnBuffer(self._rec, last=CAMERA, background=config.threads > 1)
        self._properties = {**properties, **describe_calibration(source.intrinsics), **source_properties(source),
                            "detail": str(detail), "schema_version": str(SCHEMA_VERSION)}
        # a path that is not UTF-8 (lone surrogates) cannot be stored: keep its bytes as \xff escapes
        self._properties = {k: shown_path(v) if isinstance(v, str) else v for k, v in self._properties.items()}
        self._rec.send_property("run", rr.AnyValues(**self._properties))  # type: ignore[arg-type]
        if not external:
            self._rec.send_property("config", rr.AnyValues(**config_columns(config.to_dict())))  # type: ignore[arg-type]
        self._intrinsics = source.intrinsics
        self._gravity = frame_gravity(source)  # source frame index -> (3,) m/s² in the camera frame
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
        self._map = (MapRecording(self._rec, self._columns, source.intrinsics, detail, self._gt,
                                  self._jpeg_quality)
                     if config.backend == "map" else None)
        self._check_written()  # the properties on disk before the first frame: a run killed in it says what it was

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def close(self) -> None:
        """Send the buffered columns, flush and write the footer; the file is valid afterwards. Raises
        `OutputError` if the file could not be written (full disk): it keeps what was written. Once only (`finish`
        closes it, and so does leaving its ``with`` block)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._sync()
            self._columns.wait()  # a write error of a flush in the background is raised here
            if not self._failed:  # after a write error nothing more reaches the file
                for video in self._videos.values():
                    video.flush(final=True)
                self._log_pending()
                self._columns.flush()
                self._columns.wait()
                self._check_written()
        finally:
            if self._worker is not None:
                self._worker.shutdown(wait=True, cancel_futures=True)
            self._columns.close()
            if self._encoder is not None:
                self._encoder.shutdown(cancel_futures=True)
            close_stream(self._rec, self._stuck)
        if not self._failed and not has_footer(self.path):  # the footer itself did not fit
            raise OutputError(write_failure(self.path))

    def _check_written(self) -> None:
        """Wait until Rerun's writer thread has written what was sent (`flush_or_stop`); stop the run if not."""
        if self._failed:
            return
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
            self._sync()
            self._log_pending()  # its rows before `DriftRecording.finish` reads them
            if stopped is not None or self._properties.get("frame_count") != str(run.frames):
                self._restate_frames(run, stopped)
            if self._map is not None and run.loops_at_end and run.indices:  # at the last frame's time
                self._map.log_loops_at_end(Frame(run.indices[-1], run.timestamps[-1], NO_IMAGE), run.frames - 1,
                                           run.loops_at_end)
            aligned: np.ndarray | None = None  # the scored estimate, with ground truth
            row: dict[str, Any] | None = None
            lines = [f"# {self._name}", "", f"{run.frames} frames, {run.held_summary}"
                     + (f" — {stopped}" if stopped else "")]
            if (road := run.road_summary) is not None:
                lines += ["", f"Road plane: {road}."]
            if (placed := run.placed_summary(self._scale)) is not None:
                lines += ["", f"Placed: {placed}."]
            if (settings := run.settings_summary(self._scale)) is not None:
                lines += ["", f"Settings: {settings}."]
            if (adjusted := run.adjusted_summary) is not None:
                lines += ["", f"Adjusted: {adjusted}."]
            if self._gt is not None and run.frames > 2:
                row = metrics_row(self._source_name, self._gt[: run.frames], run.pose_array(), self._scale)
                lines += ["", markdown_table([row]), "", scored_line(run, self._scale)]
                scored = log_scored(self._rec, self._gt[: run.frames], run, self._scale, self._errors_at_end)
                aligned = scored  # the overview draws the scored estimate (--scale none: Sim(3)-aligned)
                if self._scale == "none":
                    lines += ["", "Every number is of the estimate after Sim(3) alignment onto the ground truth "
                              "(--scale none: no metric scale; "
                              + ("the map's own scale)." if self._map is not None else "unit steps).")]
                if self._drift is not None:
                    lines += ["", *self._drift.finish(self._rec, self._columns, scored)]
            if self._gt_check is not None and (check := self._gt_check.summary()) is not None:
                lines += ["", f"Ground truth against the images: {check.line()}.", *(f"Warning: {w}." for w in
                                                                                     check.warnings())]
            self._rec.log("/report", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN),
                          static=True)
            self._log_overview(run, aligned, stopped, row)
            self._log_health_levels(run)
        finally:
            self.close()

    def _log_overview(self, run: RunResult, aligned: np.ndarray | None, stopped: str | None,
                      row: dict[str, Any] | None) -> None:
        """The drive at a glance (`vslam.recording.overview`); `row`: the run's metrics, with ground truth."""
        headline = [self._name, f"{run.frames} frames, {run.held_summary}" + (f" — {stopped}" if stopped else "")]
        if row is not None:
            headline.append(f"t_err {row['t_err']:.2f} %, ATE {row['ate_sim3']:.3f} m after Sim(3) ({self._scale})")
        for query, candidate in self._map.closed_loops if self._map is not None else ():
            self._overview.add_loop(query, candidate)
        self._overview.finish(self._rec, headline, estimate=None if aligned is None else aligned[:, :3, 3],
                              ground_truth=None if self._gt is None else self._gt[: run.frames, :3, 3],
                              errors=self._drift.errors if self._drift is not None else None)

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
        log_world(rec, intr, self._image_scale)
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
        sensors = SENSOR_METRICS if self._gravity else {}
        for group, series in {**METRICS, **sensors}.items():
            for name, (legend, colour) in series.items():
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)

    def log_static(self, entity: str, *archetypes: Any) -> None:
        """Log something that holds for the whole run (e.g. the prior map of `vslam run --map`)."""
        self._sync()
        self._rec.log(entity, *archetypes, static=True)

    def log_frame(self, frame: Frame, result: FrameResult, unreported: frozenset[str] = frozenset()) -> None:
        """Buffer everything about one frame for the `frame` timeline (and `time`, when known).

        `unreported`: what the frame's producer did not report (another pipeline's frames, `vslam.log`): names of
        `METRICS` series (and ``record``: the recorder's own time, which is not the producer's), left out rather
        than recorded as zero; ``status`` also leaves out the frame's ``/health`` row. A frame whose
        `frame.image` is empty (0×0) records no image. With a recording thread the frame is recorded there: an
        error of an earlier frame's recording (a full disk) is raised here."""
        if self._worker is None:
            self._log_frame(frame, result, unreported)
            return
        while self._pending and (self._pending[0].done() or len(self._pending) >= MAX_PENDING_FRAMES):
            self._wait_oldest()
        self._pending.append(self._worker.submit(self._log_frame, frame, result, unreported))

    def _sync(self) -> None:
        """Wait until the recording thread has recorded every frame handed to it; raise its first error."""
        while self._pending:
            self._wait_oldest()

    def _wait_oldest(self) -> None:
        """Wait for the oldest frame handed over, and raise its error once. Interrupted (Ctrl-C) it stays
        pending: `finish` waits for it before it touches what that frame's recording writes to."""
        job = self._pending[0]
        try:
            job.result()
        finally:
            if job.done():
                self._pending.popleft()

    def _log_frame(self, frame: Frame, result: FrameResult, unreported: frozenset[str]) -> None:
        start = time.perf_counter()
        columns = self._columns
        columns.raise_failed()  # a write that failed (full disk) stops the run now, not at the next flush
        pose = result.T_world_cam
        columns.add(CAMERA, frame, (rr.Transform3D.columns, {"translation": pose[:3, 3],
                                                                      "mat3x3": pose[:3, :3]}))
        if self.detail in (Detail.FULL, Detail.STANDARD):
            self._log_images(frame)
        if self.detail == Detail.FULL or (self._external and self.detail == Detail.STANDARD
                                          and len(result.points_world)):
            points = result.points_world.astype(np.float32)
            columns.add("/world/points", frame, (rr.Points3D.columns, {"positions": points}), batch=True)
        if self._scale == "height":
            log_road(self._columns, frame, result, self._intrinsics,
                     image=self.detail in (Detail.FULL, Detail.STANDARD))
        self._log_trajectories(frame, result)
        # the series, tracks and candidate poses of the frames since the last flush are drawn together (`_log_pending`)
        light = Frame(frame.index, frame.timestamp, NO_IMAGE)  # kept till then: not its image
        self._pending_rows.append((light, result, unreported | self._errors_logged_at_end))
        if self._external:  # another pipeline may reuse its arrays once `log_frame` returns
            self._log_pending(drift=False)
        if self._drift is not None:  # this frame's own error against the ground truth: at the flush (`_log_pending`)
            self._drift.add(frame, result.position, result.T_world_cam)
        if (gravity := self._gravity.get(frame.index)) is not None:
            for axis, value in zip(SENSOR_METRICS["accelerometer"], gravity, strict=True):
                columns.add_scalar(f"/metrics/accelerometer/{axis}", frame, float(value))
        log_events(self._columns, frame, result)
        if result.mapping is not None:
            if self._map is None:
                self._map = MapRecording(self._rec, columns, self._intrinsics, self.detail, self._gt,
                                         self._jpeg_quality)
            self._map.log_frame(light, result, result.mapping)
        self._trail.add(frame, pose[:3, 3], *(("not reported", "") if "status" in unreported else
                                              (str(result.health.status), ",".join(result.health.reasons))))
        if "status" not in unreported:
            columns.add("/health", frame, (rr.AnyValues.columns, {"status": str(result.health.status),
                                                                  "reasons": ",".join(result.health.reasons)}))
        timings = dict(result.timings_ms, record=elapsed_ms(start))
        for stage in STAGES:
            if stage in timings and stage not in unreported:
                columns.add_scalar(f"/metrics/timing_ms/{stage}", frame, timings[stage])
        self._frames += 1
        if self._frames % FLUSH_FRAMES == 0 or time.monotonic() - self._flushed_at >= FLUSH_SECONDS:
            self._flush()

    def flush(self) -> None:
        """Send every buffered row and wait until Rerun's writer thread has written it to the file (in the
        kernel: a SIGKILL keeps it; not an fsync). Every `FLUSH_SECONDS` (or `FLUSH_FRAMES`) during a run, so a
        killed run loses at most about that much, and a full disk stops the run that soon. The video samples
        go first and the camera poses last: a frame with a pose in the file is whole. With a second core the
        columns are built, sent and waited for on the sending thread (`ColumnBuffer`), beside the engine; its
        write error stops the run at the next frame recorded."""
        self._sync()
        self._flush()

    def _flush(self) -> None:
        self._flushed_at = time.monotonic()
        self._log_pending()
        for video in self._videos.values():
            video.flush()
        self._columns.flush(then=self._check_written)

    @property
    def stream(self) -> rr.RecordingStream:
        """The Rerun stream this recorder writes (the logging API hands it to a pipeline, `vslam.log`)."""
        return self._rec

    def log_series(self, frame: Frame, values: dict[str, float], root: str = "/metrics/custom") -> None:
        """Series of the frame's producer beyond `METRICS` (another pipeline's own, `vslam.log`):
        ``<root>/<name>`` (a name may hold its plot: ``plot/name``); its own stages with root
        ``/metrics/timing_ms``."""
        self._sync()
        for name, value in values.items():
            self._columns.add_scalar(f"{root}/{name}", frame, float(value))

    def extend_ground_truth(self, T_world_cam: np.ndarray) -> None:  # noqa: N803
        """Append the next frame's (4, 4) ground-truth pose, for producers that learn it frame by frame
        (`vslam.log`): the recorder was opened with an empty (0, 4, 4) ground truth. Amortised O(1)."""
        if self._gt is None:
            raise ValueError("this recording was opened without ground truth")
        self._sync()
        count = len(self._gt)
        if self._gt_buffer is None or count == len(self._gt_buffer):
            grown = np.empty((max(64, 2 * count), 4, 4))
            grown[:count] = self._gt
            self._gt_buffer = grown
        self._gt_buffer[count] = T_world_cam
        self._gt = self._gt_buffer[: count + 1]
        if self._drift is not None:
            self._drift.gt = self._gt

    def _log_images(self, frame: Frame) -> None:
        columns = self._columns
        images = {"/world/camera/image": frame.image} if frame.image.size else {}
        if self._undistort is not None and frame.image.size:
            images[UNDISTORTED] = cv2.remap(frame.image, *self._undistort, cv2.INTER_LINEAR)
        for entity, image in images.items():
            if self._videos:
                self._videos[entity].add(frame, image)
                continue
            encoding = (image, self._image_scale, self._jpeg_quality)
            jpeg: bytes | Future[bytes] = (self._encoder.submit(encode_jpeg, *encoding) if self._encoder is not None
                                           else encode_jpeg(*encoding))
            columns.add(entity, frame, (rr.EncodedImage.columns, {"blob": jpeg, "media_type": "image/jpeg"}))

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

    def _log_pending(self, drift: bool = True) -> None:
        """What is drawn for the frames recorded since the last flush, together (a frame at a time it was ~0.6 ms
        of the recording thread's Python a frame, which holds the engine back: docs/recordings.md): the map's rows
        (`MapRecording.log_pending`), the series (`METRICS`), tracks and candidate poses, and the drift series."""
        if self._map is not None:
            self._map.log_pending()
        if self._pending_rows:
            frames, results, left_out = (list(column) for column in zip(*self._pending_rows, strict=True))
            self._pending_rows = []
            if self.detail in (Detail.FULL, Detail.STANDARD):
                log_tracks(self._columns, frames, results, full=self.detail == Detail.FULL)
                log_candidates(self._columns, frames, results)
            log_series(self._columns, frames, results, left_out, self._gt, self._gt_check)
        if self._drift is not None and drift:
            self._drift.log_series(self._columns)

