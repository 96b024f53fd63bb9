"""How the `vslam` process starts and ends: quiet third-party libraries, one-line errors, exit codes.

- Third-party logging (OpenCV's own log lines; FFmpeg's "moov atom not found" on a truncated video, through
  the environment set in `vslam/__init__.py` before cv2 is imported) is silenced: vslam reports those
  problems itself, in one line.
- Usage errors (an unknown option, a value of the wrong type or out of an option's range) are one line on
  stderr, ``error: …`` and exit 2, like every `VslamError`; never a box, never a traceback.
- pandas is not imported while a command runs (`vslam.no_pandas`): vslam never uses it (~0.3 s of CPU a process).
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any

import typer

from vslam.no_pandas import pandas_left_out
from vslam_core.errors import VslamError

#: Click's exception classes, found through typer's public `BadParameter` (typer ≥ 0.2x vendors Click)
_CLICK_CLASSES = {cls.__name__: cls for cls in typer.BadParameter.__mro__}
ClickException: type[Exception] = _CLICK_CLASSES["ClickException"]
UsageError: type[Exception] = _CLICK_CLASSES["UsageError"]


def silence_opencv() -> None:
    """OpenCV's own log lines (e.g. for a corrupt PNG) would precede our one-line error: we report it. OpenCV
    not imported yet reads the level from the environment when it starts (so `vslam --help` and commands that
    never read an image do not load it, ~0.3 s of CPU)."""
    cv2 = sys.modules.get("cv2")
    if cv2 is None:
        os.environ["OPENCV_LOG_LEVEL"] = "SILENT"
        return
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def usage_line(exc: Exception) -> str:
    """A Click usage error as one line, with the command's help hint."""
    message = one_line(_message(exc))
    ctx = getattr(exc, "ctx", None)
    hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""
    return f"{message}{hint}"


def _message(exc: Exception) -> str:
    format_message = getattr(exc, "format_message", None)
    return str(format_message()) if callable(format_message) else str(exc)


def one_line(text: object) -> str:
    return " ".join(str(text).split())


def run(app: typer.Typer, report: Callable[[str], None]) -> None:
    """Run the Typer app and exit with its code. `report(message)` prints ``error: message`` on stderr."""
    silence_opencv()
    reconfigure = getattr(sys.stdout, "reconfigure", None)
    if callable(reconfigure):  # a path that is not UTF-8 is printed with \xff escapes, never a UnicodeEncodeError
        reconfigure(errors="backslashreplace")
    try:
        with pandas_left_out():
            code = _click_command(app)(standalone_mode=False)
    except VslamError as exc:
        report(one_line(exc))
        code = 2
    except UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # `vslam` alone: the help, as Click would show it
            print(_message(exc))
            code = 0
        else:
            report(usage_line(exc))
            code = 2
    except ClickException as exc:
        report(one_line(exc))
        code = int(getattr(exc, "exit_code", 1))
    except typer.Abort:
        code = 130
    except SystemExit as exc:  # typer.Exit in standalone_mode=False comes back as its code; sys.exit as this
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    _exit(code if isinstance(code, int) else 0)


@functools.cache
def _click_command(app: typer.Typer) -> Callable[..., Any]:
    """The app's Click command, built once per process (~25 ms of signature inspection each time): a process
    that runs several commands (the tests run hundreds in theirs) reuses it. What `app(...)` does, less its
    excepthook, which only prints tracebacks prettily, and the app turns that off."""
    return typer.main.get_command(app)


def _exit(code: int) -> None:
    """Exit with `code`. A writer stuck for good (`vslam.common.outputs.hold_stuck_writer`) would make the exit
    handlers wait forever: everything is reported and the files are closed by then, so skip them."""
    from vslam.common import stuck_writers

    if stuck_writers():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
