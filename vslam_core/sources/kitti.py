"""KITTI odometry sequences, and the file readers the other sources share.

Layout (the official ``data_odometry_gray`` + ``data_odometry_poses``)::

    ROOT/sequences/NN/image_0/000000.png …   left grey camera
    ROOT/sequences/NN/calib.txt              ``P0: `` + 12 numbers (3x4 projection matrix, row-major)
    ROOT/sequences/NN/times.txt              one timestamp (s) per image (optional)
    ROOT/poses/NN.txt                        ground truth, KITTI format (optional; may hold more rows)

The readers here (`read_p0_intrinsics`, `read_times`, `read_ground_truth`, `first_image`, and `read_grey_image`
of `image_files`) are also used by `ImageFolderSource` and `VideoSource`; every problem is a one-line
`SourceError` (or `TrajectoryFormatError` for a malformed poses file) naming the file. `ImageFilesSource` is
the base of the sources whose frames are image files (KITTI, image folders, EuRoC, TUM monoVO).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, SelectedSource, rebase_poses
from vslam_core.sources.image_files import (
    decode_image,
    list_frame_files,
    orientation_note,
    read_grey_image,
    sixteen_bit_shift,
)
from vslam_core.sources.stamps import stamped_lines
from vslam_core.trajectory.io import check_ground_truth_steps, detect_format, read_kitti_poses, read_tum_poses

GroundTruthFormat = Literal["kitti", "tum", "auto"]

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
    times: list[float] = []
    for number, stripped, fields in stamped_lines(path, "timestamps"):
        if len(times) == count:
            break
        try:
            times.append(float(fields[0]))
        except ValueError:
            raise SourceError(f"{path}:{number}: timestamp {stripped[:40]!r} is not a number") from None
    if len(times) < count:
        raise SourceError(f"{path}: {len(times)} timestamps for {count} images")
    return times


def read_ground_truth(path: Path, count: int, fmt: GroundTruthFormat = "auto",
                      frame_times: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
    """The first ``count`` poses (count, 4, 4) of a KITTI or TUM trajectory file, in file order.

    ``fmt="auto"`` guesses from the column count. The file may hold more rows than ``count`` (only the
    first are kept); fewer is a `SourceError`, a malformed file a `TrajectoryFormatError` (both name
    the file). TUM timestamps are ignored: row i belongs to frame i. A row that jumps further than a car can move
    (`check_ground_truth_steps`: in the TUM file's own time, else the frames' `frame_times`, else one second a
    row) is a `TrajectoryFormatError` naming its line.
    """
    if not path.is_file():
        raise SourceError(f"{path}: ground-truth file not found")
    kind = detect_format(path) if fmt == "auto" else fmt
    if kind == "kitti":
        poses = read_kitti_poses(path, max_rows=count)
        times = None if frame_times is None else np.asarray(frame_times, np.float64)[: len(poses)]
        check_ground_truth_steps(path, poses, times)
    elif kind == "tum":
        stamps, poses = read_tum_poses(path)
        check_ground_truth_steps(path, poses, stamps)
        poses = poses[:count]
    else:
        raise SourceError(f"{path}: unknown ground-truth format {fmt!r} (kitti, tum or auto)")
    if len(poses) < count:
        raise SourceError(f"{path}: {len(poses)} poses for {count} frames (need one pose per frame)")
    return poses


BadFramePolicy = Literal["fail", "skip"]


def read_frame(
    index: int, path: Path, size: tuple[int, int], stamp: float | None, on_bad_frame: BadFramePolicy,
    shift: int | None = None,
) -> Frame:
    """One frame of an image sequence (16-bit images shifted right by `shift` bits, see `read_grey_image`). An
    unreadable image (or one of another size) raises `SourceError` with ``on_bad_frame="fail"``; with ``"skip"``
    it becomes a black placeholder frame carrying the error as its `defect`, and the run goes on."""
    try:
        return Frame(index=index, timestamp=stamp, image=read_grey_image(path, size, shift))
    except SourceError as exc:
        if on_bad_frame == "fail":
            raise
        return Frame(index=index, timestamp=stamp, image=np.zeros((size[1], size[0]), np.uint8), defect=str(exc))


class ImageFilesSource(SelectedSource):
    """A `SelectedSource` whose frames are image files: a subclass also sets ``_files`` (every frame's file, in
    frame order: source index i = ``_files[i]``), ``_size`` (the first selected image's width, height),
    ``_on_bad_frame`` and ``_times`` (every frame's timestamp in seconds, or None without a clock), and
    ``_shift`` (`first_image`'s: how 16-bit images become 8-bit); images are decoded lazily, one per iteration
    step."""

    _files: list[Path]
    _size: tuple[int, int]
    _on_bad_frame: BadFramePolicy
    _times: Sequence[float] | np.ndarray | None = None
    _shift: int | None = None

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
            yield read_frame(index, self._files[index], self._size, stamp, self._on_bad_frame, self._shift)


def first_image(files: list[Path], indices: list[int], on_bad_frame: BadFramePolicy, where: object
                ) -> tuple[tuple[int, int], int | None]:
    """(width, height) of the first selected image, and the right shift that makes the sequence's 16-bit images
    8-bit (`sixteen_bit_shift` of that image; None for 8-bit images). With ``on_bad_frame="skip"`` unreadable
    images are passed over (they become placeholder frames of this size); `SourceError` when none can be read,
    or with ``"fail"`` when the first cannot."""
    for index in indices:
        try:
            image = decode_image(files[index])
        except SourceError:
            if on_bad_frame == "fail":
                raise
            continue
        shift = sixteen_bit_shift(image) if image.dtype == np.uint16 else None
        return (image.shape[1], image.shape[0]), shift
    raise SourceError(f"{where}: none of the {len(indices)} selected images can be read")


def orientation_notes(files: list[Path], indices: list[int], size: tuple[int, int]) -> list[str]:
    """[one line] when the first selected image carries an EXIF Orientation flag (ignored: frames are read as
    stored, `size` = width, height), else []."""
    note = orientation_note(files[indices[0]], size)
    return [note] if note else []


def sixteen_bit_property(shift: int | None) -> dict[str, str]:
    """The run property saying how 16-bit images were made 8-bit ({} for 8-bit images)."""
    if shift is None:
        return {}
    return {"sixteen_bit": f"{shift + 8}-bit data in 16-bit images: >> {shift} bits (from the first frame's range)"}


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

        listing = list_frame_files(self.folder / "image_0", "KITTI image folder")
        self._files = listing.files
        self.notes = [note] if (note := listing.skipped_note(self.folder / "image_0")) else []
        self._indices = select(frames, len(self._files), self.folder)
        calib = self.folder / "calib.txt"
        fx, fy, cx, cy = read_p0_intrinsics(calib)
        self._size, self._shift = first_image(self._files, self._indices, on_bad_frame, self.folder)
        self.notes += orientation_notes(self._files, self._indices, self._size)
        self.properties = {"frame_order": listing.order_property(), **sixteen_bit_property(self._shift)}
        self._intrinsics = CameraIntrinsics(fx, fy, cx, cy, width=self._size[0], height=self._size[1],
                                            origin=f"{calib} (KITTI calib.txt)")

        times_file = self.folder / "times.txt"
        self._times = read_times(times_file, len(self._files)) if times_file.is_file() else None
        self.poses_file = poses_file if poses_file.is_file() else None
        self._ground_truth = (
            select_ground_truth(read_ground_truth(poses_file, len(self._files), "kitti", self._times), self._indices)
            if self.poses_file is not None
            else None
        )
        self.gt_matching = f"row by row (line i of {poses_file.name} is image i)" if self.poses_file else None
        self._name = f"kitti-{self.sequence}"
        self._camera_height = KITTI_CAMERA_HEIGHT_M

    def __repr__(self) -> str:
        return f"KittiSource({str(self.folder)!r}, frames={len(self)})"
