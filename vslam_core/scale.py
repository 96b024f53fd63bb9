"""Where the length of each estimated translation comes from.

The essential matrix gives the direction of motion only. `gt` takes the length from ground truth, as the
published method does; `none` uses unit steps (a trajectory up to scale).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from vslam_core.config import ScaleSource
from vslam_core.errors import ConfigError


class ScaleProvider(Protocol):
    name: ScaleSource

    def step_length(self, key_position: int, cur_position: int) -> float:
        """Length of the translation between two run positions (keyframe, current frame)."""
        ...


class GroundTruthScale:
    """|t_gt(cur) − t_gt(key)|: the distance between the ground-truth positions of the two frames."""

    name: ScaleSource = "gt"

    def __init__(self, ground_truth: np.ndarray) -> None:
        self._positions = np.asarray(ground_truth)[:, :3, 3]

    def step_length(self, key_position: int, cur_position: int) -> float:
        return float(np.linalg.norm(self._positions[cur_position] - self._positions[key_position]))


class UnitScale:
    """Every accepted step has length 1: the trajectory is known up to one global scale at best."""

    name: ScaleSource = "none"

    def step_length(self, key_position: int, cur_position: int) -> float:
        return 1.0


def make_scale_provider(source: ScaleSource, ground_truth: np.ndarray | None) -> ScaleProvider:
    """The provider for a config's scale source; `gt` without ground truth is an error."""
    if source == "gt":
        if ground_truth is None:
            raise ConfigError("--scale gt needs ground truth, and this source has none (use --scale none)")
        return GroundTruthScale(ground_truth)
    return UnitScale()
