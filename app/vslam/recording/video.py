"""`--image-codec`: the recorded camera frames as JPEG images (`encode_jpeg`) or as a Rerun `VideoStream` (AV1
or H.264, encoded with PyAV).

A video stream is one static `VideoStream(codec=...)` and one `sample` per frame on the `frame` and `time`
timelines. AV1 samples are in the low-overhead OBU format with a sequence header before every key frame,
H.264 samples in Annex B with SPS/PPS before every IDR frame (what Rerun asks for: verified by decoding
and by the viewer). No B-frames, no look-ahead: each frame comes out of the encoder as its own packet, so
a sample sits at its frame's time. A key frame every `GOP_FRAMES` frames keeps scrubbing fast (the viewer
decodes from the previous key frame).
"""

from __future__ import annotations

import os
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import cv2
import numpy as np
import rerun as rr

from vslam.common import RecordingError
from vslam.recording.levels import ImageCodec, scaled_size
from vslam_core.sources.base import Frame

#: OpenCV hands a resize of more output pixels than this to its thread pool, whose threads then spin on the
#: engine's cores (~0.6 ms of CPU a KITTI frame, docs/recordings.md); a smaller one runs on the calling thread.
INLINE_RESIZE_PIXELS = 1 << 16


def encode_jpeg(image: np.ndarray, scale: float, quality: int, what: str = "a frame") -> bytes:
    """An image, (H, W) or (H, W, 3) uint8, as JPEG at `quality`, at `scale` of its size (area-averaged);
    `what` it is names it in the error."""
    if scale != 1.0:
        image = resize_area(image, scaled_size(image.shape[1], image.shape[0], scale))
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RecordingError(f"JPEG encoding of {what} failed")
    return bytes(jpeg.tobytes())


def resize_area(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`cv2.resize(image, size, interpolation=cv2.INTER_AREA)` bit for bit, on the calling thread: in bands of
    fewer than `INLINE_RESIZE_PIXELS` output pixels when the height shrinks by a whole factor (each band's rows
    then average the same source rows as in one call; checked on KITTI's and TUM's frames in
    tests/test_codec.py), else in one call."""
    width, height = size
    factor, rest = divmod(image.shape[0], height)
    rows = max(1, (INLINE_RESIZE_PIXELS - 1) // width)
    if rest or rows >= height:
        return cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    resized = np.empty((height, width, *image.shape[2:]), image.dtype)
    for top in range(0, height, rows):
        bottom = min(height, top + rows)
        resized[top:bottom] = cv2.resize(image[top * factor : bottom * factor], (width, bottom - top),
                                         interpolation=cv2.INTER_AREA)
    return resized


#: Frames between key frames: 2 s at KITTI's 10 Hz.
GOP_FRAMES = 20
#: Buffered samples are sent once they hold this much (and on `flush`).
FLUSH_BYTES = 2**20


@dataclass(frozen=True)
class VideoSettings:
    """One encoder configuration: the FFmpeg encoder and its options."""

    encoder: str
    options: dict[str, str] = field(default_factory=dict)


#: The encoder settings of each video codec (chosen from benchmarks/codecs.py; see docs/recordings.md).
VIDEO_SETTINGS: dict[ImageCodec, VideoSettings] = {
    # preset 13 on one thread (lp=1: beside the engine, not across both cores): KITTI 05 frames 0:300 at 24.8 KB a
    # frame, 34.8 dB, 13–16 ms of CPU a frame; preset 10 (the setting until issue 56) 22.1 KB, 35.1 dB, 34–36 ms
    ImageCodec.AV1: VideoSettings("libsvtav1", {"preset": "13", "crf": "41",
                                                "svtav1-params": "pred-struct=1:lookahead=0:rtc=1:lp=1"}),
    ImageCodec.H264: VideoSettings("libx264", {"preset": "faster", "crf": "25", "tune": "zerolatency",
                                               "bf": "0"}),
}

RERUN_CODEC = {ImageCodec.AV1: rr.VideoCodec.AV1, ImageCodec.H264: rr.VideoCodec.H264}


def open_encoder(settings: VideoSettings, width: int, height: int, gop: int = GOP_FRAMES) -> Any:
    """A PyAV encoder for `width`×`height` yuv420p frames (even sizes: see `to_video_frame`), full range."""
    import av  # imported here: a JPEG run never needs it

    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its configuration to stderr unless told not to

    if settings.encoder not in av.codecs_available:
        raise RecordingError(f"this PyAV build has no {settings.encoder} encoder (pip install 'av>=12')")
    context: Any = av.CodecContext.create(settings.encoder, "w")
    context.width, context.height = width, height
    context.pix_fmt = "yuv420p"
    context.time_base = Fraction(1, 10)
    context.framerate = Fraction(10, 1)
    context.gop_size = gop
    context.max_b_frames = 0
    context.color_range = 2  # full range (JPEG): grey levels go into Y unchanged
    context.options = dict(settings.options)
    context.open()
    return context


def even(size: int) -> int:
    return size + size % 2


def to_video_frame(image: np.ndarray, pts: int) -> Any:
    """A yuv420p frame of a grey (or BGR) image, padded to even width and height by repeating the last
    column/row (4:2:0 needs even sizes; KITTI frames are 1241 wide). Grey: Y = the pixels, neutral chroma."""
    import av

    if image.ndim == 3:
        image = np.asarray(image[:, :, :3])
    pad = ((0, image.shape[0] % 2), (0, image.shape[1] % 2)) + (((0, 0),) if image.ndim == 3 else ())
    if any(p[1] for p in pad):
        image = np.pad(image, pad, mode="edge")
    if image.ndim == 3:
        frame = av.VideoFrame.from_ndarray(image, format="bgr24").reformat(format="yuv420p", dst_color_range=2)
    else:
        height, width = image.shape
        chroma = np.full((height // 2, width), 128, np.uint8)
        frame = av.VideoFrame.from_ndarray(np.concatenate([image, chroma]), format="yuv420p")
    frame.pts = pts
    frame.color_range = 2
    return frame


Packets = list[tuple[bytes, bool, int]]  # sample, key frame, pts


class VideoEntity:
    """One entity's frames as a `VideoStream`: encoded (on `executor` if given, in order) and buffered, sent
    with one `send_columns` per ~`FLUSH_BYTES` and on `flush`."""

    def __init__(self, rec: rr.RecordingStream, entity: str, codec: ImageCodec,
                 executor: Executor | None = None) -> None:
        self._rec, self._entity, self._settings = rec, entity, VIDEO_SETTINGS[codec]
        self._executor = executor
        self._context: Any = None
        self._frames: dict[int, tuple[int, float | None]] = {}  # pts -> (frame index, timestamp)
        self._pending: list[Future[Packets] | Packets] = []
        self._pending_frames = 0
        self._next_pts = 0
        rec.log(entity, rr.VideoStream(codec=RERUN_CODEC[codec]), static=True)

    def add(self, frame: Frame, image: np.ndarray) -> None:
        pts = self._next_pts
        self._next_pts += 1
        self._frames[pts] = (frame.index, frame.timestamp)
        job = (self._executor.submit(self._encode, image, pts) if self._executor is not None
               else self._encode(image, pts))
        self._pending.append(job)
        self._pending_frames += 1
        if self._pending_frames * 40_000 >= FLUSH_BYTES:  # ~40 KB a frame
            self.flush()

    def _encode(self, image: np.ndarray | None, pts: int) -> Packets:
        if image is None:
            return [(bytes(p), bool(p.is_keyframe), int(p.pts)) for p in self._context.encode(None)]
        if self._context is None:
            self._context = open_encoder(self._settings, even(image.shape[1]), even(image.shape[0]))
        return [(bytes(p), bool(p.is_keyframe), int(p.pts)) for p in self._context.encode(to_video_frame(image, pts))]

    def flush(self, final: bool = False) -> None:
        """Send the encoded samples; `final` also drains the encoder (call once, at the end)."""
        packets: Packets = []
        for job in self._pending:
            packets += job.result() if isinstance(job, Future) else job
        if final and self._context is not None:
            packets += self._encode(None, -1)
        self._pending, self._pending_frames = [], 0
        if not packets:
            return
        from vslam.recording.columns import time_column

        frames = [self._frames.pop(pts) for _, _, pts in packets]
        indexes = [rr.TimeColumn("frame", sequence=[f for f, _ in frames])]
        times = [t for _, t in frames if t is not None]
        if len(times) == len(frames):
            indexes.append(time_column(times))
        self._rec.send_columns(self._entity, indexes=indexes, columns=rr.VideoStream.columns(
            sample=[b for b, _, _ in packets], is_keyframe=[k for _, k, _ in packets]))
