"""Top-view trajectory plots drawn with OpenCV (no plotting dependency): x right, z (forward) up."""

from __future__ import annotations

import errno
import math
from pathlib import Path

import cv2
import numpy as np

WHITE, GRID, AXIS, TEXT = (255, 255, 255), (225, 225, 225), (120, 120, 120), (30, 30, 30)
ESTIMATE_BGR, GROUND_TRUTH_BGR = (60, 60, 230), (90, 170, 40)
#: Colours of several estimates in one plot (BGR): the first is the single estimate's red.
ESTIMATES_BGR = (ESTIMATE_BGR, (220, 120, 30), (0, 150, 255), (180, 60, 160), (40, 40, 40), (170, 170, 0))
#: An estimate and its name (the legend's label); `top_view` takes one array or a list of these.
Named = tuple[str, np.ndarray]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def nice_step(span: float, ticks: int = 8) -> float:
    """A 1-2-5 × 10^k grid step giving about `ticks` lines over `span`."""
    raw = max(span, 1e-9) / ticks
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw)


def top_view(
    ground_truth: np.ndarray | list[np.ndarray] | None, estimate: np.ndarray | list[Named], title: str,
    subtitle: str = "", size: int = 900
) -> np.ndarray:
    """(size, size, 3) BGR picture of (N, 4, 4) trajectories seen from above (x–z plane, equal axes). Several
    estimates (a list of (name, poses)) get distinct colours (`ESTIMATES_BGR`, repeating after six) and the
    legend names them; several ground truths (e.g. one per estimate's window) are all drawn in green."""
    named = [("estimate", estimate)] if isinstance(estimate, np.ndarray) else estimate
    truths = [] if ground_truth is None else [ground_truth] if isinstance(ground_truth, np.ndarray) else ground_truth
    colours = [ESTIMATES_BGR[i % len(ESTIMATES_BGR)] for i in range(len(named))]
    tracks = [*truths, *(poses for _, poses in named)]
    xz = np.concatenate([t[:, :3, 3][:, [0, 2]] for t in tracks])
    low, high = xz.min(axis=0), xz.max(axis=0)
    span = float(max(high - low)) * 1.1 + 1.0
    centre = (low + high) / 2
    top, margin = 90, 70
    plot = size - margin - 20
    scale = plot / span

    def to_px(points: np.ndarray) -> np.ndarray:
        u = margin + (points[:, 0] - centre[0] + span / 2) * scale
        v = top + (centre[1] + span / 2 - points[:, 1]) * scale
        return np.round(np.column_stack((u, v)) * 16).astype(np.int32)  # 4 fractional bits

    canvas = np.full((size + top - 20, size, 3), WHITE, np.uint8)
    step = nice_step(span)
    low = centre - span / 2  # lower-left corner of the plotted square (metres)
    for axis in (0, 1):
        for value in np.arange(math.ceil(low[axis] / step) * step, low[axis] + span, step):
            if axis == 0:  # vertical grid line x = value, labelled below the plot
                ends = to_px(np.array([[value, low[1]], [value, low[1] + span]]))
                anchor = (int(ends[0][0] / 16) - 12, top + plot + 18)
            else:  # horizontal grid line z = value, labelled on the left
                ends = to_px(np.array([[low[0], value], [low[0] + span, value]]))
                anchor = (8, int(ends[0][1] / 16) + 4)
            colour = AXIS if abs(value) < step / 2 else GRID
            cv2.line(canvas, tuple(ends[0]), tuple(ends[1]), colour, 1, cv2.LINE_AA, 4)
            cv2.putText(canvas, f"{value:g}", anchor, FONT, 0.4, TEXT, 1, cv2.LINE_AA)
    cv2.putText(canvas, "x (m)", (margin + plot // 2, top + plot + 40), FONT, 0.5, TEXT, 1, cv2.LINE_AA)
    cv2.putText(canvas, "z (m)", (8, top - 10), FONT, 0.5, TEXT, 1, cv2.LINE_AA)
    for track, colour in zip(tracks, [GROUND_TRUTH_BGR] * len(truths) + colours, strict=True):
        cv2.polylines(canvas, [to_px(track[:, :3, 3][:, [0, 2]])], False, colour, 2, cv2.LINE_AA, 4)
    start = to_px(named[0][1][:1, :3, 3][:, [0, 2]])[0]
    cv2.circle(canvas, tuple(start), 6 * 16, TEXT, 1, cv2.LINE_AA, 4)
    cv2.putText(canvas, title, (margin, 30), FONT, 0.7, TEXT, 2, cv2.LINE_AA)
    cv2.putText(canvas, subtitle, (margin, 56), FONT, 0.45, TEXT, 1, cv2.LINE_AA)
    legend = [(name, colour) for (name, _), colour in zip(named, colours, strict=True)]
    legend += [("ground truth", GROUND_TRUTH_BGR)] if truths else []
    if len(named) == 1:  # one line at the top right
        for i, (name, colour) in enumerate(legend):
            _legend_entry(canvas, size - 320 + 150 * i, 76, name, colour)
    else:  # one entry a line, top left inside the plot, on white
        cv2.rectangle(canvas, (margin + 4, top + 4), (margin + 260, top + 12 + 20 * len(legend)), WHITE, -1)
        for i, (name, colour) in enumerate(legend):
            _legend_entry(canvas, margin + 12, top + 24 + 20 * i, name[:28], colour)
    return canvas


def _legend_entry(canvas: np.ndarray, x: int, y: int, name: str, colour: tuple[int, int, int]) -> None:
    cv2.line(canvas, (x, y - 4), (x + 30, y - 4), colour, 3, cv2.LINE_AA)
    cv2.putText(canvas, name, (x + 36, y), FONT, 0.45, TEXT, 1, cv2.LINE_AA)


def write_top_view(
    path: Path, ground_truth: np.ndarray | list[np.ndarray] | None, estimate: np.ndarray | list[Named], title: str,
    subtitle: str = ""
) -> None:
    """`top_view` as a PNG file (`OSError` when it cannot be written)."""
    encoded, png = cv2.imencode(".png", top_view(ground_truth, estimate, title, subtitle))
    if not encoded:
        raise OSError(errno.EIO, "could not encode the plot", str(path))
    path.write_bytes(png.tobytes())  # not cv2.imwrite: a full disk raises ENOSPC here, libpng only prints
