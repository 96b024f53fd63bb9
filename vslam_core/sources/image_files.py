"""The image files of a folder of frames: which files are frames, in which order, and how they are decoded.

Listing (`list_frame_files`): the folder's ``.png .jpg .jpeg .bmp .tif .tiff`` files in *natural* name order
(runs of digits compared as numbers, so ``f_2`` comes before ``f_10``; zero-padded names sort as before).
Files that cannot be frames are left out and counted: macOS AppleDouble files (``._name.png``, the resource
forks a Mac writes onto FAT/exFAT/network drives), other hidden files (``.name.png``) and empty files.

Decoding (`read_grey_image`): the file's bytes are read through Python's file layer and decoded with
``cv2.imdecode`` (OpenCV's own path handling crashes on a path that is not valid UTF-8), at the depth the
file holds (``IMREAD_ANYDEPTH``; colour is converted to grey) and as stored: an EXIF ``Orientation`` flag is
ignored (``IMREAD_IGNORE_ORIENTATION``), since a calibration describes the sensor's pixels (`orientation_note`
says when a flag was there). 16-bit images are shifted right by ``b - 8``
bits, ``b`` being the bit depth (8, 10, 12, 14 or 16) that holds the brightest pixel of the source's first
frame (`sixteen_bit_shift`), as the ``mono16`` images of a ROS log are: 10- or 12-bit sensor data stored in
16-bit PNGs keeps its full brightness instead of becoming 0–15 (which `IMREAD_GRAYSCALE` makes of it).
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from vslam_core.errors import SourceError

#: Image file extensions a folder of frames may hold (compared case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
NATURAL_ORDER = "natural name order (numbers in names compared as numbers)"
_DIGITS = re.compile(r"([0-9]+)")


def natural_key(name: str) -> tuple[list[str | int], str]:
    """Sort key of a file name in natural order: text and digit runs alternate (``"f_10.png"`` ->
    ``["f_", 10, ".png"]``), digit runs compared as numbers; ties (``f_01`` / ``f_1``) broken by the name."""
    parts = _DIGITS.split(name)
    return [int(part) if i % 2 else part for i, part in enumerate(parts)], name


@dataclass(frozen=True)
class FrameFiles:
    """A folder's frame files in natural name order, and what was left out (kind -> count)."""

    files: list[Path]
    skipped: dict[str, int] = field(default_factory=dict)
    text_order_differs: bool = False  # plain text order would have put the frames in another order

    def skipped_note(self, folder: Path) -> str | None:
        """One line saying how many files were not read as frames and why, or None."""
        if not self.skipped:
            return None
        total = sum(self.skipped.values())
        ordered = sorted(self.skipped.items(), key=lambda item: (-item[1], _KINDS.index(item[0])))
        kinds = ", ".join(f"{count} {kind} file{'s' if count != 1 else ''}" for kind, count in ordered)
        return f"{folder}: skipped {total} image file{'s' if total != 1 else ''} that are not frames ({kinds})"

    def order_property(self) -> str:
        """The run property saying in which order the frames were read (an example when it matters)."""
        if not self.text_order_differs:
            return NATURAL_ORDER
        example = _order_example(self.files)
        return f"{NATURAL_ORDER}: {example}" if example else NATURAL_ORDER


def _order_example(files: list[Path]) -> str | None:
    """``f_2.png before f_10.png``: where natural order first departs from plain text order."""
    for natural, text in zip(files, sorted(files), strict=True):
        if natural != text:
            return f"{natural.name} before {text.name}"
    return None


_KINDS = ("macOS '._' AppleDouble", "hidden", "empty")


def _skip_reason(path: Path) -> str | None:
    """Why `path` (an image file by its extension) is not a frame (one of `_KINDS`), or None if it may be one."""
    if path.name.startswith("._"):
        return _KINDS[0]
    if path.name.startswith("."):
        return _KINDS[1]
    if path.stat().st_size == 0:
        return _KINDS[2]
    return None


def list_frame_files(folder: Path, what: str = "image folder") -> FrameFiles:
    """The frame files of `folder` (see the module docstring); `SourceError` when it is missing or holds none."""
    if not folder.exists():
        raise SourceError(f"{folder}: {what} not found")
    if not folder.is_dir():
        raise SourceError(f"{folder}: {what} is not a folder")
    frames: list[Path] = []
    skipped: dict[str, int] = {}
    for path in folder.iterdir():
        if path.suffix.lower() not in IMAGE_EXTENSIONS or not path.is_file():
            continue
        reason = _skip_reason(path)
        if reason is None:
            frames.append(path)
        else:
            skipped[reason] = skipped.get(reason, 0) + 1
    if not frames:
        detail = f" ({sum(skipped.values())} skipped: {', '.join(skipped)})" if skipped else ""
        raise SourceError(f"{folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) in the {what}{detail}")
    natural = sorted(frames, key=lambda p: natural_key(p.name))
    return FrameFiles(natural, dict(sorted(skipped.items())), natural != sorted(frames))


def decode_image(path: Path) -> np.ndarray:
    """The image in `path` as (H, W) uint8 or uint16 grey, read through Python's file layer (any path the
    operating system accepts) and ``cv2.imdecode``; `SourceError` naming the file when it cannot be."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise SourceError(f"{path}: cannot read image ({exc.strerror or exc.__class__.__name__})") from None
    if (problem := png_problem(raw)) is not None:  # before libpng prints its own "libpng error: …" line
        raise SourceError(f"{path}: cannot read image (corrupt PNG: {problem})")
    data = np.frombuffer(raw, np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION) if data.size else None
    if image is None or image.size == 0:
        raise SourceError(f"{path}: cannot read image (missing, corrupt or not an image)")
    if image.dtype not in (np.uint8, np.uint16):
        raise SourceError(f"{path}: {image.dtype} pixels are not supported (8- or 16-bit integer images)")
    return image


def sixteen_bit_shift(image: np.ndarray) -> int:
    """How far to shift a 16-bit image right to make it 8-bit: ``b - 8`` for the even bit depth ``b`` (8..16)
    that holds its brightest pixel (12-bit data: 4; data that fits 8 bits: 0)."""
    bits = max(8, int(image.max()).bit_length())
    return min(16, bits + (bits % 2)) - 8


def to_eight_bit(image: np.ndarray, shift: int | None) -> np.ndarray:
    """(H, W) uint8: an 8-bit image as it is, a 16-bit one shifted right by `shift` bits (its own
    `sixteen_bit_shift` when None); brighter pixels than the shift allows are clipped to 255."""
    if image.dtype == np.uint8:
        return image
    shift = sixteen_bit_shift(image) if shift is None else shift
    return np.minimum(image >> shift, 255).astype(np.uint8)


def read_grey_image(path: Path, size: tuple[int, int] | None = None, shift: int | None = None) -> np.ndarray:
    """Decode one image as (H, W) uint8 grey (colour is converted, 16-bit scaled by `to_eight_bit`). ``size`` =
    (width, height) expected. Raises `SourceError` naming the file when it cannot be decoded or has another
    size."""
    image = decode_image(path)
    if size is not None and (image.shape[1], image.shape[0]) != size:
        raise SourceError(
            f"{path}: image is {image.shape[1]}x{image.shape[0]}, the first frame is {size[0]}x{size[1]}"
        )
    return to_eight_bit(image, shift)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: EXIF Orientation values (TIFF tag 0x0112) → how a viewer turns the stored image to show it
ORIENTATIONS = {2: "mirrored", 3: "rotated 180°", 4: "flipped upside down", 5: "mirrored and rotated 90°",
                6: "rotated 90° clockwise", 7: "mirrored and rotated 90°", 8: "rotated 90° anticlockwise"}
_BYTE_ORDERS: dict[bytes, Literal["little", "big"]] = {b"II": "little", b"MM": "big"}
_EXIF_SEARCH = 1 << 16  # the EXIF block sits at the file's start (JPEG APP1, PNG eXIf before IDAT, TIFF IFD0)


def exif_orientation(data: bytes) -> int | None:
    """The EXIF ``Orientation`` (1-8) of an image file's bytes (JPEG APP1 ``Exif``, PNG ``eXIf`` or a TIFF's own
    IFD0), or None when there is none. TIFF layout: byte order ``II``/``MM``, 42, the offset of IFD0, then its
    entries (tag 2 bytes, type 2, count 4, value 4; a SHORT value sits in the value's first 2 bytes)."""
    head = data[:_EXIF_SEARCH]
    if head[:4] in (b"II*\x00", b"MM\x00*"):
        start = 0
    elif (found := head.find(b"Exif\x00\x00")) >= 0:
        start = found + 6
    elif (found := head.find(b"eXIf")) >= 0:
        start = found + 4
    else:
        return None
    tiff = head[start:]
    order = _BYTE_ORDERS.get(tiff[:2])
    if order is None or len(tiff) < 10:
        return None
    ifd = int.from_bytes(tiff[4:8], order)
    if ifd + 2 > len(tiff):
        return None
    entries = int.from_bytes(tiff[ifd:ifd + 2], order)
    for i in range(entries):
        entry = tiff[ifd + 2 + 12 * i: ifd + 14 + 12 * i]
        if len(entry) < 12:
            return None
        if int.from_bytes(entry[:2], order) == 0x0112:
            return int.from_bytes(entry[8:10], order)
    return None


def orientation_note(path: Path, size: tuple[int, int]) -> str | None:
    """One line when the image file `path` (stored `size` = width, height) carries an EXIF Orientation other than
    1 (upright), which the frames are read without; None otherwise (or when the file cannot be read)."""
    try:
        with path.open("rb") as file:
            head = file.read(_EXIF_SEARCH)
    except OSError:
        return None
    value = exif_orientation(head)
    if value is None or value == 1:
        return None
    turned = ORIENTATIONS.get(value, "an unknown turn")
    return (f"{path.name}: EXIF Orientation {value} ({turned}) ignored: the frames are read as the sensor stored "
            f"them, {size[0]}x{size[1]}, the calibration's pixels (a viewer would show them turned)")


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
