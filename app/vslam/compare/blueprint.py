"""The layout of a `vslam compare` recording (two or more runs under ``/a``, ``/b``, ``/c``…), and how each
run's lines are told apart.

Two runs: run A (frame | world) beside run B (frame | world) on top. Three or more: one tab per run holding
that run's (frame | world) pair (N camera views side by side would each be too small to read), the first
run's tab shown. Below: one plot per metric group overlaying every run, beside the shared 3-D view of every
estimated trajectory and the ground truth, and every run's events in one log.

Telling runs apart: in the plots each run keeps the series' own colours, graded towards white and thinner
run by run (`run_style`: the first run full colour and widest, the last `LIGHTEN_LAST` lighter and
`SERIES_WIDTHS[1]` wide), so a later run's line runs inside an earlier one's where they agree, and the
legend names the run ("B: tracks alive"). In the 3-D view each run's estimate has its own hue
(`ESTIMATE_COLOURS`: red, orange, purple, cyan, pink, yellow, then again), the ground truth stays blue.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from vslam.compare.frames import DIFFERENCE_EVENTS, DIFFERENCE_ROOT, DIFFERENCE_SERIES, DIVERGENCE_MARKER
from vslam.recording import CAR_ENTITY, DRIFT_ENTITY, EYE_OFFSET, LINKS_ENTITY, METRICS
from vslam.rrd import read_entity

#: Entity prefixes of the runs, in input order (``/a/world/camera``, ``/c/metrics/tracks/alive``).
PREFIXES = tuple("abcdefghijklmnopqrstuvwxyz")
#: How much the last run's series colours are blended towards white (0 = the first run's colour, 1 = white);
#: the runs between are graded evenly (two runs: B is this much lighter).
LIGHTEN_LAST = 0.55
#: Series line widths (UI points) of the first and the last run (the runs between graded evenly): a later
#: run's thinner line runs inside an earlier one's where they are equal.
SERIES_WIDTHS = (2.5, 1.0)
#: (name, colour) of each run's estimated trajectory in the shared 3-D view, cycled; None keeps the
#: recording's own colour (red). Not blue: that is the ground truth (`vslam.recording.styles`).
ESTIMATE_COLOURS: tuple[tuple[str, tuple[int, int, int] | None], ...] = (
    ("red", None), ("orange", (255, 160, 0)), ("purple", (190, 90, 255)), ("cyan", (0, 220, 220)),
    ("pink", (255, 110, 190)), ("yellow", (240, 230, 60)))
#: Plot titles per metric group (as in vslam.recording.layout); groups not listed use their own name.
GROUP_TITLES = {
    "tracks": "tracks",
    "ransac": "inliers",
    "ratio": "inlier ratio",
    "health": "health",
    "motion": "motion",
    "error": "position error (m)",
    "angle_error": "angle errors (°)",
    "drift": "drift per frame",
    "gt_check": "ground truth vs the images",
    "timing_ms": "timing (ms)",
}
_Override = rrb.VisibleTimeRanges | rr.LineStrips3D
#: Titles of the per-frame difference plots (`vslam.compare.frames.DIFFERENCE_SERIES` kinds).
DIFFERENCE_TITLES = {"rotation": "step rotation vs first run (°)", "translation": "step translation vs first "
                     "run (% of step)", "position": "position vs first run (m, first frames aligned)"}
#: Frames either side of the first divergence selected in the time panel.
DIVERGENCE_WINDOW = 5


def run_prefixes(count: int) -> tuple[str, ...]:
    """The entity prefixes of `count` runs (``a``, ``b``, …); at most ``len(PREFIXES)``."""
    if count > len(PREFIXES):
        raise ValueError(f"at most {len(PREFIXES)} runs, got {count}")
    return PREFIXES[:count]


def run_style(index: int, count: int) -> tuple[float, float]:
    """(lighten towards white in 0..1, line width in UI points) of run `index` of `count` runs' series."""
    share = index / (count - 1) if count > 1 else 0.0
    first, last = SERIES_WIDTHS
    return LIGHTEN_LAST * share, first + (last - first) * share


def estimate_colour(index: int) -> tuple[str, tuple[int, int, int] | None]:
    """(name, RGB or None for the recording's own red) of run `index`'s estimated trajectory."""
    return ESTIMATE_COLOURS[index % len(ESTIMATE_COLOURS)]


def trajectories_title(labels: tuple[str, ...]) -> str:
    """Name of the shared 3-D view: "trajectories: A red, B orange, truth blue"."""
    runs = ", ".join(f"{label} {estimate_colour(i)[0]}" for i, label in enumerate(labels))
    return f"trajectories: {runs}, truth blue"


def own_series_plot(prefixes: tuple[str, ...], plot: str, named: list[str]) -> rrb.TimeSeriesView:
    """Every run's own series of one plot (``/<prefix>/metrics/custom/<plot>/**``); `plot` ``""``: those logged
    without a plot (the others, `named`, left out)."""
    if plot:
        return rrb.TimeSeriesView(name=plot, origin="/", contents=[f"/{p}/metrics/custom/{plot}/**" for p in prefixes])
    return rrb.TimeSeriesView(name="pipeline series", origin="/", contents=[
        *(f"/{p}/metrics/custom/**" for p in prefixes),
        *(f"- /{p}/metrics/custom/{name}/**" for p in prefixes for name in named)])


def plot_title(group: str) -> str:
    """Name of the time-series view of one `METRICS` group."""
    return GROUP_TITLES.get(group, group)


def blueprint(labels: tuple[str, ...] = ("A", "B"),
              bounds: tuple[np.ndarray, np.ndarray] | None = None,
              groups: list[str] | None = None, divergence_frame: int | None = None,
              own_plots: tuple[str, ...] = ()) -> rrb.Blueprint:
    """The comparison layout of ``len(labels)`` runs (see the module docstring). `bounds` (lowest and highest
    corner of the trajectories, `trajectory_bounds`) aims the shared 3-D view down on them. `groups`: the
    `METRICS` groups to plot (default all; `compare_recordings` leaves out groups no run logged, e.g. the
    road scale of runs with ground-truth scale). First in the plots the per-frame differences of each further
    run from the first (`vslam.compare.frames`); `divergence_frame` (the earliest first divergence) selects
    the frames around it in the time panel and loops the playback over them (Rerun 0.41's blueprint cannot
    place the time cursor itself; the 0.41 viewer was seen to play into the selection within ~4 s of opening,
    then loop over it). `own_plots`: a logging-API pipeline's own series (``/metrics/custom``), one plot each:
    ``""`` for those logged without a plot ("pipeline series"), else the plot's name."""
    prefixes = run_prefixes(len(labels))
    whole_past = rrb.VisibleTimeRanges([rr.VisibleTimeRange(
        "frame", start=rr.TimeRangeBoundary.infinite(), end=rr.TimeRangeBoundary.cursor_relative())])

    def run(prefix: str, label: str) -> rrb.Vertical:
        world = f"/{prefix}/world"
        return rrb.Vertical(
            rrb.Spatial2DView(name=f"{label}: frame", origin=f"{world}/camera/image"),
            rrb.Spatial3DView(
                name=f"{label}: world",
                origin=world,
                eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0],
                                               position=list(EYE_OFFSET), look_target=[0.0, 0.0, 0.0],
                                               tracking_entity=f"/{prefix}{CAR_ENTITY}"),  # as `vslam run`'s
                # overrides on a parent are not inherited: one per trajectory entity
                overrides={f"{world}/trajectory/estimate": whole_past,
                           f"{world}/trajectory/ground_truth": whole_past,
                           f"/{prefix}{DRIFT_ENTITY}": whole_past},  # one segment per frame, like the estimate
            ),
            row_shares=[1, 1],
            name=label,
        )

    plots = [rrb.TimeSeriesView(name=plot_title(group), origin="/",
                                contents=[f"/{prefix}/metrics/{group}/**" for prefix in prefixes])
             for group in (groups if groups is not None else METRICS)]
    plots += [own_series_plot(prefixes, plot, [p for p in own_plots if p]) for plot in own_plots]
    if len(prefixes) > 1:
        plots[:0] = difference_plots(prefixes[1:])

    # The whole past on every trajectory entity (not inherited from a parent); each run's estimate in its hue.
    # Radii in UI points (negative), so a 500 m trajectory stays visible, and thinner for later runs' lines.
    def line(points: float, colour: tuple[int, int, int] | None = None) -> list[_Override]:
        return [whole_past, rr.LineStrips3D.from_fields(radii=-points, colors=colour)]

    overrides: dict[str, list[_Override]] = {}
    for index, prefix in enumerate(prefixes):
        overrides[f"/{prefix}/world/trajectory/estimate"] = line(max(3.0 - index, 1.5), estimate_colour(index)[1])
        # wider than every estimate and under them (the recording draws it 0.2 m lower): a band where they agree
        overrides[f"/{prefix}/world/trajectory/ground_truth"] = line(4.5)
    trajectories = rrb.Spatial3DView(
        name=trajectories_title(labels),
        origin=f"/{prefixes[0]}/world",  # for its view coordinates (RDF); every /<prefix>/world is the same space
        # not the drift-coloured copies of the estimates (nor their links to the truth): they would hide the
        # runs' own hues and look like the error colours
        contents=[*(f"/{prefix}/world/trajectory/**" for prefix in prefixes),
                  *(f"- /{prefix}{entity}" for prefix in prefixes for entity in (DRIFT_ENTITY, LINKS_ENTITY))],
        eye_controls=_top_down(bounds),
        overrides=overrides,  # type: ignore[arg-type]
    )
    # every run's events in one log, ordered by frame; the entity path tells the runs apart (no level column:
    # the body needs the room, and its text says what happened)
    events = rrb.TextLogView(
        name="events", origin="/", contents=[DIFFERENCE_EVENTS, *(f"/{prefix}/events/**" for prefix in prefixes)],
        columns=rrb.archetypes.TextLogColumns(text_log_columns=[
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.EntityPath),
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.Body),
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.LogLevel, visible=False)]),
    )
    runs = [run(prefix, label) for prefix, label in zip(prefixes, labels, strict=True)]
    # two runs side by side; more as tabs (N camera views in one row would each be too small to read)
    cameras = (rrb.Horizontal(*runs, name="runs") if len(runs) <= 2
               else rrb.Tabs(*runs, active_tab=0, name="runs"))
    return rrb.Blueprint(
        rrb.Vertical(
            cameras,
            rrb.Horizontal(rrb.Grid(*plots, grid_columns=math.ceil(len(plots) / 2), name="metrics"),
                           rrb.Vertical(trajectories, events, row_shares=[2, 1]),
                           column_shares=[4, 1.4]),
            row_shares=[1, 1],
        ),
        time_panel(divergence_frame),
        collapse_panels=True,
    )


def difference_plots(prefixes: tuple[str, ...]) -> list[rrb.TimeSeriesView]:
    """One plot per `DIFFERENCE_SERIES` kind over the further runs (``prefixes``: b, c, …); the divergence
    markers go in the step-rotation plot."""
    views = []
    for name, _, kind in DIFFERENCE_SERIES:
        contents = [f"{DIFFERENCE_ROOT}/{prefix}/{name}" for prefix in prefixes]
        if kind == "rotation":
            contents += [f"{DIFFERENCE_ROOT}/{prefix}/{DIVERGENCE_MARKER}" for prefix in prefixes]
        views.append(rrb.TimeSeriesView(name=DIFFERENCE_TITLES[kind], origin=DIFFERENCE_ROOT, contents=contents))
    return views


def time_panel(divergence_frame: int | None) -> rrb.TimePanel:
    """The `frame` timeline; at a divergence, `DIVERGENCE_WINDOW` frames either side of it selected and played
    in a loop, so the recording opens on the frames where the runs part."""
    if divergence_frame is None:
        return rrb.TimePanel(timeline="frame", state="collapsed")
    low, high = max(divergence_frame - DIVERGENCE_WINDOW, 0), divergence_frame + DIVERGENCE_WINDOW
    return rrb.TimePanel(timeline="frame", time_selection=rrb.components.AbsoluteTimeRange(low, high),
                         loop_mode="selection", play_state="playing", fps=4.0)


def _top_down(bounds: tuple[np.ndarray, np.ndarray] | None) -> rrb.EyeControls3D:
    """Look down on the x–z plane (RDF world: −y is up) from a little behind, so forward (+z) points up the
    screen (a map view: right turns go right), from high enough to see the box `bounds` (lowest, highest
    corner); the viewer's own choice without bounds. (Straight down, the viewer picks the screen's up itself:
    it showed forward pointing down.)"""
    if bounds is None:
        return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, eye_up=[0.0, -1.0, 0.0])
    low, high = bounds
    centre = (low + high) / 2.0
    span = float(max(high[0] - low[0], high[2] - low[2], 1.0))
    height = 1.3 * span + float(high[1] - low[1])  # the whole box in a wide view, with a margin
    position = centre + np.array([0.0, -height, -0.15 * height])  # tilted ~9° towards the start
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position, look_target=centre,
                             eye_up=[0.0, -1.0, 0.0])


def trajectory_bounds(paths: list[Path]) -> tuple[np.ndarray, np.ndarray] | None:
    """Lowest and highest corner of every camera position and ground-truth point of vslam recordings."""
    points: list[np.ndarray] = []
    for path in paths:
        camera = read_entity(path, "/world/camera")
        if "Transform3D:translation" in camera.columns:
            points += [np.asarray(t, np.float64).reshape(-1, 3) for t in camera["Transform3D:translation"].to_list()
                       if t is not None]
        truth = read_entity(path, "/world/trajectory/ground_truth")
        if "LineStrips3D:strips" in truth.columns:
            points += [np.asarray(s, np.float64).reshape(-1, 3) for s in truth["LineStrips3D:strips"].to_list()
                       if s is not None]
    if not points:
        return None
    every = np.concatenate(points)
    every = every[np.isfinite(every).all(axis=1)]
    if not len(every):
        return None
    return every.min(axis=0), every.max(axis=0)
