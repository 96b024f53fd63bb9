"""Data sources: KITTI sequences, image folders, video files and a synthetic street.

Every source implements `FrameSource` (see base.py): name, intrinsics, ground_truth, len, iteration of
`Frame`s decoded lazily. The names below are imported on first use (PEP 562): importing one source module
(e.g. `vslam_core.sources.stamps`) does not load OpenCV and every other reader.
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

_HOMES = {
    "CameraIntrinsics": "base", "Frame": "base", "FrameRange": "base", "FrameSource": "base", "rebase_poses": "base",
    "ImageFolderSource": "folder", "PartialIntrinsics": "folder", "parse_intrinsics": "folder",
    "KittiSource": "kitti", "VideoSource": "video", "SyntheticStreet": "synthetic",
}

if TYPE_CHECKING:
    from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, FrameSource, rebase_poses
    from vslam_core.sources.folder import ImageFolderSource, PartialIntrinsics, parse_intrinsics
    from vslam_core.sources.kitti import KittiSource
    from vslam_core.sources.synthetic import SyntheticStreet
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


__getattr__ = lazy_names(__name__, _HOMES)
