"""`vslam compare`: several recordings in one (`comparison`), their tables (`table`) and layout (`blueprint`).

The names other packages use are importable from here, loaded on first use (PEP 562).
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each public name lives.
_HOMES = {
    "Divergence": "divergences",
    "FirstDivergence": "frames",
    "PREFIXES": "comparison",
    "ROTATION_DEG": "limits",
    "TRANSLATION_PCT": "limits",
    "check_labels": "comparison",
    "compare_recordings": "comparison",
    "comparison_json": "table",
    "default_labels": "comparison",
    "first_divergence": "frames",
    "format_differences": "comparison",
    "frame_differences": "frames",
    "ranked_divergences": "divergences",
    "read_run_frames": "frames",
}

if TYPE_CHECKING:
    from vslam.compare.comparison import PREFIXES, check_labels, compare_recordings, default_labels, format_differences
    from vslam.compare.divergences import Divergence, ranked_divergences
    from vslam.compare.frames import FirstDivergence, first_divergence, frame_differences, read_run_frames
    from vslam.compare.limits import ROTATION_DEG, TRANSLATION_PCT
    from vslam.compare.table import comparison_json


__getattr__ = lazy_names(__name__, _HOMES)


__all__ = [
    "Divergence",
    "FirstDivergence",
    "PREFIXES",
    "ROTATION_DEG",
    "TRANSLATION_PCT",
    "check_labels",
    "compare_recordings",
    "comparison_json",
    "default_labels",
    "first_divergence",
    "format_differences",
    "frame_differences",
    "ranked_divergences",
    "read_run_frames",
]
