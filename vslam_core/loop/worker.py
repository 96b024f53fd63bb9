"""Loop search beside tracking: the run's worker process (`worker_process.BackendWorker`, shared with bundle
adjustment) owns a `LoopSearch` and handles its jobs one at a time.

A process, not a thread: measured on this machine, a busy Python thread kept 35 % of its speed while another
thread ran gtsam's pose-graph optimisation and 58 % while another described a keyframe (FAST + ORB: OpenCV
releases the GIL, but the keypoint lists around it are Python). Without a worker (one thread) the job runs
in this process when its result is collected. Either way a job's result is collected at a fixed point chosen
by the caller and depends only on the jobs submitted before it, so runs are deterministic.
"""

from __future__ import annotations

import time

import cv2

from vslam_core.config import EngineConfig
from vslam_core.loop.search import LoopSearch, SearchJob, SearchResult
from vslam_core.mapping.worker_process import BackendWorker, ServiceClient
from vslam_core.results import elapsed_ms
from vslam_core.sources.base import CameraIntrinsics


def worker_search(camera: CameraIntrinsics, config: EngineConfig) -> LoopSearch:
    """The worker process's loop-search service (created there, from its picklable arguments)."""
    cv2.setNumThreads(1)  # one core's worth: the other is tracking's
    return LoopSearch(camera, config)


class LoopWorker:
    """Submit a job, collect its result later (waiting for it if it is not done)."""

    def __init__(self, camera: CameraIntrinsics, config: EngineConfig, worker: BackendWorker | None) -> None:
        self._camera = camera
        self._config = config
        self._local = LoopSearch(camera, config) if worker is None else None
        self._client: ServiceClient[SearchJob, SearchResult] = ServiceClient(
            worker, "loop-search", self._search_here, worker_search, camera, config, on_gone=self._fall_back)
        self.waited_ms = 0.0  # how long the last `collect` waited for the worker

    @property
    def busy(self) -> bool:
        return self._client.busy

    def submit(self, job: SearchJob) -> None:
        self._client.submit(job)

    def _search_here(self, job: SearchJob) -> SearchResult:
        assert self._local is not None
        return self._local.run(job)

    def _fall_back(self) -> None:
        """The worker process is gone (e.g. killed): search in this process from now on, with an empty place
        database (the keyframes before are no longer candidates)."""
        self._local = LoopSearch(self._camera, self._config)

    def collect(self) -> SearchResult | None:
        """The submitted job's result (waiting for it), or None if nothing was submitted."""
        start = time.perf_counter()
        collected = self._client.collect()
        self.waited_ms = elapsed_ms(start) if collected else 0.0  # in one thread: the search
        return collected[1] if collected else None
