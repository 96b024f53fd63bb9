"""Drift attribution: each frame's own relative pose error against the ground truth, in the engine
(`vslam_core.trajectory.drift`), the recording and `vslam inspect`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import VO, vslam
from kitti_runs import link_images

from vslam.recording.columns import EVENTS, EVENTS_AT_END
from vslam.recording.drift import (
    DRIFT_ENTITY,
    DRIFT_LIFT_M,
    DRIFT_RADIUS_M,
    LINKS_ENTITY,
    SERIES,
    DriftRecording,
    FrameTrail,
    drift_colours,
)
from vslam.rrd.inspect import format_report, inspect_recording
from vslam.rrd.read import read_entity, read_events
from vslam_core.sources.base import Frame, rebase_poses
from vslam_core.trajectory.drift import frame_errors, worst_frames
from vslam_core.trajectory.io import read_kitti_poses
from vslam_core.trajectory.metrics import position_errors, sim3_aligned

ROOT = Path(__file__).resolve().parents[1]
KITTI_K = "718.856,718.856,607.1928,185.2157"
KINK_FRAME, KINK_DEG = 40, 2.0
BURST, BURST_FACTOR = range(70, 75), 1.3


def rotation_y(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def faulty_estimate(gt: np.ndarray) -> np.ndarray:
    """`gt` re-chained from its relative motions with a rotation kink at `KINK_FRAME` (that step's rotation
    turned by `KINK_DEG`) and the step lengths of `BURST` × `BURST_FACTOR`."""
    estimate = [gt[0]]
    for i in range(1, len(gt)):
        step = np.linalg.inv(gt[i - 1]) @ gt[i]
        if i == KINK_FRAME:
            step[:3, :3] = step[:3, :3] @ rotation_y(KINK_DEG)
        if i in BURST:
            step[:3, 3] *= BURST_FACTOR
        estimate.append(estimate[-1] @ step)
    return np.array(estimate)


@pytest.fixture(scope="module")
def gt(kitti_root: Path) -> np.ndarray:
    return rebase_poses(read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=100))


def test_planted_faults_rank_first(gt: np.ndarray) -> None:
    errors = frame_errors(gt, faulty_estimate(gt))
    rotation = worst_frames(errors.rotation_deg, 10)
    translation = worst_frames(errors.translation_m, 10)
    assert rotation[0][0] == KINK_FRAME and rotation[0][1] == pytest.approx(KINK_DEG, abs=1e-6)
    assert len(rotation) == 1  # nothing else turned: frames without error are not ranked
    assert sorted(f for f, _ in translation[:5]) == list(BURST)
    assert all(f == KINK_FRAME for f, _ in translation[5:])
    assert np.allclose(errors.scale_ratio[list(BURST)], BURST_FACTOR)
    assert np.allclose(errors.translation_pct[list(BURST)], 100 * (BURST_FACTOR - 1))


def test_a_kink_is_one_frames_contribution_unlike_the_absolute_error(gt: np.ndarray) -> None:
    estimate = faulty_estimate(gt)
    errors = frame_errors(gt, estimate)
    after = slice(KINK_FRAME + 1, BURST[0])
    assert np.all(errors.rotation_deg[after] < 1e-6) and np.all(errors.translation_m[after] < 1e-6)
    absolute = position_errors(gt, estimate)
    assert absolute[BURST[0] - 1] > 10 * absolute[KINK_FRAME + 1] > 0  # keeps growing after the kink


def test_a_perfect_estimate_contributes_nothing(gt: np.ndarray) -> None:
    errors = frame_errors(gt, gt.copy())
    assert np.allclose(errors.rotation_deg, 0, atol=1e-5) and np.allclose(errors.translation_m, 0, atol=1e-9)
    assert np.allclose(errors.translation_pct, 0, atol=1e-6) and np.allclose(errors.scale_ratio, 1)
    # known only up to scale (--scale none): zero again after Sim(3) alignment
    unit = gt.copy()
    unit[:, :3, 3] *= 0.37
    aligned = frame_errors(gt, sim3_aligned(gt, unit))
    assert np.allclose(aligned.translation_m, 0, atol=1e-6) and np.allclose(aligned.scale_ratio, 1)


def test_series_taken_in_batches_are_the_whole_runs_frame_errors(gt: np.ndarray) -> None:
    """The recorder takes each frame's drift series at its flushes (`DriftRecording.take_series`), for however many
    frames came since the last: whatever the batches, each frame's values are its step from the frame before it."""
    estimate = faulty_estimate(gt)
    drift = DriftRecording(gt, online=True, trail=FrameTrail())
    taken: list[tuple[int, dict[str, float]]] = []
    position = 0
    for batch in (1, 3, 1, 7, 28, 32, 28):  # 100 frames; batches starting at the kink (40) and in the burst (72)
        for _ in range(batch):
            drift.add(Frame(position + 5, None, np.zeros((0, 0), np.uint8)), position, estimate[position])
            position += 1
        taken += [(frame.index, values) for frame, values in drift.take_series()]
    assert drift.take_series() == [] and [index for index, _ in taken] == list(range(5, 105))
    whole = frame_errors(gt, estimate)
    for name in SERIES:
        expected = getattr(whole, name)
        recorded = np.array([values.get(name, np.nan) for _, values in taken])
        assert np.array_equal(recorded, expected, equal_nan=True), name  # to the bit: the batches do not matter
    assert np.array(drift.rows).shape == (100, 4)
    assert taken[KINK_FRAME][1]["rotation_deg"] == pytest.approx(KINK_DEG, abs=1e-6)


def test_worst_frames_skips_nan_and_names_source_frames() -> None:
    values = np.array([0.0, 3.0, np.nan, 5.0, 3.0])
    assert worst_frames(values, 3, np.array([10, 12, 14, 16, 18])) == [(16, 5.0), (12, 3.0), (18, 3.0)]
    assert worst_frames(values, 10) == [(3, 5.0), (1, 3.0), (4, 3.0)]  # no error, no rank
    standing = frame_errors(np.repeat(np.eye(4)[None], 3, axis=0), np.repeat(np.eye(4)[None], 3, axis=0))
    assert np.isnan(standing.translation_pct[1:]).all()  # no ground-truth step: no percentage
    colours = drift_colours(np.array([0.0, 5.0, 50.0, np.nan]))
    assert colours[0].tolist() == [40, 220, 60] and colours[1].tolist() == colours[2].tolist() == [230, 30, 30]
    assert colours[3].tolist() == [150, 150, 150]


@pytest.fixture(scope="module")
def kitti_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("drift")
    rrd, trajectory = out / "run.rrd", out / "run.txt"
    result = vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "10:50", "--detail", "summary", "-o", rrd,
                   "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    return rrd, trajectory


@pytest.mark.kitti
def test_inspect_ranks_the_recorded_per_frame_errors(kitti_run: tuple[Path, Path], kitti_root: Path) -> None:
    rrd, trajectory = kitti_run
    drift = json.loads(vslam("inspect", rrd, "--json").stdout)["drift"]
    gt = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=50)[10:]
    errors = frame_errors(gt, read_kitti_poses(trajectory))
    assert len(drift["rotation"]) == len(drift["translation"]) == 10
    # the values are those of the run's trajectory (its file rounds the poses) against the ground truth
    for key, column, tolerance in (("rotation", "deg", 1e-5), ("translation", "m", 1e-6)):
        values = getattr(errors, "rotation_deg" if key == "rotation" else "translation_m")
        entries = drift[key]
        assert all(10 <= e["frame"] < 50 for e in entries) and len({e["frame"] for e in entries}) == 10
        ranked = [e[column] for e in entries]
        assert ranked == sorted(ranked, reverse=True) and ranked[-1] >= 0
        assert np.allclose(ranked, [values[e["frame"] - 10] for e in entries], atol=tolerance)
        assert ranked[0] == pytest.approx(values.max(), abs=tolerance)
        assert ranked[-1] >= np.sort(values)[-10] - tolerance  # the top 10, up to the file's rounding
    for entry in drift["translation"]:
        assert entry["pct"] == pytest.approx(errors.translation_pct[entry["frame"] - 10], abs=1e-4)
        assert isinstance(entry["reasons"], list)
    text = vslam("inspect", rrd).stdout
    assert "where the error comes from" in text
    assert f"{drift['rotation'][0]['frame']:>5}  {drift['rotation'][0]['deg']:10.3f}" in text


@pytest.mark.kitti
def test_recording_holds_drift_series_trajectory_links_and_events(kitti_run: tuple[Path, Path]) -> None:
    rrd, _ = kitti_run
    for name in ("rotation_deg", "translation_m", "translation_pct", "scale_ratio"):
        series = read_entity(rrd, f"/metrics/drift/{name}")
        assert series["frame"].to_list() == list(range(10, 50)), name
        assert not read_entity(rrd, f"/metrics/drift/{name}", static=True).is_empty()  # legend
    segments = read_entity(rrd, DRIFT_ENTITY)
    assert segments["frame"].to_list() == list(range(11, 50))  # a segment per frame after the first: the past only
    assert all(len(row) == 1 and len(row[0]) == 2 for row in segments["LineStrips3D:strips"].to_list())
    assert all(len(row) == 1 for row in segments["LineStrips3D:colors"].to_list())
    strips = read_entity(rrd, DRIFT_ENTITY, static=True)
    assert strips["LineStrips3D:radii"].to_list()[-1] == [pytest.approx(DRIFT_RADIUS_M)]  # a thin ribbon
    lift = [row for row in strips["Transform3D:translation"].to_list() if row is not None][-1]
    assert list(lift[0]) == pytest.approx([0.0, -DRIFT_LIFT_M, 0.0])  # above the estimate: no z-fighting
    links = read_entity(rrd, LINKS_ENTITY, static=True)
    assert len(links["LineStrips3D:strips"].to_list()[-1]) == 4  # frames 10, 20, 30, 40
    # the hover's frame numbers are `frame_index`: a component named `frame` would clash with the timeline
    assert [row[0] for row in segments["frame_index"].to_list()] == list(range(11, 50))
    assert [row for row in links["frame_index"].to_list() if row is not None][-1] == [10, 20, 30, 40]
    assert "frame" not in strips.columns and "frame" not in links.columns
    events = [(frame, text) for frame, _, text in read_events(rrd) if "drift:" in text]
    assert len(events) == 20 and all("health" in e and e.startswith(f"frame {frame}: ") for frame, e in events)
    # the ranking is written when the run ends, beside the frames' own events; one row a frame in each (the
    # viewer's level filter shows a wrong level, or drops a row, when two rows of a text log share a time)
    at_end = read_entity(rrd, EVENTS_AT_END)
    assert sum(len(row) for row in at_end["TextLog:text"].to_list()) == 20
    for entity in (EVENTS, EVENTS_AT_END):
        frames = read_entity(rrd, entity)["frame"].to_list()
        assert len(frames) == len(set(frames)), entity
    report = read_entity(rrd, "/report", static=True)["TextDocument:text"].to_list()[-1][0]
    assert "Where the error comes from" in report and "red ≥ 5 %" in report


def test_no_ground_truth_no_drift(kitti_root: Path, tmp_path: Path) -> None:
    images = link_images(kitti_root, tmp_path / "images", range(6), sequence="00")
    rrd = tmp_path / "folder.rrd"
    result = vslam("run", *VO, images, "--intrinsics", KITTI_K, "--detail", "summary", "-o", rrd)
    assert result.returncode == 0, result.stderr
    report = json.loads(vslam("inspect", rrd, "--json").stdout)
    assert report["drift"] is None
    assert "where the error comes from" not in format_report(inspect_recording(rrd))
    assert read_entity(rrd, DRIFT_ENTITY, static=True).is_empty() and read_entity(rrd, DRIFT_ENTITY).is_empty()


@pytest.mark.kitti
def test_scale_none_attributes_the_aligned_estimate(kitti_root: Path, tmp_path: Path) -> None:
    rrd, trajectory = tmp_path / "none.rrd", tmp_path / "none.txt"
    result = vslam("run", *VO, kitti_root, "--sequence", "00", "--frames", "0:25", "--scale", "none",
                   "--detail", "summary", "-o", rrd, "--trajectory-out", trajectory)
    assert result.returncode == 0, result.stderr
    gt = rebase_poses(read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=25))
    errors = frame_errors(gt, sim3_aligned(gt, read_kitti_poses(trajectory)))  # unit steps: aligned first
    series = read_entity(rrd, "/metrics/drift/translation_m")
    assert series["frame"].to_list() == list(range(25))
    assert np.allclose([v[0] for v in series["Scalars:scalars"].to_list()], errors.translation_m, atol=1e-6)
    drift = inspect_recording(rrd)["drift"]
    assert drift["translation"][0]["m"] == pytest.approx(errors.translation_m.max(), abs=1e-6)
