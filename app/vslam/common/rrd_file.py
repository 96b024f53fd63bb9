"""What writing and reading a `.rrd` both need: its error, whether a file is finalised, and how run
properties are flattened. Beneath `recording` (writing) and `rrd` (reading), so that neither imports the other
for these."""

from __future__ import annotations

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
