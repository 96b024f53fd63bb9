"""What a user chooses about a recording: its detail level and how the camera frames are stored. Kept apart from
the styles (which need the engine's result types, and through them OpenCV) so that the CLI can offer these as
options without loading either."""

from __future__ import annotations

from enum import StrEnum

#: The recorded frames' default JPEG quality, the lowest whose worst frame stays at ~32 dB PSNR against the source:
#: KITTI 05 frames 0:300 at 36.5 KB a frame, 33.6 dB (worst frame 31.9); q50 42.0 KB, 34.4 dB (32.7); q30 30.8 KB,
#: 32.7 dB (30.9) (docs/recordings.md).
JPEG_QUALITY = 40


class Detail(StrEnum):
    FULL = "full"
    STANDARD = "standard"
    SUMMARY = "summary"
    OFF = "off"


#: The detail of a recording unless told otherwise: `standard`, the frame with every overlay, plots and events, for
#: drives of hours; `full` (the 3-D points of every frame, the per-track and per-landmark hover values, BA
#: residuals, the undistorted frame) costs ~6.5 KB a frame more with `vo` and ~10 KB with `map` (KITTI 05 at 10 Hz,
#: docs/recordings.md).
DEFAULT_DETAIL = Detail.STANDARD


class ImageCodec(StrEnum):
    """How the camera frames are recorded: JPEG images, or an AV1 / H.264 video stream (`vslam.recording.video`)."""

    JPEG = "jpeg"
    AV1 = "av1"
    H264 = "h264"
