"""`vslam snapshot`: PNG pictures of every view of a recording at one frame, from the real viewer, headless.

The viewer binary runs headless (software Vulkan is enough: Debian ``mesa-vulkan-drivers``) in a window of
`--size`, driven over gRPC with `rerun.experimental.ViewerClient` (`vslam.viewer.processes` starts and stops it). The
whole layout is screenshotted once the pictures stop changing (``all.png``); then each view of the
recording's blueprint is maximised in turn (the blueprint's ``maximized`` view) and screenshotted on its own,
so every view's PNG is about as large as the window, whatever its share of the layout.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import re
import shutil
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rerun.experimental import View, ViewerClient, ViewerState

from vslam.common import RecordingError, first_line
from vslam.rrd import blueprint_view_names
from vslam.viewer import processes as viewer
from vslam.viewer.processes import NO_VULKAN, ViewerError

log = logging.getLogger("vslam.viewer.processes.snapshot")  # a child of processes' logger: its handlers see it

#: Default logical size of the headless viewer window: each view's PNG is about this large.
DEFAULT_SIZE = (1280, 720)
#: Smallest and largest window accepted by `--size` (the viewer's chrome needs room; memory bounds the rest).
MIN_SIZE, MAX_SIZE = (320, 240), (7680, 4320)
#: Name of the whole-window screenshot written beside the per-view ones.
WHOLE_WINDOW = "all"
#: `--frame` value for the recording's last frame.
LAST = "last"


def parse_size(text: str) -> tuple[int, int]:
    """`1280x720` -> (1280, 720); `ViewerError` (one line) for anything else or outside MIN_SIZE..MAX_SIZE."""
    match = re.fullmatch(r"\s*(\d{1,5})\s*[xX×]\s*(\d{1,5})\s*", text)
    if match is None:
        raise ViewerError(f"--size {text!r}: give WIDTHxHEIGHT in pixels, e.g. 1280x720")
    width, height = int(match.group(1)), int(match.group(2))
    if not (MIN_SIZE[0] <= width <= MAX_SIZE[0] and MIN_SIZE[1] <= height <= MAX_SIZE[1]):
        raise ViewerError(f"--size {text!r}: the window must be {MIN_SIZE[0]}x{MIN_SIZE[1]} to "
                          f"{MAX_SIZE[0]}x{MAX_SIZE[1]} pixels")
    return width, height


def parse_frame(text: str) -> int | str:
    """`--frame`: a frame index, or `last`; `ViewerError` (one line) otherwise."""
    if text.strip().lower() == LAST:
        return LAST
    try:
        return int(text)
    except ValueError:
        raise ViewerError(f"--frame {text!r}: give a frame index or 'last'") from None


def resolve_frame(rrd: Path, frame: int | str) -> int:
    """The frame to show: `frame` itself, or the recording's last one for `last`; `ViewerError` naming the
    recording's range when it is outside it."""
    first, last = viewer.recording_frames(rrd)
    if frame == LAST:
        return last
    assert isinstance(frame, int)
    if not first <= frame <= last:
        raise ViewerError(f"{rrd}: frame {frame} is outside the recording's frames {first}..{last}")
    return frame


def view_file_name(name: str) -> str:
    """`error vs ground truth` -> `error_vs_ground_truth` (a file name without extension)."""
    slug = re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_").lower()
    return slug or "view"


def snapshot(
    rrd: Path,
    frame: int | str,
    out_dir: Path,
    timeout_s: float = 300,
    *,
    window_size: tuple[int, int] = DEFAULT_SIZE,
    only: Sequence[str] = (),
) -> list[Path]:
    """Open `rrd` in the headless Rerun viewer at `frame` (an index or `last`, paused) and save one PNG per view.

    The views are those of the recording's embedded blueprint; each PNG is named after its view
    (``frame.png``, ``world.png``, ``events.png``…) and shows that view maximised in a window of
    `window_size`, plus ``all.png`` of the whole layout, in the layout's reading order.
    `only` names the pictures to take instead (a view's name or its file name, ``all`` for the whole layout):
    each view costs the viewer a render of its own, so a CI job that needs one picture asks for that one.

    Raises `ViewerError` (one line) for a missing/bad file, a frame outside the recording, no Vulkan
    adapter, or a viewer that fails or does not settle within `timeout_s`.
    """
    index = resolve_frame(rrd, frame)
    if only and (view_names := _blueprint_views(rrd)) is not None:
        check_view_names(view_names, only, rrd)  # before the viewer starts (~3 s); else once it shows the views
    if problem := video_decoding_problem(rrd):
        raise ViewerError(problem)
    if not viewer.vulkan_available():
        raise ViewerError(NO_VULKAN)
    created = not out_dir.exists()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ViewerError(f"{out_dir}: cannot create output folder ({exc.strerror})") from None
    try:
        return _snapshot(rrd, index, out_dir, timeout_s, window_size, only)
    except BaseException:  # Ctrl-C or a failure: no empty folder left behind
        if created:
            with contextlib.suppress(OSError):
                out_dir.rmdir()  # only when empty
        raise


def _snapshot(rrd: Path, index: int, out_dir: Path, timeout_s: float, window_size: tuple[int, int],
              only: Sequence[str]) -> list[Path]:
    started = time.monotonic()
    deadline = started + timeout_s
    # the window is taller by the top bar, which the whole-layout picture leaves out: all.png is `window_size`
    window = (window_size[0], window_size[1] + TOP_BAR_ROWS)
    with viewer.stop_viewer_on_sigterm(), viewer.headless_viewer(deadline, window) as (process, client):
        try:
            shots = _settled_screenshots(client, rrd, index, deadline, only, window_size[1])
        except ViewerError:
            raise
        except Exception as exc:
            if process.popen.poll() is not None:
                raise ViewerError(process.failure()) from None
            raise ViewerError(f"{rrd}: the Rerun viewer failed: {first_line(exc)}") from None
    written = _write_pictures(shots, out_dir)
    log.info("snapshot of %s at frame %d: %d pictures in %.1f s", rrd, index, len(written),
             time.monotonic() - started)
    return written


def _blueprint_views(rrd: Path) -> list[str] | None:
    """The names of the views of the recording's embedded blueprint, read without the viewer; None when they
    cannot be known before the viewer shows them (no blueprint, an unnamed view, a blueprint not readable)."""
    try:
        return blueprint_view_names(rrd)
    except RecordingError:
        return None


def video_decoding_problem(rrd: Path) -> str | None:
    """Why the native viewer cannot show this recording's video frames (one line), or None. It decodes AV1
    itself but needs an `ffmpeg` executable on PATH for H.264 (the web viewer decodes both)."""
    from vslam.common import RecordingError
    from vslam.recording import ImageCodec
    from vslam.rrd import open_store, video_codecs

    try:
        reader, recording, _ = open_store(rrd)
        codecs = set(video_codecs(reader, recording).values())
    except RecordingError:
        return None  # resolve_frame reads the file first and reports a bad one
    if ImageCodec.H264 in codecs and shutil.which("ffmpeg") is None:
        return (f"{rrd}: its camera frames are H.264 video, which the native viewer decodes with ffmpeg: install "
                "ffmpeg on PATH (e.g. apt-get install ffmpeg), or use the web viewer")
    return None


def _write_pictures(shots: list[tuple[str, bytes]], out_dir: Path) -> list[Path]:
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
    return written


def _settled_screenshots(
    client: ViewerClient, rrd: Path, frame: int, deadline: float, only: Sequence[str], height: int
) -> list[tuple[str, bytes]]:
    opened = client.open(str(viewer.viewable(rrd).resolve()))
    if not opened.store_ids:
        raise ViewerError(f"{rrd}: the Rerun viewer opened no recording from this file")
    store_id = opened.store_ids[0]

    views: list[View] = []
    while not views:  # the embedded blueprint is applied once the recording is active
        views = [v for v in client.get_state().views if v.visible]
        if not views:
            if time.monotonic() > deadline:
                raise ViewerError(f"{rrd}: the recording's blueprint has no visible view")
            time.sleep(0.1)
    _pause_at(client, store_id, frame, rrd, deadline)
    layout = client.get_blueprint(store_id=store_id).blueprint
    order = layout_order(layout)
    views.sort(key=lambda v: order.index(v.view_id) if v.view_id in order else len(order))
    whole_window = True
    if only:
        views, whole_window = chosen_views(views, only, rrd)

    window = b""
    if whole_window:  # without the viewer's top bar (its menu and "Software rasterizer" / "Docker" banners)
        client.set_blueprint(without_top_bar(layout), store_id=store_id)
        _pause_at(client, store_id, frame, rrd, deadline)
        window = crop_blank_top(_settled(client, None, rrd, deadline), height)
    shots = []
    for view in views:  # each view alone, maximised: as large as the window allows
        client.set_blueprint(maximised(layout, view.view_id), store_id=store_id)
        _pause_at(client, store_id, frame, rrd, deadline)  # the blueprint holds the time panel's play state
        shots.append((view.name or view.view_class, _settled(client, view.view_id, rrd, deadline)))
    client.set_blueprint(layout, store_id=store_id)
    if whole_window:
        shots.append((WHOLE_WINDOW, window))

    for shot_name, png in shots:
        if not png.startswith(b"\x89PNG"):
            raise ViewerError(f"{rrd}: the viewer returned no picture for view {shot_name!r}")
    for view in client.get_state().views:
        for report in view.reports:
            log.warning("view %r: %s: %s", view.name, report.severity, report.summary)
    return shots


def chosen_views(views: list[View], names: Sequence[str], rrd: Path) -> tuple[list[View], bool]:
    """The views `names` asks for, in `views`' order, and whether it asks for the whole layout (``all``); a view
    is named by its name or its file name (`view_file_name`), in any case. `ViewerError` (one line, listing the
    names there are) for a name no view has."""
    wanted = check_view_names([v.name or v.view_class for v in views], names, rrd)
    return [v for v in views if view_file_name(v.name or v.view_class) in wanted], WHOLE_WINDOW in wanted


def check_view_names(view_names: Sequence[str], names: Sequence[str], rrd: Path) -> set[str]:
    """The file names (`view_file_name`) of the views `names` asks for; `ViewerError` (one line, listing the
    views there are) for a name none of `view_names` (or ``all``) has."""
    wanted = {view_file_name(name) for name in names}
    known = {view_file_name(name) for name in view_names} | {WHOLE_WINDOW}
    if unknown := sorted(wanted - known):
        raise ViewerError(f"{rrd}: no view {', '.join(unknown)} in the recording's blueprint "
                          f"(its views: {', '.join(sorted(known))})")
    return wanted


def _pause_at(client: ViewerClient, store_id: str, frame: int, rrd: Path, deadline: float) -> None:
    """Move the time cursor to `frame` on the `frame` timeline, paused, and wait until the viewer shows it."""
    client.set_time("frame", sequence=frame, play_state="paused", recording=store_id)
    while not _time_cursor_at(client.get_state(), store_id, frame):  # applied on the viewer's next frame
        if time.monotonic() > deadline:
            raise ViewerError(f"{rrd}: the viewer did not move to frame {frame}")
        time.sleep(0.1)


def maximised(layout: dict[str, Any], view_id: str) -> dict[str, Any]:
    """A copy of the blueprint `layout` (as `ViewerClient.get_blueprint` returns it) with one view maximised."""
    copied = copy.deepcopy(layout)
    copied.setdefault("/viewport", {}).setdefault("ViewportBlueprint", {})["maximized"] = view_id
    return copied


def without_top_bar(layout: dict[str, Any]) -> dict[str, Any]:
    """A copy of the blueprint `layout` with the viewer's top bar hidden."""
    copied = copy.deepcopy(layout)
    copied["/top_panel"] = {"PanelBlueprint": {"state": "Hidden"}}
    return copied


#: The blank band a hidden top bar leaves is cropped when it is at least this many rows.
MIN_BLANK_ROWS = 8
#: The rows of the viewer's top bar (Rerun 0.41, any window size): the headless window is this much taller.
TOP_BAR_ROWS = 37


def crop_blank_top(png: bytes, height: int | None = None) -> bytes:
    """The PNG without the band a hidden top bar leaves: the leading rows that are one colour across the window
    (the window's rounded corners, 20 px each side, left out of the test), when there are `MIN_BLANK_ROWS`. With
    `height`, exactly the rows above the last `height` go (the band is a few rows short on some screenshots: the
    picture keeps the size asked for)."""
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.shape[1] <= 40:
        return png
    centre = image[:, 20:-20].reshape(image.shape[0], image.shape[1] - 40, -1)
    blank = (centre == centre[:, :1]).all(axis=(1, 2))
    rows = len(blank) if blank.all() else int(np.argmin(blank))
    if rows < MIN_BLANK_ROWS or rows == len(blank):
        return png
    if height is not None and 0 < image.shape[0] - height <= TOP_BAR_ROWS:
        rows = image.shape[0] - height
    ok, encoded = cv2.imencode(".png", image[rows:])
    return encoded.tobytes() if ok else png


def _time_cursor_at(state: ViewerState, store_id: str, frame: int) -> bool:
    return any(r.store_id == store_id and r.current_timeline == "frame" and r.current_time == frame
               for r in state.recordings)


def layout_order(tree: dict[str, Any]) -> list[str]:
    """View ids in reading order of a blueprint's layout (containers depth-first); [] if unknown."""
    try:
        root = tree["/viewport"]["ViewportBlueprint"]["root_container"]
    except (KeyError, TypeError):  # an older/newer blueprint shape: keep the viewer's order
        return []
    order: list[str] = []

    def walk(item: str) -> None:
        kind, _, ident = item.partition("/")
        if kind == "view":
            order.append(ident)
        elif kind == "container":
            contents = tree.get(f"/container/{ident}", {}).get("ContainerBlueprint", {}).get("contents", [])
            for child in [contents] if isinstance(contents, str) else contents:
                walk(child)

    walk(f"container/{root}")
    return order


#: Two screenshots this far apart (seconds) that are identical, with nothing loading, are the settled picture.
SETTLE_S = 0.1
#: A picture that keeps changing in no more than this share of its pixels for `FLICKER_S` seconds, with nothing
#: loading, is taken as it is: at small window sizes egui's plots can oscillate between two layouts (an axis
#: label's width changes the plot's, which changes the label), measured at 320x240: 100-200 of 76800 pixels
#: changing every frame for good, while the same layout at 640x360 settles at once.
FLICKER_SHARE = 0.01
FLICKER_S = 3.0


def _settled(client: ViewerClient, view_id: str | None, rrd: Path, deadline: float) -> bytes:
    """Screenshot the view (the whole window for None) until two shots `SETTLE_S` apart are identical and
    nothing is loading: the viewer loads chunks lazily, decodes images and eases the 3-D eye in the
    background (it repaints while it does, so a changing picture is never taken twice). A picture whose changes
    stay small (`FLICKER_SHARE`) for `FLICKER_S` is taken too, with a warning."""
    previous = client.take_screenshot(view_id)
    flicker_since: float | None = None
    while True:
        if time.monotonic() > deadline:
            raise ViewerError(f"{rrd}: the viewer's pictures did not settle before the time-out")
        time.sleep(SETTLE_S)
        shot = client.take_screenshot(view_id)
        if not client.get_state().loading:
            if shot == previous:
                return shot
            if changed_share(previous, shot) > FLICKER_SHARE:
                flicker_since = None
            elif flicker_since is None:
                flicker_since = time.monotonic()
            elif time.monotonic() - flicker_since >= FLICKER_S:
                log.warning("view %s kept changing in a few pixels for %.0f s (a layout oscillating at this "
                            "window size); its last picture was taken", view_id or "layout", FLICKER_S)
                return shot
        else:
            flicker_since = None
        previous = shot


def changed_share(first: bytes, second: bytes) -> float:
    """Share of pixels that differ between two PNG screenshots (1.0 when their sizes differ or one is unreadable)."""
    a, b = (cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED) for png in (first, second))
    if a is None or b is None or a.shape != b.shape:
        return 1.0
    differs = a != b
    return float((differs.any(axis=2) if differs.ndim == 3 else differs).mean())
