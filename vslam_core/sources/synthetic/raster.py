"""Synthetic street: ray-casting helpers (pixel -> plane homographies, pixel footprints, anisotropic
mip-mapped texture sampling, screen-space bounding boxes)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from vslam_core.sources.synthetic.scratch import Scratch

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


def surface_coords(g: np.ndarray, u: np.ndarray, v: np.ndarray, scratch: Scratch) -> _Footprints:
    """Surface coordinates and pixel footprints of pixels (u, v) (n,) float32.

    g: (9, n) or (9, 1) float32 row-major homographies, pixel -> surface coordinates (see
    `surface_homography`); the derivatives are exact for the homography. Computed in place in (n,) float32
    buffers of `scratch` (the footprints live there too), every value with the same float32 operations in
    the same order as the formulas say.
    """
    n = u.size
    g0, g1, g2, g3, g4, g5, g6, g7, g8 = g
    tmp, inv_c, a, b = (scratch.empty(n, np.float32) for _ in range(4))
    np.multiply(g7, v, out=tmp)
    np.multiply(g6, u, out=inv_c)
    inv_c += tmp
    inv_c += g8
    np.divide(1.0, inv_c, out=inv_c)  # 1 / (g6 u + g7 v + g8)
    for x, gu, gv, gc in ((a, g0, g1, g2), (b, g3, g4, g5)):  # (g0 u + g1 v + g2) / c, (g3 u + g4 v + g5) / c
        np.multiply(gu, u, out=x)
        np.multiply(gv, v, out=tmp)
        x += tmp
        x += gc
        x *= inv_c
    derivatives = []  # a_u, b_u, a_v, b_v: (g_i - x g_j) / c
    for x, gi, gj in ((a, g0, g6), (b, g3, g6), (a, g1, g7), (b, g4, g7)):
        d = np.multiply(x, gj, out=scratch.empty(n, np.float32))
        np.subtract(gi, d, out=d)
        d *= inv_c
        derivatives.append(d)
    a_u, b_u, a_v, b_v = derivatives
    len_u = np.multiply(a_u, a_u, out=inv_c)  # inv_c no longer needed
    np.multiply(b_u, b_u, out=tmp)
    len_u += tmp
    len_v = np.multiply(a_v, a_v, out=scratch.empty(n, np.float32))
    np.multiply(b_v, b_v, out=tmp)
    len_v += tmp
    u_major = np.greater(len_u, len_v, out=scratch.empty(n, np.bool_))
    np.copyto(a_v, a_u, where=u_major)  # major_x
    np.copyto(b_v, b_u, where=u_major)  # major_y
    minor = np.minimum(len_u, len_v, out=len_u)
    np.sqrt(minor, out=minor)
    return _Footprints(x=a, y=b, major_x=a_v, major_y=b_v, minor=minor)


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


def _wrap_into_tile(x: np.ndarray, wrap: int, scratch: Scratch) -> None:
    """x (n,) float32 -> np.mod(x, wrap), in place and bit for bit (wrap a power of two: x - floor(x / wrap)
    wrap is then exact, as is np.mod's fmod; the result is rounded once either way). Other sizes: np.mod."""
    if wrap & (wrap - 1):
        np.mod(x, wrap, out=x)
        return
    k = np.multiply(x, np.float32(1.0 / wrap), out=scratch.empty(x.size, np.float32))
    np.floor(k, out=k)
    k *= np.float32(wrap)
    np.subtract(x, k, out=x)
    negative = np.less(x, 0, out=scratch.empty(x.size, np.bool_))
    np.add(x, np.float32(wrap), out=x, where=negative)  # only a negative subnormal x, whose quotient underflows


def _level_groups(lam: np.ndarray, top: int, scratch: Scratch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Group pixels by the lower of the two mip levels they blend, lo = min(floor(lam), top - 1), each group
    split into the pixels with lam == lo (no weight on level lo + 1) and the others.

    lam: (n,) float32 level of detail in [0, top]. Returns the stable order (n,) that sorts the pixels by
    2 lo + (lam > lo); the bounds (2 top + 1,) of those keys in it (key j: bounds[j]:bounds[j + 1]); and
    frac = lam - lo (n,) float64 in that order, the weight of level lo + 1.
    """
    n = lam.size
    lo = scratch.empty(n, np.uint8)
    np.copyto(lo, lam, casting="unsafe")  # 0..top, truncated (as astype)
    np.minimum(lo, top - 1, out=lo)
    key = np.greater(lam, lo, out=scratch.empty(n, np.bool_)).view(np.uint8)
    key += lo
    key += lo  # a one-byte key, which numpy's stable sort radix-sorts
    order = np.argsort(key, kind="stable")
    bounds = np.zeros(2 * top + 1, np.int64)
    np.cumsum(np.bincount(key, minlength=2 * top)[: 2 * top], out=bounds[1:])
    frac = scratch.empty(n, np.float64)
    np.copyto(frac, np.take(lam, order, out=scratch.empty(n, np.float32), mode="wrap"))
    for k in range(1, top):
        frac[bounds[2 * k] : bounds[2 * k + 2]] -= k
    return order, bounds, frac


def sample_aniso(
    pyramid: list[np.ndarray], fp: _Footprints, scale: float, offset: tuple[float, float], scratch: Scratch,
    wrap: int = 0,
) -> np.ndarray:
    """Anisotropic trilinear sample (n,) float32 of a texture at texel coordinates fp.{x, y} * scale + offset.

    pyramid: mip levels of the texture (`mip_pyramid`, at least two). `_ANISO_TAPS` taps spread along
    each pixel's longer footprint axis are averaged, each filtered over its share of the footprint (the mip
    level, blended between the two nearest): sharp and alias-free on surfaces seen at grazing angles.
    wrap > 0: the texture is a tile of that size and every level is padded with 2 texels of wrapped border.
    Temporaries and the result are `scratch` arrays.
    """
    top, n = len(pyramid) - 1, fp.x.size
    if scale == 1.0:  # x * 1.0 is x: skip the products
        major_x, major_y, minor = fp.major_x, fp.major_y, fp.minor
    else:
        major_x, major_y, minor = (np.multiply(a, scale, out=scratch.empty(n, np.float32))
                                   for a in (fp.major_x, fp.major_y, fp.minor))
    lam = np.hypot(major_x, major_y, out=scratch.empty(n, np.float32))
    lam *= 1.0 / _ANISO_TAPS
    np.maximum(minor, lam, out=lam)  # the footprint of one tap
    np.maximum(lam, 1e-6, out=lam)
    np.log2(lam, out=lam)
    np.clip(lam, 0.0, float(top), out=lam)
    order, bounds, frac = _level_groups(lam, top, scratch)
    taps = []  # per tap: level-0 coordinates (x + t major) in level order
    c, c_sorted, major_sorted = (scratch.empty(n, np.float32) for _ in range(3))
    for axis, major, shift in ((fp.x, major_x, offset[0]), (fp.y, major_y, offset[1])):
        if scale != 1.0:
            np.multiply(axis, scale, out=c)
        else:
            c[:] = axis
        c += float(shift)  # float32 level-0 texels
        np.take(c, order, out=c_sorted, mode="wrap")
        np.take(major, order, out=major_sorted, mode="wrap")
        for k in range(_ANISO_TAPS):
            t = (k + 0.5) / _ANISO_TAPS - 0.5
            tap = np.multiply(major_sorted, t, out=scratch.empty(n, np.float32))
            tap += c_sorted  # x + t major (addition commutes bit for bit)
            if wrap:
                _wrap_into_tile(tap, wrap, scratch)
            taps.append(tap)
    pad = 2.0 if wrap else 0.0
    acc = scratch.empty(n, np.float32)
    acc[:] = 0.0
    weight = scratch.empty(n, np.float64)
    product = scratch.empty(n, np.float64)
    rows_max = -(-_ANISO_TAPS * n // 1024)
    map_x, map_y = (scratch.empty(rows_max * 1024, np.float32) for _ in range(2))
    samples_all = scratch.empty(rows_max * 1024, np.uint8)
    for level in range(top + 1):  # level l serves group l - 1 (weight frac) and group l (weight 1 - frac)
        # (not the pixels of group l - 1 with frac = 0: acc + 0 * sample is acc)
        start, mid = bounds[max(2 * level - 1, 0)], bounds[2 * level]
        stop = bounds[2 * level + 2] if level < top else mid
        m = stop - start
        if m == 0:
            continue
        w = weight[:m]
        w[: mid - start] = frac[start:mid]
        np.subtract(1.0, frac[mid:stop], out=w[mid - start :])
        w *= 1.0 / _ANISO_TAPS
        s, shift = 0.5**level, 0.5 * 0.5**level - 0.5 + pad
        rows = -(-_ANISO_TAPS * m // 1024)  # all taps in one remap, rows of 1024 points (cv2's 32767 limit)
        for maps, coords in ((map_x, taps[:_ANISO_TAPS]), (map_y, taps[_ANISO_TAPS:])):
            for k, tap in enumerate(coords):
                part = maps[k * m : (k + 1) * m]
                np.multiply(tap[start:stop], s, out=part)
                part += shift
            maps[_ANISO_TAPS * m : rows * 1024] = 0.0
        samples = cv2.remap(
            pyramid[level],
            map_x[: rows * 1024].reshape(rows, 1024),
            map_y[: rows * 1024].reshape(rows, 1024),
            cv2.INTER_LINEAR,
            dst=samples_all[: rows * 1024].reshape(rows, 1024),
            borderMode=cv2.BORDER_REPLICATE,
        ).reshape(-1)
        for k in range(_ANISO_TAPS):
            p = np.multiply(w, samples[k * m : (k + 1) * m], out=product[:m])
            np.add(acc[start:stop], p, out=acc[start:stop])  # in float64, rounded to float32
    out = scratch.empty(n, np.float32)
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
