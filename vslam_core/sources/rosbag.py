"""Frames of a camera topic in a ROS log: a ROS 1 ``.bag``, a ROS 2 bag folder (sqlite3 ``.db3`` or ``.mcap``
storage), or a bare ``.mcap`` / ``.db3`` file, read with ``rosbags.highlevel.AnyReader``.

Images: ``sensor_msgs/msg/Image`` (mono8, mono16, rgb8, bgr8, rgba8, bgra8, bayer_rggb8/bggr8/gbrg8/grbg8,
8UC1) and ``sensor_msgs/msg/CompressedImage`` (whatever ``cv2.imdecode`` reads: jpeg, png, …), all turned into
grey uint8. mono16 is shifted right by ``b - 8`` bits, ``b`` being the bit depth (8, 10, 12, 14 or 16) that
holds the brightest pixel of the first decoded frame; the same shift is used for every frame (brighter
pixels later on are clipped), so the brightness does not jump from frame to frame.

Streaming: the bag is never held in memory. Construction reads the image topic once, parsing only the
header (stamp, frame_id) out of each message's raw bytes (CDR or ROS 1 serialisation, no image decoding),
then decodes the first selected frame (image size, encoding check). Iteration reads the bag again and
decodes one frame at a time; frames are yielded in header-stamp order (stable), with a small reorder buffer
of raw messages when the log holds them out of order (or one seek per frame when the disorder is large).

Calibration: the first ``sensor_msgs/msg/CameraInfo`` of the image topic's namespace (``/cam/image_raw`` →
``/cam/camera_info``, then the parent namespaces), unless `calibration` overrides it. Ground truth: a TUM
file of camera poses, or a pose topic (PoseStamped, PoseWithCovarianceStamped, Odometry, TransformStamped),
matched to the frames by stamp; a body frame other than the camera's is moved onto the camera with
``/tf_static``. Every problem is a one-line `SourceError`.
"""

from __future__ import annotations

import re
import struct
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange
from vslam_core.sources.calibration import make_intrinsics
from vslam_core.sources.folder import complete_intrinsics
from vslam_core.sources.kitti import BadFramePolicy, select
from vslam_core.sources.stamps import DEFAULT_GT_TOLERANCE_S, ground_truth_at, stamp_problems
from vslam_core.trajectory_io import read_tum_poses, rotation_from_quaternion

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_TYPE)
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TYPE = "tf2_msgs/msg/TFMessage"
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/TransformStamped",
)

#: Raw ``sensor_msgs/Image`` encodings we turn into grey (lower case), and how.
_COLOUR_CODES = {
    "rgb8": (3, cv2.COLOR_RGB2GRAY), "bgr8": (3, cv2.COLOR_BGR2GRAY),
    "rgba8": (4, cv2.COLOR_RGBA2GRAY), "bgra8": (4, cv2.COLOR_BGRA2GRAY),
    # ROS names the Bayer pattern from the top-left pixel, OpenCV from the second row's: cv_bridge's mapping
    "bayer_rggb8": (1, cv2.COLOR_BayerBG2GRAY), "bayer_bggr8": (1, cv2.COLOR_BayerRG2GRAY),
    "bayer_gbrg8": (1, cv2.COLOR_BayerGR2GRAY), "bayer_grbg8": (1, cv2.COLOR_BayerGB2GRAY),
}
SUPPORTED_ENCODINGS = ("mono8", "8uc1", "mono16", *_COLOUR_CODES)

#: Above this many frames held back for stamp order, iteration seeks each frame instead of buffering.
REORDER_LIMIT = 32


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()).strip(" .")
    text = text if text else exc.__class__.__name__
    return text if len(text) <= 200 else text[:197] + "…"


@contextmanager
def _bag_errors(where: str, doing: str) -> Iterator[None]:
    """Turn whatever rosbags (or the file system, sqlite, a decompressor) raises into one `SourceError` line."""
    try:
        yield
    except SourceError:
        raise
    except Exception as exc:  # noqa: BLE001 - the boundary to a third-party reader: nothing else may escape
        raise SourceError(f"{where}: {doing}: {_one_line(exc)}") from None


def _bare(frame: str) -> str:
    """A tf frame name without ROS 1's leading slash."""
    return frame.strip().lstrip("/")


def _field(msg: object, *names: str) -> Any:
    """The first of `names` that `msg` has (ROS 2 ``k`` vs ROS 1 ``K``)."""
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise AttributeError(f"message {type(msg).__name__} has none of the fields {', '.join(names)}")


def _stamp_ns(stamp: object) -> int:
    return int(_field(stamp, "sec", "secs")) * 1_000_000_000 + int(_field(stamp, "nanosec", "nsec", "nsecs"))


def _format_ns(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def parse_header(raw: bytes | memoryview, cdr: bool) -> tuple[int, str]:
    """(stamp in ns, frame_id) of a serialised message that starts with a ``std_msgs/Header`` — every image
    message does — read from its first bytes without deserialising the rest. ``cdr``: ROS 2 CDR (4 bytes
    of encapsulation, then sec int32, nanosec uint32, frame_id string with its NUL); otherwise ROS 1
    (seq uint32, sec uint32, nsec uint32, frame_id string). `ValueError` for bytes that cannot be a header."""
    data = bytes(raw[:16])
    if len(data) < 16:
        raise ValueError(f"message of {len(raw)} bytes is too short for a header")
    if cdr:
        if data[0] != 0 or data[1] not in (0, 1, 2, 3):
            raise ValueError("not a CDR message (bad encapsulation header)")
        order = "<" if data[1] & 1 else ">"
        sec, nsec, length = struct.unpack_from(order + "iII", data, 4)
        text = bytes(raw[16:16 + max(length - 1, 0)])
    else:
        _seq, sec, nsec, length = struct.unpack_from("<IIII", data, 0)
        text = bytes(raw[16:16 + length])
    if nsec >= 1_000_000_000 or 16 + length > len(raw):
        raise ValueError("corrupt message header")
    return sec * 1_000_000_000 + nsec, text.decode("utf-8", errors="replace")


def _pose_matrix(position: object, orientation: object) -> np.ndarray:
    pose = np.eye(4)
    q = np.array([orientation.x, orientation.y, orientation.z, orientation.w], np.float64)  # type: ignore[attr-defined]
    if not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-9:
        raise ValueError("pose with an invalid quaternion")
    pose[:3, :3] = rotation_from_quaternion(q)
    pose[:3, 3] = [position.x, position.y, position.z]  # type: ignore[attr-defined]
    return pose


def _transform_matrix(transform: object) -> np.ndarray:
    return _pose_matrix(transform.translation, transform.rotation)  # type: ignore[attr-defined]


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "log"


@dataclass(frozen=True)
class _Decoded:
    image: np.ndarray
    encoding: str


class _Decoder:
    """Turns image messages into grey uint8 arrays; remembers the mono16 shift chosen on the first frame."""

    def __init__(self) -> None:
        self.mono16_shift: int | None = None

    def decode(self, msg: object, msgtype: str) -> _Decoded:
        if msgtype == COMPRESSED_TYPE:
            fmt = str(msg.format)  # type: ignore[attr-defined]
            if "compresseddepth" in fmt.lower():
                raise SourceError(f"compressed depth images ({fmt!r}) are not camera frames")
            data = np.asarray(msg.data, np.uint8)  # type: ignore[attr-defined]
            image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
            if image is None or image.size == 0:
                raise SourceError(f"cannot decode the compressed image (format {fmt!r}, {data.size} bytes)")
            return _Decoded(np.ascontiguousarray(image, np.uint8), fmt.split(";")[-1].strip() or "compressed")
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
            return _Decoded(np.ascontiguousarray(rows), key)
        if key == "mono16":
            big = bool(msg.is_bigendian)  # type: ignore[attr-defined]
            values = np.ascontiguousarray(rows).view(">u2" if big else "<u2").astype(np.uint16)
            if self.mono16_shift is None:
                bits = max(8, int(values.max()).bit_length())
                self.mono16_shift = min(16, bits + (bits % 2)) - 8
            return _Decoded(np.minimum(values >> self.mono16_shift, 255).astype(np.uint8), key)
        code = _COLOUR_CODES[key][1]
        pixels = np.ascontiguousarray(rows).reshape(height, width, channels) if channels > 1 else \
            np.ascontiguousarray(rows)
        return _Decoded(cv2.cvtColor(pixels, code), key)


def _open_reader(path: Path) -> Any:
    """An opened ``AnyReader`` on `path` (ROS 2 logs without type definitions use the Humble types)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    ros2 = path.suffix != ".bag"
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE) if ros2 else None)
    reader.open()
    return reader


def _log_format(path: Path) -> str:
    if path.is_dir():
        suffixes = {p.suffix for p in path.iterdir()}
        if ".mcap" in suffixes:
            return "ros2 bag (mcap)"
        if ".db3" in suffixes:
            return "ros2 bag (sqlite3)"
        return "ros2 bag"
    return {".bag": "ros1 bag", ".mcap": "mcap", ".db3": "sqlite3"}[path.suffix]


class RosbagSource:
    """Frames of one image topic of a ROS log (see the module docstring).

    path: a ROS 1 ``.bag``, a ROS 2 bag folder (``metadata.yaml`` + ``.db3`` or ``.mcap``), or a bare
    ``.mcap`` / ``.db3`` file. topic: the image topic; None picks the log's only image topic.
    frames: a selection among the frames in stamp order (0..N-1). calibration: overrides the CameraInfo
    (width/height 0 = the images' size). ground_truth: a TUM file of camera poses (absolute stamps, any
    world frame); gt_topic instead: a pose topic of the log. Both are matched to the frames' header stamps
    within gt_tolerance_s and re-based on the first selected frame. on_bad_frame: "fail" raises a
    `SourceError` naming an undecodable frame, "skip" yields it as a black placeholder with a `defect`.
    """

    def __init__(
        self,
        path: str | Path,
        topic: str | None = None,
        frames: FrameRange | None = None,
        calibration: CameraIntrinsics | None = None,
        ground_truth: str | Path | None = None,
        gt_topic: str | None = None,
        gt_tolerance_s: float = DEFAULT_GT_TOLERANCE_S,
        on_bad_frame: BadFramePolicy = "fail",
    ):
        self.path = Path(path)
        self._where = str(self.path)
        self._on_bad_frame = on_bad_frame
        self.notes: list[str] = []
        self.properties: dict[str, str] = {}
        if ground_truth is not None and gt_topic is not None:
            raise SourceError(f"{self._where}: give the ground truth as a TUM file or as a topic, not both")
        self._check_path()
        self._cdr = self.path.suffix != ".bag"
        self._decoder = _Decoder()

        with _bag_errors(self._where, "cannot open the log (corrupt, truncated or not a ROS log?)"):
            reader = _open_reader(self.path)
        try:
            with _bag_errors(self._where, "cannot read the log"):
                topics = {name: info.msgtype or "" for name, info in reader.topics.items()}
                self.topic = self._pick_topic(topics, topic)
                self._msgtype = topics[self.topic]
            self._scan_stamps(reader)
            self._indices = select(frames, len(self._order), f"{self._where} {self.topic}")
            first = self._read_first_frame(reader)
            size = (first.shape[1], first.shape[0])
            self._size = size
            self._intrinsics = self._calibrate(reader, topics, calibration, size)
            self._ground_truth = self._load_ground_truth(reader, topics, ground_truth, gt_topic, gt_tolerance_s)
        finally:
            with _bag_errors(self._where, "cannot close the log"):
                reader.close()

        self.properties.update({
            "topic": self.topic,
            "log_format": _log_format(self.path),
            "first_stamp": _format_ns(int(self._stamps_ns[self._order[self._indices[0]]])),
            "frame_id": self.frame_id or "-",
            "message_type": self._msgtype,
            "messages": str(len(self._order)),
        })
        if self._decoder.mono16_shift is not None:
            self.properties["mono16"] = f">> {self._decoder.mono16_shift} bits (from the first frame's range)"

    # ----------------------------------------------------------------------------------------------
    # construction steps

    def _check_path(self) -> None:
        path = self.path
        if not path.exists():
            raise SourceError(f"{path}: ROS log not found")
        if path.is_dir():
            if not (path / "metadata.yaml").is_file():
                raise SourceError(f"{path}: not a ROS 2 bag folder (no metadata.yaml); give the folder of a ROS 2 "
                                  "bag, or a .bag / .mcap / .db3 file")
        elif path.suffix not in (".bag", ".mcap", ".db3"):
            raise SourceError(f"{path}: not a ROS log (expected a ROS 1 .bag, a .mcap or .db3 file, or a ROS 2 bag "
                              "folder)")

    def _pick_topic(self, topics: dict[str, str], topic: str | None) -> str:
        images = sorted(name for name, kind in topics.items() if kind in IMAGE_TYPES)
        listing = ", ".join(f"{name} ({kind.replace('/msg/', '/')})" for name, kind in sorted(topics.items()))
        if topic is not None:
            wanted = topic if topic.startswith("/") or topic in topics else "/" + topic
            if wanted not in topics:
                raise SourceError(f"{self._where}: no topic {topic} (image topics: {', '.join(images) or 'none'})")
            if topics[wanted] not in IMAGE_TYPES:
                raise SourceError(f"{self._where}: topic {wanted} is {topics[wanted]}, not an image (sensor_msgs/"
                                  f"Image or CompressedImage; image topics: {', '.join(images) or 'none'})")
            return wanted
        if len(images) == 1:
            return images[0]
        if not images:
            raise SourceError(f"{self._where}: no image topic (sensor_msgs/Image or CompressedImage); the log has "
                              f"{len(topics)} topics: {listing or 'none'}")
        raise SourceError(f"{self._where}: {len(images)} image topics ({', '.join(images)}): pick one with --topic")

    def _scan_stamps(self, reader: Any) -> None:
        """First pass over the image topic: header stamps and log times, no image decoding."""
        log_times: list[int] = []
        stamps: list[int] = []
        bad: dict[int, str] = {}
        frame_id: str | None = None
        with _bag_errors(self._where, f"cannot read {self.topic}"):
            messages = reader.messages(connections=self._image_connections(reader))
            for position, (_conn, log_time, raw) in enumerate(messages):
                log_times.append(log_time)
                try:
                    stamp, frame = parse_header(raw, self._cdr)
                except ValueError as exc:
                    if self._on_bad_frame == "fail":
                        raise SourceError(f"{self._where}: message {position} of {self.topic} (log time "
                                          f"{_format_ns(log_time)}): {exc}") from None
                    bad[position] = f"message {position} of {self.topic}: {exc}"
                    stamp = 0
                else:
                    if frame_id is None:
                        frame_id = frame
                stamps.append(stamp)
        if not stamps:
            raise SourceError(f"{self._where}: topic {self.topic} holds no messages")
        self.frame_id = _bare(frame_id or "")
        log = np.asarray(log_times, np.int64)
        header = np.asarray(stamps, np.int64)
        zero = header == 0
        missing = int(zero.sum()) - len(bad)
        if zero.all():
            self.properties["stamps"] = "receive time"
            self.notes.append(f"{self.topic}: the messages have no header stamps; their receive (log) times are used")
        elif zero.any():
            self.properties["stamps"] = f"header (receive time for {int(zero.sum())} frames)"
            if missing:
                first = int(np.argmax(zero & ~np.isin(np.arange(len(zero)), list(bad))))
                self.notes.append(f"{self.topic}: {missing} messages have no header stamp (first: message {first}); "
                                  "their receive (log) times are used")
        else:
            self.properties["stamps"] = "header"
        header = np.where(zero, log, header)
        self._log_ns = log
        self._stamps_ns = header
        self._order = np.argsort(header, kind="stable")  # stamp-order index -> arrival position
        self._bad = bad
        for note in stamp_problems((header - header.min()) / 1e9):
            self.notes.append(f"{self.topic}: {note}")
        # messages() yields in log-time order; seeking by log time relies on it
        self._seekable = bool(np.all(np.diff(log) >= 0))

    def _read_first_frame(self, reader: Any) -> np.ndarray:
        """Decode the first selected frame (or, with on_bad_frame="skip", the first decodable one); an
        unsupported encoding is refused here, before any frame is processed."""
        errors: list[str] = []
        for index in self._indices:
            position = int(self._order[index])
            if position in self._bad:
                errors.append(self._bad[position])
                continue
            raw = self._seek_raw(reader, position)
            try:
                return self._decode(reader, raw, index, position, first=True)
            except SourceError as exc:
                if self._on_bad_frame == "fail" or "not supported" in str(exc):
                    raise
                errors.append(str(exc))
        raise SourceError(f"{self._where}: none of the {len(self._indices)} selected frames of {self.topic} can be "
                          f"decoded (first: {errors[0] if errors else '?'})")

    def _image_connections(self, reader: Any) -> list[Any]:
        """The image topic's connections in `reader` (each opened reader has its own)."""
        return [c for c in reader.connections if c.topic == self.topic]

    def _seek_raw(self, reader: Any, position: int) -> bytes:
        """The raw bytes of the image message at arrival `position`."""
        log = self._log_ns
        if self._seekable:
            first_same = int(np.searchsorted(log, log[position], side="left"))
            window = reader.messages(connections=self._image_connections(reader), start=int(log[position]),
                                     stop=int(log[position]) + 1)
            offset = first_same
        else:
            window = reader.messages(connections=self._image_connections(reader))
            offset = 0
        with _bag_errors(self._where, f"cannot read message {position} of {self.topic}"):
            for at, (_conn, _log_time, raw) in enumerate(window, start=offset):
                if at == position:
                    return bytes(raw)
        raise SourceError(f"{self._where}: message {position} of {self.topic} is gone (has the log changed?)")

    def _decode(self, reader: Any, raw: bytes, index: int, position: int, first: bool = False) -> np.ndarray:
        """Deserialise and decode one image message (`SourceError` naming the frame if it cannot be)."""
        what = (f"{self._where}: frame {index} of {self.topic} (message {position}, stamp "
                f"{_format_ns(int(self._stamps_ns[position]))})")
        try:
            msg = reader.deserialize(raw, self._msgtype)
        except Exception as exc:  # noqa: BLE001 - a corrupt message
            raise SourceError(f"{what}: corrupt message ({_one_line(exc)})") from None
        try:
            decoded = self._decoder.decode(msg, self._msgtype)
        except SourceError as exc:
            raise SourceError(f"{what}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a malformed message whose fields do not add up
            raise SourceError(f"{what}: cannot decode ({_one_line(exc)})") from None
        if first:
            self.properties["encoding"] = decoded.encoding
        elif (decoded.image.shape[1], decoded.image.shape[0]) != self._size:
            raise SourceError(f"{what}: image is {decoded.image.shape[1]}x{decoded.image.shape[0]}, the first "
                              f"frame is {self._size[0]}x{self._size[1]}")
        return decoded.image

    def _calibrate(self, reader: Any, topics: dict[str, str], calibration: CameraIntrinsics | None,
                   size: tuple[int, int]) -> CameraIntrinsics:
        if calibration is not None:
            self.properties["camera_info"] = "not used (calibration given)"
            return complete_intrinsics(calibration, size[0], size[1], f"{self._where} {self.topic}")
        info_topic = self._camera_info_topic(topics)
        if info_topic is None:
            raise SourceError(f"{self._where}: no sensor_msgs/CameraInfo for {self.topic} (looked for "
                              f"{', '.join(self._info_candidates())}): pass --calib FILE (or --intrinsics)")
        origin = f"CameraInfo {info_topic}"
        msg = None
        with _bag_errors(self._where, f"cannot read {info_topic}"):
            connections = [c for c in reader.connections if c.topic == info_topic]
            for conn, _log_time, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, conn.msgtype)
                break
        if msg is None:
            raise SourceError(f"{self._where}: {info_topic} holds no message: pass --calib FILE (or --intrinsics)")
        self.properties["camera_info"] = info_topic
        try:
            with _bag_errors(self._where, f"{info_topic}: malformed CameraInfo"):
                width, height = int(msg.width), int(msg.height)
                model_name = str(msg.distortion_model)
                K = np.asarray(_field(msg, "k", "K"), np.float64)  # noqa: N806
                P = np.asarray(_field(msg, "p", "P"), np.float64)  # noqa: N806
                D = np.asarray(_field(msg, "d", "D"), np.float64)  # noqa: N806
            if self._rectified_topic():
                camera = make_intrinsics(P.reshape(3, 4)[:, :3], "none", [], size[0], size[1],
                                         f"{origin} (P, for the rectified {self.topic})")
                self.notes.append(f"{self.topic} is rectified: the projection P of {info_topic} is used, no distortion")
            else:
                camera = make_intrinsics(K, model_name, D, size[0], size[1], origin)
        except SourceError as exc:
            raise SourceError(f"{self._where}: {exc}") from None
        if (width, height) != (0, 0) and (width, height) != size:
            raise SourceError(f"{self._where}: {info_topic} is for {width}x{height} images but {self.topic}'s are "
                              f"{size[0]}x{size[1]}: pass --calib FILE for these images")
        return camera

    def _info_candidates(self) -> list[str]:
        parts = [p for p in self.topic.split("/") if p]
        return ["/" + "/".join([*parts[:n], "camera_info"]) for n in range(len(parts) - 1, -1, -1)]

    def _camera_info_topic(self, topics: dict[str, str]) -> str | None:
        for candidate in self._info_candidates():
            if topics.get(candidate) == CAMERA_INFO_TYPE:
                return candidate
        return None

    def _rectified_topic(self) -> bool:
        parts = [p for p in self.topic.split("/") if p and p not in ("compressed", "theora")]
        return bool(parts) and parts[-1].startswith("image_rect")

    def _selected_stamps(self) -> np.ndarray:
        positions = self._order[np.asarray(self._indices)]
        return self._stamps_ns[positions] / 1e9

    def _load_ground_truth(self, reader: Any, topics: dict[str, str], ground_truth: str | Path | None,
                           gt_topic: str | None, tolerance_s: float) -> np.ndarray | None:
        if ground_truth is not None:
            gt_path = Path(ground_truth)
            if not gt_path.is_file():
                raise SourceError(f"{gt_path}: ground-truth file not found")
            gt_stamps, gt_poses = read_tum_poses(gt_path)
            self.properties["ground_truth"] = f"TUM {gt_path.name}"
            return ground_truth_at(self._selected_stamps(), gt_stamps, gt_poses, tolerance_s, str(gt_path))
        if gt_topic is None:
            return None
        name = gt_topic if gt_topic in topics or gt_topic.startswith("/") else "/" + gt_topic
        if name not in topics:
            raise SourceError(f"{self._where}: no ground-truth topic {gt_topic} (pose topics: "
                              f"{', '.join(t for t, k in sorted(topics.items()) if k in POSE_TYPES) or 'none'})")
        kind = topics[name]
        if kind not in POSE_TYPES:
            raise SourceError(f"{self._where}: ground-truth topic {name} is {kind}; expected one of "
                              f"{', '.join(POSE_TYPES)} (or give --gt as TUM camera poses)")
        stamps, poses, body = self._read_poses(reader, name, kind)
        where = f"{self._where} {name}"
        if body is None:
            self.notes.append(f"{name} ({kind.split('/')[-1]}) names no body frame: its poses are taken as poses of "
                              f"the camera ({self.frame_id or 'unnamed frame'})")
            self.properties["ground_truth"] = f"{name} (taken as camera poses)"
        elif body == self.frame_id:
            self.properties["ground_truth"] = f"{name} (poses of {body}, the camera frame)"
        else:
            body_cam = self._static_transform(reader, topics, body, self.frame_id)
            if body_cam is None:
                raise SourceError(f"{where}: the ground truth is of frame {body!r}, the images of {self.frame_id!r}, "
                                  "and /tf_static holds no fixed transform between them: give --gt as TUM camera "
                                  "poses")
            poses = np.einsum("nij,jk->nik", poses, body_cam)
            self.properties["ground_truth"] = f"{name} (poses of {body} · /tf_static {body}→{self.frame_id})"
        return ground_truth_at(self._selected_stamps(), stamps, poses, tolerance_s, where)

    def _read_poses(self, reader: Any, topic: str, kind: str) -> tuple[np.ndarray, np.ndarray, str | None]:
        stamps: list[int] = []
        poses: list[np.ndarray] = []
        bodies: set[str] = set()
        with _bag_errors(self._where, f"cannot read the ground-truth topic {topic}"):
            connections = [c for c in reader.connections if c.topic == topic]
            for conn, _log_time, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, conn.msgtype)
                stamps.append(_stamp_ns(msg.header.stamp))
                if kind.endswith("/PoseStamped"):
                    poses.append(_pose_matrix(msg.pose.position, msg.pose.orientation))
                elif kind.endswith("/PoseWithCovarianceStamped"):
                    poses.append(_pose_matrix(msg.pose.pose.position, msg.pose.pose.orientation))
                elif kind.endswith("/Odometry"):
                    bodies.add(_bare(msg.child_frame_id))
                    poses.append(_pose_matrix(msg.pose.pose.position, msg.pose.pose.orientation))
                else:
                    bodies.add(_bare(msg.child_frame_id))
                    poses.append(_transform_matrix(msg.transform))
        if not poses:
            raise SourceError(f"{self._where}: the ground-truth topic {topic} holds no message")
        if len(bodies) > 1:
            raise SourceError(f"{self._where}: the ground-truth topic {topic} mixes the frames "
                              f"{', '.join(sorted(bodies))}")
        body = bodies.pop() if bodies else None
        return np.asarray(stamps, np.float64) / 1e9, np.asarray(poses), body

    def _static_transform(self, reader: Any, topics: dict[str, str], source: str, target: str) -> np.ndarray | None:
        """T_source_target from the fixed transforms of /tf_static (chained through other frames if need be),
        or None when they do not connect the two frames."""
        if topics.get("/tf_static") != TF_TYPE or not target:
            return None
        edges: dict[tuple[str, str], np.ndarray] = {}
        with _bag_errors(self._where, "cannot read /tf_static"):
            connections = [c for c in reader.connections if c.topic == "/tf_static"]
            for conn, _log_time, raw in reader.messages(connections=connections):
                for t in reader.deserialize(raw, conn.msgtype).transforms:
                    parent, child = _bare(t.header.frame_id), _bare(t.child_frame_id)
                    edges[(parent, child)] = _transform_matrix(t.transform)
        neighbours: dict[str, list[tuple[str, np.ndarray]]] = {}
        for (parent, child), transform in edges.items():
            neighbours.setdefault(parent, []).append((child, transform))
            neighbours.setdefault(child, []).append((parent, np.linalg.inv(transform)))
        reached: dict[str, np.ndarray] = {source: np.eye(4)}
        queue = deque([source])
        while queue:
            frame = queue.popleft()
            for other, transform in neighbours.get(frame, []):
                if other not in reached:
                    reached[other] = reached[frame] @ transform
                    queue.append(other)
        return reached.get(target)

    # ----------------------------------------------------------------------------------------------
    # the FrameSource interface

    @property
    def name(self) -> str:
        stem = self.path.name if self.path.is_dir() else self.path.stem
        return f"{_safe_name(stem)}-{_safe_name(self.topic)}"

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def ground_truth(self) -> np.ndarray | None:
        """(N, 4, 4) T_w_c of the selected frames (first = identity), or None."""
        return None if self._ground_truth is None else self._ground_truth.copy()

    @property
    def indices(self) -> list[int]:
        """The selected frames' positions in stamp order (0 = the earliest-stamped image message)."""
        return list(self._indices)

    @property
    def stamps(self) -> np.ndarray:
        """(N,) header stamps (Unix seconds) of the selected frames."""
        return self._selected_stamps()

    @property
    def camera_height(self) -> float | None:
        return None

    def __len__(self) -> int:
        return len(self._indices)

    def __iter__(self) -> Iterator[Frame]:
        with _bag_errors(self._where, "cannot open the log"):
            reader = _open_reader(self.path)
        try:
            yield from self._frames(reader)
        finally:
            with _bag_errors(self._where, "cannot close the log"):
                reader.close()

    def _reorder_depth(self) -> int:
        """How many selected raw messages streaming in log order must hold back to yield in stamp order."""
        wanted = self._order[np.asarray(self._indices)]
        due = 0
        held = 0
        deepest = 0
        seen: set[int] = set()
        for position in np.sort(wanted):
            seen.add(int(position))
            held += 1
            while due < len(wanted) and int(wanted[due]) in seen:
                due += 1
                held -= 1
            deepest = max(deepest, held)
        return deepest

    def _frames(self, reader: Any) -> Iterator[Frame]:
        wanted = [int(self._order[i]) for i in self._indices]  # arrival positions, in yield order
        if not self._seekable or self._reorder_depth() > REORDER_LIMIT:
            for index, position in zip(self._indices, wanted, strict=True):
                yield self._frame(reader, index, position, None)
            return
        selected = set(wanted)
        start = min(wanted)
        log = self._log_ns
        first_position = int(np.searchsorted(log, log[start], side="left"))
        held: dict[int, bytes] = {}
        due = 0
        messages = reader.messages(connections=self._image_connections(reader), start=int(log[start]))
        position = first_position - 1
        while due < len(wanted):
            with _bag_errors(self._where, f"cannot read {self.topic} after message {position}"):
                item = next(messages, None)
            if item is None:
                raise SourceError(f"{self._where}: {self.topic} ended at message {position}, before frame "
                                  f"{self._indices[due]} (has the log changed?)")
            position += 1
            if position >= len(log) or item[1] != log[position]:
                raise SourceError(f"{self._where}: message {position} of {self.topic} is not the one read when the "
                                  "log was opened (has the log changed?)")
            if position in selected:
                held[position] = bytes(item[2])
            while due < len(wanted) and wanted[due] in held:
                raw = held.pop(wanted[due])
                yield self._frame(reader, self._indices[due], wanted[due], raw)
                due += 1

    def _frame(self, reader: Any, index: int, position: int, raw: bytes | None) -> Frame:
        """The frame at arrival `position` from its raw message (read from the log when None)."""
        stamp = float(self._stamps_ns[position]) / 1e9
        try:
            if position in self._bad:
                raise SourceError(f"{self._where}: frame {index}: {self._bad[position]}")
            image = self._decode(reader, self._seek_raw(reader, position) if raw is None else raw, index, position)
        except SourceError as exc:
            if self._on_bad_frame == "fail":
                raise
            return Frame(index, stamp, np.zeros((self._size[1], self._size[0]), np.uint8), defect=str(exc))
        return Frame(index, stamp, image)

    def __repr__(self) -> str:
        return f"RosbagSource({str(self.path)!r}, topic={self.topic!r}, frames={len(self)})"

