"""benchmarks/tum_rotation.py: the per-axis gain and offset of a run's frame-to-frame rotations, and the final error
with the worst steps replaced by the true ones, on rotations built with a known bias."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.tum_rotation import axis_gains, final_error_deg, step_rotations, worst_fixed_deg
from vslam_core.geometry import so3_exp, so3_log


def _chain(steps: list[np.ndarray]) -> np.ndarray:
    poses = [np.eye(4)]
    for step in steps:
        pose = poses[-1].copy()
        pose[:3, :3] = pose[:3, :3] @ step
        poses.append(pose)
    return np.array(poses)


def _true_steps(count: int = 200) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [so3_exp(np.radians(rng.normal(0.0, 1.0, 3))) for _ in range(count)]


def test_a_rotation_estimated_short_about_x_shows_as_a_gain_and_not_as_a_few_bad_steps() -> None:
    truth = _true_steps()
    short = [so3_exp(np.array([0.7, 1.0, 1.0]) * so3_log(step)) for step in truth]
    truth_steps, steps = step_rotations(_chain(truth)), step_rotations(_chain(short))
    (gain_x, offset_x), (gain_y, _), (gain_z, _) = axis_gains(truth_steps, steps)
    assert gain_x == pytest.approx(-0.3, abs=0.02) and abs(offset_x) < 0.01
    assert abs(gain_y) < 0.02 and abs(gain_z) < 0.02
    biased = final_error_deg(truth_steps, steps)
    assert biased > 1.0
    assert worst_fixed_deg(truth_steps, steps, 20) > 0.5 * biased  # a steady bias: the worst tenth is not it
    assert worst_fixed_deg(truth_steps, steps, len(steps)) == pytest.approx(0.0, abs=1e-4)


def test_one_bad_step_is_found_by_replacing_the_worst() -> None:
    truth = _true_steps()
    bad = list(truth)
    bad[50] = bad[50] @ so3_exp(np.radians([0.0, 0.0, 3.0]))
    truth_steps, steps = step_rotations(_chain(truth)), step_rotations(_chain(bad))
    assert final_error_deg(truth_steps, steps) == pytest.approx(3.0, abs=0.01)
    assert worst_fixed_deg(truth_steps, steps, 1) == pytest.approx(0.0, abs=1e-4)
    assert axis_gains(truth_steps, steps)[2][1] == pytest.approx(3.0 / 200, abs=0.01)  # an offset, not a gain

