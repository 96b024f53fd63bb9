"""Ground truth checked against the images, scale-free, from a run's own tracks.

For each tracked frame, its RANSAC inliers (raw pixels in the keyframe and in this frame, made ideal through the
lens) are scored under two relative motions keyframe → frame: the ground truth's (G_keyᵀ·G_cur) and the one the
engine fitted to them. The figures per frame: the median Sampson error (pixels) of each, and the angle between the
two relative rotations. Over the run, the ratio of the ground truth's median Sampson error to the fit's (a fit
refined on the inliers it chose always wins: 1.0 with exact ground truth, 3–6 on KITTI and TUM) and the median
rotation angle (° per frame pair), per window of 50 frames too.

A ground truth that disagrees with the images (quaternions in ``w x y z`` order, the body's poses instead of the
camera's, another sequence, other rows) gives ratios of 19–53; a time offset between the ground truth's clock and
the frames' (or rows shifted, paired row by row) is found by shifting the ground truth in time (rotations
interpolated) and keeping the shift whose relative rotations agree best with the images'. Thresholds and the
figures behind them: docs/own-data.md ("Ground truth against the images").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vslam_core.geometry import essential_from_pose, sampson_errors
from vslam_core.lens import undistort_pixels
from vslam_core.results import FrameResult, FrameStatus, Reason, TrackFate
from vslam_core.sources.base import CameraIntrinsics, Frame

#: a frame's pair is scored on at least this many inliers found in its keyframe
MIN_INLIERS = 20
#: the run's Sampson ratio (ground truth / fit) above which the ground truth disagrees with the images. The fit is
#: refined on the very inliers it selected, so agreeing ground truth sits well above 1: measured 3.1× on KITTI 05
#: 0:300, 4.0× on KITTI 00 0:150 (its known disagreement), 5.7–6.3× on TUM fr1 xyz/desk (rolling shutter, mocap
#: rows matched to the nearest), windows of 50 frames up to 8.1×; a wrong ground truth 19–53× (w x y z
#: quaternions, the body's poses, another sequence, rows 5 or 100 frames off, a TUM clock 0.1 s off; KITTI's clock
#: one frame off is 11.4×, caught by the time shift): docs/own-data.md
FAR_OFF_RATIO = 12.0
#: ... or the median angle (°) between the ground truth's and the images' relative rotations above this (0.02–0.38°
#: agreeing, 0.26–1.13° wrong: the ratio is the sharper test, this one catches a ground truth that rotates too much)
FAR_OFF_ROTATION_DEG = 1.0
#: a time shift is reported when its rotations fit at most this fraction as badly as without it (agreeing TUM
#: ground truth: 0.77–0.79 at a shift under half a frame; 0.1 s and 0.3 s offsets: 0.28–0.46) ...
SHIFT_BETTER = 0.6
#: ... and it is at least this many frame intervals (the shifts are tried in quarter frames; agreeing TUM ground truth
#: fits best 0.36–0.51 of a frame early, KITTI 05 with a clock one frame, 0.1 s, off: 0.95 of a frame late)
MIN_SHIFT_FRAMES = 0.5
#: frames scored before the run's figures are judged (warned about): KITTI 00's first 15 frames alone score 5–30×
#: (its ground truth's constant 0.86 m steps there; 10.8× over frames 1–10, 4.7× over 1–30)
MIN_PAIRS = 30
#: frames in a window (the per-window figures)
WINDOW = 50
#: the shifts tried span ± this many seconds (and at most a fifth of the run)
MAX_SHIFT_S = 1.0


@dataclass(frozen=True)
class PairCheck:
    """One frame's figures: keyframe `key` → frame `position` (run positions), over `inliers` correspondences."""

    position: int
    key: int
    inliers: int
    gt_sampson_px: float  # median Sampson error of the ground truth's relative motion
    fit_sampson_px: float  # ... of the engine's (best-fitting) motion
    rotation_deg: float  # angle between the two relative rotations

    @property
    def ratio(self) -> float:
        """Ground truth's median Sampson error over the fit's (a floor of 0.01 px keeps a perfect fit finite)."""
        return self.gt_sampson_px / max(self.fit_sampson_px, 0.01)


@dataclass(frozen=True)
class TimeShift:
    """The constant offset (s, or frames without a clock) added to the frames' times to look up the ground
    truth that fits the images' rotations best, with the median rotation angle (°) at it and at no shift."""

    offset: float
    in_seconds: bool
    rotation_deg: float
    unshifted_rotation_deg: float
    interval: float  # the frames' median interval (s, or 1 frame)
    by_time: bool = True  # the ground truth was matched to the frames by time (else row by row)

    @property
    def frames(self) -> int:
        """The shift in whole frames (rows of a ground truth paired row by row)."""
        return round(self.offset / self.interval)

    @property
    def better(self) -> bool:
        """Much better than no shift (`SHIFT_BETTER`), by a shift of half a frame or more (`MIN_SHIFT_FRAMES`), and
        by more than noise (0.01° a pair)."""
        return (self.rotation_deg <= SHIFT_BETTER * self.unshifted_rotation_deg
                and abs(self.offset) >= MIN_SHIFT_FRAMES * self.interval - 1e-9
                and self.unshifted_rotation_deg - self.rotation_deg > 0.01)

    def describe(self) -> str:
        return f"{self.offset:+.3f} s" if self.in_seconds else f"{self.offset:+.0f} frames"


@dataclass(frozen=True)
class WindowFigure:
    """The figures of the pairs whose frame lies in run positions start..end (inclusive)."""

    start: int
    end: int
    pairs: int
    ratio: float
    rotation_deg: float


@dataclass(frozen=True)
class CheckSummary:
    """The run's figures: median per-frame Sampson errors (px), their ratio, the median rotation angle (°), the
    worst window, and the best time shift (None when too few pairs)."""

    pairs: int
    gt_sampson_px: float
    fit_sampson_px: float
    ratio: float
    rotation_deg: float
    windows: tuple[WindowFigure, ...]
    shift: TimeShift | None = None

    @property
    def judged(self) -> bool:
        """Enough frames were scored to warn (`MIN_PAIRS`)."""
        return self.pairs >= MIN_PAIRS

    @property
    def far_off(self) -> bool:
        return self.judged and (self.ratio > FAR_OFF_RATIO or self.rotation_deg > FAR_OFF_ROTATION_DEG)

    @property
    def worst_window(self) -> WindowFigure | None:
        return max(self.windows, key=lambda w: w.ratio) if self.windows else None

    def line(self) -> str:
        """``Sampson 0.21 px vs best fit 0.17 px (1.2×), rotation 0.03° a frame, 298 frames; worst window …``"""
        text = (f"Sampson {self.gt_sampson_px:.2f} px vs best fit {self.fit_sampson_px:.2f} px ({self.ratio:.1f}×), "
                f"rotation {self.rotation_deg:.2f}° a frame, {self.pairs} frames")
        worst = self.worst_window
        if worst is not None and len(self.windows) > 1:
            text += f"; worst window {worst.start}–{worst.end} {worst.ratio:.1f}×, {worst.rotation_deg:.2f}°"
        if not self.judged:
            text += f" (too few to judge: {MIN_PAIRS} needed)"
        return text

    def warnings(self) -> list[str]:
        """One line each: the ground truth disagrees with the images; a time shift fits much better."""
        if self.judged and self.shift is not None and self.shift.better:
            shift = self.shift
            figures = (f"(its rotations {shift.rotation_deg:.2f}° a frame off instead of "
                       f"{shift.unshifted_rotation_deg:.2f}°; Sampson {self.ratio:.1f}× the best fit unshifted)")
            if shift.by_time and shift.in_seconds:
                return [f"the ground truth fits the images best shifted by {shift.describe()} {figures}: its clock is "
                        f"offset from the frames'; to apply the offset: --gt-time-offset {shift.offset:+.3f}"]
            return [f"the ground truth fits the images best with its rows shifted: frame i with row i{shift.frames:+d} "
                    f"{figures}: its rows are not these frames "
                    f"(row by row pairs row i with frame i); say which rows are with --gt-rows A:B (a folder's or "
                    "video's --gt), or give it with times"]
        lines = []
        if self.far_off:
            lines.append(
                f"the ground truth disagrees with the images: its relative motions fit the tracked points "
                f"{self.ratio:.1f}× worse than the best fit and its rotations are {self.rotation_deg:.2f}° off a "
                f"frame (agreeing ground truth: under {FAR_OFF_RATIO:g}× and {FAR_OFF_ROTATION_DEG:g}°): quaternion "
                "order (x y z w)? the body's poses instead of the camera's? another sequence? — accuracy figures "
                "against it are not to be trusted")
        return lines


@dataclass
class _Pair:
    key: int
    position: int
    rotation: np.ndarray  # (3, 3) the engine's relative rotation keyframe -> frame


@dataclass
class GroundTruthCheck:
    """A frame sink (`vslam_core.pipeline.FrameSink`) scoring the ground truth against each frame's inliers.

    ground_truth: (N, 4, 4) T_w_c of the run's frames (run position i); intrinsics: the camera (raw pixels are
    made ideal through its lens); by_time: how it was paired with the frames (by time, else row by row: a shift is
    then in rows). `pairs` holds each scored frame's `PairCheck` by run position."""

    ground_truth: np.ndarray
    intrinsics: CameraIntrinsics
    by_time: bool = True  # the ground truth was matched to the frames by time (a shift is then a clock offset)
    pairs: dict[int, PairCheck] = field(default_factory=dict)
    _rotations: list[_Pair] = field(default_factory=list)
    _times: list[float | None] = field(default_factory=list)
    _seen: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # position -> (ids, raw pixels)
    _summary: tuple[int, CheckSummary | None] | None = None  # (frames seen, the summary then): asked for twice

    def __call__(self, _frame: Frame, result: FrameResult) -> None:
        self._times.append(result.timestamp)
        pair = self._score(result)
        if pair is not None:
            self.pairs[result.position] = pair
        self._remember(result)

    def _remember(self, result: FrameResult) -> None:
        """Keep where this frame's tracks are (a later frame's keyframe may be this one); forget frames older
        than its keyframe."""
        alive = result.track_fate >= TrackFate.NOT_USED
        ids = np.concatenate([result.track_ids[alive], result.new_corner_ids])
        pixels = np.concatenate([np.asarray(result.track_cur, np.float64).reshape(-1, 2)[alive],
                                 np.asarray(result.new_corners, np.float64).reshape(-1, 2)])
        order = np.argsort(ids, kind="stable")
        self._seen[result.position] = (ids[order], pixels[order])
        for old in [p for p in self._seen if p < min(result.keyframe_position, result.position)]:
            del self._seen[old]

    def _score(self, result: FrameResult) -> PairCheck | None:
        if (result.status != FrameStatus.OK or result.T_key_cur is None or Reason.RECOVERED in result.health.reasons
                or result.position >= len(self.ground_truth)):
            return None
        key = result.keyframe_position
        seen = self._seen.get(key)
        if seen is None or key >= len(self.ground_truth):
            return None
        inlier = result.track_fate == TrackFate.INLIER
        ids, cur = result.track_ids[inlier], np.asarray(result.track_cur, np.float64).reshape(-1, 2)[inlier]
        where = np.clip(np.searchsorted(seen[0], ids), 0, max(len(seen[0]) - 1, 0))
        found = (seen[0][where] == ids) if len(seen[0]) else np.zeros(len(ids), bool)
        if found.sum() < MIN_INLIERS:
            return None
        x_key, x_cur = self._normalised(seen[1][where[found]]), self._normalised(cur[found])
        gt = np.linalg.inv(self.ground_truth[key]) @ self.ground_truth[result.position]
        focal = 0.5 * (self.intrinsics.fx + self.intrinsics.fy)
        rotation = result.T_key_cur[:3, :3]
        self._rotations.append(_Pair(key, result.position, rotation))
        return PairCheck(result.position, key, int(found.sum()),
                         _median_sampson(gt[:3, :3], gt[:3, 3], x_cur, x_key, focal),
                         _median_sampson(rotation, result.T_key_cur[:3, 3], x_cur, x_key, focal),
                         float(np.degrees(_angle(gt[:3, :3].T @ rotation))))

    def _normalised(self, raw: np.ndarray) -> np.ndarray:
        """(M, 2) raw pixels → ideal normalised image coordinates."""
        k = self.intrinsics
        ideal = undistort_pixels(raw, k)
        return np.column_stack(((ideal[:, 0] - k.cx) / k.fx, (ideal[:, 1] - k.cy) / k.fy))

    def summary(self) -> CheckSummary | None:
        """The run's figures (None when fewer than 5 frames could be scored)."""
        if self._summary is None or self._summary[0] != len(self._times):  # the time shifts cost ~0.5 s
            summary = summary_of(list(self.pairs.values()), self._time_shift()) if len(self.pairs) >= 5 else None
            self._summary = (len(self._times), summary)
        return self._summary[1]

    def _time_shift(self) -> TimeShift | None:
        """The shift of the ground truth in time (rotations interpolated between frames) whose relative rotations
        agree best with the engine's, over the pairs every shift tried can score."""
        count = min(len(self._times), len(self.ground_truth))
        if len(self._rotations) < 10 or count < 10:
            return None
        stamps = self._times[:count]
        in_seconds = all(t is not None for t in stamps) and bool(np.all(np.diff(np.asarray(stamps, float)) > 0))
        times = np.asarray(stamps, float) if in_seconds else np.arange(count, dtype=float)
        interval = float(np.median(np.diff(times)))
        reach = min(MAX_SHIFT_S if in_seconds else MAX_SHIFT_S * 10 * interval, 0.2 * (times[-1] - times[0]))
        steps = max(int(reach / (0.25 * interval)), 1) if in_seconds else max(int(reach / interval), 1)
        shifts = np.linspace(-reach, reach, 2 * steps + 1)
        pairs = [p for p in self._rotations
                 if times[p.key] - reach >= times[0] and times[p.position] + reach <= times[-1]]
        if len(pairs) < 10:
            return None
        rotations = self.ground_truth[:count, :3, :3]
        estimated = np.array([p.rotation for p in pairs])
        keys, positions = np.array([p.key for p in pairs]), np.array([p.position for p in pairs])
        costs = []
        for shift in shifts:
            r_key = _rotation_at(rotations, times, times[keys] + shift)
            r_cur = _rotation_at(rotations, times, times[positions] + shift)
            relative = np.einsum("nji,njk->nik", r_key, r_cur)
            costs.append(float(np.median(_angles(np.einsum("nji,njk->nik", relative, estimated)))))
        best = int(np.argmin(costs))
        centre = len(shifts) // 2
        offset = float(shifts[best])
        if in_seconds and 0 < best < len(shifts) - 1:  # the parabola's vertex through the best and its neighbours
            left, mid, right = costs[best - 1], costs[best], costs[best + 1]
            curvature = left - 2.0 * mid + right
            if curvature > 0:
                offset += 0.5 * (left - right) / curvature * (shifts[1] - shifts[0])
        return TimeShift(offset, in_seconds, costs[best], costs[centre], interval, self.by_time)


def summary_of(pairs: list[PairCheck], shift: TimeShift | None = None) -> CheckSummary | None:
    """The run's figures of its frames' checks (positions: run positions, or the frames' indices when read back
    from a recording), in windows of `WINDOW` frames; None with fewer than 5."""
    pairs = sorted(pairs, key=lambda p: p.position)
    if len(pairs) < 5:
        return None
    windows = []
    first = pairs[0].position - pairs[0].position % WINDOW
    for start in range(first, pairs[-1].position + 1, WINDOW):
        inside = [p for p in pairs if start <= p.position < start + WINDOW]
        if len(inside) >= 5:
            windows.append(WindowFigure(start, min(start + WINDOW - 1, pairs[-1].position), len(inside),
                                        *_figures(inside)[2:]))
    return CheckSummary(len(pairs), *_figures(pairs), tuple(windows), shift)


def _figures(pairs: list[PairCheck]) -> tuple[float, float, float, float]:
    """Median over the pairs of the ground truth's and the fit's Sampson errors (px), their ratio, and the median
    rotation angle (°)."""
    gt_px = float(np.median([p.gt_sampson_px for p in pairs]))
    fit_px = float(np.median([p.fit_sampson_px for p in pairs]))
    return gt_px, fit_px, gt_px / max(fit_px, 0.01), float(np.median([p.rotation_deg for p in pairs]))


def _median_sampson(rotation: np.ndarray, translation: np.ndarray, x_cur: np.ndarray, x_key: np.ndarray,
                    focal: float) -> float:
    """Median |Sampson error| (px) of the motion X_key = R·X_cur + t on normalised points (t of any length; none:
    a pure rotation, whose epipolar constraint is empty, scores through its homography instead)."""
    norm = float(np.linalg.norm(translation))
    if norm < 1e-9:
        mapped = x_cur @ rotation.T[:, :2].T + rotation[:, 2]
        mapped = mapped[:, :2] / mapped[:, 2:3]
        return float(np.median(np.linalg.norm(mapped - x_key, axis=1)) * focal)
    essential = essential_from_pose(rotation, translation / norm)
    return float(np.median(np.abs(sampson_errors(essential, x_cur, x_key))) * focal)


def _angle(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def _angles(rotations: np.ndarray) -> np.ndarray:
    """(N,) degrees of (N, 3, 3) rotations."""
    traces = np.trace(rotations, axis1=1, axis2=2)
    return np.degrees(np.arccos(np.clip((traces - 1.0) / 2.0, -1.0, 1.0)))


def _rotation_at(rotations: np.ndarray, times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(M, 3, 3) rotations at times `at` (within `times`' span), interpolated along the geodesic between the
    (N, 3, 3) `rotations` at the (N,) increasing `times`."""
    upper = np.clip(np.searchsorted(times, at, side="right"), 1, len(times) - 1)
    lower = upper - 1
    fraction = np.clip((at - times[lower]) / np.maximum(times[upper] - times[lower], 1e-12), 0.0, 1.0)
    step = np.einsum("nji,njk->nik", rotations[lower], rotations[upper])
    return np.einsum("nij,njk->nik", rotations[lower], _exp(fraction[:, None] * _log(step)))


def _log(rotations: np.ndarray) -> np.ndarray:
    """(N, 3) axis-angle vectors of (N, 3, 3) rotations (angles below π)."""
    angle = np.radians(_angles(rotations))
    axis = np.stack([rotations[:, 2, 1] - rotations[:, 1, 2], rotations[:, 0, 2] - rotations[:, 2, 0],
                     rotations[:, 1, 0] - rotations[:, 0, 1]], axis=1)
    sin = np.sin(angle)
    scale = np.where(sin > 1e-9, angle / np.maximum(2.0 * sin, 1e-12), 0.5)
    return axis * scale[:, None]


def _exp(omega: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations of (N, 3) axis-angle vectors (Rodrigues)."""
    angle = np.linalg.norm(omega, axis=1)
    axis = omega / np.maximum(angle, 1e-12)[:, None]
    k = np.zeros((len(omega), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k[:, 1, 0], k[:, 2, 0], k[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
    sin, cos = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + sin * k + (1.0 - cos) * (k @ k)
