"""Trajectory error metrics: KITTI odometry score, ATE, RPE and the seed paper's RMS error.

Pure numpy, no I/O. Every pose array is (N, 4, 4) camera-to-world T_w_c (see
../shared/docs/conventions.md); ``gt`` is the ground truth G, ``est`` the estimate E, frame-aligned
(row i of both belongs to the same frame, same N).

What is implemented, and after whom:

- KITTI odometry score (`kitti_segment_errors`, `kitti_errors`): the devkit's ``evaluate_odometry.cpp``
  (Geiger, Lenz, Urtasun, CVPR 2012): segments of 100..800 m of ground-truth path starting every 10th
  frame, translation error in % of the segment length and rotation error in deg/100 m, no alignment.
- Umeyama alignment (`umeyama_alignment`): S. Umeyama, "Least-squares estimation of transformation
  parameters between two point patterns", IEEE TPAMI 13(4), 1991, eqs. 40-42 (sign fix of eq. 43).
- ATE and RPE (`ate`, `rpe`): Sturm, Engelhard, Endres, Burgard, Cremers, "A benchmark for the evaluation
  of RGB-D SLAM systems", IROS 2012 (TUM RGB-D benchmark), the same definitions as evo's ``evo_ape`` /
  ``evo_rpe`` (``-a`` = SE(3) alignment, ``-as`` = Sim(3) alignment).

Malformed input (wrong shapes, different lengths, non-finite values) raises `GeometryError`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal, NamedTuple

import numpy as np

from vslam_core.errors import GeometryError

Alignment = Literal["se3", "sim3", "none"]

#: Segment lengths of the KITTI odometry benchmark (metres).
KITTI_LENGTHS: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: The devkit starts a segment at every 10th frame ("every second" at 10 Hz).
KITTI_STEP = 10


def scale_errors(gt: np.ndarray, est: np.ndarray, min_step_m: float = 0.1) -> tuple[float, float, float]:
    """How well the estimate's step lengths match the ground truth's (for a scale source such as the
    camera height): (median and mean absolute of |Δp_est,i| / |Δp_gt,i| − 1 over frames that moved at
    least `min_step_m`, and total path length est / gt − 1), all in percent, no alignment."""
    g, e = _check_pair(gt, est)
    step_gt = np.linalg.norm(np.diff(g[:, :3, 3], axis=0), axis=1)
    step_est = np.linalg.norm(np.diff(e[:, :3, 3], axis=0), axis=1)
    moved = step_gt >= min_step_m
    if not moved.any():
        return float("nan"), float("nan"), float("nan")
    ratio = step_est[moved] / step_gt[moved] - 1
    path = step_est.sum() / step_gt.sum() - 1
    return float(100 * np.median(ratio)), float(100 * np.mean(np.abs(ratio))), float(100 * path)


# --------------------------------------------------------------------------------------------------
# input checks and small helpers


def _as_poses(poses: np.ndarray, name: str) -> np.ndarray:
    """Check an (N, 4, 4) pose array (N >= 1, finite) and return it as float64."""
    array = np.asarray(poses, dtype=np.float64)
    if array.ndim != 3 or array.shape[1:] != (4, 4):
        raise GeometryError(f"{name}: expected (N, 4, 4) poses, got shape {array.shape}")
    if len(array) == 0:
        raise GeometryError(f"{name}: no poses (N = 0)")
    if not np.all(np.isfinite(array)):
        raise GeometryError(f"{name}: poses contain NaN or infinite values")
    return array


def _check_pair(gt: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Check ground truth and estimate: both (N, 4, 4) with the same N."""
    g = _as_poses(gt, "ground truth")
    e = _as_poses(est, "estimate")
    if len(g) != len(e):
        raise GeometryError(
            f"ground truth has {len(g)} poses but the estimate has {len(e)}: they must be frame-aligned"
        )
    return g, e


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⁻¹·b for (..., 4, 4) transforms (a general inverse, as the devkit's ``Matrix::inv``)."""
    try:
        return np.linalg.inv(a) @ b
    except np.linalg.LinAlgError:
        raise GeometryError("a pose matrix is singular (not a rigid transform)") from None


def rotation_angles(rotations: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (...) angle in radians: atan2(½‖(R − Rᵀ)^∨‖, (tr R − 1) / 2), well conditioned at
    every angle. acos((tr R − 1) / 2) alone loses half the digits near 0: a 0.05° step read back from 10-digit
    text moved by 3·10⁻⁶ of itself, and the rounding of a KITTI pose file's 7 digits costs it ~1e-3 rad."""
    skew = rotations - np.swapaxes(rotations, -1, -2)
    sine = 0.5 * np.linalg.norm(np.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], axis=-1), axis=-1)
    return np.arctan2(sine, 0.5 * (np.trace(rotations, axis1=-2, axis2=-1) - 1.0))


def _devkit_rotation_angle(rotation: np.ndarray) -> float:
    """(3, 3) rotation -> angle in radians, acos(clamp((tr R - 1) / 2, -1, 1)) as the KITTI devkit computes it."""
    return float(np.arccos(np.clip(0.5 * (np.trace(rotation) - 1.0), -1.0, 1.0)))


# --------------------------------------------------------------------------------------------------
# KITTI odometry devkit


class SegmentError(NamedTuple):
    """One KITTI segment: frames ``first``..``last`` of nominal length ``length`` metres.

    t_err: ‖t_err‖ / length (dimensionless ratio); r_err: rotation angle / length (rad/m).
    """

    first: int
    last: int
    length: float
    t_err: float
    r_err: float


def trajectory_distances(poses: np.ndarray) -> np.ndarray:
    """Cumulative path length (N,) of (N, 4, 4) poses: d[0] = 0, d[i] = d[i-1] + ‖p_i - p_{i-1}‖.

    ``trajectoryDistances`` of the KITTI devkit (which accumulates in float32; this uses float64).
    """
    p = _as_poses(poses, "poses")[:, :3, 3]
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def kitti_segment_errors(
    gt: np.ndarray,
    est: np.ndarray,
    lengths: tuple[float, ...] = KITTI_LENGTHS,
    step: int = KITTI_STEP,
) -> list[SegmentError]:
    """Per-segment errors of the KITTI devkit (``calcSequenceErrors`` of ``evaluate_odometry.cpp``).

    gt, est: (N, 4, 4) T_w_c. With d the cumulative ground-truth path length, for every
    first = 0, step, 2·step, … and every L in ``lengths``: last = the first index with
    d[last] > d[first] + L (the pair is skipped if there is none); ΔG = G_f⁻¹G_l, ΔE = E_f⁻¹E_l,
    Err = ΔE⁻¹ΔG; r = acos(clamp((tr R_err - 1) / 2)), t = ‖t_err‖; the record stores t/L and r/L
    (rad/m). Returns the records ordered by first, then by length; empty when the ground-truth path is
    shorter than every length (e.g. only the 100 m and 200 m segments exist on 300 KITTI frames).
    """
    g, e = _check_pair(gt, est)
    if step < 1:
        raise GeometryError(f"step must be at least 1, got {step}")
    if any(not (length > 0) for length in lengths):
        raise GeometryError(f"segment lengths must be positive, got {lengths}")
    d = trajectory_distances(g)
    records: list[SegmentError] = []
    for first in range(0, len(g), step):
        for length in lengths:
            # first index with d[last] > d[first] + L (d is non-decreasing)
            last = int(np.searchsorted(d, d[first] + length, side="right"))
            if last >= len(d):
                continue
            delta_gt = _relative(g[first], g[last])
            delta_est = _relative(e[first], e[last])
            error = _relative(delta_est, delta_gt)
            r = _devkit_rotation_angle(error[:3, :3])
            t = float(np.linalg.norm(error[:3, 3]))
            records.append(SegmentError(first, last, float(length), t / length, r / length))
    return records


def kitti_errors(gt: np.ndarray, est: np.ndarray) -> tuple[float, float]:
    """KITTI odometry score: (t_err in %, r_err in deg/100 m) of (N, 4, 4) ground truth and estimate.

    The plain mean over every (first frame, length) segment of `kitti_segment_errors`, t ×100 and
    r ×180/π×100, as the devkit's summary. No alignment: a monocular estimate must carry the metric
    scale (e.g. from ground truth) to score well.

    When the ground-truth path is shorter than the shortest segment (100 m) no segment exists and both
    values are NaN (no exception): callers print them as "n/a".
    """
    records = kitti_segment_errors(gt, est)
    if not records:
        return float("nan"), float("nan")
    t = np.mean([r.t_err for r in records])
    r = np.mean([r.r_err for r in records])
    return float(t * 100.0), float(np.degrees(r) * 100.0)


def kitti_errors_by_length(gt: np.ndarray, est: np.ndarray) -> dict[float, tuple[float, float, int]]:
    """The KITTI score per segment length: {L: (t_err %, r_err deg/100 m, segment count)} for every L of
    `KITTI_LENGTHS` that has at least one segment (the devkit's per-length plots)."""
    by_length: dict[float, list[SegmentError]] = {}
    for record in kitti_segment_errors(gt, est):
        by_length.setdefault(record.length, []).append(record)
    return {
        length: (
            float(np.mean([r.t_err for r in records]) * 100.0),
            float(np.degrees(np.mean([r.r_err for r in records])) * 100.0),
            len(records),
        )
        for length, records in sorted(by_length.items())
    }


# --------------------------------------------------------------------------------------------------
# Umeyama alignment and ATE


def umeyama_alignment(
    src: np.ndarray, dst: np.ndarray, with_scale: bool
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity (or rigid) transform mapping ``src`` onto ``dst``: dst ≈ s·R·src + t.

    src, dst: (3, N) corresponding points (N >= 1). Returns R (3, 3) proper rotation, t (3,) and
    s (float; 1.0 when ``with_scale`` is False).

    Umeyama 1991, eqs. 40-42: Σ = 1/N Σᵢ (yᵢ - μ_y)(xᵢ - μ_x)ᵀ = U D Vᵀ, S = diag(1, 1, -1) when
    det(U)·det(V) < 0 (eq. 43, also covers a rank-deficient Σ) else I; R = U S Vᵀ (40),
    s = tr(D S) / σ_x² (42), t = μ_y - s R μ_x (41).

    Raises `GeometryError` for wrong shapes, non-finite values, or, with scale, when all ``src`` points
    coincide (σ_x² = 0: the scale is undefined).
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] != 3 or x.shape[1] == 0:
        raise GeometryError(f"umeyama_alignment: src must be (3, N) with N >= 1, got shape {x.shape}")
    if y.shape != x.shape:
        raise GeometryError(f"umeyama_alignment: dst has shape {y.shape}, src has {x.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise GeometryError("umeyama_alignment: points contain NaN or infinite values")
    n = x.shape[1]
    mean_x = x.mean(axis=1)
    mean_y = y.mean(axis=1)
    xc = x - mean_x[:, None]
    yc = y - mean_y[:, None]
    sigma_x = float(np.sum(xc * xc) / n)
    cov = (yc @ xc.T) / n
    u, d, vt = np.linalg.svd(cov)
    s_diag = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s_diag[2] = -1.0
    rotation = u @ np.diag(s_diag) @ vt
    if with_scale:
        if sigma_x <= np.finfo(np.float64).tiny:
            raise GeometryError("umeyama_alignment: all source points coincide, the scale is undefined")
        scale = float(np.dot(d, s_diag) / sigma_x)
    else:
        scale = 1.0
    translation = mean_y - scale * rotation @ mean_x
    return rotation, translation, scale


def align_positions(gt: np.ndarray, est: np.ndarray, align: Alignment) -> np.ndarray:
    """Estimated positions (N, 3) after Umeyama-aligning them onto the ground-truth positions.

    gt, est: (N, 4, 4). ``align``: "se3" (rotation + translation), "sim3" (plus scale) or "none".
    """
    g, e = _check_pair(gt, est)
    p_est = e[:, :3, 3]
    if align == "none":
        return p_est.copy()
    if align not in ("se3", "sim3"):
        raise ValueError(f"align must be 'se3', 'sim3' or 'none', got {align!r}")
    rotation, translation, scale = umeyama_alignment(p_est.T, g[:, :3, 3].T, with_scale=align == "sim3")
    return scale * p_est @ rotation.T + translation


def stands_still(est: np.ndarray) -> bool:
    """Whether every position of the (N, 4, 4) estimate is the same (a parked car, a run that tracked no frame):
    then no Sim(3) aligns it (Umeyama's scale is undefined)."""
    positions = np.asarray(est)[:, :3, 3]
    return bool(np.all(positions == positions[0]))


def ate(gt: np.ndarray, est: np.ndarray, align: Alignment = "sim3") -> float:
    """Absolute trajectory error (metres): RMSE of ‖p_gt,i - p_est,i‖ after aligning the estimate.

    gt, est: (N, 4, 4). Sturm et al. 2012 (ATE), alignment after Umeyama 1991; ``align="sim3"`` is the
    monocular standard (evo ``-as``), "se3" evo's ``-a``, "none" the raw positions.
    """
    g, _ = _check_pair(gt, est)
    aligned = align_positions(gt, est, align)
    return float(np.sqrt(np.mean(np.sum((g[:, :3, 3] - aligned) ** 2, axis=1))))


# --------------------------------------------------------------------------------------------------
# RPE and per-frame errors


def rpe(gt: np.ndarray, est: np.ndarray, delta: int = 1) -> tuple[float, float]:
    """Relative pose error over all frame pairs (i, i + delta): (translation RMSE in m, mean rotation deg).

    gt, est: (N, 4, 4). Sturm et al. 2012: Eᵢ = (Gᵢ⁻¹G_{i+Δ})⁻¹(Eᵢ⁻¹E_{i+Δ}) for i = 0 … N-1-Δ (every
    overlapping pair, = evo_rpe with ``--all_pairs``; for Δ = 1 the same as evo's default). Translation:
    RMSE of ‖trans(Eᵢ)‖; rotation: mean of angle(Eᵢ) in degrees. NaN, NaN when N <= delta (no pair).
    """
    g, e = _check_pair(gt, est)
    if delta < 1:
        raise GeometryError(f"rpe: delta must be at least 1 frame, got {delta}")
    if len(g) <= delta:
        return float("nan"), float("nan")
    rel_gt = _relative(g[:-delta], g[delta:])
    rel_est = _relative(e[:-delta], e[delta:])
    errors = _relative(rel_gt, rel_est)
    trans = np.linalg.norm(errors[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angles(errors[:, :3, :3]))
    return float(np.sqrt(np.mean(trans**2))), float(np.mean(rot))


def rpe_by_distance(
    gt: np.ndarray, est: np.ndarray, distance_m: float, tolerance_m: float | None = None
) -> tuple[float, float]:
    """RPE over pairs ``distance_m`` of ground-truth path apart: (translation RMSE m, mean rotation deg).

    gt, est: (N, 4, 4). For every i, j > i is the frame whose path distance from i (d[j] - d[i], d the
    cumulative ground-truth path length) is nearest to ``distance_m``; the pair is kept when that is within
    ``tolerance_m`` (default 10 % of the distance). Then as `rpe`. The pairs of evo_rpe's
    ``--delta_unit m --all_pairs`` (``filter_pairs_by_path``). NaN, NaN when no pair is kept.
    """
    g, e = _check_pair(gt, est)
    if not distance_m > 0:
        raise GeometryError(f"rpe_by_distance: distance must be positive, got {distance_m}")
    tolerance = 0.1 * distance_m if tolerance_m is None else tolerance_m
    d = trajectory_distances(g)
    pairs = []
    for i in range(len(d) - 1):
        ahead = d[i + 1 :] - d[i]
        j = int(np.argmin(np.abs(ahead - distance_m)))
        if abs(ahead[j] - distance_m) <= tolerance:
            pairs.append((i, i + 1 + j))
    if not pairs:
        return float("nan"), float("nan")
    first, second = np.array(pairs).T
    errors = _relative(_relative(g[first], g[second]), _relative(e[first], e[second]))
    trans = np.linalg.norm(errors[:, :3, 3], axis=1)
    rot = np.degrees(rotation_angles(errors[:, :3, :3]))
    return float(np.sqrt(np.mean(trans**2))), float(np.mean(rot))


def position_errors(gt: np.ndarray, est: np.ndarray) -> np.ndarray:
    """Per-frame position error (N,) in metres, ‖p_gt,i - p_est,i‖, no alignment."""
    g, e = _check_pair(gt, est)
    return np.linalg.norm(g[:, :3, 3] - e[:, :3, 3], axis=1)


def heading_errors(gt: np.ndarray, est: np.ndarray) -> np.ndarray:
    """Per-frame rotation error (N,) in degrees: the angle of R_gt,iᵀ · R_est,i, no alignment."""
    g, e = _check_pair(gt, est)
    relative = np.swapaxes(g[:, :3, :3], 1, 2) @ e[:, :3, :3]
    return np.degrees(rotation_angles(relative))


def paper_rms_error(gt: np.ndarray, est: np.ndarray) -> float:
    """The seed paper's figure (metres): RMS over frames of the x–z (ground plane) position error.

    gt, est: (N, 4, 4); sqrt(mean_i((x_gt - x_est)² + (z_gt - z_est)²)), no alignment (the estimate's
    scale is expected to come from ground truth).
    """
    g, e = _check_pair(gt, est)
    diff = g[:, :3, 3][:, [0, 2]] - e[:, :3, 3][:, [0, 2]]
    return float(np.sqrt(np.mean(np.sum(diff**2, axis=1))))


# --------------------------------------------------------------------------------------------------
# everything at once


@dataclass(frozen=True)
class TrajectoryMetrics:
    """Every metric of one estimate against its ground truth.

    t_err: KITTI translation error (%); r_err: KITTI rotation error (deg/100 m) — both NaN when the path
    is shorter than 100 m. ate_se3 / ate_sim3: ATE RMSE (m) after SE(3) / Sim(3) alignment (ate_sim3 is
    NaN when every estimated position is the same point). rpe_trans (m, RMSE) / rpe_rot (deg, mean):
    RPE for Δ = 1 frame. paper_rms: x–z RMS error (m), no alignment. frames: N. length_m: ground-truth
    path length (m).
    """

    t_err: float
    r_err: float
    ate_se3: float
    ate_sim3: float
    rpe_trans: float
    rpe_rot: float
    paper_rms: float
    frames: int
    length_m: float

    def as_dict(self) -> dict[str, float | int]:
        """The fields as a plain dict (field name -> value), e.g. for a table row or JSON."""
        return asdict(self)


def sim3_aligned(gt: np.ndarray, est: np.ndarray) -> np.ndarray:
    """The (N, 4, 4) estimate moved onto the ground truth by its Umeyama Sim(3) alignment of positions:
    p ← s·R·p + t, R_est ← R·R_est. For trajectories known only up to scale (monocular, no scale source)."""
    g, e = _check_pair(gt, est)
    rotation, translation, scale = umeyama_alignment(e[:, :3, 3].T, g[:, :3, 3].T, with_scale=True)
    aligned = e.copy()
    aligned[:, :3, 3] = scale * e[:, :3, 3] @ rotation.T + translation
    aligned[:, :3, :3] = rotation @ e[:, :3, :3]
    return aligned


def evaluate(gt: np.ndarray, est: np.ndarray) -> TrajectoryMetrics:
    """Compute every metric of ``est`` (N, 4, 4) against ``gt`` (N, 4, 4); see `TrajectoryMetrics`."""
    g, e = _check_pair(gt, est)
    t_err, r_err = kitti_errors(g, e)
    ate_sim3 = float("nan") if stands_still(e) else ate(g, e, "sim3")
    rpe_trans, rpe_rot = rpe(g, e, 1)
    return TrajectoryMetrics(
        t_err=t_err,
        r_err=r_err,
        ate_se3=ate(g, e, "se3"),
        ate_sim3=ate_sim3,
        rpe_trans=rpe_trans,
        rpe_rot=rpe_rot,
        paper_rms=paper_rms_error(g, e),
        frames=len(g),
        length_m=float(trajectory_distances(g)[-1]),
    )
