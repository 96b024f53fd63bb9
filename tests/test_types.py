"""The type check (mypy over `vslam_core` and `vslam`, configured in pyproject.toml) as a test: in the suite it
runs on one xdist worker while the other runs tests, instead of alone before them with a core idle (~25 s)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_code_type_checks() -> None:
    result = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.startswith("Success: no issues found in "), result.stdout
