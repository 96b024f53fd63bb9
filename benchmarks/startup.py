"""What a `vslam` process costs before it does any work: CPU (user + system, every thread) of commands that end
at once or do little, each in a fresh process.

    python -m benchmarks.startup ../shared/data/kitti --repeat 5
    python -m benchmarks.startup ../shared/data/kitti --against /tmp/main-checkout   # paired: that tree vs this

Commands: `--help`; `run` refused at once (its output exists: the source is opened, nothing else); `eval` of
a path that does not exist; `inspect` of a recording (KITTI 05 0:150 at --detail summary, written first); and
`run` of KITTI 05 0:30 at --detail off, summary and full. CPU time rather than wall time: the machine may be
shared. With `--against`, each command alternates between the two trees (`PYTHONPATH`), in alternating order,
and the table gives both medians and the median of the paired differences.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def commands(kitti: Path, work: Path) -> dict[str, tuple[list[str], int]]:
    """Label -> the `vslam` arguments and the exit code they must end with."""
    taken = work / "taken.rrd"
    taken.write_bytes(b"")
    run = ["run", str(kitti), "-s", "05", "--frames", "0:30"]
    return {
        "--help": (["--help"], 0),
        "run, output exists": (["run", str(kitti), "-s", "05", "--frames", "0:300", "-o", str(taken)], 2),
        "eval, no such path": (["eval", str(work / "missing")], 2),
        "inspect (05 0:150 summary)": (["inspect", str(work / "summary.rrd")], 0),
        "run 0:30 --detail off": ([*run, "--detail", "off"], 0),
        "run 0:30 --detail summary": ([*run, "--detail", "summary", "-o", str(work / "s.rrd"), "--force"], 0),
        "run 0:30 --detail full": ([*run, "--detail", "full", "-o", str(work / "f.rrd"), "--force"], 0),
    }


def cpu_seconds(tree: Path, args: list[str], code: int, work: Path) -> float:
    """User + system CPU of ``python -m vslam.cli ARGS`` run from `tree`; it must exit with `code`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, "-m", "vslam.cli", *args], env={**os.environ, "PYTHONPATH": str(tree)},
                          cwd=work, capture_output=True, text=True, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != code:
        raise SystemExit(f"vslam {' '.join(args)} ({tree}) exited {done.returncode}, not {code}: {done.stderr[-300:]}")
    return after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kitti", type=Path, help="KITTI root with sequence 05")
    parser.add_argument("--repeat", type=int, default=5, help="runs of each command (per tree)")
    parser.add_argument("--against", type=Path, help="another checkout, measured in pairs with this one")
    options = parser.parse_args()
    kitti = options.kitti.resolve()
    trees = {"this": ROOT, **({"other": options.against.resolve()} if options.against else {})}
    with tempfile.TemporaryDirectory(prefix="vslam-startup-") as folder:
        work = Path(folder)
        subprocess.run([sys.executable, "-m", "vslam.cli", "run", str(kitti), "-s", "05", "--frames",
                        "0:150", "--detail", "summary", "-o", str(work / "summary.rrd")],
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, check=True)
        seconds: dict[str, dict[str, list[float]]] = {}
        for label, (args, code) in commands(kitti, work).items():
            seconds[label] = {name: [] for name in trees}
            for i in range(options.repeat):
                order = list(trees) if i % 2 == 0 else list(reversed(trees))
                for name in order:
                    seconds[label][name].append(cpu_seconds(trees[name], args, code, work))
    header = "| command | CPU s (this) |" + (" CPU s (other) | other − this (paired median) |" if options.against
                                             else "")
    print(header)
    print("|---|---:|" + ("---:|---:|" if options.against else ""))
    for label, by_tree in seconds.items():
        row = f"| {label} | {statistics.median(by_tree['this']):.2f} |"
        if options.against:
            paired = [o - t for o, t in zip(by_tree["other"], by_tree["this"], strict=True)]
            row += f" {statistics.median(by_tree['other']):.2f} | {statistics.median(paired):+.2f} |"
        print(row)
    print(f"\nmedians of {options.repeat} runs each (user + system CPU of the whole process)")


if __name__ == "__main__":
    main()
