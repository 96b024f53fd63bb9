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
from vslam_core.mapping.worker_process import BackendWorker, WorkerGone
from vslam_core.sources.base import CameraIntrinsics


def worker_search(camera: CameraIntrinsics, config: EngineConfig) -> LoopSearch:
    """The worker process's loop-search service (created there, from its picklable arguments)."""
    cv2.setNumThreads(1)  # one core's worth: the other is tracking's
    return LoopSearch(camera, config)


class LoopWorker:
    """Submit a job, collect its result later (waiting for it if it is not done)."""

    SERVICE = "loop-search"

    def __init__(self, camera: CameraIntrinsics, config: EngineConfig, worker: BackendWorker | None) -> None:
        self._camera = camera
        self._config = config
        self._pending: SearchJob | None = None
        self._sent = False  # the pending job went to the worker
        self._worker = worker
        self._local: LoopSearch | None = None
        self.waited_ms = 0.0  # how long the last `collect` waited for the worker
        if worker is not None:
            worker.setup(self.SERVICE, worker_search, camera, config)
        else:
            self._local = LoopSearch(camera, config)

    @property
    def busy(self) -> bool:
        return self._pending is not None

    def submit(self, job: SearchJob) -> None:
        assert self._pending is None, "collect the previous result first"
        self._pending, self._sent = job, False
        if self._worker is not None:
            try:
                self._worker.submit(self.SERVICE, job)
                self._sent = True
            except WorkerGone:
                self._fall_back()

    def _fall_back(self) -> None:
        """The worker process is gone (e.g. killed): search in this process from now on, with an empty place
        database (the keyframes before are no longer candidates)."""
        self._worker = None
        self._local = LoopSearch(self._camera, self._config)

    def collect(self) -> SearchResult | None:
        """The submitted job's result (waiting for it), or None if nothing was submitted."""
        job, self._pending = self._pending, None
        self.waited_ms = 0.0
        if job is None:
            return None
        start = time.perf_counter()
        result = self._receive(job)
        self.waited_ms = (time.perf_counter() - start) * 1000.0  # in one thread: the whole search
        return result

    def _receive(self, job: SearchJob) -> SearchResult:
        if self._worker is not None and self._sent:
            try:
                result: SearchResult = self._worker.receive(self.SERVICE)
                return result
            except WorkerGone:
                self._fall_back()
        assert self._local is not None
        return self._local.run(job)
