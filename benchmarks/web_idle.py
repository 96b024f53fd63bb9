"""Idle CPU of the web viewer's server (`vslam open --web`) and of the alternatives, with no browser and with one
idle browser connected.

    python -m benchmarks.web_idle REC.rrd [--seconds 20] [--repeats 3] [--configs file,open-web] [--no-browser]

For every configuration: start the server, wait `--warmup` s (the recording is ingested), measure the CPU time
(user + system, /proc via psutil, summed over the server's whole process tree) over `--seconds` s with no client;
then open the page in headless Chromium (Playwright, `/usr/bin/chromium`), wait until it holds a gRPC connection
and `--settle` s more (the recording is transferred and drawn), and measure again over `--seconds` s. Chromium's
own CPU is measured separately over the same window. Each configuration is started `--repeats` times; the table
gives the mean and [min–max] over repeats, in % of one core. CPU time counts only what the process did, not how
long it waited for a core, so an idle server reads the same under any load; but a busy loop takes what the
other processes leave it, so it reads less on a loaded machine. The *demand* column (mean number of the server's
threads that are runnable, x 100, sampled every 0.1 s) does not depend on the load: a thread spinning forever
counts 100 % (a whole core, which it uses on an idle machine), a sleeping server 0 %.

Configurations (`--configs`):
- `file`: `rerun --serve-web … FILE`, what `open --web` ran before (rerun-sdk 0.41.0);
- `file-memlimit`: the same with `--server-memory-limit 64MiB`;
- `file-threads1`: the same with `--threads 1`;
- `stdin-eof`: the file piped to `rerun --serve-web … -` and the pipe closed at its end (`cat FILE | rerun …`);
- `push-grpc`: `rerun --serve-web` with no file, the recording pushed once into it by a short-lived Python process
  (`RecordingStream.connect_grpc` + `log_file_from_path`): the embedded layout (blueprint) is lost;
- `in-process`: `rr.serve_grpc` + `rr.serve_web_viewer` in a Python process that sent the recording's chunks
  (`send_chunks(RrdReader(FILE).store())`): the embedded layout is lost, and the recording id with it;
- `open-web`: `open_recording(web=True)` (vslam.viewer.web) as `vslam open --web` runs it (Python + the Rerun
  server): the file is written to the server's stdin and the pipe held open.

Needs `pip install playwright` and Debian's `chromium`; `--no-browser` measures only the first state.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import psutil

from vslam.rrd.read import rerun_binary
from vslam.viewer.processes import HOST, free_port
from vslam.viewer.web import connections_to, web_viewer_url

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
RERUN_ENV = {"RERUN_APP_ONLY": "true"}  # the CLI's "no analytics prompt"; Python's `import rerun` fails with it


@dataclass
class Server:
    """A running configuration: the process whose tree is measured, and where a browser finds it."""

    popen: subprocess.Popen[bytes]
    url: str
    grpc_port: int
    helpers: list[subprocess.Popen[bytes]] = field(default_factory=list)


def _spawn(args: list[str], stdin: int | None = subprocess.DEVNULL) -> subprocess.Popen[bytes]:
    env = {**os.environ, **(RERUN_ENV if args[0] == rerun_binary() else {})}
    return subprocess.Popen(args, stdin=stdin, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            cwd=ROOT, start_new_session=True)


def _python(code: str, *args: str) -> subprocess.Popen[bytes]:
    return _spawn([sys.executable, "-c", textwrap.dedent(code), *args])


def _rerun_web(web: int, grpc: int, *extra: str) -> list[str]:
    return [rerun_binary(), "--serve-web", "--bind", HOST, "--port", str(grpc), "--web-viewer-port", str(web), *extra]


def start_file(rrd: Path, web: int, grpc: int, *options: str) -> Server:
    return Server(_spawn(_rerun_web(web, grpc, *options, str(rrd))), web_viewer_url(web, grpc), grpc)


def start_stdin_eof(rrd: Path, web: int, grpc: int) -> Server:
    popen = _spawn(_rerun_web(web, grpc, "-"), stdin=subprocess.PIPE)
    assert popen.stdin is not None
    popen.stdin.write(rrd.read_bytes())
    popen.stdin.close()
    return Server(popen, web_viewer_url(web, grpc), grpc)


PUSH = """
    import sys, rerun as rr
    rec = rr.RecordingStream("vslam")
    rec.connect_grpc(f"rerun+http://127.0.0.1:{sys.argv[2]}/proxy")
    rec.log_file_from_path(sys.argv[1])
    rec.flush()
    rec.disconnect()
"""


def start_push_grpc(rrd: Path, web: int, grpc: int) -> Server:
    server = Server(_spawn(_rerun_web(web, grpc)), web_viewer_url(web, grpc), grpc)
    _wait_port(grpc, server.popen)
    pusher = _python(PUSH, str(rrd), str(grpc))
    pusher.wait(120)
    return server


IN_PROCESS = """
    import sys, time, rerun as rr
    from rerun.chunk import RrdReader
    rec = rr.RecordingStream("vslam")
    uri = rec.serve_grpc(grpc_port=int(sys.argv[2]))
    rec.send_chunks(RrdReader(sys.argv[1]).store())
    rr.serve_web_viewer(web_port=int(sys.argv[3]), open_browser=False, connect_to=uri)
    while True:
        time.sleep(3600)
"""


def start_in_process(rrd: Path, web: int, grpc: int) -> Server:
    return Server(_python(IN_PROCESS, str(rrd), str(grpc), str(web)), web_viewer_url(web, grpc), grpc)


OPEN_WEB = """
    import sys
    from pathlib import Path
    from vslam.viewer.web import open_recording
    open_recording(Path(sys.argv[1]), web=True, web_port=int(sys.argv[2]), grpc_port=int(sys.argv[3]),
                   browser_wait_s=1e9)
"""


def start_open_web(rrd: Path, web: int, grpc: int) -> Server:
    return Server(_python(OPEN_WEB, str(rrd), str(web), str(grpc)), web_viewer_url(web, grpc), grpc)


CONFIGS: dict[str, Callable[[Path, int, int], Server]] = {
    "file": start_file,
    "file-memlimit": lambda rrd, web, grpc: start_file(rrd, web, grpc, "--server-memory-limit", "64MiB"),
    "file-threads1": lambda rrd, web, grpc: start_file(rrd, web, grpc, "--threads", "1"),
    "stdin-eof": start_stdin_eof,
    "push-grpc": start_push_grpc,
    "in-process": start_in_process,
    "open-web": start_open_web,
}


def _wait_port(port: int, popen: subprocess.Popen[bytes], timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if popen.poll() is not None:
            stderr = popen.stderr.read().decode(errors="replace") if popen.stderr else ""
            raise RuntimeError(f"server exited with {popen.returncode} before listening on {port}: {stderr}")
        with contextlib.closing(socket.socket()) as sock:
            if sock.connect_ex((HOST, port)) == 0:
                return
        time.sleep(0.2)
    raise RuntimeError(f"nothing listens on {port} after {timeout_s} s")


def _tree(processes: list[psutil.Process]) -> list[psutil.Process]:
    found: dict[int, psutil.Process] = {}
    for process in processes:
        with contextlib.suppress(psutil.NoSuchProcess):
            for p in [process, *process.children(recursive=True)]:
                found[p.pid] = p
    return list(found.values())


def _cpu_seconds(processes: list[psutil.Process]) -> dict[int, float]:
    seconds = {}
    for p in processes:
        with contextlib.suppress(psutil.NoSuchProcess):
            times = p.cpu_times()
            seconds[p.pid] = times.user + times.system
    return seconds


def _runnable_threads(processes: list[psutil.Process]) -> int:
    """Threads of `processes` running or waiting for a core now (state R in /proc/PID/task/*/stat)."""
    count = 0
    for process in processes:
        with contextlib.suppress(OSError):
            for task in Path(f"/proc/{process.pid}/task").iterdir():
                with contextlib.suppress(OSError):
                    stat = (task / "stat").read_text()
                    count += stat[stat.rindex(")") + 2] == "R"
    return count


@dataclass
class Usage:
    """CPU used by a group of processes over a window, in % of one core. `demand`: mean number of its threads
    that were runnable (sampled every 0.1 s), x 100: what it would use with free cores, whatever the load."""

    cpu: float
    demand: float


def usage(groups: dict[str, Callable[[], list[psutil.Process]]], seconds: float) -> dict[str, Usage]:
    """CPU time used by each group of processes over `seconds`, and its runnable threads sampled meanwhile. The
    groups are listed again at the end: a process started meanwhile counts whole, one gone by the end is not
    counted (none is, in these runs)."""
    before = {name: _cpu_seconds(find()) for name, find in groups.items()}
    runnable = {name: 0 for name in groups}
    samples = 0
    start = time.monotonic()
    while time.monotonic() - start < seconds:
        for name, find in groups.items():
            runnable[name] += _runnable_threads(find())
        samples += 1
        time.sleep(0.1)
    after = {name: _cpu_seconds(find()) for name, find in groups.items()}
    wall = time.monotonic() - start
    return {name: Usage(100 * sum(used - before[name].get(pid, 0.0) for pid, used in after[name].items()) / wall,
                        100 * runnable[name] / max(samples, 1))
            for name in groups}


@contextlib.contextmanager
def running(config: str, rrd: Path) -> Iterator[Server]:
    """`config` started on free ports and listening; stopped with every process it started (SIGTERM first, so
    `open_recording` stops its own server, then SIGKILL whatever is left of the tree)."""
    web, grpc = free_port(), free_port()
    server = CONFIGS[config](rrd, web, grpc)
    try:
        _wait_port(grpc, server.popen)
        _wait_port(web, server.popen)
        yield server
    finally:
        tree = _tree([psutil.Process(popen.pid) for popen in [server.popen, *server.helpers] if popen.poll() is None])
        for popen in [server.popen, *server.helpers]:
            with contextlib.suppress(ProcessLookupError):
                popen.terminate()
        psutil.wait_procs(tree, timeout=10)
        for process in tree:
            with contextlib.suppress(psutil.NoSuchProcess):
                process.kill()
        for popen in [server.popen, *server.helpers]:
            popen.wait()


@contextlib.contextmanager
def browser(url: str) -> Iterator[Callable[[], list[psutil.Process]]]:
    """Headless Chromium showing `url`; yields a function listing its processes."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="web-idle-chromium-") as profile, sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            profile, executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            page = context.pages[0] if context.pages else context.new_page()
            page.goto(url)

            def processes() -> list[psutil.Process]:
                return [p for p in psutil.process_iter(["cmdline"]) if profile in " ".join(p.info["cmdline"] or [])]

            yield processes
        finally:
            context.close()


def measure(config: str, rrd: Path, args: argparse.Namespace) -> dict[str, Usage]:
    """One start of `config`: the server's usage with no browser, then the server's and the browser's with one
    idle browser (`connected`: cpu 1 when the page held a gRPC connection)."""
    with running(config, rrd) as server:
        time.sleep(args.warmup)
        server_tree = psutil.Process(server.popen.pid)
        result = {"alone": usage({"server": lambda: _tree([server_tree])}, args.seconds)["server"]}
        if args.no_browser:
            return result
        with browser(server.url) as chromium:
            deadline = time.monotonic() + 60
            while not connections_to(server.grpc_port) and time.monotonic() < deadline:
                time.sleep(0.5)
            result["connected"] = Usage(float(bool(connections_to(server.grpc_port))), 0.0)
            time.sleep(args.settle)
            both = usage({"server": lambda: _tree([server_tree]), "browser": chromium}, args.seconds)
        result["with browser"], result["browser"] = both["server"], both["browser"]
        return result


def _cell(values: list[float]) -> str:
    return f"{statistics.mean(values):.1f} [{min(values):.1f}–{max(values):.1f}]"


def table(rows: list[tuple[str, list[dict[str, Usage]]]], browser: bool) -> list[str]:
    """Markdown rows: per configuration, CPU and demand of the server alone and with one idle browser."""
    lines = ["| configuration | no browser: CPU | demand | one idle browser: CPU | demand | browser's own CPU "
             "| browser connected |", "|---|---|---|---|---|---|---|"]
    for config, runs in rows:
        cells = [_cell([r["alone"].cpu for r in runs]), _cell([r["alone"].demand for r in runs])]
        if browser:
            connected = sum(int(r["connected"].cpu) for r in runs)
            cells += [_cell([r["with browser"].cpu for r in runs]), _cell([r["with browser"].demand for r in runs]),
                      _cell([r["browser"].cpu for r in runs]), f"{connected}/{len(runs)}"]
        else:
            cells += ["-"] * 4
        lines.append(f"| {config} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("rrd", type=Path)
    parser.add_argument("--configs", default=",".join(CONFIGS))
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--warmup", type=float, default=8.0)
    parser.add_argument("--settle", type=float, default=15.0)
    parser.add_argument("--no-browser", action="store_true")
    args = parser.parse_args()
    configs = args.configs.split(",")
    if unknown := [c for c in configs if c not in CONFIGS]:
        parser.error(f"unknown configuration(s) {', '.join(unknown)}: choose from {', '.join(CONFIGS)}")
    rows = []
    for config in configs:
        runs = []
        for repeat in range(args.repeats):
            runs.append(measure(config, args.rrd, args))
            figures = ", ".join(f"{k} {v.cpu:.1f} ({v.demand:.0f})" for k, v in runs[-1].items())
            print(f"{config} #{repeat + 1}: {figures}", file=sys.stderr, flush=True)
        rows.append((config, runs))
    print(f"\nserver's CPU time and demand (runnable threads), % of one core; mean [min–max] over {args.repeats} "
          f"starts, {args.seconds:.0f} s each; {args.rrd.name}, {args.rrd.stat().st_size / 1e6:.0f} MB; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n")
    print("\n".join(table(rows, not args.no_browser)))

if __name__ == "__main__":
    main()
