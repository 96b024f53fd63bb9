"""Many logs: serial vs two local workers vs a 2-CPU Ray cluster, and what a Ray task costs per log.

    python -m benchmarks.batch ../shared/data/kitti [--out DIR]            # measurable today
    python -m benchmarks.batch ../shared/data/kitti --manifest-runner      # after the `batch` branch is merged

The logs: KITTI 00 and 05, windows 0:150, 50:200, 100:250, 150:300 of each (the sample holds 300 frames per
sequence) = 8 logs of 150 frames, every path absolute, each scored with `--detail standard` recordings.

Today (no manifest runner on this branch) each log is its own `vslam eval SRC --sequences S --frames F --report
DIR/<name>` process: one after the other (serial), two at a time (a stand-in for `--workers 2`), and as Ray tasks
(one CPU each) on a local 2-CPU cluster this script starts and stops. With ``--manifest-runner`` it times the real
commands instead, each into a fresh report folder:

    vslam eval --manifest M.csv --report R1 --workers 1 --detail standard
    vslam eval --manifest M.csv --report R2 --workers 2 --detail standard
    vslam eval --manifest M.csv --report R3 --ray-address 127.0.0.1:PORT --detail standard

The Ray overheads printed: the round trip of a trivial task on a warm worker, and a task on a fresh worker that
imports vslam (what the first log on each worker pays), with the import's own share.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the `ray_cluster` helpers: start/stop a private one-node head

import ray_cluster  # noqa: E402

SEQUENCES = ("00", "05")
WINDOWS = ("0:150", "50:200", "100:250", "150:300")
#: The manifest's columns. Adapt to app/manifest.py's header when the `batch` branch lands (not on this branch).
MANIFEST_COLUMNS = ("name", "source", "sequence", "frames")


def logs(kitti: Path) -> list[dict[str, str]]:
    """The 8 logs: one row per (sequence, window), absolute paths."""
    return [{"name": f"{seq}_{window.replace(':', '-')}", "source": str(kitti.resolve()), "sequence": seq,
             "frames": window} for seq in SEQUENCES for window in WINDOWS]


def write_manifest(rows: list[dict[str, str]], path: Path) -> Path:
    """The manifest CSV for `vslam eval --manifest`."""
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=MANIFEST_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def vslam(*args: str) -> list[str]:
    """A `vslam` command line run with this interpreter (the checkout, installed or not)."""
    return [sys.executable, "-c", "from app.cli import main; main()", *args]


def eval_one(row: dict[str, str], report: str) -> float:
    """Score one log in its own process; its wall seconds. Top level: Ray tasks run it too."""
    started = time.perf_counter()
    command = vslam("eval", row["source"], "--sequences", row["sequence"], "--frames", row["frames"],
                    "--report", str(Path(report) / row["name"]), "--detail", "standard")
    subprocess.run(command, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def timed(label: str, run: object) -> tuple[str, float]:
    """(label, wall seconds) of ``run()``."""
    started = time.perf_counter()
    run()  # type: ignore[operator]
    return label, time.perf_counter() - started


def per_log_modes(rows: list[dict[str, str]], out: Path, address: str) -> list[tuple[str, float]]:
    """Serial, two local processes at a time, and Ray tasks (1 CPU each): one process per log."""
    from app.batch_ray import run_on_ray

    def serial() -> None:
        for row in rows:
            eval_one(row, str(out / "serial"))

    def two_local() -> None:
        with ThreadPoolExecutor(2) as pool:
            list(pool.map(lambda row: eval_one(row, str(out / "local2")), rows))

    def on_ray() -> None:
        jobs = [(row, str(out / "ray")) for row in rows]
        run_on_ray(_eval_job, jobs, address, num_cpus=1, on_result=lambda i, r: None, failed=lambda r: r < 0,
                   fail_fast=False, on_error=_job_error)

    return [timed("serial (per-log processes)", serial), timed("2 local processes", two_local),
            timed("Ray, 2-CPU local cluster", on_ray)]


def _eval_job(job: tuple[dict[str, str], str]) -> float:
    return eval_one(*job)


def _job_error(job: tuple[dict[str, str], str], message: str) -> float:
    print(f"{job[0]['name']}: {message}", file=sys.stderr)
    return -1.0


def manifest_modes(rows: list[dict[str, str]], out: Path, address: str) -> list[tuple[str, float]]:
    """The real `vslam eval --manifest` commands (needs the `batch` branch's manifest runner)."""
    manifest = write_manifest(rows, out / "logs.csv")
    base = ("eval", "--manifest", str(manifest), "--detail", "standard", "--report")
    modes = [("--workers 1", (str(out / "r1"), "--workers", "1")), ("--workers 2", (str(out / "r2"), "--workers", "2")),
             ("--ray-address (2 CPUs)", (str(out / "r3"), "--ray-address", address))]
    return [timed(label, lambda extra=extra: subprocess.run(vslam(*base, *extra), check=True, cwd=ROOT))
            for label, extra in modes]


def noop(value: int) -> int:
    """The trivial task."""
    return value


def import_vslam() -> float:
    """A task that imports what a log's task imports; the import's seconds."""
    started = time.perf_counter()
    import app.cli  # noqa: F401
    import vslam_core.pipeline  # noqa: F401
    return time.perf_counter() - started


def ray_overheads(address: str) -> dict[str, float]:
    """Milliseconds: trivial round trip (warm worker, median of 50), fresh-worker task importing vslam (median of 3)."""
    import ray

    ray.init(address=address, log_to_driver=False, logging_level="warning")
    try:
        task = ray.remote(num_cpus=1)(noop)
        ray.get(task.remote(0))  # warm a worker
        trips = []
        for i in range(50):
            started = time.perf_counter()
            ray.get(task.remote(i))
            trips.append(time.perf_counter() - started)
        fresh = ray.remote(num_cpus=1, max_calls=1)(import_vslam)  # max_calls=1: each call on a new worker
        cold, imports = [], []
        for _ in range(3):
            started = time.perf_counter()
            imports.append(ray.get(fresh.remote()))
            cold.append(time.perf_counter() - started)
    finally:
        ray.shutdown()
    return {"trivial task round trip, warm worker (ms)": 1e3 * statistics.median(trips),
            "fresh-worker task importing vslam (ms)": 1e3 * statistics.median(cold),
            "  of which the import (ms)": 1e3 * statistics.median(imports)}


def table(results: list[tuple[str, float]], count: int) -> str:
    """Markdown: mode, wall s, s/log, speed-up against the first row."""
    lines = ["| mode | wall s | s/log | speed-up |", "|---|---:|---:|---:|"]
    for label, seconds in results:
        lines.append(f"| {label} | {seconds:.1f} | {seconds / count:.2f} | {results[0][1] / seconds:.2f}× |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kitti", type=Path, help="KITTI root (sequences/00, 05 and poses/)")
    parser.add_argument("--out", type=Path, help="folder for the reports (default: a temporary one)")
    parser.add_argument("--manifest-runner", action="store_true", help="time `vslam eval --manifest` (after merge)")
    args = parser.parse_args()
    rows = logs(args.kitti)
    out = args.out or Path(tempfile.mkdtemp(prefix="vslam-batch-"))
    out.mkdir(parents=True, exist_ok=True)
    process, address, temp_dir = ray_cluster.start_cluster(num_cpus=2)
    try:
        print(f"Ray head (2 CPUs) ready in {ray_cluster.last_start_seconds:.1f} s at {address}")
        for name, value in ray_overheads(address).items():
            print(f"{name}: {value:.1f}")
        modes = manifest_modes if args.manifest_runner else per_log_modes
        print(table(modes(rows, out, address), len(rows)))
        print(f"{len(rows)} logs of 150 frames, --detail standard, reports under {out}")
    finally:
        ray_cluster.stop_cluster(process, temp_dir)


if __name__ == "__main__":
    main()
