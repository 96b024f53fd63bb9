"""Synthetic street: the scene as textured rectangles (buildings, street furniture, parked vehicles) and the
ground layout texture, in the map frame M."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from vslam_core.sources.synthetic.road import CENTRELINE_STEP, ROAD_HALF_WIDTH, SIDEWALK_HALF_WIDTH, Centreline
from vslam_core.sources.synthetic.textures import (
    FACADE_RES,
    FURNITURE_RES,
    SIDEWALL_RES,
    facade_texture,
    finish_texture,
    pack_atlas,
    plain_texture,
    poster_texture,
    sidewall_texture,
    smooth_field,
    vehicle_end,
    vehicle_side,
)

COARSE_RES = 0.1  # ground layout texture (road, markings, patches)


@dataclass(frozen=True)
class _GroundLayout:
    """Ground layout texture in the map frame: texel (x, y) covers map point origin + (x, y) * res.

    image: (H, W) uint8; origin: (2,) map x, y of texel (0, 0).
    """

    image: np.ndarray
    origin: np.ndarray


def ground_layout(line: Centreline, rng: np.random.Generator) -> _GroundLayout:
    """Draw verges, sidewalks, the road, repair patches, manholes, cracks and lane markings (map frame).

    The texture covers the centreline's bounding box plus 40 m, at `COARSE_RES` metres per texel.
    """
    res = COARSE_RES
    origin = line.xy.min(axis=0) - 40.0
    extent = np.ceil((line.xy.max(axis=0) + 40.0 - origin) / res / 64).astype(int) * 64
    w, h = int(extent[0]), int(extent[1])
    half = (h // 2, w // 2)  # the smooth base is made at half resolution, then upsampled
    base = 22.0 * smooth_field(half, 15, rng)
    base += 10.0 * smooth_field(half, 3, rng) + 105.0
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

    thick(offset_curve(0.0), 150.0, 2 * SIDEWALK_HALF_WIDTH)  # sidewalks
    thick(offset_curve(0.0), 75.0, 2 * ROAD_HALF_WIDTH)  # asphalt
    thick(offset_curve(ROAD_HALF_WIDTH + 0.1), 190.0, 0.2)  # kerbs
    thick(offset_curve(-ROAD_HALF_WIDTH - 0.1), 190.0, 0.2)
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
    for lateral in (-ROAD_HALF_WIDTH + 0.25, ROAD_HALF_WIDTH - 0.25):  # edge lines
        thick(offset_curve(lateral), 215.0, 0.15)
    dash = (line.s % 9.0) < 3.0  # centre line: 3 m dashes every 9 m
    starts = np.flatnonzero(dash[1:] & ~dash[:-1]) + 1
    for start in starts:
        stop = start + int(3.0 / CENTRELINE_STEP)
        thick(line.xy[start:stop], 225.0, 0.15)
    return _GroundLayout(image=img, origin=origin)


@dataclass(frozen=True)
class _Quads:
    """Q textured rectangles in the map frame.

    Point (a, b) of rectangle q (metres, 0 <= a <= size[q, 0], 0 <= b <= size[q, 1]) is
    origin[q] + a * axis_a[q] + b * axis_b[q] (unit axes; b runs along texture rows, down on walls). It
    has atlas texel coordinates texel0[q] + (a, b) / res[q] (its texture is surrounded by `ATLAS_PAD`
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
        """Store a float32 texture (grain and blur added, see `finish_texture`); returns its index."""
        self.textures.append(finish_texture(image, self.grain, rng))
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
        atlas, offsets = pack_atlas(self.textures)
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


def _add_buildings(parts: _SceneParts, line: Centreline, side: float, rng: np.random.Generator) -> None:
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
        texture = parts.texture(facade_texture(float(chords.sum()), height, rng), rng)
        along = 0.0
        for k, chord in enumerate(chords):
            axis = np.append((facade[k + 1] - facade[k]) / chord, 0.0)
            parts.panel(np.append(facade[k], height), axis, _DOWN, (chord, height), texture, FACADE_RES, along)
            along += chord
        depth = rng.uniform(6.0, 10.0)
        for end in (0, -1):  # side walls, perpendicular to the road, going away from it
            texture = parts.texture(sidewall_texture(depth, height, rng), rng)
            axis = np.append(side * normal[end], 0.0)
            parts.panel(np.append(facade[end], height), axis, _DOWN, (depth, height), texture, SIDEWALL_RES)
        s += blen


def _add_furniture(parts: _SceneParts, line: Centreline, side: float, rng: np.random.Generator) -> None:
    """Street furniture on one sidewalk, every 6..14 m: road signs on poles, poster boards and kiosks.

    They face along the road, so the camera sees them head-on at mid range: well-conditioned features.
    """
    length = float(line.s[-1])
    res = FURNITURE_RES
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
                poster_texture(size[0], size[2], rng, res),
                poster_texture(size[1], size[2], rng, res),
                poster_texture(size[0], size[2], rng, res),
                poster_texture(size[1], size[2], rng, res),
                plain_texture(size[0], size[1], rng, res),
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
                parts.texture(poster_texture(w, h, rng, res), rng), res)
    parts.panel(np.append(post_xy, bottom), across, _DOWN, (post_width, bottom),
                parts.texture(plain_texture(post_width, bottom, rng, res), rng), res)


def _add_vehicles(parts: _SceneParts, line: Centreline, rng: np.random.Generator) -> None:
    """Parked cars and vans along the left kerb (the opposite lane; the camera drives in the right one)."""
    length = float(line.s[-1])
    res = FURNITURE_RES * 1.5
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
            centre = xy[0] + (ROAD_HALF_WIDTH - 0.2 - 0.5 * size[1]) * normal[0]
            body = rng.uniform(30, 230)
            faces = [
                vehicle_side(size[0], size[2], body, rng, res),
                vehicle_end(size[1], size[2], body, rng, res),
                vehicle_side(size[0], size[2], body, rng, res),
                vehicle_end(size[1], size[2], body, rng, res),
                plain_texture(size[0], size[1], rng, res, body),
            ]
            parts.box(centre, direction, size, faces, res, rng)
            s += size[0] + rng.uniform(0.8, 3.0)
        else:
            s += rng.uniform(5.0, 25.0)


def build_street(line: Centreline, rngs: list[np.random.Generator]) -> tuple[_Quads, np.ndarray]:
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
