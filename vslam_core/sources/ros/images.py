"""Image messages of a ROS log turned into grey uint8 frames: ``sensor_msgs/msg/Image`` (mono8, mono16, rgb8, bgr8,
rgba8, bgra8, bayer_rggb8/bggr8/gbrg8/grbg8, 8UC1) and ``sensor_msgs/msg/CompressedImage`` (whatever
``cv2.imdecode`` reads: jpeg, png, …).

mono16 is shifted right by ``b - 8`` bits, ``b`` being the bit depth (8, 10, 12, 14 or 16) that holds the brightest
pixel of the first decoded frame; the same shift is used for every frame (brighter pixels later on are clipped),
so the brightness does not jump from frame to frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam_core.errors import SourceError

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_TYPE)

#: Raw ``sensor_msgs/Image`` encodings we turn into grey (lower case), and how.
_COLOUR_CODES = {
    "rgb8": (3, cv2.COLOR_RGB2GRAY), "bgr8": (3, cv2.COLOR_BGR2GRAY),
    "rgba8": (4, cv2.COLOR_RGBA2GRAY), "bgra8": (4, cv2.COLOR_BGRA2GRAY),
    # ROS names the Bayer pattern from the top-left pixel, OpenCV from the second row's: cv_bridge's mapping
    "bayer_rggb8": (1, cv2.COLOR_BayerBG2GRAY), "bayer_bggr8": (1, cv2.COLOR_BayerRG2GRAY),
    "bayer_gbrg8": (1, cv2.COLOR_BayerGR2GRAY), "bayer_grbg8": (1, cv2.COLOR_BayerGB2GRAY),
}
SUPPORTED_ENCODINGS = ("mono8", "8uc1", "mono16", *_COLOUR_CODES)


@dataclass(frozen=True)
class DecodedImage:
    """A decoded frame: (H, W) uint8 grey, and the encoding it came in (for the run properties)."""

    image: np.ndarray
    encoding: str


class ImageDecoder:
    """Turns image messages into grey uint8 arrays; remembers the mono16 shift chosen on the first frame."""

    def __init__(self) -> None:
        self.mono16_shift: int | None = None

    def decode(self, msg: object, msgtype: str) -> DecodedImage:
        """One deserialised ``Image`` or ``CompressedImage`` (`msgtype`) as grey uint8; `SourceError` for an
        encoding that is not supported or data that do not make an image of the stated size."""
        if msgtype == COMPRESSED_TYPE:
            fmt = str(msg.format)  # type: ignore[attr-defined]
            if "compresseddepth" in fmt.lower():
                raise SourceError(f"compressed depth images ({fmt!r}) are not camera frames")
            data = np.asarray(msg.data, np.uint8)  # type: ignore[attr-defined]
            # as stored: an EXIF Orientation in a JPEG is not applied (the calibration describes the sensor's pixels)
            image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION) if data.size else None
            if image is None or image.size == 0:
                raise SourceError(f"cannot decode the compressed image (format {fmt!r}, {data.size} bytes)")
            return DecodedImage(np.ascontiguousarray(image, np.uint8), fmt.split(";")[-1].strip() or "compressed")
        encoding = str(msg.encoding).strip()  # type: ignore[attr-defined]
        key = encoding.lower()
        height, width, step = int(msg.height), int(msg.width), int(msg.step)  # type: ignore[attr-defined]
        data = np.asarray(msg.data, np.uint8)  # type: ignore[attr-defined]
        if key not in SUPPORTED_ENCODINGS:
            raise SourceError(f"image encoding {encoding!r} is not supported (supported: "
                              f"{', '.join(e for e in SUPPORTED_ENCODINGS if e != '8uc1')})")
        if height <= 0 or width <= 0:
            raise SourceError(f"image of {width}x{height} pixels")
        depth = 2 if key == "mono16" else 1
        channels = _COLOUR_CODES[key][0] if key in _COLOUR_CODES else 1
        row = width * channels * depth
        if step < row or data.size < step * (height - 1) + row:
            raise SourceError(f"image data of {data.size} bytes is too short for {width}x{height} {encoding} "
                              f"(step {step})")
        rows = np.lib.stride_tricks.as_strided(data, (height, row), (step, 1))
        if key in ("mono8", "8uc1"):
            return DecodedImage(np.ascontiguousarray(rows), key)
        if key == "mono16":
            big = bool(msg.is_bigendian)  # type: ignore[attr-defined]
            values = np.ascontiguousarray(rows).view(">u2" if big else "<u2").astype(np.uint16)
            if self.mono16_shift is None:
                bits = max(8, int(values.max()).bit_length())
                self.mono16_shift = min(16, bits + (bits % 2)) - 8
            return DecodedImage(np.minimum(values >> self.mono16_shift, 255).astype(np.uint8), key)
        code = _COLOUR_CODES[key][1]
        pixels = np.ascontiguousarray(rows).reshape(height, width, channels) if channels > 1 else \
            np.ascontiguousarray(rows)
        return DecodedImage(cv2.cvtColor(pixels, code), key)
