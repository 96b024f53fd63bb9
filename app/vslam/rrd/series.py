"""A pipeline's own series and stages (`vslam.log`: ``scalars=``, ``timings_ms=`` beyond vslam's names), found by
entity path and summarised for `vslam inspect` (``own_series``, ``stages_ms``) and `vslam compare`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vslam.rrd.read import RecordingError, open_store, read_entity

#: Where a pipeline's own series live: ``/metrics/custom/<name>`` or ``/metrics/custom/<plot>/<name>``.
CUSTOM = "/metrics/custom"
#: The plot of a series logged without one.
UNGROUPED = "pipeline series"


def entity_paths(path: Path) -> list[str]:
    """Every entity path of the recording (sorted); [] for a file holding no single recording."""
    try:
        reader, store, _blueprints = open_store(path)
        return sorted(reader.store(store=store).schema().entity_paths())
    except RecordingError:
        return []


def _values(path: Path, entity: str) -> np.ndarray:
    table = read_entity(path, entity)
    if table.is_empty() or "Scalars:scalars" not in table.columns:
        return np.zeros(0)
    return np.array([v[0] for v in table["Scalars:scalars"].to_list() if v], np.float64)


def stats(values: np.ndarray) -> dict[str, float] | None:
    """mean, median, p95, min, max of the finite values (None: none)."""
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {"mean": float(values.mean()), "median": float(np.median(values)),
            "p95": float(np.percentile(values, 95)), "min": float(values.min()), "max": float(values.max())}


def own_series(path: Path, prefix: str = "", entities: list[str] | None = None
               ) -> dict[str, dict[str, dict[str, float] | None]]:
    """{plot: {name: stats}} of the pipeline's own series (``{prefix}/metrics/custom/…``; a series without a
    plot under `UNGROUPED`); {} when there are none."""
    root = f"{prefix}{CUSTOM}/"
    plots: dict[str, dict[str, dict[str, float] | None]] = {}
    for entity in entities if entities is not None else entity_paths(path):
        if not entity.startswith(root):
            continue
        parts = entity.removeprefix(root).split("/")
        plot, name = (parts[0], "/".join(parts[1:])) if len(parts) > 1 else (UNGROUPED, parts[0])
        values = _values(path, entity)
        if len(values):
            plots.setdefault(plot, {})[name] = stats(values)
    return plots


def own_stages(path: Path, known: tuple[str, ...], prefix: str = "", entities: list[str] | None = None
               ) -> dict[str, dict[str, float] | None]:
    """{stage: stats} of ``{prefix}/metrics/timing_ms/<stage>`` for stages not in `known` (vslam's)."""
    root = f"{prefix}/metrics/timing_ms/"
    stages = {}
    for entity in entities if entities is not None else entity_paths(path):
        name = entity.removeprefix(root)
        if entity.startswith(root) and "/" not in name and name not in known:
            stages[name] = stats(_values(path, entity))
    return stages


def format_own_series(plots: dict[str, dict[str, Any]] | None) -> list[str]:
    """`vslam inspect`'s table of the pipeline's own series, by plot."""
    if not plots:
        return []
    lines = ["", "own series (the pipeline's scalars=, by plot)      mean       min       max"]
    for plot, series in plots.items():
        for name, summary in series.items():
            if summary is not None:
                lines.append(f"  {plot + ': ' + name:<45} {summary['mean']:9.3f} {summary['min']:9.3f} "
                             f"{summary['max']:9.3f}")
    return lines
