"""The real Rerun viewer: headless snapshots of every view, the web viewer, and their error paths."""

from __future__ import annotations

import contextlib
import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import rerun as rr
from cli_helpers import need_vulkan, vslam, vslam_here
from rerun.chunk import RrdReader

from vslam.recording.layout import CAR_ENTITY
from vslam.rrd.read import blueprint_view_names, read_entity
from vslam.viewer import headless as snapshots
from vslam.viewer import processes as viewer
from vslam.viewer import web
from vslam.viewer.headless import DEFAULT_SIZE, snapshot
from vslam.viewer.processes import NO_VULKAN, ViewerError, choose_viewer, vulkan_icd_files
from vslam.viewer.web import open_recording
from vslam_core.errors import VslamError

ROOT = Path(__file__).resolve().parents[1]
FRAME = 10
#: The window of the all-views snapshot: a quarter of DEFAULT_SIZE's pixels, at its 16:9 (the viewer renders in
#: software here: ~8 instead of ~19 CPU-s for the 22 pictures). The 3-D view's checks count pixels of thin lines and
#: points, so they read it at the default size (`last_frame`).
SHOT_SIZE = (640, 360)
#: The views of vslam.recording.layout() for a run with ground truth and --scale gt, in reading order.
VIEWS = ["frame", "overlays", "world", "drive", "position_error_m", "rotation_per_frame", "step_length",
         "ransac_inliers", "tracks", "inliers", "inlier_ratio", "health", "motion", "angle_errors",
         "ground_truth_vs_the_images", "drift_per_frame_m", "drift_per_frame_of_step_scale_ratio", "timing_ms",
         "events", "summary", "report"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rrd = tmp_path_factory.mktemp("viewer") / "s.rrd"
    # VIEWS: the vo layout; full detail: the 3-D view's triangulated points (not in the default, standard)
    result = vslam("run", "--frames", "0:15", "--backend", "vo", "--detail", "full", "-o", rrd)
    assert result.returncode == 0, result.stderr
    return rrd


@pytest.fixture(scope="module")
def vulkan() -> None:
    """Skip without a Vulkan adapter, except when CI is set: there the snapshot tests must run."""
    need_vulkan()


class _Spy:
    """Records every process vslam.viewer.processes starts, to check that none survives."""

    def __init__(self) -> None:
        self.started: list[tuple[list[str], viewer._Process]] = []
        self._start = viewer._start

    def __call__(self, args: list[str], env: dict[str, str] | None = None) -> viewer._Process:
        process = self._start(args, env)
        self.started.append((list(args), process))
        return process

    def assert_all_gone(self) -> None:
        assert self.started
        for args, process in self.started:
            assert process.popen.poll() is not None
            with pytest.raises(ProcessLookupError):
                os.killpg(process.popen.pid, 0)  # nothing left in the viewer's process group
            for flag in ("--port", "--web-viewer-port"):
                if flag in args:
                    assert _refused(int(args[args.index(flag) + 1]))


def _refused(port: int) -> bool:
    with socket.socket() as sock:
        return sock.connect_ex(("127.0.0.1", port)) != 0


@pytest.fixture(scope="module")
def snapshot_command(recording: Path, vulkan: None,
                     tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    """`vslam snapshot RECORDING --frame FRAME --size SHOT_SIZE --out DIR` in this process, every viewer process it
    started checked gone: one viewer start shared by the tests of the pictures and of the command."""
    out = tmp_path_factory.mktemp("shots") / "shots"
    spy = _Spy()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(viewer, "_start", spy)
        started = time.monotonic()
        result = vslam("snapshot", recording, "--frame", str(FRAME), "--size", "x".join(map(str, SHOT_SIZE)),
                       "--out", out)
        print(f"snapshot took {time.monotonic() - started:.1f} s")
    spy.assert_all_gone()
    return result, out


@pytest.fixture(scope="module")
def shots(snapshot_command: tuple[subprocess.CompletedProcess[str], Path]) -> dict[str, Path]:
    result, _ = snapshot_command
    assert result.returncode == 0, result.stderr
    return {Path(line).stem: Path(line) for line in result.stdout.split()}


def _recorded_frame(rrd: Path, frame: int) -> np.ndarray:
    images = read_entity(rrd, "/world/camera/image").filter(frame=frame)
    jpeg = np.asarray(images["EncodedImage:blob"][0][0].to_list(), dtype=np.uint8)
    return cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE)


def _colourful(picture: np.ndarray) -> float:
    """Share of pixels that are clearly not grey (overlays, plot lines)."""
    return float(((picture.max(axis=2).astype(int) - picture.min(axis=2)) > 60).mean())


def test_snapshot_writes_one_png_per_view(shots: dict[str, Path]) -> None:
    assert sorted(shots) == sorted([*VIEWS, "all"])
    for name, path in shots.items():
        picture = cv2.imread(str(path))
        assert picture is not None, path
        assert min(picture.shape[:2]) > 100, (name, picture.shape)
        if name != "all":  # each view maximised in the window: readable, whatever its share of the layout
            assert picture.shape[1] >= 0.95 * SHOT_SIZE[0] and picture.shape[0] >= 0.6 * SHOT_SIZE[1], (
                name, picture.shape)
        assert picture.std() > 8, f"{name}.png looks blank"
    # the whole layout without the viewer's top bar (menu, "Software rasterizer" / "Docker" banners: orange text)
    whole = cv2.imread(str(shots["all"])).astype(int)
    assert whole.shape[:2] == (SHOT_SIZE[1], SHOT_SIZE[0])
    top = whole[:40]
    banner = (top[..., 2] > 200) & (top[..., 1] > 100) & (top[..., 1] < 180) & (top[..., 0] < 80)
    assert banner.sum() < 20, "all.png shows the viewer's banners"
    assert _colourful(cv2.imread(str(shots["frame"]))) > 0.005, "frame.png shows no overlays"
    for name in ("tracks", "inliers", "inlier_ratio", "motion", "position_error_m", "angle_errors", "timing_ms"):
        picture = cv2.imread(str(shots[name]))  # a plot line crosses most pixel columns
        coloured = (picture.max(axis=2).astype(int) - picture.min(axis=2)) > 60
        assert coloured.any(axis=0).mean() > 0.3, f"{name}.png shows no coloured data"


@pytest.fixture(scope="module")
def last_frame(recording: Path, vulkan: None,
               tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    """`vslam snapshot RECORDING --frame last --view Frame --view world --view all` at the default size."""
    out = tmp_path_factory.mktemp("last") / "last"
    return vslam("snapshot", recording, "--frame", "last", "--out", out,  # the default size
                 "--view", "Frame", "--view", "world", "--view", "all"), out  # a view by its name or file name


def test_world_view_shows_the_points_and_both_trajectories(
        last_frame: tuple[subprocess.CompletedProcess[str], Path]) -> None:
    result, out = last_frame
    assert result.returncode == 0, result.stderr
    # the 3-D view shows the triangulated points: many separate bright dots over the dark grid
    world = cv2.imread(str(out / "world.png"), cv2.IMREAD_GRAYSCALE)
    dots, _ = cv2.connectedComponents((world > 120).astype(np.uint8))
    assert dots > 100, "world.png shows no points"
    # and both trajectories: the estimate in red (255, 80, 80), the ground truth in blue (70, 130, 255), a colour
    # no error colour map uses
    bgr = cv2.imread(str(out / "world.png")).astype(int)
    red = (bgr[..., 2] > 180) & (bgr[..., 1] < 130) & (bgr[..., 0] < 130)
    blue = (bgr[..., 0] > 200) & (bgr[..., 2] < 120) & (bgr[..., 1] > 90) & (bgr[..., 1] < 180)
    assert red.sum() > 30, "world.png shows no estimated trajectory"
    assert blue.sum() > 30, "world.png shows no ground-truth trajectory"


def test_frame_view_shows_the_recorded_image_at_the_requested_frame(shots: dict[str, Path], recording: Path) -> None:
    picture = cv2.imread(str(shots["frame"]))
    grey_pixels = (picture.max(axis=2).astype(int) - picture.min(axis=2)) < 12  # not an overlay
    shown = cv2.cvtColor(picture, cv2.COLOR_BGR2GRAY)
    assert len(np.unique(shown)) > 100 and _colourful(picture) > 0.01  # a photo, with overlays on top

    def correlation(frame: int) -> float:
        image = _recorded_frame(recording, frame)
        # the 2-D view fits the image into the view, centred
        scale = min(shown.shape[1] / image.shape[1], shown.shape[0] / image.shape[0])
        w, h = round(image.shape[1] * scale), round(image.shape[0] * scale)
        x0, y0 = (shown.shape[1] - w) // 2, (shown.shape[0] - h) // 2
        crop, mask = shown[y0:y0 + h, x0:x0 + w], grey_pixels[y0:y0 + h, x0:x0 + w]
        expected = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
        return float(np.corrcoef(crop[mask].astype(float), expected[mask].astype(float))[0, 1])

    at_frame = correlation(FRAME)
    assert at_frame > 0.6
    assert at_frame > max(correlation(0), correlation(14)) + 0.15  # the time cursor is at FRAME


@pytest.mark.parametrize(
    ("content", "fragment"),
    [(None, "no such recording"), (b"not a recording\n", "not a readable Rerun recording"),
     ("truncated", "cut short before any of its recording data was written")],  # cut short in its header
)
def test_bad_files_are_one_line_errors_naming_the_file(
    content: bytes | str | None, fragment: str, recording: Path, tmp_path: Path
) -> None:
    bad = tmp_path / "bad.rrd"
    if content == "truncated":
        bad.write_bytes(recording.read_bytes()[:1000])  # a longer cut is read up to the cut (test_outputs)
    elif isinstance(content, bytes):
        bad.write_bytes(content)
    for call in (lambda: snapshot(bad, 0, tmp_path / "out"), lambda: open_recording(bad, web=True)):
        with pytest.raises(ViewerError) as info:
            call()
        message = str(info.value)
        assert str(bad) in message and fragment in message and "\n" not in message
    assert not (tmp_path / "out").exists()


def test_frame_outside_the_recording_names_the_range(recording: Path, tmp_path: Path) -> None:
    for frame in (15, -1):
        with pytest.raises(ViewerError, match=r"frame -?\d+ is outside the recording's frames 0\.\.14"):
            snapshot(recording, frame, tmp_path)


def test_missing_vulkan_is_reported_before_starting_the_viewer(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(viewer, "vulkan_available", lambda env=None: False)
    monkeypatch.setattr(viewer, "_start", lambda *_: pytest.fail("no viewer must be started"))
    with pytest.raises(VslamError) as info:
        snapshot(recording, FRAME, tmp_path)
    assert str(info.value) == NO_VULKAN
    assert "apt-get install -y mesa-vulkan-drivers libvulkan1" in str(info.value)


def test_viewer_without_an_adapter_is_reported_and_cleaned_up(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The real viewer with no Vulkan driver to load (runs with or without mesa-vulkan-drivers)."""
    monkeypatch.setattr(viewer, "vulkan_available", lambda env=None: True)  # get past the cheap check
    monkeypatch.setenv("VK_DRIVER_FILES", str(tmp_path / "none.json"))
    monkeypatch.setenv("VK_ICD_FILENAMES", str(tmp_path / "none.json"))
    monkeypatch.delenv("WGPU_BACKEND", raising=False)
    spy = _Spy()
    monkeypatch.setattr(viewer, "_start", spy)
    with pytest.raises(ViewerError) as info:
        snapshot(recording, FRAME, tmp_path, timeout_s=60)
    assert str(info.value) == NO_VULKAN
    spy.assert_all_gone()


def test_vulkan_detection_honours_the_loader_environment(tmp_path: Path) -> None:
    manifest = tmp_path / "icd.json"
    manifest.write_text("{}")
    assert vulkan_icd_files({"VK_DRIVER_FILES": str(manifest)}) == [manifest]
    assert vulkan_icd_files({"VK_ICD_FILENAMES": str(tmp_path / "missing.json")}) == []
    assert not viewer.vulkan_available({"VK_DRIVER_FILES": str(tmp_path / "missing.json")})


def test_viewer_failure_after_start_still_stops_it(
    recording: Path, vulkan: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*_: object) -> None:
        raise RuntimeError("lost the viewer\nsecond line")

    spy = _Spy()
    monkeypatch.setattr(viewer, "_start", spy)
    monkeypatch.setattr(snapshots, "_settled_screenshots", broken)
    with pytest.raises(ViewerError, match="the Rerun viewer failed: lost the viewer$"):
        snapshot(recording, FRAME, tmp_path)
    spy.assert_all_gone()


def test_terminated_snapshot_stops_the_viewer_first(recording: Path, vulkan: None, tmp_path: Path) -> None:
    code = ("import sys; from pathlib import Path; from vslam.viewer import headless as snapshot, processes as viewer\n"
            "start = viewer._start\n"
            "def spy(args, env=None):\n"
            "    process = start(args, env)\n"
            "    print(process.popen.pid, flush=True)\n"
            "    return process\n"
            "viewer._start = spy\n"
            "snapshot.snapshot(Path(sys.argv[1]), 10, Path(sys.argv[2]))\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(recording), str(tmp_path)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        viewer_pid = int(proc.stdout.readline())
        time.sleep(1.0)  # connected, opening the recording
        proc.terminate()
        _, stderr = proc.communicate(timeout=20)
        assert proc.returncode == -signal.SIGTERM, stderr
        with pytest.raises(ProcessLookupError):
            os.killpg(viewer_pid, 0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_choose_viewer() -> None:
    assert choose_viewer({"DISPLAY": ":0"}, web=False) == "native"
    assert choose_viewer({"WAYLAND_DISPLAY": "wayland-0"}, web=False) == "native"
    assert choose_viewer({"DISPLAY": ":0"}, web=True) == "web"
    assert choose_viewer({}, web=False) == "web"
    assert choose_viewer({"DISPLAY": ""}, web=False) == "web"


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_web_viewer_serves_on_loopback_until_stopped(recording: Path, stop: signal.Signals) -> None:
    port = viewer.free_port()
    code = ("import signal, sys; from vslam.cli import main; "
            "signal.signal(signal.SIGINT, signal.default_int_handler); "  # as in a terminal, even under CI
            "sys.argv = ['vslam', 'open', sys.argv[1], '--web', '--web-port', sys.argv[2]]; main()")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen([sys.executable, "-c", code, str(recording), str(port)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        url = _wait_for_url(proc, timeout_s=30)
        assert url.startswith(f"http://127.0.0.1:{port}/")
        with urllib.request.urlopen(url, timeout=10) as response:
            assert response.status == 200
            assert b"<html" in response.read().lower()
        grpc = re.search(r"url=rerun\+http://127\.0\.0\.1:(\d+)/proxy$", urllib.parse.unquote(url))
        assert grpc is not None, url
        grpc_port = int(grpc.group(1))
        proc.send_signal(stop)
        _, stderr = proc.communicate(timeout=20)
        # Ctrl-C: exit 130 like `vslam run` (issue 24); SIGTERM: the server is stopped, then the process ends by
        # the signal as usual
        assert proc.returncode == (130 if stop == signal.SIGINT else -signal.SIGTERM), stderr
        assert "Traceback" not in stderr
        assert stop != signal.SIGINT or "viewer stopped" in stderr
        assert _refused(port) and _refused(grpc_port)  # the server went with it
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_web_server_dies_with_a_killed_open(recording: Path) -> None:
    """SIGKILL leaves `open --web` no time to stop its server, which runs in a session of its own; the server is
    started with PR_SET_PDEATHSIG, so the kernel kills it too (before, it outlived `open`, its stdin at its end,
    and spun a core: see vslam.viewer.web)."""
    code = "import sys; from vslam.cli import main; sys.argv = ['vslam', 'open', sys.argv[1], '--web']; main()"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen([sys.executable, "-c", code, str(recording)], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    servers: list[int] = []
    try:
        _wait_for_url(proc, timeout_s=30)
        servers = _children(proc.pid)
        assert len(servers) == 1, servers  # the Rerun server, and nothing else
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 5
        while _alive(servers[0]) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(servers[0]), "the web server outlived the killed `vslam open --web`"
    finally:
        proc.kill()
        proc.communicate()
        for pid in servers:  # the old behaviour: clean up what the test found
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)


def _children(pid: int) -> list[int]:
    """Pids of the processes whose parent is `pid` (from /proc/*/stat)."""
    children = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[1]) == pid:
                children.append(int(stat.parent.name))
    return children


def _alive(pid: int) -> bool:
    """True while `pid` exists and is not a zombie (a reaper may take a moment to collect it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _wait_for_url(proc: subprocess.Popen[str], timeout_s: float) -> str:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                break
            if match := re.search(r"http://\S+", line):
                return match.group(0)
    stderr = proc.stderr.read() if proc.poll() is not None and proc.stderr else ""
    pytest.fail(f"no URL printed by the web viewer within {timeout_s} s: {stderr}")


def test_web_viewer_port_in_use_is_a_clear_error(recording: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(ViewerError, match=f"port {port} on 127.0.0.1: already in use"):
            open_recording(recording, web=True, web_port=port)


def test_web_server_sleeps_once_the_recording_is_in(recording: Path) -> None:
    """`open --web` writes the recording to the server's stdin and holds the pipe open, so once it is in, every
    thread of the server sleeps. (Given the file's path, or a pipe that ends, the 0.41 server's ingest loop polls
    its finished source: one thread stays runnable as long as the server runs, up to a whole core.)"""
    with web.serve_web(recording) as (_, _, _, process):
        assert process.popen.args[-1] == web.STDIN  # type: ignore[index]
        assert process.fed.wait(30), "the recording was not written to the server's stdin in 30 s"
        deadline, running = time.monotonic() + 30, _running_threads(process.popen.pid)
        while running and time.monotonic() < deadline:
            time.sleep(0.2)
            running = _running_threads(process.popen.pid)
        assert not running, f"server threads still runnable 30 s after the recording was in: {running}"
        assert process.popen.poll() is None


def _running_threads(pid: int) -> list[str]:
    """Names of the threads of `pid` that are running or runnable now (state R in /proc/PID/task/*/stat)."""
    names = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:  # the thread ended
            continue
        name_end = stat.rindex(")")
        if stat[name_end + 2] == "R":
            names.append(stat[stat.index("(") + 1:name_end])
    return names


def test_snapshot_command_writes_pngs_and_errors_in_one_line(
        recording: Path, snapshot_command: tuple[subprocess.CompletedProcess[str], Path]) -> None:
    result, out = snapshot_command
    assert result.returncode == 0, result.stderr
    written = {Path(line).name for line in result.stdout.split()}
    assert {"frame.png", "world.png", "all.png"} <= written
    assert all((out / name).is_file() for name in written)
    result = vslam("snapshot", recording, "--frame", "99", "--out", out)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "outside the recording's frames 0..14" in result.stderr


# ------------------------------------------------------------------------- layout: issue 12, items 14–15


def _blueprint(rrd: Path) -> dict[str, dict[str, Any]]:
    """The blueprint embedded in a recording, read back without a viewer: {entity: {component: value}}."""
    reader = RrdReader(rrd)
    rows: dict[str, dict[str, Any]] = {}
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" not in name:
                continue
            try:
                value = batch.column(name).to_pylist()[-1]
            except Exception:  # union-typed components (time ranges): not needed here
                continue
            if isinstance(value, list) and len(value) == 1:
                value = value[0]
            rows.setdefault(str(chunk.entity_path), {})[name] = value
    return rows


def _view_names(rows: dict[str, dict[str, Any]]) -> set[str]:
    return {r["ViewBlueprint:display_name"] for r in rows.values() if "ViewBlueprint:display_name" in r}


@pytest.mark.parametrize(
    ("args", "present", "absent"),
    [([], {"frame", "position error (m)"}, {"scale from the road"}),
     (["--detail", "summary"], {"world", "events"}, {"frame", "scale from the road"}),
     (["--scale", "height"], {"frame", "scale from the road"}, set())],
    ids=["full-gt", "summary", "height"],
)
def test_views_without_data_are_left_out_of_the_blueprint(
    args: list[str], present: set[str], absent: set[str], tmp_path: Path
) -> None:
    rrd = tmp_path / "r.rrd"
    result = vslam("run", "--frames", "0:3", "-o", rrd, *args)
    assert result.returncode == 0, result.stderr
    names = _view_names(_blueprint(rrd))
    assert present <= names and not absent & names, names


def test_blueprint_follows_the_car_on_the_frame_timeline_with_whole_events(recording: Path) -> None:
    rows = _blueprint(recording)
    eye = next(r for r in rows.values() if "EyeControls3D:tracking_entity" in r)
    # the tracked entity must have something drawn (a bounding box): /world/camera (a transform only) had not,
    # and the view showed the whole trajectory with the car as a speck
    assert eye["EyeControls3D:tracking_entity"] == CAR_ENTITY
    assert "Boxes3D:half_sizes" in read_entity(recording, CAR_ENTITY, static=True).columns
    distance = np.linalg.norm(np.subtract(eye["EyeControls3D:position"], eye["EyeControls3D:look_target"]))
    assert 10 < distance < 60  # metres behind and above the car
    assert rows["/time_panel"]["TimePanelBlueprint:timeline"] == "frame"
    key = "TextLogColumns:text_log_columns"
    columns = next(r[key] for r in rows.values() if key in r)
    assert {"visible": False, "kind": 1} in columns  # no entity-path column: the body gets the room


def test_world_view_shows_the_car_large_near_the_centre(
        last_frame: tuple[subprocess.CompletedProcess[str], Path]) -> None:
    world = cv2.imread(str(last_frame[1] / "world.png"))
    h, w = world.shape[:2]
    centre = world[h // 4: 3 * h // 4, w // 4: 3 * w // 4]
    car = (np.abs(centre.astype(int) - 230).max(axis=2) <= 20)  # the light-grey wireframe box
    ys, xs = np.nonzero(car)
    assert len(xs) > 50, "no car near the centre of world.png"
    assert xs.max() - xs.min() > 0.03 * w, "the car is a speck"


def test_snapshot_cli_last_frame_and_size(recording: Path, last_frame: tuple[subprocess.CompletedProcess[str], Path],
                                          tmp_path: Path) -> None:
    result, out = last_frame
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["all.png", "frame.png", "world.png"]  # only the views asked for
    assert result.stdout.split() == [str(out / "frame.png"), str(out / "world.png"), str(out / "all.png")]
    assert cv2.imread(str(out / "all.png")).shape[:2] == (DEFAULT_SIZE[1], DEFAULT_SIZE[0])
    shown = cv2.cvtColor(cv2.imread(str(out / "frame.png")), cv2.COLOR_BGR2GRAY)
    assert shown.shape[1] >= 0.95 * DEFAULT_SIZE[0]

    def similarity(frame: int) -> float:
        image = cv2.resize(_recorded_frame(recording, frame), (shown.shape[1], shown.shape[0]))
        return float(np.corrcoef(shown.ravel().astype(float), image.ravel().astype(float))[0, 1])

    assert similarity(14) > similarity(0)  # the last frame of 0:15
    for args, fragment in ((["--frame", "lastt"], "--frame 'lastt': give a frame index or 'last'"),
                           (["--frame", "3", "--size", "10x10"], "--size '10x10': the window must be"),
                           (["--frame", "3", "--size", "big"], "--size 'big': give WIDTHxHEIGHT")):
        bad = vslam_here("snapshot", recording, "--out", out, *args)
        assert bad.returncode == 2 and fragment in bad.stderr and "Traceback" not in bad.stderr, bad.stderr
        assert len(bad.stderr.strip().splitlines()) == 1
    with pytest.MonkeyPatch.context() as mp:  # refused from the embedded blueprint, before any viewer starts
        mp.setattr(viewer, "headless_viewer", _no_viewer)
        unknown = vslam_here("snapshot", recording, "--frame", "3", "--size", "320x240", "--view", "nope", "--out",
                             tmp_path / "none")
    assert unknown.returncode == 2 and "Traceback" not in unknown.stderr, unknown.stderr
    assert unknown.stderr.startswith(f"error: {recording}: no view nope in the recording's blueprint (its views: "
                                     "all, "), unknown.stderr
    assert "frame" in unknown.stderr and len(unknown.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "none").exists()  # no empty folder left


def _no_viewer(*_args: object) -> None:
    raise AssertionError("a viewer was started")


def test_the_blueprint_read_without_a_viewer_names_the_views_the_viewer_shows(
    recording: Path, shots: dict[str, Path], tmp_path: Path
) -> None:
    names = blueprint_view_names(recording)
    assert names is not None
    assert sorted([*(snapshots.view_file_name(name) for name in names), "all"]) == sorted(shots)
    bare = tmp_path / "bare.rrd"  # no blueprint: the views are known only once a viewer shows them
    stream = rr.RecordingStream("bare")
    stream.save(bare)
    stream.log("/points", rr.Points3D([[0.0, 0.0, 1.0]]))
    stream.flush()
    stream.disconnect()
    assert blueprint_view_names(bare) is None


class _FakeViewer:
    """Screenshots from a list (the last one repeated, or the list over and over when `cycle`), and a viewer
    state that is loading for the first `loading` calls."""

    def __init__(self, shots: list[bytes], loading: int = 0, cycle: bool = False) -> None:
        self.shots, self.loading, self.cycle, self.taken = shots, loading, cycle, 0

    def take_screenshot(self, _view_id: str | None) -> bytes:
        self.taken += 1
        k = self.taken - 1
        return self.shots[k % len(self.shots) if self.cycle else min(k, len(self.shots) - 1)]

    def get_state(self) -> Any:
        self.loading -= 1
        return type("State", (), {"loading": ["chunk"] if self.loading >= 0 else []})()


def _png(changed: int, size: tuple[int, int] = (240, 320)) -> bytes:
    image = np.zeros((*size, 3), np.uint8)
    image.reshape(-1, 3)[:changed] = 255
    return cv2.imencode(".png", image)[1].tobytes()


def test_a_picture_is_settled_when_it_stops_changing_or_only_flickers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Identical shots with nothing loading settle at once; a picture changing in 150 of 76800 pixels for good
    (egui's plots oscillating at 320x240) is taken after FLICKER_S with a warning; one changing in 5 % of its
    pixels never settles (the time-out's one-line error)."""
    monkeypatch.setattr(snapshots, "SETTLE_S", 0.0)
    monkeypatch.setattr(snapshots, "FLICKER_S", 0.05)
    settled = _FakeViewer([_png(0), _png(500), _png(500)], loading=1)
    assert snapshots._settled(settled, None, Path("r.rrd"), time.monotonic() + 5) == _png(500)  # type: ignore[arg-type]
    flicker = _FakeViewer([_png(0), _png(150)], cycle=True)
    started = time.monotonic()
    shot = snapshots._settled(flicker, "view", Path("r.rrd"), time.monotonic() + 5)  # type: ignore[arg-type]
    assert shot in (_png(0), _png(150)) and 0.05 <= time.monotonic() - started < 5
    moving = _FakeViewer([_png(0), _png(3840)], cycle=True)
    with pytest.raises(ViewerError, match="did not settle before the time-out"):
        snapshots._settled(moving, "view", Path("r.rrd"), time.monotonic() + 0.3)  # type: ignore[arg-type]
    assert snapshots.changed_share(_png(768), _png(0)) == pytest.approx(0.01)
    assert snapshots.changed_share(_png(0), _png(0, (10, 10))) == 1.0


def test_parse_size_and_frame() -> None:
    assert snapshots.parse_size("1280x720") == (1280, 720)
    assert snapshots.parse_size(" 800 X 600 ") == (800, 600)
    assert snapshots.parse_frame("last") == "last" and snapshots.parse_frame("12") == 12
    with pytest.raises(ViewerError, match="the window must be 320x240 to 7680x4320 pixels"):
        snapshots.parse_size("8000x8000")


@pytest.mark.parametrize(
    ("args", "fragment"),
    [(["--grpc-port", "70000"], "--grpc-port 70000: give a TCP port in 1..65535"),
     (["--web-port", "0"], "--web-port 0: give a TCP port in 1..65535"),
     (["--port", "-5"], "--web-port -5: give a TCP port in 1..65535"),
     (["--web-port", "40000", "--grpc-port", "40000"], "--web-port and --grpc-port are both 40000")],
)
def test_open_web_bad_ports_are_one_line_errors(recording: Path, args: list[str], fragment: str) -> None:
    result = vslam_here("open", recording, "--web", *args)
    assert result.returncode == 2 and fragment in result.stderr and "Traceback" not in result.stderr, result.stderr


def test_connections_to_counts_established_clients() -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        assert web.connections_to(port) == 0
        with socket.create_connection(("127.0.0.1", port)):
            accepted, _ = server.accept()
            with accepted:
                assert web.connections_to(port) == 1


def test_web_viewer_fixed_ports_browser_watch_and_frame_timeline(recording: Path, vulkan: None) -> None:
    web_port, grpc_port = viewer.free_port(), viewer.free_port()
    code = ("import sys; from pathlib import Path; from vslam.viewer.web import open_recording; "
            "open_recording(Path(sys.argv[1]), web=True, web_port=int(sys.argv[2]), grpc_port=int(sys.argv[3]), "
            "browser_wait_s=1)")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.Popen([sys.executable, "-c", code, str(recording), str(web_port), str(grpc_port)], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        url = _wait_for_url(proc, timeout_s=30)
        assert url == web.web_viewer_url(web_port, grpc_port)
        lines = _lines_until(proc, "no browser connected yet", timeout_s=20)
        assert any(f"-L {web_port}:127.0.0.1:{web_port} -L {grpc_port}:127.0.0.1:{grpc_port}" in line
                   for line in lines), lines
        assert lines[-1] == f"no browser connected yet: open {url}"
        # a real viewer connects to the gRPC server, as the browser's page does, and lands on `frame`
        with viewer.headless_viewer(time.monotonic() + 120, (640, 480)) as (_, client):
            client.open(f"rerun+http://127.0.0.1:{grpc_port}/proxy")
            assert _lines_until(proc, "browser connected", timeout_s=30)[-1].startswith("browser connected")
            deadline = time.monotonic() + 60
            while not (recordings := client.get_state().recordings) and time.monotonic() < deadline:
                time.sleep(0.2)
            assert recordings and recordings[0].current_timeline == "frame", recordings
            # the layout embedded in the file arrives too (the server reads the recording from its stdin)
            while not (views := client.get_state().views) and time.monotonic() < deadline:
                time.sleep(0.2)
            assert sorted(snapshots.view_file_name(v.name) for v in views) == sorted(VIEWS)
        proc.terminate()
        proc.communicate(timeout=20)
        assert _refused(web_port) and _refused(grpc_port)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _lines_until(proc: subprocess.Popen[str], fragment: str, timeout_s: float) -> list[str]:
    """Lines printed by `proc` up to and including the first holding `fragment`."""
    assert proc.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline().rstrip("\n")
            lines.append(line)
            if fragment in line:
                return lines
    pytest.fail(f"{fragment!r} not printed within {timeout_s} s: {lines}")


def test_ports_with_the_native_viewer_are_refused(recording: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DISPLAY", ":99")
    with pytest.raises(ViewerError, match="--web-port and --grpc-port set the web viewer's ports.*add --web"):
        open_recording(recording, web=False, web_port=9090)


def test_ctrl_c_in_snapshot_says_so_and_leaves_no_empty_folder(recording: Path, vulkan: None,
                                                               tmp_path: Path) -> None:
    """Issue 24, item 14: Ctrl-C while the viewer renders: one line, exit 130, no folder left behind."""
    out = tmp_path / "shots"
    code = ("import signal, sys; from vslam.cli import main; "
            "signal.signal(signal.SIGINT, signal.default_int_handler); "
            "sys.argv = ['vslam', 'snapshot', sys.argv[1], '--frame', '10', '--out', sys.argv[2]]; main()")
    proc = subprocess.Popen([sys.executable, "-c", code, str(recording), str(out)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)  # the folder is made once the recording was checked: the viewer starts next
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 130, stderr
        assert f"error: snapshot interrupted: no picture written to {out}" in stderr and "Traceback" not in stderr
        assert not out.exists()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
