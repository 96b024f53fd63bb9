"""Cut a recording down to a range of the ``frame`` timeline (for attaching to bug reports).

How (rerun-sdk 0.41):

0. The run properties (``/__properties/run``: ``frames``, ``frame_count``, and a new ``cropped_from``) and the
   recording name are rewritten to say which frames the cropped file holds (`vslam.rrd.provenance`).
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
3. A `VideoStream` entity (``--image-codec av1|h264``) decodes only from a key frame. When START falls
   inside a GOP, the frames from START up to the next key frame (or END) are decoded from the previous key
   frame and re-encoded as a new GOP that starts with a key frame; their samples replace the originals row
   for row (same frames, times and row ids: `vslam.rrd.crop_video`). The file still holds exactly frames
   START..END-1 (keeping the earlier samples instead would put frames before START on the timeline);
   the price is one re-encoding of at most one GOP.

Everything is written into a hidden temporary folder beside the output and renamed at the end.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import Chunk, RrdReader, StoreEntry

from vslam.rrd.check import schema_contract
from vslam.rrd.crop_video import reencoded_first_gops, swap_samples
from vslam.rrd.provenance import PROPERTIES, cropped_properties, read_properties
from vslam.rrd.read import RecordingError, first_line, open_store, readable, run_rerun_cli, same_file, work_dir_beside

FRAME = "frame"
#: the camera pose of a run (of each run of a comparison): the frames a recording holds are those it has one of
CAMERA = re.compile(r"(/[a-z])?/world/camera")


@dataclass(frozen=True)
class CropSummary:
    """What `crop_recording` kept: frames ``first_frame..last_frame`` (inclusive), file sizes in bytes."""

    output: Path
    first_frame: int | None  # of the frames with a camera pose (None: none has one)
    last_frame: int | None
    frame_count: int
    input_bytes: int
    output_bytes: int
    stopped: str | None = None  # the source was cut short (or stopped early): its run properties' ``stopped``


class _FrameFilter:
    """`flat_map` callback: keeps rows with ``start <= frame < end``; remembers what it saw."""

    def __init__(self, start: int, end: int, replacements: dict[str, Chunk] | None = None,
                 video: dict[str, dict[int, tuple[bytes, bool]]] | None = None) -> None:
        self.start = start
        self.video = video or {}  # re-encoded video samples to swap in, by entity path and frame
        self.end = end
        self.replacements = replacements or {}  # static chunks to swap, by entity path (the run properties)
        self.replaced = set(self.replacements)
        #: a vslam recording (it has run properties): the frames it holds are those with a camera pose
        self.of_a_run = bool(self.replacements)
        self.kept: set[int] = set()
        self.posed: set[int] = set()  # kept frames with a camera pose (``/world/camera``, ``/a/world/camera``…)
        self.lowest: int | None = None
        self.highest: int | None = None
        self.entities: set[str] = set()

    def __call__(self, chunk: Chunk) -> list[Chunk]:
        self.entities.add(chunk.entity_path)
        if chunk.is_static and chunk.entity_path in self.replacements:  # once, however often it was logged
            replacement = self.replacements.pop(chunk.entity_path, None)
            return [replacement] if replacement is not None else []
        if chunk.is_static and chunk.entity_path in self.replaced:
            return []
        if chunk.is_static or FRAME not in chunk.timeline_names:
            return [chunk]
        batch = chunk.to_record_batch()
        frames = batch.column(FRAME)
        low, high = pc.min(frames).as_py(), pc.max(frames).as_py()
        if low is None or high is None:  # no rows
            return [chunk]
        self.lowest = low if self.lowest is None else min(self.lowest, low)
        self.highest = high if self.highest is None else max(self.highest, high)
        swaps = self.video.get(chunk.entity_path, {})
        if low >= self.start and high < self.end and not swaps:  # the whole chunk is inside: pass it on unchanged
            self._keep(chunk.entity_path, frames.to_pylist())
            return [chunk]
        if high < self.start or low >= self.end:
            return []
        mask = pc.and_(pc.greater_equal(frames, pa.scalar(self.start, pa.int64())),
                       pc.less(frames, pa.scalar(self.end, pa.int64())))
        rows = batch.filter(mask)
        if rows.num_rows == 0:
            return []
        self._keep(chunk.entity_path, rows.column(FRAME).to_pylist())
        if swaps and any(f in swaps for f in rows.column(FRAME).to_pylist()):
            rows = swap_samples(rows, swaps)
        # the batch still carries the chunk id and row ids: they are kept
        return Chunk.from_record_batch(rows)

    def _keep(self, entity: str, frames: list[int]) -> None:
        self.kept.update(frames)
        if CAMERA.fullmatch(entity):
            self.posed.update(frames)


def parse_crop_frames(text: str) -> tuple[int, int | None]:
    """``"START:END"`` of the frame timeline (END excluded; either may be left out: ``:140``, ``110:``) as
    (start, end or None). The range is clamped to the recording's frames like a Python slice; crop keeps a
    contiguous range, so there is no STEP. Raises `RecordingError` with what crop accepts."""
    expected = f"--frames {text!r}: expected START:END of the frame timeline, e.g. 120:160 (END excluded; no STEP)"
    parts = text.strip().split(":")
    if len(parts) != 2:
        raise RecordingError(expected)
    try:
        start, end = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise RecordingError(expected) from None
    first = 0 if start is None else start
    if first < 0 or (end is not None and end < 0):
        raise RecordingError(f"--frames {text!r}: negative frame numbers are not supported")
    if end is not None and end <= first:
        raise RecordingError(f"--frames {text!r}: selects no frame (END must be greater than START; END is "
                             "excluded)")
    return first, end


def crop_recording(source: Path, frames: tuple[int, int | None], output: Path, mark_cropped: bool = True
                   ) -> CropSummary:
    """Write the frames ``START <= frame < END`` of `source` to `output` (END None: to the last frame), with all
    static data (Pinhole, styles…) and the embedded blueprint; the run properties and recording name are
    rewritten to say which frames the file holds a camera pose of (and, for a `source` cut short, that it was:
    ``stopped``). `mark_cropped` False (`vslam repair`): no ``cropped_from``. Raises `RecordingError`."""
    start, end = frames[0], (frames[1] if frames[1] is not None else sys.maxsize)
    if start >= end:
        raise RecordingError(f"{source}: empty frame range {start}:{end} (START must be below END; END is excluded)")
    if start < 0:
        raise RecordingError(f"{source}: frame range {start}:{end} starts below 0")
    if same_file(source, output):
        raise RecordingError(f"{output}: the output must not be the source recording")
    with schema_contract(source):  # a recording `vslam check` rejects: one line, never a traceback
        return _crop(source, start, end, frames, output, mark_cropped)


def _crop(source: Path, start: int, end: int, frames: tuple[int, int | None], output: Path, mark_cropped: bool
          ) -> CropSummary:
    reader, recording, blueprints = open_store(source)

    work = work_dir_beside(output)
    try:
        cropped = work / "recording.rrd"
        video = reencoded_first_gops(reader, recording, start, end)
        cut_short = readable(source).cut_short
        keep = _FrameFilter(start, end, cropped_properties(source, start, end, cut_short, mark_cropped), video)
        try:
            reader.stream(store=recording).flat_map(keep).write_rrd(
                cropped, application_id=recording.application_id, recording_id=recording.recording_id)
        except OSError as exc:
            raise RecordingError(f"{output}: cannot write ({exc.strerror})") from None
        except Exception as exc:  # the reader raises plain exceptions for corrupt chunks
            raise RecordingError(f"{source}: cannot read the recording ({first_line(exc)})") from None
        if not keep.kept:
            wanted = f"{start}:{frames[1] if frames[1] is not None else ''}"
            raise RecordingError(f"{source}: frames {wanted} select no frame ({_own_range(keep)})")

        result = cropped
        if blueprints:
            result = _add_blueprints(source, reader, blueprints, cropped, keep.entities, work)
        os.replace(result, output)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    stopped = read_properties(output, f"{PROPERTIES}/run").get("stopped")
    held = keep.posed if keep.of_a_run else keep.kept  # another recording: every frame it has data at
    return CropSummary(output=output, first_frame=min(held, default=None),
                       last_frame=max(held, default=None), frame_count=len(held),
                       input_bytes=source.stat().st_size, output_bytes=output.stat().st_size,
                       stopped=None if stopped is None else str(stopped))


def format_crop(summary: CropSummary, source: Path) -> str:
    """``out.rrd: frames 120..159 (40 frames), 3.1 MB (from 20.4 MB)`` (+ how the source run stopped)."""
    held = (f"frames {summary.first_frame}..{summary.last_frame} ({summary.frame_count} frames)"
            if summary.frame_count else "no camera pose in these frames")
    line = (f"{summary.output}: {held}, {summary.output_bytes / 1e6:.1f} MB (from {summary.input_bytes / 1e6:.1f} "
            "MB)")
    return line + (f"; {source}: {summary.stopped}" if summary.stopped else "")


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
    run_rerun_cli(source, "rrd", "filter", "-o", str(only_blueprint), *drops, str(readable(source).path))
    combined = work / "combined.rrd"
    run_rerun_cli(source, "rrd", "filter", "-o", str(combined), str(only_blueprint), str(cropped))

    check = RrdReader(combined)  # the CLI must have kept every blueprint chunk and nothing else
    kept = sum(len(check.store(store=store)) for store in check.blueprints())
    if kept != expected or len(check.recordings()) != 1:
        raise RecordingError(f"{source}: the blueprint was not copied intact ({kept} of {expected} chunks)")
    return combined


def _own_range(keep: _FrameFilter) -> str:
    if keep.lowest is None or keep.highest is None:
        return "the recording has no 'frame' timeline"
    return f"the recording's frames are {keep.lowest}:{keep.highest + 1}"
