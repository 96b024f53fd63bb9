"""A whole drive without a download: memory, recording size, loop closing and drift along the synthetic street's
long route (`--route drive`: KITTI 00's 4541 frames, lap after lap round two blocks at 0.45..1.7 m a frame).

    python -m benchmarks.long_drive                                  # both backends, 4541 frames
    python -m benchmarks.long_drive --frames 1500 --backends map --every 250 --csv drive.csv

Each backend runs in its own process, one after the other (they would compete for the 2 cores). Every `--every`
frames it notes the resident memory (VmRSS) of the run's process and of its children (the map backend's worker:
bundle adjustment and the loop search), the recording's size on disk and the time so far; at the end the
peak memory, the growth per frame after the first lap (the street is then revisited: a map whose memory follows
the place stays flat), the recording's KB a frame, the frames per second (rendering included: set
VSLAM_SYNTHETIC_CACHE=DIR to render the route once for both backends), the loops closed and the drift (t_err,
ATE after Sim(3)) against the route's exact ground truth.
"""

from __future__ import annotations

import argparse
import multiprocessing
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import polars as pl

from benchmarks.memory import children_mb, status_mb
from vslam.recording import Detail, Recorder
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.trajectory.metrics import evaluate

#: Frames of one lap of the drive at its mean pace (1237 m at ~1.03 m a frame): growth is measured after it.
LAP_FRAMES = 1200


def _measure(args: tuple[str, int, int, str, str, float]) -> dict[str, object]:
    backend, n_frames, every, detail_name, scale, resolution = args
    detail = Detail(detail_name)
    source = SyntheticStreet(n_frames=n_frames, frames=FrameRange(), route="drive", resolution=resolution)
    config = EngineConfig().with_backend(backend).with_scale(scale)  # type: ignore[arg-type]
    samples: list[dict[str, object]] = []
    loops: list[tuple[int, int]] = []
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "drive.rrd"
        recorder = None if detail == Detail.OFF else Recorder(path, source, config, {"name": "drive"}, detail=detail)
        start = time.perf_counter()

        def sink(frame: Frame, result: FrameResult) -> None:
            if recorder is not None:
                recorder.log_frame(frame, result)
            mapping = result.mapping
            if mapping is not None and mapping.loop is not None and mapping.loop.closed is not None:
                loops.append((frame.index, mapping.loop.closed.candidate_position))
            done = result.position + 1
            if done % every == 0 or done == n_frames:
                samples.append({"backend": backend, "frames": done, "rss_mb": status_mb("VmRSS"),
                                "worker_rss_mb": children_mb("VmRSS"),
                                "recording_mb": (path.stat().st_size if path.exists() else 0) / 2**20,
                                "seconds": time.perf_counter() - start})

        run: RunResult = run_odometry(source, config, sinks=(sink,))
        if recorder is not None:
            recorder.finish(run, None)
        seconds = time.perf_counter() - start
        size = path.stat().st_size if path.exists() else 0
    metrics = evaluate(source.ground_truth[: run.frames], run.pose_array())
    return {"backend": backend, "frames": run.frames, "samples": samples, "loops": loops, "seconds": seconds,
            "kb_per_frame": size / 1024 / run.frames, "peak_rss_mb": status_mb("VmHWM"),
            "t_err": metrics.t_err, "ate_sim3": metrics.ate_sim3}


def growth_kb_per_frame(samples: list[dict[str, object]], after: int = LAP_FRAMES) -> float:
    """Resident memory (the run's process and its worker) added per frame (KB) from the first sample at or after
    frame `after` to the last one (a least-squares slope, so one sample's noise does not decide it); NaN with
    fewer than two such samples."""
    points = [(int(s["frames"]), float(s["rss_mb"]) + float(s.get("worker_rss_mb", 0.0)))  # type: ignore[arg-type]
              for s in samples if int(s["frames"]) >= after]
    if len(points) < 2:
        return float("nan")
    frames, rss = np.array(points, dtype=np.float64).T
    return float(np.polyfit(frames, rss, 1)[0] * 1024)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=4541)
    parser.add_argument("--backends", default="vo,map")
    parser.add_argument("--every", type=int, default=500, help="a sample every this many frames")
    parser.add_argument("--detail", default="full", help="the recording's --detail (off: no recording)")
    parser.add_argument("--scale", default="gt")
    parser.add_argument("--resolution", type=float, default=1.0, help="image size factor (0.1..1)")
    parser.add_argument("--after", type=int, default=LAP_FRAMES, help="growth measured from this frame on")
    parser.add_argument("--csv", type=Path, default=None, help="the samples, one row per backend and checkpoint")
    args = parser.parse_args()
    results = []
    for backend in args.backends.split(","):  # not a Pool: its daemonic workers cannot start the map's worker
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            results.append(pool.submit(_measure, (backend, args.frames, args.every, args.detail, args.scale,
                                                  args.resolution)).result())
    samples = pl.DataFrame([s for r in results for s in r["samples"]])
    if args.csv:
        samples.write_csv(args.csv)
    print(f"synthetic drive, {args.frames} frames, --scale {args.scale}, --detail {args.detail}, "
          f"resolution {args.resolution}")
    print("| backend | frames | RSS MB | worker RSS MB | recording MB | s |")
    print("|---|---|---|---|---|---|")
    for row in samples.iter_rows(named=True):
        print(f"| {row['backend']} | {row['frames']} | {row['rss_mb']:.0f} | {row['worker_rss_mb']:.0f} | "
              f"{row['recording_mb']:.1f} | {row['seconds']:.0f} |")
    print()
    print(f"| backend | peak RSS MB | RSS growth (run + worker) after frame {args.after}, KB/frame "
          "| recording KB/frame | fps | loops closed | t_err % | ATE Sim(3) m |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['backend']} | {r['peak_rss_mb']:.0f} | {growth_kb_per_frame(r['samples'], args.after):.1f} | "
              f"{r['kb_per_frame']:.1f} | {r['frames'] / r['seconds']:.1f} | {len(r['loops'])} | "
              f"{r['t_err']:.2f} | {r['ate_sim3']:.3f} |")


if __name__ == "__main__":
    main()
