"""Many logs: `vslam eval --manifest` serially, on two local workers and on a 2-CPU Ray cluster, and what a Ray
task costs per log.

    python -m benchmarks.batch ../shared/data/kitti [--out DIR]

The logs: KITTI 00 and 05, windows 0:150, 50:200, 100:250, 150:300 of each (the sample holds 300 frames per
sequence) = 8 logs of 150 frames, every path absolute, each scored with `--detail standard` recordings. Each
mode is the real command into a fresh report folder, with the default config (`threads = 2`: a Ray task then
reserves 2 CPUs) and with `threads = 1` (two logs at a time on two cores):

    vslam eval --manifest M.csv --report R --workers 1 | --workers 2 | --ray-address 127.0.0.1:PORT

The Ray overheads printed: the round trip of a trivial task on a warm worker, and a task on a fresh worker that
imports vslam (what the first log on each worker pays), with the import's own share. The Ray head is a private
one-node cluster this script starts and stops (`tests/ray_cluster.py`).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the `ray_cluster` helpers: start/stop a private one-node head

import ray_cluster  # noqa: E402

SEQUENCES = ("00", "05")
WINDOWS = ("0:150", "50:200", "100:250", "150:300")
#: The manifest's columns (vslam/batch/manifest.py).
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
    return [sys.executable, "-c", "from vslam.cli import main; main()", *args]


def timed(label: str, run: object) -> tuple[str, float]:
    """(label, wall seconds) of ``run()``."""
    started = time.perf_counter()
    run()  # type: ignore[operator]
    return label, time.perf_counter() - started


def manifest_modes(rows: list[dict[str, str]], out: Path, address: str) -> list[tuple[str, float]]:
    """The real `vslam eval --manifest` commands, each into a fresh report folder."""
    manifest = write_manifest(rows, out / "logs.csv")
    one_thread = out / "threads1.toml"
    one_thread.write_text("threads = 1\n")
    modes = [("--workers 1 (threads 2)", ("--workers", "1")), ("--workers 2 (threads 2)", ("--workers", "2")),
             ("--ray-address, 2-CPU cluster (threads 2: one task at a time)", ("--ray-address", address)),
             ("--workers 2, threads 1", ("--workers", "2", "--config", str(one_thread))),
             ("--ray-address, 2-CPU cluster, threads 1", ("--ray-address", address, "--config", str(one_thread)))]
    results = []
    for number, (label, extra) in enumerate(modes):
        command = vslam("eval", "--manifest", str(manifest), "--detail", "standard", "--report",
                        str(out / f"r{number}"), *extra)
        results.append(timed(label, lambda command=command: subprocess.run(command, check=True, cwd=ROOT,
                                                                           stdout=subprocess.DEVNULL)))
    return results


def noop(value: int) -> int:
    """The trivial task."""
    return value


def import_vslam() -> float:
    """A task that imports what a log's task imports; the import's seconds."""
    started = time.perf_counter()
    import vslam.cli  # noqa: F401
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
    args = parser.parse_args()
    rows = logs(args.kitti)
    out = args.out or Path(tempfile.mkdtemp(prefix="vslam-batch-"))
    out.mkdir(parents=True, exist_ok=True)
    process, address, temp_dir = ray_cluster.start_cluster(num_cpus=2)
    try:
        print(f"Ray head (2 CPUs) ready in {ray_cluster.last_start_seconds:.1f} s at {address}")
        for name, value in ray_overheads(address).items():
            print(f"{name}: {value:.1f}")
        print(table(manifest_modes(rows, out, address), len(rows)))
        print(f"{len(rows)} logs of 150 frames, --detail standard, reports under {out}")
    finally:
        ray_cluster.stop_cluster(process, temp_dir)


if __name__ == "__main__":
    main()
