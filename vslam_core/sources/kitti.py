"""KITTI odometry sequences, and the file readers the other sources share.

Layout (the official ``data_odometry_gray`` + ``data_odometry_poses``)::

    ROOT/sequences/NN/image_0/000000.png …   left grey camera
    ROOT/sequences/NN/calib.txt              ``P0: `` + 12 numbers (3x4 projection matrix, row-major)
    ROOT/sequences/NN/times.txt              one timestamp (s) per image (optional)
    ROOT/poses/NN.txt                        ground truth, KITTI format (optional; may hold more rows)

The readers here (`read_p0_intrinsics`, `read_times`, `read_ground_truth`, `list_images`,
`read_grey_image`) are also used by `ImageFolderSource` and `VideoSource`; every problem is a one-line
`SourceError` (or `TrajectoryFormatError` for a malformed poses file) naming the file. `ImageFilesSource` is
the base of the sources whose frames are image files (KITTI, image folders, EuRoC, TUM monoVO).
"""

from __future__ import annotations

import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, SelectedSource, rebase_poses
from vslam_core.trajectory_io import detect_format, read_kitti_poses, read_tum_poses

GroundTruthFormat = Literal["kitti", "tum", "auto"]

#: Image file extensions a folder of frames may hold (compared case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
KITTI_CAMERA_HEIGHT_M = 1.65


# --------------------------------------------------------------------------------------------------
# shared readers


def read_p0_intrinsics(calib: Path) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) from the ``P0:`` line of a KITTI ``calib.txt`` (fx=P[0,0], fy=P[1,1], cx=P[0,2],
    cy=P[1,2] of the row-major 3x4 matrix). Raises `SourceError` naming the file when it is missing, has
    no ``P0:`` line, or the line does not hold 12 numbers."""
    try:
        lines = calib.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise SourceError(f"{calib}: calibration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{calib}: cannot read calibration file ({exc.__class__.__name__})") from None
    for number, line in enumerate(lines, start=1):
        key, colon, rest = line.strip().partition(":")
        if key.strip() != "P0" or not colon:
            continue
        fields = rest.split()
        if len(fields) != 12:
            raise SourceError(f"{calib}:{number}: P0 needs 12 numbers (3x4 matrix), found {len(fields)}")
        try:
            p = np.array([float(v) for v in fields]).reshape(3, 4)
        except ValueError:
            raise SourceError(f"{calib}:{number}: P0 holds something that is not a number") from None
        if not np.all(np.isfinite(p)) or p[0, 0] <= 0 or p[1, 1] <= 0:
            raise SourceError(f"{calib}:{number}: P0 focal lengths must be finite and positive")
        return float(p[0, 0]), float(p[1, 1]), float(p[0, 2]), float(p[1, 2])
    raise SourceError(f"{calib}: no 'P0:' line (expected 'P0: ' followed by 12 numbers)")


def read_times(path: Path, count: int) -> list[float]:
    """The first ``count`` timestamps (seconds, one a line) of a KITTI ``times.txt``.

    Raises `SourceError` naming the file for a non-number or fewer than ``count`` lines."""
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read timestamps ({exc.__class__.__name__})") from None
    times: list[float] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if len(times) == count:
            break
        try:
            times.append(float(stripped.split()[0]))
        except ValueError:
            raise SourceError(f"{path}:{number}: timestamp {stripped[:40]!r} is not a number") from None
    if len(times) < count:
        raise SourceError(f"{path}: {len(times)} timestamps for {count} images")
    return times


def read_ground_truth(path: Path, count: int, fmt: GroundTruthFormat = "auto") -> np.ndarray:
    """The first ``count`` poses (count, 4, 4) of a KITTI or TUM trajectory file, in file order.

    ``fmt="auto"`` guesses from the column count. The file may hold more rows than ``count`` (only the
    first are kept); fewer is a `SourceError`, a malformed file a `TrajectoryFormatError` (both name
    the file). TUM timestamps are ignored: row i belongs to frame i.
    """
    if not path.is_file():
        raise SourceError(f"{path}: ground-truth file not found")
    kind = detect_format(path) if fmt == "auto" else fmt
    if kind == "kitti":
        poses = read_kitti_poses(path, max_rows=count)
    elif kind == "tum":
        poses = read_tum_poses(path)[1][:count]
    else:
        raise SourceError(f"{path}: unknown ground-truth format {fmt!r} (kitti, tum or auto)")
    if len(poses) < count:
        raise SourceError(f"{path}: {len(poses)} poses for {count} frames (need one pose per frame)")
    return poses


def list_images(folder: Path, what: str = "image folder") -> list[Path]:
    """The image files of ``folder`` sorted by name; `SourceError` when it is missing or holds none."""
    if not folder.exists():
        raise SourceError(f"{folder}: {what} not found")
    if not folder.is_dir():
        raise SourceError(f"{folder}: {what} is not a folder")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file())
    if not images:
        raise SourceError(f"{folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) in the {what}")
    return images


def read_grey_image(path: Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Decode one image as (H, W) uint8 grey (colour is converted). ``size`` = (width, height) expected.

    Raises `SourceError` naming the file when it cannot be decoded or has another size. A PNG is checked
    (`png_problem`) before libpng sees it: libpng prints its own ``libpng error: …`` line on stderr."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SourceError(f"{path}: cannot read image ({exc.strerror or exc.__class__.__name__})") from None
    if (problem := png_problem(data)) is not None:
        raise SourceError(f"{path}: cannot read image (corrupt PNG: {problem})")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    if image is None or image.size == 0:
        raise SourceError(f"{path}: cannot read image (missing, corrupt or not an image)")
    if size is not None and (image.shape[1], image.shape[0]) != size:
        raise SourceError(
            f"{path}: image is {image.shape[1]}x{image.shape[0]}, the first frame is {size[0]}x{size[1]}"
        )
    return image


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: bytes) -> str | None:
    """What is wrong with the chunks of a PNG file's bytes (a chunk's CRC-32 that does not match, a chunk cut
    off), or None (also for data that is not a PNG). PNG spec §5.3: each chunk is length (4 bytes, big-endian),
    type (4), data, and the CRC-32 of type and data (4)."""
    if not data.startswith(PNG_SIGNATURE):
        return None
    position = len(PNG_SIGNATURE)
    while position + 8 <= len(data):
        length = int.from_bytes(data[position:position + 4], "big")
        kind = data[position + 4:position + 8]
        end = position + 8 + length
        if end + 4 > len(data):
            return None  # cut off: OpenCV reports it without a libpng line
        if zlib.crc32(data[position + 4:end]) != int.from_bytes(data[end:end + 4], "big"):
            return f"chunk {kind.decode('latin-1')} at byte {position} fails its CRC check"
        if kind == b"IEND":
            return None
        position = end + 4
    return None


BadFramePolicy = Literal["fail", "skip"]


def read_frame(
    index: int, path: Path, size: tuple[int, int], stamp: float | None, on_bad_frame: BadFramePolicy
) -> Frame:
    """One frame of an image sequence. An unreadable image (or one of another size) raises `SourceError`
    with ``on_bad_frame="fail"``; with ``"skip"`` it becomes a black placeholder frame carrying the error as
    its `defect`, and the run goes on."""
    try:
        return Frame(index=index, timestamp=stamp, image=read_grey_image(path, size))
    except SourceError as exc:
        if on_bad_frame == "fail":
            raise
        return Frame(index=index, timestamp=stamp, image=np.zeros((size[1], size[0]), np.uint8), defect=str(exc))


class ImageFilesSource(SelectedSource):
    """A `SelectedSource` whose frames are image files: a subclass also sets ``_files`` (every frame's file, in
    frame order: source index i = ``_files[i]``), ``_size`` (the first selected image's width, height),
    ``_on_bad_frame`` and ``_times`` (every frame's timestamp in seconds, or None without a clock); images are
    decoded lazily, one per iteration step."""

    _files: list[Path]
    _size: tuple[int, int]
    _on_bad_frame: BadFramePolicy
    _times: Sequence[float] | np.ndarray | None = None

    @property
    def files(self) -> list[Path]:
        """Every image file, in frame order (source index i = files[i])."""
        return list(self._files)

    @property
    def file_times(self) -> np.ndarray | None:
        """(len(files),) timestamps in seconds of every frame, in frame order; None without a clock."""
        return None if self._times is None else np.asarray(self._times, np.float64).copy()

    def __iter__(self) -> Iterator[Frame]:
        for index in self._indices:
            stamp = None if self._times is None else float(self._times[index])
            yield read_frame(index, self._files[index], self._size, stamp, self._on_bad_frame)


def first_image_size(files: list[Path], indices: list[int], on_bad_frame: BadFramePolicy, where: object
                     ) -> tuple[int, int]:
    """(width, height) of the first selected image. With ``on_bad_frame="skip"`` unreadable images are passed
    over (they become placeholder frames of this size); `SourceError` when none can be read, or with
    ``"fail"`` when the first cannot."""
    for index in indices:
        try:
            image = read_grey_image(files[index])
        except SourceError:
            if on_bad_frame == "fail":
                raise
            continue
        return image.shape[1], image.shape[0]
    raise SourceError(f"{where}: none of the {len(indices)} selected images can be read")


def select(frames: FrameRange | None, available: int, where: object) -> list[int]:
    """``frames.indices(available)`` (every frame when None); `SourceError` if nothing is selected."""
    try:
        indices = (frames or FrameRange()).indices(available)
    except SourceError as exc:
        raise SourceError(f"{where}: {exc}") from None
    if not indices:
        raise SourceError(f"{where}: --frames {frames} selects no frame")
    return indices


def select_ground_truth(poses: np.ndarray, indices: list[int]) -> np.ndarray:
    """The poses of the selected frames, re-based so that the first selected frame is the identity."""
    return rebase_poses(poses[np.asarray(indices)])


def normalise_sequence(sequence: str) -> str:
    """``"0"`` / ``"00"`` / ``" 5 "`` -> ``"00"`` / ``"05"``; other names are kept as they are."""
    text = sequence.strip()
    if not text:
        raise SourceError("KITTI sequence name is empty (expected e.g. 00 or 05)")
    return f"{int(text):02d}" if text.isdigit() else text


# --------------------------------------------------------------------------------------------------
# the source


class KittiSource(ImageFilesSource):
    """Frames of one KITTI odometry sequence (left grey camera ``image_0``).

    path: the dataset root (then ``sequence`` is required, "0" or "00" both mean ``sequences/00``) or a
    sequence folder (``…/sequences/NN``; the ground truth is then ``../../poses/NN.txt`` when present).
    frames: the selection (default all). Intrinsics come from ``calib.txt`` (P0), the image size from
    the first selected image; timestamps from ``times.txt`` when present (else None); ground truth
    from ``poses/NN.txt`` when present (its first N rows, N = number of images), re-based to the first
    selected frame. Images are decoded lazily, one per iteration step. ``indices`` are image numbers;
    ``camera_height`` is 1.65 m, the height of the KITTI recording car's cameras above the road (Geiger et al.
    2013).
    """

    def __init__(
        self,
        path: str | Path,
        sequence: str | None = None,
        frames: FrameRange | None = None,
        on_bad_frame: BadFramePolicy = "fail",
    ):
        self._on_bad_frame = on_bad_frame
        root = Path(path)
        if not root.exists():
            raise SourceError(f"{root}: KITTI folder not found")
        if sequence is not None:
            self.sequence = normalise_sequence(sequence)
            self.folder = root / "sequences" / self.sequence
            if not self.folder.is_dir():
                raise SourceError(f"{self.folder}: KITTI sequence {self.sequence} not found")
            poses_file = root / "poses" / f"{self.sequence}.txt"
        elif (root / "image_0").is_dir():
            self.folder = root
            self.sequence = normalise_sequence(root.resolve().name)
            poses_file = root.resolve().parent.parent / "poses" / f"{self.sequence}.txt"
        elif (root / "sequences").is_dir():
            raise SourceError(f"{root}: a KITTI dataset root; say which sequence (e.g. --sequence 00)")
        else:
            raise SourceError(f"{root}: not a KITTI sequence folder (no image_0/) nor a dataset root")

        self._files = list_images(self.folder / "image_0", "KITTI image folder")
        self._indices = select(frames, len(self._files), self.folder)
        calib = self.folder / "calib.txt"
        fx, fy, cx, cy = read_p0_intrinsics(calib)
        self._size = first_image_size(self._files, self._indices, on_bad_frame, self.folder)
        self._intrinsics = CameraIntrinsics(fx, fy, cx, cy, width=self._size[0], height=self._size[1],
                                            origin=f"{calib} (KITTI calib.txt)")

        times_file = self.folder / "times.txt"
        self._times = read_times(times_file, len(self._files)) if times_file.is_file() else None
        self.poses_file = poses_file if poses_file.is_file() else None
        self._ground_truth = (
            select_ground_truth(read_ground_truth(poses_file, len(self._files), "kitti"), self._indices)
            if self.poses_file is not None
            else None
        )
        self.gt_matching = f"row by row (line i of {poses_file.name} is image i)" if self.poses_file else None
        self._name = f"kitti-{self.sequence}"
        self._camera_height = KITTI_CAMERA_HEIGHT_M

    def __repr__(self) -> str:
        return f"KittiSource({str(self.folder)!r}, frames={len(self)})"
