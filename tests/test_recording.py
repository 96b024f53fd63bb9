"""Recordings read back (strict mode) hold exactly what the engine computed."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import cli_helpers
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr

from vslam.common import config_columns, config_from_columns, flatten
from vslam.recording import STAGES, Detail, Recorder
from vslam.recording import recorder as recorder_module
from vslam.recording.columns import NO_IMAGE, ColumnBuffer
from vslam.rrd.inspect import flagged_ranges, inspect_recording
from vslam.rrd.provenance import read_config
from vslam.rrd.read import RecordingError, read_entity, read_events
from vslam_core.config import EngineConfig
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult, FrameStatus, TrackFate
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource

ROOT = Path(__file__).resolve().parents[1]
FRAMES = 30


@pytest.fixture(autouse=True, scope="module")
def strict_rerun() -> None:
    rr.set_strict_mode(True)  # a malformed archetype raises instead of warning


def record(kitti_root: Path, path: Path, detail: Detail, frames: int = FRAMES) -> list[FrameResult]:
    source = KittiSource(kitti_root, sequence="00", frames=FrameRange(0, frames))
    results: list[FrameResult] = []
    # the recorder's own entities (the map's are tests/test_recording_map.py's), drawn and sent beside the engine
    # as in a `vslam run` (2 threads; conftest gives test runs one)
    config = EngineConfig(backend="vo", threads=2)
    with Recorder(path, source, config, {"name": "test run", "source": source.name}, detail=detail) as rec:
        run_odometry(source, config, sinks=(rec.log_frame, lambda _f, r: results.append(r)))
    return results


@pytest.fixture(scope="module")
def full(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[FrameResult]]:
    path = tmp_path_factory.mktemp("rec") / "full.rrd"
    with pytest.MonkeyPatch.context() as patch:  # one chunk per entity: see test_detail_levels_drop_what_they_promise
        patch.setattr(recorder_module, "FLUSH_SECONDS", 3600.0)
        return path, record(kitti_root, path, Detail.FULL)


def verify(path: Path) -> None:
    check = subprocess.run(["rerun", "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr


@pytest.mark.kitti
def test_full_recording_equals_the_engine_results(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    verify(path)
    k = 12
    result = results[k]
    assert result.status == FrameStatus.OK

    corners = read_entity(path, "/world/camera/image/corners")
    assert corners["frame"].to_list() == list(range(FRAMES))
    assert np.allclose(np.array(corners["Points2D:positions"][0].to_list()), results[0].new_corners)
    assert corners["track_id"][0].to_list() == results[0].new_corner_ids.tolist()

    flow = read_entity(path, "/world/camera/image/flow").filter(frame=k)
    reached = result.track_fate != TrackFate.LOST
    assert flow["track_id"][0].to_list() == result.track_ids[reached].tolist()  # one arrow per track
    assert flow["age"][0].to_list() == result.track_age[reached].tolist()
    classes = np.array(flow["Arrows2D:class_ids"][0].to_list())
    for fate in TrackFate:
        if fate != TrackFate.LOST:
            assert (classes == fate).sum() == (result.track_fate == fate).sum(), fate.name
    origins = np.array(flow["Arrows2D:origins"][0].to_list())  # both ends to 1/2 px (issue 56: the file's size)
    tips = origins + np.array(flow["Arrows2D:vectors"][0].to_list())
    assert np.abs(origins - result.track_prev[reached]).max() <= 1 / 4 + 1e-4
    assert np.abs(tips - result.track_cur[reached]).max() <= 1 / 4 + 1e-4
    assert np.abs(origins - result.track_prev[reached]).max() > 1 / 16  # not finer: the size

    candidates = read_entity(path, "/world/candidates").filter(frame=k)
    assert len(result.candidate_poses) == 4
    assert candidates["in_front"][0].to_list() == [c.in_front for c in result.candidate_poses]
    assert candidates["chosen"][0].to_list() == [i == result.chosen_candidate for i in range(4)]
    assert len(candidates["Arrows3D:vectors"][0]) == 12  # three axes per candidate

    points = read_entity(path, "/world/points").filter(frame=k)
    assert np.allclose(np.array(points["Points3D:positions"][0].to_list()), result.points_world, atol=1e-4)

    for entity in ("/world/trajectory/estimate", "/world/trajectory/ground_truth", "/world/camera",
                   "/world/camera/image", "/health"):
        assert len(read_entity(path, entity)) == FRAMES, entity
    camera = read_entity(path, "/world/camera")
    assert np.allclose(np.array(camera["Transform3D:translation"][-1].to_list()).ravel(),
                       results[-1].T_world_cam[:3, 3], atol=1e-5)
    inliers = read_entity(path, "/metrics/ransac/inliers").filter(frame=k)
    assert inliers["Scalars:scalars"][0].to_list() == [result.inlier_count]
    rejected = read_entity(path, "/metrics/tracks/fb_rejected").filter(frame=k)["Scalars:scalars"][0].to_list()
    assert rejected == [np.count_nonzero(result.track_fate == TrackFate.FB_REJECTED)]  # FrameResult.fate_counts
    for stage in ("decode", "track", "essential", "record"):
        assert len(read_entity(path, f"/metrics/timing_ms/{stage}")) >= FRAMES - 1, stage


@pytest.mark.kitti
def test_recording_carries_properties_static_conventions_and_blueprint(full: tuple[Path, list[FrameResult]]) -> None:
    path, _ = full
    run = read_entity(path, "/__properties/run", static=True)
    assert run["name"][0].to_list() == ["test run"] and run["detail"][0].to_list() == ["full"]
    # the whole config in two components (schema 2: a component per key cost every chunk a cell of Rerun's index)
    config = read_entity(path, "/__properties/config", static=True)
    assert {c for c in config.columns if not c.startswith("rerun.")} == {"key", "value"}
    stored = read_config(path)
    assert stored == flatten(EngineConfig(backend="vo", threads=2).to_dict())  # every key, with its type (JSON)
    assert stored["pose.ransac_threshold_px"] == EngineConfig().pose.ransac_threshold_px
    name = read_entity(path, "/__properties", static=True)
    assert name["RecordingInfo:name"][0].to_list() == ["test run"]
    pinhole = read_entity(path, "/world/camera/image", static=True)
    assert "Pinhole:image_from_camera" in pinhole.columns
    assert "ViewCoordinates:xyz" in read_entity(path, "/world", static=True).columns
    stats = subprocess.run(["rerun", "rrd", "stats", str(path)], capture_output=True, text=True, timeout=120)
    assert "StoreId(Blueprint" in stats.stdout  # the default blueprint is embedded in the file


@pytest.mark.kitti
def test_detail_levels_drop_what_they_promise(kitti_root: Path, tmp_path: Path,
                                              full: tuple[Path, list[FrameResult]],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    # the budgets are of the content: rows written once a second cost a chunk schema per entity per second, a
    # KB or more a frame on a machine loaded down to a few frames a second (the full fixture is written so too)
    monkeypatch.setattr(recorder_module, "FLUSH_SECONDS", 3600.0)
    sizes = {}
    for detail in (Detail.STANDARD, Detail.SUMMARY):
        path = tmp_path / f"{detail}.rrd"
        record(kitti_root, path, detail)
        verify(path)
        sizes[detail] = path.stat().st_size
        assert len(read_entity(path, "/world/trajectory/estimate")) == FRAMES
        assert len(read_entity(path, "/metrics/tracks/alive")) == FRAMES
        assert read_entity(path, "/world/points").is_empty()
        if detail == Detail.STANDARD:
            flow = read_entity(path, "/world/camera/image/flow")
            assert len(flow) == FRAMES and "track_id" not in flow.columns
        else:
            assert read_entity(path, "/world/camera/image").is_empty()
            assert read_entity(path, "/world/camera/image/flow").is_empty()
    full_size = full[0].stat().st_size
    assert sizes[Detail.SUMMARY] < sizes[Detail.STANDARD] < full_size
    # Budgets per frame (the file's fixed part — blueprint, statics, schemas — taken out): a 10-frame run
    # subtracted from the 30-frame one. summary ≤ 5 KB, full ≤ 120 KB.
    short = tmp_path / "short.rrd"
    record(kitti_root, short, Detail.SUMMARY, frames=10)
    assert (sizes[Detail.SUMMARY] - short.stat().st_size) / (FRAMES - 10) < 5 * 1024
    record(kitti_root, short.with_name("short-full.rrd"), Detail.FULL, frames=10)
    assert (full_size - short.with_name("short-full.rrd").stat().st_size) / (FRAMES - 10) < 120 * 1024


def vslam(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return cli_helpers.vslam(*args, env={"RERUN_STRICT": "1"})


@pytest.mark.kitti
def test_two_runs_of_the_same_input_compare_equal(kitti_root: Path, tmp_path: Path) -> None:
    """Everything but the measured stage timings is deterministic."""
    paths = []
    for name in ("a", "b"):
        path = tmp_path / f"{name}.rrd"
        assert vslam("run", kitti_root, "--sequence", "05", "--frames", "0:15", "-o", path).returncode == 0
        paths.append(path)
    cli_helpers.assert_same_recording(*paths, tmp_path)


@pytest.mark.kitti
def test_finish_inside_the_with_block_closes_the_recording_once(kitti_root: Path, tmp_path: Path) -> None:
    """`finish` closes the recorder and so does leaving its ``with`` block: the second close does nothing, and the
    file is whole, with the run's report."""
    source = KittiSource(kitti_root, sequence="00", frames=FrameRange(0, 5))
    config, path = EngineConfig(backend="vo", threads=2), tmp_path / "f.rrd"  # 2: the recorder has its threads
    with Recorder(path, source, config, {"name": "finished"}, detail=Detail.STANDARD) as rec:
        rec.finish(run_odometry(source, config, sinks=(rec.log_frame,)), None)
    verify(path)
    assert read_entity(path, "/report", static=True)["TextDocument:text"].to_list()[-1][0].startswith("# finished")


@pytest.mark.kitti
def test_inspect_reports_what_a_bug_report_needs(full: tuple[Path, list[FrameResult]]) -> None:
    path, results = full
    report = inspect_recording(path)
    assert report["frames"] == {"count": FRAMES, "first": 0, "last": FRAMES - 1}
    assert report["properties"]["name"] == "test run"
    assert set(report["stages_ms"]) == set(STAGES)
    assert report["stages_ms"]["track"]["mean"] > 0
    alive = [r.live_tracks for r in results]
    assert report["series"]["tracks_alive"]["max"] == max(alive)
    assert report["accuracy"]["final_position_error_m"] >= 0
    assert report["flagged"] == []

    result = vslam("inspect", path, "--json")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert set(data) >= {"schema", "file", "properties", "config", "frames", "stages_ms", "series", "accuracy",
                         "flagged"}
    text = vslam("inspect", path)
    assert text.returncode == 0 and "frames      30 (0..29)" in text.stdout


def test_flagged_frames_become_inclusive_ranges() -> None:
    frames = [10, 11, 12, 13, 14, 15, 20]
    status = ["ok", "fail", "fail", "ok", "fail", "fail", "fail"]
    reasons = ["", "low_parallax", "low_parallax", "", "low_parallax", "too_few_inliers", "too_few_inliers"]
    assert flagged_ranges(frames, status, reasons) == [
        {"start": 11, "end": 12, "status": "fail", "reasons": ["low_parallax"]},
        {"start": 14, "end": 14, "status": "fail", "reasons": ["low_parallax"]},
        {"start": 15, "end": 15, "status": "fail", "reasons": ["too_few_inliers"]},
        {"start": 20, "end": 20, "status": "fail", "reasons": ["too_few_inliers"]},
    ]


def test_bad_recordings_give_one_line_errors(tmp_path: Path) -> None:
    not_rrd = tmp_path / "notes.rrd"
    not_rrd.write_text("hello")
    with pytest.raises(RecordingError, match="not a readable Rerun recording"):
        inspect_recording(not_rrd)
    for path in (tmp_path / "missing.rrd", not_rrd):
        result = vslam("inspect", path)
        assert result.returncode == 2 and "Traceback" not in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1 and str(path) in result.stderr


def test_reading_aids_overlay_legend_event_filter_health_levels(full: tuple[Path, list[FrameResult]]) -> None:
    """The overlays' colour legend beside the frame view, the events view's level filter (INFO and above: the
    DEBUG re-detections hidden) and the health plot's named level lines, all read back from the file."""
    from rerun.chunk import RrdReader

    from vslam.recording.layout import EVENT_LEVELS
    from vslam.recording.styles import HEALTH_LEVELS_ROOT, LEGEND_ENTITY

    path, _ = full
    legend = read_entity(path, LEGEND_ENTITY, static=True)["TextDocument:text"].to_list()[-1][0]
    for line in ("green: inlier", "red: RANSAC outlier", "orange: rejected by forward–backward check",
                 "yellow dots: new corners"):
        assert line in legend
    assert "road points" not in legend  # scale gt: no road overlay
    levels = {name: read_entity(path, f"{HEALTH_LEVELS_ROOT}/{name}", static=True)["SeriesLines:names"].to_list()
              for name in ("ok", "warn", "fail")}
    assert levels == {"ok": [["0 = ok"]], "warn": [["1 = warn"]], "fail": [["2 = fail"]]}
    reader = RrdReader(path)
    filters = [chunk.to_record_batch().column("TextLogRows:filter_by_log_level").to_pylist()
               for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks()
               if "TextLogRows:filter_by_log_level" in chunk.to_record_batch().schema.names]
    assert filters == [[list(EVENT_LEVELS)]] and "DEBUG" not in EVENT_LEVELS
    debug = [text for _, level, text in read_events(path) if level == "DEBUG"]
    assert debug and all(": re-detected " in t for t in debug)  # still recorded, one click away


class _Sent:
    """A stand-in for a recording stream: the entities `send_columns` was called with, in order."""

    def __init__(self, fail_after: int | None = None) -> None:
        self.entities: list[str] = []
        self.columns: dict[str, list[pa.Array]] = {}
        self._fail_after = fail_after

    def send_columns(self, entity: str, indexes: object, columns: list[Any]) -> None:
        if self._fail_after is not None and len(self.entities) >= self._fail_after:
            raise RuntimeError("disk full")
        self.entities.append(entity)
        self.columns[entity] = [column.as_arrow_array() for column in columns]


@pytest.mark.parametrize("background", [False, True])
def test_the_camera_pose_is_sent_after_the_rest_of_its_frame(background: bool) -> None:
    """Issue 56: in a file cut anywhere, a frame with a camera pose has every other row of it (sent before)."""
    sent = _Sent()
    columns = ColumnBuffer(sent, last="/world/camera", background=background)  # type: ignore[arg-type]
    for index in range(3):
        frame = Frame(index, None, NO_IMAGE)
        columns.add("/world/camera", frame, (rr.Transform3D.columns, {"translation": np.zeros(3)}))
        columns.add("/world/camera/image/corners", frame, (rr.Points2D.columns, {"positions": np.zeros((2, 2))}),
                    batch=True)
        columns.add_scalar("/metrics/tracks/alive", frame, 1.0)
    written: list[str] = []
    columns.flush(then=lambda: written.append("checked"))
    columns.wait()
    columns.close()
    assert sent.entities == ["/world/camera/image/corners", "/metrics/tracks/alive", "/world/camera"]
    assert written == ["checked"]  # the write check runs after the rows were sent


def test_rows_of_arrays_are_sent_as_the_columns_rerun_builds_from_them_one_by_one() -> None:
    """Rows that are arrays of one shape go to Rerun stacked, (n, *shape) (~100x faster for line strips): the
    Arrow columns are those of the rows handed over as a list; rows of other shapes, and `AnyValues`, stay lists."""
    rng = np.random.default_rng(0)
    segments = [rng.normal(size=(2, 3)) for _ in range(5)]
    translations = [rng.normal(size=3) for _ in range(5)]
    rotations = [rng.normal(size=(3, 3)) for _ in range(5)]
    paths = [rng.normal(size=(2 + i % 2, 3)) for i in range(5)]  # strips of 2 and 3 points: not one shape
    labels = [rng.normal(size=2) for _ in range(5)]
    sent = _Sent()
    columns = ColumnBuffer(sent)  # type: ignore[arg-type]
    for index in range(5):
        frame = Frame(index, None, NO_IMAGE)
        columns.add("/segments", frame, (rr.LineStrips3D.columns, {"strips": segments[index]}))
        columns.add("/camera", frame, (rr.Transform3D.columns, {"translation": translations[index],
                                                                "mat3x3": rotations[index]}))
        columns.add("/paths", frame, (rr.LineStrips3D.columns, {"strips": paths[index]}))
        columns.add("/values", frame, (rr.AnyValues.columns, {"pair": labels[index]}))
    columns.flush()
    expected = {"/segments": rr.LineStrips3D.columns(strips=segments),
                "/camera": rr.Transform3D.columns(translation=translations, mat3x3=rotations),
                "/paths": rr.LineStrips3D.columns(strips=paths), "/values": rr.AnyValues.columns(pair=labels)}
    for entity, built in expected.items():
        arrays = [column.as_arrow_array() for column in built]
        assert len(sent.columns[entity]) == len(arrays), entity
        assert all(a.equals(b) for a, b in zip(sent.columns[entity], arrays, strict=True)), entity
    rows = sent.columns["/segments"][0].to_pylist()  # a row a frame, each one strip of two points
    assert len(rows) == 5 and np.allclose(rows[4][0], segments[4].astype(np.float32))


def test_a_send_that_fails_in_the_background_stops_the_next_flush() -> None:
    """The write error of a flush on the sending thread is raised on the caller's thread at its next flush."""
    columns = ColumnBuffer(_Sent(fail_after=0), background=True)  # type: ignore[arg-type]
    columns.add_scalar("/metrics/tracks/alive", Frame(0, None, NO_IMAGE), 1.0)
    columns.flush()
    time.sleep(0.2)
    with pytest.raises(RuntimeError, match="disk full"):
        columns.flush()
    columns.close()


def test_the_config_is_stored_as_keys_and_json_values_and_read_back_from_either_schema() -> None:
    """Schema 2 stores the engine config as two components (`config_columns`); a schema-1 row (a component per
    key) is read as it is."""
    config = EngineConfig().with_scale("height").to_dict()
    columns = config_columns(config)
    assert set(columns) == {"key", "value"} and len(columns["key"]) == len(flatten(config)) > 100
    assert config_from_columns(columns) == flatten(config)
    assert config_from_columns({"scale": "height", "pose.seed": 0}) == {"scale": "height", "pose.seed": 0}
    # another writer's row: not JSON, or keys and values that do not pair up, read without a traceback
    assert config_from_columns({"key": ["a", "b"], "value": ["not json", "1"]}) == {"a": "not json", "b": 1}
    assert config_from_columns({"key": ["a", "b"], "value": ["1"]}) == {"key": ["a", "b"], "value": ["1"]}
