"""Data sources: KITTI sequences, image folders, video files and a synthetic street.

Every source implements `FrameSource` (see base.py): name, intrinsics, ground_truth, len, iteration of
`Frame`s decoded lazily.
"""

from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, FrameSource, rebase_poses
from vslam_core.sources.folder import ImageFolderSource, PartialIntrinsics, parse_intrinsics
from vslam_core.sources.kitti import KittiSource
from vslam_core.sources.video import VideoSource

__all__ = [
    "CameraIntrinsics",
    "Frame",
    "FrameRange",
    "FrameSource",
    "ImageFolderSource",
    "KittiSource",
    "PartialIntrinsics",
    "SyntheticStreet",
    "VideoSource",
    "parse_intrinsics",
    "rebase_poses",
]

from vslam_core.sources.synthetic import SyntheticStreet  # noqa: E402 - written separately, kept last
