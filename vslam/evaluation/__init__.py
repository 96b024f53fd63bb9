"""Scoring runs against ground truth: `vslam eval` over sequences (`evaluate`), pairing estimates with ground
truth (`matching`), metrics rows and Markdown tables (`report`), top-view plots (`plots`) and the images that go
with another system's trajectory file (`trajectory_images`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "COLUMNS": "report",
    "DEFAULT_TOLERANCE_MS": "matching",
    "Evaluation": "evaluate",
    "METRICS": "report",
    "MatchMode": "matching",
    "REPORT_FILES": "evaluate",
    "ScoredTrajectory": "evaluate",
    "TrajectoryImages": "trajectory_images",
    "check_gates": "evaluate",
    "evaluate_sources": "evaluate",
    "evaluate_trajectory_files": "evaluate",
    "json_ready": "report",
    "markdown_table": "report",
    "match_images": "matching",
    "mean_row": "report",
    "metrics_row": "report",
    "open_images": "trajectory_images",
    "scored_estimate": "report",
    "write_report": "evaluate",
    "write_trajectory_report": "evaluate",
}

if TYPE_CHECKING:
    from vslam.evaluation.evaluate import (
        REPORT_FILES,
        Evaluation,
        ScoredTrajectory,
        check_gates,
        evaluate_sources,
        evaluate_trajectory_files,
        write_report,
        write_trajectory_report,
    )
    from vslam.evaluation.matching import DEFAULT_TOLERANCE_MS, MatchMode, match_images
    from vslam.evaluation.report import (
        COLUMNS,
        METRICS,
        json_ready,
        markdown_table,
        mean_row,
        metrics_row,
        scored_estimate,
    )
    from vslam.evaluation.trajectory_images import TrajectoryImages, open_images


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "COLUMNS",
    "DEFAULT_TOLERANCE_MS",
    "Evaluation",
    "METRICS",
    "MatchMode",
    "REPORT_FILES",
    "ScoredTrajectory",
    "TrajectoryImages",
    "check_gates",
    "evaluate_sources",
    "evaluate_trajectory_files",
    "json_ready",
    "markdown_table",
    "match_images",
    "mean_row",
    "metrics_row",
    "open_images",
    "scored_estimate",
    "write_report",
    "write_trajectory_report",
]
