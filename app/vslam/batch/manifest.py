"""The manifest of `vslam eval --manifest`: one drive log per row (CSV with a header, or TOML ``[[log]]``
tables), checked completely before any log runs.

Columns are named like the `vslam run` options; relative paths are relative to the manifest's folder, and
`~` and environment variables (`$KITTI_ROOT`, `${KITTI_ROOT}`) in paths are expanded, so that one manifest
serves machines that keep the data in different places.
Every problem is one `ManifestError` line naming the row, e.g.
``LOGS.csv row 4 (name 'kitti-05-b'): frames '10:x' is not START:END[:STEP]``. A log whose files exist
but are broken inside (a corrupt image, a truncated bag) passes: it fails at run time, as a failed row.
"""

from __future__ import annotations

import csv
import os
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vslam.runs import camera_height_problem
from vslam_core.errors import VslamError
from vslam_core.sources.base import FrameRange
from vslam_core.sources.folder import parse_intrinsics
from vslam_core.sources.open import SYNTHETIC

#: columns besides `name` and `source` (all optional)
OPTIONAL = ("sequence", "frames", "intrinsics", "calib", "gt", "gt_times", "topic", "gt_topic", "scale",
            "camera_height", "backend", "config", "calib_scale")
COLUMNS = ("name", "source", *OPTIONAL)
PATH_COLUMNS = ("calib", "gt", "config")
SCALES = ("gt", "none", "height")
BACKENDS = ("vo", "map")
#: a log's name becomes file names in the report folder
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
#: $NAME or ${NAME} in a path
ENV_VARIABLE = re.compile(r"\$(?:(\w+)|\{(\w+)\})")


class ManifestError(VslamError):
    """The manifest cannot be read, or one of its rows is invalid (one line, naming the row)."""


@dataclass(frozen=True)
class LogSpec:
    """One log of the manifest, its paths resolved: everything `open_source` and the config need."""

    index: int  # position in the manifest (0-based): the report's row order and the shard rule
    name: str
    source: str  # a path, or "synthetic"
    sequence: str | None = None
    frames: str | None = None
    intrinsics: str | None = None
    calib: Path | None = None
    gt: Path | None = None
    topic: str | None = None
    gt_topic: str | None = None
    scale: str | None = None
    camera_height: float | None = None
    backend: str | None = None
    config: Path | None = None
    calib_scale: float | None = None  # --calib-scale: the row's calibration resized for resized frames


def read_manifest(path: Path) -> list[LogSpec]:
    """Every log of the manifest at `path` (CSV, or TOML by its ``.toml`` suffix), checked."""
    if not path.is_file():
        raise ManifestError(f"{path}: manifest not found")
    rows = _toml_rows(path) if path.suffix.lower() == ".toml" else _csv_rows(path)
    if not rows:
        raise ManifestError(f"{path}: no logs in the manifest")
    specs: list[LogSpec] = []
    seen: dict[str, str] = {}
    for index, (label, row) in enumerate(rows):
        spec = _spec(path, label, index, row)
        if spec.name in seen:
            raise ManifestError(f"{path.name} {label} (name {spec.name!r}): duplicate name (also {seen[spec.name]})")
        seen[spec.name] = label
        specs.append(spec)
    return specs


def _csv_rows(path: Path) -> list[tuple[str, dict[str, str]]]:
    """(label, row) of every non-empty CSV row; the header is row 1, so the first log is row 2."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = [h.strip() for h in next(reader, [])]
            body = [(number, row) for number, row in enumerate(reader, start=2) if any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ManifestError(f"{path}: cannot read the manifest ({exc})") from None
    if not header:
        raise ManifestError(f"{path}: empty manifest (expected a header row: name,source,…)")
    _check_columns(path, "header", header)
    rows = []
    for number, cells in body:
        if len(cells) > len(header):
            raise ManifestError(f"{path.name} row {number}: {len(cells)} cells but the header has {len(header)}")
        rows.append((f"row {number}", dict(zip(header, (c.strip() for c in cells), strict=False))))
    return rows


def _toml_rows(path: Path) -> list[tuple[str, dict[str, str]]]:
    """(label, row) of every ``[[log]]`` table; values become strings, as CSV cells are."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a BOM (Windows editors) is not TOML
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ManifestError(f"{path}: cannot read the manifest ({exc})") from None
    extra = sorted(set(data) - {"log"})
    if extra or not isinstance(data.get("log", []), list):
        raise ManifestError(f"{path}: expected only [[log]] tables, found {extra[0] if extra else 'log = …'!r}")
    rows = []
    for number, table in enumerate(data.get("log", []), start=1):
        _check_columns(path, f"log {number}", list(table))
        rows.append((f"log {number}", {k: _cell(v) for k, v in table.items()}))
    return rows


def _cell(value: Any) -> str:
    return ",".join(map(str, value)) if isinstance(value, list) else str(value)


def _check_columns(path: Path, where: str, names: list[str]) -> None:
    unknown = [n for n in names if n not in COLUMNS]
    if unknown:
        raise ManifestError(f"{path.name} {where}: unknown column {unknown[0]!r} (known: {', '.join(COLUMNS)})")
    for required in ("name", "source"):
        if required not in names:
            raise ManifestError(f"{path.name} {where}: no {required!r} column")


def _spec(path: Path, label: str, index: int, row: dict[str, str]) -> LogSpec:
    """One row as a `LogSpec`, every value checked (files exist, config loads, numbers parse)."""
    values = {k: v for k, v in row.items() if v != ""}
    name = values.get("name", "")
    where = f"{path.name} {label}" + (f" (name {name!r})" if name else "")

    def bad(message: str) -> ManifestError:
        return ManifestError(f"{where}: {message}")

    def number(key: str, unit: str = "") -> float | None:
        """The row's `key` as a float (None when empty); a row error naming it when it is not a number."""
        if key not in values:
            return None
        try:
            return float(values[key])
        except ValueError:
            raise bad(f"{key} {values[key]!r} is not a number{unit}") from None

    if not NAME_PATTERN.match(name):
        raise bad(f"name {name!r} must be letters, digits, '.', '_' or '-' (it names the report's files)")
    if "source" not in values:
        raise bad("no source")
    if "gt_times" in values:
        raise bad("gt_times applies to `vslam eval --trajectory` files only; a log's frames are matched to its "
                  "ground truth by their own timestamps")
    base = path.resolve().parent

    def resolve(key: str) -> Path:
        unset = [m.group(1) or m.group(2) for m in ENV_VARIABLE.finditer(values[key])
                 if (m.group(1) or m.group(2)) not in os.environ]
        if unset:
            raise bad(f"{key} {values[key]!r}: environment variable {unset[0]} is not set")
        return base / os.path.expanduser(os.path.expandvars(values[key]))

    source = values["source"]
    if source != SYNTHETIC:
        source_path = resolve("source")
        if not source_path.exists():
            raise bad(f"source {source!r}: no such file or folder ({source_path})")
        source = str(source_path)
    paths: dict[str, Path] = {}
    for key in PATH_COLUMNS:
        if key in values:
            paths[key] = resolve(key)
            if not paths[key].exists():
                raise bad(f"{key} {values[key]!r}: no such file ({paths[key]})")
    try:
        FrameRange.parse(values.get("frames"))
    except VslamError:
        raise bad(f"frames {values['frames']!r} is not START:END[:STEP] (END > START ≥ 0, STEP ≥ 1)") from None
    if "intrinsics" in values:
        try:
            parse_intrinsics(values["intrinsics"])
        except VslamError:
            raise bad(f"intrinsics {values['intrinsics']!r} is not fx,fy,cx,cy (four numbers, fx and fy "
                      "positive)") from None
    for key, allowed in (("scale", SCALES), ("backend", BACKENDS)):
        if key in values and values[key] not in allowed:
            raise bad(f"{key} {values[key]!r} is not one of {', '.join(allowed)}")
    camera_height = number("camera_height", " (metres)")
    problem = camera_height_problem(camera_height) if camera_height is not None else None
    if problem is not None:
        raise bad(problem.replace("--camera-height", "camera_height"))
    calib_scale = number("calib_scale")
    if calib_scale is not None and not 0.01 <= calib_scale <= 100.0:
        raise bad(f"calib_scale {calib_scale:g} is outside [0.01, 100]")
    if "config" in paths:
        from vslam_core.config_file import load_config

        try:
            load_config(paths["config"])
        except VslamError as exc:
            raise bad(str(exc)) from None
    return LogSpec(index, name, source, values.get("sequence"), values.get("frames"), values.get("intrinsics"),
                   paths.get("calib"), paths.get("gt"), values.get("topic"), values.get("gt_topic"),
                   values.get("scale"), camera_height, values.get("backend"), paths.get("config"), calib_scale)


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` (1 ≤ K ≤ N) as (K, N); a `ManifestError` otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text)
    if match is None or not 1 <= int(match[1]) <= int(match[2]):
        raise ManifestError(f"--shard {text!r}: expected K/N with 1 ≤ K ≤ N, e.g. 1/4")
    return int(match[1]), int(match[2])


def shard(specs: list[LogSpec], k: int, n: int) -> list[LogSpec]:
    """The K-th (1-based) of N deterministic slices: manifest rows i (0-based) with i % N == K - 1."""
    return [s for s in specs if s.index % n == k - 1]
