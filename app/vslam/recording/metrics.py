"""Per-frame series: what `/metrics/<group>/<series>` holds, with legends and colours (one plot per group).

`METRICS` and `STAGES` are every run's (the odometry front end, both backends); `MAP_METRICS` and `MAP_STAGES`
are logged only by the map backend (`vslam inspect` and `vslam compare` read the former).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from vslam.recording.columns import ColumnBuffer
from vslam.recording.styles import ESTIMATE_COLOUR, NEW_CORNER_COLOUR, ROAD_COLOUR
from vslam_core.geometry import invert_pose
from vslam_core.results import BundleAdjusted, FrameResult, HealthStatus, MapFrame, TrackFate, TrackingMode
from vslam_core.sources.base import Frame
from vslam_core.trajectory.gt_check import GroundTruthCheck, PairCheck

HEALTH_LEVELS = {HealthStatus.OK: 0, HealthStatus.WARN: 1, HealthStatus.FAIL: 2}
STAGES = ("decode", "track", "essential", "chirality", "detect", "record")

# Per-frame series, logged to /metrics/<group>/<series> only on frames that have a value (no NaN: it
# would make identical runs compare unequal). One plot per group. `vslam inspect` reads them back.
METRICS: dict[str, dict[str, tuple[str, tuple[int, int, int]]]] = {
    "tracks": {
        "alive": ("tracks alive", (40, 120, 255)),
        "new_corners": ("corners detected", NEW_CORNER_COLOUR),
        "fb_rejected": ("forward–backward rejects", (255, 140, 0)),
        "road_points": ("road points in the plane fit (--scale height)", ROAD_COLOUR),
    },
    "ransac": {
        "inliers": ("RANSAC inliers", (40, 220, 60)),
        "chirality_margin": ("chirality margin (best − 2nd)", (200, 0, 200)),
    },
    "ratio": {"inlier_ratio": ("inlier ratio", (40, 220, 60))},
    "health": {"status": ("health: 0 ok, 1 warn, 2 fail", (255, 140, 0))},
    "motion": {"rotation_deg": ("rotation (°)", (255, 200, 0)), "scale": ("step length", (0, 200, 255))},
    "road": {  # --scale height
        "measured_step": ("step from this frame's road plane (m)", (255, 140, 0)),
        "camera_height_m": ("camera height over the plane at the step used (m)", ROAD_COLOUR),
    },
    "error": {"position_m": ("position error (m)", ESTIMATE_COLOUR)},
    "angle_error": {
        "heading_deg": ("heading error (°)", (255, 80, 200)),
        "translation_direction_deg": ("translation direction error (°)", (0, 200, 255)),
    },
    "gt_check": {  # with ground truth: its relative motion on this frame's inliers (vslam_core/trajectory/gt_check)
        "gt_sampson_px": ("Sampson error of the ground truth's motion (px, median)", (255, 80, 200)),
        "fit_sampson_px": ("Sampson error of the best fit (px, median)", (40, 220, 60)),
        "sampson_ratio": ("ground truth / best fit", (255, 140, 0)),
        "gt_rotation_deg": ("ground truth's relative rotation vs the images' (°)", (0, 200, 255)),
    },
    "drift": {  # with ground truth: this frame's own relative pose error (vslam/recording/drift.py)
        "rotation_deg": ("rotation error of this frame's step (°)", (255, 80, 200)),
        "translation_m": ("translation error of this frame's step (m)", ESTIMATE_COLOUR),
        "translation_pct": ("translation error (% of the step)", (255, 140, 0)),
        "scale_ratio": ("step length estimate / truth", (0, 200, 255)),
    },
    "timing_ms": {
        "decode": ("decode (ms)", (150, 150, 150)),
        "track": ("track (ms)", (40, 120, 255)),
        "essential": ("essential (ms)", (230, 30, 30)),
        "chirality": ("chirality (ms)", (200, 0, 200)),
        "detect": ("detect (ms)", (255, 230, 0)),
        "record": ("record (ms)", (0, 200, 200)),
    },
}


def frame_metrics(result: FrameResult, ground_truth: np.ndarray | None,
                  left_out: frozenset[str] = frozenset()) -> dict[str, float]:
    """The per-frame series of one result (names as in `METRICS`); absent where a frame has no value, and those
    `left_out` (not computed: a frame's Python is what a recording costs the engine, docs/recordings.md)."""
    return {name: float(values[0]) for name, (_, values) in series_metrics([result], ground_truth, left_out).items()}


def series_metrics(results: Sequence[FrameResult], ground_truth: np.ndarray | None,
                   left_out: frozenset[str] = frozenset()) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The per-frame series of several results (names as in `METRICS`, but those `left_out`): per name, the (K,)
    positions in `results` of the frames that have a value and their (K,) values. Computed for the frames of a
    flush together: a frame at a time they were ~0.05 ms of the recording thread's Python a frame, which holds
    the engine back (docs/recordings.md)."""
    count = len(results)
    every = np.arange(count)
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def put(name: str, values: Any, where: np.ndarray | None = None) -> None:
        if name not in left_out and (where is None or where.any()):
            series[name] = (every if where is None else every[where], np.asarray(values, np.float64))

    fates = len(TrackFate)
    frame_of = np.repeat(every, [len(r.track_fate) for r in results])
    fate = np.concatenate([r.track_fate for r in results]).astype(np.int64) if count else np.zeros(0, np.int64)
    counts = np.bincount(frame_of * fates + fate, minlength=count * fates).reshape(count, fates)
    inliers = counts[:, TrackFate.INLIER]
    used = counts[:, TrackFate.RANSAC_OUTLIER] + counts[:, TrackFate.CHIRALITY_FAILED] + inliers
    put("status", [HEALTH_LEVELS[r.health.status] for r in results])
    put("alive", [r.live_tracks for r in results])
    put("new_corners", [len(r.new_corners) for r in results])
    put("fb_rejected", counts[:, TrackFate.FB_REJECTED])
    put("inliers", inliers)
    put("inlier_ratio", inliers[used > 0] / used[used > 0], used > 0)
    four = np.array([len(r.candidate_poses) == 4 for r in results], bool)
    in_front = np.sort([[c.in_front for c in r.candidate_poses] for r in results if len(r.candidate_poses) == 4])
    put("chirality_margin", (in_front[:, 3] - in_front[:, 2]) if len(in_front) else [], four)
    stepped = np.array([r.T_key_cur is not None for r in results], bool)
    T_key_cur = np.array([r.T_key_cur for r in results if r.T_key_cur is not None]).reshape(-1, 4, 4)  # noqa: N806
    put("rotation_deg", np.degrees(_angles(T_key_cur[:, :3, :3])), stepped)
    put("scale", [r.scale or 0.0 for r in results if r.T_key_cur is not None], stepped)
    road = [r.scale_estimate for r in results]
    put("road_points", [len(e.road_points) for e in road if e is not None], np.array([e is not None for e in road]))
    heights = [(e.measured_step, e.camera_height) if e is not None and e.measured_step is not None
               and e.camera_height is not None else None for e in road]
    measured = np.array([h is not None for h in heights], bool)
    put("measured_step", [h[0] for h in heights if h is not None], measured)
    put("camera_height_m", [h[1] for h in heights if h is not None], measured)
    if ground_truth is not None and count:
        gt = ground_truth[[r.position for r in results]]
        poses = np.array([r.T_world_cam for r in results])
        if "position_m" not in left_out:
            put("position_m", np.linalg.norm(gt[:, :3, 3] - poses[:, :3, 3], axis=1))
        if "heading_deg" not in left_out:
            put("heading_deg", np.degrees(_angles(gt[:, :3, :3].transpose(0, 2, 1) @ poses[:, :3, :3])))
        if stepped.any():
            keyframes = ground_truth[[r.keyframe_position for r in results if r.T_key_cur is not None]]
            gt_steps = (invert_pose(keyframes) @ gt[stepped])[:, :3, 3]
            put("translation_direction_deg", np.degrees(_directions(gt_steps, T_key_cur[:, :3, 3])), stepped)
    return series


def _angles(rotations: np.ndarray) -> np.ndarray:
    """`rotation_angle` of (N, 3, 3) rotations: (N,) radians."""
    return np.arccos(np.clip((np.trace(rotations, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))


def _directions(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`angle_between` of (N, 3) vectors a and b row by row: (N,) radians, 0 where either is zero."""
    lengths = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    cosines = np.einsum("ij,ij->i", a, b) / np.where(lengths > 0, lengths, 1.0)
    return np.where(lengths > 0, np.arccos(np.clip(cosines, -1.0, 1.0)), 0.0)


def log_series(columns: ColumnBuffer, frames: list[Frame], results: list[FrameResult], left_out: list[frozenset[str]],
               ground_truth: np.ndarray | None, gt_check: GroundTruthCheck | None) -> None:
    """The `METRICS` series of these frames (but timings and drift: their own), each leaving out the series
    `left_out` names (`series_metrics`), with the ground-truth check's of the frames it scored."""
    start = 0
    while start < len(frames):  # frames that leave the same series out (all of them, but from `vslam.log`)
        end = start + 1
        while end < len(frames) and left_out[end] == left_out[start]:
            end += 1
        series = series_metrics(results[start:end], ground_truth, left_out[start])
        if gt_check is not None:
            checked = [(i, pair) for i, r in enumerate(results[start:end]) if (pair := gt_check.pairs.get(r.position))]
            for name in METRICS["gt_check"] if checked else ():
                series[name] = (np.array([i for i, _ in checked]),
                                np.array([gt_check_metrics(pair)[name] for _, pair in checked], np.float64))
        for group, names in METRICS.items():
            for name in names:
                if name in series and group not in ("timing_ms", "drift"):  # drift: its own names
                    where, values = series[name]
                    columns.add_scalars(f"/metrics/{group}/{name}", [frames[start + i] for i in where.tolist()],
                                        values.tolist())
        start = end


def gt_check_metrics(pair: PairCheck) -> dict[str, float]:
    """The `/metrics/gt_check/*` series of one frame's ground-truth check."""
    return {"gt_sampson_px": pair.gt_sampson_px, "fit_sampson_px": pair.fit_sampson_px, "sampson_ratio": pair.ratio,
            "gt_rotation_deg": pair.rotation_deg}


# A source's own sensors, per frame (recorded when the source has them): the accelerometer as gravity in the
# camera frame (x right, y down, z forward; m/s², the mean over the frame's interval; TUM RGB-D's accelerometer.txt).
SENSOR_METRICS: dict[str, dict[str, tuple[str, tuple[int, int, int]]]] = {
    "accelerometer": {
        "x": ("gravity x, right (m/s²)", (230, 30, 30)),
        "y": ("gravity y, down (m/s²)", (40, 220, 60)),
        "z": ("gravity z, forward (m/s²)", (40, 120, 255)),
    },
}


# Map backend (--backend map): tracking mode and bundle adjustment. The mode as a number, so it plots as a
# step line (the string is in the `/tracking` entity): 0 lost, 1 two-view (the first frame of a map segment,
# `init`, counts as two-view: nothing but two-view geometry can follow it), 2 map (PnP), 3 relocalised;
# 0.5 coasted (a degraded frame whose pose was dead-reckoned).
MODE_LEVELS = {TrackingMode.LOST: 0, TrackingMode.COASTED: 0.5, TrackingMode.INIT: 1, TrackingMode.TWO_VIEW: 1,
               TrackingMode.MAP: 2, TrackingMode.RELOCALISED: 3}
MAP_METRICS: dict[str, dict[str, tuple[str, tuple[int, int, int]]]] = {
    "tracking": {
        "mode": ("tracking mode: 0 lost, 0.5 coasted, 1 two-view, 2 map, 3 relocalised", (255, 200, 0)),
        "pnp_inliers": ("PnP inliers", (40, 220, 60)),
        "landmarks_tracked": ("landmarks tracked", (80, 160, 255)),
    },
    "map_scale": {  # the map's scale as it goes: with --scale none an arbitrary unit that should only drift slowly
        "step": ("step length in map units (metres with gt or height)", (0, 200, 255)),
        "step_over_truth": ("step length estimate / truth (ground truth given)", (255, 140, 0)),
    },
    "ba": {
        "mean_error_before_px": ("mean error before (px)", (255, 140, 0)),
        "mean_error_after_px": ("mean error after (px)", (40, 220, 60)),
        "max_error_before_px": ("max error before (px)", (230, 30, 30)),
        "max_error_after_px": ("max error after (px)", (0, 200, 200)),
        "iterations": ("iterations", (255, 230, 0)),
        "cost_before": ("cost before", (255, 80, 200)),
        "cost_after": ("cost after", (200, 0, 200)),
        "milliseconds": ("solver time (ms)", (150, 150, 150)),
        "factors": ("projection factors", (40, 120, 255)),
        "culled": ("landmarks culled", (255, 60, 60)),
        "landmark_keyframes_mean": ("keyframes per landmark (mean)", (255, 255, 255)),
        "rotation_prior_max_deg": ("largest disagreement with the front end's rotation between keyframes (°)",
                                   (255, 0, 120)),
    },
    "local_map": {
        "projected": ("local-map landmarks projected into the image", (80, 160, 255)),
        "refound": ("landmarks re-found by projection", (40, 220, 60)),
        "linked": ("re-found landmarks linked to a track (agreeing with the pose)", (255, 220, 40)),
    },
}
# extra /metrics/timing_ms stages of the map backend (shown in the timing plot beside `STAGES`)
MAP_TIMING: dict[str, tuple[str, tuple[int, int, int]]] = {
    "pnp": ("PnP (ms)", (120, 255, 120)),
    "relocalise": ("relocalisation (ms)", (255, 80, 80)),
    "mapping": ("keyframe insertion and mapping (ms)", (255, 160, 60)),
    "local_map": ("local-map search by projection (ms)", (80, 160, 255)),
}
MAP_STAGES = tuple(MAP_TIMING)
BA_ERROR_SERIES = ("mean_error_before_px", "mean_error_after_px", "max_error_before_px", "max_error_after_px")


def map_frame_metrics(mapping: MapFrame) -> dict[str, float]:
    """The map backend's series of one frame (names as in `MAP_METRICS`); absent where a frame has no value."""
    values: dict[str, float] = {"mode": MODE_LEVELS[mapping.mode]}
    if mapping.pnp is not None:
        values["pnp_inliers"] = int(np.count_nonzero(mapping.pnp.inlier_mask))
        values["landmarks_tracked"] = len(mapping.pnp.landmark_ids)
    if mapping.bundle_adjustment is not None:
        values.update(bundle_adjustment_metrics(mapping.bundle_adjustment))
    if mapping.local_map is not None:
        values["projected"] = len(mapping.local_map.landmark_ids)
        values["refound"] = int(mapping.local_map.found_mask.sum())
        values["linked"] = int(mapping.local_map.accepted.sum())
    return values


def bundle_adjustment_metrics(ba: BundleAdjusted) -> dict[str, float]:
    """The `/metrics/ba/` series of one bundle adjustment (non-finite values left out)."""
    values = {
        "iterations": ba.iterations, "cost_before": ba.cost_before, "cost_after": ba.cost_after,
        "mean_error_before_px": ba.mean_error_before, "mean_error_after_px": ba.mean_error_after,
        "max_error_before_px": ba.max_error_before, "max_error_after_px": ba.max_error_after,
        "milliseconds": ba.milliseconds, "factors": ba.factors, "culled": ba.culled,
        "landmark_keyframes_mean": float(ba.landmark_keyframes.mean()) if len(ba.landmark_keyframes) else np.nan,
        "rotation_prior_max_deg": float(ba.rotation_errors_deg.max()) if len(ba.rotation_errors_deg) else np.nan,
    }
    return {name: float(value) for name, value in values.items() if np.isfinite(value)}
