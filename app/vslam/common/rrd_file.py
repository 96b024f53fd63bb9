"""What writing and reading a `.rrd` both need: its error, whether a file is finalised, how run properties are
flattened and how the engine config is stored. Beneath `recording` (writing) and `rrd` (reading), so that neither
imports the other for these."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

from rerun.chunk import RrdReader
from rerun.error_utils import RerunWarning

from vslam_core.errors import VslamError


class RecordingError(VslamError):
    """A file that is missing, truncated or not a Rerun recording."""


def has_footer(path: Path, strict: bool = False) -> bool:
    """Whether `path` is a finalised recording (footer and manifest). A file the reader cannot open at all
    is `False`, or with `strict` a `RecordingError`."""
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RerunWarning)
            RrdReader(path)
    except Exception as exc:  # the reader raises plain exceptions for every kind of bad file
        if strict:
            raise RecordingError(f"{path}: not a readable Rerun recording ({first_line(exc)})") from None
        return False
    return not any("no footer" in str(w.message) for w in caught)


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (library errors can span many lines)."""
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__


def flatten(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"pose": {"seed": 0}} -> {"pose.seed": 0}, as the recording's config properties are stored."""
    flat: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


#: The engine config in a recording (``/__properties/config``): two components, the flattened keys and their
#: values as JSON, rather than one component per key. Rerun's file writer keeps, until the file is closed, a
#: row per chunk with a cell per component the recording has ever used (~65 bytes each); the config's ~150 keys
#: as components made that ~17 KB a chunk on the map's recordings, ~30 KB a frame (docs/long-drive.md).
CONFIG_KEY, CONFIG_VALUE = "key", "value"


def config_columns(config: dict[str, Any]) -> dict[str, list[str]]:
    """The nested engine config (`EngineConfig.to_dict`) as the two components it is recorded as."""
    flat = flatten(config)
    return {CONFIG_KEY: list(flat), CONFIG_VALUE: [json.dumps(value) for value in flat.values()]}


def config_from_columns(row: dict[str, Any]) -> dict[str, Any]:
    """The flattened config back from a recorded row: {key: value}. A recording of schema 1 (a component per
    key), or a row whose keys and values do not pair up, is returned as it is; a value that is not JSON (another
    writer's) stays its text."""
    keys, values = row.get(CONFIG_KEY), row.get(CONFIG_VALUE)
    if not isinstance(keys, list) or not isinstance(values, list) or len(keys) != len(values) or len(row) != 2:
        return row
    return {str(key): _json_or_text(value) for key, value in zip(keys, values, strict=True)}


def _json_or_text(value: Any) -> Any:
    try:
        return json.loads(value)
    except (TypeError, ValueError):
        return value
