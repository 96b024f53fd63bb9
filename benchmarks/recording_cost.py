"""What recording costs: engine time added and bytes per frame at each --detail level, and memory.

    python -m benchmarks.recording_cost ../shared/data/kitti --sequence 00 --frames 0:300 --csv cost.csv
    python -m benchmarks.recording_cost synthetic --frames 0:1500 --levels off,full   # memory over a long run

Each level runs in its own process (one after the other, so they do not compete for the 2 cores):
wall time per frame with decoding, the recorder's own time per frame on the calling thread, the file's
KB per frame, peak RSS, and RSS after the first third and at the end of the run (flat memory = the
recording does not accumulate in memory).
"""

from __future__ import annotations

import argparse
import multiprocessing
import tempfile
import time
from pathlib import Path

import polars as pl

from benchmarks.memory import status_mb
from vslam.recording import Detail, Recorder
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange, FrameSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.synthetic import SyntheticStreet


def _measure(args: tuple[str, str, str, str]) -> dict[str, object]:
    root, sequence, frames, level = args
    detail = Detail(level)
    selection = FrameRange.parse(frames)
    source: FrameSource = (
        SyntheticStreet(n_frames=selection.end or 300, frames=selection) if root == "synthetic"
        else KittiSource(root, sequence=sequence, frames=selection)
    )
    rss: list[float] = []
    record_ms: list[float] = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.rrd"
        recorder = None if detail == Detail.OFF else Recorder(path, source, EngineConfig(), {"name": "bench"},
                                                              detail=detail)

        def sink(frame: Frame, result: FrameResult) -> None:
            if recorder is not None:
                start = time.perf_counter()
                recorder.log_frame(frame, result)
                record_ms.append((time.perf_counter() - start) * 1000)
            if result.position in (len(source) // 3, len(source) - 1):
                rss.append(status_mb("VmRSS"))

        start = time.perf_counter()
        run: RunResult = run_odometry(source, EngineConfig(), sinks=(sink,))
        if recorder is not None:
            recorder.close()
        seconds = time.perf_counter() - start
        size = path.stat().st_size if path.exists() else 0
    return {
        "detail": level,
        "frames": run.frames,
        "ms_per_frame": 1000 * seconds / run.frames,
        "record_ms_per_frame": sum(record_ms) / run.frames if record_ms else 0.0,
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
    args = parser.parse_args()
    rows = []
    context = multiprocessing.get_context("spawn")
    for level in args.levels.split(","):
        with context.Pool(1) as pool:
            rows.append(pool.apply(_measure, ((str(args.root), args.sequence, args.frames, level),)))
    table = pl.DataFrame(rows)
    base = table.filter(pl.col("detail") == "off")["ms_per_frame"][0]
    table = table.with_columns((100 * (pl.col("ms_per_frame") / base - 1)).alias("added_pct"))
    if args.csv:
        table.write_csv(args.csv)
    print(f"{'synthetic street' if args.root == 'synthetic' else 'KITTI ' + args.sequence}, frames {args.frames}")
    print("| detail | ms/frame | added vs off | recorder ms/frame (caller thread) | KB/frame | RSS at 1/3 → end MB "
          "| peak RSS MB |")
    print("|---|---|---|---|---|---|---|")
    for r in table.iter_rows(named=True):
        print(f"| {r['detail']} | {r['ms_per_frame']:.1f} | {r['added_pct']:+.1f} % | {r['record_ms_per_frame']:.2f} | "
              f"{r['kb_per_frame']:.1f} | {r['rss_third_mb']:.0f} → {r['rss_end_mb']:.0f} | {r['peak_rss_mb']:.0f} |")


if __name__ == "__main__":
    main()
