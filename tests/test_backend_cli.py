"""`--backend vo|map` on `vslam run` and `vslam eval`: the option, its default (the config's) and where the
backend is reported (summary, recording properties, eval JSON / CSV / report)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import polars as pl
import pytest
from cli_helpers import vslam

from vslam.rrd.read import read_entity

ROOT = Path(__file__).resolve().parents[1]


def backend_line(stdout: str) -> str:
    lines = [line for line in stdout.splitlines() if line.startswith("backend")]
    assert len(lines) == 1, stdout
    return re.sub(r"\s+", " ", lines[0].strip())


def placed(stdout: str) -> tuple[dict[str, int], str]:
    """The summary's `placed` line (map backend): frames by how they were placed, and the line."""
    lines = [line for line in stdout.splitlines() if line.startswith("placed")]
    assert len(lines) == 1, stdout
    modes = re.sub(r" \(--scale none: .*\)$", "", lines[0][12:])  # the two-view steps' lengths: not modes
    counts = {words.strip(): int(n) for n, words in re.findall(r"(\d+) ([a-zA-Z ()-]+?)(?:,|$| \()", modes)}
    return counts, lines[0]


@pytest.mark.kitti
def test_run_with_the_map_backend_which_is_the_default(kitti_root: Path, tmp_path: Path) -> None:
    trajectory = tmp_path / "x.txt"
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:30", "--backend", "map", "--detail", "off",
                   "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    assert backend_line(result.stdout) == "backend map"
    assert len(trajectory.read_text().splitlines()) == 30
    counts, line = placed(result.stdout)  # where each frame's pose came from
    assert sum(counts.values()) == 30 and counts["by PnP against the map"] >= 20, line
    assert "scale can drift" not in line  # ground-truth scale: two-view steps have their true length
    assert "\nadjusted" not in result.stdout  # with a scale source the map is not adjusted again at the end
    assert "\nsettings" not in result.stdout  # a car moves along its optical axis (|cos| 1.00 over 5 keyframes)

    default = tmp_path / "default.txt"  # no --backend, no --config: the default engine is the map
    result = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:30", "--detail", "off", "--trajectory-out",
                   default)
    assert result.returncode == 0, result.stderr
    assert backend_line(result.stdout) == "backend map" and default.read_bytes() == trajectory.read_bytes()


@pytest.mark.kitti
def test_without_a_scale_source_the_summary_says_which_steps_took_the_maps_speed(kitti_root: Path,
                                                                                 tmp_path: Path) -> None:
    rrd = tmp_path / "none.rrd"
    result = vslam("run", kitti_root, "--sequence", "05", "--frames", "0:20", "--backend", "map", "--scale", "none",
                   "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr
    counts, line = placed(result.stdout)
    assert sum(counts.values()) == 20 and counts["by two-view motion"] > 0, line
    two_view = counts["by two-view motion"]  # at 10 Hz every one at the map's speed (map_scale.TwoViewLength)
    assert (f"(--scale none: of the two-view steps' lengths, {two_view} took the map's recent speed; the scale can "
            "drift there") in line, line
    # the frames before the map's start: two-view when tracked, placed against its first landmarks in the output
    again = re.search(r"; (\d+) frames tracked before the map started placed again by PnP against its first "
                      r"landmarks in the output poses\)$", line)
    assert again and 0 < int(again[1]) <= two_view, line
    adjusted = [line for line in result.stdout.splitlines() if line.startswith("adjusted")]
    # a car: the map stays as the windows left it
    assert len(adjusted) == 1 and re.search(r"not run: the camera moves along its optical axis \(median \|cos\| "
                                            r"(0\.9\d|1\.00)", adjusted[0]), adjusted
    report = read_entity(rrd, "/report", static=True)["TextDocument:text"].to_list()[-1][0]
    assert f"Adjusted: {adjusted[0].removeprefix('adjusted').strip()}." in report, report  # the recording says so


def test_unknown_backend_is_a_usage_error() -> None:
    result = vslam("run", "synthetic", "--frames", "0:5", "--backend", "foo", "--detail", "off")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if "--backend" in line]
    assert len(errors) == 1, result.stderr
    assert "'foo'" in errors[0] and "'vo'" in errors[0] and "'map'" in errors[0]


@pytest.mark.kitti
def test_backend_option_overrides_the_config_file(kitti_root: Path, tmp_path: Path) -> None:
    vo_config, map_config = tmp_path / "vo.toml", tmp_path / "map.toml"
    vo_config.write_text('backend = "vo"\n')
    map_config.write_text('backend = "map"\n')
    common = ["run", kitti_root, "--sequence", "00", "--detail", "off"]
    runs = {
        "option": ["--frames", "0:30", "--backend", "vo"],
        "config": ["--frames", "0:30", "--config", vo_config],
        "option over config": ["--frames", "0:30", "--config", map_config, "--backend", "vo"],
    }
    trajectories = {}
    for name, args in runs.items():
        trajectories[name] = tmp_path / f"{name}.txt"
        result = vslam(*common, *args, "--trajectory-out", trajectories[name])
        assert result.returncode == 0, (name, result.stderr)
        assert backend_line(result.stdout) == "backend vo", name
        assert not any(line.startswith("placed") for line in result.stdout.splitlines())  # vo keeps no map
    expected = trajectories["config"].read_bytes()
    assert expected and all(path.read_bytes() == expected for path in trajectories.values())

    # without the option, the config file's backend is used (and recorded in the run's properties)
    rrd = tmp_path / "map.rrd"
    result = vslam(*common[:-2], "--frames", "0:8", "--config", map_config, "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr
    assert backend_line(result.stdout) == "backend map"
    properties = read_entity(rrd, "/__properties/run", static=True)
    assert properties["backend"][0].to_list() == ["map"]


def test_eval_reports_the_backend_next_to_the_scale(tmp_path: Path) -> None:
    report = tmp_path / "report"
    result = vslam("eval", "synthetic", "--frames", "0:20", "--backend", "vo", "--json", "--report", report,
                   "--detail", "off")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert data["scale"] == "gt" and data["backend"] == "vo"
    assert [row["backend"] for row in [*data["sequences"], data["mean"]]] == ["vo", "vo"]
    table = pl.read_csv(report / "metrics.csv")
    assert table.columns[1:3] == ["scale", "backend"] and table["backend"].to_list() == ["vo", "vo"]
    assert "backend `vo`" in (report / "report.md").read_text()

    printed = vslam("eval", "synthetic", "--frames", "0:10")  # the default backend: the map
    assert printed.returncode == 0, printed.stderr
    header, _, row = [line for line in printed.stdout.splitlines() if line.startswith("|")][:3]
    assert "| scale | backend |" in header and "| gt | map |" in row


def test_backend_does_not_apply_to_trajectory_files(tmp_path: Path) -> None:
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    result = vslam("eval", "--trajectory", poses, "--gt", poses, "--backend", "map")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--backend" in lines[0], result.stderr
