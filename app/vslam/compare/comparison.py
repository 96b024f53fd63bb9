"""Two or more runs side by side in one recording, plus tables of what changed (for judging a parameter
change).

How (rerun-sdk 0.41):

1. Each input is checked (`vslam.rrd.crop` helpers: a complete `.rrd` holding one recording; it must have
   ``/world/camera``) and summarised with `vslam.rrd.inspect.inspect_recording`; the tables (`vslam.compare.table`)
   compare those summaries, every further run against the first (the baseline).
2. Each run is streamed with the chunk API (``RrdReader(…).stream().flat_map(…).write_rrd(…)``) into a part
   file of the output recording, every chunk moved under its run's prefix (``a``, ``b``, ``c``… in input
   order, `vslam.compare.blueprint.PREFIXES`) with ``Chunk.with_entity_path`` (fresh chunk id; row ids and
   timelines kept): ``/world/…`` → ``/a/world/…``, ``/metrics/…`` → ``/c/metrics/…``, static data included.
   Recording properties go to ``/__properties/a/run``, ``/__properties/a/config``… (``/__properties/<prefix>/
   <name>`` reads like ``/__properties/<name>`` of the input); the inputs' recording names are replaced by the
   comparison's, and ``/__properties/compare`` holds every run's label, input file and recording id
   (``label_a``, ``file_a``, ``recording_id_a``, ``label_b``…). The series styles (static ``SeriesLines``)
   get the run's label in the legend ("A: tracks alive"), and each further run's lines are lighter and
   thinner (`vslam.compare.blueprint.run_style`), so overlaid plots read at a glance. Every run keeps the
   ``frame`` timeline: the same source frames line up, and different frame ranges are kept whole.
3. The comparison blueprint (`vslam.compare.blueprint.blueprint`) is saved in a tiny file by a
   `RecordingStream` of the output's application id, and ``rerun rrd filter`` joins blueprint + parts into
   one file (as `vslam.rrd.crop` does). The application id is the inputs' plus ``-compare`` (see
   `comparison_application_id`).

Everything is written into a hidden temporary folder beside the output and renamed at the end. Inputs
lacking some entities (no timing or track series, no ground truth) are fine: they are moved as they are, and
their missing numbers are blank cells in the tables.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import shutil
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import rerun as rr
import rerun.archetypes as rra
from rerun.chunk import Chunk, LazyChunkStream, RrdReader, StoreEntry

from vslam.common import RecordingError, first_line
from vslam.compare.blueprint import (
    LIGHTEN_LAST,
    PREFIXES,
    SERIES_WIDTHS,
    blueprint,
    estimate_colour,
    plot_title,
    run_prefixes,
    run_style,
    trajectory_bounds,
)
from vslam.compare.divergences import Divergence, comparability, ranked_divergences
from vslam.compare.frames import (
    ROTATION_DEG,
    TRANSLATION_PCT,
    FirstDivergence,
    FrameDifferences,
    describe_divergence,
    difference_chunks,
    first_divergence,
    frame_differences,
    read_run_frames,
)
from vslam.compare.table import MetricDifference, format_differences, metric_differences, summary_markdown
from vslam.recording import APPLICATION_ID, METRICS
from vslam.rrd import inspect_recording, open_store, run_rerun_cli, same_file, schema_contract, work_dir_beside

__all__ = ["PREFIXES", "LIGHTEN_B", "SERIES_WIDTHS", "ComparisonResult", "MetricDifference", "blueprint",
           "compare_recordings", "format_differences", "metric_differences", "plot_title"]

PROPERTIES = "/__properties"
#: Appended to the inputs' application id: a comparison needs its own (see `comparison_application_id`).
APPLICATION_SUFFIX = "-compare"
#: How much run B's series colours are blended towards white in a comparison of two runs.
LIGHTEN_B = LIGHTEN_LAST
_NAMES = "SeriesLines:names"
_COLOURS = "SeriesLines:colors"
_WIDTHS = "SeriesLines:widths"


@dataclass(frozen=True)
class ComparisonResult:
    """The comparison file and each run's `inspect_recording` report (in input order; the first is the
    baseline). `differences` (B vs A) and `versus` (each further run vs the baseline) are keyed like
    ``inspect --json``: ``stages_ms.track.mean``, ``series.corners_detected.mean``, ``accuracy.paper_rms_m``,
    ``report_metrics.t_err``, ``frames.count``, ``bytes``."""

    output: Path
    inputs: tuple[Path, ...]
    labels: tuple[str, ...]
    recording_name: str
    reports: tuple[dict[str, Any], ...]
    output_bytes: int
    #: Per further run (B, C, …): its per-frame differences from the baseline and its first divergence.
    frame_differences: tuple[FrameDifferences, ...] = ()
    divergences: tuple[FirstDivergence | None, ...] = ()
    #: Per further run: its frames ranked by how much its step differs from the baseline's, against the pair's
    #: usual difference (`vslam.compare.divergences`).
    ranked: tuple[list[Divergence], ...] = ()
    #: What makes the frame-by-frame comparison partial (different frame ranges; different sources, forced).
    warnings: tuple[str, ...] = ()
    #: The thresholds of a divergence: step rotation (°) and translation (% of the step).
    thresholds: tuple[float, float] = (ROTATION_DEG, TRANSLATION_PCT)

    @property
    def prefixes(self) -> tuple[str, ...]:
        return run_prefixes(len(self.inputs))

    @property
    def versus(self) -> tuple[dict[str, MetricDifference], ...]:
        """Per further run (B, C, …): every metric against the baseline A."""
        return tuple(metric_differences(self.reports[0], report) for report in self.reports[1:])

    @property
    def differences(self) -> dict[str, MetricDifference]:
        """The second run against the first (the two-run table)."""
        return self.versus[0]


# ------------------------------------------------------------------------------------------ compare


def default_labels(count: int) -> tuple[str, ...]:
    """A, B, C, … for `count` runs."""
    return tuple(prefix.upper() for prefix in run_prefixes(count))


def check_labels(labels: Sequence[str], count: int) -> str | None:
    """Why `labels` cannot name `count` runs (one line), or None: one non-empty, distinct label per run."""
    if len(labels) != count:
        return f"{count} labels are needed (one per recording), got {len(labels)}"
    if not all(label.strip() for label in labels):
        return "a label is empty"
    if len(set(labels)) != len(labels):
        twice = next(label for label in labels if labels.count(label) > 1)
        return f"the labels must differ, got {twice!r} twice"
    return None


def compare_recordings(*paths: Path, labels: Sequence[str] | None = None, rotation_deg: float = ROTATION_DEG,
                       translation_pct: float = TRANSLATION_PCT, force: bool = False) -> ComparisonResult:
    """``compare_recordings(a, b[, c…], output)``: write `output` holding run i under ``/<PREFIXES[i]>`` and one
    blueprint showing them all (`labels`: one per run, default A, B, C…); return the runs' reports and, per
    further run, its per-frame differences from the first and its first divergence (a step rotation above
    `rotation_deg` degrees or translation above `translation_pct` % of the step: `vslam.compare.frames`) and its
    ranked divergences (`vslam.compare.divergences`). Runs of different sources, or without a common frame, are
    refused unless `force` (then named in `warnings`). Raises `RecordingError` (one line naming the file)."""
    if len(paths) < 3:
        raise RecordingError("compare: give two or more recordings and the output")
    *given, output = (Path(p) for p in paths)
    inputs = tuple(given)
    if len(inputs) > len(PREFIXES):
        raise RecordingError(f"{output}: at most {len(PREFIXES)} recordings, got {len(inputs)}")
    names = tuple(labels) if labels is not None else default_labels(len(inputs))
    if problem := check_labels(names, len(inputs)):
        raise RecordingError(f"{output}: {problem}")
    opened = [_open_run(path) for path in inputs]
    for path in inputs:
        if same_file(path, output):
            raise RecordingError(f"{output}: the output must not be one of the compared recordings")
    with schema_contract(*inputs):  # a recording `vslam check` rejects: one line, never a traceback
        reports = tuple(inspect_recording(path) for path in inputs)
        runs = [read_run_frames(path) for path in inputs]
        refusals, warnings = comparability(names, reports, runs)
        if refusals and not force:
            raise RecordingError(f"{output}: {refusals[0]} (--force compares them anyway)")
        differences = tuple(frame_differences(runs[0], run) for run in runs[1:])
        ranked = tuple(_with_suspects(ranked_divergences(runs[0], run, diff), reports[0], report)
                       for run, diff, report in zip(runs[1:], differences, reports[1:], strict=True))
        divergences = tuple(first_divergence(runs[0], run, diff, rotation_deg, translation_pct)
                            for run, diff in zip(runs[1:], differences, strict=True))
        bounds = trajectory_bounds(list(inputs))

    stores = [store for _, store in opened]
    application_id = comparison_application_id([store.application_id for store in stores])
    name = comparison_name(names, [report["recording_name"] or path.stem for report, path in zip(reports, inputs,
                                                                                                  strict=True)])
    recording_id = str(uuid.uuid5(uuid.NAMESPACE_URL, "vslam-compare:" + "\n".join(
        [*(s.recording_id for s in stores), *names])))

    work = work_dir_beside(output)
    try:
        parts, logged = [], set()
        prefixes = run_prefixes(len(inputs))
        for index, (prefix, label, path, (reader, store)) in enumerate(zip(prefixes, names, inputs, opened,
                                                                           strict=True)):
            part = work / f"{prefix}.rrd"
            lighten, width = run_style(index, len(inputs))
            rewrite = _Prefixer(prefix, label, lighten=lighten, width=width)
            _write(reader.stream(store=store).flat_map(rewrite), part, path, output, application_id, recording_id)
            parts.append(part)
            logged |= rewrite.logged
        extra = work / "properties.rrd"
        summary = summary_markdown(name, inputs=inputs, labels=names, reports=reports)
        marks = [chunk for index, (diff, divergence) in enumerate(zip(differences, divergences, strict=True), 1)
                 for chunk in difference_chunks(
                     PREFIXES[index], names[0], names[index], estimate_colour(index)[1] or (255, 80, 80), diff,
                     divergence, describe_divergence(names[0], names[index], divergence, rotation_deg,
                                                     translation_pct))]
        _write(LazyChunkStream.from_iter([*_comparison_properties(name, inputs, names, stores, summary), *marks]),
               extra, output, output, application_id, recording_id)

        layout = work / "blueprint.rrd"
        with rr.RecordingStream(application_id, recording_id=recording_id, send_properties=False) as rec:
            groups = [g for g in METRICS if any(path.startswith(f"/metrics/{g}/") for path in logged)]
            own = sorted({"/".join(path.split("/")[3:-1]) for path in logged if path.startswith("/metrics/custom/")})
            first = min((d.frame for d in divergences if d is not None), default=None)
            rec.save(layout, default_blueprint=blueprint(names, bounds, groups,
                                                         divergence_frame=first, own_plots=tuple(own)))
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

    return ComparisonResult(output=output, inputs=inputs, labels=names, recording_name=name, reports=reports,
                            output_bytes=output.stat().st_size, frame_differences=differences,
                            divergences=divergences, thresholds=(rotation_deg, translation_pct), ranked=ranked,
                            warnings=tuple([*refusals, *warnings]))


def _with_suspects(ranked: list[Divergence], report_a: dict[str, Any], report_b: dict[str, Any]
                   ) -> list[Divergence]:
    """`ranked` with each run's own suspect reasons at the frame (`inspect`'s ``suspects``) after its health's."""
    suspects = [{s["frame"]: [r for r in s["reasons"] if not r.startswith("health ")]
                 for s in report.get("suspects") or []} for report in (report_a, report_b)]
    return [dataclasses.replace(d, reasons_a=d.reasons_a + suspects[0].get(d.frame, []),
                                reasons_b=d.reasons_b + suspects[1].get(d.frame, [])) for d in ranked]


def comparison_name(labels: Sequence[str], names: Sequence[str]) -> str:
    """The comparison's recording name: the runs' names joined by "vs", or the labels when the names are all
    the same ("vslam compare: A vs B (vslam synthetic-street frames 0:20 scale gt)")."""
    if len(set(names)) == len(names):
        return "vslam compare: " + " vs ".join(names)
    if len(set(names)) == 1:
        return f"vslam compare: {' vs '.join(labels)} ({names[0]})"
    return "vslam compare: " + " vs ".join(f"{label} ({name})" for label, name in zip(labels, names, strict=True))


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
    legend, lighter colours for further runs, line width)."""

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


def _comparison_properties(name: str, inputs: tuple[Path, ...], labels: tuple[str, ...],
                           stores: list[StoreEntry], summary: str) -> list[Chunk]:
    """The comparison's recording name, ``/__properties/compare`` (per run its label, input file and recording
    id: ``label_a``, ``file_a``, ``recording_id_a``, ``label_b``, …) and ``/report`` (`summary`, Markdown)."""
    values: dict[str, Any] = {}
    for prefix, path, label, store in zip(run_prefixes(len(inputs)), inputs, labels, stores, strict=True):
        values.update({f"label_{prefix}": label, f"file_{prefix}": str(path.resolve()),
                       f"recording_id_{prefix}": store.recording_id})
    return [Chunk.from_columns(PROPERTIES, indexes=[], columns=rra.RecordingInfo.columns(name=[name])),
            Chunk.from_property("compare", rr.AnyValues(**values)),
            Chunk.from_columns("/report", indexes=[], columns=rr.TextDocument.columns(
                text=[summary], media_type=[rr.MediaType.MARKDOWN]))]
