"""Pick the right source for what a user pointed at (used by the CLI)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from vslam_core.errors import SourceError
from vslam_core.sources.base import CameraIntrinsics, FrameRange, FrameSource, ground_truth_matching
from vslam_core.sources.image_files import IMAGE_EXTENSIONS
from vslam_core.sources.stamps import DEFAULT_GT_MAX_GAP_S, DEFAULT_GT_TOLERANCE_S

if TYPE_CHECKING:
    from vslam_core.sources.kitti import BadFramePolicy, GroundTruthFormat

# Each kind of source is imported when it is the one opened: the ROS reader, the synthetic street's renderer and
# the YAML parser of calibration files cost a process that opens a KITTI folder ~0.3 s of CPU.

VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg"}
LOG_SUFFIXES = {".bag", ".mcap", ".db3"}
SYNTHETIC = "synthetic"


def open_source(
    spec: str | None,
    *,
    sequence: str | None = None,
    frames: FrameRange | None = None,
    intrinsics: str | None = None,
    calib: Path | None = None,
    ground_truth: Path | None = None,
    gt_format: GroundTruthFormat = "auto",
    on_bad_frame: BadFramePolicy = "fail",
    inject: str | None = None,
    topic: str | None = None,
    gt_topic: str | None = None,
    gt_tolerance_s: float | None = None,
    route: str | None = None,
    calib_scale: float | None = None,
    gt_time_offset_s: float | None = None,
    gt_rows: str | None = None,
) -> FrameSource:
    """None or "synthetic": the embedded synthetic street. A ROS 1 ``.bag``, a ROS 2 bag folder or a bare
    ``.mcap``/``.db3``, or a ROS 2 bag folder without ``metadata.yaml`` (the recorder killed) holding one
    ``.mcap``: `RosbagSource`. A video file: `VideoSource`. A folder with ``sequences/`` or
    ``image_0/``: KITTI; with ``mav0/``: EuRoC; with ``camera.txt``, ``times.txt`` and ``images/``: TUM
    monoVO; with ``rgb.txt`` and ``rgb/``: TUM RGB-D. Any other folder: `ImageFolderSource`. `inject` wraps the
    source in a `FaultInjector` (e.g. ``"dark@120,blur@200:210"``). `gt_tolerance_s` (None: 10 ms) applies
    where ground truth is matched to the frames by time (TUM RGB-D interpolates between the rows around a frame:
    there it is the largest gap between them, None: 100 ms); given where it is not (no ground truth, or paired row
    by row), it is a `SourceError`; so is `gt_time_offset_s` (``--gt-time-offset``: the ground truth's clock reads
    this much more than the frames'). `gt_rows` (``--gt-rows A:B``): which rows of a ``--gt`` file without times are
    the frames (a file with more rows than frames and nothing to pair them by time is refused without it). `route`
    picks the synthetic street's route ("street", "loop", "walk" or "drive"). `calib_scale` resizes the given
    calibration (`--calib-scale`, `scale_calibration`). A principal point outside the middle 60 % of the frames is
    a `SourceError` (`principal_point_problem`)."""
    tolerance = DEFAULT_GT_TOLERANCE_S if gt_tolerance_s is None else gt_tolerance_s
    from vslam_core.sources.stamps import parse_gt_rows

    rows = None if gt_rows is None else parse_gt_rows(gt_rows)
    if rows is not None and ground_truth is None:
        raise SourceError("--gt-rows does not apply here: it says which rows of a --gt file are the frames, and none "
                          "is given")
    if gt_time_offset_s is not None and not math.isfinite(gt_time_offset_s):
        raise SourceError(f"--gt-time-offset {gt_time_offset_s}: not a number of seconds")
    request = _Request(spec, sequence, frames, intrinsics, calib, ground_truth, gt_format, on_bad_frame, topic,
                       gt_topic, tolerance, route, calib_scale, gt_time_offset_s or 0.0, rows,
                       gt_tolerance_s)
    source = _open(request)
    from vslam_core.sources.calibration import principal_point_problem

    if (problem := principal_point_problem(source.intrinsics)) is not None:
        raise SourceError(problem)
    if gt_tolerance_s is not None:
        _refuse_tolerance(source)
    if gt_time_offset_s is not None:
        _refuse_tolerance(source, "--gt-time-offset")
    if not inject:
        return source
    from vslam_core.sources.faults import FaultInjector, parse_faults

    return FaultInjector(source, parse_faults(inject))


def _refuse_tolerance(source: FrameSource, option: str = "--gt-tolerance") -> None:
    """`--gt-tolerance` (or `--gt-time-offset`) where no ground truth is matched by time would be silently ignored:
    say why instead."""
    how = ground_truth_matching(source)
    if how is not None and how.startswith("matched by time"):
        return
    why = ("there is no ground truth" if how is None else f"the ground truth is not matched by time here ({how}; "
           "time matching needs timestamps on both sides: a TUM file and frames with a clock)")
    raise SourceError(f"{option} does not apply here: {why}")


@dataclass(frozen=True)
class _Request:
    spec: str | None
    sequence: str | None
    frames: FrameRange | None
    intrinsics: str | None
    calib: Path | None
    ground_truth: Path | None
    gt_format: GroundTruthFormat
    on_bad_frame: BadFramePolicy
    topic: str | None
    gt_topic: str | None
    gt_tolerance_s: float
    route: str | None = None
    calib_scale: float | None = None
    gt_time_offset_s: float = 0.0
    gt_rows: tuple[int, int | None] | None = None
    #: --gt-tolerance as given (None: the default); TUM RGB-D interpolates, and takes it as the largest gap
    given_tolerance_s: float | None = None

    def given(self) -> dict[str, object]:
        return {"--sequence": self.sequence, "--intrinsics": self.intrinsics, "--calib": self.calib,
                "--gt": self.ground_truth, "--topic": self.topic, "--gt-topic": self.gt_topic,
                "--calib-scale": self.calib_scale}


def _open(r: _Request) -> FrameSource:
    given = r.given()
    if r.spec is None or r.spec == SYNTHETIC:
        _refuse(given, tuple(given), "the synthetic street has its own camera and exact ground truth, and no "
                "sequences or topics")
        from vslam_core.sources.synthetic import SyntheticStreet

        return SyntheticStreet(frames=r.frames, route=r.route or "street")  # type: ignore[arg-type]
    if r.route is not None:
        raise SourceError(f"--route is for the synthetic street, not {r.spec}")
    path = Path(r.spec)
    if not path.exists():
        raise SourceError(f"{path}: no such file or folder")
    path = _unfinished_bag(path) or path
    if path.suffix.lower() in LOG_SUFFIXES or (path / "metadata.yaml").is_file():
        _refuse(given, ("--sequence",), f"{path} is a ROS log, not a KITTI dataset root")
        if r.gt_time_offset_s or r.gt_rows is not None:
            raise SourceError(f"{'--gt-time-offset' if r.gt_time_offset_s else '--gt-rows'} does not apply to a ROS "
                              "log yet: its ground truth is matched to the frames' header stamps")
        from vslam_core.sources.ros.bag import RosbagSource

        return RosbagSource(path, topic=r.topic, frames=r.frames, calibration=_calibration(r),
                            ground_truth=r.ground_truth, gt_topic=r.gt_topic, gt_tolerance_s=r.gt_tolerance_s,
                            on_bad_frame=r.on_bad_frame)
    _refuse(given, ("--topic", "--gt-topic"), f"{path} is not a ROS log (.bag, .mcap, .db3 or a ROS 2 bag folder)")
    if path.is_file():
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise SourceError(f"{path}: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}), a ROS log "
                              f"({', '.join(sorted(LOG_SUFFIXES))}) nor a folder")
        _refuse(given, ("--sequence",), f"{path} is a video, not a KITTI dataset root")
        camera = _calibration(r)
        if camera is None:
            raise SourceError(f"{path}: a video needs its camera: --calib FILE or --intrinsics fx,fy,cx,cy")
        from vslam_core.sources.video import VideoSource

        return VideoSource(path, camera, frames=r.frames, ground_truth=r.ground_truth, gt_format=r.gt_format,
                           gt_tolerance_s=r.gt_tolerance_s, gt_time_offset_s=r.gt_time_offset_s, gt_rows=r.gt_rows)
    if (path / "sequences").is_dir() or (path / "image_0").is_dir():
        _refuse(given, ("--intrinsics", "--calib", "--calib-scale", "--gt"),
                "a KITTI sequence has its own calib.txt and poses/NN.txt")
        from vslam_core.sources.kitti import KittiSource

        return KittiSource(path, sequence=r.sequence, frames=r.frames, on_bad_frame=r.on_bad_frame)
    _refuse(given, ("--sequence",), f"{path} is not a KITTI dataset root")
    if r.gt_rows is not None and not _plain_folder(path):
        raise SourceError(f"--gt-rows does not apply here: {path} is a dataset whose ground truth is matched to the "
                          "frames by time (--gt-time-offset shifts its clock)")
    from vslam_core.sources.euroc import EurocSource, is_euroc
    from vslam_core.sources.folder import ImageFolderSource
    from vslam_core.sources.tum_mono import TumMonoSource, is_tum_mono
    from vslam_core.sources.tum_rgbd import TumRgbdSource, is_tum_rgbd

    if is_euroc(path):
        _refuse(given, ("--intrinsics", "--calib", "--calib-scale"), "an EuRoC sequence has its own sensor.yaml")
        return EurocSource(path, frames=r.frames, ground_truth=r.ground_truth, gt_tolerance_s=r.gt_tolerance_s,
                           on_bad_frame=r.on_bad_frame, gt_time_offset_s=r.gt_time_offset_s)
    if is_tum_mono(path):
        _refuse(given, ("--intrinsics", "--calib", "--calib-scale"), "a TUM monoVO sequence has its own camera.txt")
        return TumMonoSource(path, frames=r.frames, ground_truth=r.ground_truth, gt_tolerance_s=r.gt_tolerance_s,
                             on_bad_frame=r.on_bad_frame, gt_time_offset_s=r.gt_time_offset_s)
    if is_tum_rgbd(path):
        gap = DEFAULT_GT_MAX_GAP_S if r.given_tolerance_s is None else r.given_tolerance_s
        return TumRgbdSource(path, camera=_calibration(r), frames=r.frames, ground_truth=r.ground_truth,
                             gt_max_gap_s=gap, on_bad_frame=r.on_bad_frame, gt_time_offset_s=r.gt_time_offset_s)
    return ImageFolderSource(path, intrinsics=_calibration(r), ground_truth=r.ground_truth, gt_format=r.gt_format,
                             frames=r.frames, on_bad_frame=r.on_bad_frame, gt_tolerance_s=r.gt_tolerance_s,
                             gt_time_offset_s=r.gt_time_offset_s, gt_rows=r.gt_rows)


def _plain_folder(path: Path) -> bool:
    """A folder of images (not EuRoC, TUM monoVO nor TUM RGB-D): its --gt may be paired row by row."""
    from vslam_core.sources.euroc import is_euroc
    from vslam_core.sources.tum_mono import is_tum_mono
    from vslam_core.sources.tum_rgbd import is_tum_rgbd

    return not (is_euroc(path) or is_tum_mono(path) or is_tum_rgbd(path))


def _unfinished_bag(path: Path) -> Path | None:
    """The MCAP file of a ROS 2 bag folder whose recorder was killed before it wrote ``metadata.yaml``: a folder
    holding one ``.mcap`` file and no images (None for anything else)."""
    if not path.is_dir() or (path / "metadata.yaml").exists():
        return None
    files = [p for p in path.iterdir() if p.is_file()]
    logs = [p for p in files if p.suffix == ".mcap"]
    if len(logs) != 1 or any(p.suffix.lower() in IMAGE_EXTENSIONS for p in files):
        return None
    return logs[0]


def _refuse(given: Mapping[str, object], options: tuple[str, ...], reason: str) -> None:
    """An option the source would silently ignore is an error saying why (never quietly dropped)."""
    for option in options:
        if given[option] is not None:
            raise SourceError(f"{option} does not apply here: {reason}")


def _calibration(r: _Request) -> CameraIntrinsics | None:
    """The camera the user gave: ``--intrinsics fx,fy,cx,cy`` (a pinhole) or ``--calib FILE`` (any supported
    calibration file, lens included), its size 0x0 when not stated (the source fills it); None if neither."""
    if r.intrinsics is not None and r.calib is not None:
        raise SourceError("--intrinsics and --calib both describe the camera: give one of them")
    camera = None
    if r.intrinsics is not None:
        from vslam_core.sources.folder import parse_intrinsics

        fx, fy, cx, cy = parse_intrinsics(r.intrinsics)
        camera = CameraIntrinsics(fx, fy, cx, cy, 0, 0, origin="--intrinsics")
    elif r.calib is not None:
        from vslam_core.sources.calibration_files import read_calibration

        camera = read_calibration(r.calib)
    if r.calib_scale is None:
        return camera
    if camera is None:
        raise SourceError("--calib-scale scales the calibration given with --calib or --intrinsics: give one")
    from vslam_core.sources.calibration import scale_calibration

    return scale_calibration(camera, r.calib_scale)
