"""The drive at a glance (issue 56): the worst stretches ranked from per-frame costs, the top view, and the
overview entities read back from real runs' recordings (with ground truth, and without it by health)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import vslam
from kitti_runs import link_images

from vslam.recording.overview import CANVAS, Stretch, top_view, worst_stretches
from vslam.rrd.read import read_entity


def test_worst_stretches_are_the_largest_windows_without_overlap() -> None:
    frames = np.arange(100, 200)
    cost = np.zeros(100)
    cost[20:25] = 1.0  # 5.0 in frames 120..124
    cost[60:70] = 0.8  # 8.0 in frames 160..169
    cost[90] = 3.0  # 3.0 at frame 190
    assert worst_stretches(frames, cost, 10) == [Stretch(160, 169, pytest.approx(8.0)),
                                                 Stretch(115, 124, pytest.approx(5.0)),
                                                 Stretch(181, 190, pytest.approx(3.0))]
    assert worst_stretches(frames, np.zeros(100), 10) == []  # nothing stands out: nothing listed
    assert worst_stretches(frames[:4], np.ones(4), 10) == [Stretch(100, 103, pytest.approx(4.0))]


def test_top_view_drops_the_axis_of_least_motion_and_drives_up_the_picture() -> None:
    forward = np.stack([np.linspace(0, 1, 5), np.full(5, 0.01), np.linspace(0, 50, 5)], axis=1)  # RDF: along +z
    view = top_view(forward)
    np.testing.assert_allclose(view, np.stack([forward[:, 0], -forward[:, 2]], axis=1))
    z_up = forward[:, [0, 2, 1]]  # a z-up world: the plane is x–y
    np.testing.assert_allclose(top_view(z_up), np.stack([z_up[:, 0], -z_up[:, 1]], axis=1))


@pytest.mark.kitti
def test_a_planted_bad_stretch_is_listed_first_and_drawn(kitti_root: Path, tmp_path: Path) -> None:
    """KITTI 05 0:120 with frames 70..79 blurred: the summary's worst stretch (m of drift, ground truth) covers
    them; the top view holds one coloured segment per step inside the canvas, and the ground truth beside it."""
    rrd = tmp_path / "run.rrd"
    result = vslam("run", kitti_root, "--sequence", "05", "--frames", "0:120", "--inject", "blur@70:79", "-o", rrd)
    assert result.returncode == 0, result.stderr
    summary = read_entity(rrd, "/overview/summary", static=True)["TextDocument:text"].to_list()[0][0]
    assert "**Worst stretches** (m of drift):" in summary, summary
    first = re.search(r"1\. frames (\d+)–(\d+)", summary)
    assert first is not None, summary
    start, end = int(first.group(1)), int(first.group(2))
    assert start <= 79 and end >= 70, summary  # the blurred frames are in the worst stretch
    assert "kitti-05" in summary and "t_err" in summary
    path = read_entity(rrd, "/overview/path", static=True)
    strips = path["LineStrips2D:strips"].to_list()[0]
    assert len(strips) == 119  # one segment per step
    points = np.array([p for strip in strips for p in strip])
    assert points.min() >= 0 and points.max() <= CANVAS
    assert len(path["LineStrips2D:colors"].to_list()[0]) == 119
    assert len(read_entity(rrd, "/overview/ground_truth", static=True)) == 1
    marks = read_entity(rrd, "/overview/marks", static=True)
    assert marks["Points2D:labels"].to_list()[0][0] == f"#1 {start}–{end}"


@pytest.mark.kitti
def test_without_ground_truth_the_path_is_coloured_by_health(kitti_root: Path, tmp_path: Path) -> None:
    """An image folder of KITTI 05 frames without ground truth, frames 10..14 dark: the stretches are ranked by
    health and the dark frames' stretch comes first; the path's colours are the health's."""
    folder = link_images(kitti_root, tmp_path / "frames", range(30))
    rrd = tmp_path / "run.rrd"
    result = vslam("run", folder, "--intrinsics", "707.0912,707.0912,601.8873,183.1104", "--scale", "none",
                   "--inject", "dark@10:14", "-o", rrd)
    assert result.returncode == 0, result.stderr
    summary = read_entity(rrd, "/overview/summary", static=True)["TextDocument:text"].to_list()[0][0]
    assert "(health (1 warn, 2 fail per frame))" in summary, summary
    first = re.search(r"1\. frames (\d+)–(\d+)", summary)
    assert first is not None and int(first.group(1)) <= 14 and int(first.group(2)) >= 10, summary
    colours = np.array(read_entity(rrd, "/overview/path", static=True)["LineStrips2D:colors"].to_list()[0])
    assert len(colours) == 29 and len(np.unique(colours)) > 1  # ok green and the dark frames' warn/fail
    assert len(read_entity(rrd, "/overview/ground_truth", static=True)) == 0
