"""Two-view geometry, pure numpy (+ OpenCV's decomposition of E).

Conventions (../shared/docs/conventions.md): camera frame x right, y down, z forward. Relative motion
between the current and the previous (key)frame is T_prev_cur = [R | t] with X_prev = R·X_cur + t, which
is what ``cv2.findEssentialMat(p_cur, p_prev)`` + ``cv2.recoverPose`` return; the essential matrix
satisfies x_prevᵀ·E·x_cur = 0 with E = [t]ₓR. Points are (N, 2) arrays; "normalised" means
K⁻¹-multiplied image coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam_core.errors import GeometryError


def _check_points(name: str, points: np.ndarray) -> None:
    if points.ndim != 2 or points.shape[1] != 2:
        raise GeometryError(f"{name}: expected (N, 2) points, got shape {points.shape}")


def pose_matrix(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(3, 3) R and (3,) t -> (4, 4) homogeneous transform [R | t]."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = np.asarray(translation).reshape(3)
    return pose


def chain(T_w_prev: np.ndarray, T_prev_cur: np.ndarray) -> np.ndarray:  # noqa: N803
    """T_w_cur = T_w_prev · T_prev_cur: the new pose is the relative motion applied in the previous
    camera's frame (t_w += R_w·t, R_w = R_w·R). The reverse order (mono-vo's R_w = R·R_w) is wrong as soon
    as the camera pitches or rolls while turning."""
    return T_w_prev @ T_prev_cur


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform, or of each of an (N, 4, 4) stack, using Rᵀ instead of a general
    inverse."""
    if pose.ndim == 3:
        stacked = np.broadcast_to(np.eye(4), pose.shape).copy()
        stacked[:, :3, :3] = pose[:, :3, :3].transpose(0, 2, 1)
        stacked[:, :3, 3] = -(stacked[:, :3, :3] @ pose[:, :3, 3:])[:, :, 0]
        return stacked
    inverse = np.eye(4)
    inverse[:3, :3] = pose[:3, :3].T
    inverse[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inverse


def orthonormalise(pose: np.ndarray) -> np.ndarray:
    """(4, 4) pose with its rotation projected onto SO(3) (the nearest rotation in the Frobenius norm, by SVD):
    chained products of rotations drift off it in floating point, and `invert_pose` assumes they do not."""
    u, _, vt = np.linalg.svd(pose[:3, :3])
    rigid = pose.copy()
    rigid[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rigid


def rotation_angle(rotation: np.ndarray) -> float:
    """Angle (radians) of a (3, 3) rotation: acos((tr R − 1) / 2), clamped."""
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (radians) between two 3-vectors; 0 if either is zero."""
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0 or nb == 0:
        return 0.0
    return float(np.arccos(np.clip(np.dot(a, b) / (na * nb), -1.0, 1.0)))


def skew(v: np.ndarray) -> np.ndarray:
    """[v]ₓ: the (3, 3) matrix with [v]ₓ·w = v × w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: axis-angle (3,) -> (3, 3) rotation."""
    rotation, _ = cv2.Rodrigues(np.asarray(omega, dtype=np.float64).reshape(3, 1))
    return np.asarray(rotation)


def so3_log(rotation: np.ndarray) -> np.ndarray:
    """Inverse of `so3_exp`: (3, 3) rotation -> axis-angle (3,)."""
    omega, _ = cv2.Rodrigues(np.asarray(rotation, dtype=np.float64))
    return np.asarray(omega).reshape(3)


def interpolate_pose(start: np.ndarray, end: np.ndarray, fraction: float) -> np.ndarray:
    """(4, 4) pose `fraction` of the way from `start` to `end`: positions linearly, rotation along the
    geodesic (R_start·exp(fraction·log(R_startᵀ·R_end)), spherical linear interpolation)."""
    pose = np.eye(4)
    pose[:3, :3] = start[:3, :3] @ so3_exp(fraction * so3_log(start[:3, :3].T @ end[:3, :3]))
    pose[:3, 3] = (1.0 - fraction) * start[:3, 3] + fraction * end[:3, 3]
    return pose


def interpolate_gaps(poses: list[np.ndarray], missing: set[int]) -> list[np.ndarray]:
    """The (4, 4) poses with each run of `missing` positions that has a pose on both sides replaced by poses
    interpolated between those two (`interpolate_pose`); a run at the start or the end is left as it is."""
    filled = list(poses)
    position, count = 0, len(filled)
    while position < count:
        if position not in missing or position == 0:
            position += 1
            continue
        end = position
        while end < count and end in missing:
            end += 1
        if end < count:  # positions position..end-1 are missing; end has a pose again
            before, after = filled[position - 1], filled[end]
            for gap in range(position, end):
                filled[gap] = interpolate_pose(before, after, (gap - position + 1) / (end - position + 1))
        position = end
    return filled


def essential_from_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """E = [t]ₓR for X_prev = R·X_cur + t."""
    return skew(np.asarray(translation).reshape(3)) @ rotation


def normalise_points(points: np.ndarray, K: np.ndarray) -> np.ndarray:  # noqa: N803
    """(N, 2) pixel coordinates -> (N, 2) normalised coordinates ((u − cx)/fx, (v − cy)/fy)."""
    _check_points("points", points)
    return np.column_stack(
        ((points[:, 0] - K[0, 2]) / K[0, 0], (points[:, 1] - K[1, 2]) / K[1, 1])
    ).astype(np.float64)


def candidate_poses(essential: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four (R, t) that an essential matrix E = U·diag(1, 1, 0)·Vᵀ admits (Hartley & Zisserman,
    Result 9.19): (R1, t), (R1, −t), (R2, t), (R2, −t) with R1 = U·W·Vᵀ, R2 = U·Wᵀ·Vᵀ, t = u3 (unit)."""
    if essential.shape != (3, 3) or not np.all(np.isfinite(essential)):
        raise GeometryError(f"essential matrix must be a finite (3, 3) array, got {essential.shape}")
    r1, r2, t = cv2.decomposeEssentialMat(essential)
    t = t.reshape(3)
    return [(r1, t.copy()), (r1, -t), (r2, t.copy()), (r2, -t)]


def triangulate(
    rotation: np.ndarray, translation: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray
) -> np.ndarray:
    """Midpoint triangulation of normalised correspondences (Hartley & Zisserman §12.1; Beardsley et al.
    1994), vectorised: the point halfway along the shortest segment between the two viewing rays.

    Cameras: current at the origin, previous with X_prev = R·X_cur + t. Returns (N, 3) points in the
    CURRENT camera frame, in units of |t|; rows are NaN where the rays are parallel (a point at infinity).
    A ray's depth is signed, so a point behind a camera stays behind it (chirality sees it).
    """
    _check_points("x_cur", x_cur)
    _check_points("x_prev", x_prev)
    t = np.asarray(translation, dtype=np.float64).reshape(3)
    ray_cur = _homogeneous(x_cur) @ np.asarray(rotation).T  # in the previous camera's frame
    ray_prev = _homogeneous(x_prev)
    midpoint_prev, parallel = _midpoints(ray_cur, ray_prev, t, ray_cur @ t, ray_prev @ t)
    with np.errstate(invalid="ignore"):
        points = (midpoint_prev - t) @ np.asarray(rotation)  # Rᵀ·(X_prev − t)
    points[parallel] = np.nan
    return np.asarray(points)


def triangulate_each(
    rotations: np.ndarray, translations: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray
) -> np.ndarray:
    """`triangulate` with a camera pair of its own for each correspondence: (N, 3, 3) rotations and (N, 3)
    translations (X_prev = R·X_cur + t), (N, 2) normalised points in each. Returns (N, 3) points in each
    pair's current camera frame (NaN where the rays are parallel). One call for many keyframe pairs, instead
    of one per pair."""
    _check_points("x_cur", x_cur)
    _check_points("x_prev", x_prev)
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    ray_cur = np.einsum("nij,nj->ni", rotations, _homogeneous(x_cur))  # in the previous camera's frame
    ray_prev = _homogeneous(x_prev)
    midpoint_prev, parallel = _midpoints(ray_cur, ray_prev, t, np.einsum("ij,ij->i", ray_cur, t),
                                         np.einsum("ij,ij->i", ray_prev, t))
    with np.errstate(invalid="ignore"):
        points = np.einsum("nji,nj->ni", rotations, midpoint_prev - t)  # Rᵀ·(X_prev − t)
    points[parallel] = np.nan
    return np.asarray(points)


def _midpoints(ray_cur: np.ndarray, ray_prev: np.ndarray, t: np.ndarray, d: np.ndarray,
               e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The midpoint step shared by `triangulate` and `triangulate_each`: (N, 3) rays of the current and the
    previous camera in the previous camera's frame, the baseline t ((3,) or (N, 3)), d = ray_cur·t and
    e = ray_prev·t (N,). Minimises |t + λ·ray_cur − μ·ray_prev|² over the depths λ, μ and returns the (N, 3)
    midpoints (previous camera's frame) and an (N,) mask of parallel rays."""
    a = np.einsum("ij,ij->i", ray_cur, ray_cur)
    b = np.einsum("ij,ij->i", ray_cur, ray_prev)
    c = np.einsum("ij,ij->i", ray_prev, ray_prev)
    det = b * b - a * c  # −|ray_cur × ray_prev|²
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_cur = (d * c - b * e) / det
        depth_prev = (b * d - a * e) / det
        midpoint_prev = 0.5 * (t + depth_cur[:, None] * ray_cur + depth_prev[:, None] * ray_prev)
    return midpoint_prev, np.abs(det) < 1e-12 * a * c


def in_front_mask(
    rotation: np.ndarray, translation: np.ndarray, points_cur: np.ndarray, max_depth: float
) -> np.ndarray:
    """(N,) bool: the (N, 3) points (current frame) have 0 < depth < max_depth in BOTH cameras."""
    points_prev = points_cur @ rotation.T + np.asarray(translation).reshape(1, 3)
    with np.errstate(invalid="ignore"):
        return np.asarray(
            (points_cur[:, 2] > 0)
            & (points_cur[:, 2] < max_depth)
            & (points_prev[:, 2] > 0)
            & (points_prev[:, 2] < max_depth)
        )


def in_front_with_parallax(points_cur: np.ndarray, points_prev: np.ndarray, translation: np.ndarray,
                           min_deg: float) -> np.ndarray:
    """(N,) bool: the points, (N, 3) in the current camera and (N, 3) in the previous one (X_prev = R·X_cur + t,
    `translation` t as (3,) or one per point (N, 3)), lie in front of both cameras and the two rays to each meet
    at `min_deg` or more (a landmark's depth is conditioned by that angle; NaN points are never kept)."""
    ray_cur = points_prev - translation  # from the current camera's centre, in the previous camera's frame
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.einsum("ij,ij->i", points_prev, ray_cur) / (
            np.linalg.norm(points_prev, axis=1) * np.linalg.norm(ray_cur, axis=1))
        return np.asarray((points_cur[:, 2] > 0) & (points_prev[:, 2] > 0) & (cosine < np.cos(np.radians(min_deg))))


@dataclass(frozen=True)
class CandidatePose:
    """One of the four decompositions of E, with its chirality count."""

    rotation: np.ndarray  # (3, 3), X_prev = R·X_cur + t
    translation: np.ndarray  # (3,), unit length
    in_front: int  # inliers triangulated in front of both cameras


def chirality_check(
    essential: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray, max_depth: float = 50.0
) -> tuple[list[CandidatePose], int]:
    """Triangulate the (N, 2) normalised inlier correspondences under each of the four candidates and
    count the points in front of both cameras (Hartley & Zisserman §9.6.3). Returns the four candidates in
    `candidate_poses` order and the index of the winner (most points in front; first on ties, like
    cv2.recoverPose)."""
    candidates = []
    for rotation, translation in candidate_poses(essential):
        points = triangulate(rotation, translation, x_cur, x_prev)
        count = int(in_front_mask(rotation, translation, points, max_depth).sum())
        candidates.append(CandidatePose(rotation, translation, count))
    best = int(np.argmax([c.in_front for c in candidates]))
    return candidates, best


def sampson_errors(
    essential: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray
) -> np.ndarray:
    """(N,) signed first-order geometric (Sampson) error of x_prevᵀ·E·x_cur = 0, in normalised units
    (Hartley & Zisserman eq. 11.9). Multiply by the focal length for pixels."""
    return _sampson(essential, _homogeneous(x_cur), _homogeneous(x_prev))


def _homogeneous(points: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) with a column of ones."""
    return np.column_stack((points, np.ones(len(points))))


def _sampson_terms(
    essential: np.ndarray, h_cur: np.ndarray, h_prev: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The parts of the Sampson error on (N, 3) homogeneous points: E·x_cur and Eᵀ·x_prev (N, 3), the
    algebraic error x_prevᵀ·E·x_cur (N,) and its first-order normaliser (N,), floored above zero."""
    e_cur = h_cur @ essential.T
    et_prev = h_prev @ essential
    algebraic = np.einsum("ij,ij->i", h_prev, e_cur)
    norm = np.maximum(np.sqrt(e_cur[:, 0] ** 2 + e_cur[:, 1] ** 2 + et_prev[:, 0] ** 2 + et_prev[:, 1] ** 2), 1e-15)
    return e_cur, et_prev, algebraic, norm


def _sampson(essential: np.ndarray, h_cur: np.ndarray, h_prev: np.ndarray) -> np.ndarray:
    """`sampson_errors` on (N, 3) homogeneous points."""
    _, _, algebraic, norm = _sampson_terms(essential, h_cur, h_prev)
    return np.asarray(algebraic / norm)


def sampson_jacobian(
    rotation: np.ndarray, translation: np.ndarray, basis: np.ndarray, h_cur: np.ndarray, h_prev: np.ndarray
) -> np.ndarray:
    """(N, 5) derivatives of the signed Sampson errors (`sampson_errors`) of E = [t]ₓR with respect to
    (ω, β) at zero, for R ← R·exp([ω]ₓ) and t ← normalise(t + B·β): dE/dω_k = [t]ₓ·R·[e_k]ₓ and
    dE/dβ_k = [B_k]ₓ·R (B ⟂ t, |t| = 1). basis B: (3, 2); h_cur, h_prev: (N, 3) homogeneous normalised
    points."""
    essential = skew(translation) @ rotation
    d_essential = np.stack([essential @ skew(axis) for axis in np.eye(3)] + [skew(b) @ rotation for b in basis.T])
    e_cur, et_prev, algebraic, norm = _sampson_terms(essential, h_cur, h_prev)
    d_e_cur = h_cur @ d_essential.transpose(0, 2, 1)  # (5, N, 3): dE_k·x_cur
    d_et_prev = h_prev @ d_essential  # (5, N, 3): dE_kᵀ·x_prev
    d_algebraic = (d_e_cur * h_prev).sum(axis=2)  # (5, N)
    d_norm = (e_cur[:, 0] * d_e_cur[:, :, 0] + e_cur[:, 1] * d_e_cur[:, :, 1]
              + et_prev[:, 0] * d_et_prev[:, :, 0] + et_prev[:, 1] * d_et_prev[:, :, 1]) / norm
    return np.asarray(((d_algebraic - algebraic * d_norm / norm) / norm).T)


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to unit vector t."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = skew(t) @ helper  # t × helper (np.cross is ~10x slower on 3-vectors)
    b1 /= np.linalg.norm(b1)
    return np.column_stack((b1, skew(t) @ b1))


def robust_sampson_cost(
    rotation: np.ndarray, translation: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray, robust_scale: float
) -> float:
    """The Cauchy cost `refine_relative_pose` minimises: Σ log(1 + (e_i / robust_scale)²) over the signed Sampson
    errors e_i of E = [t]ₓR on (N, 2) normalised correspondences."""
    return _cauchy_cost(_sampson(essential_from_pose(rotation, translation), _homogeneous(x_cur), _homogeneous(x_prev)),
                        robust_scale)


def _cauchy_cost(errors: np.ndarray, robust_scale: float) -> float:
    """Σ log(1 + (e_i / robust_scale)²) of (N,) errors."""
    return float(np.sum(np.log1p(errors**2 / robust_scale**2)))


def relative_pose_covariance(
    rotation: np.ndarray, translation: np.ndarray, x_cur: np.ndarray, x_prev: np.ndarray, robust_scale: float
) -> np.ndarray | None:
    """(5, 5) covariance of the relative pose that minimises the robust Sampson cost (`refine_relative_pose`),
    in its parameters (ω, β): R·exp([ω]ₓ), t + B·β. The M-estimator's K·mean(ψ²)/mean(ψ')²·(JᵀJ)⁻¹ at the
    minimum, ψ the Cauchy loss's derivative, K = N/(N−5) for the fitted parameters (Huber 1981, eq. 7.6.9; with
    ψ(r) = r it is Hartley & Zisserman's σ²·(JᵀJ)⁻¹, eq. 5.12). Where the views cannot tell a rotation from a
    step sideways (low parallax, a narrow view) the rotation block is large along that direction. None with fewer
    than 6 correspondences, or when most are outliers."""
    if len(x_cur) < 6:
        return None
    translation = np.asarray(translation, np.float64).reshape(3)
    translation = translation / np.linalg.norm(translation)
    h_cur, h_prev = _homogeneous(x_cur), _homogeneous(x_prev)
    residuals = _sampson(essential_from_pose(rotation, translation), h_cur, h_prev)
    jacobian = sampson_jacobian(rotation, translation, _tangent_basis(translation), h_cur, h_prev)
    weights = 1.0 / (1.0 + residuals**2 / robust_scale**2)
    psi = weights * residuals  # the Cauchy loss's ψ(r) = r / (1 + r²/c²) and its slope ψ'(r)
    slope = weights**2 * (1.0 - residuals**2 / robust_scale**2)
    mean_slope = float(np.mean(slope))
    if mean_slope <= 0.0:  # mostly outliers: no estimate
        return None
    try:
        inverse = np.linalg.inv(jacobian.T @ jacobian)
    except np.linalg.LinAlgError:
        return None
    dof = len(residuals) / max(len(residuals) - 5.0, 1.0)
    return np.asarray(dof * float(np.mean(psi**2)) / mean_slope**2 * inverse)


def refine_relative_pose(
    rotation: np.ndarray,
    translation: np.ndarray,
    x_cur: np.ndarray,
    x_prev: np.ndarray,
    robust_scale: float,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimise the robust (Cauchy) sum of squared Sampson errors over the 5-DoF relative pose with
    Levenberg–Marquardt: R ← R·exp(ω), t ← normalise(t + B·β) with B a basis of t's tangent plane.

    x_cur, x_prev: (N, 2) normalised inlier correspondences; robust_scale: Cauchy scale in normalised
    units (e.g. 1 px / f). Returns the refined (R, t) with |t| = 1; the input if nothing improves.
    """
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64).reshape(3)
    translation = translation / np.linalg.norm(translation)
    if len(x_cur) < 6:
        return rotation, translation
    c2 = robust_scale**2

    def params_to_pose(p: np.ndarray, r0: np.ndarray, t0: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = r0 @ so3_exp(p[:3])
        t = t0 + b @ p[3:]
        return r, t / np.linalg.norm(t)

    h_cur, h_prev = _homogeneous(x_cur), _homogeneous(x_prev)

    def residuals(r: np.ndarray, t: np.ndarray) -> np.ndarray:
        return _sampson(essential_from_pose(r, t), h_cur, h_prev)

    damping = 1e-3
    current = residuals(rotation, translation)
    current_cost = _cauchy_cost(current, robust_scale)
    for _ in range(iterations):
        basis = _tangent_basis(translation)
        jacobian = sampson_jacobian(rotation, translation, basis, h_cur, h_prev)
        weights = 1.0 / (1.0 + current**2 / c2)  # IRLS weights of the Cauchy loss
        jtw = jacobian.T * weights
        hessian = jtw @ jacobian
        gradient = jtw @ current
        improved = converged = False
        for _ in range(5):
            delta = -np.linalg.solve(hessian + damping * np.diag(np.diag(hessian) + 1e-12), gradient)
            r_new, t_new = params_to_pose(delta, rotation, translation, basis)
            candidate = residuals(r_new, t_new)
            candidate_cost = _cauchy_cost(candidate, robust_scale)
            if candidate_cost < current_cost:
                converged = current_cost - candidate_cost < 1e-6 * current_cost
                rotation, translation, current, current_cost = r_new, t_new, candidate, candidate_cost
                damping = max(damping / 10, 1e-9)
                improved = True
                break
            damping *= 10
        if not improved or converged:
            break
    return rotation, translation
