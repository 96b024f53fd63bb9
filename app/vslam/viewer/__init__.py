"""The Rerun viewer: its processes and the checks before starting one (`processes`), `vslam open` native or in a
browser (`web`) and headless PNGs (`headless`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "live_viewer": "live",
    "open_recording": "web",
    "parse_frame": "headless",
    "parse_size": "headless",
    "port_problem": "web",
    "snapshot": "headless",
}

if TYPE_CHECKING:
    from vslam.viewer.headless import parse_frame, parse_size, snapshot
    from vslam.viewer.live import live_viewer
    from vslam.viewer.web import open_recording, port_problem


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "live_viewer",
    "open_recording",
    "parse_frame",
    "parse_size",
    "port_problem",
    "snapshot",
]
