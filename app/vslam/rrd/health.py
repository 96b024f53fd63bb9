"""The pipeline's own per-frame health (``{prefix}/health``: ``status`` ok / warn / fail, ``reasons`` comma-separated
codes) read back: the one parser of that entity for `inspect`, `check` and the suspect finder."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from vslam.rrd.read import read_entity


@dataclass(frozen=True)
class FrameHealth:
    """One frame's health as recorded: `status` as written (`unknown_statuses` validates it)."""

    status: str
    reasons: list[str]


def read_health(path: Path, prefix: str = "") -> dict[int, FrameHealth]:
    """Health by frame, in the file's order; empty when the recording has no ``{prefix}/health:status``."""
    table = _table(path, prefix)
    if table is None:
        return {}
    reasons = table["reasons"].to_list() if "reasons" in table.columns else [None] * len(table)
    return {int(frame): FrameHealth(_text(status), [r for r in _text(codes).split(",") if r])
            for frame, status, codes in zip(table["frame"].to_list(), table["status"].to_list(), reasons, strict=True)}


def read_statuses(path: Path, prefix: str = "") -> list[str]:
    """The recorded statuses alone, whatever the frame timeline holds (for `vslam check`)."""
    table = _table(path, prefix)
    return [] if table is None else [_text(s) for s in table["status"].to_list()]


def unknown_statuses(statuses: Iterable[str], known: tuple[str, ...]) -> list[str]:
    """The statuses that are not in `known`, sorted (a recording that does not conform)."""
    return sorted(set(statuses) - set(known))


def _table(path: Path, prefix: str) -> pl.DataFrame | None:
    table = read_entity(path, f"{prefix}/health")
    return None if table.is_empty() or "status" not in table.columns else table


def _text(value: object) -> str:
    """One `AnyValues` cell as text (a one-element list as the reader gives it, or the bare value); "" for none."""
    if isinstance(value, list):
        value = value[0] if value else None
    return "" if value is None else str(value)
