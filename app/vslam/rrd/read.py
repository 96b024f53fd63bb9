"""Read `.rrd` recordings back without a viewer, and run the `rerun` CLI (tests, `inspect`, `crop`, `compare`)."""

from __future__ import annotations

import atexit
import functools
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from rerun.chunk import LazyStore, RrdReader, StoreEntry
from rerun.error_utils import RerunWarning

from vslam.common import RecordingError, first_line, has_footer

if TYPE_CHECKING:
    import polars as pl


@dataclass(frozen=True)
class Readable:
    """What to read for a recording: the file itself, or for one cut short a finalised temporary copy."""

    path: Path
    cut_short: bool  # no footer: the run was killed (SIGKILL, OOM, CI timeout), crashed or ran out of disk


#: why a recording has no footer, as every command says it
CUT_SHORT = "no footer: the run was killed, crashed or ran out of disk"


def no_frames(path: Path, cut_short: bool) -> str:
    """The one line for a recording without a camera frame: cut short before its first frame was whole, or
    not a run's recording."""
    if cut_short:
        return f"{path}: cut short before its first frame was completely written ({CUT_SHORT}): no frame to read"
    return f"{path}: no camera frames in this recording (not written by `vslam run`?)"


_READABLE: dict[tuple[str, int, int], Readable] = {}  # (file, size, mtime) → what to read, found once per process


def readable(path: Path) -> Readable:
    """`path` when it is a complete recording. A recording cut short has chunks but no footer, which
    `RrdReader.store()` and the viewer's random access need: it is read from a finalised copy made once
    per process with `rerun rrd filter` (`finalise`). Every way the file can be bad is a `RecordingError`."""
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    if path.is_dir():
        raise RecordingError(f"{path}: is a folder, not a Rerun recording")
    if (problem := version_problem(path)) is not None:
        raise RecordingError(problem)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _READABLE:
        if has_footer(path, strict=True):
            _READABLE[key] = Readable(path, cut_short=False)
        else:
            copy = Path(tempfile.mkdtemp(prefix="finalised-", dir=_copies_dir())) / path.name
            finalise(path, copy)
            _READABLE[key] = Readable(copy, cut_short=True)
    return _READABLE[key]


#: the start of every .rrd: Rerun's ``FileHeader``, magic ``RRF2`` then the version that wrote it (major, minor,
#: patch, suffix byte) and 4 bytes of encoding options
RRD_MAGIC = b"RRF2"


def written_by(path: Path) -> tuple[int, int, int] | None:
    """The Rerun version (major, minor, patch) in `path`'s file header; None when it has no Rerun header."""
    try:
        with path.open("rb") as file:
            header = file.read(8)
    except OSError:
        return None
    if len(header) < 8 or header[:4] != RRD_MAGIC:
        return None
    return header[4], header[5], header[6]


def version_problem(path: Path) -> str | None:
    """A recording written by another Rerun minor version than this one's (Rerun's format changes between minor
    versions; its reader logs a coloured warning and may fail): one line saying which wrote it, and what to do."""
    import rerun

    version = written_by(path)
    local = tuple(int(part) for part in rerun.__version__.split(".")[:3] if part.isdigit())
    if version is None or len(local) < 2 or version[:2] == local[:2]:
        return None
    wrote, here = ".".join(map(str, version)), rerun.__version__
    if version[:2] > local[:2]:
        return (f"{path}: written by Rerun {wrote}, newer than this vslam's Rerun {here}: open it with Rerun {wrote} "
                "or update vslam")
    return (f"{path}: written by Rerun {wrote}, older than this vslam's Rerun {here}: convert it with `rerun rrd "
            f"migrate {path}` (Rerun {here})")


def finalise(source: Path, output: Path) -> None:
    """Write `source`'s whole messages to `output` with a footer: `rerun rrd filter` reads a footer-less
    file message by message and stops cleanly at a half-written last one (what SIGKILL or a full disk
    leaves). Raises `RecordingError` when nothing usable is left."""
    run_rerun_cli(source, "rrd", "filter", "--continue-on-error", "-o", str(output), str(source))
    try:
        recordings = RrdReader(output).recordings()
    except Exception as exc:  # noqa: BLE001 - any failure means the copy is unusable
        raise RecordingError(f"{source}: not a readable Rerun recording ({first_line(exc)})") from None
    if not recordings:
        if written_by(source) is not None:  # a Rerun file whose data never reached the disk
            raise RecordingError(f"{source}: cut short before any of its recording data was written ({CUT_SHORT})")
        raise RecordingError(f"{source}: not a readable Rerun recording (no recording data in it)")


@functools.cache
def _copies_dir() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="vslam-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


@contextmanager
def _reading(path: Path) -> Iterator[RrdReader]:
    """An `RrdReader` of the recording (of its finalised copy when it was cut short); every way the file can
    be bad becomes one `RecordingError`."""
    data = readable(path).path
    with _bad_file_is_one_error(path):
        yield _open_reader(data)


def _open_reader(data: Path | str) -> RrdReader:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RerunWarning)
        return RrdReader(data)


@contextmanager
def _bad_file_is_one_error(path: Path) -> Iterator[None]:
    """Whatever the reader raises while reading `path` becomes one `RecordingError` naming it (the reader raises
    plain exceptions for every kind of bad file)."""
    try:
        yield
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - see above
        raise RecordingError(f"{path}: not a readable Rerun recording ({first_line(exc)})") from None


def read_entity(path: Path, entity: str, static: bool = False) -> pl.DataFrame:
    """All rows logged to `entity` (``/a`` exactly, ``/a/**`` a subtree) as one polars frame: the
    timelines (``frame``, ``time``) and one column per ``Archetype:component``."""
    import polars as pl  # here: writing a recording (`has_footer`, `RecordingError`) never needs it

    data = readable(path).path
    stat = data.stat()
    with _bad_file_is_one_error(path):
        store = _recording_store(str(data.resolve()), stat.st_size, stat.st_mtime_ns)
        # not one recording store (e.g. a file of the Rerun SDK's): every store, scanned
        source = store if store is not None else _open_reader(data)
        chunks = source.stream().filter(content=entity, is_static=static).to_chunks()
    frames = [pl.from_arrow(chunk.to_record_batch()) for chunk in chunks]
    if not frames:
        return pl.DataFrame()
    table = pl.concat([f for f in frames if isinstance(f, pl.DataFrame)], how="diagonal_relaxed")
    return table.sort("frame") if "frame" in table.columns else table


def read_events(path: Path) -> list[tuple[int, str, str]]:
    """Every line of the recording's text logs (`/events` and below it, e.g. `/events/at_end`) as (frame,
    level, text), by frame: a row holds all of a frame's events, one instance each."""
    table = read_entity(path, "/events/**")
    if table.is_empty():
        return []
    rows = zip(table["frame"].to_list(), table["TextLog:level"].to_list(), table["TextLog:text"].to_list(), strict=True)
    return [(frame, level, text) for frame, levels, texts in rows
            for level, text in zip(levels or [""] * len(texts), texts, strict=True)]


@functools.lru_cache(maxsize=16)
def _recording_store(data: str, _size: int, _mtime_ns: int) -> LazyStore | None:
    """The recording store of a finalised `.rrd` (keyed by its size and time too: a file written again is read
    again). Its manifest indexes the chunks by entity, so `read_entity` reads only that entity's chunks (~0.1 ms
    for a few series, against ~20 ms for a scan of a 12 MB file with `RrdReader.stream`), and it is read once
    per file rather than once per entity (`vslam inspect` reads ~30). None for a file without exactly one
    recording store."""
    reader = _open_reader(data)
    recordings = reader.recordings()
    return reader.store(store=recordings[0]) if len(recordings) == 1 else None


def open_store(source: Path) -> tuple[RrdReader, StoreEntry, list[StoreEntry]]:
    """Reader, the one recording store, and the blueprint stores of a `.rrd` (of its finalised copy when it
    was cut short: see `readable`)."""
    with _reading(source) as reader:
        recordings, blueprints = reader.recordings(), reader.blueprints()
        if len(recordings) != 1:
            raise RecordingError(f"{source}: holds {len(recordings)} recordings, expected exactly one")
        for store in [*recordings, *blueprints]:
            reader.store(store=store)  # reads and checks the manifest (milliseconds)
    return reader, recordings[0], blueprints


#: The components of a blueprint's `/view/*` entities that `blueprint_view_names` reads.
_VIEW_COLUMNS = ("ViewBlueprint:display_name", "ViewBlueprint:class_identifier", "ViewBlueprint:visible")


def blueprint_view_names(path: Path) -> list[str] | None:
    """The display names of the views in the recording's embedded blueprint (its last value per view; views
    set invisible left out), or None when the file has no blueprint or a view has no name (the viewer then
    names it by its class, which only the viewer knows). Read from the blueprint store's `/view/*` entities
    with pyarrow (polars cannot hold some of the blueprint's union columns)."""
    names: dict[str, str | None] = {}
    hidden: set[str] = set()
    with _reading(path) as reader:
        for blueprint in reader.blueprints():
            for chunk in reader.store(store=blueprint).stream().to_chunks():
                entity = chunk.entity_path
                if not entity.startswith("/view/") or entity.count("/") != 2:
                    continue
                batch = chunk.to_record_batch()
                for column, values in zip(batch.schema.names, batch.columns, strict=True):
                    if not column.endswith(_VIEW_COLUMNS):  # the timelines' ns times need pandas as Python values
                        continue
                    last = next((v for v in reversed(values.to_pylist()) if v), None)
                    if column.endswith("ViewBlueprint:display_name"):
                        names[entity] = last[0] if last else names.get(entity)
                    elif column.endswith("ViewBlueprint:class_identifier"):
                        names.setdefault(entity, None)
                    elif column.endswith("ViewBlueprint:visible") and last == [False]:
                        hidden.add(entity)
    shown = [name for entity, name in names.items() if entity not in hidden]
    if not shown or any(name is None for name in shown):
        return None
    return [name for name in shown if name is not None]


def run_rerun_cli(source: Path, *args: str) -> None:
    """Run the `rerun` binary of the installed rerun-sdk (not `python -m rerun_cli`: it exits 0 on errors)."""
    try:
        done = subprocess.run([rerun_binary(), *args], capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RecordingError(f"{source}: cannot run the rerun CLI ({first_line(exc)})") from None
    if done.returncode != 0:
        errors = [line for line in done.stderr.splitlines() if "ERROR" in line or line.startswith("Error")]
        detail = (errors or done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        raise RecordingError(f"{source}: rerun {' '.join(args[:2])} failed ({detail.strip()})")


def rerun_binary() -> str:
    """Same lookup as the `rerun` console script of rerun-sdk (``rerun_cli/__main__.py``)."""
    if override := os.environ.get("RERUN_CLI_PATH"):
        return override
    import rerun_cli  # the package that ships the binary with rerun-sdk

    folder = Path(rerun_cli.__file__).parent
    suffix = ".exe" if sys.platform.startswith("win") else ""
    candidates = [folder / "Rerun.app" / "Contents" / "MacOS" / "Rerun"] if sys.platform == "darwin" else []
    candidates.append(folder / f"rerun{suffix}")
    for candidate in candidates:
        if candidate.exists():
            return str(candidate)
    found = shutil.which("rerun")
    if found is None:
        raise RecordingError("the rerun CLI of rerun-sdk was not found")
    return found


def same_file(source: Path, output: Path) -> bool:
    if output.exists():
        try:
            return os.path.samefile(source, output)
        except OSError:
            return False
    return source.resolve() == output.resolve()


def work_dir_beside(output: Path) -> Path:
    """A hidden temporary folder next to `output`, so the finished file is moved into place atomically."""
    parent = output.parent if str(output.parent) else Path(".")
    try:
        return Path(tempfile.mkdtemp(prefix=f".{output.name}.", suffix=".tmp", dir=parent))
    except OSError as exc:
        raise RecordingError(f"{output}: cannot write beside it ({exc.strerror})") from None
