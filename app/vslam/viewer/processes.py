"""The Rerun viewer's processes and the checks made before starting one (shared by `vslam.viewer.headless`, the
headless PNG snapshots, and `vslam.viewer.web`, the interactive native or web viewer).

Every viewer process is started in its own session and killed by process group, on success, error or
Ctrl-C, so no process and no port outlives the call. Where that cannot run (vslam SIGKILLed), Linux kills the
viewer process with its parent (`PR_SET_PDEATHSIG`, see `die_with_parent`).
"""

from __future__ import annotations

import contextlib
import ctypes.util
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO, Literal

import polars as pl
from rerun.experimental import ViewerClient

from vslam.common import first_line
from vslam.rrd import comparison_prefixes, no_frames, read_entity, readable, rerun_binary
from vslam_core.errors import VslamError

log = logging.getLogger(__name__)

NO_VULKAN = ("no Vulkan adapter: install mesa-vulkan-drivers "
             "(Debian: apt-get install -y mesa-vulkan-drivers libvulkan1)")
HOST = "127.0.0.1"

# What the viewer prints when it finds no usable graphics adapter (wgpu/egui panics, exit code 102).
_NO_ADAPTER_PATTERNS = ("no graphics adapter", "failed to get render context", "failed to create render state")
_ADDRESS_IN_USE_PATTERNS = ("address already in use", "address in use", "os error 98")
_DIE_WITH_PARENT = Path(__file__).with_name("die_with_parent.py")


class ViewerError(VslamError):
    """The viewer cannot show or snapshot a recording (bad file, frame, missing Vulkan, viewer failure)."""


# --------------------------------------------------------------------------------------------- checks


def recording_frames(rrd: Path) -> tuple[int, int]:
    """First and last value of the `frame` timeline of a vslam recording; `ViewerError` naming the file
    when it is missing, truncated, not a Rerun recording, or holds no camera frames."""
    if not rrd.exists():
        raise ViewerError(f"{rrd}: no such recording")
    if not rrd.is_file():
        raise ViewerError(f"{rrd}: is not a file")
    try:
        with warnings.catch_warnings():  # "RRD file has no footer": we report the problem ourselves
            warnings.simplefilter("ignore")
            # a single run, or a `vslam compare` file holding runs under /a, /b, …
            prefixes = ["", *(f"/{p}" for p in comparison_prefixes(rrd))]
            tables = [read_entity(rrd, f"{prefix}/world/camera") for prefix in prefixes]
    except VslamError as exc:
        raise ViewerError(first_line(exc)) from None
    tables = [t for t in tables if "frame" in t.columns and t.height]
    if not tables:
        raise ViewerError(no_frames(rrd, readable(rrd).cut_short))
    camera = pl.concat([t.select("frame") for t in tables])
    frames = camera["frame"]
    return int(frames.min()), int(frames.max())  # type: ignore[arg-type]


def viewable(rrd: Path) -> Path:
    """The file to hand the viewer: `rrd`, or for a recording cut short (no footer) its finalised copy."""
    try:
        return readable(rrd).path
    except VslamError as exc:
        raise ViewerError(first_line(exc)) from None


def vulkan_available(env: Mapping[str, str] | None = None) -> bool:
    """True when the Vulkan loader (libvulkan1) and at least one driver manifest (ICD) are installed.

    The viewer renders through Vulkan only; without both it panics at start-up. This is the cheap
    check made before starting it; `snapshot` also recognises the viewer's own failure.
    """
    env = os.environ if env is None else env
    if ctypes.util.find_library("vulkan") is None:
        return False
    return bool(vulkan_icd_files(env))


def vulkan_icd_files(env: Mapping[str, str]) -> list[Path]:
    """Vulkan driver manifests the loader would consider (explicit env lists, else the standard folders)."""
    explicit = env.get("VK_DRIVER_FILES") or env.get("VK_ICD_FILENAMES")
    if explicit:
        return [Path(p) for p in explicit.split(os.pathsep) if p and Path(p).is_file()]
    config_dirs = (env.get("XDG_CONFIG_DIRS") or "/etc/xdg").split(os.pathsep)
    data_dirs = (env.get("XDG_DATA_DIRS") or "/usr/local/share:/usr/share").split(os.pathsep)
    folders = [*config_dirs, "/etc", *data_dirs, "/usr/local/share", "/usr/share"]
    found: list[Path] = []
    for folder in dict.fromkeys(f for f in folders if f):
        icd_dir = Path(folder) / "vulkan" / "icd.d"
        if icd_dir.is_dir():
            found.extend(sorted(icd_dir.glob("*.json")))
    return found


def choose_viewer(env: Mapping[str, str], web: bool) -> Literal["native", "web"]:
    """The native viewer when a display exists and the web viewer was not asked for; else the web viewer."""
    if web:
        return "web"
    return "native" if env.get("DISPLAY") or env.get("WAYLAND_DISPLAY") else "web"


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((HOST, 0))
        return int(sock.getsockname()[1])


# ------------------------------------------------------------------------------------ viewer process


def rerun_executable() -> list[str]:
    """Command that runs the Rerun CLI: the binary shipped in rerun-sdk (the `rerun` launcher script
    would start it as a child process, which complicates stopping it)."""
    try:
        return [rerun_binary()]
    except VslamError:
        raise ViewerError("the Rerun viewer is not installed: pip install 'rerun-sdk>=0.41,<0.42'") from None


@dataclass
class _Process:
    """A viewer (or server) process in its own session, with its stderr captured in a temporary file."""

    popen: subprocess.Popen[bytes]
    stderr: IO[bytes]
    stopped: bool = False
    #: Set once the whole `feed` file was written to the process's stdin (see `_start`).
    fed: threading.Event = field(default_factory=threading.Event)
    feeder: threading.Thread | None = None

    def stderr_text(self) -> str:
        self.stderr.flush()
        self.stderr.seek(0)
        return self.stderr.read().decode(errors="replace")

    def failure(self) -> str:
        """One line describing why the process stopped (its panic message, else its last stderr line)."""
        text = _strip_ansi(self.stderr_text())
        lowered = text.lower()
        if any(p in lowered for p in _NO_ADAPTER_PATTERNS):
            return NO_VULKAN
        panic = re.search(r"panicked at '([^\n]*)'", text) or re.search(r"panicked at [^\n]*:\n([^\n]+)", text)
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        detail = panic.group(1) if panic else (lines[-1] if lines else "no output")
        return f"the Rerun viewer exited with code {self.popen.returncode}: {detail}"

    def address_in_use(self) -> bool:
        return any(p in self.stderr_text().lower() for p in _ADDRESS_IN_USE_PATTERNS)

    def stop(self, grace_s: float = 5.0) -> None:
        """SIGTERM the whole process group, SIGKILL it after `grace_s`, reap the leader (idempotent)."""
        if self.stopped:
            return
        self.stopped = True
        pgid = self.popen.pid  # start_new_session: the leader's pid is the group id
        for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, grace_s)):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pgid, sig)
            try:
                self.popen.wait(wait_s)
            except subprocess.TimeoutExpired:
                continue
            # the leader is gone; make sure no child of it survives in the group
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(pgid, signal.SIGKILL)
            break
        if self.popen.stdin is not None:  # the pipe `_start` held open for a fed process
            if self.feeder is not None:  # its reader is gone: a write in progress fails at once
                self.feeder.join(grace_s)
            with contextlib.suppress(OSError):
                self.popen.stdin.close()
        self.stderr.close()


def _start(args: Sequence[str], env: Mapping[str, str] | None = None, feed: Path | None = None) -> _Process:
    """Start the Rerun CLI with `args`. With `feed`, a thread writes that file to the process's stdin and
    then keeps the pipe open until `_Process.stop`: `rerun … -` reads a recording from stdin and, as long as
    the pipe is open, waits for more in a blocking read. (Given a file path, or stdin that reaches its end,
    the 0.41 server's ingest loop polls its finished source forever: up to a whole core, see `vslam.viewer.web`.)"""
    stderr = tempfile.TemporaryFile()  # noqa: SIM115 (closed by _Process.stop)
    child_env = {**os.environ, **(env or {}), "RERUN_APP_ONLY": "true"}  # no analytics prompt
    try:
        popen = subprocess.Popen(
            _dying_with_parent([*rerun_executable(), *args]),
            stdin=subprocess.DEVNULL if feed is None else subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            env=child_env,
            start_new_session=True,  # own process group: killed as a whole, not by the terminal's Ctrl-C
            bufsize=0,  # stdin unbuffered: `stop` closes it without a flush into a dead pipe
        )
    except BaseException:
        stderr.close()
        raise
    process = _Process(popen, stderr)
    if feed is not None:
        process.feeder = threading.Thread(target=_feed, args=(process, feed), name="rerun-stdin-feed", daemon=True)
        process.feeder.start()
    return process


def _dying_with_parent(command: list[str]) -> list[str]:
    """`command` started through `die_with_parent.py`, so Linux SIGKILLs it when this process dies (even by
    SIGKILL, when `_Process.stop` cannot run); `command` itself elsewhere, or off the main thread (the signal
    comes when the thread that started the process ends)."""
    if not sys.platform.startswith("linux") or not sys.executable or \
            threading.current_thread() is not threading.main_thread():
        return command
    return [sys.executable, "-I", "-S", str(_DIE_WITH_PARENT), str(os.getpid()), *command]


def _feed(process: _Process, path: Path, block_size: int = 1 << 20) -> None:
    """Write `path` to `process`'s stdin, whole blocks despite partial writes; set `process.fed` at the end.
    The pipe is left open (closed by `stop`). A server that exits early ends the copy (broken pipe)."""
    assert process.popen.stdin is not None
    fd = process.popen.stdin.fileno()  # closed by `stop` only after this thread ended
    try:
        with path.open("rb") as source:
            while block := source.read(block_size):
                view = memoryview(block)
                while view:
                    view = view[os.write(fd, view):]
    except OSError:  # broken pipe: the server is gone
        return
    process.fed.set()


@contextlib.contextmanager
def headless_viewer(deadline: float, window_size: tuple[int, int]) -> Iterator[tuple[_Process, ViewerClient]]:
    """A headless viewer on a free loopback port and a connected `ViewerClient`; always stopped on exit."""
    env = {"WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")}
    for _attempt in range(3):  # the port found free may be taken before the viewer binds it
        port = free_port()
        process = _start(
            ["--headless", "--hide-welcome-screen", "--bind", HOST, "--port", str(port),
             "--window-size", f"{window_size[0]}x{window_size[1]}"],
            env,
        )
        try:
            client = _connect(f"rerun+http://{HOST}:{port}/proxy", process, deadline)
            if client is None:  # exited before answering
                if process.address_in_use():
                    process.stop()
                    continue
                raise ViewerError(process.failure())
            yield process, client
            return
        finally:
            process.stop()
    raise ViewerError("the Rerun viewer could not bind a free port on 127.0.0.1 (3 attempts)")


def _connect(url: str, process: _Process, deadline: float) -> ViewerClient | None:
    """Poll until the viewer answers `get_state` (and its renderer is up); None if the process exited."""
    while True:
        if process.popen.poll() is not None:
            return None
        try:
            client = ViewerClient.connect(url)
            client.get_state()
            # The gRPC server answers before the renderer starts: wait for the first painted frame, so a
            # missing adapter shows up here as an exit instead of a later, confusing error.
            client.take_screenshot(max_size=64)
            return client
        except Exception:
            if process.popen.poll() is not None:
                return None
            if time.monotonic() > deadline:
                raise ViewerError("the Rerun viewer did not answer in time") from None
            time.sleep(0.1)


class _Terminated(BaseException):
    """SIGTERM arrived while a viewer ran (BaseException: no `except Exception` swallows it)."""


@contextlib.contextmanager
def stop_viewer_on_sigterm() -> Iterator[None]:
    """On SIGTERM, unwind first (so `finally` blocks stop the viewer), then deliver the signal as before.

    The viewer runs in its own session, so without this a terminated Python process would orphan it.
    Only possible in the main thread, and only when SIGTERM is not ignored.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.getsignal(signal.SIGTERM)
    if previous == signal.SIG_IGN:
        yield
        return

    def terminated(_signum: int, _frame: FrameType | None) -> None:
        raise _Terminated

    signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    except _Terminated:
        signal.signal(signal.SIGTERM, previous)
        os.kill(os.getpid(), signal.SIGTERM)  # default action: exit by SIGTERM; a Python handler runs now
        raise KeyboardInterrupt from None  # only reached when the previous handler returned
    finally:
        signal.signal(signal.SIGTERM, previous)


# ------------------------------------------------------------------------------------------- helpers


def _strip_ansi(text: str) -> str:
    return re.sub(r"\x1b\[[0-9;]*m", "", text)
