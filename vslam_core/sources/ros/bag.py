"""Frames of a camera topic in a ROS log: a ROS 1 ``.bag``, a ROS 2 bag folder (sqlite3 ``.db3`` or ``.mcap``
storage), or a bare ``.mcap`` / ``.db3`` file, read with ``rosbags.highlevel.AnyReader``.

Images: ``sensor_msgs/msg/Image`` and ``sensor_msgs/msg/CompressedImage``, turned into grey uint8 by
`ros_images.ImageDecoder` (the encodings, and how mono16 is scaled, are described there).

Streaming: the bag is never held in memory. Construction reads the image topic once, parsing only the
header (stamp, frame_id) out of each message's raw bytes (CDR or ROS 1 serialisation, no image decoding),
then decodes the first selected frame (image size, encoding check). Iteration reads the bag again and
decodes one frame at a time; frames are yielded in header-stamp order (stable), with a small reorder buffer
of raw messages when the log holds them out of order (or one seek per frame when the disorder is large).

Calibration: the first ``sensor_msgs/msg/CameraInfo`` of the image topic's namespace (``/cam/image_raw`` →
``/cam/camera_info``, then the parent namespaces), unless `calibration` overrides it. Ground truth: a TUM
file of camera poses, or a pose topic (PoseStamped, PoseWithCovarianceStamped, Odometry, TransformStamped),
matched to the frames by stamp; a body frame other than the camera's is moved onto the camera with
``/tf_static`` (see `ros_ground_truth`). Every problem is a one-line `SourceError`.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from vslam_core.errors import SourceError
from vslam_core.sources.base import (
    CameraIntrinsics,
    Frame,
    FrameRange,
    SelectedSource,
    is_utf8_path,
    safe_name,
    shown_path,
)
from vslam_core.sources.calibration import make_intrinsics
from vslam_core.sources.folder import complete_intrinsics
from vslam_core.sources.kitti import BadFramePolicy, select
from vslam_core.sources.ros.ground_truth import topic_ground_truth
from vslam_core.sources.ros.images import IMAGE_TYPES, ImageDecoder
from vslam_core.sources.ros.mcap_recovery import RecoveredMcap, is_cut_short, recover_mcap
from vslam_core.sources.ros.messages import bag_errors, bare, field, one_line
from vslam_core.sources.stamps import DEFAULT_GT_TOLERANCE_S, ground_truth_at, matched_by_time, stamp_problems
from vslam_core.trajectory.io import check_ground_truth_steps, read_tum_poses

CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"

#: Above this many frames held back for stamp order, iteration seeks each frame instead of buffering.
REORDER_LIMIT = 32


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


def _open_reader(path: Path) -> Any:
    """An opened ``AnyReader`` on `path` (ROS 2 logs without type definitions use the Humble types)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    ros2 = path.suffix != ".bag"
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE) if ros2 else None)
    reader.open()
    return reader


def _cut_short_mcap(path: Path) -> Path | None:
    """The MCAP file of `path` (a bare ``.mcap``, or a ROS 2 bag folder's only ``.mcap``) when it is cut short."""
    files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    if len(files) != 1 or files[0].suffix != ".mcap" or not is_cut_short(files[0]):
        return None
    return files[0]


def _log_format(path: Path) -> str:
    if path.is_dir():
        suffixes = {p.suffix for p in path.iterdir()}
        if ".mcap" in suffixes:
            return "ros2 bag (mcap)"
        if ".db3" in suffixes:
            return "ros2 bag (sqlite3)"
        return "ros2 bag"
    return {".bag": "ros1 bag", ".mcap": "mcap", ".db3": "sqlite3"}[path.suffix]


class RosbagSource(SelectedSource):
    """Frames of one image topic of a ROS log (see the module docstring).

    path: a ROS 1 ``.bag``, a ROS 2 bag folder (``metadata.yaml`` + ``.db3`` or ``.mcap``), or a bare
    ``.mcap`` / ``.db3`` file. topic: the image topic; None picks the log's only image topic.
    frames: a selection among the frames in stamp order (0..N-1). calibration: overrides the CameraInfo
    (width/height 0 = the images' size). ground_truth: a TUM file of camera poses (absolute stamps, any
    world frame); gt_topic instead: a pose topic of the log. Both are matched to the frames' header stamps
    within gt_tolerance_s and re-based on the first selected frame. on_bad_frame: "fail" raises a
    `SourceError` naming an undecodable frame, "skip" yields it as a black placeholder with a `defect`.
    ``indices`` are the selected frames' positions in stamp order (0 = the earliest-stamped image message).
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
        self._where = shown_path(self.path)
        self._on_bad_frame = on_bad_frame
        self.notes: list[str] = []
        self.properties: dict[str, str] = {}
        if ground_truth is not None and gt_topic is not None:
            raise SourceError(f"{self._where}: give the ground truth as a TUM file or as a topic, not both")
        self._check_path()
        self._cdr = self.path.suffix != ".bag"
        self._decoder = ImageDecoder()

        self._recovered: RecoveredMcap | None = None
        reader = self._open_log()
        try:
            with bag_errors(self._where, "cannot read the log"):
                topics = {name: info.msgtype or "" for name, info in reader.topics.items()}
                self.topic = self._pick_topic(topics, topic)
                self._msgtype = topics[self.topic]
            if self._recovered is not None:
                self.notes.append(self._recovered.note(self.topic))
            self._scan_stamps(reader)
            self._indices = select(frames, len(self._order), f"{self._where} {self.topic}")
            first = self._read_first_frame(reader)
            size = (first.shape[1], first.shape[0])
            self._size = size
            self._intrinsics = self._calibrate(reader, topics, calibration, size)
            self._ground_truth = self._load_ground_truth(reader, topics, ground_truth, gt_topic, gt_tolerance_s)
            if self._ground_truth is not None:
                self.gt_matching = matched_by_time(len(self._indices), gt_tolerance_s)
        finally:
            with bag_errors(self._where, "cannot close the log"):
                reader.close()

        self.properties.update({
            "topic": self.topic,
            "log_format": _log_format(self.path),
            "first_stamp": _format_ns(int(self._stamps_ns[self._order[self._indices[0]]])),
            "frame_id": self.frame_id or "-",
            "message_type": self._msgtype,
            "messages": str(len(self._order)),
        })
        stem = self.path.name if self.path.is_dir() else self.path.stem
        self._name = f"{safe_name(stem, 'log')}-{safe_name(self.topic, 'log')}"
        if self._decoder.mono16_shift is not None:
            self.properties["mono16"] = f">> {self._decoder.mono16_shift} bits (from the first frame's range)"

    # ----------------------------------------------------------------------------------------------
    # construction steps

    def _open_log(self) -> Any:
        """An opened reader of the log: rosbags' `AnyReader`, or, for an MCAP file cut short (no summary: the
        recorder was killed), a reader of the messages before the cut (`mcap_recovery`), with a note saying how
        many were recovered and where the file stops."""
        if self._recovered is not None:
            return self._recovered.open()
        try:
            with bag_errors(self._where, "cannot open the log (corrupt, truncated or not a ROS log?)"):
                return _open_reader(self.path)
        except SourceError:
            cut = _cut_short_mcap(self.path)
            if cut is None:
                raise
        with bag_errors(self._where, f"cannot read the cut-short log {cut}"):
            self._recovered = recover_mcap(cut)
            reader = self._recovered.open()
        self.properties["recovered"] = (f"recovered {self._recovered.messages} messages before byte "
                                        f"{self._recovered.stopped_at} of {self._recovered.size}")
        return reader

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
        if "sqlite3" in _log_format(path) and not is_utf8_path(path):
            raise SourceError(f"{self._where}: SQLite cannot open a log whose path is not valid UTF-8; rename the log "
                              "(or its folder)")

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
        with bag_errors(self._where, f"cannot read {self.topic}"):
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
        self.frame_id = bare(frame_id or "")
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
        with bag_errors(self._where, f"cannot read message {position} of {self.topic}"):
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
            raise SourceError(f"{what}: corrupt message ({one_line(exc)})") from None
        try:
            decoded = self._decoder.decode(msg, self._msgtype)
        except SourceError as exc:
            raise SourceError(f"{what}: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - a malformed message whose fields do not add up
            raise SourceError(f"{what}: cannot decode ({one_line(exc)})") from None
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
        with bag_errors(self._where, f"cannot read {info_topic}"):
            connections = [c for c in reader.connections if c.topic == info_topic]
            for conn, _log_time, raw in reader.messages(connections=connections):
                msg = reader.deserialize(raw, conn.msgtype)
                break
        if msg is None:
            raise SourceError(f"{self._where}: {info_topic} holds no message: pass --calib FILE (or --intrinsics)")
        self.properties["camera_info"] = info_topic
        try:
            with bag_errors(self._where, f"{info_topic}: malformed CameraInfo"):
                width, height = int(msg.width), int(msg.height)
                model_name = str(msg.distortion_model)
                K = np.asarray(field(msg, "k", "K"), np.float64)  # noqa: N806
                P = np.asarray(field(msg, "p", "P"), np.float64)  # noqa: N806
                D = np.asarray(field(msg, "d", "D"), np.float64)  # noqa: N806
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

    def _load_ground_truth(self, reader: Any, topics: dict[str, str], ground_truth: str | Path | None,
                           gt_topic: str | None, tolerance_s: float) -> np.ndarray | None:
        if ground_truth is not None:
            gt_path = Path(ground_truth)
            if not gt_path.is_file():
                raise SourceError(f"{gt_path}: ground-truth file not found")
            gt_stamps, gt_poses = read_tum_poses(gt_path)
            check_ground_truth_steps(gt_path, gt_poses, gt_stamps)
            self.properties["ground_truth"] = f"TUM {gt_path.name}"
            return ground_truth_at(self.stamps, gt_stamps, gt_poses, tolerance_s, str(gt_path))
        if gt_topic is None:
            return None
        poses, label, notes = topic_ground_truth(reader, topics, gt_topic, self.frame_id, self.stamps,
                                                 tolerance_s, self._where)
        self.notes.extend(notes)
        self.properties["ground_truth"] = label
        return poses

    # ----------------------------------------------------------------------------------------------
    # the FrameSource interface

    @property
    def stamps(self) -> np.ndarray:
        """(N,) header stamps (Unix seconds) of the selected frames."""
        return self._stamps_ns[self._order[np.asarray(self._indices)]] / 1e9

    def __iter__(self) -> Iterator[Frame]:
        reader = self._open_log()
        try:
            yield from self._frames(reader)
        finally:
            with bag_errors(self._where, "cannot close the log"):
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
            with bag_errors(self._where, f"cannot read {self.topic} after message {position}"):
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

