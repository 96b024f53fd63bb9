"""Where the engine's time goes: cProfile of one run, top entries by own time (issue 6's profile).

    python -m benchmarks.profile ../shared/data/kitti --sequence 00 --frames 0:300 --threads 1 --top 15
"""

from __future__ import annotations

import argparse
import cProfile
import pstats

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--threads", type=int, default=1, help="1: decoding is profiled too (same thread)")
    parser.add_argument("--top", type=int, default=15)
    args = parser.parse_args()
    source = KittiSource(args.root, sequence=args.sequence, frames=FrameRange.parse(args.frames))
    profile = cProfile.Profile()
    profile.enable()
    run = run_odometry(source, EngineConfig(threads=args.threads))
    profile.disable()
    print(f"KITTI {args.sequence} frames {args.frames}, {args.threads} thread(s): {run.seconds:.2f} s, "
          f"{run.frames / run.seconds:.1f} fps under the profiler")
    pstats.Stats(profile).sort_stats("tottime").print_stats(args.top)


if __name__ == "__main__":
    main()
