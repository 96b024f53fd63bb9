"""Entities of the map backend (`--backend map`), logged only for results that carry `FrameResult.mapping`.

    /tracking                           AnyValues per frame: mode (init, two_view, map, relocalised, lost),
                                        segment, pnp_inliers, landmarks_tracked, pnp_rejected (why PnP was
                                        not used: "" if it was, "no PnP" if it was not tried), pnp_failure
                                        (why tracking against the map gave no pose: too_few_in_view,
                                        too_few_matched, ransac, disagrees; "" when it gave one or was not
                                        tried), landmarks_in_view (local-map landmarks the prediction puts
                                        in the image, -1 not counted), landmarks_found (by the search by
                                        projection), search_radius_px (its widest window, 0 none)
    /metrics/tracking/{mode,pnp_inliers,landmarks_tracked}   per-frame series (mode numbered as in
                                        `MODE_LEVELS`: 0 lost, 1 two-view or init, 2 map, 3 relocalised)
    /metrics/map_scale/step             per frame with a pose: the distance from the previous frame's pose as
                                        tracked, in the map's units (metres with gt or height; with none the
                                        map's own scale, which should drift slowly, never reset)
    /metrics/map_scale/step_over_truth  with ground truth: that step over the ground truth's step (frames whose
                                        ground-truth step is at least `MIN_TRUTH_STEP_M`): where scale was lost
    /metrics/ba/...                     per bundle adjustment run: iterations, costs, mean/max errors, solver
                                        time, factors, culled landmarks
    /metrics/timing_ms/{pnp,relocalise,mapping}   the map backend's stages, on frames that ran them
    /world/map/keyframes/window         LineStrips3D: a frustum per keyframe of the BA window (orange) and per
                                        keyframe held fixed in the last BA (blue); re-logged at each keyframe;
                                        keyframe_id and fixed on hover
    /world/map/keyframes/retired        LineStrips3D: keyframes that left the window, logged once each at their
                                        final pose (grey; the 3-D view shows their whole past)
    /world/map/landmarks/window         Points3D: the landmarks the window sees, re-logged at each keyframe
    /world/map/landmarks/retired        Points3D: landmarks no window keyframe sees any more, logged once at
                                        their final position (whole past in the 3-D view: the cloud grows)
    /world/map/keyframe_path/<block>    LineStrips3D: every keyframe position of the map segment, as refined
                                        so far, in blocks of `PATH_BLOCK_KEYFRAMES` keyframe ids (block = id //
                                        64; each block's strip starts at the previous block's last position);
                                        a keyframe re-logs only the blocks whose positions changed (bundle
                                        adjustment's window, a loop correction), an empty row when a block
                                        leaves the path (a new segment); not /world/trajectory/estimate, which
                                        holds the poses as tracked
    /world/map/ba_residuals             Points3D: the landmarks of the last BA at their refined positions,
                                        coloured by mean reprojection error after (full detail)
    /world/camera/image/landmarks       Points2D: landmarks tracked in this frame at their tracked pixel,
                                        class PnP inlier / outlier (landmark_id on hover in full detail)
    /world/camera/image/reprojection    LineStrips2D: each landmark's projection with the pose used → its
                                        tracked pixel (the residual as a short line), same classes; at
                                        standard only the lines longer than their dot (`HIDDEN_LINE_PX`)
    /events                             keyframes, bundle adjustments, relocalisation, new map segments
    local-map search and landmark lifetimes: see app/vslam/recording/map_backend/local_map.py

Landmarks are coloured by the number of keyframes observing them, on a fixed ramp: 2 or fewer dark blue,
3 cyan, 4 green, 5 yellow, 6 orange, 7 or more red (`OBSERVATION_RAMP`). Hover: landmark_id, observations.
BA residual points use a second ramp: < 0.5 px green, < 1 px yellow, < 2 px orange, worse red, no finite
error grey (`RESIDUAL_RAMP`).

Detail levels: summary logs the tracking mode, series, events, keyframe frusta and the keyframe path (no
per-point data, nothing in the image); standard adds the landmark clouds and the image overlays without
per-point hover values; full adds those and the BA residual points.

Rows are logged where a thing changes and persist until the next row (latest-at): the window keyframes and
landmarks until the next keyframe, each block of the keyframe path until it changes, the BA residuals until
the next BA (cleared with an empty row when a new map segment starts); the image overlays get a row every
frame (empty without PnP).
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from vslam.recording.columns import ColumnBuffer, Part, add_event, kept_per_row
from vslam.recording.levels import JPEG_QUALITY, Detail
from vslam.recording.map_backend import local_map
from vslam.recording.map_backend.loops import LoopRecording
from vslam.recording.metrics import MAP_METRICS, MAP_STAGES, MAP_TIMING, map_frame_metrics
from vslam_core.results import (
    BundleAdjusted,
    FrameResult,
    LoopStep,
    MapFrame,
    MapView,
    PnPEstimate,
    TrackingMode,
)
from vslam_core.sources.base import CameraIntrinsics, Frame

FRUSTUM_DEPTH = 1.0  # metres (or baselines with --scale none) from a keyframe's centre to its image plane
WINDOW_COLOUR = (255, 160, 40)
FIXED_COLOUR = (60, 140, 255)
RETIRED_COLOUR = (150, 150, 150)
KEYFRAME_PATH_COLOUR = (255, 220, 60)
# (fewest observations, colour): a landmark takes the last row it reaches
OBSERVATION_RAMP: tuple[tuple[int, tuple[int, int, int]], ...] = (
    (0, (40, 60, 200)), (3, (0, 200, 255)), (4, (40, 220, 60)), (5, (255, 230, 0)), (6, (255, 140, 0)),
    (7, (230, 30, 30)),
)
# (residual below, colour) in pixels; worse than the last bound: red; NaN: grey
RESIDUAL_RAMP: tuple[tuple[float, tuple[int, int, int]], ...] = (
    (0.5, (40, 220, 60)), (1.0, (255, 230, 0)), (2.0, (255, 140, 0)), (np.inf, (230, 30, 30)),
)
NO_RESIDUAL_COLOUR = (120, 120, 120)
PNP_OUTLIER, PNP_INLIER = 0, 1
MIN_TRUTH_STEP_M = 0.05  # a ground-truth step shorter than this (the car stands) gives no scale ratio
#: The landmarks in the image are recorded to 1/DOT_STEPS px, their reprojection lines' ends to 1/LINE_STEPS px (a
#: line's length, the residual, within 0.35 px): no view shows finer (a KITTI frame is drawn at about half size), and
#: the file's LZ4 packs the coarser values tighter: 6.0 → 4.9 KB a frame (KITTI 05 frames 0:300, docs/recordings.md).
DOT_STEPS, LINE_STEPS = 2, 4
LANDMARK_RADIUS_PX, LINE_RADIUS_PX = 2.5, 0.8
#: At `standard` a reprojection line no longer than this is not recorded: drawn, it lies wholly inside its
#: landmark's dot of the same colour (86 % of the lines on KITTI 05 frames 0:300, 3.5 → 0.7 KB a frame at 10 Hz).
HIDDEN_LINE_PX = LANDMARK_RADIUS_PX - LINE_RADIUS_PX
#: The keyframe path is recorded in blocks of this many keyframe ids: re-logged whole at each keyframe, row k
#: would hold k points, a file growing with the square of the keyframes over hours of new road.
PATH_BLOCK_KEYFRAMES = 64
PATH_ROOT = "/world/map/keyframe_path"
PNP_STYLE = {PNP_OUTLIER: ("PnP outlier", (230, 30, 30)), PNP_INLIER: ("PnP inlier", (0, 230, 255))}


class MapRecording:
    """Buffers the map backend's entities of each frame into the recorder's column buffer."""

    def __init__(self, rec: rr.RecordingStream, columns: ColumnBuffer, intrinsics: CameraIntrinsics,
                 detail: Detail, ground_truth: np.ndarray | None = None, jpeg_quality: int = JPEG_QUALITY) -> None:
        self._rec = rec
        self._columns = columns
        self._path_blocks: dict[int, np.ndarray] = {}  # block → its strip as last recorded (not yet emptied)
        self._truth = ground_truth[:, :3, 3] if ground_truth is not None else None  # (N, 3) positions
        self._previous: tuple[int, np.ndarray] | None = None  # run position and centre of the last frame with a pose
        self._detail = detail
        self._frustum = frustum_outline(intrinsics.K, intrinsics.width, intrinsics.height, FRUSTUM_DEPTH)
        self._segment: int | None = None
        self._pending: list[tuple[Frame, FrameResult, MapFrame]] = []  # recorded at the next flush (`log_pending`)
        self._log_static(rec)
        self._loops = LoopRecording(rec, columns, detail, jpeg_quality)

    def _log_static(self, rec: rr.RecordingStream) -> None:
        for group, series in MAP_METRICS.items():
            for name, (legend, colour) in series.items():
                rec.log(f"/metrics/{group}/{name}", rr.SeriesLines(names=legend, colors=colour), static=True)
        for stage, (legend, colour) in MAP_TIMING.items():
            rec.log(f"/metrics/timing_ms/{stage}", rr.SeriesLines(names=legend, colors=colour), static=True)
        # labels "KF <id>" on hover only: drawn, the window's ~10 close keyframes' labels overlap
        rec.log("/world/map/keyframes/window", rr.LineStrips3D.from_fields(radii=0.04, show_labels=False), static=True)
        rec.log("/world/map/keyframes/retired", rr.LineStrips3D.from_fields(radii=0.02, colors=RETIRED_COLOUR),
                static=True)
        local_map.log_static(rec, self._detail)
        if self._detail == Detail.SUMMARY:
            return
        rec.log("/world/map/landmarks/window", rr.Points3D.from_fields(radii=0.06), static=True)
        rec.log("/world/map/landmarks/retired", rr.Points3D.from_fields(radii=0.04), static=True)
        classes = rr.AnnotationContext([(class_id, label, colour) for class_id, (label, colour) in PNP_STYLE.items()])
        # no class labels on the frame (the legend names the colours): a frame with few lines would show them all
        rec.log("/world/camera/image/landmarks", classes, rr.Points2D.from_fields(radii=LANDMARK_RADIUS_PX,
                                                                                  show_labels=False),
                static=True)
        rec.log("/world/camera/image/reprojection", classes, rr.LineStrips2D.from_fields(radii=LINE_RADIUS_PX,
                                                                                         show_labels=False),
                static=True)
        if self._detail == Detail.FULL:
            rec.log("/world/map/ba_residuals", rr.Points3D.from_fields(radii=0.08), static=True)

    def log_frame(self, frame: Frame, result: FrameResult, mapping: MapFrame) -> None:
        """What changes at this frame (keyframes, events, loops) now; its tracking row, series and image overlays
        with the other frames' since the last flush (`log_pending`). `frame` without its image will do."""
        self._pending.append((frame, result, mapping))
        new_segment = self._segment is not None and mapping.segment != self._segment
        self._segment = mapping.segment
        if mapping.view is not None:
            self._log_view(frame, mapping.view)
        if mapping.bundle_adjustment is not None:
            local_map.log_lifetimes(self._columns, frame, mapping.bundle_adjustment)
        if self._detail == Detail.FULL:
            if mapping.bundle_adjustment is not None:
                self._log_residuals(frame, mapping.bundle_adjustment)
            elif new_segment:  # the old map's residuals go
                self._log_residuals(frame, None)
        self._log_events(frame, mapping, new_segment)
        self._loops.log_frame(frame, result.position, mapping.loop)

    def log_pending(self) -> None:
        """The tracking rows, series, image overlays and local-map searches of the frames since the last call,
        built together (a frame at a time they were ~0.3 ms of the recording thread's Python a frame, which holds
        the engine back: docs/recordings.md)."""
        if not self._pending:
            return
        pending, self._pending = self._pending, []
        frames = [frame for frame, _, _ in pending]
        mappings = [mapping for _, _, mapping in pending]
        pnps = [mapping.pnp for mapping in mappings]
        self._columns.add_values("/tracking", frames, rr.AnyValues.columns,
                                 mode=[str(m.mode) for m in mappings], segment=[m.segment for m in mappings],
                                 pnp_inliers=[int(np.count_nonzero(p.inlier_mask)) if p is not None else 0
                                              for p in pnps],
                                 landmarks_tracked=[len(p.landmark_ids) if p is not None else 0 for p in pnps],
                                 pnp_rejected=[(p.rejected or "") if p is not None else "no PnP" for p in pnps],
                                 pnp_failure=[str(p.failure) if p is not None and p.failure is not None else ""
                                              for p in pnps],
                                 landmarks_in_view=[p.in_view if p is not None else -1 for p in pnps],
                                 landmarks_found=[p.found if p is not None else 0 for p in pnps],
                                 search_radius_px=[p.search_radius_px if p is not None else 0.0 for p in pnps],
                                 step_length=[m.step_length or "" for m in mappings])
        series: dict[str, tuple[list[Frame], list[float]]] = {}
        for frame, mapping in zip(frames, mappings, strict=True):
            for name, value in map_frame_metrics(mapping).items():
                at, values = series.setdefault(name, ([], []))
                at.append(frame)
                values.append(value)
        for group, names in MAP_METRICS.items():
            for name in names:
                if name in series:
                    self._columns.add_scalars(f"/metrics/{group}/{name}", *series[name])
        self._log_scale(pending)
        for stage in MAP_STAGES:
            timed = [(frame, result.timings_ms[stage]) for frame, result, _ in pending if stage in result.timings_ms]
            self._columns.add_scalars(f"/metrics/timing_ms/{stage}", [f for f, _ in timed], [t for _, t in timed])
        if self._detail != Detail.SUMMARY:
            self._log_images(frames, pnps)
        local_map.log_searches(self._columns, frames, [m.local_map for m in mappings], self._detail)

    @property
    def closed_loops(self) -> list[tuple[int, int]]:
        """(query frame, candidate frame) of each loop closed so far."""
        return self._loops.closed

    def log_loops_at_end(self, frame: Frame, position: int, steps: list[LoopStep]) -> None:
        """The loop searches collected when the run ended (`RunResult.loops_at_end`), at the last frame."""
        for step in steps:
            self._loops.log_frame(frame, position, step, at_end=True)

    def _log_scale(self, pending: list[tuple[Frame, FrameResult, MapFrame]]) -> None:
        """The map's scale: each frame's step in map units, and over the ground truth's step when known."""
        steps: tuple[list[Frame], list[float]] = ([], [])
        ratios: tuple[list[Frame], list[float]] = ([], [])
        for frame, result, mapping in pending:
            if mapping.mode == TrackingMode.LOST:
                continue
            centre = result.T_world_cam[:3, 3]
            previous, self._previous = self._previous, (result.position, centre.copy())
            if previous is None or mapping.mode == TrackingMode.INIT:
                continue
            step = float(np.linalg.norm(centre - previous[1]))
            steps[0].append(frame)
            steps[1].append(step)
            if self._truth is not None and result.position < len(self._truth):
                truth = float(np.linalg.norm(self._truth[result.position] - self._truth[previous[0]]))
                if truth >= MIN_TRUTH_STEP_M:
                    ratios[0].append(frame)
                    ratios[1].append(step / truth)
        self._columns.add_scalars("/metrics/map_scale/step", *steps)
        self._columns.add_scalars("/metrics/map_scale/step_over_truth", *ratios)

    def _log_view(self, frame: Frame, view: MapView) -> None:
        """Window and fixed keyframes, what retired, the landmarks and the keyframe path (at a keyframe)."""
        columns = self._columns
        full = self._detail == Detail.FULL
        ids = np.concatenate([view.window_ids, view.fixed_ids])
        poses = np.concatenate([view.window_poses, view.fixed_poses])
        fixed = np.arange(len(ids)) >= len(view.window_ids)
        colours = np.where(fixed[:, None], np.array(FIXED_COLOUR, np.uint8), np.array(WINDOW_COLOUR, np.uint8))
        columns.add("/world/map/keyframes/window", frame,
                    (rr.LineStrips3D.columns, {"strips": self._frusta(poses), "colors": colours.astype(np.uint8),
                                               "labels": [f"KF {i}" for i in ids.tolist()]}),
                    (rr.AnyValues.columns, {"keyframe_id": ids.astype(np.uint32), "fixed": fixed}),
                    batch=True)
        if len(view.retired_ids):
            columns.add("/world/map/keyframes/retired", frame,
                        (rr.LineStrips3D.columns, {"strips": self._frusta(view.retired_poses)}),
                        (rr.AnyValues.columns, {"keyframe_id": view.retired_ids.astype(np.uint32)}),
                        batch=True)
        self._log_path(frame, view)
        if self._detail == Detail.SUMMARY:
            return
        self._log_landmarks("/world/map/landmarks/window", frame, view.landmark_ids, view.landmark_positions,
                            view.landmark_observations, full)
        if len(view.retired_landmark_ids):
            self._log_landmarks("/world/map/landmarks/retired", frame, view.retired_landmark_ids,
                                view.retired_landmark_positions, view.retired_landmark_observations, full)

    def _log_path(self, frame: Frame, view: MapView) -> None:
        """The blocks of the keyframe path (`PATH_BLOCK_KEYFRAMES`) whose strips changed since they were recorded."""
        points = np.asarray(view.keyframe_path, np.float32).reshape(-1, 3)
        blocks = view.keyframe_path_ids // PATH_BLOCK_KEYFRAMES
        strips: dict[int, np.ndarray] = {}
        end: np.ndarray | None = None  # the previous block's last position: the line stays continuous
        for block in np.unique(blocks).tolist():
            part = points[blocks == block]
            strips[block] = part if end is None else np.vstack([end, part])
            end = part[-1:]
        for block in self._path_blocks.keys() - strips.keys():  # left the path: a new segment
            strips[block] = np.empty((0, 3), np.float32)
        for block, strip in sorted(strips.items()):
            recorded = self._path_blocks.get(block)
            if recorded is None and len(strip):
                self._rec.log(f"{PATH_ROOT}/{block}", rr.LineStrips3D.from_fields(
                    radii=0.08, colors=KEYFRAME_PATH_COLOUR), static=True)
            elif recorded is None or np.array_equal(recorded, strip):
                continue
            self._columns.add(f"{PATH_ROOT}/{block}", frame, (rr.LineStrips3D.columns, {"strips": strip}))
            if len(strip):
                self._path_blocks[block] = strip
            else:
                del self._path_blocks[block]

    def _log_landmarks(self, entity: str, frame: Frame, ids: np.ndarray, positions: np.ndarray,
                       observations: np.ndarray, hover: bool) -> None:
        parts: list[Part] = [(rr.Points3D.columns, {
            "positions": np.asarray(positions, np.float32).reshape(-1, 3),
            "colors": observation_colours(observations)})]
        if hover:
            parts.append((rr.AnyValues.columns, {"landmark_id": ids.astype(np.uint32),
                                                 "observations": observations.astype(np.uint16)}))
        self._columns.add(entity, frame, *parts, batch=True)

    def _frusta(self, poses: np.ndarray) -> np.ndarray:
        """(N, k, 3) float32: one strip per (4, 4) T_world_cam, the (k, 3) frustum outline moved into the world
        (one array, not N: Rerun converts a list of strips one by one, ~30 us a frame at the flush)."""
        strips = [self._frustum @ pose[:3, :3].T + pose[:3, 3] for pose in poses]
        return np.array(strips, np.float32).reshape(len(strips), *self._frustum.shape)

    def _log_images(self, frames: list[Frame], pnps: list[PnPEstimate | None]) -> None:
        """Each frame's tracked landmarks at their pixel, and a line from each projection to it (empty rows without
        PnP)."""
        tried = [p for p in pnps if p is not None]
        counts = [len(p.landmark_ids) if p is not None else 0 for p in pnps]
        observed = np.concatenate([np.zeros((0, 2))] + [p.observed.reshape(-1, 2) for p in tried]).astype(np.float32)
        projected = np.concatenate([np.zeros((0, 2))] + [p.projected.reshape(-1, 2) for p in tried]).astype(np.float32)
        inlier = np.concatenate([np.zeros(0, bool)] + [p.inlier_mask for p in tried])
        classes = np.where(inlier, PNP_INLIER, PNP_OUTLIER).astype(np.uint16)
        points: list[Part] = [(rr.Points2D.columns, {"positions": quantised(observed, DOT_STEPS),
                                                     "class_ids": classes})]
        if self._detail == Detail.FULL:
            ids = np.concatenate([np.zeros(0, np.int64)] + [p.landmark_ids for p in tried]).astype(np.uint32)
            points.append((rr.AnyValues.columns, {"landmark_id": ids}))
        self._columns.add_rows("/world/camera/image/landmarks", frames, *points, lengths=[counts] * len(points))
        drawn = np.isfinite(projected).all(axis=1)
        if self._detail != Detail.FULL:
            drawn &= np.linalg.norm(projected - observed, axis=1) > HIDDEN_LINE_PX
        # (n, 2, 2), not a list of strips: Rerun converts an array ~100x faster
        strips = quantised(np.stack([projected[drawn], observed[drawn]], axis=1), LINE_STEPS)
        lines = kept_per_row(counts, drawn)
        self._columns.add_rows("/world/camera/image/reprojection", frames,
                               (rr.LineStrips2D.columns, {"strips": strips, "class_ids": classes[drawn]}),
                               lengths=[lines])

    def _log_residuals(self, frame: Frame, ba: BundleAdjusted | None) -> None:
        """The last BA's landmarks with a finite residual, at their refined positions (None: an empty row)."""
        positions, residuals, ids = np.zeros((0, 3), np.float32), np.zeros(0, np.float32), np.zeros(0, np.uint32)
        if ba is not None:
            finite = np.isfinite(ba.landmark_residual_px)
            positions = ba.landmark_positions[finite].astype(np.float32).reshape(-1, 3)
            residuals = ba.landmark_residual_px[finite].astype(np.float32)
            ids = ba.landmark_ids[finite].astype(np.uint32)
        self._columns.add("/world/map/ba_residuals", frame,
                          (rr.Points3D.columns, {"positions": positions, "colors": residual_colours(residuals)}),
                          (rr.AnyValues.columns, {"landmark_id": ids, "residual_px": residuals}), batch=True)

    def _log_events(self, frame: Frame, mapping: MapFrame, new_segment: bool) -> None:
        columns = self._columns
        reloc = mapping.relocalisation
        if reloc is not None:
            if reloc.success:
                add_event(columns, frame, f"relocalised against keyframe {reloc.keyframe_id}: {reloc.matches} "
                          f"matches, {reloc.inliers} inliers ({reloc.candidates} landmarks searched)", "INFO")
            else:
                add_event(columns, frame, f"relocalisation failed: {reloc.matches} matches, {reloc.inliers} "
                          f"inliers ({reloc.candidates} landmarks searched)", "WARN")
        if new_segment:
            add_event(columns, frame, f"new map segment {mapping.segment} started", "WARN")
        ba = mapping.bundle_adjustment
        if ba is not None:
            span = (f"{int(ba.keyframe_ids.min())}–{int(ba.keyframe_ids.max())}" if len(ba.keyframe_ids)
                    else "(none)")
            add_event(columns, frame, f"bundle adjustment over keyframes {span} ({len(ba.fixed_keyframe_ids)} "
                      f"fixed): mean error {ba.mean_error_before:.2f} → {ba.mean_error_after:.2f} px, "
                      f"{ba.culled} culled", "DEBUG")
        if mapping.sideways_share is not None:
            add_event(columns, frame, f"a camera moving sideways (median |cos| of keyframe step and optical axis "
                      f"{mapping.sideways_share:.2f}): the map's --scale none settings from here on", "INFO")
        keyframe = mapping.keyframe
        if keyframe is not None:
            total = f", {mapping.view.landmarks_total} in the map" if mapping.view is not None else ""
            add_event(columns, frame, f"keyframe {keyframe.keyframe_id} ({keyframe.why}): "
                      f"{keyframe.observed_landmarks} landmarks seen, {keyframe.new_landmarks} new "
                      f"(rays ≥ {keyframe.min_ray_angle_deg:g}°), "
                      f"{keyframe.culled_landmarks} culled{total}", "DEBUG")


def frustum_outline(K: np.ndarray, width: int, height: int, depth: float) -> np.ndarray:  # noqa: N803
    """(11, 3) one line strip through every edge of a camera frustum (camera frame): the image rectangle at
    `depth`, then each corner joined to the centre."""
    pixels = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    rays = np.linalg.solve(K, np.column_stack([pixels, np.ones(4)]).T).T
    c0, c1, c2, c3 = rays / rays[:, 2:3] * depth
    centre = np.zeros(3)
    return np.array([c0, c1, c2, c3, c0, centre, c1, centre, c2, centre, c3])


def observation_colours(observations: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colour of each landmark from the number of keyframes observing it (`OBSERVATION_RAMP`)."""
    bounds = np.array([bound for bound, _ in OBSERVATION_RAMP])
    colours = np.array([colour for _, colour in OBSERVATION_RAMP], np.uint8)
    return colours[np.searchsorted(bounds, np.asarray(observations), side="right") - 1]


def residual_colours(residuals: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colour of each BA residual in pixels (`RESIDUAL_RAMP`; NaN grey)."""
    bounds = np.array([bound for bound, _ in RESIDUAL_RAMP])
    colours = np.array([colour for _, colour in RESIDUAL_RAMP] + [NO_RESIDUAL_COLOUR], np.uint8)
    index = np.searchsorted(bounds, np.asarray(residuals), side="right")
    return colours[np.where(np.isfinite(residuals), np.minimum(index, len(RESIDUAL_RAMP) - 1), len(RESIDUAL_RAMP))]


def quantised(pixels: np.ndarray, steps: int) -> np.ndarray:
    """`pixels` (any shape) rounded to 1/`steps` px, float32."""
    return (np.round(pixels * steps) / steps).astype(np.float32)
