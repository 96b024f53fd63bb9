"""What the ROS log readers take out of any message: fields under their ROS 1 or ROS 2 names, header stamps, tf
frame names; and the one boundary that turns whatever the ``rosbags`` reader raises into a `SourceError` line."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from vslam_core.errors import SourceError


def one_line(exc: BaseException) -> str:
    """An exception's message on one line of at most 200 characters (its class name when it has none)."""
    text = " ".join(str(exc).split()).strip(" .")
    text = text if text else exc.__class__.__name__
    return text if len(text) <= 200 else text[:197] + "…"


@contextmanager
def bag_errors(where: str, doing: str) -> Iterator[None]:
    """Turn whatever rosbags (or the file system, sqlite, a decompressor) raises into one `SourceError` line."""
    try:
        yield
    except SourceError:
        raise
    except Exception as exc:  # noqa: BLE001 - the boundary to a third-party reader: nothing else may escape
        raise SourceError(f"{where}: {doing}: {one_line(exc)}") from None


def bare(frame: str) -> str:
    """A tf frame name without ROS 1's leading slash."""
    return frame.strip().lstrip("/")


def field(msg: object, *names: str) -> Any:
    """The first of `names` that `msg` has (ROS 2 ``k`` vs ROS 1 ``K``)."""
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise AttributeError(f"message {type(msg).__name__} has none of the fields {', '.join(names)}")


def stamp_ns(stamp: object) -> int:
    """A ``builtin_interfaces/Time`` (ROS 2: sec, nanosec) or ROS 1 time (secs, nsecs) in nanoseconds."""
    return int(field(stamp, "sec", "secs")) * 1_000_000_000 + int(field(stamp, "nanosec", "nsec", "nsecs"))
