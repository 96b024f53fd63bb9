"""Gaps in turns: does a run of unusable or missing frames in the middle of a turn cost the trajectory?

    python -m benchmarks.gaps ../shared/data/kitti --csv gaps.csv
    python -m benchmarks.gaps ../shared/data/kitti --turns 00:93-126 --kinds blur --lengths 8 \
        --placements start                                   # one placement (a smoke test)

For each turn (default: KITTI 00 frames 93–126 and 191–217, KITTI 05 frames 116–153), each fault kind
(`--kinds`, default blur, dark, drop: see vslam_core/sources/faults.py) and each placement (runs of
`--lengths` frames, default 8 and 10, at the turn's start, middle and end: `--placements`), the engine runs
on `--frames` (default 0:300) of the sequence with that fault injected (as ``vslam run --inject
KIND@FIRST:LAST``), for each backend (`--backends`, default vo and map), scale from ground truth. Plus one
clean run per (sequence, backend).

Per run: KITTI t_err / r_err, the final heading error (angle of R_gtᵀ·R_est at the last frame, degrees), the
frames held (the pose kept), the frames relocalised (map backend: mapping.mode ``relocalised``) and the new
map segments started (map backend), next to the clean run's t_err on the same sequence and backend. A run
passes when ``t_err <= 1.5 × clean t_err + 0.3`` and ``heading <= 2°``. Poses are the run's output (for the
map backend, refined by bundle adjustment). With `drop`, the dropped frames have no pose and no ground truth.

`--lens` runs the same on the window's frames re-imaged through a strong radial–tangential lens (the tests' lens,
tests/ros_logs.py: k1 −0.28, k2 0.07) as an image folder with its camera_info YAML, the faults at the same KITTI
frames: the lens path of dead reckoning, bridging and relocalisation.

Runs go to a multiprocessing pool of `--jobs` workers (default 2) with ``threads = 1``: pool workers are
daemonic and may not start the map backend's bundle-adjustment process; trajectories are identical for any
threads value.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import tempfile
from multiprocessing import get_context
from pathlib import Path

import polars as pl

from vslam_core.config import Backend, EngineConfig
from vslam_core.geometry import rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, FrameStatus, TrackingMode
from vslam_core.sources.base import FrameRange, FrameSource
from vslam_core.sources.faults import FaultInjector, parse_faults
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.open import open_source
from vslam_core.trajectory.metrics import kitti_errors

TURNS = "00:93-126,00:191-217,05:116-153"  # sequence:first-last (source frame indices, inclusive)
KINDS = ("blur", "dark", "drop")
BACKENDS: tuple[Backend, ...] = ("vo", "map")
PLACEMENTS = ("start", "middle", "end")
MAX_T_FACTOR, MAX_T_SLACK, MAX_HEADING_DEG = 1.5, 0.3, 2.0  # pass: t_err <= 1.5 × clean + 0.3 and heading <= 2°


@dataclasses.dataclass(frozen=True)
class Turn:
    sequence: str
    first: int
    last: int  # inclusive

    def __str__(self) -> str:
        return f"{self.sequence}:{self.first}-{self.last}"


@dataclasses.dataclass(frozen=True)
class Job:
    root: str
    sequence: str
    frames: str
    backend: Backend
    turn: str | None  # None for a clean run
    inject: str | None  # KIND@FIRST:LAST
    lens_folder: str | None = None  # the window's frames re-imaged through a lens (`--lens`), else KITTI itself


def parse_turns(text: str) -> list[Turn]:
    """``"00:93-126,05:116-153"`` → turns."""
    turns = []
    for item in (part.strip() for part in text.split(",") if part.strip()):
        sequence, _, span = item.partition(":")
        first, _, last = span.partition("-")
        try:
            turn = Turn(sequence, int(first), int(last))
        except ValueError:
            raise ValueError(f"turn {item!r}: expected SEQUENCE:FIRST-LAST, e.g. 00:93-126") from None
        if not sequence or turn.first > turn.last:
            raise ValueError(f"turn {item!r}: expected SEQUENCE:FIRST-LAST with FIRST <= LAST")
        turns.append(turn)
    return turns


def placement(turn: Turn, length: int, where: str) -> tuple[int, int]:
    """(first, last) inclusive of a run of `length` frames at the turn's start, middle or end (inside the
    turn when it is long enough)."""
    room = max(turn.last - turn.first + 1 - length, 0)
    first = turn.first + {"start": 0, "middle": room // 2, "end": room}[where]
    return first, first + length - 1


def make_jobs(root: str, frames: str, turns: list[Turn], kinds: list[str], lengths: list[int], placements: list[str],
              backends: list[Backend], lens_folders: dict[str, str] | None = None) -> list[Job]:
    """Clean runs first, then every fault; map runs before vo runs (the longer ones start first). `lens_folders`:
    sequence → its frames re-imaged through a lens (`write_lens_folder`)."""
    order = sorted(backends, key=lambda b: b != "map")
    sequences = list(dict.fromkeys(turn.sequence for turn in turns))
    folders = lens_folders or {}
    jobs = [Job(root, sequence, frames, backend, None, None, folders.get(sequence)) for backend in order
            for sequence in sequences]
    for backend in order:
        for turn in turns:
            spans = list(dict.fromkeys(placement(turn, length, where) for length in lengths for where in placements))
            for kind in kinds:
                for first, last in spans:
                    jobs.append(Job(root, turn.sequence, frames, backend, str(turn), f"{kind}@{first}:{last}",
                                    folders.get(turn.sequence)))
    return jobs


def write_lens_folder(root: str, sequence: str, frames: str, out: Path) -> str:
    """The window's KITTI frames re-imaged through the tests' strong radial–tangential lens (k1 −0.28, k2 0.07) as
    an image folder with ``times.txt``, ``gt.txt`` and the lens as ``FOLDER.yaml`` (`tests/ros_logs.py`)."""
    from tests.ros_logs import PLUMB_BOB, kitti_clip, make_reimager
    from tests.ros_logs import write_lens_folder as write

    window = FrameRange.parse(frames)
    count = len(list((Path(root) / "sequences" / sequence / "image_0").glob("*.png")))
    clip = kitti_clip(Path(root), sequence, range(window.start or 0, count if window.end is None else window.end))
    folder = out / f"lens-{sequence}"
    write(clip, make_reimager(clip.camera, "plumb_bob", PLUMB_BOB), folder)
    return str(folder)


def _source(job: Job) -> FrameSource:
    """KITTI with the fault injected, or the lens folder with the fault at the same KITTI frames."""
    if job.lens_folder is None:
        return open_source(job.root, sequence=job.sequence, frames=FrameRange.parse(job.frames), inject=job.inject)
    source: FrameSource = ImageFolderSource(job.lens_folder, calib=f"{job.lens_folder}.yaml",
                                            ground_truth=f"{job.lens_folder}/gt.txt")
    if job.inject is None:
        return source
    start = FrameRange.parse(job.frames).start or 0  # the folder's frame 0
    kind, _, span = job.inject.partition("@")
    first, _, last = span.partition(":")
    return FaultInjector(source, parse_faults(f"{kind}@{int(first) - start}:{int(last) - start}"))


def _segments_started(results: list[FrameResult]) -> int:
    segments = [r.mapping.segment for r in results if r.mapping is not None]
    return sum(b != a for a, b in zip(segments, segments[1:], strict=False))


def run_job(job: Job) -> dict[str, object]:
    """One run, summarised (in a pool worker: threads = 1)."""
    source = _source(job)
    gt = source.ground_truth
    assert gt is not None
    config = dataclasses.replace(EngineConfig(scale="gt", backend=job.backend), threads=1)
    results: list[FrameResult] = []
    run = run_odometry(source, config, sinks=(lambda _frame, result: results.append(result),))
    poses = run.pose_array()
    t_err, r_err = kitti_errors(gt[: len(poses)], poses)
    heading = math.degrees(rotation_angle(gt[len(poses) - 1, :3, :3].T @ poses[-1, :3, :3]))
    is_map = job.backend == "map"
    kind, _, span = (job.inject or "none@").partition("@")
    first, _, last = span.partition(":")
    return {
        "sequence": job.sequence,
        "turn": job.turn or "",
        "kind": kind,
        "first": int(first) if first else None,
        "last": int(last or first) if first else None,
        "backend": job.backend,
        "frames": len(poses),
        "t_err": t_err,
        "r_err": r_err,
        "heading_deg": heading,
        "held": sum(r.status == FrameStatus.HELD for r in results),
        "relocalised": (sum(r.mapping is not None and r.mapping.mode == TrackingMode.RELOCALISED for r in results)
                        if is_map else None),
        "new_segments": _segments_started(results) if is_map else None,
        "seconds": run.seconds,
    }


def with_verdicts(table: pl.DataFrame) -> pl.DataFrame:
    """The clean run's t_err on the same sequence and backend beside each run, and the pass check."""
    clean = table.filter(pl.col("kind") == "none").select("sequence", "backend", clean_t_err="t_err")
    return (table.join(clean, on=["sequence", "backend"], how="left", maintain_order="left")
            .with_columns(passed=(pl.col("t_err") <= MAX_T_FACTOR * pl.col("clean_t_err") + MAX_T_SLACK)
                          & (pl.col("heading_deg") <= MAX_HEADING_DEG)))


def _cell(value: object, fmt: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—" if value is None else "n/a"
    return fmt.format(value)


def markdown(table: pl.DataFrame) -> str:
    lines = ["| seq | turn | fault | backend | t_err % | r_err °/100 m | heading ° | held | relocalised | new segments "
             "| clean t_err % | pass |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in table.iter_rows(named=True):
        fault = "none (clean)" if r["kind"] == "none" else f"{r['kind']}@{r['first']}:{r['last']}"
        lines.append(
            f"| {r['sequence']} | {r['turn'] or '—'} | {fault} | {r['backend']} | {_cell(r['t_err'], '{:.2f}')} "
            f"| {_cell(r['r_err'], '{:.2f}')} | {_cell(r['heading_deg'], '{:.2f}')} | {r['held']} "
            f"| {_cell(r['relocalised'], '{:d}')} | {_cell(r['new_segments'], '{:d}')} "
            f"| {_cell(r['clean_t_err'], '{:.2f}')} | {'pass' if r['passed'] else 'FAIL'} |")
    faults = table.filter(pl.col("kind") != "none")
    if len(faults):
        lines.append("")
        for backend in faults["backend"].unique(maintain_order=True):
            part = faults.filter(pl.col("backend") == backend)
            by_kind = ", ".join(f"{kind} {int(group['passed'].sum())}/{len(group)}"
                                for (kind,), group in part.group_by("kind", maintain_order=True))
            lines.append(f"{backend}: {int(part['passed'].sum())}/{len(part)} pass ({by_kind})")
    return "\n".join(lines)


def _list(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", help="KITTI dataset root")
    parser.add_argument("--turns", default=TURNS, help=f"SEQUENCE:FIRST-LAST,… (default {TURNS})")
    parser.add_argument("--frames", default="0:300", help="START:END of each sequence to run")
    parser.add_argument("--kinds", default=",".join(KINDS), help="fault kinds (see vslam run --inject)")
    parser.add_argument("--lengths", default="8,10", help="frames per fault run")
    parser.add_argument("--placements", default=",".join(PLACEMENTS), help="where in the turn: start,middle,end")
    parser.add_argument("--backends", default=",".join(BACKENDS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--csv", type=Path, default=None)
    parser.add_argument("--lens", action="store_true", help="run on the frames re-imaged through a strong "
                        "radial–tangential lens (tests/ros_logs.py), as a folder with its calibration YAML")
    args = parser.parse_args()
    try:
        turns = parse_turns(args.turns)
    except ValueError as exc:
        parser.error(str(exc))
    kinds, placements, backends = _list(args.kinds), _list(args.placements), _list(args.backends)
    if not turns:
        parser.error("--turns: give at least one turn")
    if not kinds or any(kind not in KINDS for kind in kinds):
        parser.error(f"--kinds {args.kinds!r}: a comma-separated list of {', '.join(KINDS)}")
    if not placements or any(where not in PLACEMENTS for where in placements):
        parser.error(f"--placements {args.placements!r}: a comma-separated list of {', '.join(PLACEMENTS)}")
    if not backends or any(backend not in BACKENDS for backend in backends):
        parser.error(f"--backends {args.backends!r}: a comma-separated list of {', '.join(BACKENDS)}")
    lengths = [int(length) for length in _list(args.lengths)]
    if not lengths or min(lengths) < 1:
        parser.error(f"--lengths {args.lengths!r}: positive frame counts, e.g. 8,10")
    with tempfile.TemporaryDirectory() as scratch:
        folders = {sequence: write_lens_folder(args.root, sequence, args.frames, Path(scratch))
                   for sequence in dict.fromkeys(turn.sequence for turn in turns)} if args.lens else None
        jobs = make_jobs(args.root, args.frames, turns, kinds, lengths, placements,
                         [b for b in BACKENDS if b in backends], folders)
        # spawned, not forked: the parent has used OpenCV (its thread pool does not survive a fork: the workers hung)
        with get_context("spawn").Pool(args.jobs) as pool:
            rows = pool.map(run_job, jobs, chunksize=1)
    order = {backend: n for n, backend in enumerate(BACKENDS)}
    table = with_verdicts(pl.DataFrame(rows, infer_schema_length=None))
    table = table.sort(pl.col("sequence"), pl.col("kind") != "none", pl.col("turn"), pl.col("kind"), pl.col("first"),
                       pl.col("last"), pl.col("backend").replace_strict(order), maintain_order=True)
    if args.csv:
        table.write_csv(args.csv)
    through = " re-imaged through a strong radial–tangential lens" if args.lens else ""
    print(f"KITTI frames {args.frames}{through}, scale gt; pass: t_err <= {MAX_T_FACTOR:g} × clean + "
          f"{MAX_T_SLACK:g} and final heading <= {MAX_HEADING_DEG:g}°")
    print(markdown(table))


if __name__ == "__main__":
    main()
