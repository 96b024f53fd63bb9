"""Fault injection on any source, for tests and demos: ``--inject dark@120,blur@200:210``.

Each fault applies to an inclusive range of source frame indices:

| kind | what the camera delivers |
|---|---|
| dark | an almost black frame (lens covered, tunnel) |
| overexposed | a washed-out, saturated frame (sun straight ahead) |
| blur | strong motion blur |
| frozen | the previous frame again (a stuck driver) |
| drop | nothing: the frames are missing from the stream |
| brightness | the whole frame 60 grey levels brighter (auto-exposure jump) |
| noise | heavy sensor noise (σ = 15 grey levels, seeded by the frame index) |
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import (
    CameraIntrinsics,
    Frame,
    FrameSource,
    frame_gravity,
    ground_truth_matching,
    rebase_poses,
    source_notes,
    source_properties,
)

FAULT_KINDS = ("dark", "overexposed", "blur", "frozen", "drop", "brightness", "noise")


@dataclass(frozen=True)
class Fault:
    kind: str
    first: int  # source frame index, inclusive
    last: int  # inclusive

    def covers(self, index: int) -> bool:
        return self.first <= index <= self.last


def parse_faults(text: str) -> list[Fault]:
    """``"dark@120,blur@200:210"`` → faults; a clear `SourceError` for anything else."""
    faults = []
    for item in (part.strip() for part in text.split(",")):
        kind, at, frames = item.partition("@")
        if not at or kind not in FAULT_KINDS:
            raise SourceError(f"--inject {item!r}: expected KIND@FRAME or KIND@FIRST:LAST with KIND one of "
                              f"{', '.join(FAULT_KINDS)}")
        first_text, _, last_text = frames.partition(":")
        try:
            first = int(first_text)
            last = int(last_text) if last_text else first
        except ValueError:
            raise SourceError(f"--inject {item!r}: frames must be integers, e.g. {kind}@120 or {kind}@120:130") \
                from None
        if first < 0 or last < first:
            raise SourceError(f"--inject {item!r}: need 0 <= FIRST <= LAST")
        faults.append(Fault(kind, first, last))
    return faults


def apply_fault(kind: str, image: np.ndarray, index: int, previous: np.ndarray | None) -> np.ndarray:
    """The (H, W) uint8 image as the faulty camera delivers it (`drop` is handled by the caller)."""
    if kind == "dark":
        return (image.astype(np.float32) * 0.05).astype(np.uint8)
    if kind == "overexposed":
        return np.clip(image.astype(np.float32) * 4.0 + 60.0, 0, 255).astype(np.uint8)
    if kind == "blur":
        return cv2.GaussianBlur(image, (0, 0), 6.0)
    if kind == "frozen":
        return previous.copy() if previous is not None else image
    if kind == "brightness":
        return np.clip(image.astype(np.int16) + 60, 0, 255).astype(np.uint8)
    if kind == "noise":
        noise = np.random.default_rng(index).normal(0.0, 15.0, image.shape)
        return np.clip(image.astype(np.float32) + noise, 0, 255).astype(np.uint8)
    raise ValueError(f"unknown fault {kind!r}")


class FaultInjector:
    """A source whose frames pass through the given faults (a `FrameSource` itself)."""

    def __init__(self, source: FrameSource, faults: list[Fault]) -> None:
        selected = source.indices
        for fault in faults:
            if not any(fault.covers(i) for i in selected):
                where = "frames " + (f"{selected[0]}..{selected[-1]}" if selected else "none")
                step = selected[1] - selected[0] if len(selected) > 1 else 1
                raise SourceError(
                    f"--inject {fault.kind}@{fault.first}" + (f":{fault.last}" if fault.last != fault.first else "")
                    + f": no selected frame is affected (the run reads {where}" + (f", step {step}" if step > 1 else "")
                    + ")")
        self._source = source
        self.faults = faults
        self._dropped = {i for i in source.indices if any(f.kind == "drop" and f.covers(i) for f in faults)}
        self._kept = [position for position, i in enumerate(source.indices) if i not in self._dropped]

    @property
    def name(self) -> str:
        return self._source.name

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._source.intrinsics

    @property
    def indices(self) -> list[int]:
        return [i for i in self._source.indices if i not in self._dropped]

    @property
    def camera_height(self) -> float | None:
        return self._source.camera_height

    @property
    def properties(self) -> dict[str, str]:
        return source_properties(self._source)

    @property
    def notes(self) -> list[str]:
        return source_notes(self._source)

    @property
    def gt_matching(self) -> str | None:
        return ground_truth_matching(self._source)

    @property
    def gravity_by_frame(self) -> dict[int, np.ndarray]:
        return {i: g for i, g in frame_gravity(self._source).items() if i not in self._dropped}

    @property
    def ground_truth(self) -> np.ndarray | None:
        """The source's ground truth without the dropped frames (still relative to the first selected one,
        re-based if that one was dropped)."""
        gt = self._source.ground_truth
        if gt is None:
            return None
        return rebase_poses(gt[self._kept])

    def __len__(self) -> int:
        return len(self._kept)

    def __iter__(self) -> Iterator[Frame]:
        previous: np.ndarray | None = None
        for frame in self._source:
            if frame.index in self._dropped:
                continue
            image = frame.image
            for fault in self.faults:
                if fault.kind != "drop" and fault.covers(frame.index):
                    image = apply_fault(fault.kind, image, frame.index, previous)
            previous = image
            yield replace(frame, image=image)
