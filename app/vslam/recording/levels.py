"""What a user chooses about a recording: its detail level and how the camera frames are stored. Kept apart from
the styles (which need the engine's result types, and through them OpenCV) so that the CLI can offer these as
options without loading either."""

from __future__ import annotations

from enum import StrEnum

#: The recorded frames' default JPEG quality: KITTI 00 / 05 frames 0:300 at 38 / 42 KB a frame, PSNR 35.3 / 34.4 dB
#: against the source (q75: 57 / 63 KB, 37.8 / 36.9 dB; docs/recordings.md).
JPEG_QUALITY = 50


class Detail(StrEnum):
    FULL = "full"
    STANDARD = "standard"
    SUMMARY = "summary"
    OFF = "off"


class ImageCodec(StrEnum):
    """How the camera frames are recorded: JPEG images, or an AV1 / H.264 video stream (`vslam.recording.video`)."""

    JPEG = "jpeg"
    AV1 = "av1"
    H264 = "h264"
