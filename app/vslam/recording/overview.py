"""The whole drive at a glance, logged once the run ends: a top view of the path (`OVERVIEW_PATH`, each frame's
step coloured by its own error against the ground truth, or by its health without one), the ground truth beside it
(`OVERVIEW_GT`), marks at failed frames, closed loops and the worst stretches (`OVERVIEW_MARKS`), and a short
summary that fits a small panel (`OVERVIEW_SUMMARY`): what `vslam snapshot`'s ``all.png`` shows of a long run.

The top view drops the world axis along which the estimate moves least (KITTI's and the synthetic routes' −y,
up); the other two, in axis order, are drawn as (u, −v), so a camera driving along +z goes up the picture. The
picture is scaled uniformly into a `CANVAS`-unit square (5 % margin), which the drive view shows whole: the
overview's coordinates are canvas units, not metres.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from vslam.recording.drift import FrameTrail, drift_colours
from vslam.recording.styles import GROUND_TRUTH_COLOUR, HEALTH_LEVEL_LINES, LOOP_MARK_COLOUR, WORST_MARK_COLOUR
from vslam_core.trajectory.drift import FrameErrors

OVERVIEW_PATH = "/overview/path"
OVERVIEW_GT = "/overview/ground_truth"
OVERVIEW_MARKS = "/overview/marks"
OVERVIEW_SUMMARY = "/overview/summary"
#: A stretch is this share of the run (at least `MIN_STRETCH` frames); the `WORST_COUNT` worst are listed.
STRETCH_SHARE = 0.05
MIN_STRETCH = 10
WORST_COUNT = 3
#: Side of the square the top view is scaled into (the drive view's visual bounds).
CANVAS = 1000.0
#: Health level (0 ok, 1 warn, 2 fail) -> colour of the path without ground truth, as the health plot's lines.
HEALTH_COLOURS = {int(value): colour for _, _, value, colour in HEALTH_LEVEL_LINES}


@dataclass(frozen=True)
class Stretch:
    """Frames `first`..`last` (source indices, inclusive) and what they cost (`score`, in the ranking's unit)."""

    first: int
    last: int
    score: float


def worst_stretches(frames: np.ndarray, cost: np.ndarray, length: int, count: int = WORST_COUNT) -> list[Stretch]:
    """The `count` non-overlapping runs of `length` consecutive rows with the largest summed `cost` (N,), best
    first, each as the source frame indices `frames` (N,) it spans; windows with no cost are never listed."""
    cost = np.nan_to_num(np.asarray(cost, dtype=np.float64), nan=0.0)
    n = len(cost)
    length = max(1, min(length, n))
    if n == 0:
        return []
    sums = np.convolve(cost, np.ones(length), mode="valid")  # (n - length + 1,): window starting at row i
    taken = np.zeros(n, dtype=bool)
    stretches: list[Stretch] = []
    for start in np.argsort(-sums, kind="stable"):
        if len(stretches) == count or sums[start] <= 0:
            break
        if taken[start:start + length].any():
            continue
        taken[start:start + length] = True
        stretches.append(Stretch(int(frames[start]), int(frames[start + length - 1]), float(sums[start])))
    return stretches


def top_view(positions: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) world positions -> (N, 2) top-view points: the axis along which `reference` (N, 3; default
    `positions`) spreads least is dropped (see the module)."""
    spread = (positions if reference is None else reference).std(axis=0) if len(positions) else np.ones(3)
    up = int(np.argmin(spread))
    u, v = (axis for axis in range(3) if axis != up)
    return np.stack([positions[:, u], -positions[:, v]], axis=1)


def canvas_transform(points: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The uniform scaling and shift that puts `points` (N, 2) centred in the `CANVAS` square, 5 % margin."""
    low, high = points.min(axis=0), points.max(axis=0)
    scale = 0.9 * CANVAS / max(float((high - low).max()), 1e-9)
    centre = (low + high) / 2

    def transform(p: np.ndarray) -> np.ndarray:
        return (p - centre) * scale + CANVAS / 2

    return transform


@dataclass
class DriveOverview:
    """The overview of the frames in `trail` (which its owner fills) and the loops closed among them."""

    trail: FrameTrail
    loops: list[tuple[int, int]] = field(default_factory=list)  # (query frame, candidate frame)

    def add_loop(self, query_frame: int, candidate_frame: int) -> None:
        self.loops.append((int(query_frame), int(candidate_frame)))

    def finish(self, rec: rr.RecordingStream, headline: list[str], *, estimate: np.ndarray | None = None,
               ground_truth: np.ndarray | None = None, errors: FrameErrors | None = None) -> list[Stretch]:
        """Log the overview entities (static). `estimate` (N, 3): the positions to draw (the Sim(3)-aligned ones
        with ``--scale none``), else those added; `ground_truth` (N, 3) positions; `errors`: each frame's own
        error (drift attribution), which ranks the stretches, else the health does. `headline`: the summary's
        first lines. Returns the worst stretches."""
        frames = self.trail.indices()
        if len(frames) < 2:
            return []
        usable = errors is not None and len(errors.translation_m) == len(frames)
        translation_m = errors.translation_m if usable and errors is not None else None
        translation_pct = errors.translation_pct if usable and errors is not None else None
        rotation_deg = errors.rotation_deg if usable and errors is not None else None
        positions = np.array(self.trail.positions) if estimate is None else np.asarray(estimate)[: len(frames)]
        health = self.trail.levels()
        with_errors = translation_m is not None and translation_pct is not None
        if with_errors:
            assert translation_m is not None and translation_pct is not None
            colours = drift_colours(np.asarray(translation_pct)[1:])
            cost, unit = np.asarray(translation_m), "m of drift"
        else:
            colours = np.array([HEALTH_COLOURS[level] for level in health[1:]], dtype=np.uint8)
            cost, unit = health.astype(np.float64), "health (1 warn, 2 fail per frame)"
        length = max(MIN_STRETCH, int(round(STRETCH_SHARE * len(frames))))
        worst = worst_stretches(frames, cost, length)

        view = top_view(positions)
        gt_view = top_view(np.asarray(ground_truth)[: len(frames)], positions) if ground_truth is not None else None
        to_canvas = canvas_transform(view if gt_view is None else np.vstack([view, gt_view]))
        view = to_canvas(view)
        rec.log(OVERVIEW_PATH, rr.LineStrips2D(np.stack([view[:-1], view[1:]], axis=1), colors=colours,
                                               radii=rr.Radius.ui_points(2.5)), static=True)
        if gt_view is not None:
            rec.log(OVERVIEW_GT, rr.LineStrips2D([to_canvas(gt_view)], colors=GROUND_TRUTH_COLOUR,
                                                 radii=rr.Radius.ui_points(1.5)), static=True)
        rows = {int(f): i for i, f in enumerate(frames)}
        marks, labels, mark_colours = [], [], []
        for rank, stretch in enumerate(worst, 1):
            marks.append(view[rows.get((stretch.first + stretch.last) // 2, rows[stretch.first])])
            labels.append(f"#{rank} {stretch.first}–{stretch.last}")
            mark_colours.append(WORST_MARK_COLOUR)
        for query, candidate in self.loops:
            if query in rows:
                marks.append(view[rows[query]])
                labels.append(f"loop {query}→{candidate}")
                mark_colours.append(LOOP_MARK_COLOUR)
        failed = np.flatnonzero(health == 2)
        for i in failed:
            marks.append(view[i])
            labels.append("")
            mark_colours.append(HEALTH_COLOURS[2])
        if marks:
            rec.log(OVERVIEW_MARKS, rr.Points2D(np.array(marks), colors=mark_colours, labels=labels,
                                                radii=rr.Radius.ui_points(5.0)), static=True)
        lines = [f"**{headline[0]}**", *(f"- {line}" for line in headline[1:])]
        if worst:
            lines.append(f"\n**Worst stretches** ({unit}):")
            for rank, stretch in enumerate(worst, 1):
                extra = ""
                if rotation_deg is not None:
                    span = (frames >= stretch.first) & (frames <= stretch.last)
                    extra = f", {float(np.nansum(np.asarray(rotation_deg)[span])):.2f}°"
                lines.append(f"{rank}. frames {stretch.first}–{stretch.last}: {stretch.score:.3g}{extra}")
        else:
            lines.append("- no stretch stands out: every frame ok" if not with_errors else "- no drift measured")
        if len(failed):
            lines.append(f"- failed frames: {len(failed)} (red in the drive view)")
        if self.loops:
            lines.append(f"- loops closed: {len(self.loops)}")
        rec.log(OVERVIEW_SUMMARY, rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN), static=True)
        return worst

