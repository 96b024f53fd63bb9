"""The one small interface every data source implements.

A source yields `Frame`s (index in the source, timestamp, grey image), knows its camera intrinsics and
may know ground truth. Frames are selected with a `FrameRange` (Python slice semantics on the source's
own frame indices: ``0:300`` is frames 0..299; an END past the last frame is clamped to it, and only a
range that selects no frame is an error).

Ground truth, when present, is an (N, 4, 4) array of camera-to-world poses T_w_c for the N *selected*
frames, re-based so that the first selected frame is the identity (world = camera frame of the first
frame, see ../shared/docs/conventions.md).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from vslam_core.errors import SourceError

#: Lens distortion models: OpenCV's and ROS's names (Kalibr's ``radtan``/``equidistant`` map onto them).
DistortionModel = Literal["none", "plumb_bob", "rational_polynomial", "equidistant", "fov"]
#: How many coefficients each model takes (plumb_bob: k1 k2 p1 p2 [k3]; rational: k1 k2 p1 p2 k3 k4 k5 k6;
#: equidistant: k1 k2 k3 k4, the Kannala–Brandt fisheye of cv2.fisheye; fov: ω, the field-of-view model of
#: Devernay & Faugeras used by TUM monoVO).
DISTORTION_COEFFICIENTS: dict[str, tuple[int, ...]] = {
    "none": (0,), "plumb_bob": (4, 5), "rational_polynomial": (8,), "equidistant": (4,), "fov": (1,),
}


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera's pinhole intrinsics (pixels) and its lens distortion.

    The distortion maps ideal pinhole pixels (K) to the raw image's pixels; ``model="none"`` is a rectified
    camera. `vslam_core.lens` undistorts tracked points with it. ``origin`` says where the calibration came
    from (e.g. ``CameraInfo /cam/camera_info`` or a file name), for the recording.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    model: DistortionModel = "none"
    coefficients: tuple[float, ...] = ()
    origin: str = field(default="", compare=False)  # provenance, not geometry: equal cameras stay equal

    def __post_init__(self) -> None:
        allowed = DISTORTION_COEFFICIENTS.get(self.model)
        if allowed is None:
            raise SourceError(f"unknown lens distortion model {self.model!r} (known: "
                              f"{', '.join(DISTORTION_COEFFICIENTS)})")
        if len(self.coefficients) not in allowed:
            raise SourceError(f"lens model {self.model} takes {' or '.join(map(str, allowed))} coefficients, "
                              f"got {len(self.coefficients)}")

    @property
    def distorted(self) -> bool:
        """True when the lens bends lines (a model other than ``none`` with a non-zero coefficient)."""
        return self.model != "none" and any(c != 0.0 for c in self.coefficients)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the standard name of the matrix
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Frame:
    """One input frame.

    index: the frame's index in its source (KITTI image number, video frame number).
    timestamp: seconds on the source's clock, or None when the source has no clock: since the start for
        KITTI times.txt, videos and the synthetic street; Unix time for ROS logs, EuRoC and TUM monoVO.
    image: (H, W) uint8 grey image.
    defect: why the frame's image is unusable (e.g. a corrupt file skipped with --on-bad-frame skip).
    """

    index: int
    timestamp: float | None
    image: np.ndarray
    defect: str | None = None  # set when the image could not be read (image is then a black placeholder)


@dataclass(frozen=True)
class FrameRange:
    """A START:END[:STEP] selection of a source's frames (end exclusive, like a Python slice)."""

    start: int | None = None
    end: int | None = None
    step: int = 1

    @classmethod
    def parse(cls, text: str | None) -> FrameRange:
        """Parse ``"A:B"``, ``"A:B:S"``, ``":B"``, ``"A:"``; None or empty means every frame."""
        if text is None or text.strip() == "":
            return cls()
        parts = text.strip().split(":")
        if len(parts) not in (2, 3):
            raise SourceError(f"--frames {text!r}: expected START:END[:STEP], e.g. 0:300 or 0:300:2")
        try:
            values = [int(p) if p.strip() else None for p in parts]
        except ValueError:
            raise SourceError(f"--frames {text!r}: START, END and STEP must be integers") from None
        start, end = values[0], values[1]
        step = values[2] if len(values) == 3 and values[2] is not None else 1
        if step < 1:
            raise SourceError(f"--frames {text!r}: STEP must be at least 1")
        if (start is not None and start < 0) or (end is not None and end < 0):
            raise SourceError(f"--frames {text!r}: negative frame numbers are not supported")
        if start is not None and end is not None and end <= start:
            raise SourceError(f"--frames {text!r}: selects no frame (END must be greater than START; END is "
                              "excluded)")
        return cls(start, end, step)

    def indices(self, available: int) -> list[int]:
        """The selected source indices among ``range(available)``. END past the last frame is clamped to the
        source's length, as a Python slice is; a range that selects nothing (START at or past the end) is
        a `SourceError`."""
        start = 0 if self.start is None else self.start
        end = available if self.end is None else min(self.end, available)
        if start >= available:
            raise SourceError(
                f"--frames {self}: selects no frame, the source has {available} frames (0:{available})"
            )
        return list(range(start, end, self.step))

    def __str__(self) -> str:
        start = "" if self.start is None else str(self.start)
        end = "" if self.end is None else str(self.end)
        return f"{start}:{end}" + (f":{self.step}" if self.step != 1 else "")


@runtime_checkable
class FrameSource(Protocol):
    """What the engine and the CLI need from any source of frames."""

    @property
    def name(self) -> str:
        """Short name for file names and recording titles, e.g. ``kitti-00`` or ``synthetic-street``."""
        ...

    @property
    def intrinsics(self) -> CameraIntrinsics: ...

    @property
    def ground_truth(self) -> np.ndarray | None:
        """(N, 4, 4) T_w_c for the selected frames (first = identity), or None."""
        ...

    @property
    def indices(self) -> list[int]:
        """The source frame indices of the selected frames, in order (len = N)."""
        ...

    @property
    def camera_height(self) -> float | None:
        """The camera's height above the road in metres, when the source knows it (for --scale height)."""
        ...

    def __len__(self) -> int:
        """Number of selected frames."""
        ...

    def __iter__(self) -> Iterator[Frame]: ...


class SelectedSource:
    """The `FrameSource` properties of a source that has chosen its frames: a subclass sets ``_name``,
    ``_intrinsics``, ``_ground_truth`` ((N, 4, 4) T_w_c of the selected frames, re-based, or None) and
    ``_indices`` (the selected source indices) in its constructor, ``_camera_height`` when it knows it, and
    implements ``__iter__``."""

    _name: str
    _intrinsics: CameraIntrinsics
    _ground_truth: np.ndarray | None
    _indices: list[int]
    _camera_height: float | None = None
    #: how the ground truth was paired with the frames, e.g. ``matched by time, 200 of 200 frames, tolerance
    #: 10 ms`` or ``row by row`` (None without ground truth)
    gt_matching: str | None = None

    @property
    def name(self) -> str:
        """Short name for file names and recording titles."""
        return self._name

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def ground_truth(self) -> np.ndarray | None:
        """(N, 4, 4) T_w_c of the selected frames (first = identity), or None."""
        return None if self._ground_truth is None else self._ground_truth.copy()

    @property
    def indices(self) -> list[int]:
        """The source indices of the selected frames, in order."""
        return list(self._indices)

    @property
    def camera_height(self) -> float | None:
        """The camera's height above the road in metres, when the source knows it."""
        return self._camera_height

    def __len__(self) -> int:
        return len(self._indices)


def source_properties(source: FrameSource) -> dict[str, str]:
    """A source's own run properties (a log's topic and stamp source, …), if it has any: a source may have a
    ``properties`` attribute (dict[str, str]); the calibration is described separately."""
    return dict(getattr(source, "properties", {}) or {})


def ground_truth_matching(source: FrameSource) -> str | None:
    """How a source paired its ground truth with its frames (an optional ``gt_matching`` attribute), e.g.
    ``matched by time, 200 of 200 frames, tolerance 10 ms`` or ``row by row``; None without ground truth."""
    return getattr(source, "gt_matching", None) if source.ground_truth is not None else None


def frame_gravity(source: FrameSource) -> dict[int, np.ndarray]:
    """A source's accelerometer per frame (an optional ``gravity_by_frame`` attribute): source frame index ->
    (3,) the mean specific force over the frame's interval, as gravity in the camera frame (x right, y down,
    z forward; m/s²). Empty when the source has no accelerometer."""
    return dict(getattr(source, "gravity_by_frame", None) or {})


def source_notes(source: FrameSource) -> list[str]:
    """What a source noticed about its input that the user should hear (out-of-order stamps, receive times
    used for missing header stamps, …): an optional ``notes`` attribute (list[str])."""
    return list(getattr(source, "notes", []) or [])


def rebase_poses(poses: np.ndarray) -> np.ndarray:
    """Express (N, 4, 4) camera-to-world poses in the camera frame of the first one: T_0^-1 · T_i."""
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"expected (N, 4, 4) poses, got {poses.shape}")
    if len(poses) == 0:
        return poses.copy()
    first_inv = np.linalg.inv(poses[0])
    return np.einsum("ij,njk->nik", first_inv, poses)


def describe_indices(indices: list[int]) -> str:
    """What a list of selected source indices covers, as the START:END[:STEP] that gives it (``0:300``,
    ``0:300:2``); ``A..B (N frames)`` when it is not evenly spaced (e.g. frames dropped); ``none`` if empty."""
    if not indices:
        return "none"
    first, last = indices[0], indices[-1]
    steps = {b - a for a, b in zip(indices, indices[1:], strict=False)}
    if len(steps) <= 1:
        step = steps.pop() if steps else 1
        return f"{first}:{last + 1}" + (f":{step}" if step != 1 else "")
    return f"{first}..{last} ({len(indices)} frames)"


def is_utf8_path(path: str | os.PathLike[str]) -> bool:
    """True when `path` is valid UTF-8 (a name holding other bytes comes into Python as lone surrogates, which
    OpenCV's and Rerun's file functions cannot take: OpenCV crashes on them)."""
    try:
        os.fspath(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def shown_path(path: str | os.PathLike[str]) -> str:
    """`path` for a message: its bytes that are not UTF-8 written as ``\\xff`` escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def safe_name(text: str, fallback: str) -> str:
    """`text` for a file name: each run of characters other than letters, digits, '.', '_' and '-' becomes one '_',
    leading and trailing '_' are dropped, and `fallback` stands in for what is left empty."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or fallback
