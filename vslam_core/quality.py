"""Image checks that decide whether a frame can be tracked at all (pure functions on grey images)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# Immerkær (1996), "Fast noise variance estimation", CVIU 64(2): the difference of two Laplacians
# cancels image structure to first order; here with a median instead of a mean, which textured
# street scenes bias less.
# The 3 x 3 kernel [[1, -2, 1], [-2, 4, -2], [1, -2, 1]] is the outer product of [1, -2, 1] with itself: filtered
# as two passes, the same integers (|response| <= 4080 fits int16) in a third of the time.
_NOISE_KERNEL_1D = np.array([1, -2, 1], np.float32)


#: Frames are measured at half resolution, or narrower for a camera wider than KITTI's 1241 px: at most this wide,
#: so a 4000-px camera's frames are judged sharp or blurred as a 1241-px one's (the variance of the Laplacian falls
#: steeply with magnification: KITTI 05 frames, 1226 px, measure 1118-1424; upscaled to 4000x1207, 60-70 at half
#: size (bilinear; 89-106 bicubic), under the blur gate's 100, and 750-978 (950-1223) at this width).
MEASURED_WIDTH_PX = 620.5


@dataclass(frozen=True)
class ImageStats:
    """Statistics of one (H, W) uint8 frame, measured at half resolution (`MEASURED_WIDTH_PX` wide at most)."""

    mean: float  # grey level 0..255
    saturated: float  # fraction of pixels ≥ 250
    sharpness: float  # variance of the Laplacian (low = blurred or featureless)
    noise_sigma: float  # estimated sensor noise (grey levels)


def image_stats(image: np.ndarray) -> ImageStats:
    small = _half(image)
    return ImageStats(
        mean=float(small.mean()),
        saturated=float(np.count_nonzero(small >= 250)) / small.size,
        sharpness=_laplacian_variance(small),
        noise_sigma=float(np.sqrt(np.pi / 2) * _median_noise_response(image) / 6),
    )


def sharpness(image: np.ndarray) -> float:
    """`ImageStats.sharpness` alone: the variance of the Laplacian at half resolution (see `MEASURED_WIDTH_PX`)."""
    return _laplacian_variance(_half(image))


def _half(image: np.ndarray) -> np.ndarray:
    """The image at half size, or `MEASURED_WIDTH_PX` wide when that is smaller (a camera over 1241 px wide)."""
    height, width = image.shape[:2]
    if width * 0.5 <= MEASURED_WIDTH_PX:
        return cv2.resize(image, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    factor = MEASURED_WIDTH_PX / width
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _laplacian_variance(image: np.ndarray) -> float:
    return float(cv2.Laplacian(image, cv2.CV_32F).var())


def _median_noise_response(image: np.ndarray) -> int:
    """Median of |noise kernel * image| over the full-resolution interior. The responses are integers, so
    a 256-bin histogram gives the median exactly (values saturate at 255, far above any usable frame's
    median) in a tenth of the time of sorting ~460 k floats."""
    response = cv2.sepFilter2D(image, cv2.CV_16S, _NOISE_KERNEL_1D, _NOISE_KERNEL_1D)[1:-1, 1:-1]
    magnitude = cv2.convertScaleAbs(response)
    histogram = cv2.calcHist([magnitude], [0], None, [256], [0, 256]).ravel()
    return int(np.searchsorted(np.cumsum(histogram), magnitude.size / 2))
