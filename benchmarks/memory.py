"""Memory of the current process, read from /proc (Linux)."""

from __future__ import annotations

from pathlib import Path


def status_mb(field: str) -> float:
    """A /proc/self/status field in MB: ``VmRSS`` (resident now) or ``VmHWM`` (peak resident)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024
    return float("nan")
