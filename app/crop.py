"""Cut a recording down to a range of the ``frame`` timeline (for attaching to bug reports).

How (rerun-sdk 0.41):

1. The recording store is cropped in-process with the chunk API: ``RrdReader(src).stream()`` →
   ``flat_map`` (static chunks and chunks without a ``frame`` time pass through untouched, temporal
   chunks keep only their rows with START <= frame < END, re-wrapped with ``Chunk.from_record_batch``,
   which keeps the chunk id and the row ids) → ``LazyChunkStream.write_rrd``.
2. ``write_rrd`` can only write one *recording* store, and no Python API writes a *blueprint* store, so
   the embedded default blueprint is carried over with the ``rerun`` CLI shipped with the SDK:
   ``rerun rrd filter --drop-entity <every recording entity>`` leaves exactly the source's blueprint
   store (same store id, chunks and ``BlueprintActivationCommand``), and a second ``rerun rrd filter``
   with no drops concatenates blueprint + cropped recording into one file with one footer.
   (``rerun rrd merge`` would turn the activation into ``make_active: true``; ``rerun rrd split`` can cut
   by time but drops static data such as the camera's Pinhole, and changes the recording id.)

Everything is written into a hidden temporary folder beside the output and renamed at the end.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import Chunk, RrdReader, StoreEntry
from rerun.error_utils import RerunWarning

from app.rrd import RecordingError

FRAME = "frame"


@dataclass(frozen=True)
class CropSummary:
    """What `crop_recording` kept: frames ``first_frame..last_frame`` (inclusive), file sizes in bytes."""

    output: Path
    first_frame: int
    last_frame: int
    frame_count: int
    input_bytes: int
    output_bytes: int


class _FrameFilter:
    """`flat_map` callback: keeps rows with ``start <= frame < end``; remembers what it saw."""

    def __init__(self, start: int, end: int) -> None:
        self.start = start
        self.end = end
        self.kept: set[int] = set()
        self.lowest: int | None = None
        self.highest: int | None = None
        self.entities: set[str] = set()

    def __call__(self, chunk: Chunk) -> list[Chunk]:
        self.entities.add(chunk.entity_path)
        if chunk.is_static or FRAME not in chunk.timeline_names:
            return [chunk]
        batch = chunk.to_record_batch()
        frames = batch.column(FRAME)
        low, high = pc.min(frames).as_py(), pc.max(frames).as_py()
        if low is None or high is None:  # no rows
            return [chunk]
        self.lowest = low if self.lowest is None else min(self.lowest, low)
        self.highest = high if self.highest is None else max(self.highest, high)
        if low >= self.start and high < self.end:  # the whole chunk is inside: pass it on unchanged
            self.kept.update(frames.to_pylist())
            return [chunk]
        if high < self.start or low >= self.end:
            return []
        mask = pc.and_(pc.greater_equal(frames, pa.scalar(self.start, pa.int64())),
                       pc.less(frames, pa.scalar(self.end, pa.int64())))
        rows = batch.filter(mask)
        if rows.num_rows == 0:
            return []
        self.kept.update(rows.column(FRAME).to_pylist())
        # the batch still carries the chunk id and row ids: they are kept
        return Chunk.from_record_batch(rows)


def crop_recording(source: Path, frames: tuple[int, int], output: Path) -> CropSummary:
    """Write the frames ``START <= frame < END`` of `source` to `output`, with all static data (properties,
    recording name, Pinhole, styles…) and the embedded blueprint. Raises `RecordingError`."""
    start, end = frames
    if start >= end:
        raise RecordingError(f"{source}: empty frame range {start}:{end} (START must be below END; END is excluded)")
    if start < 0:
        raise RecordingError(f"{source}: frame range {start}:{end} starts below 0")
    reader, recording, blueprints = _open(source)
    if _same_file(source, output):
        raise RecordingError(f"{output}: the output must not be the source recording")

    parent = output.parent if str(output.parent) else Path(".")
    try:
        work = Path(tempfile.mkdtemp(prefix=f".{output.name}.", suffix=".tmp", dir=parent))
    except OSError as exc:
        raise RecordingError(f"{output}: cannot write beside it ({exc.strerror})") from None
    try:
        cropped = work / "recording.rrd"
        keep = _FrameFilter(start, end)
        try:
            reader.stream(store=recording).flat_map(keep).write_rrd(
                cropped, application_id=recording.application_id, recording_id=recording.recording_id)
        except OSError as exc:
            raise RecordingError(f"{output}: cannot write ({exc.strerror})") from None
        except Exception as exc:  # the reader raises plain exceptions for corrupt chunks
            raise RecordingError(f"{source}: cannot read the recording ({_first_line(exc)})") from None
        if not keep.kept:
            raise RecordingError(f"{source}: frames {start}:{end} select no frame ({_own_range(keep)})")

        result = cropped
        if blueprints:
            result = _add_blueprints(source, reader, blueprints, cropped, keep.entities, work)
        os.replace(result, output)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return CropSummary(output=output, first_frame=min(keep.kept), last_frame=max(keep.kept),
                       frame_count=len(keep.kept), input_bytes=source.stat().st_size,
                       output_bytes=output.stat().st_size)


def _open(source: Path) -> tuple[RrdReader, StoreEntry, list[StoreEntry]]:
    """Reader, the one recording store, and the blueprint stores of a complete (footered) `.rrd`."""
    if not source.exists():
        raise RecordingError(f"{source}: no such file")
    if source.is_dir():
        raise RecordingError(f"{source}: is a folder, not a Rerun recording")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", RerunWarning)
            reader = RrdReader(source)
        if any("no footer" in str(w.message) for w in caught):
            raise RecordingError(f"{source}: truncated or unfinished recording (no RRD footer)")
        recordings, blueprints = reader.recordings(), reader.blueprints()
        if len(recordings) != 1:
            raise RecordingError(f"{source}: holds {len(recordings)} recordings, crop needs exactly one")
        for store in [*recordings, *blueprints]:
            reader.store(store=store)  # reads and checks the manifest (milliseconds)
    except RecordingError:
        raise
    except Exception as exc:  # the reader raises plain exceptions for every kind of bad file
        raise RecordingError(f"{source}: not a readable Rerun recording ({_first_line(exc)})") from None
    return reader, recordings[0], blueprints


def _add_blueprints(source: Path, reader: RrdReader, blueprints: list[StoreEntry], cropped: Path,
                    entities: set[str], work: Path) -> Path:
    """The source's blueprint stores (as stored, activation command included) followed by `cropped`."""
    blueprint_entities: set[str] = set()
    expected = 0
    for store in blueprints:
        lazy = reader.store(store=store)
        blueprint_entities.update(lazy.schema().entity_paths())
        expected += len(lazy)
    if clash := sorted(entities & blueprint_entities):
        raise RecordingError(f"{source}: entity {clash[0]} is in both the recording and the blueprint: "
                             "cannot separate the blueprint")
    only_blueprint = work / "blueprint.rrd"
    drops = [arg for entity in sorted(entities) for arg in ("--drop-entity", entity)]
    _rerun_cli(source, "rrd", "filter", "-o", str(only_blueprint), *drops, str(source))
    combined = work / "combined.rrd"
    _rerun_cli(source, "rrd", "filter", "-o", str(combined), str(only_blueprint), str(cropped))

    check = RrdReader(combined)  # the CLI must have kept every blueprint chunk and nothing else
    kept = sum(len(check.store(store=store)) for store in check.blueprints())
    if kept != expected or len(check.recordings()) != 1:
        raise RecordingError(f"{source}: the blueprint was not copied intact ({kept} of {expected} chunks)")
    return combined


def _rerun_cli(source: Path, *args: str) -> None:
    """Run the `rerun` binary of the installed rerun-sdk (not `python -m rerun_cli`: it exits 0 on errors)."""
    try:
        done = subprocess.run([_rerun_binary(), *args], capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RecordingError(f"{source}: cannot run the rerun CLI ({_first_line(exc)})") from None
    if done.returncode != 0:
        errors = [line for line in done.stderr.splitlines() if "ERROR" in line or line.startswith("Error")]
        detail = (errors or done.stderr.strip().splitlines() or [f"exit code {done.returncode}"])[-1]
        raise RecordingError(f"{source}: rerun {' '.join(args[:2])} failed ({detail.strip()})")


def _rerun_binary() -> str:
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


def _same_file(source: Path, output: Path) -> bool:
    if output.exists():
        try:
            return os.path.samefile(source, output)
        except OSError:
            return False
    return source.resolve() == output.resolve()


def _own_range(keep: _FrameFilter) -> str:
    if keep.lowest is None or keep.highest is None:
        return "the recording has no 'frame' timeline"
    return f"the recording's frames are {keep.lowest}:{keep.highest + 1}"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else exc.__class__.__name__
