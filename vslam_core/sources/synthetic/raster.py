"""Synthetic street: ray-casting helpers (pixel -> plane homographies, pixel footprints, anisotropic
mip-mapped texture sampling, screen-space bounding boxes)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

NEAR = 0.05  # metres; rectangles are clipped at this camera depth
_ANISO_TAPS = 2  # texture taps along a pixel's longer footprint axis (anisotropic filtering)


def surface_homography(
    k: np.ndarray, r_cm: np.ndarray, t_cm: np.ndarray, origin: np.ndarray, axis_a: np.ndarray, axis_b: np.ndarray
) -> np.ndarray | None:
    """(3, 3) G mapping pixel (u, v, 1) to (a, b, 1) / z for the plane origin + a axis_a + b axis_b.

    r_cm, t_cm: map -> camera transform. The third component of G (u, v, 1) is the inverse depth 1/z
    of the ray's hit point (negative = behind the camera). None when the plane contains the camera.
    """
    m = np.column_stack([r_cm @ axis_a, r_cm @ axis_b, r_cm @ origin + t_cm])
    h = k @ m
    if abs(np.linalg.det(h)) < 1e-12:
        return None
    return np.linalg.inv(h)


@dataclass(frozen=True)
class _Footprints:
    """Where n pixels land on a surface, in surface units (metres or atlas texels).

    x, y: (n,) coordinates of the pixel centres; major_x, major_y: (n,) extent of a pixel along its longer
    image axis (the derivative of (x, y) along u or v); minor: (n,) length of the extent along the other.
    """

    x: np.ndarray
    y: np.ndarray
    major_x: np.ndarray
    major_y: np.ndarray
    minor: np.ndarray


def surface_coords(g: np.ndarray, u: np.ndarray, v: np.ndarray) -> _Footprints:
    """Surface coordinates and pixel footprints of pixels (u, v) (n,) float32.

    g: (9, n) or (9, 1) float32 row-major homographies, pixel -> surface coordinates (see
    `surface_homography`); the derivatives are exact for the homography.
    """
    inv_c = 1.0 / (g[6] * u + g[7] * v + g[8])
    a = (g[0] * u + g[1] * v + g[2]) * inv_c
    b = (g[3] * u + g[4] * v + g[5]) * inv_c
    a_u, b_u = (g[0] - a * g[6]) * inv_c, (g[3] - b * g[6]) * inv_c
    a_v, b_v = (g[1] - a * g[7]) * inv_c, (g[4] - b * g[7]) * inv_c
    len_u, len_v = a_u * a_u + b_u * b_u, a_v * a_v + b_v * b_v
    u_major = len_u > len_v
    return _Footprints(
        x=a,
        y=b,
        major_x=np.where(u_major, a_u, a_v),
        major_y=np.where(u_major, b_u, b_v),
        minor=np.sqrt(np.minimum(len_u, len_v)),
    )


def remap_points(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples (n,) of `image` at texel coordinates x, y (n,) float32, border replicated.

    (cv2.remap needs maps under 32767 columns: the points go in rows of 1024 plus one shorter row.)
    """
    n, cols = x.size, 1024
    full = n - n % cols
    parts = []
    for lo, hi, shape in ((0, full, (full // cols, cols)), (full, n, (1, n - full))):
        if hi > lo:
            parts.append(
                cv2.remap(
                    image,
                    x[lo:hi].reshape(shape),
                    y[lo:hi].reshape(shape),
                    cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE,
                ).reshape(-1)
            )
    return np.concatenate(parts) if len(parts) > 1 else parts[0] if parts else np.zeros(0, image.dtype)


def sample_aniso(
    pyramid: list[np.ndarray], fp: _Footprints, scale: float, offset: tuple[float, float], wrap: int = 0
) -> np.ndarray:
    """Anisotropic trilinear sample (n,) float32 of a texture at texel coordinates fp.{x, y} * scale + offset.

    pyramid: mip levels of the texture (`mip_pyramid`, at least two). `_ANISO_TAPS` taps spread along
    each pixel's longer footprint axis are averaged, each filtered over its share of the footprint (the mip
    level, blended between the two nearest): sharp and alias-free on surfaces seen at grazing angles.
    wrap > 0: the texture is a tile of that size and every level is padded with 2 texels of wrapped border.
    """
    top = len(pyramid) - 1
    major_x, major_y = fp.major_x * scale, fp.major_y * scale
    footprint = np.maximum(fp.minor * scale, np.hypot(major_x, major_y) * (1.0 / _ANISO_TAPS))
    lam = np.clip(np.log2(np.maximum(footprint, 1e-6)), 0.0, float(top))
    lo = np.minimum(lam.astype(np.int32), top - 1)  # blend levels lo and lo + 1
    order = np.argsort(lo, kind="stable")  # group the pixels by level: contiguous slices below
    bounds = np.searchsorted(lo[order], np.arange(top + 1))  # group k (lo == k): bounds[k]:bounds[k + 1]
    frac = (lam - lo)[order]
    x, y = fp.x * scale + float(offset[0]), fp.y * scale + float(offset[1])  # float32 level-0 texels
    taps = []  # per tap: level-0 coordinates in level order
    for k in range(_ANISO_TAPS):
        t = (k + 0.5) / _ANISO_TAPS - 0.5
        xt, yt = (x + t * major_x)[order], (y + t * major_y)[order]
        taps.append((np.mod(xt, wrap), np.mod(yt, wrap)) if wrap else (xt, yt))
    pad = 2.0 if wrap else 0.0
    acc = np.zeros(x.shape, np.float32)
    for level in range(top + 1):  # level l serves group l - 1 (weight frac) and group l (weight 1 - frac)
        start, mid, stop = bounds[max(level - 1, 0)], bounds[level], bounds[min(level + 1, top)]
        if start == stop:
            continue
        weight = np.concatenate([frac[start:mid], 1.0 - frac[mid:stop]]) * (1.0 / _ANISO_TAPS)
        s = 0.5**level
        for xt, yt in taps:
            xl, yl = xt[start:stop] * s + (0.5 * s - 0.5 + pad), yt[start:stop] * s + (0.5 * s - 0.5 + pad)
            acc[start:stop] += weight * remap_points(pyramid[level], xl, yl)
    out = np.empty_like(acc)
    out[order] = acc
    return out


def pixel_boxes(corners_c: np.ndarray, k: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel bounding boxes (n, 4) int (u0, v0, u1, v1; end exclusive; empty when u0 >= u1 or v0 >= v1)
    of n quadrilaterals (n, 4, 3) in camera coordinates, clipped at depth `NEAR`, within the image.
    """
    boxes = np.zeros((len(corners_c), 4), np.int64)
    in_front = corners_c[:, :, 2].min(axis=1) >= NEAR
    if in_front.any():  # the common case, vectorised
        uvw = corners_c[in_front] @ k.T
        uv = uvw[:, :, :2] / uvw[:, :, 2:]
        boxes[in_front, :2] = np.floor(uv.min(axis=1)) - 1
        boxes[in_front, 2:] = np.ceil(uv.max(axis=1)) + 2
    for i in np.flatnonzero(~in_front):  # crossing the near plane: clip the polygon first
        pts: list[np.ndarray] = []
        for j in range(4):
            p, q = corners_c[i, j], corners_c[i, (j + 1) % 4]
            if p[2] >= NEAR:
                pts.append(p)
            if (p[2] >= NEAR) != (q[2] >= NEAR):
                pts.append(p + (NEAR - p[2]) / (q[2] - p[2]) * (q - p))
        uvw = np.array(pts) @ k.T
        uv = uvw[:, :2] / uvw[:, 2:]
        boxes[i, :2] = np.floor(uv.min(axis=0)) - 1
        boxes[i, 2:] = np.ceil(uv.max(axis=0)) + 2
    np.clip(boxes, 0, [width, height, width, height], out=boxes)
    return boxes
