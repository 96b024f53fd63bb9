"""Pick the right source for what a user pointed at (used by the CLI)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from vslam_core.errors import SourceError
from vslam_core.sources.base import FrameRange, FrameSource
from vslam_core.sources.faults import FaultInjector, parse_faults
from vslam_core.sources.folder import ImageFolderSource, PartialIntrinsics, parse_intrinsics
from vslam_core.sources.kitti import BadFramePolicy, GroundTruthFormat, KittiSource, read_p0_intrinsics
from vslam_core.sources.synthetic import SyntheticStreet
from vslam_core.sources.video import VideoSource

VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg"}
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
) -> FrameSource:
    """None or "synthetic": the embedded synthetic street. A video file: `VideoSource`. A folder with
    ``sequences/`` or ``image_0/``: KITTI. Any other folder: `ImageFolderSource`. `inject` wraps the source
    in a `FaultInjector` (e.g. ``"dark@120,blur@200:210"``)."""
    source = _open(spec, sequence, frames, intrinsics, calib, ground_truth, gt_format, on_bad_frame)
    return FaultInjector(source, parse_faults(inject)) if inject else source


def _open(
    spec: str | None,
    sequence: str | None,
    frames: FrameRange | None,
    intrinsics: str | None,
    calib: Path | None,
    ground_truth: Path | None,
    gt_format: GroundTruthFormat,
    on_bad_frame: BadFramePolicy,
) -> FrameSource:
    given = {"--sequence": sequence, "--intrinsics": intrinsics, "--calib": calib, "--gt": ground_truth}
    if spec is None or spec == SYNTHETIC:
        _refuse(given, ("--sequence", "--intrinsics", "--calib", "--gt"),
                "the synthetic street has its own camera and exact ground truth, and no sequences")
        return SyntheticStreet(frames=frames)
    path = Path(spec)
    if not path.exists():
        raise SourceError(f"{path}: no such file or folder")
    if path.is_file():
        if path.suffix.lower() not in VIDEO_SUFFIXES:
            raise SourceError(f"{path}: not a video ({', '.join(sorted(VIDEO_SUFFIXES))}) nor a folder")
        _refuse(given, ("--sequence",), f"{path} is a video, not a KITTI dataset root")
        if intrinsics is None and calib is None:
            raise SourceError(f"{path}: a video needs --intrinsics fx,fy,cx,cy")
        return VideoSource(path, _intrinsics(intrinsics, calib), frames=frames, ground_truth=ground_truth,
                           gt_format=gt_format)
    if (path / "sequences").is_dir() or (path / "image_0").is_dir():
        _refuse(given, ("--intrinsics", "--calib", "--gt"),
                "a KITTI sequence has its own calib.txt and poses/NN.txt")
        return KittiSource(path, sequence=sequence, frames=frames, on_bad_frame=on_bad_frame)
    _refuse(given, ("--sequence",), f"{path} is an image folder, not a KITTI dataset root")
    return ImageFolderSource(
        path,
        intrinsics=parse_intrinsics(intrinsics) if intrinsics is not None else None,
        calib=calib,
        ground_truth=ground_truth,
        gt_format=gt_format,
        frames=frames,
        on_bad_frame=on_bad_frame,
    )


def _refuse(given: Mapping[str, object], options: tuple[str, ...], reason: str) -> None:
    """An option the source would silently ignore is an error saying why (never quietly dropped)."""
    for option in options:
        if given[option] is not None:
            raise SourceError(f"{option} does not apply here: {reason}")


def _intrinsics(text: str | None, calib: Path | None) -> PartialIntrinsics:
    """Intrinsics from an "fx,fy,cx,cy" string, else from a calib file's P0 line."""
    if text is not None:
        return parse_intrinsics(text)
    if calib is None:
        raise SourceError("camera intrinsics needed: --intrinsics fx,fy,cx,cy or --calib FILE")
    return PartialIntrinsics(*read_p0_intrinsics(calib))
