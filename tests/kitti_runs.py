"""Real KITTI inputs shared by several test files: the frames of a sequence in any order as an image folder,
and the map backend's run over KITTI 00 (tests/conftest.py shares one such run between files)."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource

#: A map-backend run: its results, (N, 4, 4) poses and (N, 4, 4) ground truth.
MapRun = tuple[list[FrameResult], np.ndarray, np.ndarray]


def link_images(kitti_root: Path, folder: Path, order: Iterable[int], sequence: str = "05") -> Path:
    """An image folder (made here) of the sequence's frames in `order`, numbered from 000000: symbolic links,
    nothing copied, and nothing else (no calibration, times or ground truth)."""
    folder.mkdir(parents=True, exist_ok=True)
    images = kitti_root / "sequences" / sequence / "image_0"
    for k, i in enumerate(order):
        os.symlink(images / f"{i:06d}.png", folder / f"{k:06d}.png")
    return folder


def kitti_folder(kitti_root: Path, folder: Path, order: list[int], sequence: str = "05") -> Path:
    """An image folder (made here) of the sequence's frames in `order` (symbolic links, nothing copied), with
    its calib.txt and the ground-truth rows in the same order as gt.txt (the folder source re-bases them on the
    first frame)."""
    link_images(kitti_root, folder, order, sequence)
    images = kitti_root / "sequences" / sequence
    (folder / "calib.txt").write_text((images / "calib.txt").read_text())
    np.savetxt(folder / "gt.txt", np.loadtxt(kitti_root / "poses" / f"{sequence}.txt").reshape(-1, 12)[order])
    return folder


def map_run_00(kitti_root: Path, frames: FrameRange, threads: int = 1) -> MapRun:
    """The map backend over these frames of KITTI 00, scale from ground truth."""
    source = KittiSource(kitti_root, sequence="00", frames=frames)
    results: list[FrameResult] = []
    run = run_odometry(source, EngineConfig(backend="map", threads=threads),
                       (lambda _frame, result: results.append(result),))
    assert source.ground_truth is not None
    return results, run.pose_array(), source.ground_truth
