"""Shared fixtures."""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import type_check
from cli_helpers import InterruptedRun, interrupt_kitti_run
from kitti_runs import MapRun, map_run_00
from ray_cluster import (
    note_next_test,
    ray_cluster,  # noqa: F401  (the fixture: a real one-node Ray head, see ray_cluster.py)
)

from vslam_core.config import EngineConfig
from vslam_core.mapping.worker_process import reuse_workers
from vslam_core.sources import image_files
from vslam_core.sources import kitti as kitti_source
from vslam_core.sources.base import FrameRange
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.sources.synthetic.frame_cache import ENVIRONMENT as FRAME_CACHE

ROOT = Path(__file__).resolve().parents[1]
#: The real KITTI sample: the ``shared`` folder beside the repository checkout (never inside the repo).
#: VSLAM_SHARED_DATA names another folder holding ``kitti/`` and ``tum/`` (a worktree beside the checkout).
SHARED_DATA = Path(os.environ.get("VSLAM_SHARED_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")
KITTI_ROOT = SHARED_DATA / "kitti"
KITTI_REAL = KITTI_ROOT.resolve()
#: The real hand-held sample: two TUM RGB-D sequences (frames 400-599 of fr1_xyz and fr1_desk).
TUM_ROOT = SHARED_DATA / "tum"


class _RenderedFrames:
    """The synthetic street's frames rendered once per test process: most CLI tests run `synthetic` in this
    process (tests/cli_helpers.py), and rendering is most of a synthetic run's time (~0.08 s a frame). Keyed
    by everything a frame depends on; each call gets its own copy. Off for `test_synthetic.py`, which tests the
    renderer itself (`no_render_cache`)."""

    LIMIT = 1500  # frames kept (~0.5 MB each at full size)

    def __init__(self) -> None:
        self.images: dict[tuple[object, ...], np.ndarray] = {}
        self.enabled = True
        self.render = SyntheticStreet.render

    def __call__(self, street: SyntheticStreet, index: int) -> np.ndarray:
        if not self.enabled:
            return self.render(street, index)
        key = (street.seed, street.route, street.n_frames, street.camera_height, street.intrinsics, index)
        image = self.images.get(key)
        if image is None:
            image = self.render(street, index)
            if len(self.images) < self.LIMIT:
                self.images[key] = image
        return image.copy()


RENDERED = _RenderedFrames()


class _DecodedKitti:
    """The real KITTI frames decoded once per test process: dozens of in-process runs read the same frames of
    ../shared/data/kitti (~5 ms a PNG). Only files inside it (symbolic links to them included) are kept, keyed by
    their real path, size and modification time; each call gets its own copy. Every other image (the tests' own
    folders, corrupt or re-encoded files) is decoded as usual."""

    LIMIT = 1800  # frames kept (~0.47 MB each)

    def __init__(self) -> None:
        self.images: dict[tuple[str, int, int], np.ndarray] = {}
        self.decode = image_files.decode_image

    def __call__(self, path: Path) -> np.ndarray:
        real = Path(os.path.realpath(path))
        if not real.is_relative_to(KITTI_REAL):
            return self.decode(path)
        try:
            stat = real.stat()
        except OSError:  # missing or unreadable: the source's own error
            return self.decode(path)
        key = (str(real), stat.st_size, stat.st_mtime_ns)
        image = self.images.get(key)
        if image is None:
            image = self.decode(path)
            if len(self.images) < self.LIMIT:
                self.images[key] = image
        return image.copy()


DECODED = _DecodedKitti()
image_files.decode_image = kitti_source.decode_image = DECODED  # type: ignore[assignment]


def _one_thread_by_default() -> None:
    """Runs in a test process take ``threads = 1`` unless they name a number: the two xdist workers already keep
    the 2 cores busy, and a run's second thread (background decoding, OpenCV's pool) and the map's worker process
    only add switching and pickling there (test_engine, test_scale and test_map_scale: 9 % less CPU). Trajectories
    do not depend on it (test_mapping's determinism test runs 1 and 2); `vslam` processes (``process=True``), the
    batch workers and every test that names ``threads`` keep their own: the recorder's own tests
    (test_recording.py, test_recording_map.py) name 2, so that it draws and sends beside the engine as in a run."""
    defaults = list(EngineConfig.__init__.__defaults__ or ())
    defaults[[f.name for f in dataclasses.fields(EngineConfig)].index("threads")] = 1
    EngineConfig.__init__.__defaults__ = tuple(defaults)


_one_thread_by_default()


def pytest_configure(config: pytest.Config) -> None:
    """One synthetic-frame cache on disk for the whole session (`frame_cache`): set by the controlling
    process, so the xdist workers and every `vslam` process a test starts render each frame once. The map
    backend's worker processes are kept between the runs of a test process (~0.7 s of CPU each to start).
    Compiled modules are written and reused even where PYTHONDONTWRITEBYTECODE is set (as here):
    the tests start dozens of Python processes (`vslam` commands, batch and map workers), each of which would compile
    the checkout's modules anew (~0.3 s of CPU); the __pycache__ folders are git-ignored."""
    reuse_workers(True)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False
    if not hasattr(config, "workerinput") and not os.environ.get(FRAME_CACHE):
        os.environ[FRAME_CACHE] = tempfile.mkdtemp(prefix="vslam-test-frames-")
        config.stash[_FRAME_CACHE_MADE] = os.environ[FRAME_CACHE]
    config.stash[_TYPE_CHECK] = type_check.start(config)  # in the background, niced (tests/type_check.py)


#: Test files by cost, the costliest `SAME_WORKER` group or file first, a group's files together (seconds in a full
#: run; refresh from `--durations=0` when they change).
#: Files are handed to the xdist workers whole in this order (`--no-loadscope-reorder`; xdist's own order is by
#: number of tests): the longest jobs first, so the two workers finish together. test_types.py last (`LAST_FILE`): it
#: waits for the type check started with the session (tests/type_check.py), which has had the most idle CPU by then.
SLOWEST_FILES = (
    "test_logs_cli.py", "test_mapping.py", "test_scale.py", "test_engine.py", "test_map_scale.py", "test_batch.py",
    "test_batch_ray.py", "test_outputs.py", "test_faults.py", "test_viewer.py", "test_tum_real.py",
    "test_compare.py", "test_cli.py", "test_provenance.py", "test_gt_check.py", "test_planted_bugs.py",
    "test_local_map.py", "test_contract.py", "test_loop_recording.py", "test_batch_workflow.py",
    "test_eval_external.py", "test_map_storage.py", "test_live.py", "test_eval.py", "test_keyframe_culling.py",
    "test_cli_inputs.py", "test_rosbag_source.py", "test_recording_map.py", "test_example_orb_vo.py",
    "test_coasting.py", "test_synthetic.py", "test_overview.py", "test_tum_rgbd.py", "test_codec.py",
    "test_recording.py", "test_two_view.py", "test_backend_cli.py", "test_scale_none.py", "test_source_files.py",
    "test_map_steps.py", "test_properties.py",
)
LAST_FILE = "test_types.py"


#: Files whose tests share a session fixture below (one engine run or one process serving tests of both): each
#: group goes to one xdist worker, so the fixture is made once. Every other file is a group of its own: the
#: workers get whole files (`--dist loadgroup` with these `xdist_group` marks, as `--dist loadfile` would).
SAME_WORKER = {
    "test_mapping.py": "kitti-00-map", "test_logs_cli.py": "kitti-00-map",  # kitti_00_map_run
    "test_cli.py": "interrupted-run", "test_provenance.py": "interrupted-run",  # interrupted_kitti_run
    "test_batch.py": "ray-cluster", "test_batch_ray.py": "ray-cluster",  # ray_cluster.py: one Ray head for both
    # no fixture, the same 600 real frames (KITTI 00 and 05 0:300, two runs in each file): decoded once (DECODED)
    "test_scale.py": "kitti-0-300", "test_engine.py": "kitti-0-300",
}


@pytest.hookimpl(tryfirst=True)  # before the runner tears the fixtures down
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> None:
    note_next_test(nextitem)


@pytest.hookimpl(tryfirst=True)  # the marks before xdist's own hook reads them
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    rank = {name: position for position, name in enumerate(SLOWEST_FILES)} | {LAST_FILE: len(SLOWEST_FILES) + 1}
    items.sort(key=lambda item: rank.get(item.path.name, len(SLOWEST_FILES)))  # stable: file order kept within a file
    for item in items:
        item.add_marker(pytest.mark.xdist_group(SAME_WORKER.get(item.path.name, item.path.name)))


def pytest_unconfigure(config: pytest.Config) -> None:
    type_check.stop(config.stash.get(_TYPE_CHECK, None))
    made = config.stash.get(_FRAME_CACHE_MADE, None)
    if made is not None:
        shutil.rmtree(made, ignore_errors=True)
        os.environ.pop(FRAME_CACHE, None)


_FRAME_CACHE_MADE = pytest.StashKey[str]()
_TYPE_CHECK = pytest.StashKey[subprocess.Popen[bytes] | None]()


def _render(street: SyntheticStreet, index: int) -> np.ndarray:
    return RENDERED(street, index)


SyntheticStreet.render = _render  # type: ignore[method-assign]


def _signal_state() -> tuple[object, ...]:
    return (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM),
            signal.pthread_sigmask(signal.SIG_BLOCK, []))


@pytest.fixture(autouse=True)
def signals_left_as_found() -> Iterator[None]:
    """The CLI runs in the test process (tests/cli_helpers.py): a command must leave the process's signal
    handlers and mask as it found them (a process the next test starts inherits an ignored or blocked signal)."""
    before = _signal_state()
    yield
    assert _signal_state() == before, "signal handlers or mask changed by the test"


@pytest.fixture
def no_render_cache(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Each frame rendered anew, neither kept in memory nor read from the disk cache (the renderer's own tests)."""
    monkeypatch.delenv(FRAME_CACHE, raising=False)
    RENDERED.enabled = False
    try:
        yield
    finally:
        RENDERED.enabled = True


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    """Root of the real KITTI sample (``sequences/NN/…``, ``poses/NN.txt``).

    Skips the test when the data is missing, except when the environment variable ``CI`` is set: there
    the data must be present, so the test fails instead.
    """
    if not (KITTI_ROOT / "sequences").is_dir() or not (KITTI_ROOT / "poses").is_dir():
        message = f"real KITTI data not found at {KITTI_ROOT}"
        if "CI" in os.environ:
            pytest.fail(f"{message} (CI is set: tests that need the real data must not be skipped)")
        pytest.skip(message)
    return KITTI_ROOT


def _real_data_missing(message: str) -> None:
    """Skip the test, or fail it when ``CI`` is set: there the real data must be present."""
    if "CI" in os.environ:
        pytest.fail(f"{message} (CI is set: tests that need the real data must not be skipped)")
    pytest.skip(message)


@pytest.fixture(scope="session")
def tum_root() -> Path:
    """The folder holding ``rgbd_dataset_freiburg1_{xyz,desk}/`` (TUM RGB-D, hand-held, 200 frames each); skips
    when missing, fails under ``CI``, as `kitti_root`."""
    if not all((TUM_ROOT / f"rgbd_dataset_freiburg1_{name}" / "rgb.txt").is_file() for name in ("xyz", "desk")):
        _real_data_missing(f"real TUM RGB-D data not found at {TUM_ROOT}")
    return TUM_ROOT


@pytest.fixture(scope="session")
def kitti_00_map_run(kitti_root: Path) -> MapRun:
    """The map backend over KITTI 00 0:150, one thread, ground-truth scale: (results, poses, ground truth). The
    clean reference of test_mapping.py and the rectified frames' run of test_logs_cli.py (~9 s of CPU)."""
    return map_run_00(kitti_root, FrameRange(0, 150))


@pytest.fixture(scope="session")
def interrupted_kitti_run(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> InterruptedRun:
    """One interrupted run read by test_cli.py (its exit, message and files) and test_provenance.py (what its
    recording says it holds)."""
    return interrupt_kitti_run(kitti_root, tmp_path_factory.mktemp("interrupted"), signal.SIGINT)
