"""The default layout embedded in every recording."""

from __future__ import annotations

import rerun as rr
import rerun.blueprint as rrb

from vslam.recording.drift import DRIFT_ENTITY
from vslam.recording.metrics import BA_ERROR_SERIES, MAP_METRICS
from vslam.recording.overview import CANVAS, OVERVIEW_SUMMARY
from vslam.recording.styles import HEALTH_LEVELS_ROOT, LEGEND_ENTITY

#: Entities of the map backend that keep their whole past in the 3-D view (logged once each, they accumulate).
MAP_WHOLE_PAST = ("/world/map/keyframes/retired", "/world/map/landmarks/retired")
#: The car drawn around the camera (a static wireframe box, child of `/world/camera`): the 3-D view tracks it.
CAR_ENTITY = "/world/camera/car"
#: Where the 3-D view's eye sits relative to the car it follows (world frame, RDF: −y is up, −z is behind):
#: 15 m above and 20 m behind the start direction, 25 m away, looking ~37° down.
EYE_OFFSET = (0.0, -15.0, -20.0)
#: A distorted lens at detail full: the frame undistorted to the pinhole K, in a 2-D view of its own.
UNDISTORTED = "/world/camera/undistorted"
#: The drift series in two plots (units that fit together).
#: The levels the events view shows at first: INFO and above.
EVENT_LEVELS = ("INFO", "WARN", "ERROR", "CRITICAL")
DRIFT_PLOTS = (("drift per frame (°, m)", ("rotation_deg", "translation_m")),
               ("drift per frame (% of step, scale ratio)", ("translation_pct", "scale_ratio")))


def blueprint(map_backend: bool = False, *, image: bool = True, road_scale: bool = False,
              ground_truth: bool = True, undistorted: bool = False, engine: bool = True,
              frustum: bool = True, own_series: bool = False, own_plots: tuple[str, ...] = (),
              accelerometer: bool = False) -> rrb.Blueprint:
    """A few large views, the rest one click away in tabs, readable at 1280×720 (`vslam snapshot`'s ``all.png``):

    - left: the frame with its overlays (tabs: the overlays' legend, the undistorted frame) above the 3-D world
      following the car (tab: the whole drive from above, `vslam.recording.overview`);
    - right: tabs of plots, the first (``overview``) four single-series plots without legends (the title names the
      series), then every plot with its legend by topic (tracking, accuracy, map, timing, the pipeline's own);
    - below: the events (INFO and above) and the run's summary (tab: the full report).

    Views that would stay empty are left out: the frame without `image` (detail `summary`), "scale from the
    road" without `road_scale` (`--scale height`), the error plots without `ground_truth`. `map_backend`: the map
    (retired keyframes and landmarks keep their whole past) and the map's plots. `undistorted` (a distorted lens):
    the undistorted frame. Without `engine` (another system's trajectory, `vslam.recording.external`) only the
    error plots: there are no tracks, inliers, health or timings; without `frustum` (no camera known) the frame
    stays out of the 3-D view. `own_series`: a plot of another pipeline's own series (``/metrics/custom``,
    `vslam.log`), and one per name of `own_plots` (``/metrics/custom/<plot>/*``, kept out of the first);
    `accelerometer`: a plot of the source's accelerometer (``/metrics/accelerometer``, gravity in the camera frame)."""
    worlds = rrb.Tabs(world_view(map_backend, frustum), drive_view(), active_tab=0)
    left: list[rrb.Container] = [worlds]
    if image:
        frames = [rrb.Spatial2DView(name="frame", origin="/world/camera/image"),
                  *([rrb.Spatial2DView(name="undistorted", origin=UNDISTORTED)] if undistorted else []),
                  rrb.TextDocumentView(name="overlays", origin=LEGEND_ENTITY)]
        left.insert(0, rrb.Tabs(*frames, active_tab=0))
    plots = plot_tabs(map_backend, road_scale=road_scale, ground_truth=ground_truth, engine=engine,
                      own_series=own_series, own_plots=own_plots, accelerometer=accelerometer)
    summary = rrb.Tabs(rrb.TextDocumentView(name="summary", origin=OVERVIEW_SUMMARY),
                       rrb.TextDocumentView(name="report", origin="/report"), active_tab=0)
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(rrb.Vertical(*left, row_shares=[2, 3][-len(left):]), plots, column_shares=[3, 2]),
            # the events across the window: their messages (up to ~100 characters) fit whole
            rrb.Horizontal(events_view(), summary, column_shares=[3, 2]),
            row_shares=[5, 2],
        ),
        rrb.TimePanel(timeline="frame", state="collapsed"),  # the recordings also hold `time`: the viewer picked it
        collapse_panels=True,
    )


def plot_tabs(map_backend: bool, *, road_scale: bool, ground_truth: bool, engine: bool,
              own_series: bool, own_plots: tuple[str, ...] = (), accelerometer: bool = False) -> rrb.Tabs:
    """The plots in tabs: ``overview`` (a few single-series plots, no legend), then every plot by topic."""
    tabs: list[rrb.Container | rrb.View] = []
    if overview := _overview_plots(ground_truth, engine):
        tabs.append(rrb.Vertical(*overview, name="overview"))
    plots = _plots(road_scale, ground_truth, engine)
    timing = [p for p in plots if p.name == "timing (ms)"]
    accuracy = [p for p in plots if p.name in ACCURACY_PLOTS]  # the position error is the overview's first plot
    tracking = [p for p in plots if p not in timing and p not in accuracy and p.name != "position error (m)"]
    sensors = [rrb.TimeSeriesView(name="gravity, camera frame (m/s²)", origin="/metrics/accelerometer")] \
        if accelerometer else []
    for name, group in (("tracking", tracking), ("accuracy", accuracy),
                        ("map", _map_plots() if map_backend else []), ("sensors", sensors), ("timing", timing)):
        if group:
            tabs.append(rrb.Grid(*group, grid_columns=1 if len(group) <= 3 else 2, name=name))
    if own_series:  # another pipeline's own series (`vslam.log`): one tab, a plot per group it asked for
        own = [rrb.TimeSeriesView(name="pipeline series", origin="/metrics/custom", contents=[
            "+ $origin/**", *(f"- $origin/{plot}/**" for plot in own_plots)]),
            *(rrb.TimeSeriesView(name=plot, origin=f"/metrics/custom/{plot}") for plot in own_plots)]
        tabs.append(rrb.Grid(*own, grid_columns=1 if len(own) <= 3 else 2, name="pipeline"))
    return rrb.Tabs(*tabs, active_tab=0)


#: The plots of the ``accuracy`` tab (with ground truth).
ACCURACY_PLOTS = ("angle errors (°)", "ground truth vs the images", *(name for name, _ in DRIFT_PLOTS))


def _overview_plots(ground_truth: bool, engine: bool) -> list[rrb.TimeSeriesView]:
    """One series each, so no legend is needed (hidden: it would cover the data); the title names the series."""
    chosen = [("position error (m)", "/metrics/error/position_m")] if ground_truth else []
    if engine:
        chosen += [("rotation per frame (°)", "/metrics/motion/rotation_deg"),
                   ("step length", "/metrics/motion/scale"),
                   ("RANSAC inliers", "/metrics/ransac/inliers")]
        if not ground_truth:
            chosen.insert(0, ("health (0 ok, 1 warn, 2 fail)", "/metrics/health/status"))
    return [rrb.TimeSeriesView(name=name, origin=entity, contents=[entity], plot_legend=rrb.PlotLegend(visible=False))
            for name, entity in chosen]


def drive_view() -> rrb.Spatial2DView:
    """The whole drive from above (`vslam.recording.overview`): the path coloured by each frame's error (or health),
    the ground truth in blue, the worst stretches (white), loops (magenta) and failed frames (red) marked."""
    return rrb.Spatial2DView(name="drive", origin="/overview", contents=["+ /overview/**"],
                             visual_bounds=rrb.VisualBounds2D(x_range=[0.0, CANVAS], y_range=[0.0, CANVAS]))


def world_view(map_backend: bool, frustum: bool = True) -> rrb.Spatial3DView:
    """The 3-D world: trajectories with their whole past, the rest at the current frame; the eye follows the
    car (`CAR_ENTITY`) from `EYE_OFFSET`, at any frame. Without `frustum` the frame (no pinhole) is left out."""
    whole_past = rr.VisibleTimeRange(
        "frame", start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative()
    )
    entities = ["/world/trajectory/estimate", "/world/trajectory/ground_truth", DRIFT_ENTITY,
                *(MAP_WHOLE_PAST if map_backend else ())]
    return rrb.Spatial3DView(
        name="world",
        origin="/world",
        # the raw frame (with its overlays) is on the frustum
        contents=["+ /world/**", f"- {UNDISTORTED}/**", *([] if frustum else ["- /world/camera/image/**"])],
        eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0],
                                       position=list(EYE_OFFSET), look_target=[0.0, 0.0, 0.0],
                                       tracking_entity=CAR_ENTITY),
        # the chosen candidate's label ("chosen #2 — in front …") would cover the car: selected, it is shown
        overrides={**{entity: rrb.VisibleTimeRanges([whole_past]) for entity in entities},
                   "/world/candidates": rr.Points3D.from_fields(show_labels=False)},
    )


def events_view() -> rrb.TextLogView:
    """The `/events` log: frame, level and the whole message (no entity-path column: it is always /events);
    `EVENT_LEVELS` shown (the DEBUG "re-detected" lines are one click away, in the view's level filter)."""
    kind = rrb.encodings.TextLogColumnKind
    return rrb.TextLogView(
        name="events", origin="/events", rows=rrb.archetypes.TextLogRows(filter_by_log_level=list(EVENT_LEVELS)),
        columns=rrb.archetypes.TextLogColumns(text_log_columns=[
            rrb.encodings.TextLogColumn(kind.LogLevel),
            rrb.encodings.TextLogColumn(kind.Body),
            rrb.encodings.TextLogColumn(kind.EntityPath, visible=False)]),
    )


def _plots(road_scale: bool, ground_truth: bool, engine: bool = True) -> list[rrb.TimeSeriesView]:
    plots = [("tracks", "tracks"), ("inliers", "ransac"), ("inlier ratio", "ratio"), ("health", "health"),
             ("motion", "motion")] if engine else []
    if road_scale:
        plots.append(("scale from the road", "road"))
    if ground_truth:
        plots += [("position error (m)", "error"), ("angle errors (°)", "angle_error"),
                  ("ground truth vs the images", "gt_check")]
    if engine:
        plots.append(("timing (ms)", "timing_ms"))
    views = [rrb.TimeSeriesView(name=name, origin=f"/metrics/{group}") if group != "health" else health_view()
             for name, group in plots]
    if ground_truth:  # each frame's own error (drift attribution): degrees and metres | % and ratio
        at = len(views) - 1 if engine else len(views)  # before the timing plot
        views[at:at] = [
            rrb.TimeSeriesView(name=name, origin="/metrics/drift", contents=[f"/metrics/drift/{s}" for s in series])
            for name, series in DRIFT_PLOTS]
    return views


def health_view() -> rrb.TimeSeriesView:
    """The health status (0 ok, 1 warn, 2 fail) with a thin named line at each level, on a fixed 0..2 axis."""
    return rrb.TimeSeriesView(name="health", origin="/metrics",
                              contents=["/metrics/health/**", f"{HEALTH_LEVELS_ROOT}/**"],
                              axis_y=rrb.ScalarAxis(range=(-0.2, 2.2), zoom_lock=True))


def _map_plots() -> list[rrb.TimeSeriesView]:
    """Tracking mode | landmarks tracked and PnP inliers | BA reprojection errors | BA against the front end's
    rotations (°) | the rest of each BA run."""
    rotation = "rotation_prior_max_deg"
    work = [f"/metrics/ba/{name}" for name in MAP_METRICS["ba"] if name not in (*BA_ERROR_SERIES, rotation)]
    return [
        rrb.TimeSeriesView(name="tracking mode", origin="/metrics/tracking", contents=["/metrics/tracking/mode"]),
        rrb.TimeSeriesView(name="landmarks tracked", origin="/metrics/tracking",
                           contents=["/metrics/tracking/pnp_inliers", "/metrics/tracking/landmarks_tracked"]),
        rrb.TimeSeriesView(name="bundle adjustment error (px)", origin="/metrics/ba",
                           contents=[f"/metrics/ba/{name}" for name in BA_ERROR_SERIES]),
        rrb.TimeSeriesView(name="bundle adjustment rotation vs front end (°)", origin="/metrics/ba",
                           contents=[f"/metrics/ba/{rotation}"]),
        rrb.TimeSeriesView(name="bundle adjustment", origin="/metrics/ba", contents=work),
    ]
