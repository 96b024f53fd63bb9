"""What a recording says about how it was made: its run properties and engine config, read back, rewritten
when the file changes (`crop`), and compared (`inspect`, `compare`).

Run properties live in the static entity ``/__properties/run`` (``/__properties/a/run``, ``…/b/run``, … in a
comparison), the flattened engine config in ``…/config``, the recording name in ``/__properties``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import rerun as rr
import rerun.archetypes as rra
from rerun.chunk import Chunk

from vslam.common import config_from_columns, flatten
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig
from vslam_core.sources.base import describe_indices

PROPERTIES = "/__properties"
ROW_ID = "rerun.controls.RowId"
#: Run properties worth comparing between two runs (besides the config), in this order; then every other
#: property (a pipeline's own, e.g. ``bug``) but `UNCOMPARED`.
RUN_KEYS = ("source", "source_path", "frames", "frame_count", "scale", "backend", "detail", "inject", "stopped")
#: Properties that differ between any two files and say nothing about how the run was made.
UNCOMPARED = frozenset({"name", "recording_id"})


def default_config() -> dict[str, Any]:
    """The default engine config, flattened like a recording's ``config`` properties."""
    return flatten(EngineConfig().to_dict())


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b or str(a).lower() == str(b).lower()
    if isinstance(a, int | float) and isinstance(b, int | float):
        return float(a) == float(b)
    return str(a) == str(b)


def differences(a: dict[str, Any], b: dict[str, Any], keys: list[str] | None = None) -> list[tuple[str, Any, Any]]:
    """(key, value in a, value in b) for every key whose values differ (None where a side lacks it)."""
    names = keys if keys is not None else sorted({*a, *b})
    return [(k, a.get(k), b.get(k)) for k in names if (k in a) != (k in b) or not _same(a.get(k), b.get(k))]


def non_default(config: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """(key, default, value) of a recording's config keys that differ from the default config (keys a
    newer or older vslam does not know are listed too)."""
    return [(key, default, value) for key, default, value in differences(default_config(), config)
            if value is not None]


def show(value: Any) -> str:
    return "—" if value is None else str(value)


def config_lines(diffs: list[tuple[str, Any, Any]], arrow: bool = True) -> list[str]:
    """``key: a → b`` lines (or ``key = b`` without `arrow`)."""
    return [f"{key}: {show(a)} → {show(b)}" if arrow else f"{key} = {show(b)}" for key, a, b in diffs]


def name_with_frames(name: str, frames: str) -> str:
    """A recording name with its ``frames …`` part replaced (``vslam kitti-00 frames 0:300 scale gt``)."""
    if re.search(r"\bframes \S+", name):
        return re.sub(r"\bframes \S+", f"frames {frames}", name, count=1)
    return name


def properties_chunk(entity: str, values: dict[str, str]) -> Chunk:
    """A static chunk holding run properties at `entity` (e.g. ``/__properties/run``)."""
    columns = rr.AnyValues.columns(**{k: [v] for k, v in values.items()})  # type: ignore[arg-type]
    return Chunk.from_columns(entity, indexes=[], columns=columns)


def name_chunk(name: str) -> Chunk:
    """The static recording-name chunk (``/__properties``, ``RecordingInfo:name``)."""
    return Chunk.from_columns(PROPERTIES, indexes=[], columns=rra.RecordingInfo.columns(name=[name]))


def read_properties(path: Path, entity: str) -> dict[str, Any]:
    """The static properties at `entity` (e.g. ``/__properties/run``) as {key: value}; {} when absent."""
    row = latest_static_row(path, entity)
    return {
        k: (v[0] if isinstance(v, list) and len(v) == 1 else v)
        for k, v in row.items() if not k.startswith("rerun.") and v is not None
    }


def read_config(path: Path, prefix: str = "") -> dict[str, Any]:
    """The engine config a run of `path` was made with (``/__properties[/<prefix>]/config``), flattened
    (``pose.seed`` …), from either recording schema; {} when absent (another system's run)."""
    return config_from_columns(read_properties(path, f"{PROPERTIES}{prefix}/config"))


def latest_static_row(path: Path, entity: str) -> dict[str, Any]:
    """The last static row logged to `entity` (static data is last-write-wins: an interrupted run re-logs its
    properties), as {column: value}; {} when there is none."""
    table = read_entity(path, entity, static=True)
    if table.is_empty():
        return {}
    if ROW_ID in table.columns:
        table = table.sort(ROW_ID)
    return table.row(len(table) - 1, named=True)


def comparison_prefixes(path: Path) -> list[str]:
    """The run prefixes of a `vslam compare` recording (``["a", "b", "c"]``, from the ``label_<prefix>`` keys of
    ``/__properties/compare``); [] for a single run."""
    compare = read_properties(path, f"{PROPERTIES}/compare")
    return sorted(key.removeprefix("label_") for key in compare if key.startswith("label_"))


def cropped_properties(path: Path, start: int, end: int, cut_short: bool = False, cropped: bool = True
                       ) -> dict[str, Chunk]:
    """Replacement chunks (by entity path) for the run properties and recording name of `path` cut down to
    frames ``start <= frame < end``: ``frames`` and ``frame_count`` say which frames the file holds a camera pose
    of, ``cropped_from`` the frames of the original run (with `cropped`). A recording `cut_short` (no footer: the
    run was killed) gets a ``stopped`` entry saying so, unless it has one. Every run of a comparison is covered."""
    replacements: dict[str, Chunk] = {}
    for prefix in ("", *(f"/{p}" for p in comparison_prefixes(path))):
        entity = f"{PROPERTIES}{prefix}/run"
        props = read_properties(path, entity)
        if not props:
            continue
        camera = read_entity(path, f"{prefix}/world/camera")
        frames = sorted({f for f in camera["frame"].to_list() if start <= f < end}) if "frame" in camera else []
        held = describe_indices(frames)
        values = {k: str(v) for k, v in props.items()}
        if cut_short and "stopped" not in values:
            values["stopped"] = cut_short_note(frames, values.get("frames", "?"))
        if cropped:
            values["cropped_from"] = values.get("cropped_from", values.get("frames", "?"))
        values.update(frames=held, frame_count=str(len(frames)))
        if "name" in values:
            values["name"] = name_with_frames(values["name"], held)
        replacements[entity] = properties_chunk(entity, values)
        if prefix == "" and "name" in values:
            replacements[PROPERTIES] = name_chunk(values["name"])
    return replacements


def cut_short_note(frames: list[int], planned: str) -> str:
    """The ``stopped`` entry of a recording found cut short (no footer), `frames` those with a camera pose."""
    held = f"after frame {frames[-1]}" if frames else "before any camera pose was written"
    return f"the run of frames {planned} was cut short {held} (no footer: it was killed, crashed or ran out of disk)"


def run_differences(report_a: dict[str, Any], report_b: dict[str, Any], labels: tuple[str, str] = ("A", "B")
                    ) -> list[str]:
    """What differs in how two runs were made (two `inspect_recording` reports, named by `labels`): run
    properties (source, frames, scale, backend, detail, inject, …, then any other, e.g. a pipeline's ``bug``)
    and every engine config key, as ``key: a → b`` lines."""
    props_a, props_b = report_a["properties"], report_b["properties"]
    others = sorted({*props_a, *props_b} - set(RUN_KEYS) - UNCOMPARED)
    run = differences(props_a, props_b, [*RUN_KEYS, *others])
    lines = [f"run         {line}" for line in config_lines(run)]
    without = [side for side, report in zip(labels, (report_a, report_b), strict=True) if not report["config"]]
    if without:  # another system's trajectory (`vslam eval --trajectory`): no engine config to compare
        return lines + [f"config      {' and '.join(without)} not run by the engine (no config to compare)"]
    config = differences(report_a["config"], report_b["config"])
    lines += [f"config      {line}" for line in config_lines(config)]
    if not config:
        lines.append("config      the same in both runs")
    return lines
