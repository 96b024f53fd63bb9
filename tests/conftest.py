"""Shared fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from ray_cluster import ray_cluster  # noqa: F401  (the fixture: a real one-node Ray head, see ray_cluster.py)

#: The real KITTI sample: the ``shared`` folder beside the repository checkout (never inside the repo).
KITTI_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti"


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    """Root of the real KITTI sample (``sequences/NN/…``, ``poses/NN.txt``).

    Skips the test when the data is missing, except when the environment variable ``CI`` is set: there
    the data must be present, so the test fails instead.
    """
    if not (KITTI_ROOT / "sequences").is_dir() or not (KITTI_ROOT / "poses").is_dir():
        message = f"real KITTI data not found at {KITTI_ROOT}"
        if "CI" in os.environ:
            pytest.fail(f"{message} (CI is set: tests that need the real data must not be skipped)")
        pytest.skip(message)
    return KITTI_ROOT
