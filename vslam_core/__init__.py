"""vslam's engine: monocular visual odometry as pure computation (no Rerun, no CLI)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("vslam")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"
