"""Memory on a street driven again: KITTI 00 frames 0-299 forward, back and forward again (0..299, 298..1,
0..299, ...), as a car doing the same street, so every frame after the first 300 revisits a mapped place.

    python -m benchmarks.revisit_memory ../shared/data/kitti  # both backends, RSS at 300 / 900 / 1800 frames
    python -m benchmarks.revisit_memory ../shared/data/kitti --backends map --at 300,900 --no-loops

The drive is a KITTI-layout folder of symlinks (sequences/00/image_0, calib.txt, times.txt and poses/00.txt in
the drive's order) made in a temporary folder from the KITTI folder given (read-only). Each backend runs in its
own process, one after the other, without a recording and without saving the map. At each `--at` frame it
notes the resident memory (VmRSS) and its peak (VmHWM) of the run's process and of its worker process (bundle
adjustment and loop search, vslam_core/mapping/worker_process.py); then the growth per revisited frame (peak
RSS of both processes, from the first `--at` frame to the last, over the frames between), the keyframes
inserted and the loops closed, and at each `--at` frame the keyframes and landmarks the run's map holds (objects
counted by the garbage collector; the loop search's place database is in the worker and not counted).
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame
from vslam_core.sources.kitti import KittiSource

FORWARD = 300  # frames of KITTI 00 with images here


def drive_order(frames: int, forward: int = FORWARD) -> list[int]:
    """The source frame of each drive frame: 0..forward-1, forward-2..0, 1..forward-1, ... (`frames` long)."""
    cycle = list(range(forward)) + list(range(forward - 2, 0, -1))  # one way and back, the turns not repeated
    order = [cycle[i % len(cycle)] for i in range(frames)]
    return order


def make_drive(kitti: Path, folder: Path, frames: int) -> Path:
    """A KITTI-layout folder (sequence 00) of the back-and-forth drive in `folder`; returns its root."""
    sequence = kitti / "sequences" / "00"
    images = folder / "sequences" / "00" / "image_0"
    images.mkdir(parents=True)
    poses = (kitti / "poses" / "00.txt").read_text().splitlines()
    order = drive_order(frames)
    for n, source in enumerate(order):
        (images / f"{n:06d}.png").symlink_to(sequence / "image_0" / f"{source:06d}.png")
    (folder / "sequences" / "00" / "calib.txt").write_text((sequence / "calib.txt").read_text())
    (folder / "sequences" / "00" / "times.txt").write_text("".join(f"{n * 0.1:.6f}\n" for n in range(frames)))
    (folder / "poses").mkdir()
    (folder / "poses" / "00.txt").write_text("".join(poses[i] + "\n" for i in order))
    return folder


def _kb(pid: int | str, field: str) -> int:
    """A /proc/<pid>/status field in KB (0 if the process is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _children() -> list[int]:
    """Pids of this process's children (the backend worker)."""
    try:
        text = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text()
    except OSError:
        return []
    return [int(p) for p in text.split()]


def _map_objects() -> tuple[int, int]:
    """(keyframes, landmarks) alive in this process: the map's (vslam_core/mapping/map.py)."""
    from vslam_core.mapping.map import Keyframe, Landmark
    counts = {Keyframe: 0, Landmark: 0}
    for item in gc.get_objects():
        if type(item) in counts:
            counts[type(item)] += 1
    return counts[Keyframe], counts[Landmark]


def _measure(args: tuple[str, str, int, tuple[int, ...], bool, str]) -> dict[str, object]:
    backend, root, frames, at, loops, scale = args
    config = EngineConfig().with_backend(backend).with_scale(scale)  # type: ignore[arg-type]
    if not loops:
        from dataclasses import replace
        config = replace(config, loop=replace(config.loop, enabled=False))
    source = KittiSource(root, "00")
    samples: list[dict[str, object]] = []
    workers: set[int] = set()
    inserted: list[int] = []
    loops: list[int] = []

    def keyframes(frame: Frame, result: FrameResult) -> None:
        mapping = result.mapping
        if mapping is not None and mapping.keyframe is not None:
            inserted.append(result.position)
        if mapping is not None and mapping.loop is not None and mapping.loop.closed is not None:
            loops.append(result.position)

    def sink(frame: Frame, result: FrameResult) -> None:
        done = result.position + 1
        workers.update(_children())
        if done in at:
            worker_rss = sum(_kb(p, "VmRSS") for p in workers)
            worker_peak = sum(_kb(p, "VmHWM") for p in workers)
            keyframes_kept, landmarks = _map_objects()
            samples.append({"frames": done, "rss_mb": _kb("self", "VmRSS") / 1024,
                            "peak_mb": _kb("self", "VmHWM") / 1024, "worker_rss_mb": worker_rss / 1024,
                            "worker_peak_mb": worker_peak / 1024, "keyframes": keyframes_kept,
                            "landmarks": landmarks})

    run = run_odometry(source, config, sinks=(keyframes, sink))  # no `finish`: a run without --save-map
    return {"backend": backend, "frames": run.frames, "samples": samples, "keyframes": len(inserted),
            "loops": loops}


def growth_kb(samples: list[dict[str, object]]) -> float:
    """KB of peak RSS (run + worker) added per frame from the first sample to the last."""
    first, last = samples[0], samples[-1]
    total = [float(s["peak_mb"]) + float(s["worker_peak_mb"]) for s in (first, last)]
    return (total[1] - total[0]) * 1024 / max(int(last["frames"]) - int(first["frames"]), 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("kitti", type=Path, nargs="?", default=Path("../shared/data/kitti"),
                        help="KITTI folder with sequences/00 and poses/00.txt (read-only)")
    parser.add_argument("--backends", default="vo,map")
    parser.add_argument("--at", default="300,900,1800", help="frames at which memory is noted (the last: the run)")
    parser.add_argument("--scale", default="gt")
    parser.add_argument("--no-loops", action="store_true", help="map backend without loop closing")
    args = parser.parse_args()
    at = tuple(sorted(int(a) for a in args.at.split(",")))
    if not (args.kitti / "poses" / "00.txt").exists() or not (args.kitti / "sequences" / "00" / "image_0").is_dir():
        parser.error(f"{args.kitti}: no KITTI sequence 00 (sequences/00/image_0 and poses/00.txt) there")
    with tempfile.TemporaryDirectory() as folder:
        root = str(make_drive(args.kitti, Path(folder), at[-1]))
        for backend in args.backends.split(","):
            with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
                out = pool.submit(_measure, (backend, root, at[-1], at, not args.no_loops, args.scale)).result()
            for s in out["samples"]:  # type: ignore[attr-defined]
                print(f"{backend:4s} frames {s['frames']:5d}  rss {s['rss_mb']:6.1f} MB  peak {s['peak_mb']:6.1f} MB"
                      f"  worker rss {s['worker_rss_mb']:6.1f} MB  peak {s['worker_peak_mb']:6.1f} MB"
                      f"  map {s['keyframes']} keyframes, {s['landmarks']} landmarks")
            print(f"{backend:4s} growth {growth_kb(out['samples']):.1f} KB/frame (peak RSS, run + worker, "  # type: ignore[arg-type]
                  f"frames {at[0]}..{at[-1]}); {out['keyframes']} keyframes inserted, "
                  f"{len(out['loops'])} loops closed")  # type: ignore[arg-type]


if __name__ == "__main__":
    main()
