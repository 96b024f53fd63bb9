"""What a user chooses about a recording: its detail level and how the camera frames are stored. Kept apart from
the styles (which need the engine's result types, and through them OpenCV) so that the CLI can offer these as
options without loading either."""

from __future__ import annotations

from enum import StrEnum

#: The recorded frames' default JPEG quality: a KITTI frame ~37 KB at 35.0 dB PSNR against the source (q75: ~60 KB,
#: 37.4 dB; KITTI 05 frames 0:60, docs/recordings.md).
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
