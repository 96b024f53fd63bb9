"""The recorder draws the frames since its last flush together (tracks, candidate poses, series, the map's rows):
whatever the batches (the flushes come by wall-clock time), every frame's rows are the same, to the bit."""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr

from vslam.recording import Detail
from vslam.recording.front_end import log_candidates, log_tracks
from vslam.recording.map_backend.map import MapRecording
from vslam.recording.metrics import frame_metrics, log_series, series_metrics
from vslam_core.config import EngineConfig
from vslam_core.geometry import angle_between, invert_pose, rotation_angle
from vslam_core.pipeline import run_odometry
from vslam_core.results import FrameResult
from vslam_core.sources.base import Frame, FrameRange
from vslam_core.sources.kitti import KittiSource

Rows = dict[str, dict[int, dict[str, list[Any]]]]  # entity -> frame index -> component -> values given


class RowCatcher:
    """Stands in for `ColumnBuffer`: every row each entity is given, by frame, the batches taken apart again."""

    def __init__(self) -> None:
        self.rows: Rows = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))

    def add_rows(self, entity: str, frames: list[Frame], *parts: Any, lengths: list[list[int]]) -> None:
        for (_, values), counts in zip(parts, lengths, strict=True):
            assert len(counts) == len(frames)
            ends = np.cumsum(counts, dtype=int)
            for name, value in values.items():
                assert len(value) == (ends[-1] if len(ends) else 0), (entity, name)  # every instance in a row
                for frame, end, count in zip(frames, ends.tolist(), counts, strict=True):
                    self.rows[entity][frame.index][name].append(np.asarray(value[end - count:end]))

    def add_values(self, entity: str, frames: list[Frame], _make: Any, **values: list[Any]) -> None:
        for name, column in values.items():
            assert len(column) == len(frames)
            for frame, value in zip(frames, column, strict=True):
                self.rows[entity][frame.index][name].append(value)

    def add_scalars(self, entity: str, frames: list[Frame], values: list[float]) -> None:
        self.add_values(entity, frames, None, scalars=values)

    def add(self, entity: str, frame: Frame, *parts: Any, batch: bool = False) -> None:
        for _, values in parts:
            for name, value in values.items():
                self.rows[entity][frame.index][name].append(value)

    def add_scalar(self, entity: str, frame: Frame, value: float) -> None:
        self.rows[entity][frame.index]["scalars"].append(value)

    def add_instance(self, entity: str, frame: Frame, _make: Any, **values: Any) -> None:
        self.add(entity, frame, (None, values))


@pytest.fixture(scope="module")
def map_run(kitti_root: Path) -> tuple[KittiSource, list[FrameResult]]:
    """KITTI 05 frames 0:30, the map with the camera height for scale and the local-map search on: every entity
    drawn in batches has rows (tracks, candidates, the road, PnP overlays, the search)."""
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange.parse("0:30"))
    config = EngineConfig().with_backend("map")
    config = dataclasses.replace(config, scale="height", threads=1,
                                 map=dataclasses.replace(config.map, local_map_tracking=True))
    results: list[FrameResult] = []
    run_odometry(source, config, sinks=(lambda _, result: results.append(result),))
    return source, results


def drawn(source: KittiSource, results: list[FrameResult], batches: tuple[int, ...]) -> Rows:
    """Every row of the batched entities, the frames handed over in `batches` of these sizes."""
    catcher = RowCatcher()
    recording = MapRecording(rr.RecordingStream("vslam-test-batches"), catcher,  # type: ignore[arg-type]
                             source.intrinsics, Detail.FULL, source.ground_truth)
    frames = [Frame(r.index, r.timestamp, np.zeros((0, 0), np.uint8)) for r in results]
    assert sum(batches) == len(results)
    start = 0
    for size in batches:
        batch, batch_frames = results[start:start + size], frames[start:start + size]
        for frame, result in zip(batch_frames, batch, strict=True):
            assert result.mapping is not None
            recording.log_frame(frame, result, result.mapping)
        recording.log_pending()
        log_tracks(catcher, batch_frames, batch, full=True)  # type: ignore[arg-type]
        log_candidates(catcher, batch_frames, batch)  # type: ignore[arg-type]
        log_series(catcher, batch_frames, batch, [frozenset()] * size, source.ground_truth, None)  # type: ignore[arg-type]
        start += size
    return catcher.rows


def test_every_frames_rows_are_the_same_whatever_the_batches(map_run: tuple[KittiSource, list[FrameResult]]) -> None:
    source, results = map_run
    whole = drawn(source, results, (30,))
    for entity in ("/world/camera/image/flow", "/world/camera/image/corners", "/world/candidates", "/tracking",
                   "/world/camera/image/landmarks", "/world/camera/image/reprojection", "/local_map",
                   "/metrics/road/measured_step", "/metrics/tracking/pnp_inliers", "/metrics/map_scale/step_over_truth",
                   "/metrics/angle_error/translation_direction_deg"):
        assert whole[entity], f"{entity}: no rows"
    assert len(whole["/world/camera/image/flow"]) == len(whole["/tracking"]) == 30
    assert sum(len(row["positions"][0]) for row in whole["/world/camera/image/local_map/projected"].values()) > 0
    for batches in ((1, 3, 7, 19), (13, 1, 1, 15)):
        split = drawn(source, results, batches)
        assert split.keys() == whole.keys()
        for entity, rows in whole.items():
            assert split[entity].keys() == rows.keys(), entity
            for index, row in rows.items():
                for name, values in row.items():
                    for a, b in zip(values, split[entity][index][name], strict=True):
                        assert np.array_equal(np.asarray(a), np.asarray(b)), (entity, index, name)  # to the bit


def test_one_frames_series_are_its_values_in_a_batch(map_run: tuple[KittiSource, list[FrameResult]]) -> None:
    """`frame_metrics` (a frame at a time, as another pipeline's frames are recorded: `vslam.log`) gives what the
    batch gives that frame, and leaves out what it is told to."""
    source, results = map_run
    gt = source.ground_truth
    batch = series_metrics(results, gt)
    for position, result in enumerate(results):
        alone = frame_metrics(result, gt)
        assert alone == {name: float(values[list(where).index(position)]) for name, (where, values) in batch.items()
                         if position in where}
    assert "position_m" not in frame_metrics(results[5], gt, frozenset({"position_m"}))
    assert batch["alive"][1].tolist() == [r.live_tracks for r in results]


def test_the_series_are_what_they_say(map_run: tuple[KittiSource, list[FrameResult]]) -> None:
    """Each frame's series against the geometry written out a frame at a time."""
    source, results = map_run
    gt = source.ground_truth
    assert gt is not None
    stepped = 0
    for result in results:
        values = frame_metrics(result, gt)
        truth = gt[result.position]
        position = np.linalg.norm(truth[:3, 3] - result.T_world_cam[:3, 3])
        assert values["position_m"] == pytest.approx(position, abs=1e-12)
        heading = np.degrees(rotation_angle(truth[:3, :3].T @ result.T_world_cam[:3, :3]))
        assert values["heading_deg"] == pytest.approx(heading, abs=1e-9)
        fates = result.fate_counts()
        assert (values["inliers"], values["fb_rejected"]) == (fates["inlier"], fates["fb_rejected"])
        if result.T_key_cur is None or len(result.candidate_poses) != 4:
            continue
        stepped += 1
        first, second = sorted((c.in_front for c in result.candidate_poses), reverse=True)[:2]
        assert values["chirality_margin"] == first - second
        assert values["rotation_deg"] == pytest.approx(np.degrees(rotation_angle(result.T_key_cur[:3, :3])), abs=1e-9)
        true_step = (invert_pose(gt[result.keyframe_position]) @ truth)[:3, 3]
        direction = np.degrees(angle_between(true_step, result.T_key_cur[:3, 3]))
        assert values["translation_direction_deg"] == pytest.approx(direction, abs=1e-6)
    assert stepped > 20
