"""A folder of images (any camera), with intrinsics given or from a calibration file.

Images are the folder's ``.png .jpg .jpeg .bmp .tif .tiff`` files in natural name order (``f_2`` before
``f_10``; hidden, macOS ``._`` and empty files are skipped with a note), see `image_files`; colour images are
converted to grey, 16-bit images scaled by the bit depth their data use. Intrinsics: an ``--intrinsics
fx,fy,cx,cy`` string (`parse_intrinsics`, the image size is filled from the first image), a full
`CameraIntrinsics`, or the ``P0:`` line of a KITTI ``calib.txt`` (given, or found in the folder or its parent).
Timestamps come from a ``times.txt`` in the folder or its parent, else None. Optional ground truth in KITTI or
TUM format (by time when both sides have times, else
row i = image i).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, FrameRange
from vslam_core.sources.calibration import exact_scale, scale_hint
from vslam_core.sources.calibration_files import read_calibration
from vslam_core.sources.image_files import list_frame_files
from vslam_core.sources.kitti import (
    BadFramePolicy,
    GroundTruthFormat,
    ImageFilesSource,
    first_image,
    orientation_notes,
    read_times,
    select,
    sixteen_bit_property,
)
from vslam_core.sources.stamps import DEFAULT_GT_TOLERANCE_S, associate_ground_truth


class PartialIntrinsics(NamedTuple):
    """Pinhole intrinsics without the image size (pixels); `complete` adds it."""

    fx: float
    fy: float
    cx: float
    cy: float

    def complete(self, width: int, height: int) -> CameraIntrinsics:
        """The full `CameraIntrinsics` for images of ``width`` x ``height`` pixels."""
        return CameraIntrinsics(self.fx, self.fy, self.cx, self.cy, width=width, height=height)


def parse_intrinsics(text: str) -> PartialIntrinsics:
    """Parse ``"fx,fy,cx,cy"`` (commas and/or spaces) into `PartialIntrinsics`; `SourceError` if malformed."""
    fields = [f for f in re.split(r"[,\s]+", text.strip()) if f]
    if len(fields) != 4:
        raise SourceError(f"--intrinsics {text!r}: expected 4 numbers fx,fy,cx,cy, found {len(fields)}")
    try:
        fx, fy, cx, cy = (float(f) for f in fields)
    except ValueError:
        raise SourceError(f"--intrinsics {text!r}: fx, fy, cx and cy must be numbers") from None
    if not all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
        raise SourceError(f"--intrinsics {text!r}: fx and fy must be positive, every value finite")
    return PartialIntrinsics(fx, fy, cx, cy)


def complete_intrinsics(
    intrinsics: CameraIntrinsics | PartialIntrinsics, width: int, height: int, where: object, scalable: bool = True
) -> CameraIntrinsics:
    """Intrinsics for images of ``width`` x ``height``: a `PartialIntrinsics` is completed, a
    `CameraIntrinsics` with width/height 0 gets the size, one with another size is a `SourceError` naming both
    (and, when `scalable`, i.e. the user gave the calibration, `--calib-scale` for an exact factor)."""
    if isinstance(intrinsics, PartialIntrinsics):
        return intrinsics.complete(width, height)
    if intrinsics.width == 0 and intrinsics.height == 0:
        return replace(intrinsics, width=width, height=height)
    if (intrinsics.width, intrinsics.height) != (width, height):
        factor = exact_scale((width, height), (intrinsics.width, intrinsics.height)) if scalable else None
        raise SourceError(f"{where}: images are {width}x{height} but the intrinsics are for {intrinsics.width}x"
                          f"{intrinsics.height} ({intrinsics.origin or 'given'}){scale_hint(factor)}")
    return intrinsics


def _beside(folder: Path, name: str) -> Path | None:
    """``folder/name`` or ``folder/../name``, whichever exists first (None if neither)."""
    for candidate in (folder / name, folder.resolve().parent / name):
        if candidate.is_file():
            return candidate
    return None


def _short_name(folder: Path) -> str:
    """A file-name-safe name for the folder (``seq/image_0`` -> ``seq-image_0``)."""
    resolved = folder.resolve()
    name = resolved.name
    if re.fullmatch(r"image_?\d*|images?|frames?", name, flags=re.IGNORECASE) and resolved.parent.name:
        name = f"{resolved.parent.name}-{name}"
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name) or "folder"


class ImageFolderSource(ImageFilesSource):
    """Frames from a folder of images.

    intrinsics: `CameraIntrinsics` or `PartialIntrinsics` (e.g. from `parse_intrinsics`); the size is
    taken from the first selected image. calib: a calibration file instead (any `read_calibration` reads, lens
    included: ROS camera_info, Kalibr, OpenCV, KITTI calib.txt). With
    neither, a ``calib.txt`` in the folder or its parent is used if there is one; giving both is an error.
    ground_truth: optional KITTI or TUM poses file (``gt_format`` "auto" guesses from the columns), re-based to
    the first selected frame: a TUM file is matched to the frames by time (within ``gt_tolerance_s``) when the
    folder has a ``times.txt`` (at frame time + ``gt_time_offset_s``), else row i is image i, or row A + i with
    ``gt_rows`` (A, B) (see `associate_ground_truth`: a longer file without times is refused; ``gt_matching``
    says which). Images are decoded lazily; one of another size than the first selected is a `SourceError`.
    """

    def __init__(
        self,
        path: str | Path,
        intrinsics: CameraIntrinsics | PartialIntrinsics | None = None,
        calib: str | Path | None = None,
        ground_truth: str | Path | None = None,
        gt_format: GroundTruthFormat = "auto",
        frames: FrameRange | None = None,
        on_bad_frame: BadFramePolicy = "fail",
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        gt_time_offset_s: float = 0.0,
        gt_rows: tuple[int, int | None] | None = None,
    ):
        self._on_bad_frame = on_bad_frame
        self.folder = Path(path)
        listing = list_frame_files(self.folder)
        self._files = listing.files
        #: what the user should hear about this folder (files skipped, a calibration found by searching)
        self.notes = [note] if (note := listing.skipped_note(self.folder)) else []
        self._indices = select(frames, len(self._files), self.folder)
        self._size, self._shift = first_image(self._files, self._indices, on_bad_frame, self.folder)
        self.notes += orientation_notes(self._files, self._indices, self._size)
        self.properties = {"frame_order": listing.order_property(), **sixteen_bit_property(self._shift)}

        if intrinsics is not None and calib is not None:
            raise SourceError(f"{self.folder}: give either intrinsics or a calib file, not both")
        if intrinsics is None:
            calib_file = Path(calib) if calib is not None else _beside(self.folder, "calib.txt")
            if calib_file is None:
                raise SourceError(
                    f"{self.folder}: no camera intrinsics: give --intrinsics fx,fy,cx,cy or a calib file"
                )
            intrinsics = read_calibration(calib_file)
            if calib is None:
                intrinsics = replace(intrinsics, origin=f"{intrinsics.origin}, found beside the images")
                self.notes.append(f"camera calibration not given: using {calib_file}, found beside the images "
                                  "(give --calib FILE or --intrinsics fx,fy,cx,cy to choose)")
        self._intrinsics = complete_intrinsics(intrinsics, self._size[0], self._size[1], self.folder)

        times_file = _beside(self.folder, "times.txt")
        self._times = None if times_file is None else read_times(times_file, len(self._files))
        self._ground_truth = None
        if ground_truth is not None:
            self._ground_truth, self.gt_matching = associate_ground_truth(
                Path(ground_truth), gt_format, self.file_times, len(self._files), self._indices, gt_tolerance_s,
                self.folder, gt_time_offset_s, gt_rows)
        self._name = _short_name(self.folder)

    def __repr__(self) -> str:
        return f"ImageFolderSource({str(self.folder)!r}, frames={len(self)})"
