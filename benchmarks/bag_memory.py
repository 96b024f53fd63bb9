"""Memory and speed of `RosbagSource` on big logs: peak RSS must not grow with the bag's size.

Writes ROS 2 bags (MCAP or sqlite3 storage) of raw mono8 1241x376 frames (KITTI sequence 00's frames
repeated, or noise without the data) into a temporary folder, then, in a fresh process per bag, opens the
source (the stamp pass) and iterates every frame, printing peak RSS (``resource.getrusage``) and frames per
second. The bags are deleted afterwards::

    python -m benchmarks.bag_memory                 # 0.2 GB and 2 GB MCAP bags
    python -m benchmarks.bag_memory --sizes 2 --storage sqlite3
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

KITTI_IMAGES = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti" / "sequences" / "00" / "image_0"
WIDTH, HEIGHT = 1241, 376


def frames() -> list[np.ndarray]:
    """The frames repeated in the bag: KITTI 00's first 100, or 10 noise images without the data."""
    files = sorted(KITTI_IMAGES.glob("*.png"))[:100]
    images = [cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files]
    images = [i for i in images if i is not None and i.shape == (HEIGHT, WIDTH)]
    if images:
        return images
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, (HEIGHT, WIDTH), np.uint8) for _ in range(10)]


def write_bag(path: Path, size_gb: float, storage: str) -> int:
    """A ROS 2 bag of ≈ size_gb GB of mono8 Image messages on /cam/image_raw + a CameraInfo; frame count."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.ros_logs import LogWriter  # the tests' writer (rosbags)
    from vslam_core.sources.base import CameraIntrinsics

    images = frames()
    count = int(size_gb * 1e9 / (WIDTH * HEIGHT))
    camera = CameraIntrinsics(718.856, 718.856, 607.1928, 185.2157, WIDTH, HEIGHT)
    with LogWriter(path, "mcap" if storage == "mcap" else "sqlite3") as log:
        log.write("/cam/camera_info", 1_700_000_000_000_000_000, log.camera_info(1_700_000_000_000_000_000,
                                                                                 "camera", camera))
        for i in range(count):
            stamp = 1_700_000_000_000_000_000 + i * 100_000_000
            log.write("/cam/image_raw", stamp, log.image(stamp, "camera", images[i % len(images)]))
    return count


def measure(path: str) -> dict[str, float]:
    """Open and iterate the source in this process: peak RSS (MB) before, after opening and after iterating."""
    from vslam_core.sources.ros.bag import RosbagSource

    def peak_mb() -> float:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB on Linux

    baseline = peak_mb()
    start = time.perf_counter()
    source = RosbagSource(path)
    opened = time.perf_counter()
    after_open = peak_mb()
    checksum = 0
    for frame in source:
        checksum += int(frame.image[0, 0])
    done = time.perf_counter()
    return {"frames": len(source), "open_s": opened - start, "iterate_s": done - opened,
            "fps": len(source) / (done - opened), "baseline_mb": baseline, "after_open_mb": after_open,
            "peak_mb": peak_mb()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="0.2,2", help="bag sizes in GB, comma separated")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--measure", help=argparse.SUPPRESS)  # internal: measure this bag in this process
    args = parser.parse_args()
    if args.measure:
        print(json.dumps(measure(args.measure)))
        return
    for size in (float(s) for s in args.sizes.split(",")):
        with tempfile.TemporaryDirectory(prefix="bag_memory_") as tmp:
            path = Path(tmp) / "bag"
            start = time.perf_counter()
            count = write_bag(path, size, args.storage)
            written = time.perf_counter() - start
            bag_bytes = sum(f.stat().st_size for f in path.iterdir())
            result = subprocess.run([sys.executable, "-m", "benchmarks.bag_memory", "--measure", str(path)],
                                    capture_output=True, text=True, check=True,
                                    cwd=Path(__file__).resolve().parents[1])
            r = json.loads(result.stdout.strip().splitlines()[-1])
            print(f"{args.storage} bag {bag_bytes / 1e9:.2f} GB, {count} frames (written in {written:.0f} s): "
                  f"open {r['open_s']:.1f} s, iterate {r['iterate_s']:.1f} s = {r['fps']:.0f} fps; peak RSS "
                  f"{r['peak_mb']:.0f} MB (after imports {r['baseline_mb']:.0f} MB, after opening "
                  f"{r['after_open_mb']:.0f} MB)", flush=True)


if __name__ == "__main__":
    main()
