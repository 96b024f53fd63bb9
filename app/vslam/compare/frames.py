"""Per-frame comparison of two runs: how each frame's step differs, and the first frame where they diverge.

For the frames both runs recorded (the ``frame`` timeline of ``/world/camera``, T_world_cam), frame i's step
is the relative pose from the previous common frame, ``step = T_world_cam[i−1]⁻¹ · T_world_cam[i]`` (camera
frame, RDF). Per frame of a run B against the baseline A (`frame_differences`):

- ``rotation_deg``: the angle of ``R_stepA⁻¹ · R_stepB`` (degrees),
- ``translation_pct``: ``|t_stepB − t_stepA| / |t_stepA|`` in % (NaN where A stood still: its step is shorter
  than `MIN_STEP_M`),
- ``position_m``: the distance between the camera positions after B is moved so that its first common
  frame's pose equals A's (``T_align = T_A[0] · T_B[0]⁻¹``, a rigid motion, no scale).

The first divergence (`first_divergence`) is the first frame whose step differs by more than `ROTATION_DEG`
or `TRANSLATION_PCT`; the defaults come from measurements on KITTI (`vslam.compare.limits`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
from rerun.chunk import Chunk

from vslam.compare.limits import ROTATION_DEG, TRANSLATION_PCT
from vslam.rrd import read_poses
from vslam_core.geometry import invert_pose

#: A baseline step shorter than this (metres, or units with ``--scale none``) is a car standing still: no %.
MIN_STEP_M = 0.05
#: How many frames before and after the divergence `FirstDivergence.context` holds.
CONTEXT_FRAMES = 2


@dataclass(frozen=True)
class RunFrames:
    """One run's per-frame poses and health, read back from its recording."""

    frames: np.ndarray  # (N,) int64, ascending
    poses: np.ndarray  # (N, 4, 4) T_world_cam
    health: dict[int, tuple[str, list[str]]] = field(default_factory=dict)  # frame → (status, reasons)

    def health_at(self, frame: int) -> tuple[str, list[str]]:
        """(status, reasons) of `frame`; ("not reported", []) for a recording without ``/health``."""
        return self.health.get(frame, ("not reported", []))


@dataclass(frozen=True)
class FrameDifferences:
    """Per common frame (the first has a zero step difference): run B against the baseline A."""

    frames: np.ndarray  # (M,) int64
    rotation_deg: np.ndarray  # (M,)
    translation_pct: np.ndarray  # (M,) NaN where A's step is shorter than MIN_STEP_M
    position_m: np.ndarray  # (M,)


@dataclass(frozen=True)
class FirstDivergence:
    """The first frame where B's step differs from A's by more than a threshold, and both runs' health
    around it (`context`: frame → ((status A, reasons A), (status B, reasons B)))."""

    frame: int
    rotation_deg: float
    translation_pct: float | None
    position_m: float
    health_a: tuple[str, list[str]]
    health_b: tuple[str, list[str]]
    context: dict[int, tuple[tuple[str, list[str]], tuple[str, list[str]]]]

    def as_json(self) -> dict[str, object]:
        """``first_divergence`` of ``vslam compare --json``."""
        return {"frame": self.frame, "rotation_deg": self.rotation_deg, "translation_pct": self.translation_pct,
                "position_m": self.position_m, "health_a": self.health_a[0], "health_b": self.health_b[0],
                "reasons_a": self.health_a[1], "reasons_b": self.health_b[1],
                "context": [{"frame": f, "health_a": a[0], "reasons_a": a[1], "health_b": b[0], "reasons_b": b[1]}
                            for f, (a, b) in sorted(self.context.items())]}


def read_run_frames(path: Path, prefix: str = "") -> RunFrames:
    """Poses (``{prefix}/world/camera``) and health (``{prefix}/health``) of a recording by frame
    (`vslam.rrd.read_poses`)."""
    run = read_poses(path, prefix)
    return RunFrames(run.frames, run.poses, run.health)


def frame_differences(a: RunFrames, b: RunFrames) -> FrameDifferences:
    """B against A on the frames both hold (see the module docstring)."""
    common, in_a, in_b = np.intersect1d(a.frames, b.frames, return_indices=True)
    poses_a, poses_b = a.poses[in_a], b.poses[in_b]
    m = len(common)
    rotation, pct = np.zeros(m), np.full(m, np.nan)
    for k in range(1, m):
        step_a = invert_pose(poses_a[k - 1]) @ poses_a[k]
        step_b = invert_pose(poses_b[k - 1]) @ poses_b[k]
        rotation[k] = np.degrees(small_angle(step_a[:3, :3].T @ step_b[:3, :3]))
        length = float(np.linalg.norm(step_a[:3, 3]))
        if length >= MIN_STEP_M:
            pct[k] = 100.0 * float(np.linalg.norm(step_b[:3, 3] - step_a[:3, 3])) / length
    if m:
        aligned_b = (poses_a[0] @ invert_pose(poses_b[0])) @ poses_b
        position = np.linalg.norm(aligned_b[:, :3, 3] - poses_a[:, :3, 3], axis=1)
    else:
        position = np.zeros(0)
    return FrameDifferences(common.astype(np.int64), rotation, pct, position)


def small_angle(rotation: np.ndarray) -> float:
    """Angle (radians) of a (3, 3) rotation, accurate near zero: ``atan2(|vee(R − Rᵀ)| / 2, (tr R − 1) / 2)``.
    (``acos((tr R − 1) / 2)`` of the float32 rotations a recording holds reads ~0.03° for identical steps.)"""
    skew = rotation - rotation.T
    sine = 0.5 * float(np.linalg.norm([skew[2, 1], skew[0, 2], skew[1, 0]]))
    return float(np.arctan2(sine, (np.trace(rotation) - 1.0) / 2.0))


def first_divergence(a: RunFrames, b: RunFrames, differences: FrameDifferences,
                     rotation_deg: float = ROTATION_DEG,
                     translation_pct: float = TRANSLATION_PCT) -> FirstDivergence | None:
    """The first frame whose step rotation differs by more than `rotation_deg` or translation by more than
    `translation_pct` (None: no such frame), with both runs' health there and `CONTEXT_FRAMES` around it."""
    over = (differences.rotation_deg > rotation_deg) | (np.nan_to_num(differences.translation_pct)
                                                        > translation_pct)
    hits = np.flatnonzero(over)
    if not len(hits):
        return None
    k = int(hits[0])
    frame = int(differences.frames[k])
    around = differences.frames[max(k - CONTEXT_FRAMES, 0): k + CONTEXT_FRAMES + 1]
    pct = float(differences.translation_pct[k])
    return FirstDivergence(
        frame=frame, rotation_deg=float(differences.rotation_deg[k]),
        translation_pct=pct if np.isfinite(pct) else None, position_m=float(differences.position_m[k]),
        health_a=a.health_at(frame), health_b=b.health_at(frame),
        context={int(f): (a.health_at(int(f)), b.health_at(int(f))) for f in around})


def describe_divergence(label_a: str, label_b: str, divergence: FirstDivergence | None, rotation_deg: float,
                        translation_pct: float) -> list[str]:
    """Text lines naming the first divergence of B from A (or saying there is none) and the health around it."""
    limits = f"step rotation > {rotation_deg:g}° or translation > {translation_pct:g} % of the step"
    if divergence is None:
        return [f"first divergence  {label_b} vs {label_a}: none ({limits} on no frame)"]
    d = divergence
    pct = "–" if d.translation_pct is None else f"{d.translation_pct:.1f} %"
    lines = [f"first divergence  {label_b} vs {label_a}: frame {d.frame} (step rotation {d.rotation_deg:.2f}°, "
             f"translation {pct} of the step, position {d.position_m:.2f} m apart; {limits})"]
    width = max(len(label_a), len(label_b))
    for frame, (health_a, health_b) in sorted(d.context.items()):
        mark = ">" if frame == d.frame else " "
        lines.append(f"  {mark} frame {frame:>6}  {label_a:<{width}} {_health(health_a):<28}  "
                     f"{label_b:<{width}} {_health(health_b)}")
    return lines


def _health(health: tuple[str, list[str]]) -> str:
    status, reasons = health
    return status + (f" ({', '.join(reasons)})" if reasons else "")


# ------------------------------------------------------------------------------------ into the recording

#: Where the per-frame differences of run ``<prefix>`` (b, c, …) against the baseline go in a comparison.
DIFFERENCE_ROOT = "/compare"
#: The divergence events of every run against the baseline.
DIFFERENCE_EVENTS = "/compare/events"
#: (entity name, legend, plot) of the per-frame difference series.
DIFFERENCE_SERIES = (("step_rotation_deg", "step rotation difference (°)", "rotation"),
                     ("step_translation_pct", "step translation difference (% of step)", "translation"),
                     ("position_m", "position difference after aligning the first frames", "position"))
#: The marker at the first divergence, drawn in the step-rotation plot.
DIVERGENCE_MARKER = "divergence"


def difference_chunks(prefix: str, label_a: str, label_b: str, colour: tuple[int, int, int],
                      differences: FrameDifferences, divergence: FirstDivergence | None,
                      text: list[str]) -> list[Chunk]:
    """The comparison recording's per-frame series of run `prefix` against the baseline
    (``/compare/<prefix>/{step_rotation_deg, step_translation_pct, position_m}``, legend "B − A: …"), and at
    the first divergence a marker (``/compare/<prefix>/divergence``, a point on the step-rotation plot) and a
    WARN event in ``/compare/events`` (`text` joined); an INFO event at the first frame says there is none."""
    chunks = []
    values = {"step_rotation_deg": differences.rotation_deg, "step_translation_pct": differences.translation_pct,
              "position_m": differences.position_m}
    for name, legend, _ in DIFFERENCE_SERIES:
        entity = f"{DIFFERENCE_ROOT}/{prefix}/{name}"
        series = values[name]
        keep = np.isfinite(series)
        chunks.append(Chunk.from_columns(entity, indexes=[], columns=rr.SeriesLines.columns(
            names=[f"{label_b} − {label_a}: {legend}"], colors=[colour], widths=[1.5])))
        if keep.any():
            chunks.append(Chunk.from_columns(
                entity, indexes=[rr.TimeColumn("frame", sequence=differences.frames[keep])],
                columns=rr.Scalars.columns(scalars=series[keep])))
    message = "\n".join(text)
    if divergence is None:
        if len(differences.frames):
            chunks.append(_event(int(differences.frames[0]), message, "INFO"))
        return chunks
    marker = f"{DIFFERENCE_ROOT}/{prefix}/{DIVERGENCE_MARKER}"
    chunks.append(Chunk.from_columns(marker, indexes=[], columns=rr.SeriesPoints.columns(
        names=[f"first divergence {label_b} vs {label_a}"], colors=[(255, 40, 40)], marker_sizes=[8.0],
        markers=["Cross"])))
    chunks.append(Chunk.from_columns(marker, indexes=[rr.TimeColumn("frame", sequence=[divergence.frame])],
                                     columns=rr.Scalars.columns(scalars=[divergence.rotation_deg])))
    chunks.append(_event(divergence.frame, message, "WARN"))
    return chunks


def _event(frame: int, text: str, level: str) -> Chunk:
    return Chunk.from_columns(DIFFERENCE_EVENTS, indexes=[rr.TimeColumn("frame", sequence=[frame])],
                              columns=rr.TextLog.columns(text=[text], level=[level]))


def _text(value: object) -> str:
    """One `AnyValues` cell as text (a one-element list as the reader gives it, or the bare value); "" for none."""
    if isinstance(value, list):
        value = value[0] if value else None
    return "" if value is None else str(value)
