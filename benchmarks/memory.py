"""Memory of the current process, read from /proc (Linux)."""

from __future__ import annotations

import os
from pathlib import Path


def status_mb(field: str, pid: int | str = "self") -> float:
    """A /proc/<pid>/status field in MB: ``VmRSS`` (resident now) or ``VmHWM`` (peak resident); NaN if the
    process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def children_mb(field: str) -> float:
    """The sum of a /proc status field (MB) over this process's children (the map backend's worker)."""
    try:
        pids = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text().split()
    except OSError:
        return 0.0
    return sum(v for v in (status_mb(field, pid) for pid in pids) if v == v)
