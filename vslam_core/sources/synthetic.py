"""Synthetic street: a deterministic procedural renderer, the project's embedded default data source.

Nothing is downloaded: the scene is generated from a seed and rendered on demand.

Scene, in an internal *map* frame M (x east, y north, z up, metres; never exposed):

- the ground plane z = 0: asphalt road with lane markings, kerbs, sidewalks and repair patches along
  a smooth centreline with left and right curves, plus a fine speckle (a tile repeating every 15 m);
- building façades on both sides of the road at varying setbacks (5..12 m from the centreline), in
  blocks of 10..25 m with gaps; each building is a chain of planar textured rectangles following the
  road plus two side walls;
- street furniture on the sidewalks every 6..14 m (signs on poles, poster boards, kiosks) and parked
  cars and vans along the left kerb: features at mid range seen head-on, which keep the two-view
  geometry well conditioned (far façades alone give little parallax, the near road moves too fast);
- a panorama at infinity (hills with trees, sky) seen above and between the buildings.

The camera (OpenCV/KITTI axes: x right, y down, z forward) drives in the right lane, ``camera_height``
above the road, at 0.83..1.17 m per frame, with small pitch and roll oscillations (< 1 degree).

Rendering is exact per-pixel ray casting with a z-buffer: for a plane, the pixel -> surface mapping
is a homography whose third row is the inverse depth 1/z, affine in the pixel coordinates. Each
rectangle is tested only inside the bounding box of its near-clipped projection. Textures are
sampled bilinearly from mip-map pyramids with anisotropic filtering (two taps along each pixel's
footprint, each blended between mip levels), so there is no aliasing and the road stays sharp.
Ground truth is the exact poses used for rendering.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, rebase_poses

_INTRINSICS = CameraIntrinsics(fx=718.856, fy=718.856, cx=607.1928, cy=185.2157, width=1241, height=376)
_FRAME_DT = 0.1  # seconds between frames

# Road and path (metres).
_ROAD_HALF_WIDTH = 3.5
_SIDEWALK_HALF_WIDTH = 5.0
_LANE_OFFSET = -1.6  # camera's lateral offset from the centreline (+ = left): the right lane
_START_S = 20.0  # arc length of the first camera position (buildings exist behind it)
_CENTRELINE_STEP = 0.25
_LOOK_AHEAD = 130.0  # scene generated beyond the last camera position

# Rendering.
_NEAR = 0.05  # metres; rectangles are clipped at this camera depth
_FAR = 100.0  # metres; rectangles whose nearest point is farther are culled
_GROUND_FAR = 300.0  # metres; farther ground shows the panorama (hills) instead
_FACADE_RES = 0.04  # metres per texel
_SIDEWALL_RES = 0.06
_FURNITURE_RES = 0.02
_COARSE_RES = 0.1  # ground layout texture (road, markings, patches)
_FINE_RES = 0.015  # ground speckle tile
_FINE_TILE = 1024
_SPECKLE_CONTRAST = 0.45  # ground speckle amplitude, about +-55 grey levels
_ATLAS_MIN_WIDTH = 4096
_ATLAS_PAD = 16
_MIP_LEVELS = 7
_MAX_FRAMES = 2000  # textures must stay under cv2.remap's 32767-texel limit (and memory reasonable)
_ANISO_TAPS = 2  # texture taps along a pixel's longer footprint axis (anisotropic filtering)
_PANO_ELEV_MIN = -0.12  # radians
_PANO_ELEV_MAX = 0.6


# ----------------------------------------------------------------------------------------------------
# Road centreline and camera path
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Centreline:
    """Road centreline sampled every `_CENTRELINE_STEP` metres of arc length (map frame, z = 0).

    s: (M,) arc length; xy: (M, 2) positions; heading: (M,) radians counter-clockwise from map x;
    curvature: (M,) 1/m, positive = turning left.
    """

    s: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray

    def frame_at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(n,) arc lengths -> positions (n, 2), headings (n,), left unit normals (n, 2)."""
        xy = np.stack([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])], axis=1)
        heading = np.interp(s, self.s, self.heading)
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        return xy, heading, normal

    def curvature_at(self, s: float) -> float:
        """Curvature (1/m) at arc length s."""
        return float(np.interp(s, self.s, self.curvature))


def _make_centreline(length: float, rng: np.random.Generator) -> _Centreline:
    """A smooth road of the given length: straights and 60..90 degree curves, alternating left/right.

    Curvature ramps in and out smoothly (sin^2), so the heading is smooth; the tightest radius is ~28 m.
    """
    plan = [
        (35.0, 0.0),
        (60.0, 90.0),
        (45.0, 0.0),
        (70.0, -90.0),
        (35.0, 0.0),
        (50.0, 60.0),
        (40.0, 0.0),
        (60.0, -75.0),
    ]  # (segment length m, heading change deg)
    s = np.arange(0.0, length + _CENTRELINE_STEP, _CENTRELINE_STEP)
    curvature = np.zeros_like(s)
    start, k = 0.0, 0
    while start < length:
        seg_len, angle = plan[k % len(plan)]
        seg_len *= rng.uniform(0.9, 1.1)
        if angle != 0.0:
            total = math.radians(angle) * rng.uniform(0.85, 1.05)
            t = (s - start) / seg_len
            inside = (t >= 0.0) & (t < 1.0)
            ramp = 0.25  # sin^2 ramps over the first and last quarter, constant in between
            shape = np.sin(0.5 * np.pi * np.minimum(np.minimum(t, 1.0 - t) / ramp, 1.0)) ** 2
            curvature[inside] = total / (seg_len * (1.0 - ramp)) * shape[inside]
        start += seg_len
        k += 1
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * _CENTRELINE_STEP)])
    direction = np.stack([np.cos(heading), np.sin(heading)], axis=1)
    steps = 0.5 * (direction[1:] + direction[:-1]) * _CENTRELINE_STEP
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return _Centreline(s=s, xy=xy, heading=heading, curvature=curvature)


def _rotation_x(angle: float) -> np.ndarray:
    """(3, 3) rotation about x by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_z(angle: float) -> np.ndarray:
    """(3, 3) rotation about z by `angle` radians."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _camera_path(line: _Centreline, n_frames: int, camera_height: float, rng: np.random.Generator) -> np.ndarray:
    """Camera poses T_m_c (n_frames, 4, 4) in the map frame.

    The camera follows the right lane at `camera_height` above the road (z = 0), looking along the road
    tangent, with speed 0.83..1.17 m/frame (measured along its own lane) and pitch/roll oscillations.
    """
    phase = rng.uniform(0.0, 2.0 * np.pi, 5)
    i = np.arange(n_frames, dtype=np.float64)
    speed = 1.0 + 0.12 * np.sin(2 * np.pi * i / 83 + phase[0]) + 0.05 * np.sin(2 * np.pi * i / 19 + phase[1])
    pitch = np.radians(0.6) * np.sin(2 * np.pi * i / 41 + phase[2]) + np.radians(0.2) * np.sin(
        2 * np.pi * i / 11 + phase[3]
    )
    roll = np.radians(0.6) * np.sin(2 * np.pi * i / 29 + phase[4])
    arc = np.empty(n_frames)
    arc[0] = _START_S
    for k in range(1, n_frames):  # lane arc length = (1 - offset * curvature) * centreline arc length
        arc[k] = arc[k - 1] + speed[k - 1] / (1.0 - _LANE_OFFSET * line.curvature_at(arc[k - 1]))
    xy, heading, normal = line.frame_at(arc)
    position = xy + _LANE_OFFSET * normal
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    for k in range(n_frames):
        c, s = math.cos(heading[k]), math.sin(heading[k])
        # Columns: camera x (right), y (down), z (forward) in map coordinates.
        base = np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])
        poses[k, :3, :3] = base @ _rotation_x(pitch[k]) @ _rotation_z(roll[k])
        poses[k, :3, 3] = (position[k, 0], position[k, 1], camera_height)
    return poses


# ----------------------------------------------------------------------------------------------------
# Textures
# ----------------------------------------------------------------------------------------------------


def _periodic_noise(
    shape: tuple[int, int], rng: np.random.Generator, min_wavelength: float, max_wavelength: float
) -> np.ndarray:
    """(H, W) float32 tileable band-pass noise (zero mean, unit std), wavelengths in texels, ~1/f spectrum."""
    h, w = shape
    spectrum = np.fft.rfft2(rng.standard_normal(shape))
    k = np.hypot(np.fft.fftfreq(h)[:, None], np.fft.rfftfreq(w)[None, :])
    band = (k >= 1.0 / max_wavelength) & (k <= 1.0 / min_wavelength)
    noise = np.fft.irfft2(spectrum * band / np.sqrt(np.maximum(k, 1e-6)), s=shape)
    return ((noise - noise.mean()) / (noise.std() + 1e-12)).astype(np.float32)


def _smooth_field(shape: tuple[int, int], cell: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 smooth random field (unit-ish std) varying over about `cell` texels."""
    h, w = shape
    small = rng.standard_normal((h // cell + 2, w // cell + 2)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _block_pattern(
    shape: tuple[int, int], rows: tuple[int, int], cols: tuple[int, int], contrast: float, rng: np.random.Generator
) -> np.ndarray:
    """(H, W) float32 zero-mean pattern of irregular blocks (stones, panels) separated by dark joints.

    rows, cols: inclusive ranges of block heights and widths in texels; every course has its own random
    widths and phase and every block its own brightness, so the pattern never repeats.
    """
    h, w = shape
    out = np.empty((h, w), np.float32)
    columns = np.arange(w)
    y = 0
    while y < h:
        height = int(rng.integers(rows[0], rows[1] + 1))
        widths = rng.integers(cols[0], cols[1] + 1, size=w // cols[0] + 2)
        edges = np.cumsum(widths) - int(rng.integers(0, widths[0]))
        block = np.searchsorted(edges, columns, side="right")
        course = rng.normal(0.0, contrast, size=len(edges) + 1).astype(np.float32)[block]
        course[1:][np.diff(block) != 0] = -2.5 * contrast  # vertical joints
        out[y : y + height] = course
        out[y] = -2.5 * contrast  # horizontal joint
        y += height
    return out


def _wall(shape: tuple[int, int], res: float, wall: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 bare wall of mean brightness `wall`: plaster, stone blocks or cladding panels."""
    img = np.full(shape, wall, np.float32) + 9.0 * _smooth_field(shape, 40, rng)
    kind = rng.integers(0, 3)
    if kind == 1:  # stone blocks
        img += _block_pattern(
            shape, (round(0.25 / res), round(0.6 / res)), (round(0.35 / res), round(1.2 / res)), 10.0, rng
        )
    elif kind == 2:  # cladding panels
        img += _block_pattern(
            shape, (round(0.8 / res), round(2.5 / res)), (round(0.5 / res), round(1.6 / res)), 16.0, rng
        )
    else:  # plaster
        img += 7.0 * _smooth_field(shape, 5, rng)
    return img


def _wall_details(
    img: np.ndarray, length: float, height: float, wall: float, rng: np.random.Generator, res: float
) -> None:
    """Scatter small high-contrast items (plain panels and signs, vents, posters) over a wall texture."""
    for _ in range(int(length * height / 10.0)):
        w, h = rng.uniform(0.2, 1.2), rng.uniform(0.2, 1.0)
        x, y = rng.uniform(0.0, max(0.1, length - w)), rng.uniform(0.3, max(0.4, height - h))
        value = _grey(wall + rng.choice([-1.0, 1.0]) * rng.uniform(40, 110))
        _rect(img, x, y, x + w, y + h, value, res)
        kind = rng.integers(0, 3)
        if kind == 0:  # vent / grille: slats
            for k in range(1, int(h / 0.1)):
                _rect(img, x + 0.03, y + k * 0.1, x + w - 0.03, y + k * 0.1 + 0.04, 255.0 - value, res)
        elif kind == 1:  # poster: a few inner blocks
            for _ in range(int(rng.integers(1, 5))):
                px, py = x + rng.uniform(0, 0.7) * w, y + rng.uniform(0, 0.7) * h
                _rect(
                    img,
                    px,
                    py,
                    px + rng.uniform(0.1, 0.3) * w + 0.05,
                    py + rng.uniform(0.1, 0.3) * h + 0.05,
                    rng.uniform(0, 255),
                    res,
                )


def _grey(value: float) -> float:
    """A grey level clamped to 0..255."""
    return min(255.0, max(0.0, float(value)))


def _rect(img: np.ndarray, x0: float, y0: float, x1: float, y1: float, value: float, res: float) -> None:
    """Fill the rectangle [x0, x1] x [y0, y1] (metres; y down from the texture top) with `value`."""
    cv2.rectangle(
        img, (round(x0 / res), round(y0 / res)), (round(x1 / res) - 1, round(y1 / res) - 1), float(value), thickness=-1
    )


def _window(
    img: np.ndarray, x: float, y: float, w: float, h: float, wall: float, rng: np.random.Generator, res: float
) -> None:
    """Draw one window (frame, glass, mullions, curtain, sill) with its top-left at (x, y) metres."""
    frame = _grey(wall + rng.choice([-1.0, 1.0]) * rng.uniform(45, 90))
    _rect(img, x, y, x + w, y + h, frame, res)
    glass = rng.uniform(10, 70) if rng.random() < 0.7 else rng.uniform(150, 245)
    b = 0.08
    _rect(img, x + b, y + b, x + w - b, y + h - b, glass, res)
    if rng.random() < 0.45:  # curtain or blind
        depth = rng.uniform(0.15, 0.7) * h
        left = rng.random() < 0.5
        cx0, cx1 = (x + b, x + b + rng.uniform(0.3, 1.0) * (w - 2 * b)) if left else (x + b, x + w - b)
        _rect(img, cx0, y + b, cx1, y + b + depth, rng.uniform(90, 235), res)
    if rng.random() < 0.6:  # mullions
        _rect(img, x + w / 2 - 0.03, y, x + w / 2 + 0.03, y + h, frame, res)
        if rng.random() < 0.5:
            ym = y + h * rng.uniform(0.25, 0.45)
            _rect(img, x, ym - 0.03, x + w, ym + 0.03, frame, res)
    if rng.random() < 0.7:  # sill
        _rect(img, x - 0.1, y + h, x + w + 0.1, y + h + 0.1, _grey(wall + rng.uniform(-70, 70)), res)


def _facade_texture(length: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture of a street façade `length` x `height` metres (row 0 = top of building).

    Random bays and floors; every window differs (glass, curtains, mullions), shops on the ground floor.
    """
    res = _FACADE_RES
    w, h = max(8, math.ceil(length / res)), max(8, math.ceil(height / res))
    wall = rng.uniform(80, 200)
    img = _wall((h, w), res, wall, rng)
    _wall_details(img, length, height, wall, rng, res)
    ground_floor = rng.uniform(3.6, 4.6)
    floor_h = rng.uniform(2.8, 3.4)
    ratio_w, ratio_h = rng.uniform(0.45, 0.7), rng.uniform(0.45, 0.62)
    bays: list[tuple[float, float]] = []
    x = rng.uniform(0.3, 1.2)
    while x < length - 1.2:
        bay = min(rng.uniform(1.6, 3.0), length - x - 0.3)
        bays.append((x, bay))
        x += bay
    cornice = rng.random() < 0.6
    top = rng.uniform(0.4, 1.0)  # parapet
    floor_top = top
    while floor_top + floor_h < height - ground_floor:
        if cornice:
            _rect(img, 0.0, floor_top - 0.12, length, floor_top, _grey(wall + rng.uniform(-60, 60)), res)
        for bx, bw in bays:
            if rng.random() < 0.08:
                continue
            ww = bw * ratio_w * rng.uniform(0.92, 1.08)
            _window(img, bx + (bw - ww) / 2, floor_top + floor_h * 0.28, ww, floor_h * ratio_h, wall, rng, res)
        floor_top += floor_h
    # Ground floor: shop fronts with a sign band, a big window and a door.
    y_shop = height - ground_floor
    x = 0.0
    while x < length - 0.5:
        shop = min(rng.uniform(3.0, 7.0), length - x)
        sign = rng.uniform(20, 240)
        _rect(img, x + 0.2, y_shop + 0.2, x + shop - 0.2, y_shop + 0.8, sign, res)
        for _ in range(int(shop * 2.5)):  # "letters"
            lx = x + rng.uniform(0.35, max(0.4, shop - 0.6))
            _rect(
                img,
                lx,
                y_shop + 0.3,
                lx + rng.uniform(0.08, 0.3),
                y_shop + 0.7,
                255.0 - sign + rng.uniform(-30, 30),
                res,
            )
        door = rng.uniform(0.9, 1.4)
        door_x = x + rng.uniform(0.3, max(0.35, shop - door - 0.3))
        _rect(img, x + 0.25, y_shop + 1.0, x + shop - 0.25, height - 0.4, rng.uniform(15, 90), res)
        _rect(
            img,
            x + 0.35,
            y_shop + 1.1,
            x + shop - 0.35,
            y_shop + 1.1 + rng.uniform(0.3, 1.2),
            rng.uniform(120, 240),
            res,
        )  # display / reflections
        _rect(img, door_x, y_shop + 1.2, door_x + door, height, rng.uniform(0, 60), res)
        _rect(img, door_x + 0.1, y_shop + 1.3, door_x + door - 0.1, y_shop + 1.6, rng.uniform(150, 250), res)
        x += shop
    _rect(img, 0.0, height - 0.3, length, height, _grey(wall - 50), res)  # plinth
    return img


def _sidewall_texture(depth: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture of a building's side wall: plaster, a few windows, a drain pipe."""
    res = _SIDEWALL_RES
    w, h = max(8, math.ceil(depth / res)), max(8, math.ceil(height / res))
    wall = rng.uniform(70, 190)
    img = _wall((h, w), res, wall, rng)
    _wall_details(img, depth, height, wall, rng, res)
    for _ in range(rng.integers(2, 8)):
        ww, wh = rng.uniform(0.6, 1.4), rng.uniform(0.8, 1.6)
        _window(
            img,
            rng.uniform(0.2, max(0.3, depth - ww - 0.2)),
            rng.uniform(0.5, max(0.6, height - wh - 1.0)),
            ww,
            wh,
            wall,
            rng,
            res,
        )
    px = rng.uniform(0.3, depth - 0.3)
    _rect(img, px, 0.0, px + 0.12, height, _grey(wall + rng.uniform(-80, 80)), res)
    return img


def _plain_texture(w: float, h: float, rng: np.random.Generator, res: float, value: float | None = None) -> np.ndarray:
    """(H, W) float32 plain surface `w` x `h` metres (poles, roofs) with slight smooth variation."""
    shape = (max(4, math.ceil(h / res)), max(4, math.ceil(w / res)))
    base = rng.uniform(40, 200) if value is None else value
    return np.full(shape, base, np.float32) + 10.0 * _smooth_field(shape, 20, rng)


def _poster_texture(w: float, h: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 high-contrast poster or sign `w` x `h` metres: frame, picture blocks, text lines."""
    img = _plain_texture(w, h, rng, res, rng.uniform(20, 235))
    background = float(img.mean())
    _rect(img, 0.0, 0.0, w, h, 255.0 - background, res)
    _rect(img, 0.04, 0.04, w - 0.04, h - 0.04, background, res)  # frame
    for _ in range(int(rng.integers(1, 4))):  # picture blocks
        bw, bh = rng.uniform(0.15, 0.6) * w, rng.uniform(0.1, 0.4) * h
        x, y = rng.uniform(0.05, w - bw - 0.05), rng.uniform(0.05, h - bh - 0.05)
        _rect(img, x, y, x + bw, y + bh, rng.uniform(0, 255), res)
    y = rng.uniform(0.05, 0.3) * h
    while y < h - 0.12:  # text lines: runs of "letters" of random widths
        size = rng.uniform(0.04, 0.12)
        x = rng.uniform(0.06, 0.2) * w
        ink = _grey(255.0 - background + rng.uniform(-40, 40))
        while x < w - 0.1 and rng.random() < 0.93:
            lw = size * rng.uniform(0.4, 1.0)
            _rect(img, x, y, x + lw, y + size, ink, res)
            x += lw + size * rng.uniform(0.2, 0.6)
        y += size * rng.uniform(1.6, 3.0)
    return img


def _vehicle_side(length: float, height: float, body: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 side of a car or van: body, window band with pillars, door seams, wheels."""
    img = _plain_texture(length, height, rng, res, body)
    top = 0.08 * height
    _rect(img, 0.12 * length, top, 0.9 * length, 0.45 * height, rng.uniform(10, 60), res)  # windows
    for x in np.linspace(0.12 * length, 0.9 * length, int(rng.integers(3, 5))):  # pillars
        _rect(img, x - 0.04, top, x + 0.04, 0.45 * height, body, res)
        _rect(img, x - 0.01, 0.45 * height, x + 0.01, 0.85 * height, body - 60.0 if body > 90 else body + 60.0, res)
    _rect(img, 0.0, 0.8 * height, length, height, rng.uniform(15, 45), res)  # sill and shadow
    for x in (0.18 * length, 0.82 * length):  # wheels
        r = 0.32
        cv2.circle(img, (round(x / res), round((height - 0.05 - r) / res)), round(r / res), 15.0, -1)
        cv2.circle(
            img,
            (round(x / res), round((height - 0.05 - r) / res)),
            round(0.45 * r / res),
            float(rng.uniform(120, 200)),
            -1,
        )
    return img


def _vehicle_end(width: float, height: float, body: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 front or back of a vehicle: window, lights, number plate, bumper."""
    img = _plain_texture(width, height, rng, res, body)
    _rect(img, 0.12 * width, 0.08 * height, 0.88 * width, 0.45 * height, rng.uniform(10, 70), res)
    light = rng.uniform(170, 250)
    for x in (0.05 * width, 0.8 * width):
        _rect(img, x, 0.55 * height, x + 0.15 * width, 0.65 * height, light, res)
    _rect(img, 0.35 * width, 0.68 * height, 0.65 * width, 0.68 * height + 0.12, 230.0, res)  # plate
    x = 0.37 * width
    while x < 0.62 * width:
        _rect(img, x, 0.68 * height + 0.025, x + 0.025, 0.68 * height + 0.095, 20.0, res)
        x += rng.uniform(0.035, 0.05)
    _rect(img, 0.0, 0.85 * height, width, height, rng.uniform(15, 50), res)  # bumper
    return img


def _finish_texture(tex: np.ndarray, grain: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture -> uint8, with a random window of the (G, G) `grain` added and a slight blur."""
    h, w = tex.shape
    if h > grain.shape[0] or w > grain.shape[1]:  # never with the sizes used here
        grain = np.tile(grain, (h // grain.shape[0] + 1, w // grain.shape[1] + 1))
    gy, gx = int(rng.integers(0, grain.shape[0] - h + 1)), int(rng.integers(0, grain.shape[1] - w + 1))
    blurred = cv2.GaussianBlur(tex + grain[gy : gy + h, gx : gx + w], (0, 0), 0.7)
    return np.clip(blurred, 0, 255, out=blurred).astype(np.uint8)


def _pack_atlas(textures: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Shelf-pack (H_i, W_i) uint8 textures into one atlas.

    Returns the atlas (H_a, W_a) uint8 and each texture's top-left texel (n, 2) as (x, y). W_a is at
    least `_ATLAS_MIN_WIDTH`, wider for long streets so that H_a stays below cv2.remap's 32767 limit.
    Textures are separated by `_ATLAS_PAD` texels of replicated border (limits mip-map bleeding).
    """
    area = sum((t.shape[0] + 2 * _ATLAS_PAD) * (t.shape[1] + 2 * _ATLAS_PAD) for t in textures)
    width = max(_ATLAS_MIN_WIDTH, math.ceil(math.sqrt(2.0 * area) / 1024) * 1024)
    offsets = np.zeros((len(textures), 2), np.int64)
    x = y = shelf = 0
    for k, tex in enumerate(textures):
        h, w = tex.shape
        if x + w + 2 * _ATLAS_PAD > width:
            x, y, shelf = 0, y + shelf, 0
        offsets[k] = (x + _ATLAS_PAD, y + _ATLAS_PAD)
        x += w + 2 * _ATLAS_PAD
        shelf = max(shelf, h + 2 * _ATLAS_PAD)
    height = -(-(y + shelf) // 64) * 64
    atlas = np.full((height, width), 128, np.uint8)
    for (ox, oy), tex in zip(offsets, textures, strict=True):
        h, w = tex.shape
        padded = cv2.copyMakeBorder(tex, _ATLAS_PAD, _ATLAS_PAD, _ATLAS_PAD, _ATLAS_PAD, cv2.BORDER_REPLICATE)
        atlas[oy - _ATLAS_PAD : oy + h + _ATLAS_PAD, ox - _ATLAS_PAD : ox + w + _ATLAS_PAD] = padded
    return atlas, offsets


def _ground_fine_tile(rng: np.random.Generator) -> np.ndarray:
    """(_FINE_TILE, _FINE_TILE) uint8 tileable high-contrast mottled speckle (asphalt grain), ~128 mean."""
    blobs = _periodic_noise((_FINE_TILE, _FINE_TILE), rng, 3.0, 60.0)
    grain = _periodic_noise((_FINE_TILE, _FINE_TILE), rng, 2.0, 5.0)
    value = 128.0 + 110.0 * np.tanh(1.3 * blobs) + 18.0 * grain
    return np.clip(value, 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class _GroundLayout:
    """Ground layout texture in the map frame: texel (x, y) covers map point origin + (x, y) * res.

    image: (H, W) uint8; origin: (2,) map x, y of texel (0, 0).
    """

    image: np.ndarray
    origin: np.ndarray


def _ground_layout(line: _Centreline, rng: np.random.Generator) -> _GroundLayout:
    """Draw verges, sidewalks, the road, repair patches, manholes, cracks and lane markings (map frame).

    The texture covers the centreline's bounding box plus 40 m, at `_COARSE_RES` metres per texel.
    """
    res = _COARSE_RES
    origin = line.xy.min(axis=0) - 40.0
    extent = np.ceil((line.xy.max(axis=0) + 40.0 - origin) / res / 64).astype(int) * 64
    w, h = int(extent[0]), int(extent[1])
    half = (h // 2, w // 2)  # the smooth base is made at half resolution, then upsampled
    base = 22.0 * _smooth_field(half, 15, rng)
    base += 10.0 * _smooth_field(half, 3, rng) + 105.0
    base8 = np.clip(base, 0, 255, out=base).astype(np.uint8)
    img = cv2.resize(base8, (w, h), interpolation=cv2.INTER_LINEAR)  # uint8: OpenCV anti-aliases only 8-bit

    def to_px(xy: np.ndarray) -> np.ndarray:
        """(n, 2) map points -> (n, 1, 2) int32 fixed-point (4 fractional bits) texel coordinates."""
        return np.round((xy - origin) / res * 16).astype(np.int32).reshape(-1, 1, 2)

    def offset_curve(lateral: float) -> np.ndarray:
        """(M, 2) points `lateral` metres left of the centreline."""
        xy, _, normal = line.frame_at(line.s)
        return xy + lateral * normal

    def thick(pts: np.ndarray, value: float, width_m: float) -> None:
        """Draw the open polyline pts (n, 2) (map metres), `width_m` wide, anti-aliased."""
        cv2.polylines(img, [to_px(pts)], False, round(value), max(1, round(width_m / res)), cv2.LINE_AA, 4)

    thick(offset_curve(0.0), 150.0, 2 * _SIDEWALK_HALF_WIDTH)  # sidewalks
    thick(offset_curve(0.0), 75.0, 2 * _ROAD_HALF_WIDTH)  # asphalt
    thick(offset_curve(_ROAD_HALF_WIDTH + 0.1), 190.0, 0.2)  # kerbs
    thick(offset_curve(-_ROAD_HALF_WIDTH - 0.1), 190.0, 0.2)
    length = float(line.s[-1])
    for _ in range(int(length / 3)):  # asphalt repairs
        s = rng.uniform(0, length)
        xy, heading, normal = line.frame_at(np.array([s]))
        centre = xy[0] + rng.uniform(-3.0, 3.0) * normal[0]
        box = cv2.boxPoints(
            (
                (0.0, 0.0),
                (rng.uniform(0.4, 3.0), rng.uniform(0.3, 1.6)),
                float(np.degrees(heading[0])) + rng.uniform(-30, 30),
            )
        )
        cv2.fillConvexPoly(img, to_px(centre + box), round(75 + rng.uniform(-35, 45)), cv2.LINE_AA, 4)
    for _ in range(int(length / 12)):  # manholes
        xy, _, normal = line.frame_at(np.array([rng.uniform(0, length)]))
        centre = to_px(xy + rng.uniform(-2.5, 2.5) * normal)[0, 0]
        cv2.circle(
            img,
            (int(centre[0]), int(centre[1])),
            round(0.35 / res * 16),
            round(rng.uniform(20, 50)),
            -1,
            cv2.LINE_AA,
            4,
        )
    for _ in range(int(length / 4)):  # cracks
        xy, heading, normal = line.frame_at(np.array([rng.uniform(0, length)]))
        steps = np.cumsum(
            rng.normal(0, 0.3, (8, 2)) + 0.3 * np.array([math.cos(heading[0]), math.sin(heading[0])]), axis=0
        )
        thick(xy + rng.uniform(-3.2, 3.2) * normal + steps, 35.0, 0.05)
    for lateral in (-_ROAD_HALF_WIDTH + 0.25, _ROAD_HALF_WIDTH - 0.25):  # edge lines
        thick(offset_curve(lateral), 215.0, 0.15)
    dash = (line.s % 9.0) < 3.0  # centre line: 3 m dashes every 9 m
    starts = np.flatnonzero(dash[1:] & ~dash[:-1]) + 1
    for start in starts:
        stop = start + int(3.0 / _CENTRELINE_STEP)
        thick(line.xy[start:stop], 225.0, 0.15)
    return _GroundLayout(image=img, origin=origin)


def _panorama(rng: np.random.Generator, fx: float) -> np.ndarray:
    """(H_p, W_p) uint8 panorama at infinity: columns = azimuth 0..2 pi, rows = elevation max..min.

    Sampled at about one texel per pixel (W_p = 2 pi fx). Sky gradient with soft clouds, hills with trees.
    """
    wp = round(2 * np.pi * fx)
    hp = round((_PANO_ELEV_MAX - _PANO_ELEV_MIN) * fx)
    elev = _PANO_ELEV_MAX - (np.arange(hp) + 0.5) / fx  # (hp,) radians per row
    az = np.arange(wp) / wp * 2 * np.pi
    sky = 235.0 - 70.0 * np.clip(elev / _PANO_ELEV_MAX, 0, 1)[:, None] + np.zeros((1, wp))
    sky += 14.0 * cv2.resize(_periodic_noise((32, 256), rng, 2.0, 40.0), (wp, hp), interpolation=cv2.INTER_CUBIC)
    silhouette = np.full(wp, 0.03)
    for k in range(1, 40):
        silhouette += 0.035 / k * np.sin(k * az + rng.uniform(0, 2 * np.pi))
    silhouette = np.maximum(silhouette, 0.005)
    hills = 90.0 + 25.0 * cv2.resize(_periodic_noise((64, 512), rng, 2.0, 30.0), (wp, hp))
    img = np.clip(np.where(elev[:, None] < silhouette[None, :], hills, sky), 0, 255).astype(np.uint8)
    for _ in range(int(wp * 1.5)):  # trees on the hills, drawn twice across the azimuth seam
        col = int(rng.integers(0, wp))
        top = _PANO_ELEV_MAX - silhouette[col]
        row = int(top * fx + rng.uniform(-3, 25))
        radius = int(rng.integers(2, 9))
        value = round(rng.uniform(25, 150))
        for shift in (-wp, 0, wp):
            cv2.circle(img, (col + shift, row), radius, value, -1, cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), 0.6)


def _mip_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Box-filtered mip-map pyramid: level l is (H / 2^l, W / 2^l); stops before a side gets below 4."""
    pyramid = [image]
    while len(pyramid) < levels and min(pyramid[-1].shape) >= 8:
        h, w = pyramid[-1].shape
        pyramid.append(cv2.resize(pyramid[-1], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    return pyramid


# ----------------------------------------------------------------------------------------------------
# Scene geometry
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Quads:
    """Q textured rectangles in the map frame.

    Point (a, b) of rectangle q (metres, 0 <= a <= size[q, 0], 0 <= b <= size[q, 1]) is
    origin[q] + a * axis_a[q] + b * axis_b[q] (unit axes; b runs along texture rows, down on walls). It
    has atlas texel coordinates texel0[q] + (a, b) / res[q] (its texture is surrounded by `_ATLAS_PAD`
    texels of replicated border). corners: (Q, 4, 3); shade: (Q,) brightness factor; centre: (Q, 3);
    radius: (Q,) half diagonal; to_atlas: (Q, 3, 3) maps (a, b, 1) to atlas texel coordinates.
    """

    origin: np.ndarray
    axis_a: np.ndarray
    axis_b: np.ndarray
    size: np.ndarray
    texel0: np.ndarray
    res: np.ndarray
    shade: np.ndarray
    corners: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    to_atlas: np.ndarray


class _Panel(NamedTuple):
    """One textured rectangle before packing (map frame, metres).

    origin: (3,) corner at texture (0, 0); axis_a, axis_b: (3,) unit vectors along texture columns and
    rows; size: extent along them; texture: index in the texture list; along: metres of that texture
    before this rectangle along axis_a; res: metres per texel; shade: brightness factor.
    """

    origin: np.ndarray
    axis_a: np.ndarray
    axis_b: np.ndarray
    size: tuple[float, float]
    texture: int
    along: float
    res: float
    shade: float


_SUN = np.array([0.6, -0.5, 0.62]) / np.linalg.norm([0.6, -0.5, 0.62])
_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass
class _SceneParts:
    """Textures and rectangles collected while generating the scene; `grain`: (G, G) float32 texture grain."""

    grain: np.ndarray
    textures: list[np.ndarray] = field(default_factory=list)
    panels: list[_Panel] = field(default_factory=list)

    def texture(self, image: np.ndarray, rng: np.random.Generator) -> int:
        """Store a float32 texture (grain and blur added, see `_finish_texture`); returns its index."""
        self.textures.append(_finish_texture(image, self.grain, rng))
        return len(self.textures) - 1

    def panel(
        self,
        origin: np.ndarray,
        axis_a: np.ndarray,
        axis_b: np.ndarray,
        size: tuple[float, float],
        texture: int,
        res: float,
        along: float = 0.0,
    ) -> None:
        """Add a rectangle (see `_Panel`), shaded by its angle to the sun (both faces alike)."""
        shade = 0.65 + 0.4 * abs(float(np.dot(np.cross(axis_a, axis_b), _SUN)))
        self.panels.append(_Panel(origin, axis_a, axis_b, (float(size[0]), float(size[1])), texture, along, res, shade))

    def box(
        self,
        centre: np.ndarray,
        direction: np.ndarray,
        size: tuple[float, float, float],
        faces: list[np.ndarray],
        res: float,
        rng: np.random.Generator,
    ) -> None:
        """Add a box standing on the ground: four walls (textures faces[0..3]: right side, front, left
        side, back) and a roof (faces[4]). centre: (2,) map x, y; direction: (2,) unit forward; size:
        length (along direction), width, height (metres); textures: float32 at `res` metres per texel.
        """
        length, width, height = size
        left = np.array([-direction[1], direction[0]])
        corners = [
            centre + sx * 0.5 * length * direction + sy * 0.5 * width * left
            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
        ]  # counter-clockwise from the back right
        for k in range(4):
            start, stop = corners[k], corners[(k + 1) % 4]
            edge = float(np.linalg.norm(stop - start))
            axis = np.append((stop - start) / edge, 0.0)
            self.panel(np.append(start, height), axis, _DOWN, (edge, height), self.texture(faces[k], rng), res)
        self.panel(
            np.append(corners[0], height),
            np.append(direction, 0.0),
            np.append(left, 0.0),
            (length, width),
            self.texture(faces[4], rng),
            res,
        )

    def quads(self) -> tuple[_Quads, np.ndarray]:
        """Pack the textures into an atlas: the rectangles as `_Quads` and the atlas (uint8)."""
        atlas, offsets = _pack_atlas(self.textures)
        panels = self.panels
        origin = np.array([p.origin for p in panels])
        axis_a = np.array([p.axis_a for p in panels])
        axis_b = np.array([p.axis_b for p in panels])
        size = np.array([p.size for p in panels])
        res = np.array([p.res for p in panels])
        texel0 = offsets[[p.texture for p in panels]].astype(np.float64)
        texel0[:, 0] += np.array([p.along for p in panels]) / res
        along_a, along_b = size[:, :1] * axis_a, size[:, 1:] * axis_b
        corners = np.stack([origin, origin + along_a, origin + along_a + along_b, origin + along_b], axis=1)
        shades = np.array([p.shade for p in panels])
        to_atlas = np.zeros((len(panels), 3, 3))
        to_atlas[:, 0, 0] = to_atlas[:, 1, 1] = 1.0 / res
        to_atlas[:, :2, 2] = texel0
        to_atlas[:, 2, 2] = 1.0
        centre, radius = corners.mean(axis=1), 0.5 * np.linalg.norm(size, axis=1)
        quads = _Quads(origin, axis_a, axis_b, size, texel0, res, shades, corners, centre, radius, to_atlas)
        return quads, atlas


def _add_buildings(parts: _SceneParts, line: _Centreline, side: float, rng: np.random.Generator) -> None:
    """Buildings along one side of the road (side +1 left, -1 right): blocks of 10..25 m, 5..12 m from the
    centreline, 6..22 m high, with gaps; a façade following the road (chords of the curve) and side walls.
    """
    length = float(line.s[-1])
    s = 0.0
    while s < length:
        if rng.random() < 0.22:
            s += rng.uniform(4.0, 10.0)
            continue
        blen = min(rng.uniform(10.0, 25.0), length - s)
        if blen < 4.0:
            break
        offset, height = rng.uniform(5.0, 12.0), rng.uniform(6.0, 22.0)
        kappa = float(np.max(np.abs(line.curvature[(line.s >= s) & (line.s <= s + blen)]), initial=0.0))
        kappa /= 1.0 - offset * kappa  # worst case: the inside of the curve
        max_panel = math.sqrt(8.0 * 0.05 / kappa) if kappa > 1e-6 else blen  # sagitta <= 5 cm
        knots = np.linspace(s, s + blen, max(1, math.ceil(blen / max_panel)) + 1)
        xy, _, normal = line.frame_at(knots)
        facade = xy + side * offset * normal  # (k, 2)
        chords = np.linalg.norm(np.diff(facade, axis=0), axis=1)
        texture = parts.texture(_facade_texture(float(chords.sum()), height, rng), rng)
        along = 0.0
        for k, chord in enumerate(chords):
            axis = np.append((facade[k + 1] - facade[k]) / chord, 0.0)
            parts.panel(np.append(facade[k], height), axis, _DOWN, (chord, height), texture, _FACADE_RES, along)
            along += chord
        depth = rng.uniform(6.0, 10.0)
        for end in (0, -1):  # side walls, perpendicular to the road, going away from it
            texture = parts.texture(_sidewall_texture(depth, height, rng), rng)
            axis = np.append(side * normal[end], 0.0)
            parts.panel(np.append(facade[end], height), axis, _DOWN, (depth, height), texture, _SIDEWALL_RES)
        s += blen


def _add_furniture(parts: _SceneParts, line: _Centreline, side: float, rng: np.random.Generator) -> None:
    """Street furniture on one sidewalk, every 6..14 m: road signs on poles, poster boards and kiosks.

    They face along the road, so the camera sees them head-on at mid range: well-conditioned features.
    """
    length = float(line.s[-1])
    res = _FURNITURE_RES
    s = rng.uniform(2.0, 10.0)
    while s < length - 2.0:
        xy, heading, normal = line.frame_at(np.array([s]))
        direction = np.array([math.cos(heading[0]), math.sin(heading[0])])
        across = np.append(side * normal[0], 0.0)  # horizontal, away from the road
        kind = rng.random()
        if kind < 0.45:  # sign on a pole
            w, h, bottom = rng.uniform(0.45, 0.9), rng.uniform(0.4, 0.9), rng.uniform(2.0, 2.6)
            pole = xy[0] + side * rng.uniform(3.9, 4.3) * normal[0]
            _board_on_post(parts, pole - 0.5 * w * across[:2], (w, h), bottom, pole - 0.05 * across[:2], 0.1,
                           across, rng, res)
        elif kind < 0.75:  # poster board on a post
            w, h, bottom = rng.uniform(0.8, 1.2), rng.uniform(1.2, 1.8), rng.uniform(0.3, 0.6)
            inner = xy[0] + side * 3.8 * normal[0]
            _board_on_post(parts, inner, (w, h), bottom, inner + (0.5 * w - 0.06) * across[:2], 0.12, across, rng, res)
        else:  # kiosk / advertising column
            size = (rng.uniform(0.8, 1.2), rng.uniform(0.8, 1.0), rng.uniform(2.0, 2.7))
            centre = xy[0] + side * (3.8 + 0.5 * size[1]) * normal[0]
            faces = [
                _poster_texture(size[0], size[2], rng, res),
                _poster_texture(size[1], size[2], rng, res),
                _poster_texture(size[0], size[2], rng, res),
                _poster_texture(size[1], size[2], rng, res),
                _plain_texture(size[0], size[1], rng, res),
            ]
            parts.box(centre, direction, size, faces, res, rng)
        s += rng.uniform(6.0, 14.0)


def _board_on_post(
    parts: _SceneParts, board_xy: np.ndarray, board: tuple[float, float], bottom: float, post_xy: np.ndarray,
    post_width: float, across: np.ndarray, rng: np.random.Generator, res: float,
) -> None:
    """A (w, h) poster board whose left edge stands at ground position `board_xy` with its lower edge
    `bottom` metres up, on a `post_width` post from the ground to that edge at `post_xy`; both face the
    road (`across` is horizontal, away from it)."""
    w, h = board
    parts.panel(np.append(board_xy, bottom + h), across, _DOWN, (w, h),
                parts.texture(_poster_texture(w, h, rng, res), rng), res)
    parts.panel(np.append(post_xy, bottom), across, _DOWN, (post_width, bottom),
                parts.texture(_plain_texture(post_width, bottom, rng, res), rng), res)


def _add_vehicles(parts: _SceneParts, line: _Centreline, rng: np.random.Generator) -> None:
    """Parked cars and vans along the left kerb (the opposite lane; the camera drives in the right one)."""
    length = float(line.s[-1])
    res = _FURNITURE_RES * 1.5
    s = rng.uniform(5.0, 20.0)
    while s < length - 4.0:
        if rng.random() < 0.6:
            van = rng.random() < 0.25
            size = (
                rng.uniform(4.8, 5.8) if van else rng.uniform(3.8, 4.8),
                rng.uniform(1.7, 1.9),
                rng.uniform(1.9, 2.3) if van else rng.uniform(1.35, 1.55),
            )
            xy, heading, normal = line.frame_at(np.array([s + 0.5 * size[0]]))
            direction = np.array([math.cos(heading[0]), math.sin(heading[0])])
            centre = xy[0] + (_ROAD_HALF_WIDTH - 0.2 - 0.5 * size[1]) * normal[0]
            body = rng.uniform(30, 230)
            faces = [
                _vehicle_side(size[0], size[2], body, rng, res),
                _vehicle_end(size[1], size[2], body, rng, res),
                _vehicle_side(size[0], size[2], body, rng, res),
                _vehicle_end(size[1], size[2], body, rng, res),
                _plain_texture(size[0], size[1], rng, res, body),
            ]
            parts.box(centre, direction, size, faces, res, rng)
            s += size[0] + rng.uniform(0.8, 3.0)
        else:
            s += rng.uniform(5.0, 25.0)


def _build_street(line: _Centreline, rngs: list[np.random.Generator]) -> tuple[_Quads, np.ndarray]:
    """Buildings, street furniture and parked vehicles -> their rectangles and the texture atlas (uint8).

    rngs: 6 independent generators (texture grain; left and right buildings; left and right furniture;
    vehicles), so that a longer road only appends objects.
    """
    parts = _SceneParts(grain=rngs[0].normal(0.0, 7.0, (1024, 1024)).astype(np.float32))
    _add_buildings(parts, line, 1.0, rngs[1])
    _add_buildings(parts, line, -1.0, rngs[2])
    _add_furniture(parts, line, 1.0, rngs[3])
    _add_furniture(parts, line, -1.0, rngs[4])
    _add_vehicles(parts, line, rngs[5])
    return parts.quads()


# ----------------------------------------------------------------------------------------------------
# Rendering helpers
# ----------------------------------------------------------------------------------------------------


def _surface_homography(
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


def _surface_coords(g: np.ndarray, u: np.ndarray, v: np.ndarray) -> _Footprints:
    """Surface coordinates and pixel footprints of pixels (u, v) (n,) float32.

    g: (9, n) or (9, 1) float32 row-major homographies, pixel -> surface coordinates (see
    `_surface_homography`); the derivatives are exact for the homography.
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


def _remap_points(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
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


def _sample_aniso(
    pyramid: list[np.ndarray], fp: _Footprints, scale: float, offset: tuple[float, float], wrap: int = 0
) -> np.ndarray:
    """Anisotropic trilinear sample (n,) float32 of a texture at texel coordinates fp.{x, y} * scale + offset.

    pyramid: mip levels of the texture (`_mip_pyramid`, at least two). `_ANISO_TAPS` taps spread along
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
            acc[start:stop] += weight * _remap_points(pyramid[level], xl, yl)
    out = np.empty_like(acc)
    out[order] = acc
    return out


def _pixel_boxes(corners_c: np.ndarray, k: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel bounding boxes (n, 4) int (u0, v0, u1, v1; end exclusive; empty when u0 >= u1 or v0 >= v1)
    of n quadrilaterals (n, 4, 3) in camera coordinates, clipped at depth `_NEAR`, within the image.
    """
    boxes = np.zeros((len(corners_c), 4), np.int64)
    in_front = corners_c[:, :, 2].min(axis=1) >= _NEAR
    if in_front.any():  # the common case, vectorised
        uvw = corners_c[in_front] @ k.T
        uv = uvw[:, :, :2] / uvw[:, :, 2:]
        boxes[in_front, :2] = np.floor(uv.min(axis=1)) - 1
        boxes[in_front, 2:] = np.ceil(uv.max(axis=1)) + 2
    for i in np.flatnonzero(~in_front):  # crossing the near plane: clip the polygon first
        pts: list[np.ndarray] = []
        for j in range(4):
            p, q = corners_c[i, j], corners_c[i, (j + 1) % 4]
            if p[2] >= _NEAR:
                pts.append(p)
            if (p[2] >= _NEAR) != (q[2] >= _NEAR):
                pts.append(p + (_NEAR - p[2]) / (q[2] - p[2]) * (q - p))
        uvw = np.array(pts) @ k.T
        uv = uvw[:, :2] / uvw[:, 2:]
        boxes[i, :2] = np.floor(uv.min(axis=0)) - 1
        boxes[i, 2:] = np.ceil(uv.max(axis=0)) + 2
    np.clip(boxes, 0, [width, height, width, height], out=boxes)
    return boxes


# ----------------------------------------------------------------------------------------------------
# The source
# ----------------------------------------------------------------------------------------------------


class SyntheticStreet:
    """Procedurally generated street, rendered deterministically from `seed` (a `FrameSource`).

    n_frames: number of source frames (the path length is about n_frames metres).
    frames: selection among them (`FrameRange.indices(n_frames)`, SourceError when out of range).
    camera_height: metres between the camera centre and the road plane.
    """

    def __init__(
        self, n_frames: int = 300, frames: FrameRange | None = None, seed: int = 0, camera_height: float = 1.65
    ) -> None:
        if not 1 <= n_frames <= _MAX_FRAMES:
            raise SourceError(f"synthetic street: n_frames must be in 1..{_MAX_FRAMES}, got {n_frames}")
        self.n_frames = n_frames
        self.seed = seed
        self.camera_height = float(camera_height)
        self._indices = (frames or FrameRange()).indices(n_frames)
        # Independent streams: the road, path and buildings of a shorter run are a prefix of a longer one's.
        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(11)]
        intr = _INTRINSICS
        self._k = intr.K
        self._line = _make_centreline(_START_S + 1.25 * n_frames + _LOOK_AHEAD, rngs[0])
        self._poses_map = _camera_path(self._line, n_frames, self.camera_height, rngs[1])
        self._quads, atlas = _build_street(self._line, rngs[2:8])
        self._atlas = _mip_pyramid(atlas, _MIP_LEVELS)
        layout = _ground_layout(self._line, rngs[8])
        self._ground_origin = layout.origin
        self._ground = _mip_pyramid(layout.image, _MIP_LEVELS)
        tile = _mip_pyramid(_ground_fine_tile(rngs[9]), 9)
        self._fine = [cv2.copyMakeBorder(t, 2, 2, 2, 2, cv2.BORDER_WRAP) for t in tile]
        pano = _panorama(rngs[10], intr.fx)
        self._pano = cv2.copyMakeBorder(pano, 0, 0, 2, 2, cv2.BORDER_WRAP)
        self._pano_width = pano.shape[1]
        v, u = np.mgrid[0 : intr.height, 0 : intr.width]
        self._u = u.ravel().astype(np.float32)  # (H*W,) pixel column of each flat index
        self._v = v.ravel().astype(np.float32)
        self._ground_truth = rebase_poses(self._poses_map[self._indices])

    @property
    def name(self) -> str:
        return "synthetic-street"

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return _INTRINSICS

    @property
    def ground_truth(self) -> np.ndarray:
        """(N, 4, 4) float64 T_w_c of the selected frames, world = camera of the first selected frame."""
        return self._ground_truth.copy()

    @property
    def ground_plane(self) -> np.ndarray:
        """(4,) float64 (n_x, n_y, n_z, d): the road plane n . X + d = 0 in world coordinates.

        n is the unit normal pointing up (towards the cameras); d = `camera_height`, the first selected
        camera's distance to the road. n = (0, -1, 0) when that camera has no pitch or roll.
        """
        r_m_c0 = self._poses_map[self._indices[0], :3, :3] if self._indices else np.eye(3)
        return np.append(r_m_c0[2, :], self.camera_height)  # R_c0_m . z_map = third row of R_m_c0

    @property
    def indices(self) -> list[int]:
        """Source indices of the selected frames."""
        return list(self._indices)

    def __len__(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[Frame]:
        for index in self._indices:
            yield Frame(index=index, timestamp=index * _FRAME_DT, image=self.render(index))

    def render(self, index: int) -> np.ndarray:
        """(H, W) uint8 grey image of source frame `index` (0 <= index < n_frames)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range 0..{self.n_frames - 1}")
        intr = _INTRINSICS
        pose = self._poses_map[index]
        r_cm = pose[:3, :3].T
        position = pose[:3, 3]
        t_cm = -r_cm @ position
        ids, ground_g, facade_g = self._visibility(r_cm, t_cm, position)
        out = np.empty(intr.height * intr.width, np.float32)
        flat_ids = ids.ravel()
        self._shade_ground(out, np.flatnonzero(flat_ids == 0), ground_g, position)
        self._shade_sky(out, np.flatnonzero(flat_ids < 0), r_cm)
        self._shade_facades(out, flat_ids, facade_g)
        image = cv2.GaussianBlur(out.reshape(intr.height, intr.width), (0, 0), 0.5)  # soften silhouettes
        return np.clip(image + 0.5, 0, 255).astype(np.uint8)

    # -- rendering steps --------------------------------------------------------------------------

    def _visibility(
        self, r_cm: np.ndarray, t_cm: np.ndarray, position: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Z-buffer pass for the camera with map -> camera transform (r_cm, t_cm) at map `position` (3,).

        Returns the id of the surface seen per pixel (H, W) int32 (-1 sky, 0 ground, q + 1 rectangle q);
        the ground homography (3, 3): pixel -> map (x, y) relative to the camera position, third row =
        inverse depth; and per id the homography pixel -> atlas texel coordinates, (9, Q + 1) float32
        row-major (zero for rectangles not drawn).
        """
        intr = _INTRINSICS
        w, h = intr.width, intr.height
        u = np.arange(w, dtype=np.float32)[None, :]
        v = np.arange(h, dtype=np.float32)[:, None]
        ground_g = _surface_homography(
            self._k,
            r_cm,
            t_cm,
            np.array([position[0], position[1], 0.0]),
            np.array([1.0, 0.0, 0.0]),
            np.array([0.0, 1.0, 0.0]),
        )
        assert ground_g is not None  # the camera is above the ground
        inv_z = ((ground_g[2, 0] * u + ground_g[2, 2]) + ground_g[2, 1] * v).astype(np.float32)
        ground = inv_z > 1.0 / _GROUND_FAR
        zbuf = np.where(ground, inv_z, np.float32(0.0)).astype(np.float32)
        ids = np.where(ground, 0, -1).astype(np.int32)

        quads = self._quads
        corners_c = (quads.corners - position) @ r_cm.T  # (Q, 4, 3) camera coordinates
        distance = np.maximum(np.linalg.norm(quads.centre - position, axis=1) - quads.radius, _NEAR)
        candidates = np.flatnonzero((distance < _FAR) & (corners_c[:, :, 2].max(axis=1) > _NEAR))
        # Pixel -> (a, b, 1/z) homographies of all candidates (see `_surface_homography`), then -> atlas.
        m = np.stack(
            [quads.axis_a[candidates] @ r_cm.T, quads.axis_b[candidates] @ r_cm.T, corners_c[candidates, 0]], axis=2
        )
        h_all = self._k @ m
        solvable = np.abs(np.linalg.det(h_all)) > 1e-12
        candidates, h_all = candidates[solvable], h_all[solvable]
        g_all = np.linalg.inv(h_all)  # (n, 3, 3)
        facade_g = np.zeros((9, len(quads.size) + 1), np.float32)
        facade_g[:, candidates + 1] = (quads.to_atlas[candidates] @ g_all).reshape(-1, 9).T
        boxes = _pixel_boxes(corners_c[candidates], self._k, w, h)
        for q, g, (u0, v0, u1, v1) in zip(candidates, g_all.astype(np.float32), boxes, strict=True):
            if u0 >= u1 or v0 >= v1:
                continue
            uu, vv = u[:, u0:u1], v[v0:v1]
            c = g[2, 0] * uu + (g[2, 1] * vv + g[2, 2])
            na = g[0, 0] * uu + (g[0, 1] * vv + g[0, 2])
            nb = g[1, 0] * uu + (g[1, 1] * vv + g[1, 2])
            zview, iview = zbuf[v0:v1, u0:u1], ids[v0:v1, u0:u1]
            # Inside test a in [0, length], b in [0, height] (times c > 0), widened by 1 mm so that rounding
            # never leaves a crack between adjacent rectangles.
            hit = c > zview
            hit &= na >= np.float32(-1e-3) * c
            hit &= na <= np.float32(quads.size[q, 0] + 1e-3) * c
            hit &= nb >= np.float32(-1e-3) * c
            hit &= nb <= np.float32(quads.size[q, 1] + 1e-3) * c
            np.copyto(zview, c, where=hit)
            np.copyto(iview, q + 1, where=hit)
        return ids, ground_g, facade_g

    def _shade_ground(self, out: np.ndarray, idx: np.ndarray, g: np.ndarray, position: np.ndarray) -> None:
        """Write the ground's grey values into out (H*W,) at flat pixel indices idx (layout + speckle)."""
        fp = _surface_coords(g.astype(np.float32).reshape(9, 1), self._u[idx], self._v[idx])
        res = _COARSE_RES
        layout = _sample_aniso(
            self._ground,
            fp,
            1.0 / res,
            ((position[0] - self._ground_origin[0]) / res - 0.5, (position[1] - self._ground_origin[1]) / res - 0.5),
        )
        fres = _FINE_RES
        fine = _sample_aniso(
            self._fine,
            fp,
            1.0 / fres,
            ((position[0] / fres) % _FINE_TILE, (position[1] / fres) % _FINE_TILE),
            wrap=_FINE_TILE,
        )
        out[idx] = layout + _SPECKLE_CONTRAST * (fine - 128.0)

    def _shade_sky(self, out: np.ndarray, idx: np.ndarray, r_cm: np.ndarray) -> None:
        """Write the panorama at infinity into out (H*W,) at flat pixel indices idx."""
        intr = _INTRINSICS
        xr = (self._u[idx] - intr.cx) / intr.fx
        yr = (self._v[idx] - intr.cy) / intr.fy
        r = r_cm.T.astype(np.float32)  # camera -> map rotation
        dx = r[0, 0] * xr + r[0, 1] * yr + r[0, 2]
        dy = r[1, 0] * xr + r[1, 1] * yr + r[1, 2]
        dz = r[2, 0] * xr + r[2, 1] * yr + r[2, 2]
        az = np.mod(np.arctan2(dy, dx), 2 * np.pi)
        el = np.arctan2(dz, np.hypot(dx, dy))
        px = az * (self._pano_width / (2 * np.pi)) + 1.5  # +2 pad, -0.5 texel centre
        py = (_PANO_ELEV_MAX - el) * intr.fx - 0.5
        out[idx] = _remap_points(self._pano, px.astype(np.float32), py.astype(np.float32))

    def _shade_facades(self, out: np.ndarray, flat_ids: np.ndarray, facade_g: np.ndarray) -> None:
        """Write the rectangles' textures into out (H*W,) where flat_ids (H*W,) > 0 (see `_visibility`)."""
        idx = np.flatnonzero(flat_ids > 0)
        if idx.size == 0:
            return
        ids = flat_ids[idx]
        fp = _surface_coords(facade_g[:, ids], self._u[idx], self._v[idx])
        out[idx] = _sample_aniso(self._atlas, fp, 1.0, (-0.5, -0.5)) * self._quads.shade.astype(np.float32)[ids - 1]
