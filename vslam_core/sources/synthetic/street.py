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

The package follows those steps: `road` (centreline, camera path), `textures` (procedural images, atlas,
mip-maps), `scene` (rectangles and the ground layout), `raster` (ray-casting helpers) and this module, the
source that renders a frame from them (its temporary arrays in a reused `scratch.Scratch`).
"""

from __future__ import annotations

import dataclasses
import functools
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, rebase_poses
from vslam_core.sources.synthetic import frame_cache
from vslam_core.sources.synthetic.raster import (
    NEAR,
    pixel_boxes,
    remap_points,
    sample_aniso,
    surface_coords,
    surface_homography,
)
from vslam_core.sources.synthetic.road import (
    DRIVE_PLAN,
    START_S,
    WALK_STEP,
    Centreline,
    camera_path,
    drive_path,
    make_centreline,
    make_loop_centreline,
    walk_path,
)
from vslam_core.sources.synthetic.scene import COARSE_RES, _Quads, build_street, ground_layout
from vslam_core.sources.synthetic.scratch import Scratch
from vslam_core.sources.synthetic.textures import FINE_TILE, PANO_ELEV_MAX, ground_fine_tile, mip_pyramid, panorama

_INTRINSICS = CameraIntrinsics(fx=718.856, fy=718.856, cx=607.1928, cy=185.2157, width=1241, height=376,
                              origin="the synthetic street (KITTI 00's camera)")
_FRAME_DT = {"street": 0.1, "loop": 0.1, "walk": 1 / 30, "drive": 0.1}  # seconds between frames, by route
_LOOK_AHEAD = 130.0  # scene generated beyond the last camera position
_FAR = 100.0  # metres; rectangles whose nearest point is farther are culled
_GROUND_FAR = 300.0  # metres; farther ground shows the panorama (hills) instead
_FINE_RES = 0.015  # ground speckle tile
_SPECKLE_CONTRAST = 0.45  # ground speckle amplitude, about +-55 grey levels
_MIP_LEVELS = 7
_MAX_FRAMES = 2000  # textures must stay under cv2.remap's 32767-texel limit (and memory reasonable)
#: On a closed circuit the scene does not grow with the frames (the textures are the circuit's): an hour at 10 Hz.
_MAX_FRAMES_CLOSED = 36000
_SCRATCH = threading.local()  # .memory: the `Scratch` of this thread's renderings (~50 MB at full size)
Route = Literal["street", "loop", "walk", "drive"]
#: route -> default number of frames ("drive": KITTI 00's length, 4541)
ROUTES: dict[str, int] = {"street": 300, "loop": 660, "walk": 450, "drive": 4541}
#: The routes round a closed circuit: their scene is the circuit's, whatever the number of frames.
CLOSED_ROUTES = ("loop", "drive")


def _scaled(intrinsics: CameraIntrinsics, factor: float) -> CameraIntrinsics:
    """The camera with images `factor` times as wide and high (pixel centres at integer coordinates)."""
    return CameraIntrinsics(fx=intrinsics.fx * factor, fy=intrinsics.fy * factor,
                            cx=(intrinsics.cx + 0.5) * factor - 0.5, cy=(intrinsics.cy + 0.5) * factor - 0.5,
                            width=round(intrinsics.width * factor), height=round(intrinsics.height * factor))


@dataclass(frozen=True)
class _World:
    """What a street's images are rendered from, independent of the image size (arrays read-only)."""

    line: Centreline
    quads: Any  # the scene's rectangles (`scene.build_street`)
    atlas: list[np.ndarray]  # mip pyramid of the texture atlas
    ground_origin: np.ndarray
    ground: list[np.ndarray]  # mip pyramid of the ground layout
    fine: list[np.ndarray]  # mip pyramid of the fine ground speckle, wrapped by 2 texels


def _streams(seed: int) -> list[np.random.Generator]:
    """Independent streams: the road, path and buildings of a shorter run are a prefix of a longer one's."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(11)]


@functools.lru_cache(maxsize=2)
def _centreline(n_frames: int, seed: int, route: Route) -> Centreline:
    """The road the camera drives along (cheap; the scene around it is `_world`)."""
    if route == "loop":  # around a block and back past the start (~1 m per frame)
        return make_loop_centreline()
    if route == "drive":  # round two blocks, lap after lap (~1 m per frame on average)
        return make_loop_centreline(DRIVE_PLAN)
    length = (WALK_STEP * 1.25 if route == "walk" else 1.25) * n_frames
    return make_centreline(START_S + length + _LOOK_AHEAD, _streams(seed)[0])


@functools.lru_cache(maxsize=2)
def _world(n_frames: int, seed: int, route: Route) -> _World:
    """The street's scene, built once per process for the same arguments (building it takes seconds; a
    pure function of them, so every `SyntheticStreet` alike shares it)."""
    parts = frame_cache.stored_arrays(f"{route}-seed{seed}-n{n_frames}", _SCENE_PARTS,
                                      lambda: _scene_parts(n_frames, seed, route))
    quads = _Quads(**{name: parts[f"quads.{name}"] for name in _QUAD_FIELDS})
    fine = [cv2.copyMakeBorder(t, 2, 2, 2, 2, cv2.BORDER_WRAP) for t in mip_pyramid(parts["fine"], 9)]
    world = _World(_centreline(n_frames, seed, route), quads, mip_pyramid(parts["atlas"], _MIP_LEVELS),
                   parts["ground_origin"], mip_pyramid(parts["ground"], _MIP_LEVELS), fine)
    for array in (world.ground_origin, *world.atlas, *world.ground, *fine, *vars(quads).values()):
        if isinstance(array, np.ndarray):
            array.setflags(write=False)
    return world


_QUAD_FIELDS = tuple(field.name for field in dataclasses.fields(_Quads))
_SCENE_PARTS = ("atlas", "ground", "ground_origin", "fine", *(f"quads.{name}" for name in _QUAD_FIELDS))


def _scene_parts(n_frames: int, seed: int, route: Route) -> dict[str, np.ndarray]:
    """What `_world` is made of, by name: the rectangles (``quads.*``), the texture atlas, the ground layout and
    its origin, the fine ground speckle tile (the mip-maps are made from them, quickly)."""
    rngs = _streams(seed)
    line = _centreline(n_frames, seed, route)
    quads, atlas = build_street(line, rngs[2:8])
    layout = ground_layout(line, rngs[8])
    parts = {"atlas": atlas, "ground": layout.image, "ground_origin": layout.origin, "fine": ground_fine_tile(rngs[9]),
             **{f"quads.{name}": getattr(quads, name) for name in _QUAD_FIELDS}}
    assert all(isinstance(array, np.ndarray) for array in parts.values())
    return parts


@functools.lru_cache(maxsize=2)
def _panorama(seed: int, fx: float) -> np.ndarray:
    name = f"panorama-seed{seed}-f{fx!r}"
    built = frame_cache.stored_arrays(name, ("panorama",), lambda: {"panorama": panorama(_streams(seed)[10], fx)})
    pano = built["panorama"]
    pano.setflags(write=False)
    return pano


class SyntheticStreet:
    """Procedurally generated street, rendered deterministically from `seed` (a `FrameSource`).

    n_frames: number of source frames (the path length is about n_frames metres); default by route.
    route: "street" (an open road with curves both ways), "loop" (around a 600 m block, four left turns,
    and on past the start: a closed route whose end revisits its start, for loop closure), "walk" (a
    hand-held camera carried down the street at 30 Hz, swinging about its centre: `road.walk_path`) or "drive"
    (KITTI 00's 4541 frames round an L-shaped pair of blocks, 1237 m a lap, at 0.45..1.7 m a frame: revisits,
    loops and changing speeds over a whole drive, `road.drive_path`).
    resolution: image size factor (< 1 renders smaller images, faster: for tests).
    frames: selection among them (`FrameRange.indices(n_frames)`, SourceError when out of range).
    camera_height: metres between the camera centre and the road plane.
    """

    #: its ground truth is the path it was rendered from (exact), one pose per frame
    gt_matching = "exact (the poses the street was rendered from)"

    def __init__(
        self, n_frames: int | None = None, frames: FrameRange | None = None, seed: int = 0,
        camera_height: float = 1.65, route: Route = "street", resolution: float = 1.0,
    ) -> None:
        if route not in ROUTES:
            raise SourceError(f"synthetic street: unknown route {route!r} (one of: {', '.join(ROUTES)})")
        n_frames = n_frames if n_frames is not None else ROUTES[route]
        most = _MAX_FRAMES_CLOSED if route in CLOSED_ROUTES else _MAX_FRAMES
        if not 1 <= n_frames <= most:
            raise SourceError(f"synthetic street: n_frames must be in 1..{most} on route {route}, got {n_frames}")
        if not 0.1 <= resolution <= 1.0:
            raise SourceError(f"synthetic street: resolution must be in 0.1..1, got {resolution}")
        self.n_frames = n_frames
        self.seed = seed
        self.route = route
        self.camera_height = float(camera_height)
        self._indices = (frames or FrameRange()).indices(n_frames)
        self._intr = intr = _INTRINSICS if resolution == 1.0 else _scaled(_INTRINSICS, resolution)
        self._k = intr.K
        path = {"walk": walk_path, "drive": drive_path}.get(route, camera_path)
        self._poses_map = path(_centreline(n_frames, seed, route), n_frames, self.camera_height, _streams(seed)[1])
        self._ground_truth = rebase_poses(self._poses_map[self._indices])
        self._prepared = False  # the scene is built on the first frame not found in the frame cache

    def _prepare(self) -> None:
        """Build (or share) the scene and the per-pixel arrays rendering needs."""
        world = _world(self.n_frames, self.seed, self.route)
        self._quads = world.quads
        self._atlas, self._ground_origin, self._ground = world.atlas, world.ground_origin, world.ground
        self._fine = world.fine
        pano = _panorama(self.seed, self._intr.fx)
        self._pano = cv2.copyMakeBorder(pano, 0, 0, 2, 2, cv2.BORDER_WRAP)
        self._pano_width = pano.shape[1]
        v, u = np.mgrid[0 : self._intr.height, 0 : self._intr.width]
        self._u = u.ravel().astype(np.float32)  # (H*W,) pixel column of each flat index
        self._v = v.ravel().astype(np.float32)
        self._prepared = True

    @property
    def name(self) -> str:
        return "synthetic-street"

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intr

    @property
    def ground_truth(self) -> np.ndarray:
        """(N, 4, 4) float64 T_w_c of the selected frames, world = camera of the first selected frame."""
        return self._ground_truth.copy()

    @property
    def ground_plane(self) -> np.ndarray:
        """(4,) float64 (n_x, n_y, n_z, d): the road plane n . X + d = 0 in world coordinates.

        n is the unit normal pointing up (towards the cameras); d = the first selected camera's distance to the
        road (`camera_height`; on the walk, ± the bob of its step). n = (0, -1, 0) when that camera has no pitch
        or roll.
        """
        pose = self._poses_map[self._indices[0]] if self._indices else np.eye(4)
        height = float(pose[2, 3]) if self._indices else self.camera_height  # the road is the map's z = 0
        return np.append(pose[2, :3], height)  # R_c0_m . z_map = third row of R_m_c0

    @property
    def indices(self) -> list[int]:
        """Source indices of the selected frames."""
        return list(self._indices)

    def __len__(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[Frame]:
        for index in self._indices:
            yield Frame(index=index, timestamp=index * _FRAME_DT[self.route], image=self.render(index))

    def render(self, index: int) -> np.ndarray:
        """(H, W) uint8 grey image of source frame `index` (0 <= index < n_frames); read from, or written
        to, the frame cache when ``VSLAM_SYNTHETIC_CACHE`` names one (`frame_cache`)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range 0..{self.n_frames - 1}")
        folder = frame_cache.cache_folder()
        if folder is None:
            return self._render(index)
        intr = self._intr
        key = (self.route, self.seed, self.n_frames, self.camera_height, intr.width, intr.height, intr.fx)
        path = frame_cache.frame_path(folder, key, index)
        image = frame_cache.load_frame(path, (intr.height, intr.width))
        if image is None:
            image = self._render(index)
            frame_cache.store_frame(path, image)
        return image

    def _render(self, index: int) -> np.ndarray:
        if not self._prepared:
            self._prepare()
        intr = self._intr
        pose = self._poses_map[index]
        r_cm = pose[:3, :3].T
        position = pose[:3, 3]
        t_cm = -r_cm @ position
        scratch = getattr(_SCRATCH, "memory", None)
        if scratch is None:
            scratch = _SCRATCH.memory = Scratch()
        scratch.reset()
        ids, ground_g, facade_g = self._visibility(r_cm, t_cm, position, scratch)
        out = np.empty(intr.height * intr.width, np.float32)
        flat_ids = ids.ravel()
        self._shade_ground(out, np.flatnonzero(flat_ids == 0), ground_g, position, scratch)
        self._shade_sky(out, np.flatnonzero(flat_ids < 0), r_cm)
        scratch.reset()  # the ground's arrays are no longer needed
        self._shade_facades(out, flat_ids, facade_g, scratch)
        image = cv2.GaussianBlur(out.reshape(intr.height, intr.width), (0, 0), 0.5)  # soften silhouettes
        return np.clip(image + 0.5, 0, 255).astype(np.uint8)

    # -- rendering steps --------------------------------------------------------------------------

    def _visibility(
        self, r_cm: np.ndarray, t_cm: np.ndarray, position: np.ndarray, scratch: Scratch
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Z-buffer pass for the camera with map -> camera transform (r_cm, t_cm) at map `position` (3,).

        Returns the id of the surface seen per pixel (H, W) int32 (-1 sky, 0 ground, q + 1 rectangle q);
        the ground homography (3, 3): pixel -> map (x, y) relative to the camera position, third row =
        inverse depth; and per id the homography pixel -> atlas texel coordinates, (9, Q + 1) float32
        row-major (zero for rectangles not drawn). `scratch` holds the per-rectangle (box) work arrays.
        """
        intr = self._intr
        w, h = intr.width, intr.height
        u = np.arange(w, dtype=np.float32)[None, :]
        v = np.arange(h, dtype=np.float32)[:, None]
        ground_g = surface_homography(
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
        distance = np.maximum(np.linalg.norm(quads.centre - position, axis=1) - quads.radius, NEAR)
        candidates = np.flatnonzero((distance < _FAR) & (corners_c[:, :, 2].max(axis=1) > NEAR))
        # Pixel -> (a, b, 1/z) homographies of all candidates (see `surface_homography`), then -> atlas.
        m = np.stack(
            [quads.axis_a[candidates] @ r_cm.T, quads.axis_b[candidates] @ r_cm.T, corners_c[candidates, 0]], axis=2
        )
        h_all = self._k @ m
        solvable = np.abs(np.linalg.det(h_all)) > 1e-12
        candidates, h_all = candidates[solvable], h_all[solvable]
        g_all = np.linalg.inv(h_all)  # (n, 3, 3)
        facade_g = np.zeros((9, len(quads.size) + 1), np.float32)
        facade_g[:, candidates + 1] = (quads.to_atlas[candidates] @ g_all).reshape(-1, 9).T
        boxes = pixel_boxes(corners_c[candidates], self._k, w, h)
        # Per rectangle, its box's inverse depth c and numerators na, nb of (a, b) = (na, nb) / c: views of
        # image-sized scratch buffers, written in place.
        planes = [scratch.empty(h * w, np.float32) for _ in range(4)]
        masks = [scratch.empty(h * w, np.bool_) for _ in range(2)]
        near, size = np.float32(-1e-3), (quads.size + 1e-3).astype(np.float32)
        for q, g, (u0, v0, u1, v1) in zip(candidates, g_all.astype(np.float32), boxes, strict=True):
            if u0 >= u1 or v0 >= v1:
                continue
            uu, vv = u[:, u0:u1], v[v0:v1]
            c, na, nb, product = (x[: (v1 - v0) * (u1 - u0)].reshape(v1 - v0, u1 - u0) for x in planes)
            hit, test = (x[: (v1 - v0) * (u1 - u0)].reshape(v1 - v0, u1 - u0) for x in masks)
            zview, iview = zbuf[v0:v1, u0:u1], ids[v0:v1, u0:u1]
            np.add(g[2, 0] * uu, g[2, 1] * vv + g[2, 2], out=c)
            np.greater(c, zview, out=hit)
            if not hit.any():  # hidden behind what is drawn already
                continue
            np.add(g[0, 0] * uu, g[0, 1] * vv + g[0, 2], out=na)
            np.add(g[1, 0] * uu, g[1, 1] * vv + g[1, 2], out=nb)
            # Inside test a in [0, length], b in [0, height] (times c > 0), widened by 1 mm so that rounding
            # never leaves a crack between adjacent rectangles.
            for numerator, bound, above in ((na, near, True), (na, size[q, 0], False), (nb, near, True),
                                            (nb, size[q, 1], False)):
                np.multiply(bound, c, out=product)
                (np.greater_equal if above else np.less_equal)(numerator, product, out=test)
                hit &= test
            np.copyto(zview, c, where=hit)
            np.copyto(iview, q + 1, where=hit)
        return ids, ground_g, facade_g

    def _shade_ground(
        self, out: np.ndarray, idx: np.ndarray, g: np.ndarray, position: np.ndarray, scratch: Scratch
    ) -> None:
        """Write the ground's grey values into out (H*W,) at flat pixel indices idx (layout + speckle)."""
        u, v = (np.take(a, idx, out=scratch.empty(idx.size, np.float32), mode="wrap") for a in (self._u, self._v))
        fp = surface_coords(g.astype(np.float32).reshape(9, 1), u, v, scratch)
        res = COARSE_RES
        layout = sample_aniso(
            self._ground,
            fp,
            1.0 / res,
            ((position[0] - self._ground_origin[0]) / res - 0.5, (position[1] - self._ground_origin[1]) / res - 0.5),
            scratch,
        )
        fres = _FINE_RES
        fine = sample_aniso(
            self._fine,
            fp,
            1.0 / fres,
            ((position[0] / fres) % FINE_TILE, (position[1] / fres) % FINE_TILE),
            scratch,
            wrap=FINE_TILE,
        )
        out[idx] = layout + _SPECKLE_CONTRAST * (fine - 128.0)

    def _shade_sky(self, out: np.ndarray, idx: np.ndarray, r_cm: np.ndarray) -> None:
        """Write the panorama at infinity into out (H*W,) at flat pixel indices idx."""
        intr = self._intr
        xr = (self._u[idx] - intr.cx) / intr.fx
        yr = (self._v[idx] - intr.cy) / intr.fy
        r = r_cm.T.astype(np.float32)  # camera -> map rotation
        dx = r[0, 0] * xr + r[0, 1] * yr + r[0, 2]
        dy = r[1, 0] * xr + r[1, 1] * yr + r[1, 2]
        dz = r[2, 0] * xr + r[2, 1] * yr + r[2, 2]
        az = np.mod(np.arctan2(dy, dx), 2 * np.pi)
        el = np.arctan2(dz, np.hypot(dx, dy))
        px = az * (self._pano_width / (2 * np.pi)) + 1.5  # +2 pad, -0.5 texel centre
        py = (PANO_ELEV_MAX - el) * intr.fx - 0.5
        out[idx] = remap_points(self._pano, px.astype(np.float32), py.astype(np.float32))

    def _shade_facades(self, out: np.ndarray, flat_ids: np.ndarray, facade_g: np.ndarray, scratch: Scratch) -> None:
        """Write the rectangles' textures into out (H*W,) where flat_ids (H*W,) > 0 (see `_visibility`)."""
        idx = np.flatnonzero(flat_ids > 0)
        if idx.size == 0:
            return
        ids = flat_ids[idx]
        # Runs of pixels on one rectangle (along image rows): per-pixel homographies and shades by repetition,
        # contiguous (a column gather facade_g[:, ids] is strided, which makes every later step slower).
        starts = np.flatnonzero(ids[1:] != ids[:-1])
        starts += 1
        starts = np.concatenate([[0], starts])
        lengths = np.diff(starts, append=ids.size)
        run_ids = ids[starts]
        g = np.repeat(facade_g[:, run_ids], lengths, axis=1)  # (9, n) float32
        shade = np.repeat(self._quads.shade.astype(np.float32)[run_ids - 1], lengths)
        u, v = (np.take(a, idx, out=scratch.empty(idx.size, np.float32), mode="wrap") for a in (self._u, self._v))
        fp = surface_coords(g, u, v, scratch)
        shaded = sample_aniso(self._atlas, fp, 1.0, (-0.5, -0.5), scratch)
        shaded *= shade
        out[idx] = shaded
