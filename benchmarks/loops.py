"""Loop closing's acceptance figures (map backend, scale from ground truth), as a printed table:

    python -m benchmarks.loops ../shared/data/kitti [--skip-synthetic]

1. The synthetic closed route (`synthetic --route loop`, 660 frames around a 600 m block): where the loop is
   found, and the final position error with loop closing against the same run without it (target <= 10 %).
2. A real revisit: KITTI 05 frames 0..149 driven forward, then 149..0 (the camera backs up along the same
   street): loops found (frame pairs, which must show the same KITTI frame) and ATE (no alignment) of the
   map backend with loop closing against `vo`'s (target: no worse).
3. False loops: loops accepted on the open synthetic street (300 frames) and KITTI 00 and 05 0:300 (target 0).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
from pathlib import Path

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange, FrameSource
from vslam_core.sources.folder import ImageFolderSource
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.synthetic.street import SyntheticStreet


def _run(source: FrameSource, backend: str, loop: bool) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """(N, 4, 4) poses after the run and the (frame, matched frame) source indices of each loop closed."""
    config = EngineConfig(backend=backend, scale="gt")  # type: ignore[arg-type]
    config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=loop))
    indices = source.indices
    closed: list[tuple[int, int]] = []

    def sink(_frame: Frame, result: FrameResult) -> None:
        if result.mapping is not None and result.mapping.loop is not None and result.mapping.loop.closed:
            found = result.mapping.loop.closed
            closed.append((indices[found.query_position], indices[found.candidate_position]))

    return run_odometry(source, config, (sink,)).pose_array(), closed


def _errors(poses: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.asarray(np.linalg.norm(poses[:, :3, 3] - truth[: len(poses), :3, 3], axis=1))


def _revisit_folder(root: Path, folder: Path, count: int) -> ImageFolderSource:
    """KITTI 05 frames 0..count-1 then count-1..0 as an image folder (symbolic links) with ground truth."""
    order = list(range(count)) + list(range(count - 1, -1, -1))
    sequence = root / "sequences" / "05"
    for k, i in enumerate(order):
        os.symlink(sequence / "image_0" / f"{i:06d}.png", folder / f"{k:06d}.png")
    (folder / "calib.txt").write_text((sequence / "calib.txt").read_text())
    np.savetxt(folder / "gt.txt", np.loadtxt(root / "poses" / "05.txt").reshape(-1, 12)[order])
    return ImageFolderSource(folder, ground_truth=folder / "gt.txt")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path)
    parser.add_argument("--skip-synthetic", action="store_true", help="leave out the synthetic runs (slow)")
    args = parser.parse_args()
    rows: list[str] = []
    if not args.skip_synthetic:
        loop = SyntheticStreet(route="loop")
        truth = loop.ground_truth
        on, closed = _run(loop, "map", True)
        off, _ = _run(loop, "map", False)
        final_on, final_off = _errors(on, truth)[-1], _errors(off, truth)[-1]
        rows.append(f"| synthetic loop, 660 frames | map + loop closing | loops {closed} | final error "
                    f"{final_on:.3f} m = {100 * final_on / final_off:.1f} % of {final_off:.3f} m without |")
    with tempfile.TemporaryDirectory() as folder:
        revisit = _revisit_folder(args.root, Path(folder), 150)
        truth = revisit.ground_truth
        assert truth is not None
        mapped, closed = _run(revisit, "map", True)
        vo, _ = _run(revisit, "vo", False)
        ate_map, ate_vo = (float(np.sqrt(np.mean(_errors(p, truth) ** 2))) for p in (mapped, vo))
        order = list(range(150)) + list(range(149, -1, -1))
        same = [abs(order[a] - order[b]) for a, b in closed]
        rows.append(f"| KITTI 05 0:150 then 149:0 | map + loop closing vs vo | {len(closed)} loops, KITTI frames "
                    f"apart: {same} | ATE {ate_map:.3f} m vs vo {ate_vo:.3f} m |")
    sources: list[tuple[str, FrameSource]] = [
        (f"KITTI {s} 0:300", KittiSource(args.root, sequence=s, frames=FrameRange(0, 300))) for s in ("00", "05")]
    if not args.skip_synthetic:
        sources.append(("synthetic street 0:300", SyntheticStreet()))
    for name, source in sources:
        _, closed = _run(source, "map", True)
        rows.append(f"| {name} (open route) | map + loop closing | loops accepted: {len(closed)} {closed} | |")
    print("| data | run | loops | accuracy |\n|---|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
