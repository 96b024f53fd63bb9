"""Read `.rrd` recordings back without a viewer (tests, `inspect`, `crop`, `compare`)."""

from __future__ import annotations

from pathlib import Path

import polars as pl
from rerun.chunk import RrdReader

from vslam_core.errors import VslamError


class RecordingError(VslamError):
    """A file that is missing, truncated or not a Rerun recording."""


def read_entity(path: Path, entity: str, static: bool = False) -> pl.DataFrame:
    """All rows logged to `entity` (``/a`` exactly, ``/a/**`` a subtree) as one polars frame: the
    timelines (``frame``, ``time``) and one column per ``Archetype:component``."""
    try:
        chunks = RrdReader(path).stream().filter(content=entity, is_static=static).to_chunks()
    except Exception as exc:  # the reader raises plain exceptions for every kind of bad file
        raise RecordingError(f"{path}: not a readable Rerun recording ({_first_line(exc)})") from None
    frames = [pl.from_arrow(chunk.to_record_batch()) for chunk in chunks]
    if not frames:
        return pl.DataFrame()
    table = pl.concat([f for f in frames if isinstance(f, pl.DataFrame)], how="diagonal_relaxed")
    return table.sort("frame") if "frame" in table.columns else table


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__
