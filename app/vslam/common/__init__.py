"""What the application's layers share, beneath them all: claimed output files and write errors (`outputs`),
the `.rrd` file's error, footer check and flattened properties (`rrd_file`), metrics rows and Markdown tables
(`metric_rows`) and the camera frames that go with a trajectory file (`trajectory_images`).

The layers above import in one direction (tests/test_layout.py keeps it): `common` ← `recording` (writing) ←
`rrd` (reading) ← `runs` ← `evaluation` ← `batch`, `compare`, `viewer`, `cli`. Writing a recording depends on
nothing that reads or scores one.

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "COLUMNS": "metric_rows",
    "ClaimedFile": "outputs",
    "FOLDER_LOCK": "outputs",
    "METRICS": "metric_rows",
    "OutputError": "outputs",
    "RECORDINGS": "outputs",
    "RecordingError": "rrd_file",
    "TrajectoryImages": "trajectory_images",
    "claim": "outputs",
    "claimed": "outputs",
    "config_columns": "rrd_file",
    "config_from_columns": "rrd_file",
    "default_recording": "outputs",
    "ensure_folder": "outputs",
    "first_line": "rrd_file",
    "flatten": "rrd_file",
    "has_footer": "rrd_file",
    "hold_stuck_writer": "outputs",
    "json_ready": "metric_rows",
    "likely_errno": "outputs",
    "lock_folder": "outputs",
    "markdown_table": "metric_rows",
    "mean_row": "metric_rows",
    "metrics_row": "metric_rows",
    "open_images": "trajectory_images",
    "scored_estimate": "metric_rows",
    "stamps_from_names": "trajectory_images",
    "stuck_writers": "outputs",
    "write_failure": "outputs",
}

if TYPE_CHECKING:
    from vslam.common.metric_rows import (
        COLUMNS,
        METRICS,
        json_ready,
        markdown_table,
        mean_row,
        metrics_row,
        scored_estimate,
    )
    from vslam.common.outputs import (
        FOLDER_LOCK,
        RECORDINGS,
        ClaimedFile,
        OutputError,
        claim,
        claimed,
        default_recording,
        ensure_folder,
        hold_stuck_writer,
        likely_errno,
        lock_folder,
        stuck_writers,
        write_failure,
    )
    from vslam.common.rrd_file import (
        RecordingError,
        config_columns,
        config_from_columns,
        first_line,
        flatten,
        has_footer,
    )
    from vslam.common.trajectory_images import (
        TrajectoryImages,
        open_images,
        stamps_from_names,
    )


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "COLUMNS",
    "ClaimedFile",
    "FOLDER_LOCK",
    "METRICS",
    "OutputError",
    "RECORDINGS",
    "RecordingError",
    "TrajectoryImages",
    "claim",
    "claimed",
    "config_columns",
    "config_from_columns",
    "default_recording",
    "ensure_folder",
    "first_line",
    "flatten",
    "has_footer",
    "hold_stuck_writer",
    "json_ready",
    "likely_errno",
    "lock_folder",
    "markdown_table",
    "mean_row",
    "metrics_row",
    "open_images",
    "scored_estimate",
    "stamps_from_names",
    "stuck_writers",
    "write_failure",
]
