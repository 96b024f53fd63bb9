"""`vslam eval`: report folder, JSON, gates, and scoring of external trajectory files."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import polars as pl
import pytest
from cli_helpers import VO, vslam

from vslam.rrd.read import read_entity
from vslam_core.sources.base import rebase_poses
from vslam_core.trajectory.io import read_kitti_poses, write_tum_poses
from vslam_core.trajectory.metrics import evaluate

ROOT = Path(__file__).resolve().parents[1]
JSON_KEYS = {"t_err", "r_err", "ate_se3", "ate_sim3", "rpe_trans", "rpe_rot", "paper_rms", "frames"}


@pytest.fixture(scope="module")
def report(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    folder = tmp_path_factory.mktemp("eval") / "report"
    result = vslam("eval", *VO, kitti_root, "--sequences", "00,05", "--frames", "0:150", "--report", folder, "--json",
                   "--detail", "summary")
    assert result.returncode == 0, result.stderr
    return folder, json.loads(result.stdout)


@pytest.mark.kitti
def test_report_folder_holds_every_artefact(report: tuple[Path, dict], kitti_root: Path) -> None:
    folder, data = report
    table = pl.read_csv(folder / "metrics.csv")
    assert table["sequence"].to_list() == ["kitti-00", "kitti-05", "mean"]
    parquet = pl.read_parquet(folder / "metrics.parquet")
    assert parquet.columns == table.columns and parquet["sequence"].to_list() == table["sequence"].to_list()
    for key in ("t_err", "r_err", "ate_se3", "ate_sim3", "rpe_trans", "rpe_rot", "paper_rms", "frames"):
        assert np.allclose(parquet[key].to_numpy(), table[key].to_numpy(), equal_nan=True), key
    markdown = (folder / "report.md").read_text()
    assert "| kitti-00 | 150 |" in markdown and "| mean |" in markdown and "kitti-05_top.png" in markdown
    for sequence in ("00", "05"):
        name = f"kitti-{sequence}"
        poses = read_kitti_poses(folder / f"{name}.txt")
        assert len(poses) == 150
        gt = rebase_poses(read_kitti_poses(kitti_root / "poses" / f"{sequence}.txt", max_rows=150))
        expected = evaluate(gt, poses)
        row = table.filter(pl.col("sequence") == name).row(0, named=True)
        for key in ("t_err", "r_err", "ate_sim3", "paper_rms"):
            assert row[key] == pytest.approx(getattr(expected, key), rel=1e-6), key
        plot = cv2.imread(str(folder / f"{name}_top.png"))
        assert plot is not None and plot.shape[0] > 500 and plot.std() > 5
        verdict = read_entity(folder / f"{name}.rrd", "/report", static=True)
        text = verdict["TextDocument:text"][0][0]
        assert "t_err" in text and f"{row['t_err']:.2f}" in text  # the recording carries its verdict
        assert not read_entity(folder / f"{name}.rrd", "/metrics/error/position_m").is_empty()
    means = table.filter(pl.col("sequence") == "mean").row(0, named=True)
    assert means["t_err"] == pytest.approx(table["t_err"][:2].mean())


@pytest.mark.kitti
def test_json_has_the_documented_keys(report: tuple[Path, dict]) -> None:
    _, data = report
    assert [s["sequence"] for s in data["sequences"]] == ["kitti-00", "kitti-05"]
    for row in [*data["sequences"], data["mean"]]:
        assert set(row) >= JSON_KEYS | {"scale", "backend"}
    assert data["gates"] == {"passed": True, "failures": []}
    assert data["scale"] == "gt" and data["backend"] == "vo"


@pytest.mark.kitti
def test_gates_fail_naming_sequence_and_metric(kitti_root: Path, tmp_path: Path, report: tuple[Path, dict]) -> None:
    folder, data = report
    t_err_05 = data["sequences"][1]["t_err"]
    estimate = folder / "kitti-05.txt"
    gt = kitti_root / "poses" / "05.txt"
    result = vslam("eval", "--trajectory", estimate, "--gt", gt, "--match", "rows", "--frames", "0:150",
                   "--max-t-err", t_err_05 / 2,
                   "--max-ate", 100)
    assert result.returncode == 1
    assert "gate failed: kitti-05: t_err" in result.stderr and "ate_sim3" not in result.stderr
    passing = vslam("eval", "--trajectory", estimate, "--gt", gt, "--match", "rows", "--frames", "0:150",
                    "--max-t-err", t_err_05 * 2,
                    "--max-r-err", 50)
    assert passing.returncode == 0, passing.stderr


@pytest.mark.kitti
def test_external_trajectories_in_kitti_and_tum_score_the_same(kitti_root: Path, report: tuple[Path, dict],
                                                               tmp_path: Path) -> None:
    folder, data = report
    kitti = vslam("eval", "--trajectory", folder / "kitti-00.txt", "--gt", kitti_root / "poses" / "00.txt", "--json",
                  "--match", "rows", "--frames", "0:150")
    assert kitti.returncode == 0, kitti.stderr
    external = json.loads(kitti.stdout)["sequences"][0]
    for key in JSON_KEYS - {"frames"}:
        assert external[key] == pytest.approx(data["sequences"][0][key], rel=1e-6, abs=1e-9), key
    # TUM files matched by timestamps: the estimate covers every second frame only
    times = np.loadtxt(kitti_root / "sequences" / "00" / "times.txt")[:150]
    poses = read_kitti_poses(folder / "kitti-00.txt")
    gt = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=150)
    write_tum_poses(tmp_path / "est.tum", times[::2], poses[::2])
    write_tum_poses(tmp_path / "gt.tum", times, gt)
    tum = vslam("eval", "--trajectory", tmp_path / "est.tum", "--gt", tmp_path / "gt.tum", "--json")
    assert tum.returncode == 0, tum.stderr
    row = json.loads(tum.stdout)["sequences"][0]
    assert row["frames"] == 75
    assert row["ate_sim3"] == pytest.approx(evaluate(gt[::2], poses[::2]).ate_sim3, rel=1e-5)


def test_malformed_trajectory_names_file_and_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 oops 0 1 0 0 0 0 1 0\n")
    result = vslam("eval", "--trajectory", bad, "--gt", bad)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert f"{bad}:2" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_unit_scale_is_scored_after_sim3_alignment(tmp_path: Path) -> None:
    result = vslam("eval", "synthetic", "--frames", "0:40", "--scale", "none", "--json")
    assert result.returncode == 0, result.stderr
    row = json.loads(result.stdout)["sequences"][0]
    assert row["alignment"] == "sim3" and row["scale"] == "none"
    assert row["ate_sim3"] < 0.5  # unit steps, scaled onto the ground truth by the alignment


def test_existing_report_needs_force(tmp_path: Path) -> None:
    (tmp_path / "report.md").write_text("an earlier report")
    result = vslam("eval", "synthetic", "--frames", "0:5", "--report", tmp_path)
    assert result.returncode == 2 and "--force" in result.stderr
    assert (tmp_path / "report.md").read_text() == "an earlier report"


def test_report_folder_another_eval_is_writing_is_refused(tmp_path: Path) -> None:
    """Two evals into one --report folder: the second is refused while the first holds it (even with --force)."""
    import fcntl
    import os

    from vslam.common.outputs import FOLDER_LOCK

    fd = os.open(tmp_path / FOLDER_LOCK, os.O_WRONLY | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running `vslam eval --report` holds it
        result = vslam("eval", "synthetic", "--frames", "0:5", "--report", tmp_path, "--force")
    finally:
        os.close(fd)
    assert result.returncode == 2, result.stderr
    assert f"{tmp_path}: another command is writing this report folder" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "report.md").exists()


def test_json_ready_replaces_nan_at_any_depth() -> None:
    """`inspect --json` and `eval --json` print JSON, which has no NaN (e.g. a metric on a too-short path)."""
    from vslam.common.metric_rows import json_ready

    data = {"a": float("nan"), "b": [1.0, float("inf"), {"c": float("nan"), "d": "x"}], "e": 2}
    assert json.loads(json.dumps(json_ready(data), allow_nan=False)) == {"a": None, "b": [1.0, None, {"c": None,
                                                                                                    "d": "x"}], "e": 2}
