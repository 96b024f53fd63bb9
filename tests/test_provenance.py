"""What a recording and a report say about how they were made: the real frame range and count (also after an
interruption), injected faults, non-default config, and config differences between runs (issue 12, item 10;
crop's rewritten properties are in test_crop.py)."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_helpers import InterruptedRun, vslam

from vslam.rrd.provenance import read_properties
from vslam.rrd.read import read_entity
from vslam_core.trajectory.io import read_kitti_poses

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def small_kitti(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A KITTI-layout copy of 00 frames 0–11."""
    root = tmp_path_factory.mktemp("small")
    images = root / "sequences" / "00" / "image_0"
    images.mkdir(parents=True)
    for i in range(12):
        shutil.copy(kitti_root / "sequences" / "00" / "image_0" / f"{i:06d}.png", images)
    shutil.copy(kitti_root / "sequences" / "00" / "calib.txt", images.parent)
    (root / "poses").mkdir()
    shutil.copy(kitti_root / "poses" / "00.txt", root / "poses")
    return root


@pytest.mark.kitti
@pytest.mark.parametrize(("frames", "expected"), [(None, "0:12"), ("4:", "4:12"), ("0:999", "0:12")])
def test_name_and_properties_give_the_real_frame_range(small_kitti: Path, tmp_path: Path, frames: str | None,
                                                       expected: str) -> None:
    rrd = tmp_path / "r.rrd"
    result = vslam("run", small_kitti, "--sequence", "00", "--detail", "summary", "-o", rrd,
                   *(["--frames", frames] if frames else []))
    assert result.returncode == 0, result.stderr
    props = read_properties(rrd, "/__properties/run")
    assert props["frames"] == expected and props["name"] == f"vslam kitti-00 frames {expected} scale gt"
    assert read_entity(rrd, "/__properties", static=True)["RecordingInfo:name"].to_list() == [[props["name"]]]
    assert int(props["frame_count"]) == len(read_entity(rrd, "/world/camera"))


def _interrupt_once_grown(process: subprocess.Popen[str], rrd: Path) -> None:
    """SIGINT once `rrd` holds ~2 MB (some frames written); the run must exit 130."""
    deadline = time.monotonic() + 60
    while (not rrd.exists() or rrd.stat().st_size < 2_000_000) and time.monotonic() < deadline:
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr


@pytest.mark.kitti
def test_interrupted_run_says_what_the_recording_holds(interrupted_kitti_run: InterruptedRun) -> None:
    """`vslam run` on KITTI 00 sent SIGINT once its trajectory holds some poses (the run test_cli.py checks too)."""
    rrd, trajectory = interrupted_kitti_run.recording, interrupted_kitti_run.trajectory
    assert interrupted_kitti_run.returncode == 130, interrupted_kitti_run.stderr
    count = len(read_kitti_poses(trajectory))
    assert 1 <= count < 300
    props = read_properties(rrd, "/__properties/run")
    assert props["frame_count"] == str(count) and props["frames"] == f"0:{count}"
    assert props["stopped"] == f"interrupted by SIGINT after {count} frames"
    inspected = vslam("inspect", rrd)
    assert f"name        vslam kitti-00 frames 0:{count} scale gt" in inspected.stdout
    assert f"stopped     interrupted by SIGINT after {count} frames" in inspected.stdout


def test_report_md_states_injected_faults(tmp_path: Path) -> None:
    result = vslam("eval", "synthetic", "--frames", "0:5", "--inject", "dark@3", "--report", tmp_path, "--detail",
                   "off")
    assert result.returncode == 0, result.stderr
    assert "Faults injected into every sequence: `dark@3` (`--inject`)." in (tmp_path / "report.md").read_text()
    clean = tmp_path / "clean"
    assert vslam("eval", "synthetic", "--frames", "0:5", "--report", clean, "--detail", "off").returncode == 0
    assert "No faults injected." in (clean / "report.md").read_text()


@pytest.mark.kitti
def test_report_md_states_the_interruption(kitti_root: Path, tmp_path: Path) -> None:
    report = tmp_path / "report"
    process = subprocess.Popen(
        [sys.executable, "-m", "vslam.cli", "eval", str(kitti_root), "--sequences", "00,05", "--report", str(report),
         "--detail", "full"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    rrd = report / "kitti-00.rrd"
    _interrupt_once_grown(process, rrd)
    text = (report / "report.md").read_text()
    assert "**Interrupted by SIGINT**: kitti-00: interrupted by SIGINT after " in text
    assert "of 300 frames" in text and "not run: kitti-05" in text


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("runs")
    (out / "seed.toml").write_text("[pose]\nseed = 3\n")
    a, b = out / "a.rrd", out / "b.rrd"
    assert vslam("run", "--frames", "0:6", "--detail", "summary", "-o", a).returncode == 0
    done = vslam("run", "--frames", "0:6", "--detail", "summary", "-o", b, "--config", out / "seed.toml",
                 "--inject", "dark@3")
    assert done.returncode == 0, done.stderr
    return a, b


def test_text_inspect_shows_inject_and_non_default_config(two_runs: tuple[Path, Path]) -> None:
    a, b = two_runs
    plain = vslam("inspect", a).stdout
    assert "inject      none (no faults injected)" in plain and "config      the defaults" in plain
    changed = vslam("inspect", b).stdout
    assert "inject      dark@3" in changed and "config      pose.seed = 3 (differ from the defaults)" in changed


def test_compare_diffs_configs_and_run_properties(two_runs: tuple[Path, Path], tmp_path: Path) -> None:
    a, b = two_runs
    result = vslam("compare", a, b, "-o", tmp_path / "c.rrd")
    assert result.returncode == 0, result.stderr
    assert "config      pose.seed: 0 → 3" in result.stdout
    assert "run         inject: — → dark@3" in result.stdout
    same = vslam("compare", a, a, "-o", tmp_path / "same.rrd")
    assert "config      the same in both runs" in same.stdout
