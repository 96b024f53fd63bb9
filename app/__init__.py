"""The `vslam` application: command line, recordings, evaluation."""

import os

# Rerun's file writer only logs its write errors (coloured, on stderr, from its own thread) and stops; the
# recorder notices the stop and reports it in one line (`app.recording.recorder`), so those log lines are
# silenced. Rust's logger reads RUST_LOG once, when rerun is first imported: this must run before that.
os.environ.setdefault(
    "RUST_LOG",
    "warn,re_log_encoding::rrd::file_sink=off,re_log_encoding::rrd::encoder=off,re_sdk::recording_stream=off",
)
