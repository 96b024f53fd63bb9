"""Scoring runs against ground truth: `vslam eval` over sequences (`evaluate`), pairing estimates with ground
truth (`matching`) and top-view plots (`plots`); metrics rows and the images of a trajectory file are in
`vslam.common`.

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "DEFAULT_TOLERANCE_MS": "matching",
    "Evaluation": "evaluate",
    "MatchMode": "matching",
    "REPORT_FILES": "evaluate",
    "ScoredTrajectory": "evaluate",
    "check_gates": "evaluate",
    "evaluate_sources": "evaluate",
    "evaluate_trajectory_files": "evaluate",
    "match_images": "matching",
    "scored_sentence": "evaluate",
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
        scored_sentence,
        write_report,
        write_trajectory_report,
    )
    from vslam.evaluation.matching import DEFAULT_TOLERANCE_MS, MatchMode, match_images


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "DEFAULT_TOLERANCE_MS",
    "Evaluation",
    "MatchMode",
    "REPORT_FILES",
    "ScoredTrajectory",
    "check_gates",
    "evaluate_sources",
    "evaluate_trajectory_files",
    "match_images",
    "scored_sentence",
    "write_report",
    "write_trajectory_report",
]
