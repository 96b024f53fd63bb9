"""What the `vslam` commands share: the consoles, option types and help texts, and one-line errors."""

from __future__ import annotations

import errno
from collections.abc import Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import NoReturn

import typer
from rich.console import Console
from rich.text import Text

#: stderr and stdout. User text (paths, --frames 0:100:2, manifest cells) is printed as it is: no Rich markup
#: (``[red]`` in a file name), no emoji codes (``:100:`` would become an emoji), no highlighting; the coloured
#: prefixes (`labelled`) are styled `Text`, never markup.
err = Console(stderr=True, soft_wrap=True, markup=False, emoji=False, highlight=False)
out = Console(soft_wrap=True, markup=False, emoji=False, highlight=False)


def labelled(label: str, style: str, message: str) -> Text:
    """``label message`` with the label styled (e.g. ``error:`` in bold red), the message verbatim."""
    return Text.assemble((label, style), " ", message)


def print_error(message: str, label: str = "error:") -> None:
    """``error: message`` on stderr, the message verbatim."""
    err.print(labelled(label, "bold red", message), soft_wrap=True)
class Scale(StrEnum):
    gt = "gt"
    none = "none"
    height = "height"


class Live(StrEnum):
    """``vslam run --live``: where to show the run while it goes on (`vslam.viewer.live`)."""

    auto = "auto"
    native = "native"
    web = "web"


#: ``--live`` alone means this (`live_default`).
LIVE_DEFAULT = "auto"


def live_default(args: list[str]) -> list[str]:
    """`args` of ``vslam run`` with ``--live`` given no value (last, or followed by another option or the
    source) completed to ``--live auto``."""
    if not args or args[0] != "run":
        return args
    done: list[str] = []
    for i, arg in enumerate(args):
        done.append(arg)
        following = args[i + 1] if i + 1 < len(args) else None
        if arg == "--live" and (following is None or following not in Live.__members__):
            done.append(LIVE_DEFAULT)
    return done


class Backend(StrEnum):
    vo = "vo"
    map = "map"


BACKEND_HELP = ("vo = frame-to-keyframe odometry; map = keyframes and landmarks, tracking against the map, windowed "
                "bundle adjustment, relocalisation [default: the config's backend, map unless --config says otherwise]")
CAMERA_HEIGHT_HELP = ("metres from the camera to the road, for --scale height [default: the source's own: KITTI "
                      "1.65 m, the synthetic street's]")


CALIB_SCALE_HELP = ("resize the camera given with --calib or --intrinsics by this factor, for frames that are resized "
                    "copies of the calibrated camera's (0.5: half-size frames); said on the camera line")
CALIB_HELP = ("camera calibration file, lens included: ROS camera_info YAML, Kalibr camchain or EuRoC sensor.yaml, "
              "OpenCV YAML/XML, KITTI calib.txt (for image folders, videos and logs: overrides a log's CameraInfo)")
GT_HELP = ("ground-truth camera poses, KITTI (row i = frame i) or TUM; TUM rows are matched to a log's or "
           "dataset's frames by timestamp")
TOPIC_HELP = "the image topic of a ROS bag / MCAP log [default: its only image topic]"
GT_TOPIC_HELP = ("ground truth from a topic of the log (PoseStamped, Odometry, TransformStamped), as camera "
                 "poses (via /tf_static when it is of another frame)")
GT_TOLERANCE_HELP = ("how far (ms) a ground-truth stamp may be from its frame's when matched by time (TUM RGB-D, "
                     "interpolated: the largest gap between the two rows around a frame, default 100)")
GT_TIME_OFFSET_HELP = ("seconds the ground truth's clock reads ahead of the frames' (frame time t takes the pose "
                       "stamped t + offset; the run's gt check estimates it)")
GT_ROWS_HELP = ("A:B: rows A..B-1 of a --gt file without times are the frames (needed when it has more rows than "
                "frames and nothing pairs them by time)")


class BadFrame(StrEnum):
    fail = "fail"
    skip = "skip"


class TrajectoryFormat(StrEnum):
    kitti = "kitti"
    tum = "tum"


def fail(message: str, code: int = 2) -> NoReturn:
    """One line on stderr, a non-zero exit, no traceback."""
    print_error(message)
    raise typer.Exit(code)


def warn(message: str) -> None:
    """One line on stderr; the run goes on."""
    err.print(labelled("warning:", "bold yellow", message), soft_wrap=True)


def refuse(problem: str | None, code: int = 2) -> None:
    if problem is not None:
        fail(problem, code)


IMAGE_CODEC_HELP = ("recorded camera frames: jpeg images, or an av1 / h264 video stream at the source's size (the "
                    "native viewer needs ffmpeg on PATH for h264)")


@contextmanager
def report_writes(report: Path | None) -> Iterator[None]:
    """A report file that cannot be written (full disk) ends the command in one line, not a traceback."""
    try:
        yield
    except OSError as exc:
        if report is None:
            raise
        from vslam.common import write_failure

        path = Path(exc.filename) if exc.filename else report  # a write() error names no file
        # EIO (cv2 gives no reason): the file system tells whether it is full
        fail(write_failure(path, None if exc.errno in (None, errno.EIO) else exc))
