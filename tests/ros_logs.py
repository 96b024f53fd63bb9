"""ROS logs made from real KITTI frames, for the ROS bag source's tests and for accuracy benchmarks.

Each KITTI frame (rectified, pinhole) is re-imaged through a lens with known distortion: every pixel of the
distorted output image is undistorted with the lens (`vslam_core.lens.undistort_pixels`, K = the new camera's)
to a ray, the ray is projected into the rectified KITTI camera and sampled there (bilinear, `cv2.remap`).
The new camera has the KITTI camera's pose, so KITTI's ground truth holds for it unchanged; its focal length
is chosen so that every output pixel lands inside the KITTI frame.

`write_lens_logs` writes three logs (ROS 2 MCAP of JPEG CompressedImage + plumb_bob CameraInfo + pose topics
+ /tf_static; ROS 1 .bag of raw mono8 + equidistant CameraInfo; ROS 2 sqlite3 of raw mono8 + plumb_bob
CameraInfo), each with a TUM ground-truth file beside it. `LogWriter` and the message builders write any
other log a test needs. From the command line::

    python -m tests.ros_logs OUT_DIR --sequence 00 --frames 0:300
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, Protocol

import cv2
import numpy as np

from vslam_core.lens import undistort_pixels
from vslam_core.sources.base import CameraIntrinsics
from vslam_core.sources.kitti import read_p0_intrinsics, read_times
from vslam_core.trajectory.io import quaternion_from_rotation, read_kitti_poses, write_tum_poses

LogKind = Literal["ros1", "mcap", "sqlite3"]

#: Header stamps are this Unix time (ns) + KITTI's times.txt; the log (receive) time is 30 ms later.
BASE_STAMP_NS = 1_700_000_000_000_000_000
RECEIVE_DELAY_NS = 30_000_000

PLUMB_BOB = (-0.28, 0.07, 1e-4, -2e-4, 0.0)
EQUIDISTANT = (0.08, -0.02, 0.005, -0.001)

#: base_link → camera of the MCAP log's /tf_static (chained through a mount frame): ROS body axes (x forward,
#: y left, z up) to optical axes (z forward, x right, y down), 1.2 m up and 0.3 m forward, slightly pitched.
_BODY_TO_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _pitch(degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def base_to_mount() -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _pitch(2.0)
    t[:3, 3] = [0.3, 0.0, 1.2]
    return t


def mount_to_camera() -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _BODY_TO_OPTICAL
    t[:3, 3] = [0.05, 0.0, 0.0]
    return t


# --------------------------------------------------------------------------------------------------
# re-imaging


@dataclass(frozen=True)
class Reimager:
    """Re-images rectified KITTI frames through `camera`'s lens (remap tables built once)."""

    camera: CameraIntrinsics
    map_x: np.ndarray
    map_y: np.ndarray

    def __call__(self, kitti_image: np.ndarray) -> np.ndarray:
        return cv2.remap(kitti_image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _to_kitti(raw: np.ndarray, camera: CameraIntrinsics, kitti: CameraIntrinsics) -> np.ndarray:
    ideal = undistort_pixels(raw, camera)
    normalised = (ideal - [camera.cx, camera.cy]) / [camera.fx, camera.fy]
    return normalised * [kitti.fx, kitti.fy] + [kitti.cx, kitti.cy]


def _border(width: int, height: int) -> np.ndarray:
    xs, ys = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    return np.concatenate([
        np.column_stack((xs, np.zeros_like(xs))), np.column_stack((xs, np.full_like(xs, height - 1))),
        np.column_stack((np.zeros_like(ys), ys)), np.column_stack((np.full_like(ys, width - 1), ys)),
    ])


def _inside(points: np.ndarray, kitti: CameraIntrinsics, margin: float = 1.0) -> bool:
    return bool(np.all(np.isfinite(points)) and points[:, 0].min() >= margin and points[:, 1].min() >= margin
                and points[:, 0].max() <= kitti.width - 1 - margin and points[:, 1].max() <= kitti.height - 1 - margin)


def make_reimager(kitti: CameraIntrinsics, model: str, coefficients: tuple[float, ...],
                  size: tuple[int, int] | None = None) -> Reimager:
    """A lens camera of `size` (default KITTI's) with the given distortion, whose smallest focal length (fx=fy)
    keeps every output pixel inside the KITTI frame, and its remap tables."""
    width, height = size or (kitti.width, kitti.height)

    def lens(focal: float) -> CameraIntrinsics:
        return CameraIntrinsics(focal, focal, (width - 1) / 2, (height - 1) / 2, width, height, model,  # type: ignore[arg-type]
                                coefficients, f"re-imaged KITTI ({model})")

    border = _border(width, height)
    low, high = 0.3 * kitti.fx, 4.0 * kitti.fx
    if not _inside(_to_kitti(border, lens(high), kitti), kitti):
        raise ValueError("no focal length fits this lens into the KITTI frame")
    for _ in range(30):
        mid = (low + high) / 2
        if _inside(_to_kitti(border, lens(mid), kitti), kitti):
            high = mid
        else:
            low = mid
    camera = lens(float(np.ceil(high * 1.01)))
    ys, xs = np.mgrid[0:height, 0:width]
    grid = np.column_stack((xs.ravel(), ys.ravel())).astype(np.float64)
    mapped = _to_kitti(grid, camera, kitti)
    if not _inside(mapped, kitti, margin=0.0):
        raise ValueError("the lens maps pixels outside the KITTI frame")
    map_x = mapped[:, 0].reshape(height, width).astype(np.float32)
    map_y = mapped[:, 1].reshape(height, width).astype(np.float32)
    return Reimager(camera, map_x, map_y)


@dataclass(frozen=True)
class KittiClip:
    """The frames of a KITTI sequence to re-image: files, header stamps (ns), camera poses, the camera."""

    files: list[Path]
    stamps_ns: np.ndarray
    poses: np.ndarray
    camera: CameraIntrinsics

    def images(self) -> Iterator[np.ndarray]:
        for file in self.files:
            image = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise ValueError(f"{file}: cannot read")
            yield image


def kitti_clip(kitti_root: Path, sequence: str, frames: range) -> KittiClip:
    folder = kitti_root / "sequences" / sequence
    files = sorted((folder / "image_0").glob("*.png"))
    selected = [files[i] for i in frames]
    times = read_times(folder / "times.txt", len(files))
    stamps = np.array([BASE_STAMP_NS + round(times[i] * 1e9) for i in frames], np.int64)
    poses = read_kitti_poses(kitti_root / "poses" / f"{sequence}.txt")[np.asarray(frames)]
    fx, fy, cx, cy = read_p0_intrinsics(folder / "calib.txt")
    first = cv2.imread(str(selected[0]), cv2.IMREAD_GRAYSCALE)
    camera = CameraIntrinsics(fx, fy, cx, cy, first.shape[1], first.shape[0])
    return KittiClip(selected, stamps, poses, camera)


# --------------------------------------------------------------------------------------------------
# writing logs


class LogWriter:
    """Writes a ROS 1 .bag (`kind` "ros1") or a ROS 2 bag folder ("mcap", "sqlite3") with rosbags; messages
    are built with this writer's typestore (ROS 1 Noetic or ROS 2 Humble field names)."""

    def __init__(self, path: Path, kind: LogKind):
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.kind = kind
        self.ros1 = kind == "ros1"
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        if self.ros1:
            self._writer: Any = Writer1(self.path)
        else:
            plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            self._writer = Writer2(self.path, version=9, storage_plugin=plugin)
        self._connections: dict[str, Any] = {}

    def __enter__(self) -> LogWriter:
        self._writer.open()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
                 ) -> None:
        self._writer.close()

    def write(self, topic: str, log_ns: int, msg: Any) -> None:
        """Serialise `msg` onto `topic` (the connection is made on first use) at log time `log_ns`."""
        msgtype = msg.__msgtype__
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
        serialise = self.typestore.serialize_ros1 if self.ros1 else self.typestore.serialize_cdr
        self._writer.write(self._connections[topic], int(log_ns), serialise(msg, msgtype))

    def write_raw(self, topic: str, msgtype: str, log_ns: int, raw: bytes) -> None:
        """Write already serialised bytes (e.g. a deliberately corrupt message)."""
        if topic not in self._connections:
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
        self._writer.write(self._connections[topic], int(log_ns), raw)

    # message builders ------------------------------------------------------------------------------

    def _type(self, name: str) -> Any:
        return self.typestore.types[name]

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        stamp = self._type("builtin_interfaces/msg/Time")(sec=int(stamp_ns // 1_000_000_000),
                                                          nanosec=int(stamp_ns % 1_000_000_000))
        header = self._type("std_msgs/msg/Header")
        return header(seq=0, stamp=stamp, frame_id=frame_id) if self.ros1 else header(stamp=stamp, frame_id=frame_id)

    def image(self, stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str = "mono8",
              bigendian: bool = False) -> Any:
        pixels = np.ascontiguousarray(pixels)
        height, width = pixels.shape[:2]
        data = pixels.view(np.uint8).reshape(-1)
        return self._type("sensor_msgs/msg/Image")(
            header=self.header(stamp_ns, frame_id), height=height, width=width, encoding=encoding,
            is_bigendian=int(bigendian), step=len(data) // height, data=data)

    def compressed(self, stamp_ns: int, frame_id: str, data: bytes, fmt: str = "jpeg") -> Any:
        return self._type("sensor_msgs/msg/CompressedImage")(
            header=self.header(stamp_ns, frame_id), format=fmt, data=np.frombuffer(data, np.uint8).copy())

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraIntrinsics, model: str | None = None,
                    K: np.ndarray | None = None) -> Any:  # noqa: N803
        k = camera.K.ravel() if K is None else np.asarray(K, np.float64).ravel()
        p = np.zeros((3, 4))
        p[:, :3] = k.reshape(3, 3)
        d = np.asarray(camera.coefficients, np.float64)
        roi = self._type("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0,
                                                             do_rectify=False)
        names = ("D", "K", "R", "P") if self.ros1 else ("d", "k", "r", "p")
        fields = dict(zip(names, (d, k, np.eye(3).ravel(), p.ravel()), strict=True))
        return self._type("sensor_msgs/msg/CameraInfo")(
            header=self.header(stamp_ns, frame_id), height=camera.height, width=camera.width,
            distortion_model=model if model is not None else camera.model, binning_x=0, binning_y=0, roi=roi,
            **fields)

    def _pose(self, transform: np.ndarray) -> Any:
        qx, qy, qz, qw = quaternion_from_rotation(transform[:3, :3])
        x, y, z = transform[:3, 3]
        return self._type("geometry_msgs/msg/Pose")(
            position=self._type("geometry_msgs/msg/Point")(x=float(x), y=float(y), z=float(z)),
            orientation=self._type("geometry_msgs/msg/Quaternion")(x=float(qx), y=float(qy), z=float(qz),
                                                                   w=float(qw)))

    def pose_stamped(self, stamp_ns: int, frame_id: str, pose: np.ndarray) -> Any:
        return self._type("geometry_msgs/msg/PoseStamped")(header=self.header(stamp_ns, frame_id),
                                                           pose=self._pose(pose))

    def odometry(self, stamp_ns: int, frame_id: str, child: str, pose: np.ndarray) -> Any:
        vector = self._type("geometry_msgs/msg/Vector3")
        twist = self._type("geometry_msgs/msg/Twist")(linear=vector(x=0.0, y=0.0, z=0.0),
                                                       angular=vector(x=0.0, y=0.0, z=0.0))
        return self._type("nav_msgs/msg/Odometry")(
            header=self.header(stamp_ns, frame_id), child_frame_id=child,
            pose=self._type("geometry_msgs/msg/PoseWithCovariance")(pose=self._pose(pose), covariance=np.zeros(36)),
            twist=self._type("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)))

    def transform(self, stamp_ns: int, parent: str, child: str, transform: np.ndarray) -> Any:
        qx, qy, qz, qw = quaternion_from_rotation(transform[:3, :3])
        x, y, z = transform[:3, 3]
        value = self._type("geometry_msgs/msg/Transform")(
            translation=self._type("geometry_msgs/msg/Vector3")(x=float(x), y=float(y), z=float(z)),
            rotation=self._type("geometry_msgs/msg/Quaternion")(x=float(qx), y=float(qy), z=float(qz), w=float(qw)))
        return self._type("geometry_msgs/msg/TransformStamped")(header=self.header(stamp_ns, parent),
                                                                child_frame_id=child, transform=value)

    def tf_message(self, transforms: list[Any]) -> Any:
        return self._type("tf2_msgs/msg/TFMessage")(transforms=transforms)


def jpeg(image: np.ndarray, quality: int = 95) -> bytes:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return bytes(data.tobytes())


@dataclass(frozen=True)
class LensLog:
    """One written log: where it is, its TUM ground truth, the lens the frames were re-imaged through."""

    path: Path
    gt_path: Path
    camera: CameraIntrinsics
    topic: str
    kind: LogKind


#: name → (kind, lens model, coefficients, image topic, camera_info topic, compressed)
LOGS: dict[str, tuple[LogKind, str, tuple[float, ...], str, str, bool]] = {
    "mcap-plumb_bob": ("mcap", "plumb_bob", PLUMB_BOB, "/cam/image_raw/compressed", "/cam/camera_info", True),
    "ros1-equidistant": ("ros1", "equidistant", EQUIDISTANT, "/kitti/camera/image_raw",
                         "/kitti/camera/camera_info", False),
    "sqlite3-plumb_bob": ("sqlite3", "plumb_bob", PLUMB_BOB, "/camera/image_raw", "/camera/camera_info", False),
}


def write_lens_log(name: str, clip: KittiClip, out_dir: Path, reimager: Reimager | None = None) -> LensLog:
    """Write the log `name` of `LOGS` from `clip` into `out_dir` (plus ``NAME.tum`` beside it). The MCAP log
    also holds ground truth as topics: /gt/pose (PoseStamped of the camera, 2 ms after each frame) and
    /gt/odom (Odometry of base_link in odom), with /tf_static base_link → mount → camera."""
    kind, model, coefficients, topic, info_topic, compressed = LOGS[name]
    reimager = reimager or make_reimager(clip.camera, model, coefficients)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / (f"{name}.bag" if kind == "ros1" else name)
    gt_path = out_dir / f"{name}.tum"
    write_tum_poses(gt_path, clip.stamps_ns / 1e9, clip.poses)
    base_cam = base_to_mount() @ mount_to_camera()
    with LogWriter(path, kind) as log:
        if kind == "mcap":
            static = [log.transform(int(clip.stamps_ns[0]), "base_link", "mount", base_to_mount()),
                      log.transform(int(clip.stamps_ns[0]), "mount", "camera", mount_to_camera())]
            log.write("/tf_static", int(clip.stamps_ns[0]), log.tf_message(static))
        for stamp, pose, image in zip(clip.stamps_ns, clip.poses, clip.images(), strict=True):
            stamp = int(stamp)
            received = stamp + RECEIVE_DELAY_NS
            lens_image = reimager(image)
            log.write(info_topic, received, log.camera_info(stamp, "camera", reimager.camera))
            if compressed:
                log.write(topic, received, log.compressed(stamp, "camera", jpeg(lens_image)))
            else:
                log.write(topic, received, log.image(stamp, "camera", lens_image))
            if kind == "mcap":
                log.write("/gt/pose", stamp + 2_000_000, log.pose_stamped(stamp + 2_000_000, "world", pose))
                log.write("/gt/odom", stamp, log.odometry(stamp, "odom", "base_link",
                                                          pose @ np.linalg.inv(base_cam)))
    return LensLog(path, gt_path, reimager.camera, topic, kind)


def camera_info_yaml(lens: CameraIntrinsics) -> str:
    """`lens` as a ROS camera_info YAML (what `--calib` reads)."""
    return (f"image_width: {lens.width}\nimage_height: {lens.height}\ncamera_name: lens\n"
            f"camera_matrix:\n  rows: 3\n  cols: 3\n"
            f"  data: [{lens.fx}, 0, {lens.cx}, 0, {lens.fy}, {lens.cy}, 0, 0, 1]\n"
            f"distortion_model: {lens.model}\ndistortion_coefficients:\n  rows: 1\n  cols: {len(lens.coefficients)}\n"
            f"  data: [{', '.join(map(str, lens.coefficients))}]\n")


class Reimaging(Protocol):
    """What `write_lens_folder` needs: the camera of the frames it makes, and how it makes one from a KITTI frame
    (`Reimager` through a lens; benchmarks/matrix.py resizes)."""

    camera: CameraIntrinsics

    def __call__(self, kitti_image: np.ndarray) -> np.ndarray: ...


def write_lens_folder(clip: KittiClip, reimager: Reimaging, folder: Path) -> Path:
    """The clip re-imaged (through the lens) as an image folder (PNGs, ``times.txt``, ``gt.txt`` of KITTI poses) and
    its camera as ``FOLDER.yaml`` beside it (returned): a distorted camera with exact ground truth."""
    folder.mkdir(parents=True)
    for k, image in enumerate(clip.images()):
        cv2.imwrite(str(folder / f"{k:06d}.png"), reimager(image))
    (folder / "times.txt").write_text("".join(f"{(t - clip.stamps_ns[0]) / 1e9:.6f}\n" for t in clip.stamps_ns))
    np.savetxt(folder / "gt.txt", clip.poses[:, :3, :].reshape(-1, 12))
    calib = folder.parent / f"{folder.name}.yaml"
    calib.write_text(camera_info_yaml(reimager.camera))
    return calib


def write_lens_logs(kitti_root: Path, sequence: str, frames: range, out_dir: Path
                    ) -> dict[str, tuple[Path, Path, CameraIntrinsics]]:
    """Write every log of `LOGS` for KITTI `sequence`'s `frames` into `out_dir`:
    name → (log path, TUM ground-truth path, the lens camera of the frames)."""
    clip = kitti_clip(Path(kitti_root), sequence, frames)
    written = {}
    for name in LOGS:
        log = write_lens_log(name, clip, Path(out_dir))
        written[name] = (log.path, log.gt_path, log.camera)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m tests.ros_logs", description=__doc__.split("\n\n")[0])
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--kitti", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti")
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--frames", default="0:300", help="START:END of the KITTI frames")
    args = parser.parse_args(argv)
    start, end = (int(v) for v in args.frames.split(":"))
    for name, (path, gt_path, camera) in write_lens_logs(args.kitti, args.sequence, range(start, end),
                                                          args.out_dir).items():
        coefficients = " ".join(f"{c:g}" for c in camera.coefficients)
        print(f"{name}: {path} (gt {gt_path.name}; {camera.model} {coefficients}; fx {camera.fx:g} "
              f"{camera.width}x{camera.height})")


if __name__ == "__main__":
    main()
