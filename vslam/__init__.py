"""The `vslam` application (CLI, recordings, viewer, reports).

Importing it first quiets FFmpeg, OpenCV and Rerun's file writer before anything imports cv2 or rerun: they
read these variables when they start. FFmpeg's and OpenCV's log lines (e.g. "moov atom not found" for a
truncated video) would precede vslam's own one-line error; Rerun's file writer only logs its write errors
(coloured, from its own thread) and stops, and the recorder reports that stop in one line
(`vslam.recording.recorder`). Values already set in the environment win.
"""

import os

os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET

# Rust's logger reads RUST_LOG once, when rerun is first imported; the variable is removed again so that the
# rerun processes we start (viewer, `rerun rrd …`) log as usual. A RUST_LOG of the user's wins.
# re_log_encoding: the reader's warnings (a file of another Rerun version, a corrupt message) precede our own
# one-line error about the file (`vslam.rrd.read.version_problem`, `readable`)
_RERUN_WRITER_SILENT = "warn,re_log_encoding=off,re_sdk::recording_stream=off"
if "RUST_LOG" not in os.environ:
    os.environ["RUST_LOG"] = _RERUN_WRITER_SILENT
    try:
        import rerun  # noqa: F401
    finally:
        del os.environ["RUST_LOG"]
