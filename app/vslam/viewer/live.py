"""`vslam run --live`: a viewer that shows the run while it goes on.

The run's recording stream gets two sinks (`vslam.recording.stream.open_stream`): the `.rrd` file, written as
without ``--live``, and a ``rr.GrpcSink`` to the viewer started here. ``native`` (the default where a display
exists): the native viewer listening for gRPC on a free port of 127.0.0.1; it stays open after the run.
``web`` (the default without a display): ``rerun --serve-web`` with no file (idle at ~0 % CPU, see
`vslam.viewer.web`) on the same ports and with the same SSH hint as ``vslam open --web``; after the run it
keeps serving until Ctrl-C.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from vslam.viewer import processes as viewer
from vslam.viewer.processes import HOST, ViewerError, choose_viewer, free_port
from vslam.viewer.web import _bind_problem, _wait_listening, check_web_port, tunnel_hint, web_viewer_url

#: Seconds to wait for the viewer or the web server to listen.
START_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class LiveViewer:
    """A started viewer: `grpc_url` for the run's `rr.GrpcSink`; `web_url` the page (web only)."""

    kind: str
    grpc_url: str
    grpc_port: int
    web_port: int | None
    web_url: str | None
    process: viewer._Process


def grpc_url(port: int) -> str:
    return f"rerun+http://{HOST}:{port}/proxy"


@contextlib.contextmanager
def live_viewer(live: str, web_port: int | None = None, grpc_port: int | None = None,
                say: Callable[[str], None] = print) -> Iterator[LiveViewer]:
    """Start the viewer `live` asks for (auto: native with a display, else web; native; web), `ViewerError` if
    it cannot start; yield it for the run; then the web server keeps serving until Ctrl-C (then stopped), the
    native viewer is left open."""
    check_web_port(web_port, "--web-port")
    check_web_port(grpc_port, "--grpc-port")
    kind = choose_viewer(os.environ, live == "web") if live != "native" else "native"
    if kind == "native" and web_port is not None:
        raise ViewerError("--web-port sets the web viewer's port, and the native viewer would open: use --live web")
    if kind == "web" and web_port is not None and web_port == grpc_port:
        raise ViewerError(f"--web-port and --grpc-port are both {web_port}: the web viewer needs two ports")
    for port in (web_port, grpc_port):
        if port is not None and (problem := _bind_problem(port)) is not None:
            raise ViewerError(f"port {port} on {HOST}: {problem}")
    started = _start_web(web_port, grpc_port) if kind == "web" else _start_native(grpc_port)
    if started.web_url is not None:
        assert started.web_port is not None
        say(f"Rerun web viewer (live): {started.web_url}")
        say(f"from another machine: {tunnel_hint(started.web_port, started.grpc_port)}, then open the URL")
    else:
        say(f"Rerun viewer (live) on gRPC port {started.grpc_port}")
    try:
        yield started
    except BaseException:
        if kind == "web":
            started.process.stop()
        raise
    if kind == "web":
        say("the run is over; the web viewer keeps serving it: press Ctrl-C to stop")
        try:
            started.process.popen.wait()
        except KeyboardInterrupt:
            print("viewer stopped", file=sys.stderr, flush=True)
        finally:
            started.process.stop()


def _start_web(web_port: int | None, grpc_port: int | None) -> LiveViewer:
    """``rerun --serve-web`` without a file on `web_port` and `grpc_port` (free ones when None)."""
    import time

    deadline = time.monotonic() + START_TIMEOUT_S
    for _attempt in range(3):
        web = web_port if web_port is not None else free_port()
        grpc = grpc_port if grpc_port is not None else free_port()
        process = viewer._start(["--serve-web", "--bind", HOST, "--port", str(grpc), "--web-viewer-port", str(web)])
        try:
            listening = _wait_listening(process, web, deadline) and _wait_listening(process, grpc, deadline)
        except BaseException:
            process.stop()
            raise
        if listening:
            return LiveViewer("web", grpc_url(grpc), grpc, web, web_viewer_url(web, grpc), process)
        process.stop()
        if not (process.address_in_use() and (web_port is None or grpc_port is None)):
            raise ViewerError(process.failure())
    raise ViewerError(f"the Rerun web viewer could not bind free ports on {HOST} (3 attempts)")


def _start_native(grpc_port: int | None) -> LiveViewer:
    """The native viewer listening for gRPC on `grpc_port` (a free one when None)."""
    import time

    port = grpc_port if grpc_port is not None else free_port()
    process = viewer._start(["--bind", HOST, "--port", str(port)])
    try:
        if not _wait_listening(process, port, time.monotonic() + START_TIMEOUT_S):
            raise ViewerError(f"{process.failure()} (no usable display? try --live web)")
    except BaseException:
        process.stop()
        raise
    return LiveViewer("native", grpc_url(port), port, None, None, process)
