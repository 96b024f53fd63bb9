"""Detail levels, and the colours and legends shared by the entities, the plots and the blueprint."""

from __future__ import annotations

from enum import StrEnum

from vslam_core.results import TrackFate

APPLICATION_ID = "vslam"


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


# Legend of the flow arrows: one annotation context, so the viewer explains the colours.
FATE_STYLE: dict[TrackFate, tuple[str, tuple[int, int, int]]] = {
    TrackFate.LOST: ("lost (KLT failed / left image)", (120, 120, 120)),
    TrackFate.FB_REJECTED: ("rejected by forward–backward check", (255, 140, 0)),
    TrackFate.NOT_USED: ("tracked, no keyframe position yet", (80, 160, 255)),
    TrackFate.RANSAC_OUTLIER: ("RANSAC outlier", (230, 30, 30)),
    TrackFate.CHIRALITY_FAILED: ("failed chirality (behind a camera)", (200, 0, 200)),
    TrackFate.INLIER: ("inlier", (40, 220, 60)),
}
NEW_CORNER_COLOUR = (255, 230, 0)
CANDIDATE_COLOURS = [(255, 200, 0), (0, 200, 255), (255, 0, 160), (160, 255, 0)]
ROAD_COLOUR = (255, 120, 220)
AXIS_COLOURS = [(255, 60, 60), (60, 255, 60), (60, 120, 255)]  # x, y, z of each candidate's camera
CAR_COLOUR = (230, 230, 230)
ESTIMATE_COLOUR = (255, 80, 80)
GROUND_TRUTH_COLOUR = (80, 255, 120)
