"""The map backend's recording (`vslam.recording.map_backend`), read back from the `.rrd` in strict mode: tracking mode,
keyframe frusta, landmarks, keyframe path, bundle adjustment, PnP overlays, events, blueprint; detail levels;
and none of it with the odometry backend."""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path
from typing import Any

import cli_helpers
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from vslam.recording import MAP_METRICS, MAP_STAGES, MODE_LEVELS, Detail, Recorder
from vslam.recording.columns import NO_IMAGE, ColumnBuffer
from vslam.recording.map_backend import map as map_recording
from vslam.recording.map_backend.map import (
    FRUSTUM_DEPTH,
    HIDDEN_LINE_PX,
    PATH_ROOT,
    PNP_INLIER,
    PNP_OUTLIER,
    observation_colours,
)
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import FrameResult, MapFrame, PnPFailure, Reason, TrackingMode
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource

ROOT = Path(__file__).resolve().parents[1]
FRAMES = 40
LOCAL_FRAMES = 30
MAP_ENTITIES = ("/tracking", "/world/map/**", "/metrics/tracking/**", "/metrics/ba/**",
                "/world/camera/image/landmarks", "/world/camera/image/reprojection",
                "/local_map", "/map/landmark_lifetimes", "/metrics/local_map/**", "/world/camera/image/local_map/**",
                *(f"/metrics/timing_ms/{stage}" for stage in MAP_STAGES))


@pytest.fixture(autouse=True, scope="module")
def strict_rerun() -> None:
    rr.set_strict_mode(True)  # a malformed archetype raises instead of warning


def record(kitti_root: Path, path: Path, backend: str, frames: int, local_map: bool = False,
           **map_settings: Any) -> list[FrameResult]:
    """A run as `record_run` does it (the recorder's sink, then `finish`), keeping the engine's results."""
    source = KittiSource(kitti_root, sequence="00", frames=FrameRange(0, frames))
    config = EngineConfig(backend=backend, threads=2)  # type: ignore[arg-type]  # the recorder's threads too
    config = dataclasses.replace(config, map=dataclasses.replace(config.map, local_map_tracking=local_map,
                                                                 **map_settings))
    results: list[FrameResult] = []
    run = RunResult([], [], [])
    recorder = Recorder(path, source, config, {"name": "map test", "source": source.name}, detail=Detail.FULL)
    try:
        run_odometry(source, config, (recorder.log_frame, lambda _f, r: results.append(r)), run)
    finally:
        recorder.finish(run, None)
    return results


@pytest.fixture(scope="module")
def full(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[FrameResult]]:
    path = tmp_path_factory.mktemp("map") / "map-full.rrd"
    return path, record(kitti_root, path, "map", FRAMES)


def mapping(result: FrameResult) -> MapFrame:
    assert result.mapping is not None
    return result.mapping


def by_frame(path: Path, entity: str) -> dict[int, dict[str, Any]]:
    """frame -> {column: the row's instances} of an entity's rows."""
    table = read_entity(path, entity)
    return {row["frame"]: row for row in table.iter_rows(named=True)} if not table.is_empty() else {}


def verify(path: Path) -> None:
    check = subprocess.run(["rerun", "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr


def logged_entities(path: Path, static: bool) -> set[str]:
    reader = RrdReader(path)
    return {chunk.entity_path for chunk in reader.stream().filter(is_static=static).to_chunks()}


def is_map_entity(entity: str) -> bool:
    return any(entity == e or (e.endswith("/**") and entity.startswith(e[:-2])) for e in MAP_ENTITIES)


@pytest.mark.kitti
def test_tracking_mode_series_and_values(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    verify(path)
    tracking = read_entity(path, "/tracking")
    assert tracking["frame"].to_list() == list(range(FRAMES))
    modes = [v[0] for v in tracking["mode"].to_list()]
    assert modes == [str(mapping(r).mode) for r in results]
    assert modes[0] == "init"
    mode_series = read_entity(path, "/metrics/tracking/mode")
    levels = [v[0] for v in mode_series["Scalars:scalars"].to_list()]
    assert levels == [MODE_LEVELS[TrackingMode(m)] for m in modes]
    after_start = levels[5:]
    assert sum(level == MODE_LEVELS[TrackingMode.MAP] for level in after_start) >= 0.8 * len(after_start)

    inliers = by_frame(path, "/metrics/tracking/pnp_inliers")
    tracked = by_frame(path, "/metrics/tracking/landmarks_tracked")
    with_pnp = [r for r in results if mapping(r).pnp is not None]
    assert sorted(inliers) == sorted(tracked) == [r.index for r in with_pnp]
    for r in with_pnp:
        pnp = mapping(r).pnp
        assert pnp is not None
        assert inliers[r.index]["Scalars:scalars"] == [int(pnp.inlier_mask.sum())]
        assert tracked[r.index]["Scalars:scalars"] == [len(pnp.landmark_ids)]
    pnps = [mapping(r).pnp for r in results]
    assert [v[0] for v in tracking["pnp_inliers"].to_list()] == [
        int(pnp.inlier_mask.sum()) if pnp is not None else 0 for pnp in pnps]
    style = read_entity(path, "/metrics/tracking/mode", static=True)
    assert style["SeriesLines:names"].to_list() == [[MAP_METRICS["tracking"]["mode"][0]]]
    assert len(read_entity(path, "/metrics/timing_ms/pnp")) >= FRAMES - 2

    # the report says where the poses came from, counted over the frames' modes
    report = read_entity(path, "/report", static=True)["TextDocument:text"].to_list()[-1][0]
    counts = {mode: modes.count(str(mode)) for mode in TrackingMode}
    assert f"Placed: {counts[TrackingMode.MAP]} by PnP against the map" in report, report
    assert f"{counts[TrackingMode.INIT]} starting a map" in report, report
    assert "Adjusted:" not in report, report  # with a scale source the map is not adjusted again at the end


@pytest.mark.kitti
def test_keyframes_as_frusta(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    views = {r.index: mapping(r).view for r in results if mapping(r).view is not None}
    assert len(views) >= 5
    window = by_frame(path, "/world/map/keyframes/window")
    assert sorted(window) == sorted(views)
    for frame, view in views.items():
        assert view is not None
        row = window[frame]
        ids = np.concatenate([view.window_ids, view.fixed_ids])
        assert row["keyframe_id"] == ids.tolist()
        assert row["fixed"] == [False] * len(view.window_ids) + [True] * len(view.fixed_ids)
        strips = [np.array(s) for s in row["LineStrips3D:strips"]]
        poses = np.concatenate([view.window_poses, view.fixed_poses])
        assert len(strips) == len(poses)
        for strip, pose in zip(strips, poses, strict=True):
            assert strip.shape == (11, 3)
            assert np.allclose(strip[5], pose[:3, 3], atol=1e-4)  # the frustum's apex: the camera centre
            corners_cam = (strip[:4] - pose[:3, 3]) @ pose[:3, :3]  # back into the camera frame
            assert np.allclose(corners_cam[:, 2], FRUSTUM_DEPTH, atol=1e-4)
    assert len(set(map(len, (w["LineStrips3D:colors"] for w in window.values())))) > 1  # window grows
    last = views[max(views)]
    assert last is not None and len(last.fixed_ids) > 0  # fixed keyframes are drawn (in another colour)
    colours = window[max(views)]["LineStrips3D:colors"]
    assert colours is not None and len(set(colours)) == 2

    retired = read_entity(path, "/world/map/keyframes/retired")
    expected = [int(i) for v in views.values() if v is not None for i in v.retired_ids]
    assert expected and [i for row in retired["keyframe_id"].to_list() for i in row] == expected

    paths = recorded_keyframe_paths(path, sorted(views))
    for frame, view in views.items():
        assert view is not None and np.allclose(paths[frame], view.keyframe_path, atol=1e-4)


def recorded_keyframe_paths(path: Path, frames: list[int]) -> dict[int, np.ndarray]:
    """frame → the keyframe path as the viewer shows it there: each block's latest row (the blocks of
    `/world/map/keyframe_path/<block>`, in order), joined without the point each repeats of the block before."""
    blocks = sorted((int(e.rsplit("/", 1)[1]), e) for e in logged_entities(path, static=False)
                    if e.startswith(PATH_ROOT + "/"))
    rows = [by_frame(path, entity) for _, entity in blocks]
    paths = {}
    for frame in frames:
        parts = []
        for block in rows:
            latest = max((f for f in block if f <= frame), default=None)
            strip = np.array(block[latest]["LineStrips3D:strips"][0]).reshape(-1, 3) if latest is not None else []
            if len(strip):
                parts.append(strip[1:] if parts else strip)
        paths[frame] = np.concatenate(parts) if parts else np.empty((0, 3))
    return paths


@pytest.mark.kitti
def test_keyframe_path_blocks_rebuild_every_keyframes_path(kitti_root: Path, full: tuple[Path, list[FrameResult]],
                                                           tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """In blocks of 3 keyframe ids, a keyframe re-logs only the blocks that changed (never the whole path), and
    the blocks joined at each keyframe give its whole path as refined then."""
    _, results = full
    monkeypatch.setattr(map_recording, "PATH_BLOCK_KEYFRAMES", 3)
    path = tmp_path / "blocks.rrd"
    rec = rr.RecordingStream("keyframe-path-blocks")
    rec.save(path)
    columns = ColumnBuffer(rec)
    intrinsics = KittiSource(kitti_root, sequence="00", frames=FrameRange(0, 1)).intrinsics
    recording = map_recording.MapRecording(rec, columns, intrinsics, Detail.SUMMARY)
    for result in results:
        recording.log_frame(Frame(result.index, None, NO_IMAGE), result, mapping(result))
    columns.flush()
    rec.disconnect()
    views = {r.index: mapping(r).view for r in results if mapping(r).view is not None}
    paths = recorded_keyframe_paths(path, sorted(views))
    for frame, view in views.items():
        assert view is not None and np.allclose(paths[frame], view.keyframe_path, atol=1e-4)
    last = views[max(views)]
    assert last is not None and len(last.keyframe_path) >= 9  # at least three blocks
    rows = [row for e in logged_entities(path, static=False) if e.startswith(PATH_ROOT + "/")
            for row in by_frame(path, e).values()]
    assert max(len(row["LineStrips3D:strips"][0]) for row in rows) <= 3 + 1  # a block and its join point


@pytest.mark.kitti
def test_landmark_cloud_grows_and_is_coloured_by_observations(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    window = by_frame(path, "/world/map/landmarks/window")
    retired = by_frame(path, "/world/map/landmarks/retired")
    assert window and retired
    views = {r.index: mapping(r).view for r in results if mapping(r).view is not None}
    counts = []
    retired_so_far = 0
    for frame in sorted(window):
        view = views[frame]
        assert view is not None
        row = window[frame]
        assert row["landmark_id"] == view.landmark_ids.tolist()
        assert row["observations"] == view.landmark_observations.tolist()
        assert np.allclose(np.array(row["Points3D:positions"]).reshape(-1, 3), view.landmark_positions, atol=1e-4)
        expected = observation_colours(view.landmark_observations)
        packed = [(int(r) << 24) | (int(g) << 16) | (int(b) << 8) | 0xFF for r, g, b in expected]
        assert row["Points3D:colors"] == packed
        if frame in retired:
            assert retired[frame]["landmark_id"] == view.retired_landmark_ids.tolist()
            retired_so_far += len(retired[frame]["landmark_id"])
        counts.append(retired_so_far + len(row["landmark_id"]))
    # the cloud the 3-D view shows (retired ones keep their whole past, plus the window's) grows
    assert counts[0] >= 0 and counts[-1] > 0
    assert counts[-1] > 2 * max(c for c in counts[:3])
    assert sum(b >= a for a, b in zip(counts, counts[1:], strict=False)) >= 0.8 * (len(counts) - 1)


@pytest.mark.kitti
def test_bundle_adjustment_series_residuals_and_events(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    runs = {r.index: mapping(r).bundle_adjustment for r in results if mapping(r).bundle_adjustment is not None}
    assert len(runs) >= 5
    series = {name: by_frame(path, f"/metrics/ba/{name}") for name in MAP_METRICS["ba"]}
    for name, rows in series.items():
        assert sorted(rows) == sorted(runs), name
    before = {f: row["Scalars:scalars"][0] for f, row in series["mean_error_before_px"].items()}
    after = {f: row["Scalars:scalars"][0] for f, row in series["mean_error_after_px"].items()}
    assert sum(after[f] <= before[f] + 1e-9 for f in runs) >= 0.8 * len(runs)
    for frame, ba in runs.items():
        assert ba is not None
        assert series["iterations"][frame]["Scalars:scalars"] == [ba.iterations]
        assert np.isclose(after[frame], ba.mean_error_after)
        # every adjusted keyframe after the first has the front end's chained rotation as a prior, and keeps to it
        assert len(ba.rotation_errors_deg) >= len(ba.keyframe_ids) - 1
        largest = series["rotation_prior_max_deg"][frame]["Scalars:scalars"][0]
        assert largest == pytest.approx(ba.rotation_errors_deg.max()) and largest < 0.2

    residuals = by_frame(path, "/world/map/ba_residuals")
    assert sorted(residuals) == sorted(runs)
    frame = max(runs)
    ba = runs[frame]
    assert ba is not None
    finite = np.isfinite(ba.landmark_residual_px)
    assert residuals[frame]["landmark_id"] == ba.landmark_ids[finite].tolist()
    assert np.allclose(residuals[frame]["residual_px"], ba.landmark_residual_px[finite], atol=1e-4)
    positions = np.array(residuals[frame]["Points3D:positions"]).reshape(-1, 3)
    assert np.allclose(positions, ba.landmark_positions[finite], atol=1e-3)

    events = read_entity(path, "/events")
    texts = [t for row in events["TextLog:text"].to_list() for t in row]
    assert sum("bundle adjustment over keyframes" in t for t in texts) == len(runs)
    keyframes = [mapping(r).keyframe for r in results if mapping(r).keyframe is not None]
    assert sum(": keyframe " in t for t in texts) == len(keyframes)
    assert sum(" new (rays ≥ 1°)" in t for t in texts) == len(keyframes)  # gt scale: map.min_triangulation_deg
    first_ba = min(runs)
    ba = runs[first_ba]
    assert ba is not None
    expected = (f"frame {first_ba}: bundle adjustment over keyframes {ba.keyframe_ids.min()}–{ba.keyframe_ids.max()} "
                f"({len(ba.fixed_keyframe_ids)} fixed): mean error {ba.mean_error_before:.2f} → "
                f"{ba.mean_error_after:.2f} px, {ba.culled} culled")
    assert expected in texts


@pytest.mark.kitti
def test_landmarks_and_reprojection_lines_in_the_image(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    points = by_frame(path, "/world/camera/image/landmarks")
    lines = by_frame(path, "/world/camera/image/reprojection")
    assert sorted(points) == sorted(lines) == list(range(FRAMES))  # every frame: empty rows without PnP
    assert not points[0]["Points2D:positions"] and not lines[0]["LineStrips2D:strips"]
    with_lines = 0
    for r in results:
        pnp = mapping(r).pnp
        if pnp is None:
            continue
        row = points[r.index]
        # to 1/2 px, the lines' ends to 1/4 px (issue 56: the file's size)
        assert np.abs(np.array(row["Points2D:positions"]).reshape(-1, 2) - pnp.observed).max() <= 1 / 4 + 1e-4
        assert row["Points2D:class_ids"] == np.where(pnp.inlier_mask, PNP_INLIER, PNP_OUTLIER).tolist()
        assert row["landmark_id"] == pnp.landmark_ids.tolist()
        finite = np.isfinite(pnp.projected).all(axis=1)
        strips = np.array(lines[r.index]["LineStrips2D:strips"]).reshape(-1, 2, 2)
        assert len(strips) == finite.sum()
        if len(strips):
            with_lines += 1
            assert np.abs(strips[:, 0] - pnp.projected[finite]).max() <= 1 / 8 + 1e-4
            assert np.abs(strips[:, 1] - pnp.observed[finite]).max() <= 1 / 8 + 1e-4
    assert with_lines >= FRAMES // 2


@pytest.mark.kitti
def test_blueprint_shows_the_map_plots_and_keeps_the_retired_map(full: tuple[Path, list[FrameResult]]) -> None:
    path, _ = full
    reader = RrdReader(path)
    views: dict[str, dict[str, object]] = {}
    overrides: set[str] = set()
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "ViewBlueprint:display_name" in batch.schema.names:
            views[batch.column("ViewBlueprint:display_name").to_pylist()[-1][0]] = {"path": chunk.entity_path}
        if "/ViewContents/overrides/" in chunk.entity_path:
            overrides.add(chunk.entity_path.split("/overrides", 1)[1].rsplit("/visualizers", 1)[0])
    assert {"tracking mode", "landmarks tracked", "bundle adjustment", "bundle adjustment error (px)",
            "bundle adjustment rotation vs front end (°)"} <= set(views)
    assert {"/world/map/keyframes/retired", "/world/map/landmarks/retired", "/world/trajectory/estimate"} <= overrides


def vslam(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return cli_helpers.vslam(*args, env={"RERUN_STRICT": "1"})


@pytest.mark.kitti
def test_detail_levels_of_the_map(kitti_root: Path, tmp_path: Path) -> None:
    """Through the CLI: summary keeps the mode, series, events, frusta and keyframe path, but no per-point data
    and nothing in the image; standard adds the landmarks and image overlays without hover values."""
    for detail in (Detail.SUMMARY, Detail.STANDARD):
        path = tmp_path / f"{detail}.rrd"
        done = vslam("run", kitti_root, "--sequence", "00", "--frames", "0:12", "--backend", "map",
                     "--detail", detail, "-o", path)
        assert done.returncode == 0, done.stderr
        verify(path)
        assert len(read_entity(path, "/tracking")) == 12
        assert not read_entity(path, "/world/map/keyframes/window").is_empty()
        assert not read_entity(path, f"{PATH_ROOT}/0").is_empty()
        assert not read_entity(path, "/metrics/ba/mean_error_after_px").is_empty()
        assert read_entity(path, "/world/map/ba_residuals").is_empty()
        landmarks = read_entity(path, "/world/map/landmarks/window")
        image = read_entity(path, "/world/camera/image/landmarks")
        if detail == Detail.SUMMARY:
            assert landmarks.is_empty() and image.is_empty()
            assert read_entity(path, "/world/camera/image/reprojection").is_empty()
        else:
            assert "Points3D:positions" in landmarks.columns and "landmark_id" not in landmarks.columns
            assert len(image) == 12 and "landmark_id" not in image.columns
            lines = read_entity(path, "/world/camera/image/reprojection")
            assert len(lines) == 12
            # the lines their dot would hide are left out (their ends rounded to 1/4 px), no class labels drawn
            strips = [np.array(row, float).reshape(-1, 2, 2) for row in lines["LineStrips2D:strips"].to_list() if row]
            assert strips and all((np.linalg.norm(s[:, 0] - s[:, 1], axis=1) > HIDDEN_LINE_PX - 0.5).all()
                                  for s in strips)
            style = read_entity(path, "/world/camera/image/reprojection", static=True)
            assert [row for row in style["LineStrips2D:show_labels"].to_list() if row] == [[False]]


@pytest.mark.kitti
def test_odometry_backend_writes_none_of_the_map_entities(kitti_root: Path, tmp_path: Path,
                                                          full: tuple[Path, list[FrameResult]]) -> None:
    path = tmp_path / "vo.rrd"
    results = record(kitti_root, path, "vo", 10)
    assert all(r.mapping is None for r in results)
    vo = logged_entities(path, static=False) | logged_entities(path, static=True)
    assert not {e for e in vo if is_map_entity(e)}
    map_run = logged_entities(full[0], static=False)
    assert {e for e in map_run if is_map_entity(e)} >= {
        "/tracking", "/world/map/keyframes/window", "/world/map/keyframes/retired", "/world/map/landmarks/window",
        "/world/map/landmarks/retired", f"{PATH_ROOT}/0", "/world/map/ba_residuals",
        "/metrics/tracking/mode", "/metrics/ba/iterations", "/world/camera/image/landmarks",
        "/world/camera/image/reprojection"}
    assert vo <= map_run | logged_entities(full[0], static=True)  # the map run has everything vo's has


@pytest.fixture(scope="module")
def local(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[FrameResult]]:
    """A short run with local-map tracking on (`map.local_map_tracking`, off by default)."""
    path = tmp_path_factory.mktemp("map") / "map-local.rrd"
    return path, record(kitti_root, path, "map", LOCAL_FRAMES, local_map=True)


@pytest.mark.kitti
def test_local_map_search_and_landmark_lifetimes_read_back(local: tuple[Path, list[FrameResult]]) -> None:
    """Per frame: the landmarks projected with the predicted pose, their search windows and what was
    re-found (values and pixels as the engine's `LocalMapSearch`); per bundle adjustment: the histogram
    of keyframes per landmark (as `BundleAdjusted.landmark_keyframes` counts them)."""
    path, results = local
    summary = by_frame(path, "/local_map")
    projected = by_frame(path, "/world/camera/image/local_map/projected")
    windows = by_frame(path, "/world/camera/image/local_map/windows")
    lines = by_frame(path, "/world/camera/image/local_map/refound")
    assert sorted(summary) == sorted(projected) == sorted(windows) == sorted(lines) == list(range(LOCAL_FRAMES))
    searched = linked = 0
    for r in results:
        search = mapping(r).local_map
        row = summary[r.index]
        if search is None:
            assert row["search"] == [""] and row["projected"] == [0] and not projected[r.index]["Points2D:positions"]
            continue
        searched += 1
        found = search.found_mask
        assert row["search"] == [search.purpose] and row["projected"] == [len(search.landmark_ids)]
        assert row["refound"] == [int(found.sum())] and row["keyframes"] == [len(search.keyframe_ids)]
        points = projected[r.index]
        assert np.allclose(np.array(points["Points2D:positions"]).reshape(-1, 2), search.projected, atol=1e-3)
        classes = np.where(search.accepted, 2, found.astype(int))
        assert points["Points2D:class_ids"] == classes.tolist() and row["linked"] == [int(search.accepted.sum())]
        assert points["landmark_id"] == search.landmark_ids.tolist()
        boxes = windows[r.index]
        assert np.allclose(np.array(boxes["Boxes2D:half_sizes"]).reshape(-1, 2)[:, 0], search.radius_px, atol=1e-4)
        strips = np.array(lines[r.index]["LineStrips2D:strips"]).reshape(-1, 2, 2)
        assert np.allclose(strips[:, 1], search.found_pixels[found], atol=1e-3)
        linked += int(search.accepted.sum())
    assert searched >= LOCAL_FRAMES // 2 and linked > 0
    refound = by_frame(path, "/metrics/local_map/refound")
    assert sum(v["Scalars:scalars"][0] for v in refound.values()) == sum(
        int(s.found_mask.sum()) for s in (mapping(r).local_map for r in results) if s is not None) > 0

    lifetimes = by_frame(path, "/map/landmark_lifetimes")
    adjusted = [r for r in results if mapping(r).bundle_adjustment is not None]
    assert sorted(lifetimes) == [r.index for r in adjusted] and adjusted
    for r in adjusted:
        ba = mapping(r).bundle_adjustment
        assert ba is not None
        row = lifetimes[r.index]
        assert row["landmarks"] == np.bincount(ba.landmark_keyframes).tolist()
        assert row["keyframes"] == list(range(len(row["landmarks"])))
        assert sum(row["landmarks"]) == len(ba.landmark_ids)
    mean = by_frame(path, "/metrics/ba/landmark_keyframes_mean")
    last = adjusted[-1]
    assert mean[last.index]["Scalars:scalars"][0] == pytest.approx(
        float(mapping(last).bundle_adjustment.landmark_keyframes.mean()))  # type: ignore[union-attr]


@pytest.mark.kitti
def test_why_pnp_failed_is_read_back_frame_by_frame(kitti_root: Path, tmp_path: Path) -> None:
    """A map that cannot place any frame (PnP asked for more inliers than there are landmarks): every frame with
    a map says why in `/tracking` (pnp_failure "ransac": landmarks matched, too few inliers), with the landmarks
    in view and the search's window, as the engine's `PnPEstimate` has them, and takes its two-view pose. With
    more landmarks asked for than the local map has, the reason is too_few_in_view, with the search by
    projection (`map_search`) or without it (the landmarks in view are counted all the same)."""
    for settings, expected in (({"pnp_min_inliers": 10**6, "map_search": True}, PnPFailure.RANSAC),
                               ({"pnp_min_landmarks": 10**6, "map_search": True}, PnPFailure.TOO_FEW_IN_VIEW),
                               ({"pnp_min_landmarks": 10**6, "map_search": False}, PnPFailure.TOO_FEW_IN_VIEW)):
        path = tmp_path / f"{expected}-{settings['map_search']}.rrd"
        results = record(kitti_root, path, "map", 10, **settings)
        tracking = by_frame(path, "/tracking")
        failed = [r for r in results if mapping(r).pnp is not None]
        assert len(failed) >= 5
        for r in failed:
            pnp = mapping(r).pnp
            assert pnp is not None and pnp.failure == expected and mapping(r).mode == TrackingMode.TWO_VIEW
            row = tracking[r.index]
            assert row["pnp_failure"] == [str(expected)]
            assert row["landmarks_in_view"] == [pnp.in_view] and pnp.in_view > 0
            assert row["landmarks_found"] == [pnp.found]
            assert row["search_radius_px"] == [pytest.approx(pnp.search_radius_px)]
            assert pnp.search_radius_px >= 16 if settings["map_search"] else pnp.search_radius_px == pnp.found == 0
            assert Reason.PNP_REJECTED in r.health.reasons
        assert all(tracking[r.index]["pnp_failure"] == [""] for r in results if mapping(r).pnp is None)
        checked = vslam("check", path)  # /tracking with pnp_failure conforms to the schema
        assert checked.returncode == 0, checked.stdout
