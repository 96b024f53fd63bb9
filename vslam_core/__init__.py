"""vslam's engine: monocular visual odometry as pure computation (no Rerun, no CLI)."""

import functools
from typing import Any


@functools.cache
def _installed_version() -> str:
    """The installed distribution's version, looked up on first use (PEP 562): importlib.metadata and its scan of
    the installed distributions cost every process ~30 ms, most of which never ask for it."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vslam")
    except PackageNotFoundError:  # running from a source tree that was not installed
        return "0.0.0+unknown"


def __getattr__(name: str) -> Any:
    if name == "__version__":
        return _installed_version()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
