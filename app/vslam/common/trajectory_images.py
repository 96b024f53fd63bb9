"""The camera frames that go with a trajectory file (`vslam eval --trajectory … --images PATH`).

PATH is anything `open_source` reads as image files: a KITTI sequence folder (``image_0``, ``calib.txt``,
``times.txt``), an EuRoC, TUM monoVO or TUM RGB-D folder, or a folder of images (sorted by name). The camera
comes with the dataset, from ``--intrinsics`` / ``--calib`` or a ``calib.txt`` in the folder or its parent; a
plain folder without any is still shown, as 2-D images without a frustum. Times come from the dataset, a
``times.txt`` beside the images, or file names that are integer nanosecond stamps (EuRoC style).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics
from vslam_core.sources.euroc import is_euroc
from vslam_core.sources.folder import ImageFolderSource, PartialIntrinsics
from vslam_core.sources.kitti import ImageFilesSource, read_grey_image
from vslam_core.sources.open import open_source
from vslam_core.sources.tum_mono import is_tum_mono

#: A file name of this many digits or more is a timestamp in nanoseconds (19 digits for Unix times today).
STAMP_DIGITS = 16
#: Stands in for a camera the folder does not describe: it is never logged (the images go to a 2-D view).
_NO_CAMERA = PartialIntrinsics(1.0, 1.0, 0.0, 0.0)


@dataclass(frozen=True)
class TrajectoryImages:
    """Every image of PATH in frame order, their (len(files),) times in seconds (or None) and the camera
    (None: no pinhole known, the frames are shown in 2-D only)."""

    path: Path
    files: list[Path]
    times: np.ndarray | None
    intrinsics: CameraIntrinsics | None

    def read(self, index: int) -> np.ndarray:
        """(H, W) uint8 grey image `index` (a `SourceError` naming the file if it cannot be read)."""
        return read_grey_image(self.files[index])


def open_images(path: Path, intrinsics: str | None = None, calib: Path | None = None) -> TrajectoryImages:
    """The images of `path` (see the module docstring); `SourceError` in one line for anything else."""
    if not path.is_dir():
        raise SourceError(f"--images {path}: not a folder (give an image folder or a KITTI sequence folder)")
    if (path / "sequences").is_dir():
        raise SourceError(f"--images {path}: a KITTI dataset root; give a sequence folder, e.g. "
                          f"{path / 'sequences' / '00'}")
    if intrinsics is None and calib is None and _plain_folder_without_camera(path):
        source: ImageFilesSource = ImageFolderSource(path, intrinsics=_NO_CAMERA)
        camera = None
    else:
        opened = open_source(str(path), intrinsics=intrinsics, calib=calib)
        if not isinstance(opened, ImageFilesSource):
            raise SourceError(f"--images {path}: not a folder of image files")
        source, camera = opened, opened.intrinsics
    files = source.files
    times = source.file_times
    if times is None:
        times = stamps_from_names(files)
    return TrajectoryImages(path, files, times, camera)


def _plain_folder_without_camera(path: Path) -> bool:
    """A folder of images that is no dataset (KITTI, EuRoC, TUM monoVO) and has no ``calib.txt`` beside it."""
    if (path / "image_0").is_dir() or (path / "sequences").is_dir() or is_euroc(path) or is_tum_mono(path):
        return False
    return not any((folder / "calib.txt").is_file() for folder in (path, path.resolve().parent))


def stamps_from_names(files: list[Path]) -> np.ndarray | None:
    """(len(files),) seconds when every file name is an integer of `STAMP_DIGITS` or more digits (nanoseconds,
    as EuRoC names its frames); None otherwise."""
    if not files or not all(re.fullmatch(rf"\d{{{STAMP_DIGITS},}}", f.stem) for f in files):
        return None
    return np.array([int(f.stem) for f in files], np.float64) / 1e9
