"""`compare_recordings`: two real runs side by side in one valid recording, its blueprint, the difference table,
the error paths, and a headless snapshot of the comparison in the real viewer."""

from __future__ import annotations

import json
import logging
import subprocess
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import rerun as rr
from cli_helpers import VO, need_vulkan, vslam, vslam_here
from rerun.chunk import RrdReader

from vslam.compare.blueprint import DIFFERENCE_TITLES
from vslam.compare.comparison import (
    LIGHTEN_B,
    SERIES_WIDTHS,
    ComparisonResult,
    compare_recordings,
    format_differences,
    plot_title,
)
from vslam.compare.frames import DIFFERENCE_SERIES
from vslam.recording import METRICS
from vslam.rrd.crop import crop_recording
from vslam.rrd.inspect import inspect_recording
from vslam.rrd.provenance import read_config
from vslam.rrd.read import RecordingError, read_entity
from vslam.viewer.headless import snapshot, view_file_name
from vslam.viewer.processes import rerun_executable

ROOT = Path(__file__).resolve().parents[1]
FRAMES = list(range(20))
SNAPSHOT_FRAME = 15


@pytest.fixture(scope="module", autouse=True)
def strict_rerun() -> Iterator[None]:
    previous = rr.strict_mode()
    rr.set_strict_mode(True)  # a malformed archetype or blueprint raises instead of warning
    yield
    rr.set_strict_mode(previous)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two real runs of the synthetic street, B keeping half as many tracks (CLI runs in this process)."""
    folder = tmp_path_factory.mktemp("runs")
    (folder / "b.toml").write_text("[detector]\ntarget_tracks = 400\nredetect_below = 300\n")
    a, b = folder / "a.rrd", folder / "b.rrd"
    for args in (["run", "--frames", "0:20", "--backend", "vo", "-o", a],
                 ["run", "--frames", "0:20", "--backend", "vo", "--config", folder / "b.toml", "-o", b]):
        result = vslam(*args)
        assert result.returncode == 0, result.stderr
    return a, b


@pytest.fixture(scope="module")
def compared(runs: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> ComparisonResult:
    return compare_recordings(*runs, tmp_path_factory.mktemp("compare") / "ab.rrd")


def _one_line_error(call: object, *fragments: str) -> str:
    with pytest.raises(RecordingError) as info:
        call()  # type: ignore[operator]
    message = str(info.value)
    assert "\n" not in message and all(f in message for f in fragments), message
    return message


def test_output_is_a_valid_recording_beside_no_leftovers(compared: ComparisonResult) -> None:
    done = subprocess.run([*rerun_executable(), "rrd", "verify", str(compared.output)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    reader = RrdReader(compared.output)
    (recording,) = reader.recordings()
    (blueprint,) = reader.blueprints()
    assert recording.application_id == blueprint.application_id == "vslam-compare"
    assert compared.output_bytes == compared.output.stat().st_size
    assert [p.name for p in compared.output.parent.iterdir()] == [compared.output.name]  # no temp folder left


def test_every_entity_of_each_run_is_under_its_prefix(runs: tuple[Path, Path], compared: ComparisonResult) -> None:
    def entities(path: Path) -> set[str]:
        reader = RrdReader(path)
        return set(reader.store(store=reader.recordings()[0]).schema().entity_paths())

    expected = {f"/{prefix}{e}" for prefix, run in zip("ab", runs, strict=True) for e in entities(run)
                if not e.startswith("/__properties")}
    expected.add("/report")  # the comparison's own: its runs and their summary table
    # …and B's per-frame differences from A, the event saying where (or that) they diverge, and its marker
    expected |= {f"/compare/b/{name}" for name, _, _ in DIFFERENCE_SERIES} | {"/compare/events"}
    if compared.divergences[0] is not None:
        expected.add("/compare/b/divergence")
    assert {e for e in entities(compared.output) if not e.startswith("/__properties")} == expected

    for prefix, run in zip("ab", runs, strict=True):
        for entity in ("/world/camera", "/world/camera/image", "/world/trajectory/estimate", "/events"):
            original, moved = read_entity(run, entity), read_entity(compared.output, f"/{prefix}{entity}")
            assert moved.equals(original), entity  # same rows: timelines, components and row ids
        assert read_entity(compared.output, f"/{prefix}/world/camera")["frame"].to_list() == FRAMES


def test_static_data_of_both_runs_is_kept(runs: tuple[Path, Path], compared: ComparisonResult) -> None:
    for prefix, run in zip("ab", runs, strict=True):
        for entity in ("/world", "/world/camera/image", "/world/camera/image/flow"):
            original = read_entity(run, entity, static=True)
            moved = read_entity(compared.output, f"/{prefix}{entity}", static=True)
            assert not original.is_empty() and moved.equals(original), entity
        pinhole = read_entity(compared.output, f"/{prefix}/world/camera/image", static=True)
        assert pinhole["Pinhole:resolution"].to_list() == [[[1241.0, 376.0]]]
        # standard: the frames stored at half size, drawn over the whole image plane in each run's frame view
        assert np.allclose(pinhole["InstancePoses3D:scales"][0].to_list(), [[1241 / 620, 2.0, 1.0]])


def test_metrics_of_both_runs_with_labelled_legends(runs: tuple[Path, Path], compared: ComparisonResult) -> None:
    for group, series in METRICS.items():
        for name, (legend, colour) in series.items():
            entity = f"/metrics/{group}/{name}"
            for prefix, label, run in zip("ab", ("A", "B"), runs, strict=True):
                values = read_entity(compared.output, f"/{prefix}{entity}")
                assert values.equals(read_entity(run, entity)), entity
                style = read_entity(compared.output, f"/{prefix}{entity}", static=True)
                assert style["SeriesLines:names"].to_list() == [[f"{label}: {legend}"]]
                r, g, b = colour if prefix == "a" else [round(c + (255 - c) * LIGHTEN_B) for c in colour]
                assert style["SeriesLines:colors"].to_list() == [[(r << 24) | (g << 16) | (b << 8) | 0xFF]]
                assert style["SeriesLines:widths"].to_list() == [[SERIES_WIDTHS["ab".index(prefix)]]]


def test_properties_of_both_runs_and_the_comparison_name(compared: ComparisonResult) -> None:
    out = compared.output
    for prefix, tracks in (("a", 800), ("b", 400)):
        config = read_config(out, f"/{prefix}")
        assert config["detector.target_tracks"] == tracks
    for prefix in "ab":
        run = read_entity(out, f"/__properties/{prefix}/run", static=True).row(0, named=True)
        assert run["name"] == ["vslam synthetic-street frames 0:20 scale gt"] and run["frames"] == ["0:20"]
    name = read_entity(out, "/__properties", static=True)["RecordingInfo:name"].to_list()
    assert name == [[compared.recording_name]]
    assert compared.recording_name == "vslam compare: A vs B (vslam synthetic-street frames 0:20 scale gt)"
    compare = read_entity(out, "/__properties/compare", static=True).row(0, named=True)
    assert compare["label_a"] == ["A"] and compare["file_b"] == [str(compared.inputs[1].resolve())]
    # everything under /__properties: one row per property entity, columns merged (no entity column)
    everything = read_entity(out, "/__properties/**", static=True)
    assert everything.height == 6 and {"RecordingInfo:name", "label_a", "key", "value"} <= set(everything.columns)


def _views(rrd: Path) -> dict[str, dict[str, object]]:
    """Views of the embedded blueprint: name -> class, origin, contents, overridden entities."""
    reader = RrdReader(rrd)
    chunks = reader.stream(store=reader.blueprints()[0]).to_chunks()
    columns: dict[str, dict[str, object]] = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        columns.setdefault(chunk.entity_path, {}).update(
            {c: batch.column(c).to_pylist()[-1] for c in batch.schema.names if c.startswith(("View", "Container"))})
    views: dict[str, dict[str, object]] = {}
    for path, values in columns.items():
        if "ViewBlueprint:display_name" in values:
            overridden = {p.split("/overrides", 1)[1].rsplit("/visualizers", 1)[0]
                          for p in columns if p.startswith(f"{path}/ViewContents/overrides/")}
            views[values["ViewBlueprint:display_name"][0]] = {  # type: ignore[index]
                "class": values["ViewBlueprint:class_identifier"][0],  # type: ignore[index]
                "origin": values["ViewBlueprint:space_origin"][0],  # type: ignore[index]
                "contents": list(columns[f"{path}/ViewContents"]["ViewContents:query"]),  # type: ignore[call-overload]
                "overrides": overridden,
            }
    return views


def test_embedded_blueprint_has_both_runs_and_overlaid_plots(compared: ComparisonResult) -> None:
    views = _views(compared.output)
    for label, prefix in (("A", "a"), ("B", "b")):
        assert views[f"{label}: frame"]["origin"] == f"/{prefix}/world/camera/image"
        world = views[f"{label}: world"]
        assert world["class"] == "3D" and world["origin"] == f"/{prefix}/world"
        assert world["overrides"] == {f"/{prefix}/world/trajectory/{t}" for t in ("estimate", "ground_truth", "drift")}
    plotted = [group for group in METRICS if group != "road"]  # neither run used --scale height
    assert plot_title("road") not in views
    for group in plotted:
        plot = views[plot_title(group)]
        assert plot["class"] == "TimeSeries"
        assert plot["contents"] == [f"/a/metrics/{group}/**", f"/b/metrics/{group}/**"]
    trajectories = views["trajectories: A red, B orange, truth blue"]
    # every trajectory but the drift-coloured copies of the estimates (they would hide the runs' hues)
    assert trajectories["contents"] == ["/a/world/trajectory/**", "/b/world/trajectory/**",
                                        *(f"- /{p}/world/trajectory/{e}" for p in "ab" for e in ("drift", "gt_links"))]
    assert trajectories["overrides"] == {f"/{p}/world/trajectory/{t}" for p in "ab"
                                         for t in ("estimate", "ground_truth")}
    assert views["events"]["contents"] == ["/compare/events", "/a/events/**", "/b/events/**"]
    for name, _, kind in DIFFERENCE_SERIES:  # B's per-frame differences from A, the marker with the rotation
        assert views[DIFFERENCE_TITLES[kind]]["contents"] == [f"/compare/b/{name}"] + (
            ["/compare/b/divergence"] if kind == "rotation" else [])
    assert len(views) == 4 + len(plotted) + len(DIFFERENCE_SERIES) + 2


def test_differences_are_the_inspect_values(runs: tuple[Path, Path], compared: ComparisonResult) -> None:
    reports = [inspect_recording(run) for run in runs]
    diffs = compared.differences

    def value(report: dict[str, object], key: str) -> float:
        node: object = report
        for part in key.split(".") if not key.startswith("accuracy.") else ["accuracy", key.split(".", 1)[1]]:
            node = node[part]  # type: ignore[index]
        return float(node)  # type: ignore[arg-type]

    for key in ["frames.count", "bytes", "stages_ms.track.mean", "series.tracks_alive.mean",
                "series.inlier_ratio.mean", "accuracy.paper_rms_m", "accuracy.final_heading_error_deg"]:
        a, b = (value(report, key) for report in reports)
        assert (diffs[key].a, diffs[key].b) == (a, b), key
        assert diffs[key].difference == pytest.approx(b - a)
    assert {f"stages_ms.{s}.mean" for s in reports[0]["stages_ms"]} <= set(diffs)
    assert {f"accuracy.{k}" for k in reports[0]["accuracy"]} <= set(diffs)
    tracks = diffs["series.tracks_alive.mean"]
    assert tracks.b is not None and tracks.a is not None and tracks.b < tracks.a  # half the target
    assert tracks.percent == pytest.approx(100 * (tracks.b - tracks.a) / tracks.a)
    assert diffs["frames.count"].difference == 0 and diffs["bytes"].a == runs[0].stat().st_size

    table = format_differences(compared)
    lines = table.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("metric"))
    assert lines[header].split() == ["metric", "A", "B", "B", "−", "A", "%"]
    rows = {line.split()[0]: line for line in lines[header + 1:]}
    assert set(rows) == set(diffs)
    assert rows["frames.count"].split()[1:] == ["20", "20", "+0", "+0.0%"]
    assert f"{tracks.percent:+.1f}%" in rows["series.tracks_alive.mean"]
    widths = {len(line) for line in lines[header:] if line.endswith("%")}
    assert len(widths) == 1  # right-aligned columns


def test_different_frame_ranges_are_kept_whole(runs: tuple[Path, Path], tmp_path: Path) -> None:
    part = tmp_path / "b_5_15.rrd"
    crop_recording(runs[1], (5, 15), part)
    result = compare_recordings(runs[0], part, tmp_path / "out.rrd", labels=("base", "cropped"))
    assert read_entity(result.output, "/a/world/camera")["frame"].to_list() == FRAMES
    assert read_entity(result.output, "/b/world/camera")["frame"].to_list() == list(range(5, 15))
    style = read_entity(result.output, "/b/metrics/tracks/alive", static=True)
    assert style["SeriesLines:names"].to_list() == [["cropped: tracks alive"]]
    assert result.differences["frames.count"].b == 10
    assert "cropped − base" in format_differences(result)


def test_bad_inputs_and_outputs_are_one_line_errors_naming_the_file(runs: tuple[Path, Path], tmp_path: Path) -> None:
    a, b = runs
    out = tmp_path / "out.rrd"
    missing = tmp_path / "missing.rrd"
    _one_line_error(lambda: compare_recordings(a, missing, out), str(missing), "no such recording")
    garbage = tmp_path / "garbage.rrd"
    garbage.write_bytes(b"not a recording\n")
    _one_line_error(lambda: compare_recordings(garbage, b, out), str(garbage), "not a readable Rerun recording")
    # cut before its first /world/camera rows were written (where they start depends on when the writer flushed:
    # a cut at half the file can hold whole frames, which are then read)
    truncated = tmp_path / "truncated.rrd"
    truncated.write_bytes(a.read_bytes()[:4_000])
    message = _one_line_error(lambda: compare_recordings(a, truncated, out), str(truncated))
    assert "cut short before any of its recording data was written" in message, message
    other = tmp_path / "other.rrd"
    with rr.RecordingStream("other", recording_id="x", send_properties=False) as rec:
        rec.save(other)
        rec.log("/points", rr.Points3D([[0.0, 0.0, 0.0]]), static=True)
    _one_line_error(lambda: compare_recordings(other, b, out), str(other), "not a vslam recording")
    before = a.read_bytes()
    for output in (a, b):
        _one_line_error(lambda output=output: compare_recordings(a, b, output), str(output), "must not be one of")
    assert a.read_bytes() == before
    _one_line_error(lambda: compare_recordings(a, b, out, labels=("A", "A")), "labels must differ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.rrd", "other.rrd", "truncated.rrd"]


# ------------------------------------------------------------------------------------------- viewer


@pytest.fixture(scope="module")
def shots(compared: ComparisonResult, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    need_vulkan()

    warnings: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: warnings.append(record.getMessage())  # type: ignore[method-assign]
    handler.setLevel(logging.WARNING)
    logging.getLogger("vslam.viewer.processes").addHandler(handler)
    try:
        # a small window: half the viewer's rendering time; at 640x360 the checks below measured b_frame 1.6 %
        # colourful, plot lines 166+ columns, 636 estimate and 306 truth pixels (1280x720: 1.1 %, 361+, 1652, 718)
        paths = snapshot(compared.output, SNAPSHOT_FRAME, tmp_path_factory.mktemp("shots"), window_size=(640, 360))
    finally:
        logging.getLogger("vslam.viewer.processes").removeHandler(handler)
    assert not warnings, warnings  # the viewer reported no problem with any view
    return {p.stem: p for p in paths}


def _columns(picture: np.ndarray, rgb: tuple[int, int, int] | list[int], tolerance: int = 30) -> int:
    """How many pixel columns show this colour: a line across a plot spans many, a legend dot ~10."""
    close = (np.abs(picture.astype(int) - np.array(rgb[::-1])).max(axis=2) <= tolerance)
    return int(close.any(axis=0).sum())


def test_snapshot_shows_both_runs_and_overlaid_plots(shots: dict[str, Path]) -> None:
    plots = [view_file_name(plot_title(group)) for group in METRICS if group != "road"]  # no --scale height run
    plots += [view_file_name(title) for title in DIFFERENCE_TITLES.values()]
    expected = ["a_frame", "a_world", "b_frame", "b_world", *plots, "events",
                "trajectories_a_red_b_orange_truth_blue", "all"]
    assert sorted(shots) == sorted(expected)
    pictures = {name: cv2.imread(str(path)) for name, path in shots.items()}
    for name, picture in pictures.items():  # each view maximised in the window: thin lines, large dark background
        assert picture is not None and picture.std() > 4, f"{name}.png looks blank"
    for name in ("a_frame", "b_frame"):  # a photo with overlays on top
        picture = pictures[name]
        colourful = ((picture.max(axis=2).astype(int) - picture.min(axis=2)) > 60).mean()
        assert len(np.unique(cv2.cvtColor(picture, cv2.COLOR_BGR2GRAY))) > 100 and colourful > 0.01, name
    assert not np.array_equal(pictures["a_frame"], pictures["b_frame"])  # B detects fewer corners
    # one line per run (A in the series colour, B lighter) in plots of one series per run
    for group, name in (("ratio", "inlier_ratio"), ("error", "position_m")):
        colour = METRICS[group][name][1]
        lighter = [round(c + (255 - c) * LIGHTEN_B) for c in colour]
        picture = pictures[view_file_name(plot_title(group))]
        assert _columns(picture, colour) > 60 and _columns(picture, lighter) > 60, group
    # the shared 3-D view: the estimates (A red, B orange) and the ground truth (blue). Here the runs agree within
    # 3 cm, so the lines lie on each other: which one is on top depends on their heights, not on their order.
    b, g, r = (pictures["trajectories_a_red_b_orange_truth_blue"].astype(int)[..., i] for i in range(3))
    estimates = (r > 150) & (r > b + 60)  # red or orange
    truth = (b > 200) & (b > r + 60) & (g < 180)
    assert estimates.sum() > 100 and truth.sum() > 100


def test_both_world_views_follow_their_car(compared: ComparisonResult) -> None:
    reader = RrdReader(compared.output)
    tracked = set()
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        if "EyeControls3D:tracking_entity" in batch.schema.names:
            values = batch.column("EyeControls3D:tracking_entity").to_pylist()
            tracked |= {v[0] if isinstance(v, list) else v for v in values if v}
    assert {"/a/world/camera/car", "/b/world/camera/car"} <= tracked, tracked
    for prefix in "ab":  # something drawn to follow (the camera entity alone is a transform)
        assert "Boxes3D:half_sizes" in read_entity(compared.output, f"/{prefix}/world/camera/car", static=True).columns


# ------------------------------------------------------------------------------------------ N runs


def _one_line_exit(result: subprocess.CompletedProcess[str], *fragments: str) -> str:
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in result.stderr, result.stderr
    assert all(f in lines[0] for f in fragments), lines[0]
    return lines[0]


#: Three small real runs of KITTI 00: every second frame (long enough for KITTI's 100 m segments: t_err; the
#: ground truth travels 124 m over 0..168 and 107 m over 20..168), B keeping half the tracks, C a later, shorter
#: window. (Every third frame of 0:240 cost more: fewer inliers, longer RANSAC in findEssentialMat.)
KITTI_RUNS = {
    "base": ["--frames", "0:170:2"],
    "tracks400": ["--frames", "0:170:2", "--config", "{half}"],
    "later": ["--frames", "20:170:2"],
}


@pytest.fixture(scope="module")
def kitti_runs(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    folder = tmp_path_factory.mktemp("kitti_runs")
    half = folder / "half.toml"
    half.write_text("[detector]\ntarget_tracks = 400\nredetect_below = 300\n")
    paths = [folder / f"{name}.rrd" for name in KITTI_RUNS]
    for path, args in zip(paths, KITTI_RUNS.values(), strict=True):  # CLI runs in this process, one by one
        result = vslam("run", *VO, kitti_root, "--sequence", "00", *(a.format(half=half) for a in args),
                       "--detail", "standard", "-o", path)
        assert result.returncode == 0, result.stderr
    return paths


@pytest.fixture(scope="module")
def three(kitti_runs: list[Path], tmp_path_factory: pytest.TempPathFactory
          ) -> tuple[Path, subprocess.CompletedProcess[str]]:
    output = tmp_path_factory.mktemp("three") / "abc.rrd"
    return output, vslam("compare", *kitti_runs, "-o", output, "--labels", ",".join(KITTI_RUNS))


@pytest.mark.kitti
def test_three_real_runs_in_one_valid_recording(kitti_runs: list[Path],
                                                three: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    output, result = three
    assert result.returncode == 0, result.stderr
    done = subprocess.run([*rerun_executable(), "rrd", "verify", str(output)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    for prefix, run in zip("abc", kitti_runs, strict=True):
        for entity in ("/world/camera", "/world/trajectory/estimate", "/metrics/tracks/alive"):
            assert read_entity(output, f"/{prefix}{entity}").equals(read_entity(run, entity)), (prefix, entity)
    assert read_entity(output, "/c/world/camera")["frame"].to_list() == list(range(20, 170, 2))
    labels = list(KITTI_RUNS)
    for index, (prefix, label) in enumerate(zip("abc", labels, strict=True)):
        style = read_entity(output, f"/{prefix}/metrics/tracks/alive", static=True)
        assert style["SeriesLines:names"].to_list() == [[f"{label}: tracks alive"]]
        assert style["SeriesLines:widths"].to_list() == [[[2.5, 1.75, 1.0][index]]]  # graded, first widest
    compare = read_entity(output, "/__properties/compare", static=True).row(0, named=True)
    assert [compare[f"label_{p}"] for p in "abc"] == [[label] for label in labels]
    assert [compare[f"file_{p}"] for p in "abc"] == [[str(run.resolve())] for run in kitti_runs]
    assert read_config(output, "/b")["detector.target_tracks"] == 400

    summary = read_entity(output, "/report", static=True)["TextDocument:text"].to_list()[0][0]
    assert all(f"| {label} | /{p} | {run.resolve()} |" in summary
               for label, p, run in zip(labels, "abc", kitti_runs, strict=True)), summary

    views = _views(output)
    assert views["trajectories: base red, tracks400 orange, later purple, truth blue"]["contents"][:3] == [
        f"/{p}/world/trajectory/**" for p in "abc"]
    assert views["events"]["contents"] == ["/compare/events", "/a/events/**", "/b/events/**", "/c/events/**"]
    assert views[plot_title("tracks")]["contents"] == [f"/{p}/metrics/tracks/**" for p in "abc"]
    assert {f"{label}: frame" for label in labels} <= set(views)  # one tab per run

    report = json.loads(vslam("inspect", output, "--json").stdout)  # inspect reads all three back
    assert list(report["runs"]) == ["a", "b", "c"] and report["runs"]["c"]["frames"]["count"] == 75


@pytest.mark.kitti
def test_three_run_summary_rows_are_the_inspect_values(kitti_runs: list[Path],
                                                       three: tuple[Path, subprocess.CompletedProcess[str]]) -> None:
    _, result = three
    lines = result.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("run "))
    assert lines[start].split()[:3] == ["run", "frames", "t_err"]
    rows = [line.split() for line in lines[start + 1:start + 4]]
    assert [row[0] for row in rows] == list(KITTI_RUNS) and not lines[start + 4].strip()
    for row, run in zip(rows, kitti_runs, strict=True):
        inspected = json.loads(vslam("inspect", run, "--json").stdout)
        t_err = inspected["report_metrics"]["t_err"]
        assert t_err is not None and row[1:3] == [str(inspected["frames"]["count"]), f"{t_err:.2f}"], row
    # the metric table: every run's value and each further run against the first
    header = next(line for line in lines if line.startswith("metric"))
    assert header.split() == ["metric", "base", "tracks400", "later", "tracks400", "−", "base", "%", "later", "−",
                              "base", "%"]
    counts = next(line for line in lines if line.startswith("frames.count")).split()
    assert counts[1:] == ["85", "85", "75", "+0", "+0.0%", "-10", "-11.8%"]
    assert "tracks400 vs base:" in lines and "later vs base:" in lines
    assert any("detector.target_tracks: 800 → 400" in line for line in lines)


@pytest.mark.kitti
def test_three_runs_as_json_and_bad_labels(kitti_runs: list[Path], tmp_path: Path) -> None:
    output = tmp_path / "abc.rrd"
    result = vslam("compare", *kitti_runs, "-o", output, "--json")
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    assert [run["label"] for run in data["runs"]] == ["A", "B", "C"] and data["baseline"] == "A"
    assert [run["prefix"] for run in data["runs"]] == ["a", "b", "c"]
    assert [run["frames"] for run in data["runs"]] == [85, 85, 75]
    assert set(data["differences"]) == {"B", "C"}
    assert data["differences"]["C"]["frames.count"] == {"baseline": 85, "value": 75, "difference": -10,
                                                        "percent": pytest.approx(-100 * 10 / 85)}
    _one_line_exit(vslam_here("compare", *kitti_runs, "-o", tmp_path / "x.rrd", "--labels", "one,two"),
                   "3 labels are needed", "got 2")
    _one_line_exit(vslam_here("compare", kitti_runs[0], "-o", tmp_path / "x.rrd"), "two or more recordings")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["abc.rrd"]


@pytest.mark.kitti
def test_snapshot_of_three_runs(three: tuple[Path, subprocess.CompletedProcess[str]], tmp_path: Path) -> None:
    need_vulkan()
    output, _ = three
    # the smallest window --size allows, four of the views: that each run has its views (--view refuses a view the
    # blueprint does not have) and that the pictures are not blank is checked
    trajectories = "trajectories_base_red_tracks400_orange_later_purple_truth_blue"
    views = ("all", "base_frame", "later_world", trajectories)
    result = vslam("snapshot", output, "--frame", "120", "--size", "320x240", "--out", tmp_path,
                   *(arg for view in views for arg in ("--view", view)))
    assert result.returncode == 0, result.stderr
    assert {p.stem for p in tmp_path.glob("*.png")} == set(views)  # one tab per run: every run's views
    for name in ("all", trajectories):
        picture = cv2.imread(str(tmp_path / f"{name}.png"))
        assert picture is not None and picture.std() > 4, f"{name}.png looks blank"


def test_inputs_without_timing_or_tracks_give_blank_cells(runs: tuple[Path, Path], tmp_path: Path) -> None:
    """A recording of an external trajectory (camera poses and the estimate only) compares without error."""
    bare = tmp_path / "trajectory.rrd"
    with rr.RecordingStream("vslam", recording_id="bare", send_properties=False) as rec:
        rec.save(bare)
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
        for frame in FRAMES:
            rec.set_time("frame", sequence=frame)
            rec.log("/world/camera", rr.Transform3D(translation=[0.0, 0.0, float(frame)]))
        rec.log("/world/trajectory/estimate", rr.LineStrips3D([[[0.0, 0.0, float(f)] for f in FRAMES]]), static=True)
    result = compare_recordings(runs[0], bare, runs[1], tmp_path / "out.rrd")
    assert result.labels == ("A", "B", "C")
    assert read_entity(result.output, "/b/world/camera")["frame"].to_list() == FRAMES
    lines = format_differences(result).splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("run "))
    assert lines[start + 2].split()[:8] == ["B", "20", "–", "–", "–", "–", "–", "–"]
    tracks = next(line for line in lines if line.startswith("series.tracks_alive.mean")).split()
    assert tracks[2] == "–" and tracks[4] == "–"  # B's value and B − A blank, C's present
    _one_line_error(lambda: compare_recordings(runs[0], bare, runs[1], tmp_path / "x.rrd", labels=("A", "B")),
                    "3 labels are needed")
