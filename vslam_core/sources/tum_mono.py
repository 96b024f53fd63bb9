"""TUM monoVO sequences (Engel, Usenko, Cremers, "A Photometrically Calibrated Benchmark For Monocular Visual
Odometry", 2016), and any folder in DSO's dataset layout.

Layout::

    SEQ/images/00000.jpg …     8-bit grey frames (vignetted; images.zip must be unzipped first)
    SEQ/times.txt              ``id timestamp exposure`` a line (id = the image's name, timestamp in seconds)
    SEQ/camera.txt             line 1 the lens: ``fx fy cx cy omega`` (FOV model; omega 0 = pinhole), or
                               DSO's ``FOV|Pinhole fx fy cx cy omega`` / ``RadTan|EquiDistant|KannalaBrandt
                               fx fy cx cy k1 k2 k3 k4`` (8 unprefixed numbers = RadTan); line 2 ``width
                               height`` of the images; lines 3–4 DSO's rectified output (ignored: vslam
                               undistorts tracked points, not images)
    SEQ/groundtruthSync.txt    TUM poses for the start and end segments only (NaN elsewhere): not used unless
                               given as the ground truth

Relative calibrations follow DSO's ``Undistort::readFromFile``: when cx < 1 and cy < 1 the four values are
fractions of the image size, converted to pixels as fx·w, fy·h, cx·w − 0.5, cy·h − 0.5 (the −0.5 moves the
origin from the corner of pixel (0, 0) to its centre, OpenCV's and vslam's convention). Larger values are
pixels already. The photometric calibration (pcalib.txt response, vignette.png) and the exposure times are
not applied.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, FrameRange, safe_name
from vslam_core.sources.calibration import make_intrinsics
from vslam_core.sources.image_files import list_frame_files
from vslam_core.sources.kitti import BadFramePolicy, ImageFilesSource, first_image, orientation_notes, select
from vslam_core.sources.stamps import (
    DEFAULT_GT_TOLERANCE_S,
    optional_tum_camera_poses,
    parse_stamp,
    stamp_problems,
    stamped_lines,
)

#: DSO's camera.txt prefixes (lower case) → (our model name, how many numbers follow).
CAMERA_PREFIXES: dict[str, tuple[str, int]] = {
    "fov": ("fov", 5), "pinhole": ("none", 5), "radtan": ("plumb_bob", 8), "equidistant": ("equidistant", 8),
    "kannalabrandt": ("equidistant", 8),
}
#: The photometric calibration files of a TUM monoVO sequence (not applied: the images are used as recorded).
PHOTOMETRIC_FILES = ("pcalib.txt", "vignette.png")


def sequence_folder(path: str | Path) -> Path | None:
    """The sequence folder of a TUM monoVO / DSO layout given the sequence folder or its ``images/``
    folder (None when `path` is neither)."""
    folder = Path(path)
    for candidate in (folder, folder.parent) if folder.name == "images" else (folder,):
        if (candidate / "camera.txt").is_file() and (candidate / "times.txt").is_file() and (
            (candidate / "images").is_dir() or (candidate / "images.zip").is_file()
        ):
            return candidate
    return None


def is_tum_mono(path: str | Path) -> bool:
    """True when `path` is a TUM monoVO sequence (or its ``images/`` folder): ``camera.txt`` and ``times.txt``
    beside ``images/`` or ``images.zip`` (the zip is then refused by `TumMonoSource` with a clear message)."""
    return sequence_folder(path) is not None


def read_camera_txt(path: Path) -> CameraIntrinsics:
    """A DSO / TUM monoVO ``camera.txt`` as `CameraIntrinsics` in pixels of the line-2 image size (see the
    module docstring for the forms and the relative convention). `SourceError` naming the file and line."""
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise SourceError(f"{path}: camera calibration not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    if len(lines) < 2:
        raise SourceError(f"{path}: expected the lens on line 1 and 'width height' on line 2")
    fields = lines[0].split()
    prefix = fields[0] if fields and re.fullmatch(r"[A-Za-z]+", fields[0]) else ""
    numbers_text = fields[1:] if prefix else fields
    try:
        numbers = [float(v) for v in numbers_text]
    except ValueError:
        raise SourceError(f"{path}:1: the lens line holds something that is not a number") from None
    if prefix:
        known = CAMERA_PREFIXES.get(prefix.lower())
        if known is None:
            raise SourceError(f"{path}:1: unknown camera model {prefix!r} (known: FOV, Pinhole, RadTan, EquiDistant, "
                              "KannalaBrandt)")
        model, count = known
        if len(numbers) != count:
            raise SourceError(f"{path}:1: {prefix} needs {count} numbers (fx fy cx cy + "
                              f"{'omega' if count == 5 else '4 coefficients'}), found {len(numbers)}")
    elif len(numbers) == 5:
        model, count = "fov", 5
    elif len(numbers) == 8:
        model, count = "plumb_bob", 8
    else:
        raise SourceError(f"{path}:1: expected 'fx fy cx cy omega' (5 numbers) or 8 RadTan numbers, found "
                          f"{len(numbers)}")
    if not all(np.isfinite(numbers)):
        raise SourceError(f"{path}:1: the lens line holds a non-finite value")
    size = lines[1].split()
    if len(size) != 2 or not all(re.fullmatch(r"\d+", v) for v in size) or int(size[0]) <= 0 or int(size[1]) <= 0:
        raise SourceError(f"{path}:2: expected the image size 'width height' (two positive integers)")
    width, height = int(size[0]), int(size[1])
    fx, fy, cx, cy = numbers[:4]
    if cx < 1 and cy < 1:  # DSO's test for a calibration relative to the image size
        fx, fy, cx, cy = fx * width, fy * height, cx * width - 0.5, cy * height - 0.5
    coefficients = numbers[4:]
    if model == "none" or (model == "fov" and coefficients[0] == 0.0):
        model, coefficients = "none", []
    return make_intrinsics([fx, fy, cx, cy], model, coefficients, width, height, str(path))


def read_frame_times(path: Path) -> dict[str, float]:
    """``times.txt``: image id → timestamp (s). Ids are compared as numbers when they are numbers (``00007``
    = ``7``). `SourceError` naming the file and line for a malformed line."""
    times: dict[str, float] = {}
    for number, stripped, fields in stamped_lines(path, "timestamps"):
        if len(fields) < 2:
            raise SourceError(f"{path}:{number}: expected 'id timestamp [exposure]', found {stripped[:60]!r}")
        times[_image_id(fields[0])] = parse_stamp(path, number, fields[1])
    if not times:
        raise SourceError(f"{path}: no timestamps")
    return times


def _image_id(text: str) -> str:
    """An image id as compared between times.txt and file names (numbers without leading zeros)."""
    return str(int(text)) if text.isdigit() else text


class TumMonoSource(ImageFilesSource):
    """Frames of a TUM monoVO sequence (or any folder in DSO's layout, see the module docstring).

    path: the sequence folder (or its ``images/`` folder). frames: the selection over the images sorted by
    name (default all). ground_truth: optional TUM trajectory of camera poses T_w_c matched to the frames by
    timestamp within gt_tolerance_s (rows holding NaN, like groundtruthSync.txt's, count as no pose; selected
    frames without a pose are an error naming the frames that have one); without it ``ground_truth`` is None.
    on_bad_frame: as for image folders (``"skip"`` turns an unreadable image into a `Frame.defect`). ``indices``
    are positions among the images sorted by name.
    """

    _times: np.ndarray

    def __init__(
        self,
        path: str | Path,
        frames: FrameRange | None = None,
        ground_truth: str | Path | None = None,
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        on_bad_frame: BadFramePolicy = "fail",
        gt_time_offset_s: float = 0.0,
    ):
        self._on_bad_frame = on_bad_frame
        given = Path(path)
        if not given.exists():
            raise SourceError(f"{given}: TUM monoVO folder not found")
        folder = sequence_folder(given)
        if folder is None:
            raise SourceError(f"{given}: not a TUM monoVO sequence (needs camera.txt, times.txt and images/)")
        self.folder = folder
        if not (folder / "images").is_dir():
            raise SourceError(f"{folder / 'images.zip'}: the frames are zipped; unzip them into "
                              f"{folder / 'images'}/ first (zip archives are not read)")
        listing = list_frame_files(folder / "images", "TUM monoVO image folder")
        self._files = listing.files
        self._indices = select(frames, len(self._files), folder)

        camera_file = folder / "camera.txt"
        self._intrinsics = read_camera_txt(camera_file)
        self._size, self._shift = first_image(self._files, self._indices, on_bad_frame, folder)
        if (self._intrinsics.width, self._intrinsics.height) != self._size:
            raise SourceError(f"{camera_file}:2: the calibration is for {self._intrinsics.width}x"
                              f"{self._intrinsics.height} images but they are {self._size[0]}x{self._size[1]}")

        times_file = folder / "times.txt"
        times = read_frame_times(times_file)
        stamps = []
        for file in self._files:
            stamp = times.get(_image_id(file.stem))
            if stamp is None:
                raise SourceError(f"{times_file}: no timestamp for image {file.name} (id {file.stem})")
            stamps.append(stamp)
        self._times = np.asarray(stamps, np.float64)
        self.notes: list[str] = [f"{times_file}: {note}" for note in stamp_problems(self._times)]
        self.notes += orientation_notes(self._files, self._indices, self._size)
        if (skipped := listing.skipped_note(folder / "images")) is not None:
            self.notes.append(skipped)
        photometric = [name for name in PHOTOMETRIC_FILES if (folder / name).is_file()]
        if photometric:
            self.notes.append(f"photometric calibration ({', '.join(photometric)}) not applied: images are used as "
                              "recorded (vignetting, camera response and exposure times ignored)")

        self.properties: dict[str, str] = {"dataset": "TUM monoVO", "photometric_calibration": "not applied"}
        self._ground_truth, self.properties["ground_truth"], self.gt_matching = optional_tum_camera_poses(
            Path(ground_truth) if ground_truth is not None else None, self._times, self._indices, gt_tolerance_s,
            folder, gt_time_offset_s)
        self._name = "tum-mono-" + safe_name(folder.resolve().name, "sequence")

    @property
    def stamps(self) -> np.ndarray:
        """(len(files),) timestamps in seconds of every image, from times.txt."""
        return self._times.copy()

    def __repr__(self) -> str:
        return f"TumMonoSource({str(self.folder)!r}, frames={len(self)})"
