"""--scale none: a frame the map cannot place takes its step's length from the tracks of the two frames before it
(`map_scale.TwoViewLength`), not from the map's last speed, which a car leaving a turn outruns (issue 53)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from vslam.recording.recorder import Recorder
from vslam.rrd.read import read_entity
from vslam_core.config import EngineConfig, MapConfig
from vslam_core.geometry import invert_pose, pose_matrix, so3_exp
from vslam_core.mapping.map_scale import TwoViewLength, triangulated_points
from vslam_core.pipeline import RunResult, run_odometry
from vslam_core.results import TrackFate
from vslam_core.sources.base import CameraIntrinsics, FrameRange
from vslam_core.sources.kitti import KittiSource
from vslam_core.trajectory.metrics import ate, scale_errors, sim3_aligned

CAMERA = CameraIntrinsics(700.0, 700.0, 620.0, 188.0, 1241, 376)


def pixels(points: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:  # noqa: N803
    """(N, 2) pixels of (N, 3) world points seen from a camera at `T_world_cam`."""
    in_cam = points @ invert_pose(T_world_cam)[:3, :3].T + invert_pose(T_world_cam)[:3, 3]
    return (in_cam[:, :2] / in_cam[:, 2:]) * [CAMERA.fx, CAMERA.fy] + [CAMERA.cx, CAMERA.cy]


def frame(position: int, ids: np.ndarray, before: np.ndarray, now: np.ndarray, T_key_cur=None,  # noqa: ANN001, N803
          hz: float = 5.0) -> SimpleNamespace:
    return SimpleNamespace(position=position, keyframe_position=position - 1, track_ids=ids, track_prev=before,
                           track_cur=now, track_fate=np.full(len(ids), TrackFate.INLIER, np.uint8), T_key_cur=T_key_cur,
                           timestamp=position / hz)


@pytest.mark.parametrize("seed", range(5))
def test_the_step_length_is_measured_on_points_the_two_frames_before_triangulate(seed: int) -> None:
    """Exact data at 5 Hz: a car accelerating through a turn (steps 1.0 then 1.6 map units), the frame's rotation
    and direction given, its length guessed at the old speed: the length comes back to the digit."""
    rng = np.random.default_rng(seed)
    points = np.column_stack((rng.uniform(-15, 15, 300), rng.uniform(-2, 2, 300), rng.uniform(8, 60, 300)))
    poses = [pose_matrix(so3_exp(np.array([0.0, 0.05 * k, 0.0])), np.array([0.0, 0.0, z]))
             for k, z in enumerate((0.0, 1.0, 2.6))]
    ids = np.arange(300)
    seen = [pixels(points, pose) for pose in poses]
    step = invert_pose(poses[1]) @ poses[2]
    guess = step.copy()
    guess[:3, 3] *= 1.0 / np.linalg.norm(step[:3, 3])  # the map's speed: one unit a frame
    two_view = poses[1] @ guess
    length = TwoViewLength(CAMERA.K, CAMERA)

    def place(source: str, held: set[int] = frozenset(), config: MapConfig = MapConfig(),  # noqa: B008
              hz: float = 5.0) -> np.ndarray:
        pose, said = length.place(two_view, frame(2, ids, seen[1], seen[2], guess, hz), None, None,
                                  lambda p: poses[p], held, config)
        assert said == source
        return pose

    length.remember(frame(1, ids, seen[0], seen[1]))
    np.testing.assert_allclose(place("tracks"), poses[2], atol=1e-6)
    # the frame before it held (its pose a copy of an older one): nothing to triangulate from, the map's speed
    np.testing.assert_array_equal(place("speed", held={1}), two_view)
    # off: the map's speed, as before; and frames 0.1 s apart (10 Hz), over which the speed barely changes
    np.testing.assert_array_equal(place("speed", config=MapConfig(relative_step_min_points=0)), two_view)
    length.remember(frame(1, ids, seen[0], seen[1], hz=10.0))
    np.testing.assert_array_equal(place("speed", hz=10.0), two_view)
    # too few tracks reach back two frames: the last step's length (1.0 unit a frame), not the map's speed
    length.remember(frame(1, ids[:5], seen[0][:5], seen[1][:5]))
    assert np.linalg.norm(place("last step")[:3, 3] - poses[1][:3, 3]) == pytest.approx(1.0, rel=1e-6)

def test_points_behind_a_camera_or_on_parallel_rays_are_not_used() -> None:
    T_world_a, T_world_b = np.eye(4), pose_matrix(np.eye(3), np.array([1.0, 0.0, 0.0]))  # noqa: N806
    ahead, far = np.array([[0.5, 0.0, 10.0]]), np.array([[0.5, 0.0, 1e6]])

    def normalised(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        return (pixels(points, pose) - [CAMERA.cx, CAMERA.cy]) / [CAMERA.fx, CAMERA.fy]

    both = np.vstack((ahead, far))
    a = np.vstack((normalised(both, T_world_a), [[-0.15, 0.0]]))
    b = np.vstack((normalised(both, T_world_b), [[-0.05, 0.0]]))  # rays that meet 10 units behind both cameras
    world, rows = triangulated_points(T_world_a, T_world_b, a, b, min_deg=1.0)
    assert rows.tolist() == [0]
    np.testing.assert_allclose(world, ahead, atol=1e-9)


@pytest.mark.kitti
def test_a_car_accelerating_out_of_a_turn_at_half_the_frame_rate_keeps_its_scale(kitti_root: Path,
                                                                                   tmp_path: Path) -> None:
    """KITTI 05 frames 116:200 at every 2nd frame (5 Hz), `--scale none`: PnP fails through the turn and the car
    speeds up as it leaves it (0.7 → 1.6 m a step). Measured (2026-12-04): ATE after Sim(3) 0.11 m, the steps'
    mean scale error 2.2 %; with the map's last speed instead (`relative_step_min_points = 0`) 1.87 m and 29.3 %."""
    source = KittiSource(kitti_root, sequence="05", frames=FrameRange.parse("116:200:2"))
    config, path, results = EngineConfig(scale="none"), tmp_path / "none.rrd", []
    recorder = Recorder(path, source, config, {"name": "relative step", "source": source.name})
    run = RunResult([], [], [])
    try:
        run_odometry(source, config, (recorder.log_frame, lambda _f, r: results.append(r)), run)
    finally:
        recorder.finish(run, None)
    assert source.ground_truth is not None
    assert run.step_lengths.get("tracks", 0) >= 5  # and the summary and the recording say so, frame by frame
    assert "measured on the tracks of the two frames before" in (run.placed_summary("none") or "")
    tracking = read_entity(path, "/tracking")
    recorded = dict(zip(tracking["frame"].to_list(), tracking["step_length"].to_list(), strict=True))
    assert [recorded[r.index] for r in results if r.mapping is not None] == \
        [[r.mapping.step_length or ""] for r in results if r.mapping is not None]
    gt, poses = source.ground_truth, run.pose_array()
    assert ate(gt, poses, "sim3") < 0.5
    _, mean_abs, _ = scale_errors(gt, sim3_aligned(gt, poses))
    assert mean_abs < 8.0
