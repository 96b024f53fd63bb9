"""Drift attribution in the recording: each frame's own relative pose error against the ground truth.

Per frame (`DriftRecording.take_series`, the frames of each flush computed together): ``/metrics/drift/{rotation_deg,
translation_m, translation_pct, scale_ratio}`` (`vslam_core.trajectory.drift`; frame i against frame i−1). With
``--scale none`` the estimate has unit steps, so the series are logged when the run ends, of the estimate
after Sim(3) alignment onto the ground truth (as every other error of such a run).

When the run ends (`DriftRecording.finish`):

    /world/trajectory/drift      the estimate, one segment per frame (on the `frame` timeline, logged at the
                                 end: the 3-D view shows the past only) coloured by that frame's
                                 translation error in % of its step (`DRIFT_SCALE_PCT`: green 0 %, yellow,
                                 red at 5 % and more; grey where the car stood still); ``frame_index``, % and ° on
                                 hover (not ``frame``: no component shares a timeline's name);
                                 drawn `DRIFT_LIFT_M` above the estimate line (a static Transform3D)
    /world/trajectory/gt_links   static: a line from the estimated to the ground-truth position every
                                 `LINK_EVERY` frames (as evo's Rerun bridge draws them), ``frame_index`` on hover
    /events                      the `WORST` worst frames by rotation and by translation, with their health
    /report                      (the lines returned) the colour scale's legend and the worst frames' table
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from vslam.recording.columns import EVENTS_AT_END, NO_IMAGE, ColumnBuffer, add_event
from vslam.recording.metrics import HEALTH_LEVELS
from vslam_core.sources.base import Frame
from vslam_core.trajectory.drift import FrameErrors, frame_errors, worst_frames

DRIFT_ENTITY = "/world/trajectory/drift"
LINKS_ENTITY = "/world/trajectory/gt_links"
#: The colour scale of `DRIFT_ENTITY`: translation error in % of the ground-truth step, this value is red.
DRIFT_SCALE_PCT = 5.0
#: Colour stops of the scale (fraction of `DRIFT_SCALE_PCT` → RGB), and of frames without a percentage.
DRIFT_STOPS = ((0.0, (40, 220, 60)), (0.5, (255, 230, 0)), (1.0, (230, 30, 30)))
STILL_COLOUR = (150, 150, 150)
LINK_COLOUR = (190, 150, 255)  # lilac: apart from the ground truth (blue) and the error colours
#: A correspondence line every this many frames.
LINK_EVERY = 10
#: `DRIFT_ENTITY` is drawn this far above the estimate (metres, −y of the world's RDF): the viewer draws lines
#: as flat ribbons, and two at one depth flicker into each other (z-fighting).
DRIFT_LIFT_M = 0.3
#: Half-width (metres) of the `DRIFT_ENTITY` ribbon: thin enough that the estimate and ground-truth lines
#: beside it stay visible in the 3-D view.
DRIFT_RADIUS_M = 0.06
#: How many worst frames become events (per ranking) and `vslam inspect` lists.
WORST = 10


def drift_colours(pct: np.ndarray, scale: float = DRIFT_SCALE_PCT) -> np.ndarray:
    """(N, 3) uint8 colours of per-frame errors in %: green at 0, yellow at scale/2, red from `scale` on,
    grey for NaN (no ground-truth step)."""
    values = np.asarray(pct, dtype=np.float64)
    t = np.clip(np.nan_to_num(values / scale, nan=0.0), 0.0, 1.0)
    stops = np.array([s for s, _ in DRIFT_STOPS])
    rgb = np.array([c for _, c in DRIFT_STOPS], dtype=np.float64)
    colours = np.stack([np.interp(t, stops, rgb[:, k]) for k in range(3)], axis=1)
    colours[~np.isfinite(values)] = STILL_COLOUR
    return np.round(colours).astype(np.uint8)

_LEVELS = {str(status): level for status, level in HEALTH_LEVELS.items()}


@dataclass
class FrameTrail:
    """What the recorder keeps of each frame once its image is written: its index and time, estimated position and
    health (a few numbers a frame), read by the drift attribution and by the drive overview when the run ends."""

    frames: list[Frame] = field(default_factory=list)  # index and timestamp only (image dropped)
    positions: list[np.ndarray] = field(default_factory=list)  # estimated camera positions (3,)
    health: list[tuple[str, str]] = field(default_factory=list)  # (status, "reason,reason")

    def add(self, frame: Frame, position: np.ndarray, status: str, reasons: str) -> None:
        self.frames.append(Frame(frame.index, frame.timestamp, NO_IMAGE))
        self.positions.append(np.asarray(position, dtype=np.float64)[:3].copy())
        self.health.append((status, reasons))

    def indices(self) -> np.ndarray:
        """(N,) int64 frame indices."""
        return np.array([f.index for f in self.frames], dtype=np.int64)

    def levels(self) -> np.ndarray:
        """(N,) int health levels (`HEALTH_LEVELS`: 0 ok, 1 warn, 2 fail; a status not reported is 0)."""
        return np.array([_LEVELS.get(status, 0) for status, _ in self.health], dtype=np.int64)

    def health_text(self, i: int) -> str:
        status, reasons = self.health[i]
        return status + (f": {reasons.replace(',', ', ')}" if reasons else "")


@dataclass
class DriftRecording:
    """Each frame's own error against the ground truth, of the frames in `trail` (which its owner fills)."""

    gt: np.ndarray  # (N, 4, 4) ground truth of the run's frames, by run position
    online: bool  # False with --scale none: the series are logged at the end, after Sim(3) alignment
    trail: FrameTrail
    run_positions: list[int] = field(default_factory=list)
    rows: list[tuple[float, float, float, float]] = field(default_factory=list)  # online errors per frame
    errors: FrameErrors | None = None  # each frame's own error, known once `finish` ran
    _previous: tuple[np.ndarray, int] | None = None  # the last frame taken: (4, 4) pose, run position
    _pending: list[tuple[Frame, int, np.ndarray]] = field(default_factory=list)  # added, series not yet taken

    def add(self, frame: Frame, position: int, pose: np.ndarray) -> None:
        """Remember the frame's run position (its trail row is added by the owner) and, with ``online``, its (4, 4)
        pose for its drift series, which `take_series` computes with the other frames' since the last call."""
        self.run_positions.append(position)
        if self.online:
            self._pending.append((Frame(frame.index, frame.timestamp, NO_IMAGE), position, np.array(pose, np.float64)))

    def take_series(self) -> list[tuple[Frame, dict[str, float]]]:
        """The drift series of the frames added since the last call, each against the frame before it (the first
        frame of the run: no step), computed together (`frame_errors` on the stacked poses: the recorder calls this
        at each flush, not a frame at a time). NaN values are left out (the recording's series hold none)."""
        if not self._pending:
            return []
        frames = [frame for frame, _, _ in self._pending]
        positions = [position for _, position, _ in self._pending]
        poses = [pose for _, _, pose in self._pending]
        if self._previous is not None:  # the step into the first of them
            poses.insert(0, self._previous[0])
            positions.insert(0, self._previous[1])
        errors = frame_errors(self.gt[np.array(positions)], np.stack(poses))
        table = np.stack([errors.rotation_deg, errors.translation_m, errors.translation_pct, errors.scale_ratio], 1)
        rows = [(float(r[0]), float(r[1]), float(r[2]), float(r[3])) for r in table[len(table) - len(frames):]]
        self._previous, self._pending = (poses[-1], positions[-1]), []
        self.rows.extend(rows)
        return [(frame, {name: value for name, value in zip(SERIES, row, strict=True) if np.isfinite(value)})
                for frame, row in zip(frames, rows, strict=True)]

    def log_series(self, columns: ColumnBuffer) -> None:
        """The ``/metrics/drift/*`` rows of the frames added since the last call (`take_series`)."""
        for frame, values in self.take_series():
            for name, value in values.items():
                columns.add_scalar(f"/metrics/drift/{name}", frame, value)

    def finish(self, rec: rr.RecordingStream, columns: ColumnBuffer, aligned: np.ndarray | None) -> list[str]:
        """Log the coloured trajectory, the ground-truth links and the worst frames' events; with ``online``
        False (``aligned``: the (N, 4, 4) Sim(3)-aligned estimate) also the series. Returns the report lines."""
        n = len(self.run_positions)
        if n < 2:
            return []
        gt = self.gt[np.array(self.run_positions)]
        if self.online:
            errors = FrameErrors(*(np.array(column) for column in zip(*self.rows, strict=True)))
            estimate = np.array(self.trail.positions[:n])
        elif aligned is None:
            return []
        else:
            errors = frame_errors(gt, aligned[:n])
            estimate = aligned[:n, :3, 3]
            self._send_series(rec, errors)
        self.errors = errors  # the drive overview ranks its stretches by them
        indices = self.trail.indices()[:n]
        strips = np.stack([estimate[:-1], estimate[1:]], axis=1)
        rec.log(DRIFT_ENTITY, rr.Transform3D(translation=[0.0, -DRIFT_LIFT_M, 0.0]),
                rr.LineStrips3D.from_fields(radii=DRIFT_RADIUS_M), static=True)
        # one segment per frame on the `frame` timeline, so the 3-D view shows the past only (as the estimate)
        rec.send_columns(DRIFT_ENTITY, indexes=[rr.TimeColumn("frame", sequence=indices[1:])],
                         columns=[*rr.LineStrips3D.columns(strips=strips,  # (n, 2, 3): ~100x faster than a list
                                                           colors=drift_colours(errors.translation_pct[1:])),
                                  *rr.AnyValues.columns(frame_index=indices[1:],
                                                        translation_pct=np.nan_to_num(errors.translation_pct[1:]),
                                                        rotation_deg=errors.rotation_deg[1:])])
        linked = np.arange(0, n, LINK_EVERY)
        rec.log(LINKS_ENTITY, rr.LineStrips3D(np.stack([estimate[linked], gt[linked, :3, 3]], axis=1),
                                              colors=LINK_COLOUR, radii=0.04),
                rr.AnyValues(frame_index=indices[linked]), static=True)
        return self._events(columns, errors, indices)

    def _send_series(self, rec: rr.RecordingStream, errors: FrameErrors) -> None:
        for name in SERIES:
            values = getattr(errors, name)
            keep = np.isfinite(values)
            frames = [f.index for f, k in zip(self.trail.frames[:len(keep)], keep, strict=True) if k]
            rec.send_columns(f"/metrics/drift/{name}", indexes=[rr.TimeColumn("frame", sequence=frames)],
                             columns=rr.Scalars.columns(scalars=values[keep]))

    def _events(self, columns: ColumnBuffer, errors: FrameErrors, indices: np.ndarray) -> list[str]:
        by_frame = {int(index): i for i, index in enumerate(indices)}
        rotation = worst_frames(errors.rotation_deg, WORST, indices)
        translation = worst_frames(errors.translation_m, WORST, indices)
        lines = [
            "## Where the error comes from",
            "",
            f"`{DRIFT_ENTITY}`: the estimate coloured by each frame's translation error in % of its step, "
            f"green 0 %, yellow {DRIFT_SCALE_PCT / 2:g} %, red ≥ {DRIFT_SCALE_PCT:g} % (grey: standing still); "
            f"`{LINKS_ENTITY}`: estimate → ground truth every {LINK_EVERY} frames.",
            "",
            "| rank | frame | rotation ° | health | frame | translation m | % of step | health |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for rank in range(max(len(rotation), len(translation))):
            r = rotation[rank] if rank < len(rotation) else None
            t = translation[rank] if rank < len(translation) else None
            pct = errors.translation_pct[by_frame[t[0]]] if t is not None else np.nan
            lines.append(f"| {rank + 1} | {r[0] if r else ''} | {f'{r[1]:.3f}' if r else ''} | "
                         f"{self.trail.health_text(by_frame[r[0]]) if r else ''} | "
                         f"{t[0] if t else ''} | {f'{t[1]:.3f}' if t else ''} | "
                         f"{f'{pct:.1f}' if np.isfinite(pct) else 'n/a'} | "
                         f"{self.trail.health_text(by_frame[t[0]]) if t else ''} |")
        for rank, (index, value) in enumerate(rotation):
            i = by_frame[index]
            add_event(columns, self.trail.frames[i], f"drift: rotation #{rank + 1}, {value:.3f}° this frame "
                      f"({errors.translation_m[i]:.3f} m); health {self.trail.health_text(i)}", "WARN", EVENTS_AT_END)
        for rank, (index, value) in enumerate(translation):
            i = by_frame[index]
            pct = errors.translation_pct[i]
            add_event(columns, self.trail.frames[i], f"drift: translation #{rank + 1}, {value:.3f} m this frame"
                      + (f" ({pct:.1f} % of the step)" if np.isfinite(pct) else "")
                      + f" ({errors.rotation_deg[i]:.3f}°); health {self.trail.health_text(i)}", "WARN",
                      EVENTS_AT_END)
        return lines


SERIES = ("rotation_deg", "translation_m", "translation_pct", "scale_ratio")
