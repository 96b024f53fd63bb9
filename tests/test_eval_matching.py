"""`vslam eval --trajectory`: rows matched by timestamp (`--gt-times`), row-by-row only when it is safe or
asked (`--match rows`), and the output says which (issue 12, item 8)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from cli_helpers import vslam, vslam_here

from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses, write_tum_poses

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def dropped(kitti_root: Path, tmp_path: Path) -> tuple[Path, Path, Path]:
    """A TUM 'estimate' that is the ground truth itself with frames 100..109 dropped, the KITTI poses file
    (4541 rows) and its times.txt (300 lines)."""
    times_file = kitti_root / "sequences" / "00" / "times.txt"
    times = np.loadtxt(times_file)
    gt = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=len(times))
    keep = np.r_[0:100, 110:len(times)]
    estimate = tmp_path / "dropped.tum"
    write_tum_poses(estimate, times[keep], gt[keep])
    return estimate, kitti_root / "poses" / "00.txt", times_file


@pytest.mark.kitti
def test_dropped_frames_are_matched_by_timestamp_with_gt_times(dropped: tuple[Path, Path, Path],
                                                               tmp_path: Path) -> None:
    estimate, gt, times = dropped
    report = tmp_path / "report"
    result = vslam("eval", "--trajectory", estimate, "--gt", gt, "--gt-times", times, "--report", report)
    assert result.returncode == 0, result.stderr
    assert "matched by timestamp: 290 of 290 rows, tolerance 10 ms" in result.stdout
    row = pl.read_csv(report / "metrics.csv").row(0, named=True)
    assert row["frames"] == 290 and row["t_err"] < 0.01  # the estimate is the ground truth: no error at all
    # times from 0 on both sides: said to be taken on the ground truth's clock (a window's own would be paired
    # with rows 0.. too: issue 54)
    assert row["matching"] == ("matched by timestamp: 290 of 290 rows, tolerance 10 ms; ground-truth rows 0..299, "
                               "290 rows: its times are taken on the ground truth's clock; if they count from a "
                               "later first frame, give --frames A:B")
    assert "matched by timestamp: 290 of 290 rows" in (report / "report.md").read_text()
    as_json = vslam("eval", "--trajectory", estimate, "--gt", gt, "--gt-times", times, "--json",
                    "--time-tolerance", 5)
    data = json.loads(as_json.stdout)
    assert data["matching"]["method"] == "timestamp" and data["matching"]["tolerance_ms"] == 5
    assert data["sequences"][0]["matching"].startswith("matched by timestamp: 290 of 290 rows, tolerance 5 ms; ")


@pytest.mark.kitti
def test_different_lengths_without_times_are_refused_unless_rows_asked(dropped: tuple[Path, Path, Path]) -> None:
    estimate, gt, _ = dropped
    refused = vslam_here("eval", "--trajectory", estimate, "--gt", gt)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1
    assert "290 poses" in refused.stderr and "--gt-times" in refused.stderr and "--frames A:B" in refused.stderr
    # --match rows alone no longer pairs from row 0 whatever the counts: the frames must be stated
    unstated = vslam_here("eval", "--trajectory", estimate, "--gt", gt, "--match", "rows")
    assert unstated.returncode == 2 and len(unstated.stderr.strip().splitlines()) == 1
    assert "with --match rows" in unstated.stderr and "--frames A:B" in unstated.stderr
    rows = vslam("eval", "--trajectory", estimate, "--gt", gt, "--match", "rows", "--frames", "0:290", "--json")
    assert rows.returncode == 0, rows.stderr
    data = json.loads(rows.stdout)
    assert data["matching"]["method"] == "frame" and data["sequences"][0]["t_err"] > 1.0  # the gap misaligns them


def test_same_length_kitti_files_match_row_by_row_and_say_so(tmp_path: Path) -> None:
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, 2, 3] = np.arange(20.0)
    write_kitti_poses(tmp_path / "a.txt", poses)
    result = vslam("eval", "--trajectory", tmp_path / "a.txt", "--gt", tmp_path / "a.txt")
    assert result.returncode == 0, result.stderr
    assert "matched row by row: 20 rows" in result.stdout
    timestamps = vslam_here("eval", "--trajectory", tmp_path / "a.txt", "--gt", tmp_path / "a.txt", "--match",
                       "timestamps")
    assert timestamps.returncode == 2 and "has no timestamps" in timestamps.stderr


def test_gt_times_only_for_trajectory_files() -> None:
    result = vslam_here("eval", "synthetic", "--frames", "0:5", "--gt-times", "times.txt")
    assert result.returncode == 2 and "--trajectory files only" in result.stderr
