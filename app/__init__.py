"""The `vslam` application: command line, recordings, evaluation."""

import os

# Rerun's file writer only logs its write errors (coloured, on stderr, from its own thread) and stops; the
# recorder notices the stop and reports it in one line (`app.recording.recorder`), so those log lines are
# silenced. Rust's logger reads RUST_LOG once, when rerun is first imported; the variable is removed again
# so that the rerun processes we start (viewer, `rerun rrd …`) log as usual. A RUST_LOG of the user's wins.
_RERUN_WRITER_SILENT = (
    "warn,re_log_encoding::rrd::file_sink=off,re_log_encoding::rrd::encoder=off,re_sdk::recording_stream=off"
)
if "RUST_LOG" not in os.environ:
    os.environ["RUST_LOG"] = _RERUN_WRITER_SILENT
    try:
        import rerun  # noqa: F401
    finally:
        del os.environ["RUST_LOG"]
