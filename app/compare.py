"""Two runs side by side in one recording, plus a table of what changed (for judging a parameter change).

How (rerun-sdk 0.41):

1. Each input is checked (`app.crop` helpers: a complete `.rrd` holding one recording; it must have
   ``/world/camera``) and summarised with `app.inspect.inspect_recording`; the metric-difference table
   compares those summaries.
2. Each run is streamed with the chunk API (``RrdReader(…).stream().flat_map(…).write_rrd(…)``) into a part
   file of the output recording, every chunk moved under its run's prefix with ``Chunk.with_entity_path``
   (fresh chunk id; row ids and timelines kept): ``/world/…`` → ``/a/world/…``, ``/metrics/…`` →
   ``/b/metrics/…``, static data included. Recording properties go to ``/__properties/a/run``,
   ``/__properties/a/config``… (``/__properties/<prefix>/<name>`` reads like ``/__properties/<name>`` of
   the input); the inputs' recording names are replaced by the comparison's, and ``/__properties/compare``
   holds the labels, input files and recording ids. The series styles (static ``SeriesLines``) get the
   run's label in the legend ("A: tracks alive"), and run B's lines are lighter and thinner than run A's,
   so overlaid plots read at a glance (where both runs have the same value, B's line runs inside A's).
   Both runs keep the ``frame`` timeline: the same source frames line up, and different frame ranges are
   kept whole.
3. The comparison blueprint (`blueprint`) is saved in a tiny file by a `RecordingStream` of the output's
   application id, and ``rerun rrd filter`` joins blueprint + parts into one file (as `app.crop` does).
   The application id is the inputs' plus ``-compare`` (see `comparison_application_id`).

Everything is written into a hidden temporary folder beside the output and renamed at the end.
"""

from __future__ import annotations

import functools
import math
import os
import shutil
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.archetypes as rra
import rerun.blueprint as rrb
from rerun.chunk import Chunk, LazyChunkStream, RrdReader, StoreEntry

from app.inspect import inspect_recording
from app.provenance import run_differences
from app.recording import APPLICATION_ID, METRICS, STAGES
from app.recording.blueprint import CAR_ENTITY, EYE_OFFSET
from app.rrd import (
    RecordingError,
    first_line,
    open_store,
    read_entity,
    run_rerun_cli,
    same_file,
    work_dir_beside,
)

#: Entity prefixes of the two runs in a comparison (``/a/world/camera``, ``/b/metrics/tracks/alive``).
PREFIXES = ("a", "b")
PROPERTIES = "/__properties"
#: Appended to the inputs' application id: a comparison needs its own (see `comparison_application_id`).
APPLICATION_SUFFIX = "-compare"
#: Colour of run B's estimated trajectory in the shared 3-D view (run A keeps the recording's red).
ESTIMATE_COLOUR_B = (60, 170, 255)
#: How much run B's series colours are blended towards white (0 = same colour as run A, 1 = white).
LIGHTEN_B = 0.55
#: Series line widths (UI points) of runs A and B: B's thin line runs inside A's where they are equal.
SERIES_WIDTHS = (2.5, 1.0)
#: Plot titles per metric group (as in app.recording.blueprint); groups not listed use their own name.
GROUP_TITLES = {
    "tracks": "tracks",
    "ransac": "inliers",
    "ratio": "inlier ratio",
    "health": "health",
    "motion": "motion",
    "error": "position error (m)",
    "angle_error": "angle errors (°)",
    "drift": "drift per frame",
    "timing_ms": "timing (ms)",
}
#: Metrics shown as whole numbers by `format_differences`.
WHOLE_NUMBERS = ("frames.count", "frames.flagged", "bytes")
_NAMES = "SeriesLines:names"
_COLOURS = "SeriesLines:colors"
_WIDTHS = "SeriesLines:widths"
_Override = rrb.VisibleTimeRanges | rr.LineStrips3D


@dataclass(frozen=True)
class MetricDifference:
    """One metric of both runs: `a`, `b` (None where a run has no value) and B − A."""

    name: str
    a: float | None
    b: float | None

    @property
    def difference(self) -> float | None:
        if self.a is None or self.b is None:
            return None
        return self.b - self.a

    @property
    def percent(self) -> float | None:
        """(B − A) / |A| in %; None when A is missing, zero or not finite."""
        diff = self.difference
        if diff is None or self.a is None or not math.isfinite(self.a) or self.a == 0:
            return None
        return 100.0 * diff / abs(self.a)


@dataclass(frozen=True)
class ComparisonResult:
    """The comparison file and the metric table (keys mirror `inspect --json`: ``stages_ms.track.mean``,
    ``series.corners_detected.mean``, ``accuracy.paper_rms_m``, ``frames.count``, ``bytes``)."""

    output: Path
    inputs: tuple[Path, Path]
    labels: tuple[str, str]
    recording_name: str
    differences: dict[str, MetricDifference]
    reports: tuple[dict[str, Any], dict[str, Any]]  # inspect_recording of A and B
    output_bytes: int


# ------------------------------------------------------------------------------------------ compare


def compare_recordings(a: Path, b: Path, output: Path, labels: tuple[str, str] = ("A", "B")) -> ComparisonResult:
    """Write `output`: run `a` under ``/a``, run `b` under ``/b``, one blueprint showing both, and return the
    metric differences. Raises `RecordingError` (one line naming the file)."""
    if len(labels) != 2 or not all(label.strip() for label in labels):
        raise RecordingError(f"{output}: two non-empty labels are needed, got {labels!r}")
    if labels[0] == labels[1]:
        raise RecordingError(f"{output}: the two labels must differ, got {labels[0]!r} twice")
    inputs = (a, b)
    opened = [_open_run(path) for path in inputs]
    for path in inputs:
        if same_file(path, output):
            raise RecordingError(f"{output}: the output must not be one of the compared recordings")
    reports = (inspect_recording(a), inspect_recording(b))

    stores = [store for _, store in opened]
    application_id = comparison_application_id([store.application_id for store in stores])
    names = [report["recording_name"] or path.stem for report, path in zip(reports, inputs, strict=True)]
    name = (f"vslam compare: {names[0]} vs {names[1]}" if names[0] != names[1]
            else f"vslam compare: {labels[0]} vs {labels[1]} ({names[0]})")
    recording_id = str(uuid.uuid5(uuid.NAMESPACE_URL, "vslam-compare:" + "\n".join(
        [*(s.recording_id for s in stores), *labels])))

    work = work_dir_beside(output)
    try:
        parts, logged = [], set()
        for prefix, label, path, (reader, store) in zip(PREFIXES, labels, inputs, opened, strict=True):
            part = work / f"{prefix}.rrd"
            rewrite = _Prefixer(prefix, label, lighten=LIGHTEN_B if prefix == "b" else 0.0,
                                width=SERIES_WIDTHS[PREFIXES.index(prefix)])
            _write(reader.stream(store=store).flat_map(rewrite), part, path, output, application_id, recording_id)
            parts.append(part)
            logged |= rewrite.logged
        extra = work / "properties.rrd"
        _write(LazyChunkStream.from_iter(_comparison_properties(name, inputs, labels, stores)), extra, output,
               output, application_id, recording_id)

        layout = work / "blueprint.rrd"
        with rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False) as rec:
            groups = [g for g in METRICS if any(path.startswith(f"/metrics/{g}/") for path in logged)]
            rec.save(layout, default_blueprint=blueprint(labels, trajectory_bounds(list(inputs)), groups))
        combined = work / "combined.rrd"
        run_rerun_cli(output, "rrd", "filter", "-o", str(combined), str(layout), *map(str, parts), str(extra))
        check = RrdReader(combined)
        if len(check.recordings()) != 1 or len(check.blueprints()) != 1:
            raise RecordingError(f"{output}: joining the blueprint and the recording failed "
                                 f"({len(check.recordings())} recordings, {len(check.blueprints())} blueprints)")
        try:
            os.replace(combined, output)
        except OSError as exc:
            raise RecordingError(f"{output}: cannot write ({exc.strerror})") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)

    return ComparisonResult(output=output, inputs=inputs, labels=labels, recording_name=name,
                            differences=metric_differences(*reports), reports=reports,
                            output_bytes=output.stat().st_size)


def comparison_application_id(inputs: list[str]) -> str:
    """``<inputs' application id>-compare`` (``vslam-compare`` when they differ).

    Not the inputs' own id: the viewer keeps one active blueprint per application id, so a comparison
    sharing ``vslam`` with the runs would be shown with the single-run layout (empty views) after a run
    was opened in the same viewer, and a run with the comparison layout after a comparison.
    """
    ids = set(inputs)
    return f"{ids.pop() if len(ids) == 1 else APPLICATION_ID}{APPLICATION_SUFFIX}"


def _write(stream: LazyChunkStream, part: Path, source: Path, output: Path, application_id: str,
           recording_id: str) -> None:
    """Run `stream` into `part` (one recording store); `RecordingError` naming `source` if it cannot be read."""
    try:
        stream.write_rrd(part, application_id=application_id, recording_id=recording_id)
    except OSError as exc:
        raise RecordingError(f"{output}: cannot write ({exc.strerror})") from None
    except Exception as exc:  # the reader raises plain exceptions for corrupt chunks
        raise RecordingError(f"{source}: cannot read the recording ({first_line(exc)})") from None


def _open_run(path: Path) -> tuple[RrdReader, StoreEntry]:
    """Reader and recording store of a complete vslam recording (it has ``/world/camera``)."""
    reader, store, _blueprints = open_store(path)
    try:
        entities = reader.store(store=store).schema().entity_paths()
    except Exception as exc:
        raise RecordingError(f"{path}: not a readable Rerun recording ({first_line(exc)})") from None
    if "/world/camera" not in entities:
        raise RecordingError(f"{path}: not a vslam recording (no /world/camera; written by `vslam run`?)")
    return reader, store


class _Prefixer:
    """`flat_map` callback: moves one run's chunks under ``/<prefix>`` and styles its series (label in the
    legend, lighter colours for run B, line width)."""

    def __init__(self, prefix: str, label: str, lighten: float, width: float) -> None:
        self.prefix = prefix
        self.label = label
        self.lighten = lighten
        self.width = width
        self.logged: set[str] = set()  # entity paths (of the input) with temporal data

    def __call__(self, chunk: Chunk) -> list[Chunk]:
        path = chunk.entity_path
        if not chunk.is_static:
            self.logged.add(path)
        if path == PROPERTIES:  # the input's recording name: the comparison has its own
            return []
        if path.startswith(PROPERTIES + "/"):
            moved = chunk.with_entity_path(f"{PROPERTIES}/{self.prefix}{path[len(PROPERTIES):]}")
        else:
            moved = chunk.with_entity_path(f"/{self.prefix}{path if path != '/' else ''}")
        batch = moved.to_record_batch()
        if _NAMES not in batch.schema.names:
            return [moved]
        batch = _replace(batch, _NAMES, lambda names: [f"{self.label}: {n}" for n in names])
        if self.lighten and _COLOURS in batch.schema.names:
            batch = _replace(batch, _COLOURS, lambda colours: [_lightened(c, self.lighten) for c in colours])
        if _WIDTHS not in batch.schema.names:
            field = _widths_field()
            batch = batch.append_column(field, pa.nulls(batch.num_rows, field.type))
        batch = _replace(batch, _WIDTHS, lambda _: [self.width], names=batch.column(_NAMES))
        return Chunk.from_record_batch(batch)  # the batch carries the new entity path, chunk id and row ids


@functools.cache
def _widths_field() -> pa.Field:
    """The ``SeriesLines:widths`` column's field (type and Rerun metadata) as `rr.SeriesLines` makes it."""
    template = Chunk.from_columns("/", indexes=[], columns=rr.SeriesLines.columns(widths=[1.0]))
    return template.to_record_batch().schema.field(_WIDTHS)


def _replace(batch: pa.RecordBatch, column: str, change: Callable[[list[Any]], list[Any]],
             names: pa.Array | None = None) -> pa.RecordBatch:
    """`batch` with every non-null list in `column` rewritten by `change` (type and field metadata kept); with
    `names`, the rows where `names` is not null are rewritten instead (`change` gets the old value)."""
    index = batch.schema.get_field_index(column)
    field = batch.schema.field(index)
    rows = batch.column(index).to_pylist()
    present = [row is not None for row in (rows if names is None else names.to_pylist())]
    values = [change(row) if keep else None for row, keep in zip(rows, present, strict=True)]
    return batch.set_column(index, field, pa.array(values, type=field.type))


def _lightened(rgba: int, amount: float) -> int:
    """A packed 0xRRGGBBAA colour blended `amount` of the way towards white (alpha kept)."""
    channels = [(rgba >> shift) & 0xFF for shift in (24, 16, 8)]
    r, g, b = (round(c + (255 - c) * amount) for c in channels)
    return (r << 24) | (g << 16) | (b << 8) | (rgba & 0xFF)


def _comparison_properties(name: str, inputs: tuple[Path, Path], labels: tuple[str, str],
                           stores: list[StoreEntry]) -> list[Chunk]:
    """The comparison's recording name and ``/__properties/compare`` (labels, input files, recording ids)."""
    values: dict[str, Any] = {}
    for prefix, path, label, store in zip(PREFIXES, inputs, labels, stores, strict=True):
        values.update({f"label_{prefix}": label, f"file_{prefix}": str(path.resolve()),
                       f"recording_id_{prefix}": store.recording_id})
    return [Chunk.from_columns(PROPERTIES, indexes=[], columns=rra.RecordingInfo.columns(name=[name])),
            Chunk.from_property("compare", rr.AnyValues(**values))]


# ---------------------------------------------------------------------------------------- blueprint


def plot_title(group: str) -> str:
    """Name of the time-series view of one `METRICS` group."""
    return GROUP_TITLES.get(group, group)


def blueprint(labels: tuple[str, str] = ("A", "B"),
              bounds: tuple[np.ndarray, np.ndarray] | None = None,
              groups: list[str] | None = None) -> rrb.Blueprint:
    """Run A (frame, world) | run B (frame, world) above one plot per metric group overlaying both runs (two
    rows), beside the shared 3-D view of both trajectories and the ground truth, and both runs' events.
    `bounds` (lowest and highest corner of the trajectories, `trajectory_bounds`) aims the shared 3-D view
    straight down on them. `groups`: the `METRICS` groups to plot (default all; `compare_recordings` leaves
    out groups neither run logged, e.g. the road scale of runs with ground-truth scale)."""
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
                           f"{world}/trajectory/ground_truth": whole_past},
            ),
            row_shares=[1, 1],
            name=label,
        )

    (label_a, label_b), (a, b) = labels, PREFIXES
    plots = [rrb.TimeSeriesView(name=plot_title(group), origin="/",
                                contents=[f"/{a}/metrics/{group}/**", f"/{b}/metrics/{group}/**"])
             for group in (groups if groups is not None else METRICS)]
    # The whole past on every trajectory entity (not inherited from a parent); run B's estimate in blue. Radii
    # in UI points (negative), so a 500 m trajectory stays visible, and thinner for the lines drawn inside others.
    def line(points: float, colour: tuple[int, int, int] | None = None) -> list[_Override]:
        return [whole_past, rr.LineStrips3D.from_fields(radii=-points, colors=colour)]

    trajectories = rrb.Spatial3DView(
        name=f"trajectories: {label_a} red, {label_b} blue, truth green",
        origin=f"/{a}/world",  # for its view coordinates (RDF); /b/world is the same space (no transforms)
        contents=[f"/{prefix}/world/trajectory/**" for prefix in PREFIXES],
        eye_controls=_top_down(bounds),
        overrides={
            f"/{a}/world/trajectory/estimate": line(3.0),
            f"/{b}/world/trajectory/estimate": line(2.0, ESTIMATE_COLOUR_B),
            f"/{a}/world/trajectory/ground_truth": line(1.0),
            f"/{b}/world/trajectory/ground_truth": line(1.0),
        },
    )
    # both runs' events in one log, ordered by frame; the entity path tells the runs apart (no level column:
    # the body needs the room, and its text says what happened)
    events = rrb.TextLogView(
        name="events", origin="/", contents=[f"/{prefix}/events" for prefix in PREFIXES],
        columns=rrb.archetypes.TextLogColumns(text_log_columns=[
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.EntityPath),
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.Body),
            rrb.encodings.TextLogColumn(rrb.encodings.TextLogColumnKind.LogLevel, visible=False)]),
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(run(a, label_a), run(b, label_b), name="runs"),
            rrb.Horizontal(rrb.Grid(*plots, grid_columns=math.ceil(len(plots) / 2), name="metrics"),
                           rrb.Vertical(trajectories, events, row_shares=[2, 1]),
                           column_shares=[4, 1.4]),
            row_shares=[1, 1],
        ),
        collapse_panels=True,
    )


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


# ------------------------------------------------------------------------------------- differences


def metric_differences(report_a: dict[str, Any], report_b: dict[str, Any]) -> dict[str, MetricDifference]:
    """Frame count, flagged frames, file size, every stage and series mean and every accuracy value of two
    `inspect_recording` reports, keyed like the report (``stages_ms.track.mean``)."""
    reports = (report_a, report_b)
    rows: dict[str, list[Any]] = {
        "frames.count": [r["frames"]["count"] for r in reports],
        "frames.flagged": [sum(f["end"] - f["start"] + 1 for f in r["flagged"]) for r in reports],
        "bytes": [r["bytes"] for r in reports],
    }
    for section, names in (("stages_ms", STAGES), ("series", ())):
        for name in dict.fromkeys([*names, *report_a[section], *report_b[section]]):
            rows[f"{section}.{name}.mean"] = [(r[section].get(name) or {}).get("mean") for r in reports]
    for name in dict.fromkeys([*(report_a["accuracy"] or {}), *(report_b["accuracy"] or {})]):
        rows[f"accuracy.{name}"] = [(r["accuracy"] or {}).get(name) for r in reports]
    return {key: MetricDifference(key, _number(a), _number(b)) for key, (a, b) in rows.items()}


def _number(value: Any) -> float | None:
    """A metric as a float; None where a run has none (absent, or NaN: e.g. no direction error without keyframes)."""
    return None if value is None or not math.isfinite(float(value)) else float(value)


def format_differences(result: ComparisonResult) -> str:
    """The comparison as a plain-text table (metric, A, B, B − A, %), columns aligned; each row shows about
    four significant digits of its larger value (counts and bytes as whole numbers)."""
    label_a, label_b = result.labels
    header = ["metric", label_a, label_b, f"{label_b} − {label_a}", "%"]
    rows = []
    for d in result.differences.values():
        digits = _decimals(d)
        rows.append([d.name, _fmt(d.a, digits), _fmt(d.b, digits), _fmt(d.difference, digits, sign=True),
                     "" if d.percent is None else f"{d.percent:+.1f}%"])
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(len(header))]
    lines = [f"comparison  {result.output} ({result.output_bytes / 1e6:.1f} MB)",
             f"name        {result.recording_name}"]
    for label, path, report in zip(result.labels, result.inputs, result.reports, strict=True):
        lines.append(f"{label:<11} {path}: {report['recording_name']}")
    lines += run_differences(*result.reports)  # how the runs were made: properties and config, A → B
    lines.append("")
    for row in [header, *rows]:
        cells = [row[0].ljust(widths[0]), *(cell.rjust(width) for cell, width in zip(row[1:], widths[1:],
                                                                                       strict=True))]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def _decimals(d: MetricDifference) -> int:
    if d.name in WHOLE_NUMBERS:
        return 0
    values = [abs(v) for v in (d.a, d.b) if v is not None and math.isfinite(v) and v != 0]
    if not values:
        return 3
    return min(6, max(0, 3 - math.floor(math.log10(max(values)))))


def _fmt(value: float | None, decimals: int, sign: bool = False) -> str:
    if value is None:
        return "–"
    if not math.isfinite(value):
        return str(value)
    return f"{value:{'+' if sign else ''},.{decimals}f}"
