"""The `vslam` application (CLI, recordings, viewer, reports).

Importing it first quiets FFmpeg, OpenCV and Rerun's file writer before anything imports cv2 or rerun: they
read these variables when they start. FFmpeg's and OpenCV's log lines (e.g. "moov atom not found" for a
truncated video) would precede vslam's own one-line error; Rerun's file writer only logs its write errors
(coloured, from its own thread) and stops, and the recorder reports that stop in one line
(`vslam.recording.recorder`). Values already set in the environment win.

Importing it imports neither cv2 nor rerun (~0.8 s of CPU): `vslam --help` and a command refused at once stay
fast. Rerun is quieted when it is first imported, by whom ever (`_QuietRerunImport`).
"""

import importlib.abc
import importlib.machinery
import os
import sys
from collections.abc import Sequence
from types import ModuleType

os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

# Rust's logger reads RUST_LOG once, when rerun is first imported; the variable is set only during that import, so
# that the rerun processes we start (viewer, `rerun rrd …`) log as usual. A RUST_LOG of the user's wins.
# re_log_encoding: the reader's warnings (a file of another Rerun version, a corrupt message) precede our own
# one-line error about the file (`vslam.rrd.read.version_problem`, `readable`)
_RERUN_WRITER_SILENT = "warn,re_log_encoding=off,re_sdk::recording_stream=off"


class _QuietRerunImport(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """The import of the `rerun` package, the first time anything imports it, with RUST_LOG set to
    `_RERUN_WRITER_SILENT` while the package runs (and its Rust logger starts), removed again right after.
    It finds rerun as the path finder would, only wrapping that loader's `exec_module`, and takes itself off
    `sys.meta_path` once rerun is imported: later imports are untouched. (Importing rerun here instead costs
    every command that never records or reads a recording, `vslam --help` included, ~0.7 s of CPU.)"""

    def __init__(self) -> None:
        self._loader: importlib.abc.Loader | None = None

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if fullname != "rerun":
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return spec
        self._loader, spec.loader = spec.loader, self
        return spec

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        assert self._loader is not None
        return self._loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        assert self._loader is not None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        quiet = "RUST_LOG" not in os.environ
        if quiet:
            os.environ["RUST_LOG"] = _RERUN_WRITER_SILENT
        try:
            self._loader.exec_module(module)
        finally:
            if quiet:
                del os.environ["RUST_LOG"]
            module.__loader__ = self._loader  # rerun's own loader from now on
            if module.__spec__ is not None:
                module.__spec__.loader = self._loader


if "rerun" not in sys.modules:
    sys.meta_path.insert(0, _QuietRerunImport())
