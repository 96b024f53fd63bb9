"""`vslam run --live web`: the web viewer's ports answer while the run goes on, and the saved recording is the
same in content as a run without --live."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import polars as pl
import pytest
from cli_helpers import ROOT, vslam, vslam_here
from rerun.chunk import RrdReader

from vslam.cli.common import live_default
from vslam.rrd.read import read_entity
from vslam.viewer.processes import HOST, free_port

#: Long enough that the ports answer while the run still goes on, on a loaded machine too: on a quiet host they
#: answer ~1 s after the start and 15 frames end at ~3 s, but under the suite 15 frames ended first once the
#: synthetic scene was cached (its ~1.4 s build had made the run longer)
FRAMES = "0:45"
N_FRAMES = 45


def answers_http(port: int) -> bool:
    try:
        with urllib.request.urlopen(f"http://{HOST}:{port}/", timeout=2) as response:
            return bool(response.status == 200 and response.read(64))
    except OSError:
        return False


def accepts_tcp(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(1.0)
        return sock.connect_ex((HOST, port)) == 0


def _sigint_default() -> None:
    """Ctrl-C acts in the run as in a shell: the test process may have SIGINT ignored at the OS level (Ray's
    native client, used in-process by the Ray tests, leaves it so), and an ignored signal is inherited."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """A synthetic run with --live web on two fixed free ports: the ports probed while it runs, then Ctrl-C."""
    folder = tmp_path_factory.mktemp("live")
    web_port, grpc_port = free_port(), free_port()
    output = folder / "live.rrd"
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "app"), str(ROOT)])}
    environment.pop("DISPLAY", None)
    environment.pop("WAYLAND_DISPLAY", None)
    log = folder / "stdout.txt"
    with log.open("w") as stdout:
        process = subprocess.Popen(
            [sys.executable, "-m", "vslam.cli", "run", "--frames", FRAMES, "-o", str(output), "--live", "web",
             "--web-port", str(web_port), "--grpc-port", str(grpc_port)],
            cwd=ROOT, env=environment, stdout=stdout, stderr=subprocess.PIPE, text=True, start_new_session=True,
            preexec_fn=_sigint_default)
    try:
        deadline = time.monotonic() + 120
        http = tcp = False
        while not (http and tcp) and time.monotonic() < deadline and process.poll() is None:
            http, tcp = answers_http(web_port), accepts_tcp(grpc_port)
            time.sleep(0.2)
        during_run = "the run is over" not in log.read_text()  # the ports answered before the run had ended
        while "press Ctrl-C" not in log.read_text() and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.5)
        os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    plain = folder / "plain.rrd"
    done = vslam("run", "--frames", FRAMES, "-o", plain)
    assert done.returncode == 0, done.stderr
    return {"http": http, "tcp": tcp, "during_run": during_run, "code": process.returncode, "stderr": stderr,
            "stdout": log.read_text(), "output": output, "plain": plain, "ports": (web_port, grpc_port)}


def test_ports_answer_while_the_run_goes_on(live_run: dict[str, object]) -> None:
    assert live_run["code"] == 0, live_run["stderr"]
    assert live_run["http"] and live_run["tcp"]
    assert live_run["during_run"]
    web_port, grpc_port = live_run["ports"]  # type: ignore[misc]
    stdout = str(live_run["stdout"])
    assert f"Rerun web viewer (live): http://{HOST}:{web_port}/?url=" in stdout
    assert f"ssh -N -L {web_port}:{HOST}:{web_port} -L {grpc_port}:{HOST}:{grpc_port}" in stdout
    assert f"frames      {N_FRAMES}" in stdout  # the run's summary, before the viewer waits for Ctrl-C


def test_saved_recording_equals_a_run_without_live(live_run: dict[str, object]) -> None:
    """Every entity, static and per frame, read back equal (row ids aside); except the stage timings and the
    bundle adjustment's solver time (wall-clock: they differ between any two runs, which is also why `rerun rrd
    compare --unordered` reports them)."""
    live, plain = Path(str(live_run["output"])), Path(str(live_run["plain"]))

    def entities(path: Path) -> set[str]:
        reader = RrdReader(path)
        return set(reader.store(store=reader.recordings()[0]).schema().entity_paths())

    assert entities(live) == entities(plain)
    wall_clock = ("/metrics/timing_ms", "/metrics/ba/milliseconds")
    compared = [e for e in entities(live) if not e.startswith(wall_clock)]
    assert {"/world/camera", "/world/camera/image", "/world/camera/image/flow", "/health", "/events"} <= set(compared)
    def content(path: Path, entity: str, static: bool) -> pl.DataFrame:
        table = read_entity(path, entity, static)  # without the row ids: each run makes its own
        return table.drop([c for c in table.columns if c.startswith("rerun.controls")])

    for entity in compared:
        for static in (False, True):
            assert content(live, entity, static).equals(content(plain, entity, static)), (entity, static)
    assert len(read_entity(live, "/world/camera")) == N_FRAMES
    levels = read_entity(live, "/metrics/health_levels/warn")  # the health plot's named level, first to last frame
    assert levels["frame"].to_list() == [0, N_FRAMES - 1] and levels["Scalars:scalars"].to_list() == [[1.0], [1.0]]
    timing = read_entity(live, "/metrics/timing_ms/track")
    assert timing["frame"].to_list() == read_entity(plain, "/metrics/timing_ms/track")["frame"].to_list()


def test_bare_live_means_auto_and_ports_need_it() -> None:
    assert live_default(["run", "--live"]) == ["run", "--live", "auto"]
    assert live_default(["run", "--live", "--frames", "0:3"]) == ["run", "--live", "auto", "--frames", "0:3"]
    assert live_default(["run", "--live", "web", "x"]) == ["run", "--live", "web", "x"]
    assert live_default(["open", "--live"]) == ["open", "--live"]
    refused = vslam_here("run", "--frames", "0:2", "--grpc-port", "9999", "--detail", "off")
    assert refused.returncode == 2 and "add --live web" in refused.stderr
