"""The loop search's hand-over (vslam_core/loop/worker.py): the run's worker process gives the same results as the
search run in the tracking thread, shares the process with bundle adjustment, and a run carries on (searching and
adjusting in its own process) if the worker dies."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from vslam_core.config import EngineConfig
from vslam_core.loop.search import SearchJob
from vslam_core.loop.worker import LoopWorker
from vslam_core.mapping import worker_process
from vslam_core.mapping.bundle_adjustment import BundleAdjuster, Problem, solve
from vslam_core.mapping.worker_process import BackendWorker
from vslam_core.sources.base import CameraIntrinsics

ROOT = Path(__file__).resolve().parents[1]
CAMERA = CameraIntrinsics(700.0, 700.0, 320.0, 120.0, 640, 240)


def _job(keyframe_id: int) -> SearchJob:
    """A keyframe of a textured 240 x 640 image (its own random blobs), without landmarks."""
    rng = np.random.default_rng(keyframe_id)
    image = cv2.GaussianBlur((rng.random((240, 640)) * 255).astype(np.uint8), (5, 5), 1.5)
    empty = np.zeros((0, 3))
    return SearchJob(keyframe_id=keyframe_id, position=3 * keyframe_id, segment=0, image=image,
                     point_ids=np.zeros(0, np.int64), points_cam=empty, point_pixels=np.zeros((0, 2), np.float32),
                     point_descriptors=np.zeros((0, 32), np.uint8), graph_ids=np.arange(keyframe_id + 1),
                     graph_positions=3 * np.arange(keyframe_id + 1),
                     graph_poses=np.tile(np.eye(4), (keyframe_id + 1, 1, 1)))


def _problem(seed: int) -> Problem:
    """A small BA problem: 4 cameras along a street, 60 points seen by all, the first two held."""
    rng = np.random.default_rng(seed)
    K = np.array([[700.0, 0, 320], [0, 700, 120], [0, 0, 1]])  # noqa: N806
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 2, 3] = np.arange(4.0)
    points = np.column_stack((rng.uniform(-8, 8, 60), rng.uniform(-2, 2, 60), rng.uniform(12, 30, 60)))
    pose_index, point_index = np.repeat(np.arange(4), 60), np.tile(np.arange(60), 4)
    camera = points[point_index] - poses[pose_index, :3, 3]
    pixels = camera[:, :2] / camera[:, 2:] * 700.0 + [320.0, 120.0] + rng.normal(0, 0.5, (240, 2))
    noisy = poses.copy()
    noisy[2:, :3, 3] += rng.normal(0, 0.05, (2, 3))
    return Problem(K, noisy, 4, points + rng.normal(0, 0.1, points.shape), pose_index, point_index, pixels,
                   np.zeros((0, 4)), fix_first=2, iterations=5, huber_px=1.5)


def test_worker_process_matches_the_search_in_this_process() -> None:
    config = EngineConfig(backend="map")
    process = BackendWorker()
    inline, background = LoopWorker(CAMERA, config, None), LoopWorker(CAMERA, config, process)
    try:
        for keyframe_id in range(3):
            results = []
            for worker in (inline, background):
                worker.submit(_job(keyframe_id))
                assert worker.busy
                results.append(worker.collect())
            ours, theirs = results
            assert ours is not None and theirs is not None
            assert ours.keyframe_id == theirs.keyframe_id == keyframe_id
            assert len(ours.pixels) > 100  # described: the image's FAST corners
            np.testing.assert_array_equal(ours.pixels, theirs.pixels)
            np.testing.assert_array_equal(ours.descriptors, theirs.descriptors)
        assert background.collect() is None  # nothing pending
    finally:
        process.close()
        process.close()  # a second close does nothing: the worker is not kept (or stopped) twice
        assert sum(idle.process is process._process for idle in worker_process._pool) <= 1


def test_bundle_adjustment_and_loop_search_share_one_worker_process() -> None:
    """Jobs of both kinds in flight at once in the one process: each client gets its own results, in order,
    the same as in this process."""
    process = BackendWorker()
    adjuster, search = BundleAdjuster(process), LoopWorker(CAMERA, EngineConfig(backend="map"), process)
    try:
        for step in range(3):
            search.submit(_job(step))
            adjuster.submit(_problem(step))
            collected = adjuster.collect()  # read past the search's result, which is kept for its client
            assert collected is not None
            np.testing.assert_array_equal(collected[1].poses, solve(_problem(step)).poses)
            result = search.collect()
            assert result is not None and result.keyframe_id == step and len(result.pixels) > 100
    finally:
        process.close()


def test_a_dead_worker_is_replaced_by_the_search_in_this_process() -> None:
    process = BackendWorker()
    adjuster, search = BundleAdjuster(process), LoopWorker(CAMERA, EngineConfig(backend="map"), process)
    try:
        search.submit(_job(0))
        assert search.collect() is not None
        adjuster.submit(_problem(0))  # in flight when the worker dies
        process._process.kill()  # the worker this test started
        process._process.join(timeout=10)
        collected = adjuster.collect()
        assert collected is not None
        np.testing.assert_array_equal(collected[1].poses, solve(_problem(0)).poses)
        search.submit(_job(1))
        result = search.collect()
        assert result is not None and result.keyframe_id == 1 and len(result.pixels) > 100
    finally:
        process.close()


def test_worker_processes_start_without_the_callers_main_module(kitti_root: Path, tmp_path: Path) -> None:
    """A user's script without the `if __name__ == "__main__"` guard runs the map backend with its worker
    processes (bundle adjustment, loop search): they are spawned without the script, which would otherwise
    run again in each of them (before: a RuntimeError in the worker, and the CLI's imports paid in each)."""
    script = tmp_path / "my_pipeline.py"
    script.write_text(
        "from pathlib import Path\n"
        "from vslam_core.config import EngineConfig\n"
        "from vslam_core.pipeline import run_odometry\n"
        "from vslam_core.sources.base import FrameRange\n"
        "from vslam_core.sources.kitti import KittiSource\n"
        "print('script body ran')\n"
        f"source = KittiSource(Path({str(kitti_root)!r}), sequence='05', frames=FrameRange(0, 12))\n"
        "poses = run_odometry(source, EngineConfig(backend='map', threads=2)).pose_array()\n"
        "print('poses', len(poses))\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "app"), str(ROOT)])})
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["script body ran", "poses 12"]  # the body ran once, in the script alone
    assert "Traceback" not in done.stderr
