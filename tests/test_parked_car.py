"""A parked car (every frame the same image) is a valid log (issue 24, item 6): its frames are `stationary`,
the pose is held, and `run` and `eval` both succeed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam

from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses

FRAMES = 12


@pytest.fixture(scope="module")
def parked(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """12 frames that are all KITTI 00 image 0 (links), and ground truth that does not move."""
    base = tmp_path_factory.mktemp("parked")
    folder = base / "frames"
    folder.mkdir()
    first = kitti_root / "sequences" / "00" / "image_0" / "000000.png"
    for i in range(FRAMES):
        (folder / f"{i:06d}.png").symlink_to(first)
    write_kitti_poses(base / "gt.txt", np.tile(np.eye(4), (FRAMES, 1, 1)))
    return {"folder": folder, "gt": base / "gt.txt", "calib": kitti_root / "sequences" / "00" / "calib.txt",
            "base": base}


@pytest.mark.kitti
@pytest.mark.parametrize("backend", ["vo", "map"])
def test_a_parked_car_runs_and_holds_its_pose(parked: dict[str, Path], backend: str) -> None:
    trajectory = parked["base"] / f"{backend}.txt"
    result = vslam("run", parked["folder"], "--calib", parked["calib"], "--backend", backend, "--detail", "off",
                   "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    assert f"frames      {FRAMES} ({FRAMES - 1} held the previous pose: stationary {FRAMES - 1})" in result.stdout
    np.testing.assert_allclose(read_kitti_poses(trajectory), np.tile(np.eye(4), (FRAMES, 1, 1)), atol=1e-9)


@pytest.mark.kitti
def test_eval_and_run_agree_on_a_parked_car(parked: dict[str, Path]) -> None:
    evaluated = vslam("eval", parked["folder"], "--calib", parked["calib"], "--gt", parked["gt"], "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    rrd = parked["base"] / "run.rrd"
    run = vslam("run", parked["folder"], "--calib", parked["calib"], "--gt", parked["gt"], "-o", rrd)
    assert run.returncode == 0, run.stderr
    assert re.search(r"^ATE +0\.000 m without alignment, — after Sim\(3\) \(the estimate does not move\) "
                     r"\(3-D RMSE over 12 frames\)$", run.stdout, re.MULTILINE), run.stdout
    inspected = vslam("inspect", rrd, "--json")
    assert inspected.returncode == 0 and "stationary" in inspected.stdout
