"""Drift attribution: each frame's own contribution to the trajectory error.

Pure numpy, no I/O. Pose arrays are (N, 4, 4) camera-to-world T_w_c, ``gt`` the ground truth G and ``est``
the estimate E, frame-aligned (row i of both is the same frame).

The absolute position error keeps growing after a single bad frame; the relative pose error between
consecutive frames does not: it is the error of that frame's own step. This is the RPE of Sturm,
Engelhard, Endres, Burgard, Cremers, "A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012
(TUM RGB-D benchmark), eqs. 1–2 with Δ = 1, kept per frame instead of averaged (`vslam_core.trajectory.metrics.rpe`).
An estimate known only up to scale (``--scale none``) must be Sim(3)-aligned onto the ground truth first
(`vslam_core.trajectory.metrics.sim3_aligned`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vslam_core.errors import GeometryError
from vslam_core.trajectory.metrics import _check_pair, rotation_angles

#: A ground-truth step shorter than this (metres) has no meaningful percentage or scale ratio (NaN).
MIN_STEP_M = 1e-3


@dataclass(frozen=True)
class FrameErrors:
    """Per-frame relative pose error, every array (N,), frame 0 all zero (it has no step).

    rotation_deg: angle of Eᵢ (°); translation_m: ‖trans(Eᵢ)‖ (m); translation_pct: 100·translation_m /
    ‖ground-truth step‖ (NaN when that step is shorter than `MIN_STEP_M`); scale_ratio: ‖estimated step‖ /
    ‖ground-truth step‖ (1 for frame 0, NaN like translation_pct).
    """

    rotation_deg: np.ndarray
    translation_m: np.ndarray
    translation_pct: np.ndarray
    scale_ratio: np.ndarray

    def __len__(self) -> int:
        return len(self.rotation_deg)


def rigid_inverse(poses: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms with Rᵀ (as `vslam_core.geometry.invert_pose`, batched)."""
    rotation_t = np.swapaxes(poses[..., :3, :3], -1, -2)
    inverse = np.zeros(poses.shape)
    inverse[..., :3, :3] = rotation_t
    inverse[..., :3, 3] = -(rotation_t @ poses[..., :3, 3:4])[..., 0]
    inverse[..., 3, 3] = 1.0
    return inverse


def rotation_angle_deg(rotations: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (...) angle in degrees (`metrics.rotation_angles`: accurate for the small angles
    of one frame's error)."""
    return np.degrees(rotation_angles(rotations))


def step_errors(gt_step: np.ndarray, est_step: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The four errors of (..., 4, 4) relative motions: ground truth Gᵢ₋₁⁻¹Gᵢ and estimate Eᵢ₋₁⁻¹Eᵢ.

    Eᵢ = (Gᵢ₋₁⁻¹Gᵢ)⁻¹(Eᵢ₋₁⁻¹Eᵢ) (Sturm et al. 2012, eq. 1). Returns (rotation °, translation m,
    translation % of the ground-truth step, scale ratio), each of shape (...).
    """
    error = rigid_inverse(gt_step) @ est_step
    rotation = rotation_angle_deg(error[..., :3, :3])
    translation = np.linalg.norm(error[..., :3, 3], axis=-1)
    gt_length = np.linalg.norm(gt_step[..., :3, 3], axis=-1)
    est_length = np.linalg.norm(est_step[..., :3, 3], axis=-1)
    moved = gt_length >= MIN_STEP_M
    safe = np.where(moved, gt_length, 1.0)
    pct = np.where(moved, 100.0 * translation / safe, np.nan)
    ratio = np.where(moved, est_length / safe, np.nan)
    return rotation, translation, pct, ratio


def frame_errors(gt: np.ndarray, est: np.ndarray) -> FrameErrors:
    """Each frame's relative pose error against the ground truth, from the previous frame (Δ = 1).

    gt, est: (N, 4, 4) T_w_c, N >= 1. For i >= 1, Eᵢ = (Gᵢ₋₁⁻¹Gᵢ)⁻¹(Eᵢ₋₁⁻¹Eᵢ) — the relative pose error of
    Sturm et al. 2012 (TUM RGB-D benchmark), eqs. 1–2 with Δ = 1 — and the values of `FrameErrors` are its
    rotation angle and translation norm, the latter also as a percentage of the ground-truth step, plus
    the ratio of the step lengths. Frame 0 has no step: zeros (ratio 1). Raises `GeometryError` for
    malformed input. Poses are inverted as rigid transforms (Rᵀ), as the recorder does frame by frame.
    With ``--scale none`` pass the Sim(3)-aligned estimate (unit steps have no metric scale).
    """
    g, e = _check_pair(gt, est)
    n = len(g)
    rotation, translation = np.zeros(n), np.zeros(n)
    pct, ratio = np.zeros(n), np.ones(n)
    if n > 1:
        rotation[1:], translation[1:], pct[1:], ratio[1:] = step_errors(rigid_inverse(g[:-1]) @ g[1:],
                                                                        rigid_inverse(e[:-1]) @ e[1:])
    return FrameErrors(rotation, translation, pct, ratio)


#: Per-frame errors below this (degrees, metres, %) are rounding, not error (arccos alone leaves ~1e-6°).
NEGLIGIBLE = 1e-5


def worst_frames(errors: np.ndarray, k: int = 10, frames: np.ndarray | None = None) -> list[tuple[int, float]]:
    """The `k` largest per-frame errors as (frame, value), largest first; NaN values are never ranked, nor
    errors below `NEGLIGIBLE` (a step equal to the truth but for rounding: it contributes nothing).

    errors: (N,) e.g. `FrameErrors.rotation_deg`; frames: (N,) the frame index of each entry (default 0..N-1,
    e.g. the source frame indices of a run). Ties keep the earlier frame first.
    """
    values = np.asarray(errors, dtype=np.float64)
    if values.ndim != 1:
        raise GeometryError(f"worst_frames: expected (N,) errors, got shape {values.shape}")
    index = np.arange(len(values)) if frames is None else np.asarray(frames)
    if index.shape != values.shape:
        raise GeometryError(f"worst_frames: {len(index)} frame indices for {len(values)} errors")
    if k < 1:
        return []
    finite = np.flatnonzero(np.isfinite(values) & (values >= NEGLIGIBLE))
    order = finite[np.argsort(-values[finite], kind="stable")][:k]
    return [(int(index[i]), float(values[i])) for i in order]
