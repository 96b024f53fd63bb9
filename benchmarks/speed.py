"""Speed of the engine against the paper configuration, with accuracy beside it (issue 6's yardstick).

    python -m benchmarks.speed ../shared/data/kitti --sequences 00,05 --frames 0:300 --csv speed.csv

Each configuration runs in its own process, one after the other, on the same frames: frames per second
(decoding included), its ratio to the paper configuration's, the cost of recording over the same threading
with recording off, ms per frame per stage, peak RSS, KB per frame of recording, and KITTI t_err / r_err.
With 2 threads the next frame is decoded in the background, so `decode` overlaps the other stages.
A memory check follows: peak RSS of a full recording over the first 100 frames and over all of them.
"""

from __future__ import annotations

import argparse
import multiprocessing
import tempfile
import time
from pathlib import Path

import polars as pl

from app.recording import Detail, Recorder
from benchmarks.memory import status_mb
from benchmarks.paper_baseline import run_paper_configuration
from vslam_core.config import EngineConfig
from vslam_core.metrics import kitti_errors
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource

STAGES = ("decode", "track", "essential", "chirality", "detect", "match", "record")
SYSTEMS = {
    "paper configuration (1 thread)": ("paper", 1, Detail.OFF),
    "vslam, recording off (1 thread)": ("vslam", 1, Detail.OFF),
    "vslam --detail summary (1 thread)": ("vslam", 1, Detail.SUMMARY),
    "vslam --detail full (1 thread)": ("vslam", 1, Detail.FULL),
    "vslam, recording off (2 threads, default)": ("vslam", 2, Detail.OFF),
    "vslam --detail summary (2 threads, default)": ("vslam", 2, Detail.SUMMARY),
    "vslam --detail full (2 threads, default)": ("vslam", 2, Detail.FULL),
}
MEMORY_SYSTEM = "vslam --detail full (2 threads, default)"


def _measure(args: tuple[str, str, str, str]) -> dict[str, object]:
    label, root, sequence, frames = args
    system, threads, detail = SYSTEMS[label]
    source = KittiSource(root, sequence=sequence, frames=FrameRange.parse(frames))
    gt = source.ground_truth
    assert gt is not None
    stage_ms = dict.fromkeys(STAGES, 0.0)
    size = 0
    if system == "paper":
        baseline = run_paper_configuration(source)
        poses, seconds = baseline.poses, baseline.seconds
        stage_ms.update(baseline.stage_ms)
    else:
        config = EngineConfig(threads=threads)
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "run.rrd"
            recorder = Recorder(path, source, config, {"name": "speed"}, detail) if detail != Detail.OFF else None

            def sink(frame: Frame, result: FrameResult) -> None:
                if recorder is not None:
                    start = time.perf_counter()
                    recorder.log_frame(frame, result)
                    stage_ms["record"] += (time.perf_counter() - start) * 1000
                for stage, ms in result.timings_ms.items():
                    stage_ms[stage] = stage_ms.get(stage, 0.0) + ms

            run = run_odometry(source, config, sinks=(sink,))
            if recorder is not None:
                recorder.close()
                size = path.stat().st_size
        poses, seconds = run.pose_array(), run.seconds
    t_err, r_err = kitti_errors(gt, poses)
    n = len(poses)
    return {"system": label, "sequence": sequence, "frames": frames, "threads": threads, "detail": str(detail),
            "fps": n / seconds, "t_err": t_err, "r_err": r_err,
            "peak_rss_mb": status_mb("VmHWM"), "kb_per_frame": size / 1024 / n,
            **{f"{stage}_ms": stage_ms.get(stage, 0.0) / n for stage in STAGES}}


def _in_own_process(label: str, root: str, sequence: str, frames: str, repeat: int = 1) -> dict[str, object]:
    """The run with the median fps of `repeat` runs, each in a fresh process."""
    runs = []
    for _ in range(repeat):
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            runs.append(pool.apply(_measure, ((label, root, sequence, frames),)))
    runs.sort(key=lambda r: float(r["fps"]))  # type: ignore[arg-type]
    return runs[len(runs) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--repeat", type=int, default=3, help="runs per row; the median-fps run is reported")
    parser.add_argument("--memory-frames", default="0:50,0:100,0:200",
                        help="shorter runs for the memory check (beside --frames)")
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    rows = [_in_own_process(label, args.root, sequence, args.frames, args.repeat)
            for sequence in args.sequences.split(",") for label in SYSTEMS]
    table = pl.DataFrame(rows)
    paper = table.filter(pl.col("system") == next(iter(SYSTEMS))).select("sequence", paper_fps="fps")
    off = (table.filter((pl.col("detail") == str(Detail.OFF)) & pl.col("system").str.starts_with("vslam"))
           .select("sequence", "threads", off_fps="fps"))
    table = (table.join(paper, on="sequence").join(off, on=["sequence", "threads"], how="left")
             .with_columns(x_paper=pl.col("fps") / pl.col("paper_fps"),
                           recording_cost_pct=100 * (pl.col("off_fps") / pl.col("fps") - 1))
             .drop("paper_fps", "off_fps"))
    if args.csv:
        table.write_csv(args.csv)
    stages = " | ".join(STAGES)
    print(f"KITTI {args.sequences}, frames {args.frames}; median-fps run of {args.repeat}; ms per frame per stage")
    print(f"| system | seq | fps | × paper | recording cost | t_err % | r_err °/100 m | {stages} | peak RSS MB "
          "| KB/frame |")
    print("|---|---|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|")
    for r in table.iter_rows(named=True):
        cells = " | ".join(f"{r[f'{stage}_ms']:.1f}" for stage in STAGES)
        cost = "—" if r["detail"] == str(Detail.OFF) else f"{r['recording_cost_pct']:+.1f} %"
        print(f"| {r['system']} | {r['sequence']} | {r['fps']:.1f} | {r['x_paper']:.2f} | {cost} | {r['t_err']:.2f} "
              f"| {r['r_err']:.2f} | {cells} | {r['peak_rss_mb']:.0f} | {r['kb_per_frame']:.1f} |")

    sequence = args.sequences.split(",")[0]
    print(f"\nPeak RSS (MB) by run length, KITTI {sequence}")
    lengths = [*args.memory_frames.split(","), args.frames]
    print("| system | " + " | ".join(f"frames {f}" for f in lengths) + " |")
    print("|---|" + "---|" * len(lengths))
    for label in ("vslam, recording off (2 threads, default)", MEMORY_SYSTEM):
        peaks = [_in_own_process(label, args.root, sequence, frames)["peak_rss_mb"] for frames in lengths]
        print(f"| {label} | " + " | ".join(f"{peak:.0f}" for peak in peaks) + " |")

if __name__ == "__main__":
    main()
