"""`vslam repair`: a finalised copy of a recording cut short (killed run, crash, full disk).

A recording without its footer still holds every chunk written before the end: `vslam.rrd.read.finalise` copies
the whole messages (`rerun rrd filter` stops cleanly at a half-written last one) into a file with a footer,
which `rerun rrd verify` then checks. The copy is written beside the output and moved into place. Its run
properties are rewritten to say what it holds (``frames``, ``frame_count``: the frames with a camera pose) and
that the run was cut short (``stopped``), the way `vslam crop` rewrites them (without ``cropped_from``).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from vslam.rrd.crop import crop_recording
from vslam.rrd.provenance import PROPERTIES, read_properties
from vslam.rrd.read import RecordingError, read_entity, readable, run_rerun_cli, same_file, work_dir_beside


@dataclass(frozen=True)
class RepairSummary:
    source: Path
    output: Path
    cut_short: bool  # False: the source was complete already (the output is a plain copy)
    first_frame: int | None
    last_frame: int | None
    frame_count: int
    input_bytes: int
    output_bytes: int
    stopped: str | None = None  # the run properties' ``stopped`` (a run cut short, or stopped early)


def repaired_path(source: Path) -> Path:
    """``run.rrd`` → ``run.repaired.rrd`` beside it (the source is never replaced)."""
    return source.with_name(f"{source.stem}.repaired.rrd")


def repair_recording(source: Path, output: Path) -> RepairSummary:
    """Write a finalised copy of `source` to `output`; `RecordingError` in one line if nothing is usable."""
    if same_file(source, output):
        raise RecordingError(f"{output}: the output must not be the recording being repaired")
    data = readable(source)  # a finalised temporary copy when `source` has no footer
    work = work_dir_beside(output)
    try:
        repaired = work / "repaired.rrd"
        try:
            if data.cut_short:  # every frame, its properties restated (and a `stopped` entry)
                crop_recording(source, (0, None), repaired, mark_cropped=False)
            else:
                shutil.copyfile(data.path, repaired)
        except OSError as exc:
            raise RecordingError(f"{output}: cannot write ({exc.strerror})") from None
        run_rerun_cli(source, "rrd", "verify", str(repaired))
        os.replace(repaired, output)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    camera = read_entity(output, "/world/camera")
    frames = camera["frame"].to_list() if "frame" in camera.columns else []
    stopped = read_properties(output, f"{PROPERTIES}/run").get("stopped")
    return RepairSummary(source, output, data.cut_short, min(frames, default=None), max(frames, default=None),
                         len(frames), source.stat().st_size, output.stat().st_size,
                         None if stopped is None else str(stopped))


def format_repair(summary: RepairSummary) -> str:
    held = (f"frames {summary.first_frame}..{summary.last_frame} ({summary.frame_count} frames)"
            if summary.frame_count else "no camera pose")
    state = "was cut short (no footer)" if summary.cut_short else "was complete already"
    return (f"{summary.output}: {held}, {summary.output_bytes / 1e6:.1f} MB; {summary.source} {state}, "
            f"{summary.input_bytes / 1e6:.1f} MB" + (f"; stopped: {summary.stopped}" if summary.stopped else ""))
