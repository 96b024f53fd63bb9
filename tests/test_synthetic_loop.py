"""The synthetic street's closed route (`--route loop`): around a block and back past the start."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.cli_helpers import vslam_here
from vslam_core.errors import SourceError
from vslam_core.geometry import rotation_angle
from vslam_core.sources.synthetic.road import make_loop_centreline
from vslam_core.sources.synthetic.street import SyntheticStreet


@pytest.fixture(scope="module")
def loop() -> SyntheticStreet:
    return SyntheticStreet(route="loop", resolution=0.25)


def test_loop_centreline_closes() -> None:
    line = make_loop_centreline()
    assert line.closed
    assert np.linalg.norm(line.xy[-1] - line.xy[0]) < 1e-6
    assert np.degrees(line.heading[-1]) == pytest.approx(360.0, abs=1e-6)
    xy, heading, _ = line.frame_at(np.array([10.0, 10.0 + line.s[-1]]))  # arc lengths wrap around
    np.testing.assert_allclose(xy[0], xy[1], atol=1e-9)


def test_loop_route_returns_to_its_start(loop: SyntheticStreet) -> None:
    gt = loop.ground_truth
    assert len(gt) == 660  # 600+ frames
    distance = np.linalg.norm(gt[:, :3, 3] - gt[0, :3, 3], axis=1)
    assert distance[100:500].min() > 40.0  # it goes away around the block ...
    revisit = 400 + int(np.argmin(distance[400:]))
    assert 590 <= revisit <= 630 and distance[revisit] < 1.0  # ... and comes back to where it started
    assert np.degrees(rotation_angle(gt[revisit, :3, :3] @ gt[0, :3, :3].T)) < 5.0  # facing the same way
    path = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum()
    assert 600.0 < path < 700.0


def test_loop_renders_the_same_place_again(loop: SyntheticStreet) -> None:
    """The scene is static: the revisit sees what the start saw (the images are alike, not just the poses)."""
    gt = loop.ground_truth
    revisit = 400 + int(np.argmin(np.linalg.norm(gt[400:, :3, 3] - gt[0, :3, 3], axis=1)))
    start, again, elsewhere = (loop.render(i).astype(np.float64) for i in (0, revisit, 300))
    assert start.shape == (94, 310)  # resolution 0.25
    assert np.abs(start - again).mean() < 0.5 * np.abs(start - elsewhere).mean()


def test_unknown_route_is_refused() -> None:
    with pytest.raises(SourceError, match="unknown route 'ring'"):
        SyntheticStreet(route="ring")  # type: ignore[arg-type]


def test_cli_route_only_for_synthetic(tmp_path: Path) -> None:
    result = vslam_here("run", tmp_path, "--route", "loop", "--detail", "off")
    assert result.returncode != 0
    assert result.stderr.strip().splitlines() == [f"error: --route is for the synthetic street, not {tmp_path}"]
