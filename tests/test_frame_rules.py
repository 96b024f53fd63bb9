"""One rule for frame ranges (END clamped like a Python slice; only an empty range is an error), crop's
accepted syntax and its error text, inspect on compare outputs, a corrupt first frame skipped (issue 12,
item 16)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from cli_helpers import vslam, vslam_here

from vslam.rrd.provenance import read_properties
from vslam_core.trajectory.io import read_kitti_poses

ROOT = Path(__file__).resolve().parents[1]


def one_line_error(result: subprocess.CompletedProcess[str], *fragments: str) -> str:
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rrd = tmp_path_factory.mktemp("rules") / "run.rrd"
    result = vslam("run", "--frames", "294:999", "--detail", "summary", "-o", rrd)  # END clamped to 300
    assert result.returncode == 0, result.stderr
    assert "frames      6 " in result.stdout
    return rrd


def test_end_past_the_last_frame_is_clamped_for_run(recording: Path) -> None:
    assert read_properties(recording, "/__properties/run")["frames"] == "294:300"


def test_a_range_that_selects_nothing_is_a_one_line_error(tmp_path: Path) -> None:
    one_line_error(vslam_here("run", "--frames", "300:400", "-o", tmp_path / "x.rrd"), "selects no frame",
                   "300 frames")
    one_line_error(vslam_here("run", "--frames", "20:10", "-o", tmp_path / "x.rrd"), "selects no frame")
    assert not (tmp_path / "x.rrd").exists()


def test_crop_clamps_the_same_way_and_its_errors_name_what_it_accepts(recording: Path, tmp_path: Path) -> None:
    clamped = vslam("crop", recording, "--frames", "297:400", "-o", tmp_path / "a.rrd")
    assert clamped.returncode == 0, clamped.stderr
    assert "frames 297..299 (3 frames)" in clamped.stdout
    open_end = vslam("crop", recording, "--frames", "298:", "-o", tmp_path / "b.rrd")
    assert open_end.returncode == 0 and "frames 298..299 (2 frames)" in open_end.stdout
    for bad in ("5", "1:5:2", "a:b"):
        message = one_line_error(vslam_here("crop", recording, "--frames", bad, "-o", tmp_path / "c.rrd"), "START:END",
                                 "no STEP")
        assert "[:STEP]" not in message
    one_line_error(vslam_here("crop", recording, "--frames", "400:500", "-o", tmp_path / "c.rrd"), "select no frame")


def test_inspect_reads_compare_outputs(recording: Path, tmp_path: Path) -> None:
    comparison = tmp_path / "cmp.rrd"
    assert vslam("compare", recording, recording, "-o", comparison, "--labels", "old,new").returncode == 0
    text = vslam("inspect", comparison)
    assert text.returncode == 0, text.stderr
    assert "── run A: old" in text.stdout and "── run B: new" in text.stdout
    data = json.loads(vslam("inspect", comparison, "--json").stdout)
    assert data["comparison"]["label_a"] == "old" and set(data["runs"]) == {"a", "b"}
    assert data["runs"]["b"]["frames"] == {"count": 6, "first": 294, "last": 299}
    cropped = tmp_path / "cmp-crop.rrd"
    assert vslam("crop", comparison, "--frames", "296:298", "-o", cropped).returncode == 0
    data = json.loads(vslam("inspect", cropped, "--json").stdout)
    assert data["runs"]["a"]["frames"]["count"] == 2 and data["runs"]["a"]["properties"]["frame_count"] == "2"


@pytest.mark.kitti
def test_corrupt_first_frame_is_skipped_with_skip(kitti_root: Path, tmp_path: Path) -> None:
    images = tmp_path / "sequences" / "00" / "image_0"
    images.mkdir(parents=True)
    for i in range(10):
        shutil.copy(kitti_root / "sequences" / "00" / "image_0" / f"{i:06d}.png", images)
    (images / "000000.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 100)
    shutil.copy(kitti_root / "sequences" / "00" / "calib.txt", images.parent)
    skipped = vslam("run", tmp_path, "--sequence", "00", "--on-bad-frame", "skip", "--detail", "off",
                    "--trajectory-out", tmp_path / "t.txt")
    assert skipped.returncode == 0, skipped.stderr
    assert len(read_kitti_poses(tmp_path / "t.txt")) == 10
    one_line_error(vslam("run", tmp_path, "--sequence", "00", "--detail", "off"), "000000.png", "cannot read image")
