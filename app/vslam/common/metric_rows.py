"""Metrics of one run as a table row, and tables as Markdown (report.md, the recording's verdict)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vslam_core.trajectory.metrics import evaluate, rpe_by_distance, scale_errors, sim3_aligned, stands_still

# key -> (column header, format); the keys are also the JSON keys of `vslam eval --json`.
COLUMNS: dict[str, tuple[str, str]] = {
    "sequence": ("sequence", "{}"),
    "status": ("status", "{}"),  # batches (`vslam eval --manifest`): ok or failed
    "frames": ("frames", "{:d}"),
    "length_m": ("length m", "{:.1f}"),
    "scale": ("scale", "{}"),
    "backend": ("backend", "{}"),
    "alignment": ("aligned", "{}"),
    "t_err": ("t_err %", "{:.2f}"),
    "r_err": ("r_err °/100 m", "{:.2f}"),
    "ate_se3": ("ATE SE3 m", "{:.3f}"),
    "ate_sim3": ("ATE Sim3 m", "{:.3f}"),
    "rpe_trans": ("RPE m", "{:.3f}"),
    "rpe_rot": ("RPE °", "{:.3f}"),
    "rpe_trans_10m": ("RPE 10 m: m", "{:.3f}"),
    "rpe_rot_10m": ("RPE 10 m: °", "{:.3f}"),
    "paper_rms": ("paper RMS m", "{:.3f}"),
    "step_err_median": ("step err median %", "{:+.1f}"),
    "step_err_abs": ("step err mean abs %", "{:.1f}"),
    "path_length_err": ("path length err %", "{:+.1f}"),
    "fps": ("fps", "{:.1f}"),
}
METRICS = ("t_err", "r_err", "ate_se3", "ate_sim3", "rpe_trans", "rpe_rot", "rpe_trans_10m", "rpe_rot_10m", "paper_rms",
           "step_err_median", "step_err_abs", "path_length_err")


def metrics_row(name: str, gt: np.ndarray, poses: np.ndarray, scale: str, backend: str | None = None
                ) -> dict[str, Any]:
    """Every metric of `poses` (N, 4, 4) against `gt` (N, 4, 4). With ``scale == "none"`` the estimate is
    known only up to scale: it is Sim(3)-aligned to the ground truth first (``alignment = "sim3"``). With
    `backend`, the row names the engine backend that produced the poses (``backend`` key, after ``scale``)."""
    alignment = "sim3" if scale == "none" else "none"
    estimate = scored_estimate(gt, poses, scale)
    metrics = evaluate(gt, estimate).as_dict()
    metrics["rpe_trans_10m"], metrics["rpe_rot_10m"] = rpe_by_distance(gt, estimate, 10.0)
    # how far each step's length is from the truth: the scale source's own error
    metrics["step_err_median"], metrics["step_err_abs"], metrics["path_length_err"] = scale_errors(gt, estimate)
    return {"sequence": name, "scale": scale, **({"backend": backend} if backend is not None else {}),
            "alignment": alignment, **metrics}


def scored_estimate(gt: np.ndarray, poses: np.ndarray, scale: str) -> np.ndarray:
    """The estimate as it is scored, printed and plotted: with ``scale == "none"`` (unit steps, no metric
    scale) Sim(3)-aligned onto the ground truth, else as it is (also when it does not move: no Sim(3) exists)."""
    return sim3_aligned(gt, poses) if scale == "none" and len(poses) > 2 and not stands_still(poses) else poses


def mean_row(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The plain mean of every metric over rows (NaN ignored), frames and length summed."""
    mean: dict[str, Any] = {
        "sequence": "mean",
        "scale": rows[0]["scale"] if rows else "",
        **({"backend": rows[0]["backend"]} if rows and "backend" in rows[0] else {}),
        "alignment": rows[0]["alignment"] if rows else "",
    }
    for key in METRICS + (("fps",) if any("fps" in r for r in rows) else ()):  # trajectory files have no fps
        values = [r[key] for r in rows if key in r and r[key] is not None and not math.isnan(r[key])]
        mean[key] = float(np.mean(values)) if values else math.nan
    mean["frames"] = int(sum(r["frames"] for r in rows))
    mean["length_m"] = float(sum(r["length_m"] for r in rows))
    return mean


def json_ready(value: Any) -> Any:
    """`value` with every NaN or infinite float (at any depth) replaced by None, as JSON has no NaN."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(v) for v in value]
    return value


def _cell(key: str, value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return COLUMNS[key][1].format(value)


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """A Markdown table of metric rows (the columns of `COLUMNS` that the rows have)."""
    keys = [k for k in COLUMNS if any(k in r for r in rows)]
    lines = ["| " + " | ".join(COLUMNS[k][0] for k in keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_cell(k, r.get(k)) for k in keys) + " |" for r in rows]
    return "\n".join(lines)
