"""Loop closing's acceptance figures (map backend, scale from ground truth), as a printed table:

    python -m benchmarks.loops ../shared/data/kitti [--skip-synthetic] [--seeds 0,1,2,3]

1. The synthetic closed route (`synthetic --route loop`, 660 frames around a 600 m block): where the loop is
   found, and the final position error with loop closing against the same run without it (target <= 10 %),
   beside the run's own error where its first pass went by the final frame's place (what the loop closes onto).
2. A real revisit: KITTI 05 frames 0..149 driven forward, then 149..0 (the camera backs up along the same
   street): loops found (frame pairs, which must show the same KITTI frame) and ATE (no alignment) of the
   map backend with loop closing against `vo`'s (target: no worse).
3. False loops: loops accepted on the open synthetic street (300 frames) and KITTI 00 and 05 0:300 (target 0).

    python -m benchmarks.loops ../shared/data/kitti --scale none [--skip-synthetic]

prints instead the Sim(3) path (no scale source): ATE after Sim(3) alignment with loop closing on and off, and
`vo`'s, on the synthetic loop and on real revisits driven forward then backward over part of the way.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange, FrameSource
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.synthetic.street import SyntheticStreet
from vslam_core.trajectory.metrics import ate


def _run(source: FrameSource, backend: str, loop: bool, scale: str = "gt",
         seed: int = 0) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """(N, 4, 4) poses after the run and the (frame, matched frame) source indices of each loop closed (those
    closed when the run ended last). `seed`: RANSAC's."""
    config = EngineConfig(backend=backend, scale=scale)  # type: ignore[arg-type]
    config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=loop),
                                 pose=dataclasses.replace(config.pose, seed=seed))
    indices = source.indices
    closed: list[tuple[int, int]] = []

    def sink(_frame: Frame, result: FrameResult) -> None:
        if result.mapping is not None and result.mapping.loop is not None and result.mapping.loop.closed:
            found = result.mapping.loop.closed
            closed.append((indices[found.query_position], indices[found.candidate_position]))

    run = run_odometry(source, config, (sink,))
    closed += [(indices[step.closed.query_position], indices[step.closed.candidate_position])
               for step in run.loops_at_end if step.closed is not None]
    return run.pose_array(), closed


def _errors(poses: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.asarray(np.linalg.norm(poses[:, :3, 3] - truth[: len(poses), :3, 3], axis=1))


def _revisit_folder(root: Path, folder: Path, count: int, sequence: str = "05", first: int = 0,
                    back_to: int | None = None) -> ImageFolderSource:
    """KITTI frames first..first+count-1 then back down to `back_to` (default `first`) as an image folder
    (symbolic links) with ground truth."""
    last = first + count - 1
    order = list(range(first, last + 1)) + list(range(last, (first if back_to is None else back_to) - 1, -1))
    images = root.resolve() / "sequences" / sequence  # the links must work from the temporary folder
    for k, i in enumerate(order):
        os.symlink(images / "image_0" / f"{i:06d}.png", folder / f"{k:06d}.png")
    (folder / "calib.txt").write_text((images / "calib.txt").read_text())
    np.savetxt(folder / "gt.txt", np.loadtxt(root / "poses" / f"{sequence}.txt").reshape(-1, 12)[order])
    return ImageFolderSource(folder, ground_truth=folder / "gt.txt")


def _similarity_rows(root: Path, skip_synthetic: bool) -> Iterator[str]:
    """--scale none: ATE after Sim(3) alignment, loop closing on / off and `vo`, per route (as each is done)."""
    routes: list[tuple[str, tuple[int, str, int, int]]] = [
        ("KITTI 05 0..149..0", (150, "05", 0, 0)), ("KITTI 05 0..149..60", (150, "05", 0, 60)),
        ("KITTI 05 100..249..100", (150, "05", 100, 100)), ("KITTI 00 150..299..150", (150, "00", 150, 150))]
    for name, (count, sequence, first, back_to) in routes:
        with tempfile.TemporaryDirectory() as folder:
            yield _similarity_row(name, _revisit_folder(root, Path(folder), count, sequence, first, back_to))
    if not skip_synthetic:
        yield _similarity_row("synthetic loop, 660 frames", SyntheticStreet(route="loop"))


def _similarity_row(name: str, source: FrameSource) -> str:
    truth = source.ground_truth
    assert truth is not None
    on, closed = _run(source, "map", True, "none")
    off, _ = _run(source, "map", False, "none")
    vo, _ = _run(source, "vo", False, "none")
    on_m, off_m, vo_m = (ate(truth[: len(p)], p, "sim3") for p in (on, off, vo))
    return f"| {name} | {len(closed)} loops {closed} | {on_m:.2f} | {off_m:.2f} | {vo_m:.2f} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--skip-synthetic", action="store_true", help="leave out the synthetic runs (slow)")
    parser.add_argument("--seeds", default="0", help="RANSAC seeds of the synthetic loop's runs (gt), e.g. 0,1,2,3")
    parser.add_argument("--scale", choices=("gt", "none"), default="gt",
                        help="none: the Sim(3) path's table instead (ATE after Sim(3) alignment)")
    args = parser.parse_args()
    if args.scale == "none":
        print("| route (--scale none) | loops closed (frame, matched frame) | ATE Sim(3) m, loop on | off | vo |")
        print("|---|---|---|---|---|")
        for row in _similarity_rows(args.root, args.skip_synthetic):
            print(row, flush=True)
        return
    print("| data | run | loops | accuracy |\n|---|---|---|---|", flush=True)
    if not args.skip_synthetic:
        loop = SyntheticStreet(route="loop")
        truth = loop.ground_truth
        for seed in (int(s) for s in args.seeds.split(",")):
            on, closed = _run(loop, "map", True, seed=seed)
            off, _ = _run(loop, "map", False, seed=seed)
            errors = _errors(on, truth)
            final_on, final_off = errors[-1], _errors(off, truth)[-1]
            # the floor: the same run's error where it first passed the final frame's place (the map the loop
            # closes onto), on the first half of the route
            half = len(truth) // 2
            first = int(np.argmin(np.linalg.norm(truth[:half, :3, 3] - truth[-1, :3, 3], axis=1)))
            print(f"| synthetic loop, 660 frames, seed {seed} | map + loop closing | loops {closed} | final error "
                  f"{final_on:.3f} m = {100 * final_on / final_off:.1f} % of {final_off:.3f} m without; "
                  f"{errors[first]:.3f} m at frame {first}, the first pass there |", flush=True)
    with tempfile.TemporaryDirectory() as folder:
        revisit = _revisit_folder(args.root, Path(folder), 150)
        revisit_truth = revisit.ground_truth
        assert revisit_truth is not None
        mapped, closed = _run(revisit, "map", True)
        vo, _ = _run(revisit, "vo", False)
        ate_map, ate_vo = (float(np.sqrt(np.mean(_errors(p, revisit_truth) ** 2))) for p in (mapped, vo))
        order = list(range(150)) + list(range(149, -1, -1))
        same = [abs(order[a] - order[b]) for a, b in closed]
        print(f"| KITTI 05 0:150 then 149:0 | map + loop closing vs vo | {len(closed)} loops, KITTI frames "
              f"apart: {same} | ATE {ate_map:.3f} m vs vo {ate_vo:.3f} m |", flush=True)
    sources: list[tuple[str, FrameSource]] = [
        (f"KITTI {s} 0:300", KittiSource(args.root, sequence=s, frames=FrameRange(0, 300))) for s in ("00", "05")]
    if not args.skip_synthetic:
        sources.append(("synthetic street 0:300", SyntheticStreet()))
    for name, source in sources:
        _, closed = _run(source, "map", True)
        print(f"| {name} (open route) | map + loop closing | loops accepted: {len(closed)} {closed} | |", flush=True)


if __name__ == "__main__":
    main()
