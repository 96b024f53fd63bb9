"""`crop_recording`: a real `vslam run` recording cut to frames 10:20 keeps exactly those rows, all static
data and the embedded blueprint, and stays a valid file; bad inputs fail with one-line `RecordingError`s."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow as pa
import pytest
import rerun as rr
from cli_helpers import vslam
from polars.testing import assert_frame_equal
from rerun.chunk import Chunk, RrdReader

from vslam.rrd.crop import CropSummary, crop_recording
from vslam.rrd.inspect import inspect_recording
from vslam.rrd.provenance import read_properties
from vslam.rrd.read import RecordingError, read_entity, rerun_binary

ROOT = Path(__file__).resolve().parents[1]
START, END = 10, 20
# one row per frame each
ENTITIES = ["/world/camera", "/world/camera/image", "/world/camera/image/flow", "/metrics/tracks/alive"]


@pytest.fixture(scope="module")
def full(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real 30-frame recording of the synthetic street (full detail, embedded blueprint)."""
    path = tmp_path_factory.mktemp("crop") / "full.rrd"
    done = vslam("run", "--frames", "0:30", "--backend", "vo", "--detail", "full", "-o", path,
                 env={"RERUN_STRICT": "1"})
    assert done.returncode == 0, done.stderr
    return path


@pytest.fixture(scope="module")
def cropped(full: Path) -> tuple[Path, CropSummary]:
    out = full.parent / "cropped" / "bug_10-20.rrd"
    out.parent.mkdir()
    return out, crop_recording(full, (START, END), out)


def rerun_cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([rerun_binary(), *map(str, args)], capture_output=True, text=True, timeout=120)


def chunks_by_id(path: Path, *, blueprint: bool = False, static: bool | None = None) -> dict[str, pa.RecordBatch]:
    """Every chunk of the recording (or blueprint) store, by chunk id, as Arrow (row ids included)."""
    reader = RrdReader(path)
    store = reader.blueprints()[0] if blueprint else reader.recordings()[0]
    stream = reader.stream(store=store)
    if static is not None:
        stream = stream.filter(is_static=static)
    return {chunk.id: chunk.to_record_batch() for chunk in stream.to_chunks()}


def by_row(table: pl.DataFrame) -> pl.DataFrame:
    return table.sort(["frame", "rerun.controls.RowId"])


# --- the cropped real recording ------------------------------------------------------------------------


def test_output_verifies(cropped: tuple[Path, CropSummary]) -> None:
    out, _ = cropped
    result = rerun_cli("rrd", "verify", out)
    assert result.returncode == 0, result.stderr
    assert "verified without error" in result.stdout + result.stderr


def test_summary_and_size(full: Path, cropped: tuple[Path, CropSummary]) -> None:
    out, summary = cropped
    assert (summary.first_frame, summary.last_frame, summary.frame_count) == (10, 19, 10)
    assert summary.output == out
    assert summary.input_bytes == full.stat().st_size
    assert summary.output_bytes == out.stat().st_size
    # 10 of 30 frames, plus what every crop keeps whole (~0.55 MB here: static data, blueprint); all 30 kept
    # would be ~100 %, and how rows fall into chunks follows the wall clock (the share moves by a few %)
    assert summary.output_bytes < 0.6 * summary.input_bytes
    assert [p.name for p in out.parent.iterdir()] == [out.name]  # no temporary files left behind


@pytest.mark.parametrize("entity", ENTITIES)
def test_rows_are_exactly_the_range_with_original_content(full: Path, cropped: tuple[Path, CropSummary],
                                                          entity: str) -> None:
    out, _ = cropped
    if entity == "/metrics/tracks/alive" and read_entity(full, entity).is_empty():
        entity = "/metrics/tracks"  # the layout with one entity per plot (alive, new corners, rejects)
    got = read_entity(out, entity)
    assert got["frame"].to_list() == list(range(START, END))
    original = read_entity(full, entity).filter(pl.col("frame").is_between(START, END, closed="left"))
    # same values, same row ids, same `time` (column order follows the first chunk read: may differ)
    assert_frame_equal(by_row(got), by_row(original), check_column_order=False)


def test_no_temporal_row_outside_the_range(full: Path, cropped: tuple[Path, CropSummary]) -> None:
    out, _ = cropped

    def rows(path: Path) -> dict[bytes, int]:
        """Row id -> frame of every temporal row (vslam logs everything on the `frame` timeline)."""
        return {row_id: frame for batch in chunks_by_id(path, static=False).values()
                for row_id, frame in zip(batch.column("rerun.controls.RowId").to_pylist(),
                                         batch.column("frame").to_pylist(), strict=True)}

    kept = rows(out)
    assert set(kept.values()) == set(range(START, END))
    # exactly the original rows in the range, no more, no fewer (row ids are kept)
    assert kept == {row_id: frame for row_id, frame in rows(full).items() if START <= frame < END}


def test_static_data_is_kept_verbatim(full: Path, cropped: tuple[Path, CropSummary]) -> None:
    """Every static chunk but the run properties and the recording name (rewritten: see below)."""
    out, _ = cropped
    rewritten = {"/__properties", "/__properties/run"}
    original = {k: v for k, v in chunks_by_id(full, static=True).items()
                if v.schema.metadata[b"rerun:entity_path"].decode() not in rewritten}
    kept = {k: v for k, v in chunks_by_id(out, static=True).items()
            if v.schema.metadata[b"rerun:entity_path"].decode() not in rewritten}
    assert kept.keys() == original.keys()
    for chunk_id, batch in original.items():
        assert kept[chunk_id].equals(batch), chunk_id
    pinhole = read_entity(out, "/world/camera/image", static=True)
    assert {"Pinhole:image_from_camera", "Pinhole:resolution"} <= set(pinhole.columns)
    assert_frame_equal(pinhole, read_entity(full, "/world/camera/image", static=True))


def test_properties_and_recording_name(full: Path, cropped: tuple[Path, CropSummary]) -> None:
    """The cropped file says which frames it holds (issue 12, item 10), and keeps everything else."""
    out, _ = cropped
    before = read_properties(full, "/__properties/run")
    after = read_properties(out, "/__properties/run")
    assert before["frames"] == "0:30" and before["frame_count"] == "30"
    assert after["frames"] == "10:20" and after["frame_count"] == "10" and after["cropped_from"] == "0:30"
    assert after["name"] == "vslam synthetic-street frames 10:20 scale gt"
    assert {k: v for k, v in after.items() if k not in ("frames", "frame_count", "cropped_from", "name")} == \
        {k: v for k, v in before.items() if k not in ("frames", "frame_count", "name")}
    assert_frame_equal(read_entity(out, "/__properties/config", static=True),
                       read_entity(full, "/__properties/config", static=True))
    report = inspect_recording(out)
    assert report["recording_name"] == "vslam synthetic-street frames 10:20 scale gt"
    assert report["properties"]["frame_count"] == "10"
    assert RrdReader(out).recordings() == RrdReader(full).recordings()  # same application and recording id


def test_blueprint_is_kept(full: Path, cropped: tuple[Path, CropSummary]) -> None:
    """The source's blueprint store, its chunks (ids, row ids, content) and its activation command."""
    out, _ = cropped
    source_blueprints = RrdReader(full).blueprints()
    assert len(source_blueprints) == 1
    assert RrdReader(out).blueprints() == source_blueprints  # same kind, application id, store id
    original, kept = chunks_by_id(full, blueprint=True), chunks_by_id(out, blueprint=True)
    assert len(original) > 10 and kept.keys() == original.keys()
    for chunk_id, batch in original.items():
        assert kept[chunk_id].equals(batch), chunk_id

    def activation(path: Path) -> list[str]:
        printed = rerun_cli("rrd", "print", path)
        assert printed.returncode == 0, printed.stderr
        return [line for line in printed.stdout.splitlines() if line.startswith("BlueprintActivationCommand")]

    commands = activation(out)
    assert commands == activation(full)
    assert len(commands) == 1 and "make_active: false, make_default: true" in commands[0]


# --- chunks holding many frames, data without `frame`, files without blueprint -------------------------


@pytest.fixture(scope="module")
def columns_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One chunk with frames 0..29, a series on another timeline only, static data; no blueprint."""
    path = tmp_path_factory.mktemp("columns") / "columns.rrd"
    strict = rr.strict_mode()
    rr.set_strict_mode(True)
    try:
        rec = rr.RecordingStream("crop-test", recording_id="columns", send_properties=False)
        rec.save(path)
        rec.send_recording_name("columns")
        rec.log("/world", rr.ViewCoordinates.RDF, static=True)
        frames = np.arange(30)
        rec.send_columns("/series", indexes=[rr.TimeColumn("frame", sequence=frames)],
                         columns=rr.Scalars.columns(scalars=frames * 10.0))
        rec.send_columns("/ticks", indexes=[rr.TimeColumn("tick", sequence=np.arange(5))],
                         columns=rr.Scalars.columns(scalars=np.arange(5.0)))
        rec.disconnect()
    finally:
        rr.set_strict_mode(strict)
    return path


def test_rows_are_filtered_inside_a_chunk(columns_recording: Path, tmp_path: Path) -> None:
    source = RrdReader(columns_recording).stream().filter(content="/series").to_chunks()
    assert len(source) == 1 and source[0].num_rows == 30  # the case under test: one chunk, many frames
    out = tmp_path / "out.rrd"
    summary = crop_recording(columns_recording, (START, END), out)
    assert (summary.first_frame, summary.last_frame, summary.frame_count) == (10, 19, 10)
    series = read_entity(out, "/series")
    assert series["frame"].to_list() == list(range(START, END))
    assert [v[0] for v in series["Scalars:scalars"].to_list()] == [10.0 * f for f in range(START, END)]
    chunk: Chunk = RrdReader(out).stream().filter(content="/series").to_chunks()[0]
    assert chunk.id == source[0].id  # the row subset keeps the chunk's identity and row ids
    assert_frame_equal(series, read_entity(columns_recording, "/series").filter(pl.col("frame") >= START)
                       .filter(pl.col("frame") < END))
    ticks = read_entity(out, "/ticks")  # no `frame` time: kept as is
    assert ticks["tick"].to_list() == list(range(5))
    assert read_entity(out, "/world", static=True).height == 1
    assert RrdReader(out).blueprints() == []
    assert rerun_cli("rrd", "verify", out).returncode == 0


def test_range_beyond_the_end_keeps_what_exists(columns_recording: Path, tmp_path: Path) -> None:
    summary = crop_recording(columns_recording, (25, 1000), tmp_path / "tail.rrd")
    assert (summary.first_frame, summary.last_frame, summary.frame_count) == (25, 29, 5)


# --- errors --------------------------------------------------------------------------------------------


def assert_fails(source: Path, frames: tuple[int, int], output: Path, *fragments: str) -> None:
    with pytest.raises(RecordingError) as caught:
        crop_recording(source, frames, output)
    message = str(caught.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    assert not output.exists() or output.read_text() == "previous"
    assert not [p for p in output.parent.iterdir() if p.name.startswith(f".{output.name}.")]  # no temp left


def test_missing_source(tmp_path: Path) -> None:
    assert_fails(tmp_path / "nope.rrd", (0, 5), tmp_path / "out.rrd", "nope.rrd", "no such recording")


def test_folder_source(tmp_path: Path) -> None:
    assert_fails(tmp_path, (0, 5), tmp_path / "out.rrd", str(tmp_path), "folder")


def test_truncated_source_is_cropped_from_what_it_holds(full: Path, tmp_path: Path) -> None:
    """A recording cut mid-message (a killed run) is read up to its last whole message."""
    truncated = tmp_path / "truncated.rrd"
    truncated.write_bytes(full.read_bytes()[: full.stat().st_size - 1000])
    summary = crop_recording(truncated, (0, 5), tmp_path / "out.rrd")
    assert (summary.first_frame, summary.last_frame) == (0, 4)
    assert rerun_cli("rrd", "verify", tmp_path / "out.rrd").returncode == 0
    assert RrdReader(tmp_path / "out.rrd").blueprints()  # the blueprint came along


def test_unfinished_source_without_footer_is_cropped(tmp_path: Path) -> None:
    path = tmp_path / "unfinished.rrd"
    rec = rr.RecordingStream("crop-test", recording_id="unfinished", send_properties=False)
    rec.save(path, write_footer=False)
    rec.set_time("frame", sequence=1)
    rec.log("/a", rr.Points3D([[0.0, 0.0, 0.0]]))
    rec.disconnect()
    summary = crop_recording(path, (0, 5), tmp_path / "out.rrd")
    assert (summary.first_frame, summary.last_frame, summary.frame_count) == (1, 1, 1)
    assert rerun_cli("rrd", "verify", tmp_path / "out.rrd").returncode == 0


@pytest.mark.parametrize("content", [b"", b"hello, not a recording\n", b"RRF2" + bytes(200)])
def test_not_a_rerun_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "notes.rrd"
    path.write_bytes(content)
    assert_fails(path, (0, 5), tmp_path / "out.rrd", "notes.rrd")


def test_range_selecting_no_frame_names_the_recordings_range(full: Path, tmp_path: Path) -> None:
    output = tmp_path / "out.rrd"
    assert_fails(full, (100, 200), output, "full.rrd", "100:200", "select no frame", "0:30")


@pytest.mark.parametrize("frames", [(20, 10), (10, 10)])
def test_empty_range(full: Path, tmp_path: Path, frames: tuple[int, int]) -> None:
    assert_fails(full, frames, tmp_path / "out.rrd", "full.rrd", f"{frames[0]}:{frames[1]}")


def test_output_equal_to_source(full: Path, tmp_path: Path) -> None:
    before = full.stat().st_size
    for output in (full, full.parent / "." / full.name, full.parent.parent / full.parent.name / full.name):
        with pytest.raises(RecordingError, match="must not be the source"):
            crop_recording(full, (START, END), output)
    link = tmp_path / "link.rrd"
    link.symlink_to(full)
    with pytest.raises(RecordingError, match="must not be the source"):
        crop_recording(full, (START, END), link)
    assert full.stat().st_size == before


def test_failure_leaves_an_existing_output_untouched(full: Path, tmp_path: Path) -> None:
    output = tmp_path / "out.rrd"
    output.write_text("previous")
    assert_fails(full, (500, 600), output, "select no frame")
    assert output.read_text() == "previous"


def test_missing_cli_is_a_clean_error(full: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RERUN_CLI_PATH", str(tmp_path / "no-rerun-here"))
    assert_fails(full, (START, END), tmp_path / "out.rrd", "full.rrd", "rerun CLI")


def test_rerun_binary_is_the_sdk_one() -> None:
    binary = Path(rerun_binary())
    assert binary.exists() and shutil.which(str(binary))
