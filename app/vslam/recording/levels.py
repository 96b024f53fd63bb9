"""What a user chooses about a recording: its detail level and how the camera frames are stored. Kept apart from
the styles (which need the engine's result types, and through them OpenCV) so that the CLI can offer these as
options without loading either."""

from __future__ import annotations

from enum import StrEnum


class Detail(StrEnum):
    FULL = "full"
    STANDARD = "standard"
    SUMMARY = "summary"
    OFF = "off"


#: The detail of a recording unless told otherwise: `standard`, the frame (at half size) with every overlay, plots
#: and events, for drives of hours: 21.8 KB a frame with `vo`, 29.2 with `map` (KITTI 05 at 10 Hz,
#: docs/recordings.md); `full` (the frame at its own size, the 3-D points of every frame, the per-track and
#: per-landmark hover values, BA residuals, the undistorted frame) 55.0 / 67.6 KB.
DEFAULT_DETAIL = Detail.STANDARD


#: The size the camera frame is recorded at (`--image-codec jpeg`), as a fraction of the source's: at `standard`
#: half (a quarter of the pixels: the default layout draws a KITTI frame at about half size anyway), drawn over
#: the pinhole's whole image plane so that every overlay stays in the source's pixels; at `full` the source's own.
IMAGE_SCALE: dict[Detail, float] = {Detail.FULL: 1.0, Detail.STANDARD: 0.5, Detail.SUMMARY: 1.0, Detail.OFF: 1.0}

#: The recorded frames' default JPEG quality at full size, the lowest whose worst frame stays at ~32 dB PSNR
#: against the source: KITTI 05 frames 0:300 at 36.5 KB a frame, 33.6 dB (worst frame 31.9); q50 42.0 KB, 34.4 dB
#: (32.7); q30 30.8 KB, 32.7 dB (30.9) (docs/recordings.md).
JPEG_QUALITY = 40
#: ...and at half size, where the halving, not the JPEG, sets the fidelity against the source (27.3 dB at q30,
#: 27.7 at q40, 28.0 at q50, the frame drawn with linear filtering; 26.7 at q20): 10.1 KB a frame (q40 11.9).
HALF_SIZE_JPEG_QUALITY = 30


def default_jpeg_quality(detail: Detail) -> int:
    """The JPEG quality of the frames recorded at `detail` unless told otherwise (`--jpeg-quality`)."""
    return HALF_SIZE_JPEG_QUALITY if IMAGE_SCALE[detail] < 1.0 else JPEG_QUALITY


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """(width, height) of a frame stored at `scale` of (width, height), at least one pixel each."""
    return max(1, round(width * scale)), max(1, round(height * scale))


class ImageCodec(StrEnum):
    """How the camera frames are recorded: JPEG images, or an AV1 / H.264 video stream (`vslam.recording.video`)."""

    JPEG = "jpeg"
    AV1 = "av1"
    H264 = "h264"
