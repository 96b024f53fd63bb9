"""Every Python block of docs/logging-api.md and docs/recording-schema.md runs as it is (the blocks of a page one
after the other, in an empty folder, as a reader pasting them would), and what they write passes `vslam check` and
reads back as the page says."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from cli_helpers import ROOT, vslam

from vslam.rrd import blueprint_view_names, read_entity

PAGES = ("logging-api.md", "recording-schema.md")
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)


def python_blocks(page: str) -> list[str]:
    return _BLOCK.findall((ROOT / "docs" / page).read_text())


def _run_page(page: str, folder: Path, monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Run the page's blocks in `folder`; the recordings they wrote."""
    monkeypatch.chdir(folder)
    blocks = python_blocks(page)
    assert blocks, page
    namespace: dict[str, object] = {"__name__": f"docs_{page}"}
    for number, block in enumerate(blocks, 1):
        exec(compile(block, f"docs/{page} block {number}", "exec"), namespace)  # noqa: S102 - the docs' own code
    return sorted(folder.glob("*.rrd"))


def test_the_logging_api_page_runs_and_its_recordings_conform(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    written = _run_page("logging-api.md", tmp_path, monkeypatch)
    assert [p.name for p in written] == ["extra.rrd", "run.rrd", "two_view.rrd"]
    for path in written:
        check = vslam("check", path)
        assert check.returncode == 0, check.stdout
    report = json.loads(vslam("inspect", tmp_path / "run.rrd", "--json").stdout)
    assert report["frames"]["count"] == 20 and report["stages_ms"]["orb"]["mean"] == pytest.approx(1.2)
    assert set(report["own_series"]) == {"counts", "ratios", "pipeline series"}
    views = blueprint_view_names(tmp_path / "run.rrd")
    assert views is not None and {"counts", "ratios", "pipeline series"} <= set(views)
    assert read_entity(tmp_path / "extra.rrd", "/my/loop_score")["frame"].to_list() == [0, 1, 2]
    # the two-view block: OpenCV's candidates and points as the page says, the truth recovered
    two_view = json.loads(vslam("inspect", tmp_path / "two_view.rrd", "--json").stdout)
    assert two_view["series"]["chirality_margin"]["min"] > 100  # one candidate has (nearly) every point in front
    assert two_view["accuracy"]["max_position_error_m"] < 0.01  # exact correspondences: the steps are the truth's
    points = read_entity(tmp_path / "two_view.rrd", "/world/points")
    assert len(points["Points3D:positions"].to_list()[-1]) == 200


def test_the_schema_page_runs_and_its_recording_conforms(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    written = _run_page("recording-schema.md", tmp_path, monkeypatch)
    assert [p.name for p in written] == ["my.rrd"]
    check = vslam("check", written[0])
    assert check.returncode == 0, check.stdout
    report = json.loads(vslam("inspect", written[0], "--json").stdout)
    assert report["frames"] == {"count": 100, "first": 0, "last": 99}
    assert report["series"]["tracks_alive"]["mean"] == 500
