"""Injected faults on real KITTI frames: is each flagged where it is, and does tracking recover?

    python -m benchmarks.faults ../shared/data/kitti --sequence 00 --frames 0:300

For each fault (alone, at the given frames) and the clean run: the frames flagged and their reasons, the
per-frame accuracy (RPE over 1 frame) in the 60 frames after the fault next to the clean run's on the
same frames, and KITTI t_err / r_err of the whole run.
"""

from __future__ import annotations

import argparse
from multiprocessing import Pool

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, HealthStatus
from vslam_core.sources.base import FrameRange
from vslam_core.sources.open import open_source
from vslam_core.trajectory.metrics import kitti_errors, rpe

FAULTS = ["dark@120", "overexposed@90", "blur@160:166", "frozen@60:62", "drop@150:152", "brightness@250:255",
          "noise@30:35", "blur@200:210"]


def _run(args: tuple[str, str, str, str | None]) -> tuple[str | None, list[FrameResult], np.ndarray]:
    root, sequence, frames, inject = args
    source = open_source(root, sequence=sequence, frames=FrameRange.parse(frames), inject=inject)
    results: list[FrameResult] = []
    run_odometry(source, EngineConfig(), sinks=(lambda _f, r: results.append(r),))
    assert source.ground_truth is not None
    return inject, results, source.ground_truth


def _after(results: list[FrameResult], gt: np.ndarray, first: int, count: int = 60) -> tuple[float, float]:
    positions = [i for i, r in enumerate(results) if first <= r.index < first + count]
    return rpe(gt[positions], np.array([results[i].T_world_cam for i in positions]), 1)


def _flagged(results: list[FrameResult]) -> str:
    spans: list[list] = []
    for r in results:
        if r.health.status == HealthStatus.OK:
            continue
        reasons = ",".join(r.health.reasons)
        if spans and spans[-1][1] == r.index - 1 and spans[-1][2] == reasons and spans[-1][3] == r.health.status:
            spans[-1][1] = r.index
        else:
            spans.append([r.index, r.index, reasons, r.health.status])
    return "; ".join(f"{a}" + (f"–{b}" if b != a else "") + f" {s} {why}" for a, b, why, s in spans) or "none"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--frames", default="0:300")
    args = parser.parse_args()
    jobs = [(args.root, args.sequence, args.frames, f) for f in [None, *FAULTS]]
    with Pool(2) as pool:
        runs = pool.map(_run, jobs, chunksize=1)
    _, clean, clean_gt = runs[0]
    print(f"KITTI {args.sequence}, frames {args.frames}")
    print("| fault | flagged frames (status reasons) | RPE after fault m / ° | clean run there m / ° "
          "| t_err % | r_err °/100 m |")
    print("|---|---|---|---|---|---|")
    for inject, results, gt in runs:
        t_err, r_err = kitti_errors(gt, np.array([r.T_world_cam for r in results]))
        if inject is None:
            print(f"| none | {_flagged(results)} | | | {t_err:.2f} | {r_err:.2f} |")
            continue
        end = int(inject.split("@")[1].split(":")[-1])
        trans, rot = _after(results, gt, end + 1)
        clean_trans, clean_rot = _after(clean, clean_gt, end + 1)
        print(f"| {inject} | {_flagged(results)} | {trans:.3f} / {rot:.3f} | {clean_trans:.3f} / {clean_rot:.3f} "
              f"| {t_err:.2f} | {r_err:.2f} |")


if __name__ == "__main__":
    main()
