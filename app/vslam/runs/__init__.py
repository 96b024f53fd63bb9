"""One run of the engine and its files: running a source through the engine into its outputs (`runner`), a run's set of
output files (`run_outputs`, claimed through `vslam.common`), the trajectory written as the run goes
(`trajectory_out`), progress lines (`progress`) and the checks on what a user asked for (`checks`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "EXIT_NOTHING_TRACKED": "checks",
    "Interrupted": "runner",
    "RecordedRun": "runner",
    "RunOutputs": "run_outputs",
    "FRAMES_HEADER": "trajectory_out",
    "TrajectoryWriter": "trajectory_out",
    "camera_height_problem": "checks",
    "claim_run_outputs": "run_outputs",
    "describe_outputs": "run_outputs",
    "eta": "progress",
    "format_map_summary": "map_files",
    "input_warnings": "checks",
    "map_saver": "map_files",
    "map_summary": "map_files",
    "nothing_tracked": "checks",
    "output_problem": "checks",
    "record_run": "runner",
    "same_file_problem": "checks",
    "save_map_problem": "map_files",
    "with_camera_height": "checks",
}

if TYPE_CHECKING:
    from vslam.runs.checks import (
        EXIT_NOTHING_TRACKED,
        camera_height_problem,
        input_warnings,
        nothing_tracked,
        output_problem,
        same_file_problem,
        with_camera_height,
    )
    from vslam.runs.map_files import format_map_summary, map_saver, map_summary, save_map_problem
    from vslam.runs.progress import eta
    from vslam.runs.run_outputs import RunOutputs, claim_run_outputs, describe_outputs
    from vslam.runs.runner import Interrupted, RecordedRun, record_run
    from vslam.runs.trajectory_out import FRAMES_HEADER, TrajectoryWriter


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "EXIT_NOTHING_TRACKED",
    "Interrupted",
    "RecordedRun",
    "RunOutputs",
    "FRAMES_HEADER",
    "TrajectoryWriter",
    "camera_height_problem",
    "claim_run_outputs",
    "describe_outputs",
    "eta",
    "format_map_summary",
    "input_warnings",
    "map_saver",
    "map_summary",
    "nothing_tracked",
    "output_problem",
    "record_run",
    "same_file_problem",
    "save_map_problem",
    "with_camera_height",
]
