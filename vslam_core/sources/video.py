"""A video file read with OpenCV's `cv2.VideoCapture` (any container/codec the installed backend reads).

Frame count: ``CAP_PROP_FRAME_COUNT`` comes from the container header and is unreliable: for many
formats it is an estimate (duration x fps), it is 0 or -1 for streamed/unindexed files and off by a few
frames for variable-frame-rate ones. Frame numbers matter here (``FrameRange`` and the ground truth are
indexed by them), so the source counts the frames exactly by reading through the file once with
``grab()`` when it is opened (the frames are decoded but not converted, not kept; roughly the cost of one
decoding pass) and records each frame's timestamp on the way.

Timestamps: ``CAP_PROP_POS_MSEC`` of each frame when those increase strictly, else frame / fps when
the fps is known, else None. Colour frames are converted to grey. Frames are decoded lazily in
``__iter__`` (frames outside the selection are skipped with ``grab()``).

Orientation: frames are read as the sensor stored them, a container's rotation (an MP4's display matrix, a
phone's portrait video) not applied (``CAP_PROP_ORIENTATION_AUTO`` = 0), since a calibration describes the
sensor's pixels; ``notes`` says so when the container had one.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, SelectedSource, is_utf8_path, shown_path
from vslam_core.sources.folder import PartialIntrinsics, complete_intrinsics
from vslam_core.sources.kitti import GroundTruthFormat, select
from vslam_core.sources.stamps import DEFAULT_GT_TOLERANCE_S, associate_ground_truth


def _to_grey(frame: np.ndarray) -> np.ndarray:
    """A decoded frame (H, W), (H, W, 1), (H, W, 3) BGR or (H, W, 4) BGRA -> (H, W) uint8 grey."""
    if frame.dtype == np.uint16:
        frame = (frame // 257).astype(np.uint8)
    elif frame.dtype != np.uint8:
        frame = np.clip(frame, 0, 255).astype(np.uint8)
    if frame.ndim == 2:
        return frame
    if frame.shape[2] == 1:
        return frame[:, :, 0]
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)


class VideoSource(SelectedSource):
    """Frames of a video file.

    intrinsics: `CameraIntrinsics` or `PartialIntrinsics` (e.g. ``parse_intrinsics("fx,fy,cx,cy")``);
    the size comes from the video. frames: the selection (video frame numbers, default all).
    ground_truth: optional KITTI/TUM poses file, re-based to the first selected frame: a TUM file is matched by
    time (within ``gt_tolerance_s``) to the container's frame times, else row i = video frame i (see
    `associate_ground_truth`; ``gt_matching`` says which); without it ``ground_truth`` is None.
    """

    def __init__(
        self,
        path: str | Path,
        intrinsics: CameraIntrinsics | PartialIntrinsics,
        frames: FrameRange | None = None,
        ground_truth: str | Path | None = None,
        gt_format: GroundTruthFormat = "auto",
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        gt_time_offset_s: float = 0.0,
        gt_rows: tuple[int, int | None] | None = None,
    ):
        self.path = Path(path)
        if not self.path.is_file():
            raise SourceError(f"{self.path}: video file not found")
        if not is_utf8_path(self.path):  # cv2.VideoCapture crashes the process on such a path
            raise SourceError(f"{shown_path(self.path)}: OpenCV cannot open a video whose path is not valid UTF-8; "
                              "rename the file (or its folder)")
        capture = self._open()
        try:
            ok, first = capture.read()
            if not ok or first is None:
                raise SourceError(f"{self.path}: the video has no readable frame")
            grey = _to_grey(first)
            self._size = (grey.shape[1], grey.shape[0])
            fps = float(capture.get(cv2.CAP_PROP_FPS))
            stamps_ms = [float(capture.get(cv2.CAP_PROP_POS_MSEC))]
            rotation = float(capture.get(cv2.CAP_PROP_ORIENTATION_META))
            while capture.grab():
                stamps_ms.append(float(capture.get(cv2.CAP_PROP_POS_MSEC)))
        finally:
            capture.release()
        self._count = len(stamps_ms)
        #: what the user should hear about this video (a display rotation not applied)
        self.notes = [] if not math.isfinite(rotation) or rotation % 360 == 0 else [
            f"{self.path.name}: the container says to show the frames rotated {rotation:g}° (a display matrix): "
            f"not applied, the frames are read as the sensor stored them, {self._size[0]}x{self._size[1]}, the "
            "calibration's pixels"]
        self._container_times = self._increasing(stamps_ms)
        self._times = self._timestamps(stamps_ms, fps)
        self.fps = fps if math.isfinite(fps) and fps > 0 else None
        self._indices = select(frames, self._count, self.path)
        self._intrinsics = complete_intrinsics(intrinsics, self._size[0], self._size[1], self.path)
        self._ground_truth = None
        if ground_truth is not None:  # by time on the container's clock (a frame rate alone is no clock)
            clock = None if self._times is None or not self._container_times else np.asarray(self._times)
            self._ground_truth, self.gt_matching = associate_ground_truth(
                Path(ground_truth), gt_format, clock, self._count, self._indices, gt_tolerance_s, self.path,
                gt_time_offset_s, gt_rows)
        self._name = "video-" + (re.sub(r"[^A-Za-z0-9._-]+", "_", self.path.stem) or "video")

    def _open(self) -> cv2.VideoCapture:
        capture = cv2.VideoCapture(str(self.path))
        if not capture.isOpened():
            capture.release()
            raise SourceError(f"{self.path}: cannot open the video (not a video, or a codec OpenCV lacks)")
        capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)  # the stored pixels: see the module docstring
        return capture

    @staticmethod
    def _increasing(stamps_ms: list[float]) -> bool:
        """The container's frame times are usable: finite, from 0 on, strictly increasing."""
        stamps = np.asarray(stamps_ms)
        return bool(np.all(np.isfinite(stamps)) and stamps[0] >= 0 and np.all(np.diff(stamps) > 0))

    @classmethod
    def _timestamps(cls, stamps_ms: list[float], fps: float) -> list[float] | None:
        """Seconds per frame: the container's when they increase strictly, else frame / fps, else None."""
        if cls._increasing(stamps_ms):
            return [s / 1000.0 for s in stamps_ms]
        if math.isfinite(fps) and fps > 0:
            return [i / fps for i in range(len(stamps_ms))]
        return None

    @property
    def frame_count(self) -> int:
        """Frames in the whole video (counted when opened)."""
        return self._count

    def __iter__(self) -> Iterator[Frame]:
        wanted = set(self._indices)
        last = self._indices[-1]
        capture = self._open()
        try:
            for index in range(last + 1):
                if index not in wanted:
                    if not capture.grab():
                        raise SourceError(f"{self.path}: frame {index} cannot be read (the video changed?)")
                    continue
                ok, frame = capture.read()
                if not ok or frame is None:
                    raise SourceError(f"{self.path}: frame {index} cannot be decoded")
                image = _to_grey(frame)
                if (image.shape[1], image.shape[0]) != self._size:
                    raise SourceError(
                        f"{self.path}: frame {index} is {image.shape[1]}x{image.shape[0]}, "
                        f"the first frame is {self._size[0]}x{self._size[1]}"
                    )
                stamp = None if self._times is None else self._times[index]
                yield Frame(index=index, timestamp=stamp, image=image)
        finally:
            capture.release()

    def __repr__(self) -> str:
        return f"VideoSource({str(self.path)!r}, frames={len(self)})"
