"""`vslam inspect`: what a bug report needs from a recording, read without a viewer.

The JSON form (`inspect_recording`) is a stable interface; its keys are documented in README.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from app.recording import METRICS, STAGES
from app.rrd import RecordingError, read_entity, readable

SCHEMA_VERSION = 1


def _scalars(path: Path, group: str) -> dict[str, np.ndarray]:
    """Values of each series of one metric group, over the frames that have one."""
    series = {}
    for name in METRICS[group]:
        table = read_entity(path, f"/metrics/{group}/{name}")
        values = [v[0] for v in table["Scalars:scalars"].to_list()] if not table.is_empty() else []
        series[name] = np.asarray(values, dtype=np.float64)
    return series


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


def _properties(path: Path, name: str) -> dict[str, Any]:
    table = read_entity(path, f"/__properties/{name}", static=True)
    if table.is_empty():
        return {}
    row = table.row(0, named=True)
    return {
        k: (v[0] if isinstance(v, list) and len(v) == 1 else v) for k, v in row.items() if not k.startswith("rerun.")
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


def _accuracy(path: Path) -> dict[str, float] | None:
    position = _scalars(path, "error")["position_m"]
    if not len(position):
        return None
    angles = _scalars(path, "angle_error")
    camera = read_entity(path, "/world/camera")
    ground_truth = read_entity(path, "/world/trajectory/ground_truth")
    translations = camera["Transform3D:translation"].to_list()
    estimate_xyz = np.array([t[0] if isinstance(t[0], list) else t for t in translations], np.float64).reshape(-1, 3)
    gt_xyz = np.array([strips[0][1] for strips in ground_truth["LineStrips3D:strips"].to_list()]).reshape(-1, 3)
    n = min(len(estimate_xyz), len(gt_xyz))
    xz = (estimate_xyz[:n] - gt_xyz[:n])[:, [0, 2]]
    heading, direction = angles["heading_deg"], angles["translation_direction_deg"]
    return {
        "final_position_error_m": float(position[-1]),
        "mean_position_error_m": float(position.mean()),
        "max_position_error_m": float(position.max()),
        "paper_rms_m": float(np.sqrt(np.mean(np.sum(xz**2, axis=1)))),
        "final_heading_error_deg": float(heading[-1]),
        "mean_translation_direction_error_deg": float(direction.mean()) if len(direction) else math.nan,
    }


def inspect_recording(path: Path) -> dict[str, Any]:
    """Everything `vslam inspect --json` prints (see README: "vslam inspect --json")."""
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording")
    cut_short = readable(path).cut_short
    camera = read_entity(path, "/world/camera")
    if camera.is_empty() or "frame" not in camera.columns:
        raise RecordingError(f"{path}: no camera frames in this recording (not written by `vslam run`?)"
                             + (" (cut short before the first frame was written)" if cut_short else ""))
    frames = camera["frame"].to_list()
    health = read_entity(path, "/health")
    flagged = []
    if not health.is_empty():
        reasons = health["reasons"].to_list() if "reasons" in health.columns else [None] * len(health)
        flagged = flagged_ranges(
            health["frame"].to_list(), [v[0] for v in health["status"].to_list()], [v[0] if v else "" for v in reasons]
        )
    timing = _scalars(path, "timing_ms")
    tracks, ransac, ratio = _scalars(path, "tracks"), _scalars(path, "ransac"), _scalars(path, "ratio")
    name_table = read_entity(path, "/__properties", static=True)
    name = name_table["RecordingInfo:name"][0][0] if "RecordingInfo:name" in name_table.columns else None
    return {
        "schema": SCHEMA_VERSION,
        "file": str(path),
        "bytes": path.stat().st_size,
        "recording_name": name,
        "properties": _properties(path, "run"),
        "config": _properties(path, "config"),
        "frames": {"count": len(frames), "first": int(min(frames)), "last": int(max(frames))},
        "cut_short": cut_short,
        "stages_ms": {stage: _stats(timing[stage]) for stage in STAGES},
        "series": {
            "tracks_alive": _stats(tracks["alive"]),
            "corners_detected": _stats(tracks["new_corners"]),
            "fb_rejected": _stats(tracks["fb_rejected"]),
            "ransac_inliers": _stats(ransac["inliers"]),
            "inlier_ratio": _stats(ratio["inlier_ratio"]),
            "chirality_margin": _stats(ransac["chirality_margin"]),
        },
        "accuracy": _accuracy(path),
        "flagged": flagged,
    }


def format_report(report: dict[str, Any]) -> str:
    """The human-readable form of `inspect_recording`."""
    props = report["properties"]
    frames = report["frames"]
    lines = [
        f"recording   {report['file']} ({report['bytes'] / 1e6:.1f} MB)",
        f"name        {report['recording_name']}",
        f"source      {props.get('source', '?')} ({props.get('source_path', '?')}), frames {props.get('frames', '?')}, "
        f"scale {props.get('scale', '?')}, detail {props.get('detail', '?')}",
        f"versions    vslam {props.get('vslam_version', '?')}, OpenCV {props.get('opencv_version', '?')}, "
        f"Rerun {props.get('rerun_version', '?')}",
        f"frames      {frames['count']} ({frames['first']}..{frames['last']})",
        *([f"cut short   after frame {frames['last']} (no footer: the run was killed, crashed or ran out of disk); "
           f"it holds frames {frames['first']}..{frames['last']} of the {props.get('frame_count', '?')} the run "
           "was to process; `vslam repair` writes a finalised copy"] if report["cut_short"] else []),
        "",
        "stage          mean ms   median    p95     max",
    ]
    for stage, stats in report["stages_ms"].items():
        if stats is not None:
            lines.append(
                f"{stage:<12} {stats['mean']:9.2f} {stats['median']:8.2f} {stats['p95']:7.2f} {stats['max']:7.2f}"
            )
    lines += ["", "series               mean      min      max"]
    for name, stats in report["series"].items():
        if stats is not None:
            lines.append(f"{name:<16} {stats['mean']:9.2f} {stats['min']:8.2f} {stats['max']:8.2f}")
    accuracy = report["accuracy"]
    lines.append("")
    if accuracy is None:
        lines.append("accuracy    no ground truth in this recording")
    else:
        lines.append(
            f"accuracy    position error final {accuracy['final_position_error_m']:.2f} m, mean "
            f"{accuracy['mean_position_error_m']:.2f} m, max {accuracy['max_position_error_m']:.2f} m; "
            f"paper RMS (x–z) {accuracy['paper_rms_m']:.2f} m; heading error final "
            f"{accuracy['final_heading_error_deg']:.2f}°; mean direction error "
            f"{accuracy['mean_translation_direction_error_deg']:.2f}°"
        )
    flagged = report["flagged"]
    lines.append(f"flagged     {len(flagged)} range(s)" + (":" if flagged else ""))
    for item in flagged:
        span = f"{item['start']}" if item["start"] == item["end"] else f"{item['start']}..{item['end']}"
        lines.append(f"  frames {span:<12} {item['status']:<5} {', '.join(item['reasons'])}")
    return "\n".join(lines)
