"""The map at a larger motion per frame (KITTI at every 2nd frame, `--scale none`): a frame that sees too few of
the map's landmarks is made a keyframe (`[map] none_starving_keyframes`), so the map keeps landmarks through a
turn."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vslam_core.config import EngineConfig
from vslam_core.mapping.map_scale import for_scale
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, PnPFailure, TrackingMode
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import ate


@pytest.mark.kitti
def test_the_map_keeps_landmarks_through_a_turn_at_every_second_frame(kitti_root: Path) -> None:
    """00 frames 150:250:2 (a 5 Hz camera, the turn at 200–250): without the keyframe rule the map lost every
    landmark in the turn (18 frames `too_few_in_view`), 25 of 50 frames were placed by two-view motion at the
    map's last speed and the ATE after Sim(3) was 0.84 m; with it 34 frames by PnP, 0.24 m (2026-12-02)."""
    source = KittiSource(kitti_root, sequence="00", frames=FrameRange(150, 250, 2))
    config = EngineConfig(backend="map", scale="none", threads=1)
    assert for_scale(config.map, "none").starving_keyframes and not for_scale(config.map, "height").starving_keyframes
    results: list[FrameResult] = []
    run = run_odometry(source, config, (lambda _frame, result: results.append(result),))
    assert source.ground_truth is not None
    placed = sum(r.mapping is not None and r.mapping.mode == TrackingMode.MAP for r in results)
    unseen = sum(r.mapping is not None and r.mapping.pnp is not None
                 and r.mapping.pnp.failure == PnPFailure.TOO_FEW_IN_VIEW for r in results)
    error = ate(source.ground_truth[:len(results)], run.pose_array(), "sim3")
    assert len(results) == 50 and placed >= 30 and unseen <= 3, (placed, unseen)
    assert error < 0.4, error
    assert np.isfinite(run.pose_array()).all()
