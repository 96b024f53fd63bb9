"""`vslam run`'s summary, `vslam inspect` and `vslam eval` score the same trajectory: with the map, the refined poses
that `--trajectory-out` holds (not the tracking-time ones of `/world/camera`), and each says so."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam

from vslam.rrd import inspect_recording
from vslam.rrd.read import read_entity
from vslam_core.trajectory.io import read_kitti_poses
from vslam_core.trajectory.metrics import ate, paper_rms_error, position_errors

FRAMES = 40


@pytest.fixture(scope="module")
def map_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path, str]:
    """A map run of KITTI 00 0:40: (recording, trajectory file, ground truth of those frames, the summary)."""
    folder = tmp_path_factory.mktemp("scored")
    rrd, trajectory, gt = folder / "run.rrd", folder / "poses.txt", folder / "gt.txt"
    run = vslam("run", kitti_root, "--sequence", "00", "--frames", f"0:{FRAMES}", "--backend", "map",
                "-o", rrd, "--trajectory-out", trajectory, "--detail", "summary")
    assert run.returncode == 0, run.stderr
    gt.write_text("".join((kitti_root / "poses" / "00.txt").read_text().splitlines(keepends=True)[:FRAMES]))
    return rrd, trajectory, gt, run.stdout


def test_inspect_scores_the_refined_trajectory_file_and_says_so(map_run: tuple[Path, Path, Path, str]) -> None:
    rrd, trajectory, gt_path, summary = map_run
    report = inspect_recording(rrd)
    assert report["scored_trajectory"] == "refined"
    refined, gt = read_kitti_poses(trajectory), read_kitti_poses(gt_path)
    accuracy = report["accuracy"]
    errors = position_errors(gt, refined)
    assert accuracy["paper_rms_m"] == pytest.approx(paper_rms_error(gt, refined), abs=1e-4)
    assert accuracy["final_position_error_m"] == pytest.approx(errors[-1], abs=1e-4)
    assert accuracy["max_position_error_m"] == pytest.approx(errors.max(), abs=1e-4)
    assert accuracy["ate_m"] == pytest.approx(ate(gt, refined, "none"), abs=1e-4)  # as the summary's ATE line
    printed = re.search(r"^ATE +([\d.]+) m without alignment", summary, re.MULTILINE)
    assert printed is not None and float(printed.group(1)) == pytest.approx(accuracy["ate_m"], abs=6e-4)
    # the tracking-time poses (kept in /world/camera) differ: the test would see the wrong ones
    camera = read_entity(rrd, "/world/camera")
    tracked = np.array([t[0] if isinstance(t[0], list) else t for t in camera["Transform3D:translation"].to_list()],
                       np.float64).reshape(-1, 3)
    assert np.abs(tracked - refined[:, :3, 3]).max() > 1e-3
    # the recording's verdict table (`/report`, as the summary) agrees with the file too
    assert "scored      the map's refined poses" in summary
    paper_line = next(line for line in summary.splitlines() if line.startswith("paper RMS"))
    assert f"{paper_rms_error(gt, refined):.2f} m" in paper_line
    assert report["report_metrics"]["paper_rms"] == pytest.approx(paper_rms_error(gt, refined), abs=1e-3)
    verdict = read_entity(rrd, "/report", static=True)["TextDocument:text"].to_list()[-1][0]
    assert "Scored: the map's refined poses" in verdict


def test_eval_of_the_trajectory_file_equals_inspect(map_run: tuple[Path, Path, Path, str]) -> None:
    rrd, trajectory, gt_path, _ = map_run
    result = vslam("eval", "--trajectory", trajectory, "--gt", gt_path, "--json")
    assert result.returncode == 0, result.stderr
    row = json.loads(result.stdout)["sequences"][0]
    report = inspect_recording(rrd)
    assert row["paper_rms"] == pytest.approx(report["accuracy"]["paper_rms_m"], abs=1e-4)
    for key in ("t_err", "ate_se3", "ate_sim3"):
        mine, theirs = report["report_metrics"][key], row[key]
        assert (mine is None and theirs is None) or mine == pytest.approx(theirs, abs=2e-3), key
    text = vslam("inspect", rrd)
    assert text.returncode == 0 and "of the map's refined poses" in text.stdout
