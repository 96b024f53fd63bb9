"""`vslam open`: the native viewer where a display exists, else the web viewer served on 127.0.0.1.

The web viewer needs two ports: HTTP for the page (`--web-port`, alias `--port`) and gRPC for the data
(`--grpc-port`); fixing both lets an SSH tunnel be set up before the server starts. While serving, the gRPC
port's established TCP connections (from /proc/net/tcp) tell whether a browser is connected: the user is told
when none is after `BROWSER_WAIT_S`, and when one connects or leaves (one poll a second: ≈1–3 % of a core).

Idle CPU. Given the recording's path (`rerun --serve-web … file.rrd`), the 0.41 server keeps one thread
(`tokio-#1`) busy for as long as it runs, with or without a browser: its ingest loop
(`re_grpc_server::spawn_from_rx_set`) asks its set of sources for the next message, gets "disconnected" at once
from the file source that has ended, finds the set not yet empty and asks again (perf: `LogReceiverSet::recv`,
`crossbeam_channel::select`, no syscall). That thread is runnable all the time and takes whatever a core has to
give: ≈100 % on an idle machine (issue 24), 15–40 % on this shared 2-core one (load average 30–40). Neither
`--server-memory-limit` nor `--threads 1` changes it, nor a stdin that reaches its end. So the recording is written
to the server's stdin (`rerun … -`) and the pipe is held open until the server is stopped
(`viewer._start(feed=…)`): the source never ends, the loop waits in a blocking read, and the server sleeps (0.0 %
of a core, with or without an idle browser; `benchmarks/web_idle.py`). The embedded layout (blueprint) arrives as
from the file, which pushing the recording over gRPC from the SDK (`log_file_from_path`, `send_chunks`) would lose.
A SIGKILLed `vslam open` can neither stop the server nor hold its pipe open: Linux kills the server with it
(`PR_SET_PDEATHSIG`, set by `vslam.viewer.die_with_parent` before the server starts).
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import sys
import time
import urllib.parse
from collections.abc import Callable, Iterator
from pathlib import Path

from vslam.viewer import processes as viewer
from vslam.viewer.processes import HOST, ViewerError, choose_viewer, free_port

#: Seconds without a connected browser before `open --web` says so.
BROWSER_WAIT_S = 10.0
PORT_RANGE = (1, 65535)
_TCP_ESTABLISHED = "01"
#: The Rerun CLI's name for its standard input: the recording is fed there, never given as a path.
STDIN = "-"


def port_problem(port: int | None, option: str) -> str | None:
    """Why `port` is not a TCP port 1..65535 (None: it is, or it is None = pick a free one). 0 is refused too:
    the OS would pick a port no tunnel could know in advance."""
    if port is not None and not PORT_RANGE[0] <= port <= PORT_RANGE[1]:
        return f"{option} {port}: give a TCP port in {PORT_RANGE[0]}..{PORT_RANGE[1]} (or leave it out for a free one)"
    return None


def check_web_port(port: int | None, option: str) -> int | None:
    """`port` if `port_problem` finds none, else `ViewerError`."""
    if (problem := port_problem(port, option)) is not None:
        raise ViewerError(problem)
    return port


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    """The web viewer's page, told to connect to the gRPC server that holds the recording."""
    return f"http://{HOST}:{web_port}/?url=" + urllib.parse.quote(f"rerun+http://{HOST}:{grpc_port}/proxy", safe="")


def tunnel_hint(web_port: int, grpc_port: int) -> str:
    """The SSH command that forwards both ports from another machine."""
    return f"ssh -N -L {web_port}:{HOST}:{web_port} -L {grpc_port}:{HOST}:{grpc_port} <this host>"


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


@contextlib.contextmanager
def serve_web(rrd: Path, web_port: int | None = None, grpc_port: int | None = None,
              timeout_s: float = 30) -> Iterator[tuple[str, int, int, viewer._Process]]:
    """Serve `rrd` with the web viewer on 127.0.0.1 until the block ends: HTTP on `web_port` and gRPC on
    `grpc_port` (free ones when None). Yields the URL, both ports and the server process (killed on exit)."""
    check_web_port(web_port, "--web-port")
    check_web_port(grpc_port, "--grpc-port")
    if web_port is not None and web_port == grpc_port:
        raise ViewerError(f"--web-port and --grpc-port are both {web_port}: the web viewer needs two ports")
    for port in (web_port, grpc_port):
        if port is not None and (problem := _bind_problem(port)) is not None:
            raise ViewerError(f"port {port} on {HOST}: {problem}")
    deadline = time.monotonic() + timeout_s
    for _attempt in range(3):
        web = web_port if web_port is not None else free_port()
        grpc = grpc_port if grpc_port is not None else free_port()
        process = viewer._start(["--serve-web", "--bind", HOST, "--port", str(grpc), "--web-viewer-port", str(web),
                                 STDIN], feed=viewer.viewable(rrd).resolve())
        try:
            if not _wait_listening(process, web, deadline):
                if process.address_in_use() and (web_port is None or grpc_port is None):
                    process.stop()
                    continue
                raise ViewerError(process.failure())
            yield web_viewer_url(web, grpc), web, grpc, process
            return
        finally:
            process.stop()
    raise ViewerError(f"the Rerun web viewer could not bind free ports on {HOST} (3 attempts)")


def _wait_listening(process: viewer._Process, port: int, deadline: float) -> bool:
    while process.popen.poll() is None:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.settimeout(0.5)
            if sock.connect_ex((HOST, port)) == 0:
                return True
        if time.monotonic() > deadline:
            raise ViewerError(f"the Rerun web viewer did not listen on {HOST}:{port} in time")
        time.sleep(0.1)
    return False


def connections_to(port: int, tables: tuple[str, ...] = ("/proc/net/tcp", "/proc/net/tcp6")) -> int | None:
    """Established TCP connections whose local port is `port` (clients of a server on it); None where
    /proc/net/tcp cannot be read (not Linux)."""
    count, readable = 0, False
    for table in tables:
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        readable = True
        for line in lines:
            fields = line.split()
            if len(fields) > 3 and fields[3] == _TCP_ESTABLISHED and int(fields[1].rsplit(":", 1)[1], 16) == port:
                count += 1
    return count if readable else None


def watch_browser(process: viewer._Process, grpc_port: int, url: str, wait_s: float = BROWSER_WAIT_S,
                  say: Callable[[str], None] = print, poll_s: float = 1.0) -> None:
    """Until the server exits: say when no browser is connected `wait_s` after the start (or after the last
    one left), and when one connects. Sleeps between polls: no busy loop."""
    connected, alone_since, told = False, time.monotonic(), False
    while process.popen.poll() is None:
        count = connections_to(grpc_port)
        if count is None:  # no /proc: nothing to watch, just wait
            process.popen.wait()
            return
        if count and not connected:
            say(f"browser connected ({count} connection{'s' if count > 1 else ''} to the gRPC port {grpc_port})")
            connected, told = True, False
        elif not count and connected:
            say("browser disconnected")
            connected, alone_since = False, time.monotonic()
        elif not count and not told and time.monotonic() - alone_since >= wait_s:
            say(f"no browser connected yet: open {url}")
            told = True
        time.sleep(poll_s)


def open_recording(rrd: Path, web: bool = False, web_port: int | None = None, grpc_port: int | None = None,
                   browser_wait_s: float = BROWSER_WAIT_S) -> None:
    """Show `rrd` interactively until the viewer is closed or Ctrl-C is pressed (KeyboardInterrupt, after saying
    "viewer stopped").

    The native viewer when a display exists (DISPLAY / WAYLAND_DISPLAY) and `web` is False; otherwise the
    web viewer served on 127.0.0.1 (`web_port` and `grpc_port`, or free ones) whose URL is printed with the
    SSH command forwarding both ports: no browser is opened.
    """
    check_web_port(web_port, "--web-port")
    check_web_port(grpc_port, "--grpc-port")
    viewer.recording_frames(rrd)
    kind = choose_viewer(os.environ, web)
    if kind == "native" and (web_port is not None or grpc_port is not None):
        raise ViewerError("--web-port and --grpc-port set the web viewer's ports, and a display was found so the "
                          "native viewer would open: add --web")
    with viewer.stop_viewer_on_sigterm():
        try:
            if kind == "web":
                with serve_web(rrd, web_port, grpc_port) as (url, http_port, grpc, process):
                    print(f"Rerun web viewer: {url}", flush=True)
                    print(f"from another machine: {tunnel_hint(http_port, grpc)}, then open the URL", flush=True)
                    print("press Ctrl-C to stop", flush=True)
                    watch_browser(process, grpc, url, browser_wait_s, lambda line: print(line, flush=True))
                    raise ViewerError(process.failure())
            else:
                _run_native(rrd)
        except KeyboardInterrupt:
            print("viewer stopped", file=sys.stderr, flush=True)
            raise  # the command exits 130, as `vslam run` does on Ctrl-C


def _run_native(rrd: Path) -> None:
    # A port of our own: `rerun file.rrd` would otherwise hand the file to any viewer already on 9876.
    viewable = viewer.viewable(rrd).resolve()
    process = viewer._start(["--bind", HOST, "--port", str(free_port()), str(viewable)])
    try:
        code = process.popen.wait()
        if code != 0:
            raise ViewerError(f"{process.failure()} (no usable display? try --web)")
    finally:
        process.stop()
