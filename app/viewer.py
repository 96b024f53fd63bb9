"""Show recordings in the real Rerun viewer: headless PNG snapshots of every view, or an interactive viewer.

`snapshot` starts the viewer binary headless (software Vulkan is enough: Debian ``mesa-vulkan-drivers``),
drives it over gRPC with `rerun.experimental.ViewerClient`, and screenshots each view of the recording's
embedded blueprint once the pictures stop changing. `open_recording` starts the native viewer when a
display exists, and otherwise serves the web viewer on 127.0.0.1.

Every viewer process is started in its own session and killed by process group, on success, error or
Ctrl-C, so no process and no port outlives the call.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import errno
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
import urllib.parse
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import IO, Literal

import polars as pl
from rerun.experimental import View, ViewerClient, ViewerState

from app.rrd import first_line, read_entity, rerun_binary
from vslam_core.errors import VslamError

log = logging.getLogger(__name__)

NO_VULKAN = ("no Vulkan adapter: install mesa-vulkan-drivers "
             "(Debian: apt-get install -y mesa-vulkan-drivers libvulkan1)")
#: Logical size of the headless viewer window (the screenshots have this many pixels).
WINDOW_SIZE = (1600, 900)
#: Name of the whole-window screenshot written beside the per-view ones.
WHOLE_WINDOW = "all"
HOST = "127.0.0.1"

# What the viewer prints when it finds no usable graphics adapter (wgpu/egui panics, exit code 102).
_NO_ADAPTER_PATTERNS = ("no graphics adapter", "failed to get render context", "failed to create render state")
_ADDRESS_IN_USE_PATTERNS = ("address already in use", "address in use", "os error 98")


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
            # a single run, or a `vslam compare` file holding runs under /a and /b
            tables = [read_entity(rrd, path) for path in ("/world/camera", "/a/world/camera", "/b/world/camera")]
    except VslamError as exc:
        raise ViewerError(first_line(exc)) from None
    tables = [t for t in tables if "frame" in t.columns and t.height]
    if not tables:
        raise ViewerError(f"{rrd}: no camera frames in this recording (not written by `vslam run`?)")
    camera = pl.concat([t.select("frame") for t in tables])
    frames = camera["frame"]
    return int(frames.min()), int(frames.max())  # type: ignore[arg-type]


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


def _bind_problem(port: int) -> str | None:
    """Why `port` cannot be bound on 127.0.0.1 right now (None: it can)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((HOST, port))
        except PermissionError:
            return "permission denied (ports below 1024 need root)"
        except OSError as exc:
            return "already in use" if exc.errno == errno.EADDRINUSE else (exc.strerror or str(exc))
    return None


def view_file_name(name: str) -> str:
    """`error vs ground truth` -> `error_vs_ground_truth` (a file name without extension)."""
    slug = re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_").lower()
    return slug or "view"


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
        self.stderr.close()


def _start(args: Sequence[str], env: Mapping[str, str] | None = None) -> _Process:
    stderr = tempfile.TemporaryFile()  # noqa: SIM115 (closed by _Process.stop)
    child_env = {**os.environ, **(env or {}), "RERUN_APP_ONLY": "true"}  # no analytics prompt
    try:
        popen = subprocess.Popen(
            [*rerun_executable(), *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=stderr,
            env=child_env,
            start_new_session=True,  # own process group: killed as a whole, not by the terminal's Ctrl-C
        )
    except BaseException:
        stderr.close()
        raise
    return _Process(popen, stderr)


@contextlib.contextmanager
def _headless_viewer(deadline: float, window_size: tuple[int, int]) -> Iterator[tuple[_Process, ViewerClient]]:
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


# ------------------------------------------------------------------------------------------ snapshot


def snapshot(
    rrd: Path,
    frame: int,
    out_dir: Path,
    timeout_s: float = 120,
    *,
    whole_window: bool = True,
    window_size: tuple[int, int] = WINDOW_SIZE,
) -> list[Path]:
    """Open `rrd` in the headless Rerun viewer at `frame` (paused) and save one PNG per view.

    The views are those of the recording's embedded blueprint; each PNG is named after its view
    (``frame.png``, ``world.png``, ``error_vs_ground_truth.png``…), plus ``all.png`` of the whole window
    when `whole_window`, in the layout's reading order. The viewer loads chunks lazily and decodes images
    in the background, so the whole window is screenshotted until two shots in a row are identical and
    nothing is loading; the views are captured then, and the window checked once more.

    Raises `ViewerError` (one line) for a missing/bad file, a frame outside the recording, no Vulkan
    adapter, or a viewer that fails or does not settle within `timeout_s`.
    """
    first, last = recording_frames(rrd)
    if not first <= frame <= last:
        raise ViewerError(f"{rrd}: frame {frame} is outside the recording's frames {first}..{last}")
    if not vulkan_available():
        raise ViewerError(NO_VULKAN)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ViewerError(f"{out_dir}: cannot create output folder ({exc.strerror})") from None

    started = time.monotonic()
    deadline = started + timeout_s
    with _stop_viewer_on_sigterm(), _headless_viewer(deadline, window_size) as (process, client):
        try:
            shots = _settled_screenshots(client, rrd, frame, deadline, whole_window)
        except ViewerError:
            raise
        except Exception as exc:
            if process.popen.poll() is not None:
                raise ViewerError(process.failure()) from None
            raise ViewerError(f"{rrd}: the Rerun viewer failed: {first_line(exc)}") from None

    written: list[Path] = []
    used: set[str] = set()
    for name, png in shots:
        stem = view_file_name(name)
        while stem in used:
            stem += "_"
        used.add(stem)
        path = out_dir / f"{stem}.png"
        try:
            path.write_bytes(png)
        except OSError as exc:
            raise ViewerError(f"{path}: cannot write ({exc.strerror})") from None
        written.append(path)
    log.info("snapshot of %s at frame %d: %d pictures in %.1f s", rrd, frame, len(written),
             time.monotonic() - started)
    return written


def _settled_screenshots(
    client: ViewerClient, rrd: Path, frame: int, deadline: float, whole_window: bool
) -> list[tuple[str, bytes]]:
    opened = client.open(str(rrd.resolve()))
    if not opened.store_ids:
        raise ViewerError(f"{rrd}: the Rerun viewer opened no recording from this file")
    store_id = opened.store_ids[0]

    views: list[View] = []
    while not views:  # the embedded blueprint is applied once the recording is active
        state = client.get_state()
        views = [v for v in state.views if v.visible]
        if not views:
            if time.monotonic() > deadline:
                raise ViewerError(f"{rrd}: the recording's blueprint has no visible view")
            time.sleep(0.1)
    order = _layout_order(client)
    views.sort(key=lambda v: order.index(v.view_id) if v.view_id in order else len(order))
    client.set_time("frame", sequence=frame, play_state="paused", recording=store_id)
    while not _time_cursor_at(client.get_state(), store_id, frame):  # applied on the viewer's next frame
        if time.monotonic() > deadline:
            raise ViewerError(f"{rrd}: the viewer did not move to frame {frame}")
        time.sleep(0.1)

    # Settled = the whole window is the same picture twice in a row (0.2 s apart) and nothing is loading;
    # the views are then captured, and the window once more: if it changed meanwhile, start again.
    window = _settled_window(client, rrd, deadline, previous=None)
    while True:
        shots = [(v.name or v.view_class, client.take_screenshot(v.view_id)) for v in views]
        again = client.take_screenshot()
        if again == window:
            break
        window = _settled_window(client, rrd, deadline, previous=again)
    if whole_window:
        shots.append((WHOLE_WINDOW, window))
    state = client.get_state()

    for shot_name, png in shots:
        if not png.startswith(b"\x89PNG"):
            raise ViewerError(f"{rrd}: the viewer returned no picture for view {shot_name!r}")
    for view in state.views:
        for report in view.reports:
            log.warning("view %r: %s: %s", view.name, report.severity, report.summary)
    return shots


def _time_cursor_at(state: ViewerState, store_id: str, frame: int) -> bool:
    return any(r.store_id == store_id and r.current_timeline == "frame" and r.current_time == frame
               for r in state.recordings)


def _layout_order(client: ViewerClient) -> list[str]:
    """View ids in reading order of the blueprint's layout (containers depth-first); [] if unknown."""
    try:
        tree = client.get_blueprint().blueprint
        root = tree["/viewport"]["ViewportBlueprint"]["root_container"]
    except Exception:  # an older/newer blueprint shape: keep the viewer's order
        return []
    order: list[str] = []

    def walk(item: str) -> None:
        kind, _, ident = item.partition("/")
        if kind == "view":
            order.append(ident)
        elif kind == "container":
            for child in tree.get(f"/container/{ident}", {}).get("ContainerBlueprint", {}).get("contents", []):
                walk(child)

    walk(f"container/{root}")
    return order


def _settled_window(client: ViewerClient, rrd: Path, deadline: float, previous: bytes | None) -> bytes:
    """Screenshot the whole window until two shots in a row are identical and nothing is loading."""
    while True:
        if time.monotonic() > deadline:
            raise ViewerError(f"{rrd}: the viewer's pictures did not settle before the time-out")
        time.sleep(0.2)
        shot = client.take_screenshot()
        if shot == previous and not client.get_state().loading:
            return shot
        previous = shot


# ------------------------------------------------------------------------------------ interactive


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    """The web viewer's page, told to connect to the gRPC server that holds the recording."""
    return f"http://{HOST}:{web_port}/?url=" + urllib.parse.quote(f"rerun+http://{HOST}:{grpc_port}/proxy", safe="")


@contextlib.contextmanager
def serve_web(rrd: Path, port: int | None = None, timeout_s: float = 30) -> Iterator[tuple[str, _Process]]:
    """Serve `rrd` with the web viewer on 127.0.0.1 (HTTP on `port`, or a free one) until the block ends.

    Yields the URL to open and the server process (its group is killed on exit).
    """
    if port is not None and (problem := _bind_problem(port)) is not None:
        raise ViewerError(f"port {port} on {HOST}: {problem}")
    deadline = time.monotonic() + timeout_s
    for _attempt in range(3):
        web_port = port if port is not None else free_port()
        grpc_port = free_port()
        process = _start(["--serve-web", "--bind", HOST, "--port", str(grpc_port),
                          "--web-viewer-port", str(web_port), str(rrd.resolve())])
        try:
            if not _wait_listening(process, web_port, deadline):
                if process.address_in_use() and port is None:
                    process.stop()
                    continue
                raise ViewerError(process.failure())
            yield web_viewer_url(web_port, grpc_port), process
            return
        finally:
            process.stop()
    raise ViewerError(f"the Rerun web viewer could not bind free ports on {HOST} (3 attempts)")


def _wait_listening(process: _Process, port: int, deadline: float) -> bool:
    while process.popen.poll() is None:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.settimeout(0.5)
            if sock.connect_ex((HOST, port)) == 0:
                return True
        if time.monotonic() > deadline:
            raise ViewerError(f"the Rerun web viewer did not listen on {HOST}:{port} in time")
        time.sleep(0.1)
    return False


def open_recording(rrd: Path, web: bool = False, port: int | None = None) -> None:
    """Show `rrd` interactively until the viewer is closed or Ctrl-C is pressed.

    The native viewer when a display exists (DISPLAY / WAYLAND_DISPLAY) and `web` is False; otherwise the
    web viewer served on 127.0.0.1 (`port`, or a free one) whose URL is printed: no browser is opened.
    """
    recording_frames(rrd)
    kind = choose_viewer(os.environ, web)
    if kind == "native" and port is not None:
        raise ViewerError("--port sets the web viewer's port, and a display was found so the native viewer would "
                          "open: add --web")
    with _stop_viewer_on_sigterm():
        try:
            if kind == "web":
                with serve_web(rrd, port) as (url, process):
                    print(f"Rerun web viewer: {url}", flush=True)
                    print("press Ctrl-C to stop", flush=True)
                    process.popen.wait()
                    raise ViewerError(process.failure())
            else:
                _run_native(rrd)
        except KeyboardInterrupt:
            print("viewer stopped", file=sys.stderr, flush=True)


def _run_native(rrd: Path) -> None:
    # A port of our own: `rerun file.rrd` would otherwise hand the file to any viewer already on 9876.
    process = _start(["--bind", HOST, "--port", str(free_port()), str(rrd.resolve())])
    try:
        code = process.popen.wait()
        if code != 0:
            raise ViewerError(f"{process.failure()} (no usable display? try --web)")
    finally:
        process.stop()


class _Terminated(BaseException):
    """SIGTERM arrived while a viewer ran (BaseException: no `except Exception` swallows it)."""


@contextlib.contextmanager
def _stop_viewer_on_sigterm() -> Iterator[None]:
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


