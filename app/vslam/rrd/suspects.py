"""Suspect frames: steps that are implausible judged by the run itself, ranked (`vslam inspect`, key ``suspects``).

A run's frame i has the step ``S_i = T_world_cam[i−1]⁻¹ · T_world_cam[i]`` from the previous recorded frame. A
bug in one frame's step (a translation whose sign flipped, a rotation kinked by a few degrees, a step of the
wrong length) leaves the steps around it as they were, so each frame is judged against its two neighbours, and
the result against how much neighbours differ elsewhere in the same run (robust and scale-free):

- ``direction``: the angle (°) between this step's translation and the nearer of its neighbours', each in the
  axes of the camera it starts from (the constant-velocity motion model: a steady turn keeps it); a flipped step
  reads ~180°. Left out where a step is shorter than
  `STILL` × the run's median step (a car standing still has no direction).
- ``rotation``: the angle (°) between this step's rotation and the nearer of its neighbours' rotations.
- ``length``: |log(step length / the nearer neighbour's)|, scale-free.
- ``inliers``: a collapse of RANSAC inliers (or tracks) against the frames around it (log ratio below the local
  median); ``health``: the pipeline's own ``warn`` / ``fail``.
- with ground truth, ``error_rotation`` / ``error_translation``: the frame's own step error (``/metrics/drift/*``).

Each feature becomes a robust z-score, ``(x − median) / (1.4826 · MAD)`` over a window of `WINDOW` frames
either side (a spread never below the feature's `FLOOR`: a run that is smoother than the recording's float32
precision must not turn noise into suspects); a frame's score is the sum of its positive z-scores (``warn`` adds
`WARN_SCORE`, ``fail`` `FAIL_SCORE`), and a feature with z ≥ `REASON_Z` is named in its reasons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from vslam.rrd.health import read_health
from vslam.rrd.poses import camera_poses
from vslam.rrd.read import read_entity

#: Frames either side whose spread a frame's features are judged against (~20 s of driving at 10 Hz: a whole
#: short run; measured on KITTI 05 0:120 with bugs planted at 57, a ±25 window ranked a 3° kink second in a
#: noisy ORB VO, behind a frame whose local spread was smaller).
WINDOW = 100
#: A z-score from which a feature is named among the frame's reasons (and the frame listed).
REASON_Z = 6.0
#: The smallest spread (1.4826 · MAD) of each feature: degrees, degrees, log ratio, log ratio, degrees, %.
FLOOR = {"direction": 0.05, "rotation": 0.01, "length": 0.01, "inliers": 0.05, "error_rotation": 0.01,
         "error_translation": 0.5}
#: Scores of the pipeline's own verdicts (a z-score of this size).
WARN_SCORE, FAIL_SCORE = 2.0, 8.0
#: A step shorter than this fraction of the run's median step has no direction.
STILL = 0.1
#: How many suspects are listed.
TOP = 10


@dataclass(frozen=True)
class RunPoses:
    """One run's poses read back by frame: (N,) int64 ascending frames, (N, 4, 4) T_world_cam."""

    frames: np.ndarray
    poses: np.ndarray
    health: dict[int, tuple[str, list[str]]] = field(default_factory=dict)  # frame → (status, reasons)


def read_poses(path: Path, prefix: str = "") -> RunPoses:
    """Poses (``{prefix}/world/camera``, any rotation the schema allows: `vslam.rrd.poses`) and health
    (``{prefix}/health``) of a recording, by frame."""
    camera = camera_poses(path, prefix)
    health = {frame: (h.status, h.reasons) for frame, h in read_health(path, prefix).items()}
    return RunPoses(camera.frames, camera.poses, health)


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle (°) of a (3, 3) rotation, accurate near zero (from the skew part, not ``acos`` of the trace)."""
    skew = rotation - rotation.T
    sine = 0.5 * float(np.linalg.norm([skew[2, 1], skew[0, 2], skew[1, 0]]))
    return math.degrees(math.atan2(sine, (float(np.trace(rotation)) - 1.0) / 2.0))


def robust_z(values: np.ndarray, floor: float, window: int = WINDOW) -> np.ndarray:
    """Per entry of (N,) `values` (NaN: unknown, z 0): ``(x − median) / max(1.4826 · MAD, floor)`` over the
    finite values within `window` entries either side."""
    z = np.zeros(len(values))
    for k, value in enumerate(values):
        if not np.isfinite(value):
            continue
        around = values[max(0, k - window): k + window + 1]
        around = around[np.isfinite(around)]
        median = float(np.median(around))
        spread = max(1.4826 * float(np.median(np.abs(around - median))), floor)
        z[k] = (value - median) / spread
    return z


def _nearer(values: np.ndarray) -> np.ndarray:
    """(N,) from (N, 2) differences to the previous and next neighbour: the smaller known one (NaN: neither)."""
    out = np.full(len(values), np.nan)
    for k, pair in enumerate(values):
        known = pair[np.isfinite(pair)]
        if len(known):
            out[k] = float(known.min())
    return out


def step_features(poses: np.ndarray) -> dict[str, np.ndarray]:
    """Per pose of (N, 4, 4) T_world_cam (entry 0 has no step: NaN): ``direction``, ``rotation`` (°) and
    ``length`` (log ratio) against the nearer neighbouring step (see the module docstring)."""
    n = len(poses)
    feats = {name: np.full(n, np.nan) for name in ("direction", "rotation", "length")}
    if n < 3:
        return feats
    # (N−1, 3) step k + 1's motion in the axes of the camera it starts from: a car turning steadily keeps moving
    # forward in its own axes (the constant-velocity model), while its direction in the world turns with it
    motion = np.einsum("kji,kj->ki", poses[:-1, :3, :3], poses[1:, :3, 3] - poses[:-1, :3, 3])
    rotation = np.einsum("kji,kjl->kil", poses[:-1, :3, :3], poses[1:, :3, :3])  # (N−1, 3, 3) R_step
    length = np.linalg.norm(motion, axis=1)
    moving = length > STILL * max(float(np.median(length)), 1e-12)
    m = len(motion)
    pairs = {name: np.full((m, 2), np.nan) for name in feats}
    for k in range(m):
        for side, j in enumerate((k - 1, k + 1)):
            if not 0 <= j < m:
                continue
            pairs["rotation"][k, side] = rotation_angle_deg(rotation[j].T @ rotation[k])
            if moving[k] and moving[j]:
                cosine = float(motion[k] @ motion[j]) / (length[k] * length[j])
                pairs["direction"][k, side] = math.degrees(math.acos(min(1.0, max(-1.0, cosine))))
                pairs["length"][k, side] = abs(math.log(length[k] / length[j]))
    for name in feats:
        feats[name][1:] = _nearer(pairs[name])
    return feats


def _series(path: Path, entity: str) -> dict[int, float]:
    table = read_entity(path, entity)
    if table.is_empty() or "Scalars:scalars" not in table.columns:
        return {}
    return {int(f): float(v[0]) for f, v in zip(table["frame"].to_list(), table["Scalars:scalars"].to_list(),
                                                strict=True) if v}


def _drop(values: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """(N,) each count against the local median, ``log(median / count)`` (positive: fewer; NaN unknown)."""
    out = np.full(len(values), np.nan)
    for k, value in enumerate(values):
        if not np.isfinite(value):
            continue
        around = values[max(0, k - window): k + window + 1]
        median = float(np.median(around[np.isfinite(around)]))
        out[k] = math.log(max(median, 1.0) / max(value, 1.0))
    return out


def find_suspects(path: Path, prefix: str = "", top: int = TOP) -> list[dict[str, Any]]:
    """The `top` most suspect frames of a recording, ranked: ``{frame, score, reasons}`` (see the module
    docstring); [] for a run shorter than three frames."""
    run = read_poses(path, prefix)
    series = {key: _series(path, f"{prefix}{entity}") for key, entity in (
        ("inliers", "/metrics/ransac/inliers"), ("alive", "/metrics/tracks/alive"),
        ("error_rotation", "/metrics/drift/rotation_deg"), ("error_translation", "/metrics/drift/translation_pct"))}
    errors = {key: series[key] for key in ("error_rotation", "error_translation") if series[key]}
    return rank_suspects(run, series["inliers"] or series["alive"], errors, top)


def rank_suspects(run: RunPoses, counts: dict[int, float], errors: dict[str, dict[int, float]],
                  top: int = TOP) -> list[dict[str, Any]]:
    """Ranked suspects of `run`: `counts` (frame → inliers or tracks), `errors` (``error_rotation`` °,
    ``error_translation`` %: frame → the frame's own step error against the ground truth; {} without)."""
    n = len(run.frames)
    if n < 3:
        return []
    features = step_features(run.poses)
    # the first frame has nothing to match: no count of it is a collapse
    features["inliers"] = _drop(np.array([counts.get(int(f), np.nan) if k else np.nan
                                          for k, f in enumerate(run.frames)]))
    for key, by_frame in errors.items():
        features[key] = np.array([by_frame.get(int(f), np.nan) for f in run.frames])
    z = {name: robust_z(values, FLOOR[name]) for name, values in features.items()}
    suspects = []
    for k, frame in enumerate(run.frames.tolist()):
        score = math.hypot(*(max(0.0, float(zs[k])) for zs in z.values()))
        reasons = [_reason(name, float(features[name][k]), float(zs[k])) for name, zs in z.items() if zs[k] >= REASON_Z]
        status, codes = run.health.get(frame, ("", []))
        if status in ("warn", "fail"):
            score += FAIL_SCORE if status == "fail" else WARN_SCORE
            reasons.append(f"health {status}" + (f" ({', '.join(codes)})" if codes else ""))
        if reasons and any(not r.startswith("health warn") for r in reasons):
            suspects.append({"frame": frame, "score": round(score, 2), "reasons": reasons})
    suspects.sort(key=lambda s: (-s["score"], s["frame"]))
    return suspects[:top]


def _reason(name: str, value: float, z: float) -> str:
    """One feature's reason, with its value and how unusual it is."""
    times = f"z {z:.0f}"
    if name == "direction":
        return f"translation turns {value:.0f}° against its neighbours' ({times})"
    if name == "rotation":
        return f"rotation {value:.2f}° out of line with its neighbours' ({times})"
    if name == "length":
        return f"step length ×{math.exp(value):.2f} (or ÷) its neighbours' ({times})"
    if name == "inliers":
        return f"inliers collapse to 1/{math.exp(value):.1f} of the frames around ({times})"
    if name == "error_rotation":
        return f"ground truth: step rotation error {value:.2f}° ({times})"
    return f"ground truth: step translation error {value:.1f} % ({times})"


def format_suspects(suspects: list[dict[str, Any]] | None, with_gt: bool, rows: int = 5) -> list[str]:
    """`vslam inspect`'s suspects table: rank, frame, score and reasons of the first `rows`."""
    if suspects is None:
        return []
    basis = "the run's own steps" + (" and its errors against the ground truth" if with_gt else
                                     ", no ground truth")
    if not suspects:
        return ["", f"suspects    none: no frame's step is out of line with its neighbours' (judged by {basis})"]
    lines = ["", f"suspects (frames whose step is implausible, judged by {basis}; --json: top {TOP})",
             "  rank  frame   score  reasons"]
    for rank, item in enumerate(suspects[:rows], 1):
        lines.append(f"  {rank:>4}  {item['frame']:>5}  {item['score']:6.1f}  {'; '.join(item['reasons'])}")
    return lines
