"""examples/orb_vo.py, another pipeline logging through `vslam.log`, run on KITTI 05 frames 0:40: its recording
conforms to the schema, `inspect` reads its per-frame health, tracks and drift, and `compare` puts it beside a
`vslam run` of the same frames."""

from __future__ import annotations

import contextlib
import io
import json
import runpy
import sys
from pathlib import Path

import pytest
from cli_helpers import ROOT, vslam

from vslam.rrd import read_entity

FRAMES = "0:40"


@pytest.fixture(scope="module")
def orb_rrd(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The example script run as `__main__` in this process (runpy, its own argv; a new process only added ~2 s of
    imports), its printed line checked."""
    path = tmp_path_factory.mktemp("orb") / "orb.rrd"
    script = ROOT / "examples" / "orb_vo.py"
    argv = [str(script), str(kitti_root), "--sequence", "05", "--frames", FRAMES, "-o", str(path),
            "--trajectory-out", str(path.with_suffix(".txt"))]
    stdout = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(stdout):
        mp.setattr(sys, "argv", argv)
        runpy.run_path(str(script), run_name="__main__")  # a failure raises here, with its traceback
    assert stdout.getvalue().strip() == f"{path}: 40 frames of kitti-05 {FRAMES} (orb-vo)"
    return path


@pytest.mark.kitti
def test_its_recording_conforms_and_inspect_has_health_tracks_and_drift(orb_rrd: Path) -> None:
    check = vslam("check", orb_rrd)
    assert check.returncode == 0, check.stdout
    report = json.loads(vslam("inspect", orb_rrd, "--json").stdout)
    assert report["properties"]["pipeline"] == "orb-vo" and report["frames"]["count"] == 40
    health = read_entity(orb_rrd, "/health")
    assert health["frame"].to_list() == list(range(40))  # a verdict on every frame
    assert all(item["reasons"] for item in report["flagged"])  # every flagged frame says why
    assert report["series"]["tracks_alive"]["min"] > 300  # ORB matches between consecutive frames
    assert 0.2 < report["series"]["inlier_ratio"]["mean"] < 1.0
    assert len(report["drift"]["rotation"]) == len(report["drift"]["translation"]) == 10
    # a plain frame-to-frame VO with ground-truth step lengths: measured 0.38 m and 2.6° after 40 frames
    assert report["accuracy"]["final_position_error_m"] < 1.5
    assert report["accuracy"]["final_heading_error_deg"] < 6.0
    flow = read_entity(orb_rrd, "/world/camera/image/flow")
    assert flow["frame"].to_list() == list(range(40))


@pytest.mark.kitti
def test_eval_scores_its_trajectory_as_its_recording_reports(orb_rrd: Path, kitti_root: Path) -> None:
    """FrameLog(trajectory=…) writes the poses with vslam's trajectory writer: `vslam eval --trajectory` scores
    them exactly as the recording's own verdict (/report) did."""
    result = vslam("eval", "--trajectory", orb_rrd.with_suffix(".txt"), "--gt", kitti_root / "poses" / "05.txt",
                   "--match", "rows", "--frames", FRAMES, "--json")
    assert result.returncode == 0, result.stderr
    scored = json.loads(result.stdout)["sequences"][0]
    assert scored["frames"] == 40
    reported = json.loads(vslam("inspect", orb_rrd, "--json").stdout)["report_metrics"]
    for key in ("ate_se3", "ate_sim3", "rpe_trans", "paper_rms"):
        assert scored[key] == pytest.approx(reported[key], abs=1e-3), key  # the report prints 3 decimals


@pytest.mark.kitti
def test_compare_with_vslam_on_the_same_frames(orb_rrd: Path, kitti_root: Path, tmp_path: Path) -> None:
    run = tmp_path / "vslam.rrd"
    result = vslam("run", kitti_root, "--sequence", "05", "--frames", FRAMES, "--detail", "summary", "-o", run)
    assert result.returncode == 0, result.stderr
    compared = vslam("compare", run, orb_rrd, "--labels", "vslam,orb-vo", "-o", tmp_path / "both.rrd", "--json")
    assert compared.returncode == 0, compared.stderr
    text = vslam("inspect", tmp_path / "both.rrd", "--json")
    runs = json.loads(text.stdout)["runs"]
    assert runs["a"]["frames"]["count"] == runs["b"]["frames"]["count"] == 40
    assert runs["b"]["properties"]["pipeline"] == "orb-vo" and runs["b"]["drift"] is not None
