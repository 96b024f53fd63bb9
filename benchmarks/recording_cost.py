"""What recording costs: engine time added and bytes per frame at each --detail level, and memory.

    python -m benchmarks.recording_cost ../shared/data/kitti --sequence 05 --frames 0:300 --backends vo,map \
        --levels off,summary,standard,full --repeats 3 --csv cost.csv
    python -m benchmarks.recording_cost synthetic --frames 0:1500 --levels off,full   # memory over a long run
    python -m benchmarks.recording_cost ../shared/data/kitti --sequence 05 --backends vo,map --pace 10  # a live drive
    python -m benchmarks.recording_cost ../shared/data/kitti --sequence 05 --levels standard --keep runs/
    python -m benchmarks.recording_entities runs/vo_standard_jpeg.rrd     # where the bytes of a kept run go

Each (backend, level) runs in its own process, one after the other so they do not compete for the 2 cores,
`--repeats` times (the levels interleaved, so a burst of other work on the machine hits every level alike):
wall time per frame with decoding and the recording's closing flush; CPU time per frame of the process (all
its threads: less sensitive to other work on the machine than wall time, but blind to work moved beside the
engine); the same two over the last two thirds of the run only ("after 1/3": the per-frame cost without the
first frames' set-up); the recorder's own time per frame on the calling thread; the time per frame the tracking
thread spends waiting rather than computing (wall time less its own CPU time, the median of the repeats; a
recording adds to it what it holds the tracking thread back by: the GIL, the cores; docs/recordings.md); the
file's KB per frame; peak RSS, and RSS after the first third and at the end of the run (flat memory = the
recording does not accumulate in memory).
Timings on a shared machine are noisy: the table keeps the fastest repeat of each (`added` compares fastest
with fastest), and its last column each level's added time against the run without a recording of the same round
(run just before it), the median over the rounds and their range. `--pace HZ` feeds the frames no faster than HZ
a second, as a live drive does: the file's size then is a live recording's (rows are written every 1.5 s, so KB
per frame follow the frame rate); its times are not the run's cost.
"""

from __future__ import annotations

import argparse
import multiprocessing
import shutil
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import polars as pl

from benchmarks.memory import status_mb
from vslam.recording import HALF_SIZE_JPEG_QUALITY, JPEG_QUALITY, Detail, ImageCodec, Recorder
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange, FrameSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.synthetic import SyntheticStreet


def _measure(args: tuple[str, str, str, str, str, str, int, float, str]) -> dict[str, object]:
    root, sequence, frames, level, backend, codec, quality, pace, keep = args
    detail = Detail(level)
    config = EngineConfig().with_backend(backend)  # type: ignore[arg-type]
    selection = FrameRange.parse(frames)
    source: FrameSource = (
        SyntheticStreet(n_frames=selection.end or 300, frames=selection) if root == "synthetic"
        else KittiSource(root, sequence=sequence, frames=selection)
    )
    rss: list[float] = []
    record_ms: list[float] = []
    begun = [time.perf_counter()]  # when the run started (`--pace`)
    third: list[float] = []  # wall and CPU clocks after the first third of the frames
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.rrd"
        recorder = None if detail == Detail.OFF else Recorder(path, source, config, {"name": "bench"},
                                                              detail=detail, jpeg_quality=quality,
                                                              image_codec=ImageCodec(codec))

        def sink(frame: Frame, result: FrameResult) -> None:
            if recorder is not None:
                start = time.perf_counter()
                recorder.log_frame(frame, result)
                record_ms.append((time.perf_counter() - start) * 1000)
            if result.position in (len(source) // 3, len(source) - 1):
                rss.append(status_mb("VmRSS"))
            if result.position == len(source) // 3:
                third.extend((time.perf_counter(), time.process_time()))
            if pace and (wait := begun[0] + (result.position + 1) / pace - time.perf_counter()) > 0:
                time.sleep(wait)  # not before this frame's time of a live camera at `pace` Hz

        start, cpu, tracking_cpu = time.perf_counter(), time.process_time(), time.thread_time()
        begun[0] = start
        run: RunResult = run_odometry(source, config, sinks=(sink,))
        # the tracking thread's time not spent computing: waiting for the GIL, its OpenCV pool, the map's jobs
        tracking_wait = time.perf_counter() - start - (time.thread_time() - tracking_cpu)
        if recorder is not None:
            recorder.close()
        end, end_cpu = time.perf_counter(), time.process_time()
        seconds, cpu = end - start, end_cpu - cpu
        after_third = run.frames - len(source) // 3 - 1  # frames timed by the `third` clocks
        size = path.stat().st_size if path.exists() else 0
        if keep and path.exists():  # for `benchmarks.recording_entities`
            shutil.copyfile(path, Path(keep) / f"{backend}_{level}_{codec}.rrd")
    return {
        "backend": backend,
        "detail": level,
        "frames": run.frames,
        "ms_per_frame": 1000 * seconds / run.frames,
        "cpu_ms_per_frame": 1000 * cpu / run.frames,
        "record_ms_per_frame": sum(record_ms) / run.frames if record_ms else 0.0,
        "wait_ms_per_frame": 1000 * tracking_wait / run.frames,
        # the rest of the run, the recording's closing flush included: without the first frames' one-off costs
        # (first use of each entity), as an hour's drive would see it
        "steady_ms_per_frame": 1000 * (end - third[0]) / after_third,
        "steady_cpu_ms_per_frame": 1000 * (end_cpu - third[1]) / after_third,
        "kb_per_frame": size / 1024 / run.frames,
        "rss_third_mb": rss[0],
        "rss_end_mb": rss[-1],
        "peak_rss_mb": status_mb("VmHWM"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", help="KITTI dataset root, or 'synthetic' (long runs: e.g. --frames 0:1500)")
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--csv", type=Path, default=None)
    parser.add_argument("--levels", default="off,summary,standard,full")
    parser.add_argument("--backends", default="vo", help="comma-separated: vo, map")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each; the fastest is kept")
    parser.add_argument("--image-codec", default="jpeg", choices=[c.value for c in ImageCodec])
    parser.add_argument("--jpeg-quality", type=int, default=None, help="default: the level's (vslam run's)")
    parser.add_argument("--pace", type=float, default=0.0, help="frames a second at most (a live camera); 0: none")
    parser.add_argument("--keep", type=Path, default=None,
                        help="folder to keep the last repeat's recordings in (BACKEND_DETAIL_CODEC.rrd)")
    args = parser.parse_args()
    levels = args.levels.split(",")
    if "off" not in levels:
        levels.insert(0, "off")  # the baseline every cost is against
    rows = []
    context = multiprocessing.get_context("spawn")
    for repeat in range(args.repeats):
        for backend in args.backends.split(","):
            for level in levels:
                # not a multiprocessing.Pool: its workers are daemons, and the map backend starts a process
                with ProcessPoolExecutor(1, mp_context=context) as pool:
                    rows.append({"round": repeat, **pool.submit(
                        _measure, (str(args.root), args.sequence, args.frames, level, backend, args.image_codec,
                                   args.jpeg_quality, args.pace, str(args.keep or ""))).result()})
    every = pl.DataFrame(rows)
    paired = paired_cost(every)
    table = every.group_by("backend", "detail", maintain_order=True).agg(
        pl.col("ms_per_frame").min(), pl.col("ms_per_frame").max().alias("ms_max"), pl.col("cpu_ms_per_frame").min(),
        pl.col("record_ms_per_frame").min(), pl.col("kb_per_frame").mean(), pl.col("steady_ms_per_frame").min(),
        pl.col("steady_cpu_ms_per_frame").min(), pl.col("wait_ms_per_frame").median(),
        pl.col("rss_third_mb").max(), pl.col("rss_end_mb").max(), pl.col("peak_rss_mb").max())
    base = table.filter(pl.col("detail") == "off").select(
        "backend", pl.col("ms_per_frame").alias("off_ms"), pl.col("cpu_ms_per_frame").alias("off_cpu"),
        pl.col("steady_ms_per_frame").alias("off_steady"), pl.col("steady_cpu_ms_per_frame").alias("off_steady_cpu"))
    table = table.join(base, on="backend").with_columns(
        (100 * (pl.col("ms_per_frame") / pl.col("off_ms") - 1)).alias("added_pct"),
        (100 * (pl.col("cpu_ms_per_frame") / pl.col("off_cpu") - 1)).alias("added_cpu_pct"),
        (100 * (pl.col("steady_ms_per_frame") / pl.col("off_steady") - 1)).alias("steady_added_pct"),
        (100 * (pl.col("steady_cpu_ms_per_frame") / pl.col("off_steady_cpu") - 1)).alias("steady_added_cpu_pct")
    ).join(paired, on=["backend", "detail"])
    if args.csv:
        table.write_csv(args.csv)
    name = "synthetic street" if args.root == "synthetic" else "KITTI " + args.sequence
    print(f"{name}, frames {args.frames}, images {args.image_codec}"
          + ((f" q{args.jpeg_quality}" if args.jpeg_quality
               else f" (standard: half size q{HALF_SIZE_JPEG_QUALITY}, full: q{JPEG_QUALITY})")
             if args.image_codec == "jpeg" else "") + f", fastest of {args.repeats}"
          + (f", paced at {args.pace:g} Hz" if args.pace else ""))
    print("| backend | detail | ms/frame (slowest) | added vs off | CPU ms/frame | CPU added | after 1/3: ms/frame "
          "| added | CPU added | recorder ms/frame (caller thread) | tracking thread waits ms/frame (median) "
          "| KB/frame | RSS at 1/3 → end MB | peak RSS MB | added, round by round: median (range) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in table.iter_rows(named=True):
        print(f"| {r['backend']} | {r['detail']} | {r['ms_per_frame']:.1f} ({r['ms_max']:.1f}) "
              f"| {r['added_pct']:+.1f} % | {r['cpu_ms_per_frame']:.1f} | {r['added_cpu_pct']:+.1f} % "
              f"| {r['steady_ms_per_frame']:.1f} | {r['steady_added_pct']:+.1f} % | {r['steady_added_cpu_pct']:+.1f} % "
              f"| {r['record_ms_per_frame']:.2f} | {r['wait_ms_per_frame']:.2f} | {r['kb_per_frame']:.1f} "
              f"| {r['rss_third_mb']:.0f} → "
              f"{r['rss_end_mb']:.0f} | {r['peak_rss_mb']:.0f} | {r['paired_added_pct']:+.1f} % "
              f"({r['paired_min_pct']:+.1f} to {r['paired_max_pct']:+.1f}) |")


def paired_cost(every: pl.DataFrame) -> pl.DataFrame:
    """Each level's added wall time against the run without a recording of the same round (the two ran one
    after the other, so a slow spell of the machine hits both): the median over the rounds and its range, per
    (backend, detail). Steadier than fastest against fastest when the machine's speed drifts between rounds."""
    off = every.filter(pl.col("detail") == "off").select("round", "backend", pl.col("ms_per_frame").alias("off"))
    added = every.join(off, on=["round", "backend"]).with_columns(
        (100 * (pl.col("ms_per_frame") / pl.col("off") - 1)).alias("pct"))
    return added.group_by("backend", "detail", maintain_order=True).agg(
        pl.col("pct").median().alias("paired_added_pct"), pl.col("pct").min().alias("paired_min_pct"),
        pl.col("pct").max().alias("paired_max_pct"))


if __name__ == "__main__":
    main()
