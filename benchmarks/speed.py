"""Speed of the engine against the paper configuration, with accuracy beside it (issue 6's yardstick).

    python -m benchmarks.speed ../shared/data/kitti --sequences 00,05 --frames 0:300 --csv speed.csv
    python -m benchmarks.speed ../shared/data/kitti --taskset 0     # every row pinned to CPU 0

Each configuration runs in its own fresh Python process (``python -m benchmarks.speed --measure LABEL``),
one after the other, on the same frames: frames per second (decoding included), its ratio to the paper
configuration's (with `--repeat` N the rows run round by round, N rounds, and the ratio is the median of the N
ratios within a round: the host's speed may drift between rounds), the cost of recording over the same threading
with recording off, the CPU time the run took per frame (all its threads and the map backend's worker process:
on a shared host a steadier measure of work than fps), ms per frame per stage, peak RSS, KB per frame of
recording, and KITTI t_err / r_err. With 2 threads the next frame is decoded in the background, so `decode`
overlaps the other stages.

The `--backend map` rows (recording off, 1 and 2 threads) add: `pnp` (tracking against the map) and
`mapping` (keyframe insertion and local mapping in the tracking thread, including the wait for the pending
bundle adjustment and, with loop closing on, the wait for the loop search) in ms per frame, keyframes per 100
frames, and bundle-adjustment solver ms per keyframe
(gtsam's time as reported in `FrameResult.mapping.bundle_adjustment`, summed over the run and divided by
its keyframes; the adjustment still pending at the end is applied to the output poses but reported by no
frame, so it is not counted; with 2 threads it runs in the worker process beside tracking, with 1 thread
inside `mapping`), and the map's adjustment as a whole once the run ended (`map.adjust_at_end`; in the tracking
thread, counted in fps) per keyframe of the run. Relocalisation time (`relocalise_ms`) is in the CSV only.
Peak RSS is the measuring
process's; the map backend's worker's (bundle adjustment and loop search; 2 threads; 0 with 1 thread) is in the
CSV as `worker_peak_rss_mb`.

Loop closing: the map backend with 2 threads runs once with it on (the default) and once off; the table after the
main one gives both fps and ms per keyframe of each part of loop closing (`--rows "backend map"` runs only these
rows and the paper configuration).

`--taskset CPU` runs every row under ``taskset -c CPU``: the engine, its decode thread and the map backend's
worker all share that one core (the worker inherits the affinity), which shows what the background work
costs when there is no second core.

A memory check follows: peak RSS by run length of vslam with recording off, with a full recording, and of
the map backend.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import polars as pl

from benchmarks.memory import status_mb
from benchmarks.paper_baseline import run_paper_configuration
from vslam.recording import Detail, Recorder
from vslam_core.config import Backend, EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import kitti_errors

STAGES = ("decode", "track", "essential", "chirality", "detect", "match", "pnp", "mapping", "record")
CSV_STAGES = (*STAGES, "relocalise")
NO_BACKEND = "-"  # the paper configuration's backend
# label -> (system, backend, threads, detail)
SYSTEMS: dict[str, tuple[str, str, int, Detail]] = {
    "paper configuration (1 thread)": ("paper", NO_BACKEND, 1, Detail.OFF),
    "vslam, recording off (1 thread)": ("vslam", "vo", 1, Detail.OFF),
    "vslam --detail summary (1 thread)": ("vslam", "vo", 1, Detail.SUMMARY),
    "vslam --detail full (1 thread)": ("vslam", "vo", 1, Detail.FULL),
    "vslam --backend map, recording off (1 thread)": ("vslam", "map", 1, Detail.OFF),
    "vslam, recording off (2 threads, default)": ("vslam", "vo", 2, Detail.OFF),
    "vslam --detail summary (2 threads, default)": ("vslam", "vo", 2, Detail.SUMMARY),
    "vslam --detail full (2 threads, default)": ("vslam", "vo", 2, Detail.FULL),
    "vslam --backend map, recording off (2 threads, default)": ("vslam", "map", 2, Detail.OFF),
    "vslam --backend map, loop closing off (2 threads)": ("vslam", "map", 2, Detail.OFF),
}
LOOP_OFF = {"vslam --backend map, loop closing off (2 threads)"}
# loop closing's parts, ms per keyframe: the search (worker process with 2 threads) and, in the tracking thread,
# the wait for the search at the fixed point, applying a closed loop to the map and submitting the next search
# (the keyframe's snapshot, sent to the worker)
LOOP_PARTS = ("describe", "query", "verify", "optimise", "wait", "apply", "submit")
MEMORY_SYSTEMS = ("vslam, recording off (2 threads, default)", "vslam --detail full (2 threads, default)",
                  "vslam --backend map, recording off (2 threads, default)")


def _measure(label: str, root: str, sequence: str, frames: str) -> dict[str, object]:
    system, backend, threads, detail = SYSTEMS[label]
    source = KittiSource(root, sequence=sequence, frames=FrameRange.parse(frames))
    gt = source.ground_truth
    assert gt is not None
    stage_ms = dict.fromkeys(CSV_STAGES, 0.0)
    size = 0
    keyframes, ba_ms, end_ms = 0, 0.0, 0.0
    loop_ms: dict[str, float] = {}
    cpu_before = resource.getrusage(resource.RUSAGE_SELF)
    if system == "paper":
        baseline = run_paper_configuration(source)
        poses, seconds = baseline.poses, baseline.seconds
        stage_ms.update(baseline.stage_ms)
    else:
        engine_backend: Backend = "map" if backend == "map" else "vo"
        config = EngineConfig(threads=threads, backend=engine_backend)
        if label in LOOP_OFF:
            config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=False))
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "run.rrd"
            recorder = Recorder(path, source, config, {"name": "speed"}, detail) if detail != Detail.OFF else None

            def sink(frame: Frame, result: FrameResult) -> None:
                nonlocal keyframes, ba_ms
                if result.mapping is not None:
                    keyframes += result.mapping.keyframe is not None
                    if result.mapping.loop is not None:
                        for part, ms in result.mapping.loop.timings_ms.items():
                            loop_ms[part] = loop_ms.get(part, 0.0) + ms
                    if result.mapping.bundle_adjustment is not None:
                        ba_ms += result.mapping.bundle_adjustment.milliseconds
                if recorder is not None:
                    start = time.perf_counter()
                    recorder.log_frame(frame, result)
                    stage_ms["record"] += (time.perf_counter() - start) * 1000
                for stage, ms in result.timings_ms.items():
                    stage_ms[stage] = stage_ms.get(stage, 0.0) + ms

            run = run_odometry(source, config, sinks=(sink,))
            end = run.adjusted_at_end  # the map's adjustment as a whole as the run ended (--scale none), or why not
            end_ms = end.milliseconds if end is not None and not isinstance(end, str) else 0.0
            if recorder is not None:
                recorder.close()
                size = path.stat().st_size
        poses, seconds = run.pose_array(), run.seconds
    cpu_after, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    # this process's threads during the run and its finished children (the map backend's worker, stopped at the
    # run's end; a fresh process per run, so no other child counts)
    cpu_s = (cpu_after.ru_utime + cpu_after.ru_stime - cpu_before.ru_utime - cpu_before.ru_stime
             + children.ru_utime + children.ru_stime)
    t_err, r_err = kitti_errors(gt, poses)
    n = len(poses)
    is_map = backend == "map"
    return {"system": label, "backend": backend + (" (no loop closing)" if label in LOOP_OFF else ""),
            "sequence": sequence, "frames": frames, "threads": threads,
            "detail": str(detail), "fps": n / seconds, "cpu_ms": 1000 * cpu_s / n, "t_err": t_err, "r_err": r_err,
            "peak_rss_mb": status_mb("VmHWM"), "kb_per_frame": size / 1024 / n,
            # the map backend's worker process (2 threads), reaped by then: ru_maxrss is in KB
            "worker_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024 if is_map else None,
            "keyframes_per_100": 100 * keyframes / n if is_map else None,
            "ba_ms_per_keyframe": (ba_ms / keyframes if keyframes else 0.0) if is_map else None,
            # the map's adjustment as a whole once the run ended (map.adjust_at_end), per keyframe of the run
            "end_ba_ms_per_keyframe": (end_ms / keyframes if keyframes else 0.0) if is_map else None,
            **{f"{stage}_ms": stage_ms.get(stage, 0.0) / n for stage in CSV_STAGES},
            **{f"loop_{part}_ms_per_keyframe": loop_ms.get(part, 0.0) / max(keyframes, 1) for part in LOOP_PARTS}}


def _in_own_process(label: str, root: str, sequence: str, frames: str, cpu: str | None = None) -> dict[str, object]:
    """One run of `label` in a fresh Python process (under ``taskset -c CPU`` when `cpu` is given). A process
    of its own rather than a multiprocessing pool worker: those are daemonic and may not start the map
    backend's worker processes."""
    command = [sys.executable, "-m", "benchmarks.speed", root, "--measure", label, "--sequences", sequence,
               "--frames", frames]
    if cpu is not None:
        command = ["taskset", "-c", cpu, *command]
    done = subprocess.run(command, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr}")
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def _median_runs(labels: list[str], root: str, sequence: str, frames: str, repeat: int = 1,
                 cpu: str | None = None) -> list[dict[str, object]]:
    """For each label, the run with the median fps of `repeat` runs. The labels take turns (round robin), so a
    change in the machine's load hits every row alike and the ratios between rows stay fair."""
    runs: dict[str, list[dict[str, object]]] = {label: [] for label in labels}
    for _ in range(repeat):
        for label in labels:
            runs[label].append(_in_own_process(label, root, sequence, frames, cpu))
    medians = []
    for label in labels:
        ordered = sorted(runs[label], key=lambda r: float(r["fps"]))  # type: ignore[arg-type]
        medians.append({**ordered[len(ordered) // 2],
                        "fps_runs": " ".join(f"{float(r['fps']):.2f}" for r in runs[label]),  # type: ignore[arg-type]
                        "cpu_runs": " ".join(f"{float(r['cpu_ms']):.2f}" for r in runs[label])})  # type: ignore[arg-type]
    return medians


def _paired(fps_runs: str, against: str) -> list[float]:
    """Per round, a row's fps (or CPU) over another row's (two `fps_runs` or `cpu_runs` strings, rounds in order):
    the rows of a round ran one after the other, so a change in the machine's speed between rounds cancels out of
    each ratio."""
    return [float(a) / float(b) for a, b in zip(fps_runs.split(), against.split(), strict=True)]


def _optional(value: object, fmt: str) -> str:
    return "—" if value is None else fmt.format(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--repeat", type=int, default=3, help="runs per row; the median-fps run is reported")
    parser.add_argument("--memory-frames", default="0:50,0:100,0:200",
                        help="shorter runs for the memory check (beside --frames)")
    parser.add_argument("--csv", type=Path, default=None)
    parser.add_argument("--taskset", metavar="CPU", default=None,
                        help="run every row pinned to this CPU (taskset -c CPU), e.g. 0")
    parser.add_argument("--skip-memory", action="store_true", help="leave out the peak-RSS-by-length check")
    parser.add_argument("--rows", default=None, help="only the rows whose label contains this text (or one of "
                        "several, separated by |), e.g. 'backend map' (the paper configuration always runs: the "
                        "ratios need it)")
    parser.add_argument("--measure", metavar="LABEL", choices=list(SYSTEMS), default=None,
                        help=argparse.SUPPRESS)  # internal: one run of LABEL in this process, as JSON on stdout
    args = parser.parse_args()
    if args.measure is not None:
        print(json.dumps(_measure(args.measure, args.root, args.sequences, args.frames)))
        return
    wanted = args.rows.split("|") if args.rows is not None else None
    labels = [label for label in SYSTEMS
              if wanted is None or any(w in label for w in wanted) or label == next(iter(SYSTEMS))]
    rows = [row for sequence in args.sequences.split(",")
            for row in _median_runs(labels, args.root, sequence, args.frames, args.repeat, args.taskset)]
    paper_runs = {row["sequence"]: str(row["fps_runs"]) for row in rows if row["system"] == next(iter(SYSTEMS))}
    for row in rows:  # the median over rounds of the ratio within each round
        row["x_paper"] = statistics.median(_paired(str(row["fps_runs"]), paper_runs[str(row["sequence"])]))
    table = pl.DataFrame(rows)
    off = (table.filter((pl.col("detail") == str(Detail.OFF)) & pl.col("system").str.starts_with("vslam"))
           .select("sequence", "backend", "threads", off_fps="fps"))
    table = (table.join(off, on=["sequence", "backend", "threads"], how="left")
             .with_columns(recording_cost_pct=100 * (pl.col("off_fps") / pl.col("fps") - 1))
             .drop("off_fps"))
    if args.csv:
        table.write_csv(args.csv)
    stages = " | ".join(STAGES)
    pinned = f"; every run pinned to CPU {args.taskset} (taskset -c {args.taskset})" if args.taskset else ""
    print(f"KITTI {args.sequences}, frames {args.frames}; median-fps run of {args.repeat} (rows measured in turn, "
          "round by round); × paper: the median over rounds of the ratio within each round; ms per frame per stage"
          + pinned)
    print(f"| system | seq | fps | × paper | CPU ms/frame | recording cost | t_err % | r_err °/100 m | {stages} | "
          "keyframes/100 frames | BA ms/keyframe | end BA ms/keyframe | peak RSS MB | KB/frame |")
    print("|---|---|---|---|---|---|---|---|" + "---|" * len(STAGES) + "---|---|---|---|---|")
    for r in table.iter_rows(named=True):
        cells = " | ".join(f"{r[f'{stage}_ms']:.1f}" for stage in STAGES)
        cost = "—" if r["detail"] == str(Detail.OFF) else f"{r['recording_cost_pct']:+.1f} %"
        print(f"| {r['system']} | {r['sequence']} | {r['fps']:.1f} | {r['x_paper']:.2f} | {r['cpu_ms']:.1f} | {cost} "
              f"| {r['t_err']:.2f} "
              f"| {r['r_err']:.2f} | {cells} | {_optional(r['keyframes_per_100'], '{:.1f}')} "
              f"| {_optional(r['ba_ms_per_keyframe'], '{:.1f}')} | {_optional(r['end_ba_ms_per_keyframe'], '{:.1f}')} "
              f"| {r['peak_rss_mb']:.0f} | {r['kb_per_frame']:.1f} |")
    _loop_table(table)
    if args.skip_memory:
        return

    sequence = args.sequences.split(",")[0]
    print(f"\nPeak RSS (MB) by run length, KITTI {sequence}")
    lengths = [*args.memory_frames.split(","), args.frames]
    print("| system | " + " | ".join(f"frames {f}" for f in lengths) + " |")
    print("|---|" + "---|" * len(lengths))
    for label in MEMORY_SYSTEMS:
        peaks = [_in_own_process(label, args.root, sequence, frames, cpu=args.taskset)["peak_rss_mb"]
                 for frames in lengths]
        print(f"| {label} | " + " | ".join(f"{peak:.0f}" for peak in peaks) + " |")


def _loop_table(table: pl.DataFrame) -> None:
    """Loop closing's cost: the map backend's fps with it on and off (2 threads), and ms per keyframe of each
    part (describe the keyframe, query the places, verify candidates, optimise the pose graph)."""
    on = table.filter(pl.col("system") == "vslam --backend map, recording off (2 threads, default)")
    off = table.filter(pl.col("system").is_in(list(LOOP_OFF)))
    if on.is_empty() or off.is_empty():
        return
    print("\nLoop closing (map backend, 2 threads, recording off): fps on / off, the CPU time the run took (all its"
          "\nthreads and its worker process) on / off, and ms per keyframe; describe, query, verify and optimise run in"
          "\nthe worker process, wait (for the worker, at the fixed point), apply (a closed loop to the map) and submit"
          "\n(the next keyframe's snapshot) in the tracking thread")
    print("(change: the median over rounds of on / off within each round, and its range)")
    print("| seq | fps on | fps off | change | CPU ms/frame on | off | change | " + " | ".join(LOOP_PARTS) + " |")
    print("|---|---|---|---|---|---|---|" + "---|" * len(LOOP_PARTS))
    joined = on.join(off.select("sequence", fps_off="fps", runs_off="fps_runs", cpu_off="cpu_ms",
                                cpu_runs_off="cpu_runs"), on="sequence")
    for row in joined.iter_rows(named=True):
        parts = " | ".join(f"{row[f'loop_{part}_ms_per_keyframe']:.1f}" for part in LOOP_PARTS)
        changes = []
        for runs, runs_off in (("fps_runs", "runs_off"), ("cpu_runs", "cpu_runs_off")):
            change = [100 * (ratio - 1) for ratio in _paired(row[runs], row[runs_off])]
            spread = f" [{min(change):+.1f} to {max(change):+.1f}]" if len(change) > 1 else ""
            changes.append(f"{statistics.median(change):+.1f} %{spread}")
        print(f"| {row['sequence']} | {row['fps']:.1f} | {row['fps_off']:.1f} | {changes[0]} | {row['cpu_ms']:.1f} | "
              f"{row['cpu_off']:.1f} | {changes[1]} | {parts} |")


if __name__ == "__main__":
    main()
