"""`--scale none` is printed, recorded and plotted as it is scored: after Sim(3) alignment, and says so
(issue 12, item 9)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import VO, vslam

from vslam.evaluation import evaluate as evaluation
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig
from vslam_core.sources.base import rebase_poses
from vslam_core.trajectory.io import read_kitti_poses
from vslam_core.trajectory.metrics import ate, kitti_errors, paper_rms_error, sim3_aligned

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def unit_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str, np.ndarray]:
    out = tmp_path_factory.mktemp("none")
    rrd, trajectory = out / "none.rrd", out / "none.txt"
    result = vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "0:150", "--scale", "none", "--detail",
                   "summary", "-o", rrd, "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    gt = rebase_poses(read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=150))
    return rrd, trajectory, result.stdout, gt


@pytest.mark.kitti
def test_run_summary_prints_the_aligned_errors_and_says_so(unit_run: tuple[Path, Path, str, np.ndarray]) -> None:
    _, trajectory, stdout, gt = unit_run
    poses = read_kitti_poses(trajectory)
    aligned_t, _ = kitti_errors(gt, sim3_aligned(gt, poses))
    raw_t, _ = kitti_errors(gt, poses)
    printed = float(re.search(r"t_err ([\d.]+) %", stdout).group(1))  # type: ignore[union-attr]
    assert printed == pytest.approx(aligned_t, abs=0.006) and abs(raw_t - aligned_t) > 1.0
    assert "after Sim(3) alignment: --scale none has no metric scale" in stdout
    rms = float(re.search(r"paper RMS\s+([\d.]+) m \(x–z, after Sim\(3\) alignment\)", stdout).group(1))  # type: ignore[union-attr]
    assert rms == pytest.approx(paper_rms_error(gt, sim3_aligned(gt, poses)), abs=0.006)
    ate_line = re.search(r"^ATE +([\d.]+) m after Sim\(3\) \(3-D RMSE over 150 frames\)$", stdout, re.MULTILINE)
    assert ate_line is not None, stdout  # and no unaligned figure: without a scale it would be meaningless
    assert float(ate_line.group(1)) == pytest.approx(ate(gt, poses, "sim3"), abs=0.0006)


@pytest.mark.kitti
def test_recording_holds_the_aligned_error_and_estimate(unit_run: tuple[Path, Path, str, np.ndarray]) -> None:
    rrd, trajectory, _, gt = unit_run
    aligned = sim3_aligned(gt, read_kitti_poses(trajectory))
    errors = read_entity(rrd, "/metrics/error/position_m")
    values = np.array([v[0] for v in errors["Scalars:scalars"].to_list()])
    assert errors["frame"].to_list() == list(range(150))
    assert np.allclose(values, np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1), atol=1e-6)
    legend = read_entity(rrd, "/metrics/error/position_m", static=True)["SeriesLines:names"].to_list()
    assert legend[-1] == ["position error after Sim(3) alignment (m)"]
    report = json.loads(vslam("inspect", rrd, "--json").stdout)
    assert report["accuracy_alignment"] == "sim3"
    assert report["accuracy"]["paper_rms_m"] == pytest.approx(paper_rms_error(gt, aligned), rel=1e-5)
    assert "after Sim(3) alignment" in vslam("inspect", rrd).stdout


def test_eval_plots_the_aligned_estimate(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gt = np.tile(np.eye(4), (30, 1, 1))
    gt[:, 2, 3] = np.arange(30.0)
    gt[:, 0, 3] = 0.01 * np.arange(30.0) ** 2
    unit = gt.copy()
    unit[:, :3, 3] /= 7.0  # the right shape, the wrong scale
    plotted = {}
    monkeypatch.setattr(evaluation, "write_top_view", lambda path, g, e, title, subtitle: plotted.update(
        estimate=e, title=title))
    row, _ = evaluation._score("x", gt, unit, EngineConfig(scale="none"), tmp_path)
    assert np.allclose(plotted["estimate"], sim3_aligned(gt, unit)) and "Sim(3)-aligned" in plotted["title"]
    assert row["alignment"] == "sim3" and row["ate_sim3"] < 1e-6


def test_eval_text_and_report_say_the_numbers_are_aligned(tmp_path: Path) -> None:
    result = vslam("eval", "synthetic", "--frames", "0:20", "--scale", "none", "--report", tmp_path, "--detail",
                   "off")
    assert result.returncode == 0, result.stderr
    assert "every number is of the Sim(3)-aligned estimate" in result.stdout
    report = (tmp_path / "report.md").read_text()
    assert "Sim(3)-aligned onto the ground truth before scoring and plotting" in report
    assert "no alignment" not in report
