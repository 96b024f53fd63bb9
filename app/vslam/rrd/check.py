"""`vslam check`: validate any recording (vslam's, the logging API's, or one written with the Rerun SDK from C++ or
another language) against the recording schema (`vslam.recording.schema`, docs/recording-schema.md).

Each problem is one line naming the entity, component or property, what is wrong, and the commands it affects.
Checked: the ``frame`` timeline; no component named like a timeline; every required entity and run property; for
every schema entity present, its components, whether it is static or per frame on ``frame``, and its values where
commands rely on them (rigid camera poses, health levels, the schema version); entities outside the schema whose
name is close to a missing schema entity (misnamed). Entities outside the schema are otherwise allowed.
A `vslam compare` file is checked run by run (``/a``, ``/b``, …).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl
import typer
from rerun.chunk import Chunk

from vslam.recording import (
    ENTITIES,
    EVERY_COMMAND,
    FRAME_TIMELINE,
    HEALTH_STATUSES,
    REQUIRED_PROPERTIES,
    SCHEMA_VERSION,
    TIMELINES,
    EntitySpec,
)
from vslam.rrd.health import read_statuses, unknown_statuses
from vslam.rrd.provenance import PROPERTIES, comparison_prefixes, read_properties
from vslam.rrd.read import RecordingError, first_line, open_store, read_entity, readable
from vslam_core.errors import VslamError

#: Rotation components of `/world/camera`: any one of them.
ROTATIONS = ("Transform3D:mat3x3", "Transform3D:quaternion", "Transform3D:rotation_axis_angle")
#: How alike an unknown entity's path must be to a missing schema entity's to be called misnamed (difflib ratio).
MISNAMED_RATIO = 0.75
#: Dataframe readers (`vslam inspect`, `compare`, `crop`) and the viewer's dataframe view join on the timelines.
TIMELINE_CLASH_AFFECTS = ("inspect", "compare", "crop", "open")


@dataclass(frozen=True)
class Problem:
    item: str  # entity path, ``entity:component``, ``property <key>`` or ``timeline <name>``
    problem: str
    affects: tuple[str, ...]

    def line(self) -> str:
        return f"{self.item}: {self.problem} (affects {', '.join(self.affects)})"


@dataclass
class CheckResult:
    path: Path
    problems: list[Problem] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    entities: int = 0
    frames: list[int] = field(default_factory=list)

    @property
    def conforms(self) -> bool:
        return not self.problems


@dataclass
class _Layout:
    """What the file holds, from its schema and one pass over its temporal chunks' timelines."""

    components: dict[str, dict[str, bool]]  # entity → component → static
    timelines: dict[str, set[str]]  # entity → timelines of its temporal chunks
    index: set[str]  # the recording's timelines


def check_recording(path: Path) -> CheckResult:
    """Check `path` against the schema. Raises `RecordingError` when it is not a readable recording at all."""
    reader, store, _ = open_store(path)
    result = CheckResult(path)
    if readable(path).cut_short:
        result.notes.append("cut short (no footer): commands read a finalised copy; `vslam repair` writes one")
    try:
        schema = reader.store(store=store).schema()
        seen: dict[str, set[str]] = {}

        def note_timelines(chunk: Chunk) -> list[Chunk]:
            seen.setdefault(chunk.entity_path, set()).update(chunk.timeline_names)
            return []

        reader.stream(store=store).filter(is_static=False).flat_map(note_timelines).to_chunks()
        components: dict[str, dict[str, bool]] = {}
        for column in schema.component_columns():
            components.setdefault(column.entity_path, {})[column.component] = column.is_static
        layout = _Layout(components, seen, {str(c.name) for c in schema.index_columns()})
    except Exception as exc:  # the reader raises plain exceptions for corrupt chunks
        raise RecordingError(f"{path}: not a readable Rerun recording ({first_line(exc)})") from None
    result.entities = len([e for e in layout.components if not e.startswith(PROPERTIES)])
    if FRAME_TIMELINE not in layout.index:
        result.problems.append(Problem(f"timeline {FRAME_TIMELINE}", "missing: per-frame data must be logged on a "
                                       "sequence timeline named frame (the source's frame index)", EVERY_COMMAND))
    result.problems += _timeline_clashes(layout)
    prefixes = [f"/{p}" for p in comparison_prefixes(path)] or [""]
    for prefix in prefixes:
        result.problems += _check_run(path, layout, prefix, result)
    return result


def _timeline_clashes(layout: _Layout) -> list[Problem]:
    """Components named like a timeline (``frame``, ``time``): dataframe readers cannot tell them apart."""
    problems = []
    for entity, components in sorted(layout.components.items()):
        for component in sorted(c for c in components if c in TIMELINES):  # `AnyValues` names are bare
            problems.append(Problem(f"{entity}:{component}", f"a component named like the {component} timeline "
                                    f"(rename it, e.g. {component}_index)", TIMELINE_CLASH_AFFECTS))
    return problems


def _check_run(path: Path, layout: _Layout, prefix: str, result: CheckResult) -> list[Problem]:
    problems = _check_properties(path, prefix)
    for spec in ENTITIES:
        entity = prefix + spec.path
        if entity not in layout.components:
            if spec.required:
                problems.append(Problem(entity, f"missing (required: {spec.what})", spec.readers))
            continue
        problems += _check_entity(spec, entity, layout)
    problems += _misnamed(layout, prefix)
    problems += _check_camera(path, prefix, layout, result)
    if prefix + "/health" in layout.components:
        problems += _check_health(path, prefix)
    return problems


def _check_entity(spec: EntitySpec, entity: str, layout: _Layout) -> list[Problem]:
    """Components and their static-ness. A per-frame entity holding only static styles (a series' legend
    logged up front, as the recorder does for every series) has no data yet: nothing to check."""
    problems = []
    present = layout.components[entity]
    if not spec.static and all(present.values()):
        if spec.required:
            return [Problem(entity, f"no per-frame data (required: {spec.what})", spec.readers)]
        return []
    for component in spec.components:
        if component not in present:
            problems.append(Problem(entity, f"malformed: no {component} ({spec.what})", spec.readers))
        elif present[component] != spec.static:
            how = "static" if spec.static else f"per frame on the {FRAME_TIMELINE} timeline"
            problems.append(Problem(f"{entity}:{component}", f"must be logged {how}", spec.readers))
    if spec.path == "/world/camera" and not any(r in present for r in ROTATIONS):
        problems.append(Problem(entity, "malformed: no rotation (Transform3D:mat3x3 or quaternion)", spec.readers))
    if not spec.static and entity in layout.timelines and FRAME_TIMELINE not in layout.timelines[entity]:
        problems.append(Problem(entity, f"logged on {', '.join(sorted(layout.timelines[entity])) or 'no timeline'}, "
                                f"not on the {FRAME_TIMELINE} timeline", spec.readers))
    return problems


def _misnamed(layout: _Layout, prefix: str) -> list[Problem]:
    """Entities outside the schema whose path is close to a schema entity the recording lacks."""
    expected = {prefix + s.path: s for s in ENTITIES}
    missing = [path for path in expected if path not in layout.components]
    problems = []
    for entity in sorted(layout.components):
        if entity in expected or entity.startswith(PROPERTIES) or not entity.startswith(prefix + "/"):
            continue
        close = difflib.get_close_matches(entity, missing, n=1, cutoff=MISNAMED_RATIO)
        if close:
            spec = expected[close[0]]
            problems.append(Problem(entity, f"not in recording schema {SCHEMA_VERSION}: misnamed {close[0]}?",
                                    spec.readers))
    return problems


def _check_properties(path: Path, prefix: str) -> list[Problem]:
    entity = f"{PROPERTIES}{prefix}/run"
    properties = read_properties(path, entity)
    problems = [Problem(f"property {key}", f"missing from {entity}", readers)
                for key, readers in REQUIRED_PROPERTIES.items() if key not in properties]
    version = properties.get("schema_version")
    if version is not None:
        try:
            number = int(str(version))
        except ValueError:
            number = None
        if number is None or number < 1:
            problems.append(Problem("property schema_version", f"{version!r} is not a schema version (1, 2, …)",
                                    EVERY_COMMAND))
        elif number > SCHEMA_VERSION:
            problems.append(Problem("property schema_version", f"{number}: newer than this vslam knows "
                                    f"({SCHEMA_VERSION}); update vslam", EVERY_COMMAND))
    frame_count = properties.get("frame_count")
    if frame_count is not None and not str(frame_count).isdigit():
        problems.append(Problem("property frame_count", f"{frame_count!r} is not a number of frames",
                                REQUIRED_PROPERTIES["frame_count"]))
    return problems


def _check_camera(path: Path, prefix: str, layout: _Layout, result: CheckResult) -> list[Problem]:
    """Every camera pose is a finite rigid transform on a distinct frame."""
    entity = prefix + "/world/camera"
    if entity not in layout.components or FRAME_TIMELINE not in layout.timelines.get(entity, set()):
        return []
    table = read_entity(path, entity)
    if not table["frame"].dtype.is_integer():  # set_time("frame", duration=… / timestamp=…)
        return [Problem(f"timeline {FRAME_TIMELINE}", f"a {str(table['frame'].dtype).split('(')[0].lower()} "
                        "timeline, not a sequence: log the source's frame index with set_time(\"frame\", "
                        "sequence=i)", EVERY_COMMAND)]
    frames = [int(f) for f in table["frame"].to_list() if f is not None]
    result.frames = frames
    problems = []
    if len(set(frames)) != len(frames):
        problems.append(Problem(entity, "two poses on one frame (one T_world_cam per frame)", EVERY_COMMAND))
    translations = _rows(table, "Transform3D:translation", 3)
    if translations is not None and not np.isfinite(translations).all():
        problems.append(Problem(f"{entity}:Transform3D:translation", "not finite on some frame", EVERY_COMMAND))
    rotations = _rows(table, "Transform3D:mat3x3", 9)
    if rotations is not None:
        matrices = rotations.reshape(-1, 3, 3)
        error = np.abs(np.einsum("nji,njk->nik", matrices, matrices) - np.eye(3)).max(axis=(1, 2))
        if not (np.isfinite(error) & (error < 1e-3)).all():
            bad = [f for f, e in zip(frames, error, strict=False) if not (np.isfinite(e) and e < 1e-3)]
            problems.append(Problem(f"{entity}:Transform3D:mat3x3", f"not a rotation on frame {bad[0]}"
                                    + (f" and {len(bad) - 1} more" if len(bad) > 1 else ""), EVERY_COMMAND))
    return problems


def _rows(table: pl.DataFrame, column: str, width: int) -> np.ndarray | None:
    """(N, width) float rows of a one-instance component column (NaN rows when malformed), None when absent."""
    if column not in table.columns:
        return None
    values = [row[0] if isinstance(row, list) and row else row for row in table[column].to_list()]
    try:
        return np.array([np.asarray(v, np.float64).reshape(width) for v in values if v is not None])
    except (ValueError, TypeError):
        return np.full((1, width), np.nan)


def _check_health(path: Path, prefix: str) -> list[Problem]:
    entity = prefix + "/health"
    unknown = unknown_statuses(read_statuses(path, prefix), HEALTH_STATUSES)
    if unknown:
        return [Problem(f"{entity}:status", f"{unknown[0]!r} is not a health level ({', '.join(HEALTH_STATUSES)})",
                        ("inspect", "compare"))]
    return []


@contextmanager
def schema_contract(*paths: Path) -> Iterator[None]:
    """The contract of `vslam check` for every command that reads recordings: a recording it accepts works with
    every command; one it rejects ends the command in one line (`RecordingError`) naming its first problem,
    never a traceback. An unexpected error reading `paths` is turned into that line when a path does not
    conform; when every path conforms it is vslam's bug and is raised as it is (the property test finds it)."""
    try:
        yield
    except VslamError:  # already one line
        raise
    except typer.Exit:  # the command already said its one line (`fail`)
        raise
    except Exception as exc:  # noqa: BLE001 - see above: re-raised unless a recording breaks the schema
        for path in paths:
            try:
                result = check_recording(path)
            except RecordingError:
                raise
            except Exception:  # noqa: BLE001 - the checker failing too: the first error is the one to see
                raise exc from None
            if not result.conforms:
                count = len(result.problems)
                raise RecordingError(f"{path}: does not conform to recording schema {SCHEMA_VERSION}: "
                                     f"{result.problems[0].line()}"
                                     + (f" (and {count - 1} more: vslam check {path})" if count > 1 else
                                        f" (vslam check {path})")) from None
        raise


def format_check(result: CheckResult) -> Iterable[str]:
    """One line per problem and note, then the verdict."""
    for problem in result.problems:
        yield f"{result.path}: {problem.line()}"
    for note in result.notes:
        yield f"{result.path}: note: {note}"
    frames = (f", {len(result.frames)} frames {min(result.frames)}..{max(result.frames)}" if result.frames else "")
    if result.conforms:
        yield f"{result.path}: conforms to recording schema {SCHEMA_VERSION} ({result.entities} entities{frames})"
    else:
        yield (f"{result.path}: does not conform to recording schema {SCHEMA_VERSION}: {len(result.problems)} "
               f"problem{'s' if len(result.problems) != 1 else ''}")


__all__ = ["CheckResult", "Problem", "check_recording", "format_check", "schema_contract"]
