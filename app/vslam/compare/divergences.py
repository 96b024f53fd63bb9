"""Ranked divergences of two runs: the frames where their steps differ most, relative to how much they differ
elsewhere in the same pair, and whether the two runs can be compared frame by frame at all.

Two different front ends always differ a little on every frame (the first divergence above fixed thresholds is
then early and says little); a bug in one of them makes one frame's step differ far more than the pair's usual.
Per common frame (`vslam.compare.frames.frame_differences`), the step rotation difference (°) and translation
difference (% of the baseline's step) each become a robust z-score against the pair's own spread
(`vslam.rrd.suspects.robust_z`: ``(x − median) / (1.4826 · MAD)`` over a window of frames); a frame's score is
the larger, and the `TOP` highest-scoring frames are listed, with each run's own health reasons there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vslam.compare.frames import FrameDifferences, RunFrames
from vslam.rrd import robust_z

#: The ``source`` of `vslam eval --trajectory … --report` recordings: ``external trajectory <file name>``.
EXTERNAL = "external trajectory "
#: How many divergences are listed.
TOP = 10
#: The smallest spread of the step rotation (°) and translation (%) differences: runs that agree to the
#: recording's float32 precision must not turn that noise into divergences.
FLOOR_DEG, FLOOR_PCT = 0.01, 0.5


@dataclass(frozen=True)
class Divergence:
    """One ranked frame: its step differences, their score (the larger robust z) and each run's reasons."""

    frame: int
    rotation_deg: float
    translation_pct: float | None
    score: float
    reasons_a: list[str]
    reasons_b: list[str]

    def as_json(self) -> dict[str, Any]:
        """An entry of ``divergences`` of ``vslam compare --json``."""
        return {"frame": self.frame, "rotation_deg": self.rotation_deg, "translation_pct": self.translation_pct,
                "score": self.score, "reasons_a": self.reasons_a, "reasons_b": self.reasons_b}


def ranked_divergences(a: RunFrames, b: RunFrames, differences: FrameDifferences,
                       top: int = TOP) -> list[Divergence]:
    """The `top` common frames whose steps differ most for this pair (see the module docstring); the first
    common frame has no step and is never listed."""
    if len(differences.frames) < 3:
        return []
    rotation = differences.rotation_deg.astype(np.float64).copy()
    rotation[0] = np.nan
    pct = differences.translation_pct.astype(np.float64)
    score = np.maximum(robust_z(rotation, FLOOR_DEG), robust_z(pct, FLOOR_PCT))
    order = sorted(range(1, len(score)), key=lambda k: (-score[k], int(differences.frames[k])))[:top]
    out = []
    for k in order:
        frame = int(differences.frames[k])
        value = float(pct[k])
        out.append(Divergence(frame, float(rotation[k]), value if np.isfinite(value) else None,
                              round(float(score[k]), 2), _reasons(a, frame), _reasons(b, frame)))
    return out


def _reasons(run: RunFrames, frame: int) -> list[str]:
    """The run's health there as reasons: its codes, or its status when it gave none (``[]`` when ok)."""
    status, codes = run.health_at(frame)
    if codes:
        return codes
    return [] if status in ("ok", "not reported", "") else [status]


def comparability(labels: Sequence[str], reports: Sequence[dict[str, Any]], runs: Sequence[RunFrames]
                  ) -> tuple[list[str], list[str]]:
    """(refusals, warnings) about comparing each further run with the first frame by frame: runs of different
    sources are refused (unless forced); different frame ranges are named, with how many frames they share."""
    refusals, warnings = [], []
    base_label, base = labels[0], reports[0]["properties"]
    for label, report, run in zip(labels[1:], reports[1:], runs[1:], strict=True):
        source_a, source_b = _source(base), _source(report["properties"])
        if source_a is not None and source_b is not None and source_a != source_b:
            refusals.append(f"{label} is of {source_b}, {base_label} of {source_a}: different sources, so their "
                            "frames are different images and the divergences would be meaningless")
        common = len(np.intersect1d(runs[0].frames, run.frames))
        if common == len(runs[0].frames) == len(run.frames):
            continue
        frames_a, frames_b = _span(runs[0].frames), _span(run.frames)
        if common == 0:
            refusals.append(f"{label} (frames {frames_b}) and {base_label} (frames {frames_a}) share no frame: "
                            "nothing to compare frame by frame")
        else:
            warnings.append(f"{label} holds frames {frames_b}, {base_label} frames {frames_a}: the divergences are "
                            f"of the {common} frames both hold")
    return refusals, warnings


def _source(properties: dict[str, Any]) -> str | None:
    """What a run's frames are of; None when unknown (an external trajectory's ``source`` names its file, not
    the sequence: `vslam eval --trajectory … --report`)."""
    source = properties.get("source")
    return None if source is None or str(source).startswith(EXTERNAL) else str(source)


def _span(frames: np.ndarray) -> str:
    return f"{int(frames[0])}..{int(frames[-1])} ({len(frames)})" if len(frames) else "none"


def describe_divergences(label_a: str, label_b: str, divergences: list[Divergence], rows: int = 5) -> list[str]:
    """Text lines of the ranked divergences of B from A (the first `rows`)."""
    if not divergences:
        return [f"divergences {label_b} vs {label_a}: none (fewer than three common frames)"]
    lines = [f"divergences {label_b} vs {label_a}, ranked (step differences against this pair's usual; "
             f"--json: top {TOP})", f"  rank  frame  rotation °  translation %   score  {label_a} / {label_b}"]
    for rank, d in enumerate(divergences[:rows], 1):
        pct = "–" if d.translation_pct is None else f"{d.translation_pct:.1f}"
        reasons = f"{', '.join(d.reasons_a) or 'ok'} / {', '.join(d.reasons_b) or 'ok'}"
        lines.append(f"  {rank:>4}  {d.frame:>5}  {d.rotation_deg:10.3f}  {pct:>13}  {d.score:6.1f}  {reasons}")
    return lines
