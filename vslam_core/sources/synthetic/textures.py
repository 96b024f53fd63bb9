"""Synthetic street: procedural textures (walls, façades, posters, vehicles, ground speckle, panorama),
the texture atlas and mip-map pyramids. All deterministic in the generators they are given."""

from __future__ import annotations

import math

import cv2
import numpy as np

FACADE_RES = 0.04  # metres per texel
SIDEWALL_RES = 0.06
FURNITURE_RES = 0.02
FINE_TILE = 1024
_ATLAS_MIN_WIDTH = 4096
ATLAS_PAD = 16
_PANO_ELEV_MIN = -0.12  # radians
PANO_ELEV_MAX = 0.6


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


def smooth_field(shape: tuple[int, int], cell: int, rng: np.random.Generator) -> np.ndarray:
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
    img = np.full(shape, wall, np.float32) + 9.0 * smooth_field(shape, 40, rng)
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
        img += 7.0 * smooth_field(shape, 5, rng)
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


def facade_texture(length: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture of a street façade `length` x `height` metres (row 0 = top of building).

    Random bays and floors; every window differs (glass, curtains, mullions), shops on the ground floor.
    """
    res = FACADE_RES
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


def sidewall_texture(depth: float, height: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture of a building's side wall: plaster, a few windows, a drain pipe."""
    res = SIDEWALL_RES
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


def plain_texture(w: float, h: float, rng: np.random.Generator, res: float, value: float | None = None) -> np.ndarray:
    """(H, W) float32 plain surface `w` x `h` metres (poles, roofs) with slight smooth variation."""
    shape = (max(4, math.ceil(h / res)), max(4, math.ceil(w / res)))
    base = rng.uniform(40, 200) if value is None else value
    return np.full(shape, base, np.float32) + 10.0 * smooth_field(shape, 20, rng)


def poster_texture(w: float, h: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 high-contrast poster or sign `w` x `h` metres: frame, picture blocks, text lines."""
    img = plain_texture(w, h, rng, res, rng.uniform(20, 235))
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


def vehicle_side(length: float, height: float, body: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 side of a car or van: body, window band with pillars, door seams, wheels."""
    img = plain_texture(length, height, rng, res, body)
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


def vehicle_end(width: float, height: float, body: float, rng: np.random.Generator, res: float) -> np.ndarray:
    """(H, W) float32 front or back of a vehicle: window, lights, number plate, bumper."""
    img = plain_texture(width, height, rng, res, body)
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


def finish_texture(tex: np.ndarray, grain: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 texture -> uint8, with a random window of the (G, G) `grain` added and a slight blur."""
    h, w = tex.shape
    if h > grain.shape[0] or w > grain.shape[1]:  # never with the sizes used here
        grain = np.tile(grain, (h // grain.shape[0] + 1, w // grain.shape[1] + 1))
    gy, gx = int(rng.integers(0, grain.shape[0] - h + 1)), int(rng.integers(0, grain.shape[1] - w + 1))
    blurred = cv2.GaussianBlur(tex + grain[gy : gy + h, gx : gx + w], (0, 0), 0.7)
    return np.clip(blurred, 0, 255, out=blurred).astype(np.uint8)


def pack_atlas(textures: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Shelf-pack (H_i, W_i) uint8 textures into one atlas.

    Returns the atlas (H_a, W_a) uint8 and each texture's top-left texel (n, 2) as (x, y). W_a is at
    least `_ATLAS_MIN_WIDTH`, wider for long streets so that H_a stays below cv2.remap's 32767 limit.
    Textures are separated by `ATLAS_PAD` texels of replicated border (limits mip-map bleeding).
    """
    area = sum((t.shape[0] + 2 * ATLAS_PAD) * (t.shape[1] + 2 * ATLAS_PAD) for t in textures)
    width = max(_ATLAS_MIN_WIDTH, math.ceil(math.sqrt(2.0 * area) / 1024) * 1024)
    offsets = np.zeros((len(textures), 2), np.int64)
    x = y = shelf = 0
    for k, tex in enumerate(textures):
        h, w = tex.shape
        if x + w + 2 * ATLAS_PAD > width:
            x, y, shelf = 0, y + shelf, 0
        offsets[k] = (x + ATLAS_PAD, y + ATLAS_PAD)
        x += w + 2 * ATLAS_PAD
        shelf = max(shelf, h + 2 * ATLAS_PAD)
    height = -(-(y + shelf) // 64) * 64
    atlas = np.full((height, width), 128, np.uint8)
    for (ox, oy), tex in zip(offsets, textures, strict=True):
        h, w = tex.shape
        padded = cv2.copyMakeBorder(tex, ATLAS_PAD, ATLAS_PAD, ATLAS_PAD, ATLAS_PAD, cv2.BORDER_REPLICATE)
        atlas[oy - ATLAS_PAD : oy + h + ATLAS_PAD, ox - ATLAS_PAD : ox + w + ATLAS_PAD] = padded
    return atlas, offsets


def ground_fine_tile(rng: np.random.Generator) -> np.ndarray:
    """(FINE_TILE, FINE_TILE) uint8 tileable high-contrast mottled speckle (asphalt grain), ~128 mean."""
    blobs = _periodic_noise((FINE_TILE, FINE_TILE), rng, 3.0, 60.0)
    grain = _periodic_noise((FINE_TILE, FINE_TILE), rng, 2.0, 5.0)
    value = 128.0 + 110.0 * np.tanh(1.3 * blobs) + 18.0 * grain
    return np.clip(value, 0, 255).astype(np.uint8)


def panorama(rng: np.random.Generator, fx: float) -> np.ndarray:
    """(H_p, W_p) uint8 panorama at infinity: columns = azimuth 0..2 pi, rows = elevation max..min.

    Sampled at about one texel per pixel (W_p = 2 pi fx). Sky gradient with soft clouds, hills with trees.
    """
    wp = round(2 * np.pi * fx)
    hp = round((PANO_ELEV_MAX - _PANO_ELEV_MIN) * fx)
    elev = PANO_ELEV_MAX - (np.arange(hp) + 0.5) / fx  # (hp,) radians per row
    az = np.arange(wp) / wp * 2 * np.pi
    sky = 235.0 - 70.0 * np.clip(elev / PANO_ELEV_MAX, 0, 1)[:, None] + np.zeros((1, wp))
    sky += 14.0 * cv2.resize(_periodic_noise((32, 256), rng, 2.0, 40.0), (wp, hp), interpolation=cv2.INTER_CUBIC)
    silhouette = np.full(wp, 0.03)
    for k in range(1, 40):
        silhouette += 0.035 / k * np.sin(k * az + rng.uniform(0, 2 * np.pi))
    silhouette = np.maximum(silhouette, 0.005)
    hills = 90.0 + 25.0 * cv2.resize(_periodic_noise((64, 512), rng, 2.0, 30.0), (wp, hp))
    img = np.clip(np.where(elev[:, None] < silhouette[None, :], hills, sky), 0, 255).astype(np.uint8)
    for _ in range(int(wp * 1.5)):  # trees on the hills, drawn twice across the azimuth seam
        col = int(rng.integers(0, wp))
        top = PANO_ELEV_MAX - silhouette[col]
        row = int(top * fx + rng.uniform(-3, 25))
        radius = int(rng.integers(2, 9))
        value = round(rng.uniform(25, 150))
        for shift in (-wp, 0, wp):
            cv2.circle(img, (col + shift, row), radius, value, -1, cv2.LINE_AA)
    return cv2.GaussianBlur(img, (0, 0), 0.6)


def mip_pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """Box-filtered mip-map pyramid: level l is (H / 2^l, W / 2^l); stops before a side gets below 4."""
    pyramid = [image]
    while len(pyramid) < levels and min(pyramid[-1].shape) >= 8:
        h, w = pyramid[-1].shape
        pyramid.append(cv2.resize(pyramid[-1], (w // 2, h // 2), interpolation=cv2.INTER_AREA))
    return pyramid
