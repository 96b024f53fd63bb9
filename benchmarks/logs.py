"""Accuracy and speed of vslam on ROS logs of real KITTI frames re-imaged through known lenses.

    python -m benchmarks.logs ../shared/data/kitti --sequences 00,05 --windows 0:300,0:150,150:300,0:300:2 \
        --seeds 0,1 [--out DIR] [--jobs 2] [--speed-repeats 3]

For every sequence the three lens logs of `tests.ros_logs.LOGS` (MCAP of JPEG q95 + plumb_bob CameraInfo,
ROS 1 raw mono8 + equidistant, ROS 2 sqlite3 raw mono8 + plumb_bob) are written once for KITTI frames
0:300, each with its TUM ground truth; log frame i is KITTI frame i, so a window START:END[:STEP] selects
the same frames from KITTI and from a log.

ACCURACY: for each window × RANSAC seed the engine (default config but the seed; scale from ground truth)
runs on (a) the rectified KITTI frames (`KittiSource`), (b) each log with its CameraInfo, (c) each log with
the distortion IGNORED (calibration = the same K, model none; a control that shows the lens matters). The
table gives the mean KITTI t_err (%) and r_err (°/100 m) over windows × seeds and checks the acceptance
rule, per sequence on the means: log t_err ≤ 1.5 × rectified t_err + 0.5, and the same for r_err; the
worst single (window, seed) against its own rectified run is given beside it. These runs go through a
pool of `--jobs` processes with ``threads = 1`` (trajectories do not depend on threads; see
benchmarks/accuracy.py), so their fps are not speeds.

SPEED: for the first sequence (`--speed-sequence`, default 00), frames 0:300, the re-imaged lens frames are
also written as PNG folders (``cv2.imwrite``) with a ROS camera_info YAML beside them, read back with
`read_calibration` and given to `ImageFolderSource`. The engine then runs, one run at a time in this
process, on: the PNG folder (plumb_bob), the MCAP JPEG log, the sqlite3 raw log, the PNG folder
(equidistant), the ROS 1 raw log, and the rectified KITTI PNGs for reference; with the default threads
(2: decoding of the next frame overlaps the engine) and with ``threads = 1``. fps = 300 / wall time of
`run_odometry` (decoding included; opening the source — the log's stamp scan — is timed apart), median
of `--speed-repeats` repeats run round-robin. The rule: a log's fps ≥ 0.8 × its PNG twin's. The source
iteration alone (decoding, no engine) is timed too; when a log misses the rule, the source iteration and a
whole run are profiled with cProfile and the top functions printed.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import functools
import io
import itertools
import math
import multiprocessing
import os
import pstats
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from tests.ros_logs import LOGS, KittiClip, LensLog, Reimager, kitti_clip, make_reimager, write_lens_log
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.sources.base import CameraIntrinsics, FrameRange, FrameSource
from vslam_core.sources.calibration_files import read_calibration
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.ros.bag import RosbagSource
from vslam_core.trajectory.metrics import kitti_errors

LOG_FRAMES = range(0, 300)
RECTIFIED = "rectified KITTI"
SLACK_FACTOR, SLACK_OFFSET = 1.5, 0.5  # log ≤ 1.5 × rectified + 0.5
SPEED_RULE = 0.8  # log fps ≥ 0.8 × PNG fps


# --------------------------------------------------------------------------------------------------
# sources


@dataclasses.dataclass(frozen=True)
class Spec:
    """One source to run: rectified KITTI, a log with its CameraInfo, a log without distortion, a PNG folder."""

    label: str
    kind: str  # kitti, log, log-nodist, folder
    root: str
    sequence: str
    path: str = ""
    gt_path: str = ""
    camera: CameraIntrinsics | None = None
    calib_path: str = ""


def undistorted_k(camera: CameraIntrinsics) -> CameraIntrinsics:
    """The lens's K with model none (width/height 0 = the images' size): the distortion ignored."""
    return CameraIntrinsics(camera.fx, camera.fy, camera.cx, camera.cy, 0, 0, origin="K only (distortion ignored)")


def open_source(spec: Spec, window: str) -> FrameSource:
    frames = FrameRange.parse(window)
    if spec.kind == "kitti":
        return KittiSource(spec.root, sequence=spec.sequence, frames=frames)
    if spec.kind == "log":
        return RosbagSource(spec.path, frames=frames, ground_truth=spec.gt_path)
    if spec.kind == "log-nodist":
        assert spec.camera is not None
        return RosbagSource(spec.path, frames=frames, ground_truth=spec.gt_path, calibration=undistorted_k(spec.camera))
    if spec.kind == "folder":
        intrinsics = read_calibration(Path(spec.calib_path))
        return ImageFolderSource(spec.path, intrinsics=intrinsics, ground_truth=spec.gt_path, frames=frames)
    raise ValueError(spec.kind)


def seeded(seed: int, threads: int | None = None) -> EngineConfig:
    config = EngineConfig()
    config = dataclasses.replace(config, pose=dataclasses.replace(config.pose, seed=seed))
    return config if threads is None else dataclasses.replace(config, threads=threads)


# --------------------------------------------------------------------------------------------------
# writing the logs and PNG twins


def camera_info_yaml(camera: CameraIntrinsics) -> str:
    """A ROS camera_info YAML (camera_calibration's format) of `camera`."""
    def row(values: list[float]) -> str:
        return "[" + ", ".join(repr(float(v)) for v in values) + "]"

    k = camera.K.ravel().tolist()
    p = [camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return (f"image_width: {camera.width}\nimage_height: {camera.height}\ncamera_name: reimaged_kitti\n"
            f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {row(k)}\n"
            f"distortion_model: {camera.model}\n"
            f"distortion_coefficients:\n  rows: 1\n  cols: {len(camera.coefficients)}\n"
            f"  data: {row(list(camera.coefficients))}\n"
            f"rectification_matrix:\n  rows: 3\n  cols: 3\n  data: {row(np.eye(3).ravel().tolist())}\n"
            f"projection_matrix:\n  rows: 3\n  cols: 4\n  data: {row(p)}\n")


def write_png_twin(clip: KittiClip, reimager: Reimager, folder: Path, gt_path: Path) -> Path:
    """The re-imaged frames as ``folder/images/NNNNNN.png`` + ``folder/camera.yaml``; returns the YAML's path
    (checked to read back as the lens camera)."""
    images = folder / "images"
    images.mkdir(parents=True, exist_ok=True)
    for i, image in enumerate(clip.images()):
        if not cv2.imwrite(str(images / f"{i:06d}.png"), reimager(image)):
            raise OSError(f"cannot write {images / f'{i:06d}.png'}")
    calib = folder / "camera.yaml"
    calib.write_text(camera_info_yaml(reimager.camera), encoding="utf-8")
    read = read_calibration(calib)
    lens = reimager.camera
    assert (read.fx, read.fy, read.cx, read.cy, read.width, read.height, read.model) == \
        (lens.fx, lens.fy, lens.cx, lens.cy, lens.width, lens.height, lens.model), (read, lens)
    assert np.allclose(read.coefficients, lens.coefficients), (read, lens)
    (folder / "gt.tum").write_bytes(gt_path.read_bytes())
    return calib


def write_logs(root: Path, sequence: str, out: Path, png_twins: bool) -> tuple[dict[str, LensLog], dict[str, Path]]:
    """The three lens logs of `sequence` (frames 0:300) in ``out/SEQUENCE``; with `png_twins`, one PNG folder
    per lens model too: model → folder."""
    clip = kitti_clip(root, sequence, LOG_FRAMES)
    folder = out / sequence
    reimagers: dict[str, Reimager] = {}
    logs = {}
    for name, (_kind, model, coefficients, *_rest) in LOGS.items():
        if model not in reimagers:
            reimagers[model] = make_reimager(clip.camera, model, coefficients)
        kind = LOGS[name][0]
        old = folder / (f"{name}.bag" if kind == "ros1" else name)  # rosbags will not overwrite a log
        if old.is_dir():
            shutil.rmtree(old)
        elif old.exists():
            old.unlink()
        start = time.perf_counter()
        logs[name] = write_lens_log(name, clip, folder, reimagers[model])
        size = sum(p.stat().st_size for p in ([logs[name].path] if logs[name].path.is_file()
                                              else logs[name].path.rglob("*")))
        print(f"  wrote {logs[name].path} ({size / 1e6:.0f} MB, {time.perf_counter() - start:.0f} s)", flush=True)
    twins = {}
    if png_twins:
        for model, reimager in reimagers.items():
            gt = next(log.gt_path for name, log in logs.items() if LOGS[name][1] == model)
            twin = folder / f"png-{model}"
            write_png_twin(clip, reimager, twin, gt)
            twins[model] = twin
            print(f"  wrote {twin}/images (300 PNG) + camera.yaml", flush=True)
    return logs, twins


def log_specs(root: Path, sequence: str, logs: dict[str, LensLog]) -> list[Spec]:
    specs = [Spec(RECTIFIED, "kitti", str(root), sequence)]
    for name, log in logs.items():
        specs.append(Spec(f"{name} (CameraInfo)", "log", str(root), sequence, str(log.path), str(log.gt_path),
                          log.camera))
    for name, log in logs.items():
        specs.append(Spec(f"{name} (distortion ignored)", "log-nodist", str(root), sequence, str(log.path),
                          str(log.gt_path), log.camera))
    return specs


# --------------------------------------------------------------------------------------------------
# accuracy


@dataclasses.dataclass(frozen=True)
class Job:
    spec: Spec
    window: str
    seed: int


def _accuracy_run(job: Job) -> dict[str, object]:
    source = open_source(job.spec, job.window)
    gt = source.ground_truth
    assert gt is not None
    run = run_odometry(source, seeded(job.seed, threads=1), (), RunResult([], [], []))
    t_err, r_err = kitti_errors(gt, run.pose_array())
    return {"sequence": job.spec.sequence, "source": job.spec.label, "kind": job.spec.kind, "window": job.window,
            "seed": job.seed, "frames": run.frames, "t_err": t_err, "r_err": r_err, "held": run.held}


def _mean(values: list[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _limit(rectified: float) -> float:
    return SLACK_FACTOR * rectified + SLACK_OFFSET


def _fmt(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.2f}"


def accuracy_table(rows: list[dict[str, object]]) -> str:
    lines = ["| sequence | source | runs | mean t_err % | mean r_err °/100 m | check (means: ≤ 1.5 × rectified + 0.5) "
             "| worst single window/seed (value vs its limit) |",
             "|---|---|---|---|---|---|---|"]
    sequences = list(dict.fromkeys(str(r["sequence"]) for r in rows))
    for sequence in sequences:
        part = [r for r in rows if r["sequence"] == sequence]
        sources = list(dict.fromkeys(str(r["source"]) for r in part))
        rect = {(r["window"], r["seed"]): r for r in part if r["source"] == RECTIFIED}
        rect_t = _mean([float(r["t_err"]) for r in rect.values()])  # type: ignore[arg-type]
        rect_r = _mean([float(r["r_err"]) for r in rect.values()])  # type: ignore[arg-type]
        for label in sources:
            runs = [r for r in part if r["source"] == label]
            t = _mean([float(r["t_err"]) for r in runs])  # type: ignore[arg-type]
            r_ = _mean([float(r["r_err"]) for r in runs])  # type: ignore[arg-type]
            if label == RECTIFIED:
                check, worst = f"limits: t ≤ {_fmt(_limit(rect_t))}, r ≤ {_fmt(_limit(rect_r))}", "-"
            else:
                ok_t, ok_r = t <= _limit(rect_t), r_ <= _limit(rect_r)
                check = ("PASS" if ok_t and ok_r else "FAIL") + f" (t {'ok' if ok_t else 'over'}, " \
                    f"r {'ok' if ok_r else 'over'})"
                worst = _worst(runs, rect)
            lines.append(f"| {sequence} | {label} | {len(runs)} | {_fmt(t)} | {_fmt(r_)} | {check} | {worst} |")
    return "\n".join(lines)


def _worst(runs: list[dict[str, object]], rect: dict[tuple[object, object], dict[str, object]]) -> str:
    """The (window, seed) whose t_err or r_err exceeds its own rectified run's limit the most (by ratio)."""
    best: tuple[float, str] | None = None
    failures = 0
    for run in runs:
        base = rect.get((run["window"], run["seed"]))
        if base is None:
            continue
        over = False
        for metric, unit in (("t_err", "%"), ("r_err", "°")):
            value, limit = float(run[metric]), _limit(float(base[metric]))  # type: ignore[arg-type]
            if not (math.isfinite(value) and math.isfinite(limit)):
                continue
            over |= value > limit
            ratio = value / limit
            text = f"{run['window']} s{run['seed']} {metric[0]}: {value:.2f}{unit} vs {limit:.2f}"
            if best is None or ratio > best[0]:
                best = (ratio, text)
        failures += over
    if best is None:
        return "n/a"
    return f"{best[1]} ({'over' if best[0] > 1 else 'within'}; {failures}/{len(runs)} runs over)"


# --------------------------------------------------------------------------------------------------
# speed


def _timed_run(spec: Spec, threads: int | None) -> tuple[float, float, int]:
    """(seconds to open the source, seconds of run_odometry, frames)."""
    start = time.perf_counter()
    source = open_source(spec, "0:300")
    opened = time.perf_counter() - start
    start = time.perf_counter()
    run = run_odometry(source, seeded(0, threads), (), RunResult([], [], []))
    return opened, time.perf_counter() - start, run.frames


def _iterate(spec: Spec) -> tuple[float, int]:
    source = open_source(spec, "0:300")
    start = time.perf_counter()
    n = sum(1 for _ in source)
    return time.perf_counter() - start, n


def _profile(what: Callable[[], object], top: int) -> str:
    profiler = cProfile.Profile()
    profiler.enable()
    what()
    profiler.disable()
    out = io.StringIO()
    stats = pstats.Stats(profiler, stream=out)
    stats.sort_stats("tottime").print_stats(top)
    text = out.getvalue()
    return "\n".join(line for line in text.splitlines() if line.strip())


def speed(specs: list[Spec], twins: dict[str, str], repeats: int) -> tuple[str, list[str]]:
    """The speed table, and the labels of the logs that miss the 20 % rule."""
    default_threads = EngineConfig().threads
    thread_options = [default_threads] + ([1] if default_threads != 1 else [])
    times: dict[tuple[str, int], list[float]] = {}
    opens: dict[str, list[float]] = {}
    decode: dict[str, list[float]] = {}
    for repeat in range(repeats):
        for spec, threads in itertools.product(specs, thread_options):
            opened, seconds, frames = _timed_run(spec, threads)
            assert frames == 300, (spec.label, frames)
            times.setdefault((spec.label, threads), []).append(frames / seconds)
            opens.setdefault(spec.label, []).append(opened)
            print(f"  speed repeat {repeat + 1}: {spec.label}, threads {threads}: {frames / seconds:.1f} fps "
                  f"(open {opened:.2f} s; load {os.getloadavg()[0]:.2f})", flush=True)
        for spec in specs:
            seconds, frames = _iterate(spec)
            decode.setdefault(spec.label, []).append(frames / seconds)
    header = ["source"] + [f"fps, {t} thread{'s' if t > 1 else ''}" + (" (default)" if t == default_threads else "")
                           for t in thread_options]
    header += [f"log/PNG, {t} thr" for t in thread_options] + ["decode only fps", "open s", f"≥ {SPEED_RULE:.0%} rule"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    failing = []
    for spec in specs:
        fps = [statistics.median(times[(spec.label, t)]) for t in thread_options]
        twin = twins.get(spec.label)
        ratios = [] if twin is None else [f / statistics.median(times[(twin, t)]) for f, t in
                                           zip(fps, thread_options, strict=True)]
        if twin is None:
            rule = "-"
        else:
            ok = all(r >= SPEED_RULE for r in ratios)
            rule = ("PASS" if ok else "FAIL") + f" vs {twin}"
            if not ok:
                failing.append(spec.label)
        cells = [spec.label] + [f"{f:.1f} [{min(times[(spec.label, t)]):.1f}–{max(times[(spec.label, t)]):.1f}]"
                                for f, t in zip(fps, thread_options, strict=True)]
        cells += [f"{r:.2f}" for r in ratios] if ratios else ["-"] * len(thread_options)
        cells += [f"{statistics.median(decode[spec.label]):.0f}", f"{statistics.median(opens[spec.label]):.2f}", rule]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines), failing


# --------------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--sequences", default="00,05")
    parser.add_argument("--windows", default="0:300,0:150,150:300,0:300:2")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--out", type=Path, default=None, help="keep the logs, PNG folders and runs.csv here")
    parser.add_argument("--jobs", type=int, default=2, help="processes for the accuracy runs (threads = 1 each)")
    parser.add_argument("--speed-sequence", default="00")
    parser.add_argument("--speed-repeats", type=int, default=3)
    parser.add_argument("--skip", choices=("accuracy", "speed"), action="append", default=[])
    args = parser.parse_args()
    sequences = [s.strip() for s in args.sequences.split(",") if s.strip()]
    windows = [w.strip() for w in args.windows.split(",") if w.strip()]
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    for window in windows:
        frames = FrameRange.parse(window)
        if frames.end is None or frames.end > len(LOG_FRAMES):
            parser.error(f"window {window}: the logs hold frames 0:{len(LOG_FRAMES)}")
    print(f"# {' '.join(sys.argv)}\n# load at start: {os.getloadavg()}, {os.cpu_count()} cores", flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        written: dict[str, tuple[dict[str, LensLog], dict[str, Path]]] = {}
        for sequence in sequences:
            print(f"writing the lens logs of {sequence} into {out / sequence}", flush=True)
            twins = "speed" not in args.skip and sequence == args.speed_sequence
            written[sequence] = write_logs(args.root, sequence, out, png_twins=twins)

        if "accuracy" not in args.skip:
            jobs = [Job(spec, window, seed) for sequence in sequences
                    for spec in log_specs(args.root, sequence, written[sequence][0])
                    for window, seed in itertools.product(windows, seeds)]
            print(f"accuracy: {len(jobs)} runs in {args.jobs} processes", flush=True)
            start = time.perf_counter()
            # spawn, not fork: the parent has used OpenCV's thread pool (writing the logs), and forked children
            # hang in their first OpenCV call
            with multiprocessing.get_context("spawn").Pool(args.jobs) as pool:
                rows = []
                for i, row in enumerate(pool.imap(_accuracy_run, jobs, chunksize=1)):
                    rows.append(row)
                    if (i + 1) % 14 == 0:
                        print(f"  {i + 1}/{len(jobs)} runs, {time.perf_counter() - start:.0f} s, load "
                              f"{os.getloadavg()[0]:.2f}", flush=True)
            if args.out:
                import polars as pl

                pl.DataFrame(rows).write_csv(args.out / "runs.csv")
            print(f"\nACCURACY — KITTI {','.join(sequences)}, lens logs of frames 0:300, windows {','.join(windows)}, "
                  f"seeds {','.join(map(str, seeds))}; default config but the seed, scale from ground truth; means "
                  f"over windows × seeds ({time.perf_counter() - start:.0f} s, load {os.getloadavg()})")
            print(accuracy_table(rows), flush=True)

        if "speed" not in args.skip:
            logs, png = written[args.speed_sequence]
            root, seq = str(args.root), args.speed_sequence
            png_plumb = f"PNG folder (plumb_bob), {seq}"
            png_equi = f"PNG folder (equidistant), {seq}"
            log = {name: f"{name} log, {seq}" for name in LOGS}

            def folder(label: str, model: str) -> Spec:
                return Spec(label, "folder", root, seq, str(png[model] / "images"), str(png[model] / "gt.tum"),
                            calib_path=str(png[model] / "camera.yaml"))

            def bag(name: str) -> Spec:
                return Spec(log[name], "log", root, seq, str(logs[name].path), str(logs[name].gt_path))

            specs = [folder(png_plumb, "plumb_bob"), bag("mcap-plumb_bob"), bag("sqlite3-plumb_bob"),
                     folder(png_equi, "equidistant"), bag("ros1-equidistant"),
                     Spec(f"{RECTIFIED} PNG (reference), {seq}", "kitti", root, seq)]
            twins = {log["mcap-plumb_bob"]: png_plumb, log["sqlite3-plumb_bob"]: png_plumb,
                     log["ros1-equidistant"]: png_equi}
            print(f"\nspeed: {len(specs)} sources × threads × {args.speed_repeats} repeats", flush=True)
            start_load = os.getloadavg()
            table, failing = speed(specs, twins, args.speed_repeats)
            print(f"\nSPEED — KITTI {seq} frames 0:300 (300 frames), fps = frames / wall time of run_odometry "
                  f"(decoding included, opening apart), median [min–max] of {args.speed_repeats}; load at start "
                  f"{start_load}, at end {os.getloadavg()}")
            print(table, flush=True)
            by_label = {spec.label: spec for spec in specs}
            for label in failing:
                spec = by_label[label]
                print(f"\nPROFILE of {label} (misses the 20 % rule): source iteration alone, top by own time")
                print(_profile(functools.partial(_iterate, spec), 18))
                print(f"\nPROFILE of {label}: whole run (threads 1), top by own time")
                print(_profile(functools.partial(_timed_run, spec, 1), 18))


if __name__ == "__main__":
    main()
