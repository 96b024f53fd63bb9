"""The CLI answers `--help`, usage errors and bad paths without loading the engine, the recorder, polars
or the viewer client: each command imports what it needs when it runs (vslam/cli/commands.py)."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import vslam.cli.commands
from vslam.viewer.snapshot import DEFAULT_SIZE

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("polars", "av", "gtsam", "ray", "rosbags", "vslam_core.engine", "vslam.recording.recorder",
         "vslam.evaluation.evaluate", "vslam.viewer.snapshot", "vslam.batch.run", "vslam_core.sources.kitti")


def test_importing_the_cli_loads_none_of_the_heavy_modules() -> None:
    probe = f"import sys, vslam.cli.commands; print(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == ""


def test_the_snapshot_size_default_is_the_snapshot_modules() -> None:
    default = inspect.signature(vslam.cli.commands.snapshot_command).parameters["size"].default
    assert default == f"{DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]}"
