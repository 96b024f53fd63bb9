"""Loop search beside tracking: a worker process that owns a `LoopSearch` and handles its jobs one at a time.

A process, not a thread: measured on this machine, a busy Python thread kept 35 % of its speed while another
thread ran gtsam's pose-graph optimisation and 58 % while another described a keyframe (FAST + ORB: OpenCV
releases the GIL, but the keypoint lists around it are Python). Without `background` (one thread) the job runs
in this process when its result is collected. Either way a job's result is collected at a fixed point chosen
by the caller and depends only on the jobs submitted before it, so runs are deterministic.
"""

from __future__ import annotations

import multiprocessing
import queue
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import cv2

from vslam_core.config import EngineConfig
from vslam_core.loop.search import LoopSearch, SearchJob, SearchResult
from vslam_core.mapping.worker_process import (
    IdleWorker,
    release_worker,
    take_idle_worker,
    without_main,
)
from vslam_core.sources.base import CameraIntrinsics


@dataclass(frozen=True)
class _Restart:
    """To a kept worker: forget the last run's search and start a new one for this camera and config (None: a
    run closed; the worker stays idle, holding nothing, until a new run takes it)."""

    camera: CameraIntrinsics | None
    config: EngineConfig | None


def _serve(jobs: Any, connection: Connection, camera: CameraIntrinsics, config: EngineConfig) -> None:
    """The worker process: run each job received, until None arrives; a `_Restart` starts a new run's search."""
    cv2.setNumThreads(1)  # one core's worth: the other is tracking's
    search: LoopSearch | None = LoopSearch(camera, config)
    assert search is not None
    # gtsam (a few seconds to import) is needed only when a loop is accepted: imported beside the first searches
    threading.Thread(target=search.warm_up, name="vslam-gtsam-import", daemon=True).start()
    parent = multiprocessing.parent_process()
    while True:
        try:
            job = jobs.get(timeout=1.0)
        except queue.Empty:  # nothing to do: stop if the run's process is gone (killed: no None will come)
            if parent is not None and not parent.is_alive():
                return
            continue
        if job is None:
            return
        if isinstance(job, _Restart):
            search = LoopSearch(job.camera, job.config) if job.camera is not None and job.config is not None \
                else None
            continue
        assert search is not None, "a job before its run's restart"
        try:
            connection.send(search.run(job))
        except (BrokenPipeError, OSError):  # the run's process is gone
            return


class LoopWorker:
    """Submit a job, collect its result later (waiting for it if it is not done)."""

    def __init__(self, camera: CameraIntrinsics, config: EngineConfig, background: bool) -> None:
        self._camera = camera
        self._config = config
        self._pending: SearchJob | None = None
        self._connection: Connection | None = None
        self._process: Any = None
        self._local: LoopSearch | None = None
        self.waited_ms = 0.0  # how long the last `collect` waited for the worker
        self._jobs: Any = None
        if background and (idle := take_idle_worker("loop-search")) is not None:
            self._jobs, self._connection, self._process = idle.jobs, idle.connection, idle.process
            self._jobs.put(_Restart(camera, config))  # a fresh search: the same results as a new worker's
        elif background:
            context = multiprocessing.get_context("spawn")
            # jobs through a queue: its feeder thread writes the keyframe's image to the pipe, so submitting does
            # not block tracking; results come back through a pipe
            self._jobs = context.Queue()
            self._connection, child = context.Pipe(duplex=False)
            self._process = context.Process(target=_serve, args=(self._jobs, child, camera, config), name="vslam-loop",
                                            daemon=True)
            with without_main():
                self._process.start()
            child.close()
        else:
            self._local = LoopSearch(camera, config)

    @property
    def busy(self) -> bool:
        return self._pending is not None

    def submit(self, job: SearchJob) -> None:
        assert self._pending is None, "collect the previous result first"
        self._pending = job
        if self._connection is not None:
            if self._process is not None and not self._process.is_alive():  # it died: search here from now on
                self._fall_back()
            else:
                self._jobs.put(job)

    def _fall_back(self) -> None:
        """The worker process is gone (e.g. killed): search in this process from now on, with an empty place
        database (the keyframes before are no longer candidates)."""
        if self._connection is not None:
            self._connection.close()
        self._connection = None
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
        if self._connection is not None:
            try:
                result: SearchResult = self._connection.recv()
                return result
            except (EOFError, OSError):
                self._fall_back()
        assert self._local is not None
        return self._local.run(job)

    def close(self) -> None:
        if self._connection is not None and self._process is not None and self._jobs is not None:
            release_worker("loop-search", IdleWorker(self._process, self._connection, self._jobs),
                           awaiting_result=self._pending is not None, restart=_Restart(None, None))
        self._pending = None
        self._connection = None
        self._jobs = None
        self._process = None
