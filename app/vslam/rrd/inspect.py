"""`vslam inspect`: what a bug report needs from a recording, read without a viewer.

The JSON form (`inspect_recording`) is a stable interface; its keys are documented in docs/recordings.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from vslam.common import COLUMNS
from vslam.common import METRICS as REPORT_METRICS
from vslam.recording import HEALTH_STATUSES, METRICS, STAGES
from vslam.recording import WORST as DRIFT_TOP
from vslam.rrd.check import schema_contract
from vslam.rrd.health import read_health, unknown_statuses
from vslam.rrd.poses import camera_poses
from vslam.rrd.provenance import (
    PROPERTIES,
    comparison_prefixes,
    config_lines,
    latest_static_row,
    non_default,
    read_config,
    read_properties,
)
from vslam.rrd.read import RecordingError, no_frames, read_entity, readable
from vslam.rrd.series import entity_paths, format_own_series, own_series, own_stages
from vslam.rrd.suspects import find_suspects, format_suspects
from vslam_core.trajectory.drift import worst_frames
from vslam_core.trajectory.gt_check import PairCheck, summary_of

SCHEMA_VERSION = 1


def _scalars(path: Path, group: str, prefix: str = "") -> dict[str, np.ndarray]:
    """Values of each series of one metric group, over the frames that have one."""
    series = {}
    for name in METRICS[group]:
        table = read_entity(path, f"{prefix}/metrics/{group}/{name}")
        values = [v[0] for v in table["Scalars:scalars"].to_list()] if not table.is_empty() else []
        series[name] = np.asarray(values, dtype=np.float64)
    return series


def _series_by_frame(path: Path, entity: str) -> dict[int, float]:
    """One series as {frame: value} (frames without a value absent)."""
    table = read_entity(path, entity)
    if table.is_empty():
        return {}
    return {int(f): float(v[0]) for f, v in zip(table["frame"].to_list(), table["Scalars:scalars"].to_list(),
                                                strict=True) if v}


def _drift(path: Path, health: dict[int, list[str]], prefix: str = "") -> dict[str, list[dict[str, Any]]] | None:
    """The `DRIFT_TOP` frames contributing most to the drift (their own relative pose error against the ground
    truth, `/metrics/drift/*`), by rotation and by translation, largest first; None without ground truth."""
    rotation = _series_by_frame(path, f"{prefix}/metrics/drift/rotation_deg")
    translation = _series_by_frame(path, f"{prefix}/metrics/drift/translation_m")
    if not rotation and not translation:
        return None
    pct = _series_by_frame(path, f"{prefix}/metrics/drift/translation_pct")

    def top(series: dict[int, float]) -> list[tuple[int, float]]:
        frames = np.array(list(series), dtype=np.int64)
        return worst_frames(np.array(list(series.values()), dtype=np.float64), DRIFT_TOP, frames)

    return {
        "rotation": [{"frame": f, "deg": v, "reasons": health.get(f, [])} for f, v in top(rotation)],
        "translation": [{"frame": f, "m": v, "pct": pct.get(f, math.nan), "reasons": health.get(f, [])}
                        for f, v in top(translation)],
    }


def _stats(values: np.ndarray) -> dict[str, float] | None:
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {
        "mean": float(values.mean()),
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "min": float(values.min()),
        "max": float(values.max()),
    }


def flagged_ranges(frames: list[int], statuses: list[str], reasons: list[str]) -> list[dict[str, Any]]:
    """Consecutive non-ok frames with the same status and reasons, as inclusive source-frame ranges."""
    ranges: list[dict[str, Any]] = []
    for frame, status, reason in zip(frames, statuses, reasons, strict=True):
        if status == "ok":
            continue
        codes = [r for r in reason.split(",") if r]
        last = ranges[-1] if ranges else None
        if last is not None and last["status"] == status and last["reasons"] == codes and last["_next"] == frame:
            last["end"] = frame
        else:
            ranges.append({"start": frame, "end": frame, "status": status, "reasons": codes})
        ranges[-1]["_next"] = frame + 1
    return [{k: v for k, v in r.items() if k != "_next"} for r in ranges]


def _accuracy(path: Path, prefix: str = "") -> dict[str, float] | None:
    """Position and angle errors (`/metrics/error`, `/metrics/angle_error`: each series by its own frames, any
    of them may be absent) and the paper RMS of the estimate against the ground truth, paired by FRAME (never
    by row: see `ground_truth_by_frame`); None without position errors."""
    position = _series_by_frame(path, f"{prefix}/metrics/error/position_m")
    if not position:
        return None
    heading = _series_by_frame(path, f"{prefix}/metrics/angle_error/heading_deg")
    direction = _series_by_frame(path, f"{prefix}/metrics/angle_error/translation_direction_deg")
    errors = np.array(list(position.values()), np.float64)
    directions = np.array(list(direction.values()), np.float64)
    return {
        "final_position_error_m": position[max(position)],
        "mean_position_error_m": float(errors.mean()),
        "ate_m": float(np.sqrt(np.mean(errors**2))),  # the RMS: the ATE of the recorded estimate (run's summary)
        "max_position_error_m": float(errors.max()),
        "paper_rms_m": _paper_rms(path, prefix),
        "final_heading_error_deg": heading[max(heading)] if heading else math.nan,
        "mean_translation_direction_error_deg": float(directions.mean()) if len(directions) else math.nan,
    }


def _gt_check(path: Path, prefix: str = "") -> dict[str, Any] | None:
    """The ground truth against the images (`/metrics/gt_check/*`, windows of 50 frames by frame index) and the
    verdict's lines about it (its warnings: far off, a time offset); None without ground truth."""
    series = {name: _series_by_frame(path, f"{prefix}/metrics/gt_check/{name}")
              for name in ("gt_sampson_px", "fit_sampson_px", "gt_rotation_deg")}
    frames = sorted(set(series["gt_sampson_px"]) & set(series["fit_sampson_px"]) & set(series["gt_rotation_deg"]))
    summary = summary_of([PairCheck(f, f, 0, series["gt_sampson_px"][f], series["fit_sampson_px"][f],
                                    series["gt_rotation_deg"][f]) for f in frames])
    if summary is None:
        return None
    table = read_entity(path, f"{prefix}/report", static=True)
    text = "" if table.is_empty() or "TextDocument:text" not in table.columns else \
        table["TextDocument:text"].to_list()[-1]
    text = text[0] if isinstance(text, list) else text or ""
    return {"frames": summary.pairs, "gt_sampson_px": summary.gt_sampson_px, "fit_sampson_px": summary.fit_sampson_px,
            "ratio": summary.ratio, "rotation_deg": summary.rotation_deg, "far_off": summary.far_off,
            "line": summary.line(),
            "windows": [{"first": w.start, "last": w.end, "frames": w.pairs, "ratio": w.ratio,
                         "rotation_deg": w.rotation_deg} for w in summary.windows],
            "warnings": [line.removeprefix("Warning: ").rstrip(".") for line in text.splitlines()
                         if line.startswith("Warning: the ground truth")]}


def _paper_rms(path: Path, prefix: str = "") -> float:
    """RMS of the x–z distance between the estimate (its Sim(3)-aligned form with --scale none) and the ground
    truth over the frames that have both; NaN when none has."""
    estimate = camera_positions(path, prefix)
    aligned = read_entity(path, f"{prefix}/world/trajectory/estimate_sim3", static=True)  # --scale none
    refined = _refined_path(path, prefix, len(estimate))  # the map's refined poses: what the run is scored on
    if not aligned.is_empty():  # one point per camera frame, in frame order (aligned: of the refined poses)
        points = np.array(aligned["LineStrips3D:strips"][0][0], np.float64).reshape(-1, 3)
        if len(points) == len(estimate):
            estimate = dict(zip(sorted(estimate), points, strict=True))
    elif refined is not None:
        estimate = dict(zip(sorted(estimate), refined, strict=True))
    truth = ground_truth_by_frame(path, prefix)
    common = sorted(set(estimate) & set(truth))
    if not common:
        return math.nan
    xz = np.array([estimate[f] - truth[f] for f in common])[:, [0, 2]]
    return float(np.sqrt(np.mean(np.sum(xz**2, axis=1))))


def camera_positions(path: Path, prefix: str = "") -> dict[int, np.ndarray]:
    """{frame: (3,) camera position} of `/world/camera` (frames whose translation is missing left out)."""
    poses = camera_poses(path, prefix)
    return {int(f): pose[:3, 3] for f, pose in zip(poses.frames, poses.poses, strict=True)}


def ground_truth_by_frame(path: Path, prefix: str = "") -> dict[int, np.ndarray]:
    """{frame: (3,) ground-truth position} from `/world/trajectory/ground_truth` (docs/recording-schema.md): the
    segment logged at frame f runs from the previous camera frame's ground truth to frame f's, so its END is
    frame f's; a frame without a segment of its own (a first frame logged without vslam's zero-length one)
    takes the START of the next camera frame's segment. Paired by frame, never by row."""
    table = read_entity(path, f"{prefix}/world/trajectory/ground_truth")
    if table.is_empty() or "LineStrips3D:strips" not in table.columns or "frame" not in table.columns:
        return {}
    segments: dict[int, np.ndarray] = {}
    for frame, strips in zip(table["frame"].to_list(), table["LineStrips3D:strips"].to_list(), strict=True):
        if frame is None or not strips or strips[0] is None or len(strips[0]) < 1:
            continue
        segments[int(frame)] = np.asarray(strips[0], np.float64).reshape(-1, 3)
    truth = {frame: points[-1] for frame, points in segments.items()}
    frames = sorted(camera_positions(path, prefix))
    for before, after in zip(frames, frames[1:], strict=False):
        if before not in truth and after in segments and len(segments[after]) >= 2:
            truth[before] = segments[after][0]
    return truth


def report_metrics(path: Path, prefix: str = "") -> dict[str, float | None] | None:
    """The metric row of the recording's verdict (``/report``: the Markdown table `vslam run` logs when it
    ends, as `vslam eval` computes it) as {``t_err``, ``r_err``, ``ate_se3``, ``ate_sim3``, …: value or None
    for n/a}, at the table's printed precision; None when there is no such table (no ground truth, older or
    interrupted runs)."""
    table = read_entity(path, f"{prefix}/report", static=True)
    if table.is_empty() or "TextDocument:text" not in table.columns:
        return None
    text = table["TextDocument:text"].to_list()[-1]
    lines = [line for line in (text[0] if isinstance(text, list) else text or "").splitlines()
             if line.startswith("|")]
    keys = {header: key for key, (header, _) in COLUMNS.items() if key in REPORT_METRICS}
    # the first table whose header names a metric: header row, |---| row, then the run's row
    for i, line in enumerate(lines[:-2]):
        headers = [cell.strip() for cell in line.strip("|").split("|")]
        if any(h in keys for h in headers):
            cells = [cell.strip() for cell in lines[i + 2].strip("|").split("|")]
            return {keys[h]: _float(c) for h, c in zip(headers, cells, strict=False) if h in keys}
    return None


def _float(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:  # "n/a"
        return None
    return value if math.isfinite(value) else None


def scored_trajectory(path: Path, prefix: str = "") -> str:
    """Which poses the recording's accuracy is of: ``refined`` (the map's, after bundle adjustment and loop
    closing, as `--trajectory-out`, `vslam eval` and the run summary score them) or ``as tracked`` (the odometry
    backend, a map run localised in a saved map, another system's trajectory, or a recording written before the
    refined path was recorded)."""
    frames = len(read_entity(path, f"{prefix}/world/camera"))
    return "as tracked" if _refined_path(path, prefix, frames) is None else "refined"


def _refined_path(path: Path, prefix: str, frames: int) -> np.ndarray | None:
    """(N, 3) the map's refined positions (`/world/trajectory/estimate_refined`), or None: not recorded, or not
    one per frame of the file (a `vslam crop` keeps the whole run's static path; its frames' errors are then
    those recorded)."""
    table = read_entity(path, f"{prefix}/world/trajectory/estimate_refined", static=True)
    if table.is_empty():
        return None
    positions = np.array(table["LineStrips3D:strips"][0][0], np.float64).reshape(-1, 3)
    return positions if len(positions) == frames else None


def _accuracy_alignment(path: Path, prefix: str = "") -> str:
    """``sim3`` when the recording's position errors are of the Sim(3)-aligned estimate (--scale none)."""
    aligned = read_entity(path, f"{prefix}/world/trajectory/estimate_sim3", static=True)
    return "none" if aligned.is_empty() else "sim3"


def inspect_recording(path: Path) -> dict[str, Any]:
    """Everything `vslam inspect --json` prints (see docs/recordings.md: "vslam inspect --json"). A `vslam compare`
    output gives ``comparison`` (labels, input files) and ``runs`` (``a``, ``b``, …: each run's report)."""
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    if not path.is_file():
        raise RecordingError(f"{path}: not a file (a .rrd recording is a regular file)")
    with schema_contract(path):
        return _inspect(path)


def _inspect(path: Path) -> dict[str, Any]:
    comparison = read_properties(path, f"{PROPERTIES}/compare")
    if comparison and read_entity(path, "/world/camera").is_empty():
        return {
            "schema": SCHEMA_VERSION, "file": str(path), "bytes": path.stat().st_size,
            "recording_name": _recording_name(path), "comparison": comparison,
            "runs": {prefix: _run_report(path, f"/{prefix}") for prefix in comparison_prefixes(path)},
        }
    return {"schema": SCHEMA_VERSION, "file": str(path), "bytes": path.stat().st_size,
            "recording_name": _recording_name(path), **_run_report(path)}


def _recording_name(path: Path) -> str | None:
    name = latest_static_row(path, PROPERTIES).get("RecordingInfo:name")
    return name[0] if name else None


def _run_report(path: Path, prefix: str = "") -> dict[str, Any]:
    """One run's part of the report; `prefix` ``/a`` or ``/b`` for a run inside a comparison."""
    cut_short = readable(path).cut_short
    camera = read_entity(path, f"{prefix}/world/camera")
    if camera.is_empty() or "frame" not in camera.columns:
        raise RecordingError(no_frames(path, cut_short))
    frames = camera["frame"].to_list()
    health = read_health(path, prefix)
    if unknown := unknown_statuses((h.status for h in health.values()), HEALTH_STATUSES):
        raise RecordingError(f"{path}: {prefix}/health:status: {unknown[0]!r} is not a health level (ok, warn, "
                             f"fail): the recording does not conform to the schema (vslam check {path})")
    flagged = flagged_ranges(list(health), [h.status for h in health.values()],
                             [",".join(h.reasons) for h in health.values()])
    frame_reasons = {frame: h.reasons for frame, h in health.items()}
    timing = _scalars(path, "timing_ms", prefix)
    tracks, ransac = _scalars(path, "tracks", prefix), _scalars(path, "ransac", prefix)
    ratio = _scalars(path, "ratio", prefix)
    config = read_config(path, prefix)
    properties = read_properties(path, f"{PROPERTIES}{prefix}/run")
    entities = entity_paths(path)  # a pipeline's own series and stages are found by name (`vslam.log`)
    return {
        "properties": properties,
        "calibration": {key.removeprefix("calibration_"): value for key, value in properties.items()
                        if key.startswith("calibration_")} or None,
        "config": config,
        "config_non_default": {key: value for key, _, value in non_default(config)} if config else {},
        "frames": {"count": len(frames), "first": int(min(frames)), "last": int(max(frames))},
        "cut_short": cut_short,
        "stages_ms": {**{stage: _stats(timing[stage]) for stage in STAGES},
                      **own_stages(path, STAGES, prefix, entities)},
        "series": {
            "tracks_alive": _stats(tracks["alive"]),
            "corners_detected": _stats(tracks["new_corners"]),
            "fb_rejected": _stats(tracks["fb_rejected"]),
            "ransac_inliers": _stats(ransac["inliers"]),
            "inlier_ratio": _stats(ratio["inlier_ratio"]),
            "chirality_margin": _stats(ransac["chirality_margin"]),
        },
        "own_series": own_series(path, prefix, entities),
        "accuracy": _accuracy(path, prefix),
        "report_metrics": report_metrics(path, prefix),
        # `vslam crop` keeps the whole run's verdict: say which frames it is of, never pass it off as the crop's
        "report_metrics_frames": properties.get("cropped_from", properties.get("frames")),
        "report_metrics_cropped": "cropped_from" in properties,
        "accuracy_alignment": _accuracy_alignment(path, prefix),
        "scored_trajectory": scored_trajectory(path, prefix),
        "flagged": flagged,
        "drift": _drift(path, frame_reasons, prefix),
        "gt_check": _gt_check(path, prefix),
        "suspects": find_suspects(path, prefix),
        "loops": _loops(path, prefix),
    }


def _loops(path: Path, prefix: str = "") -> list[dict[str, Any]]:
    """The loops closed (`/loops/closed`, map backend): frame, matched frame, inliers, and the correction
    applied to the frame's keyframe in metres and degrees."""
    table = read_entity(path, f"{prefix}/loops/closed")
    names = ("query_frame", "candidate_frame", "inliers", "correction_m", "correction_deg")
    if table.is_empty() or not all(name in table.columns for name in names):
        return []  # outside the schema (vslam's map backend writes it): another writer's entity of that name

    def column(name: str) -> list[Any]:
        return [v[0] for v in table[name].to_list()]

    return [{"frame": int(f), "matched_frame": int(m), "inliers": int(n), "correction_m": float(c),
             "correction_deg": float(d)}
            for f, m, n, c, d in zip(column("query_frame"), column("candidate_frame"), column("inliers"),
                                     column("correction_m"), column("correction_deg"), strict=True)]


def format_report(report: dict[str, Any]) -> str:
    """The human-readable form of `inspect_recording` (a comparison: every run, one after the other)."""
    head = [f"recording   {report['file']} ({report['bytes'] / 1e6:.1f} MB)", f"name        {report['recording_name']}"]
    if "runs" not in report:
        return "\n".join(head + _format_run(report))
    compare = report["comparison"]
    head.append(f"comparison  of {len(report['runs'])} runs (vslam compare)")
    for prefix, run in report["runs"].items():
        label = compare.get(f"label_{prefix}", prefix)
        head += ["", f"── run {prefix.upper()}: {label} ({compare.get(f'file_{prefix}', '?')})", *_format_run(run)]
    return "\n".join(head)


def _format_run(report: dict[str, Any]) -> list[str]:
    props = report["properties"]
    frames = report["frames"]
    lines = [
        f"source      {props.get('source', '?')} ({props.get('source_path', '?')}), frames {props.get('frames', '?')}, "
        f"scale {props.get('scale', '?')}, backend {props.get('backend', '?')}, detail {props.get('detail', '?')}",
        *([f"pipeline    {props['pipeline']} (logged with vslam.log: its own front end and backend, not vslam's "
           "engine)"] if "pipeline" in props else []),
        *_camera_lines(props),
        f"versions    vslam {props.get('vslam_version', '?')}, OpenCV {props.get('opencv_version', '?')}, "
        f"Rerun {props.get('rerun_version', '?')}",
        f"frames      {frames['count']} ({frames['first']}..{frames['last']})"
        + (f"; cropped from frames {props['cropped_from']}" if "cropped_from" in props else ""),
        *([f"cut short   after frame {frames['last']} (no footer: the run was killed, crashed or ran out of disk); "
           f"it holds frames {frames['first']}..{frames['last']} of the {props.get('frame_count', '?')} the run "
           "was to process; `vslam repair` writes a finalised copy"] if report["cut_short"] else []),
    ]
    if "stopped" in props:
        lines.append(f"stopped     {props['stopped']}")
    lines.append(f"inject      {props.get('inject') or 'none (no faults injected)'}")
    if report["config"]:
        changed = non_default(report["config"])
        lines.append("config      " + ("; ".join(config_lines(changed, arrow=False)) + " (differ from the defaults)"
                                       if changed else "the defaults"))
    stages = {stage: stats for stage, stats in report["stages_ms"].items() if stats is not None}
    if stages:  # another system's trajectory (`vslam eval --trajectory`) has no stages or engine series
        lines += ["", "stage          mean ms   median    p95     max"]
    for stage, stats in stages.items():
        lines.append(f"{stage:<12} {stats['mean']:9.2f} {stats['median']:8.2f} {stats['p95']:7.2f} {stats['max']:7.2f}")
    series = {name: stats for name, stats in report["series"].items() if stats is not None}
    if series:
        lines += ["", "series               mean      min      max"]
    for name, stats in series.items():
        lines.append(f"{name:<16} {stats['mean']:9.2f} {stats['min']:8.2f} {stats['max']:8.2f}")
    lines += format_own_series(report.get("own_series"))
    accuracy = report["accuracy"]
    lines.append("")
    if accuracy is None:
        lines.append("accuracy    no ground truth in this recording")
    else:
        direction = _finite(accuracy["mean_translation_direction_error_deg"])  # none without keyframes (external)
        heading, rms = _finite(accuracy["final_heading_error_deg"]), _finite(accuracy["paper_rms_m"])
        lines.append(
            f"accuracy    position error final {accuracy['final_position_error_m']:.2f} m, mean "
            f"{accuracy['mean_position_error_m']:.2f} m, max {accuracy['max_position_error_m']:.2f} m, RMS (ATE) "
            f"{accuracy['ate_m']:.3f} m"
            + (f"; paper RMS (x–z) {rms:.2f} m" if rms is not None else "; no ground-truth trajectory for the paper "
               "RMS")
            + (f"; heading error final {heading:.2f}°" if heading is not None else "")
            + (f"; mean direction error {direction:.2f}°" if direction is not None else "")
        )
        lines.append("            of the map's refined poses (after bundle adjustment and loop closing), as "
                     "--trajectory-out, eval and the run summary score them; /world/camera is as tracked"
                     if report.get("scored_trajectory") == "refined" else "            of the poses as tracked")
        if report.get("accuracy_alignment") == "sim3":
            lines.append("            (position errors and paper RMS after Sim(3) alignment: --scale none has unit "
                         "steps; heading and direction errors need none)")
    if (check := report.get("gt_check")) is not None:
        lines.append(f"gt check    {check['line']}")
        lines += [f"            warning: {warning}" for warning in check["warnings"]]
    if report.get("report_metrics") and report.get("report_metrics_cropped"):
        lines.append(f"verdict     /report (t_err, ATE …) is of frames {report['report_metrics_frames']}, the run "
                     "before crop: not recomputed for the frames this file holds")
    flagged = report["flagged"]
    lines.append(f"flagged     {len(flagged)} range(s)" + (":" if flagged else ""))
    for item in flagged:
        span = f"{item['start']}" if item["start"] == item["end"] else f"{item['start']}..{item['end']}"
        lines.append(f"  frames {span:<12} {item['status']:<5} {', '.join(item['reasons'])}")
    loops = report.get("loops") or []
    if loops:
        lines.append(f"loops       {len(loops)} closed:")
    for loop in loops:
        lines.append(f"  frame {loop['frame']} revisits frame {loop['matched_frame']}: {loop['inliers']} inliers, "
                     f"corrected {loop['correction_m']:.2f} m, {loop['correction_deg']:.2f}°")
    lines += _drift_lines(report.get("drift"))
    lines += format_suspects(report.get("suspects"), report.get("drift") is not None)
    return lines


def _drift_lines(drift: dict[str, list[dict[str, Any]]] | None, rows: int = 5) -> list[str]:
    """The short "where the error comes from" table: the worst frames by rotation and by translation."""
    if drift is None:
        return []
    rotation, translation = drift["rotation"][:rows], drift["translation"][:rows]
    width = max([13, *(len(",".join(r["reasons"])) for r in rotation)])  # the rotation side's reasons column
    lines = ["", "where the error comes from (each frame's own step against the ground truth; --json: top 10)",
             f"  rank  frame  rotation °  {'reasons':<{width}}  frame  translation m  % of step  reasons"]
    for rank in range(max(len(rotation), len(translation))):
        r = rotation[rank] if rank < len(rotation) else None
        t = translation[rank] if rank < len(translation) else None
        reasons = ",".join(r["reasons"]) or "-" if r else ""
        left = f"{r['frame']:>5}  {r['deg']:10.3f}  {reasons:<{width}}" if r else " " * (width + 19)
        right = ""
        if t:
            pct = t["pct"]
            pct_text = f"{pct:9.1f}" if pct is not None and math.isfinite(pct) else "      n/a"
            right = f"{t['frame']:>5}  {t['m']:13.3f}  {pct_text}  {','.join(t['reasons']) or '-'}"
        lines.append(f"  {rank + 1:>4}  {left}  {right}".rstrip())
    return lines


def _finite(value: float | None) -> float | None:
    """`value` when it is a finite number (JSON gives None for NaN), else None."""
    return value if value is not None and math.isfinite(value) else None


def _camera_lines(props: dict[str, Any]) -> list[str]:
    """The calibration the run used and, for a log, its topic and stamps (recordings of older versions have
    neither)."""
    lines = []
    if "calibration_model" in props:
        coefficients = props.get("calibration_coefficients", "-")
        lines.append(f"camera      {props.get('calibration_size', '?')}, {props.get('calibration_K', '?')}, lens "
                     f"{props['calibration_model']}" + (f" [{coefficients}]" if coefficients != "-" else "")
                     + f", from {props.get('calibration_origin', '?')}")
    if "topic" in props:
        lines.append(f"log         {props.get('log_format', '?')}, topic {props['topic']}, stamps "
                     f"{props.get('stamps', '?')}" + (f"; cut short: {props['recovered']}" if "recovered" in props
                                                      else ""))
    if "frame_order" in props:
        lines.append(f"order       {props['frame_order']}")
    if "sixteen_bit" in props:
        lines.append(f"16-bit      {props['sixteen_bit']}")
    return lines
