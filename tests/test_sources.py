"""Tests of the frame sources: KITTI (real data), image folders, videos, and every error case."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from vslam_core.errors import SourceError, TrajectoryFormatError, VslamError
from vslam_core.sources.base import CameraIntrinsics, Frame, FrameRange, FrameSource, rebase_poses
from vslam_core.sources.folder import ImageFolderSource, PartialIntrinsics, parse_intrinsics
from vslam_core.sources.kitti import KittiSource, read_p0_intrinsics
from vslam_core.sources.video import VideoSource
from vslam_core.trajectory.io import read_kitti_poses, write_kitti_poses, write_tum_poses

KITTI_00 = dict(fx=718.856, fy=718.856, cx=607.1928, cy=185.2157, width=1241, height=376)
KITTI_05 = dict(fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, width=1226, height=370)
FAKE_P0 = "P0: 100.0 0.0 32.0 0.0 0.0 110.0 24.0 0.0 0.0 0.0 1.0 0.0\n"


# --------------------------------------------------------------------------------------------------
# helpers: small datasets in tmp_path (never in the repository)


def fake_poses(n: int) -> np.ndarray:
    """(n, 4, 4): a gentle left turn, 1 m a frame, first pose NOT the identity (to see the re-basing)."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        angle = 0.05 * i + 0.3
        c, s = np.cos(angle), np.sin(angle)
        poses[i, :3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        poses[i, :3, 3] = [5.0 + i * s, 1.0, -2.0 + i * c]
    return poses


def noise_image(seed: int, width: int = 64, height: int = 48) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(height, width), dtype=np.uint8)


def make_kitti(root: Path, n: int = 4, seq: str = "00", poses_rows: int | None = None) -> Path:
    """A synthetic KITTI root: n noise images 64x48, calib, times, poses (``poses_rows`` rows)."""
    folder = root / "sequences" / seq
    (folder / "image_0").mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(folder / "image_0" / f"{i:06d}.png"), noise_image(i))
    (folder / "calib.txt").write_text(FAKE_P0 + "P1: 1 2 3 4 5 6 7 8 9 10 11 12\n")
    (folder / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(n)))
    (root / "poses").mkdir()
    write_kitti_poses(root / "poses" / f"{seq}.txt", fake_poses(n if poses_rows is None else poses_rows))
    return root


def copy_real_frames(
    kitti_root: Path, seq: str, folder: Path, count: int, colour: bool = False
) -> list[Path]:
    """Copy the first ``count`` real frames with cv2 (read from the shared folder, write into folder)."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for i in range(count):
        image = cv2.imread(
            str(kitti_root / "sequences" / seq / "image_0" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE
        )
        assert image is not None
        if colour:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        path = folder / f"{i:06d}.png"
        assert cv2.imwrite(str(path), image)
        written.append(path)
    return written


def assert_names(exc: pytest.ExceptionInfo[BaseException], path: Path) -> None:
    message = str(exc.value)
    assert str(path) in message, message
    assert "\n" not in message


# --------------------------------------------------------------------------------------------------
# real KITTI


@pytest.mark.kitti
def test_kitti_00_root_and_sequence_folder_agree(kitti_root: Path) -> None:
    by_root = KittiSource(kitti_root, sequence="0")
    by_folder = KittiSource(kitti_root / "sequences" / "00")
    for source in (by_root, by_folder):
        assert isinstance(source, FrameSource)
        assert source.name == "kitti-00" and source.sequence == "00"
        assert len(source) == 300
        assert source.intrinsics == CameraIntrinsics(**KITTI_00)  # type: ignore[arg-type]
        gt = source.ground_truth
        assert gt is not None and gt.shape == (300, 4, 4)
        np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(by_root.ground_truth, by_folder.ground_truth)

    count = 0
    for frame in by_root:  # every frame decodes, 376x1241 grey
        assert isinstance(frame, Frame) and frame.index == count
        assert frame.image.shape == (376, 1241) and frame.image.dtype == np.uint8
        count += 1
    assert count == 300
    step = FrameRange(0, 300, 37)
    a = list(KittiSource(kitti_root, "00", frames=step))
    b = list(KittiSource(kitti_root / "sequences" / "00", frames=step))
    assert [f.index for f in a] == [f.index for f in b] == list(range(0, 300, 37))
    for fa, fb in zip(a, b, strict=True):
        assert fa.timestamp == fb.timestamp
        np.testing.assert_array_equal(fa.image, fb.image)
    assert a[0].timestamp == 0.0 and a[1].timestamp == pytest.approx(3.835871, abs=1e-9)  # times.txt[37]


@pytest.mark.kitti
def test_kitti_00_ground_truth_rebased_for_frame_range(kitti_root: Path) -> None:
    source = KittiSource(kitti_root, "00", frames=FrameRange(100, 200))
    assert len(source) == 100 and source.indices[0] == 100
    raw = read_kitti_poses(kitti_root / "poses" / "00.txt", max_rows=300)
    gt = source.ground_truth
    assert gt is not None and gt.shape == (100, 4, 4)
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-12)
    expected = np.linalg.inv(raw[100]) @ raw[100:200]
    np.testing.assert_allclose(gt, expected, atol=1e-9)
    # the relative motions are unchanged by the re-basing
    np.testing.assert_allclose(np.linalg.inv(gt[10]) @ gt[60], np.linalg.inv(raw[110]) @ raw[160], atol=1e-9)
    first = next(iter(source))
    assert first.index == 100
    reference = cv2.imread(str(kitti_root / "sequences/00/image_0/000100.png"), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(first.image, reference)


@pytest.mark.kitti
def test_kitti_05_intrinsics(kitti_root: Path) -> None:
    source = KittiSource(kitti_root, "05", frames=FrameRange(0, 10))
    assert source.name == "kitti-05"
    assert source.intrinsics == CameraIntrinsics(**KITTI_05)  # type: ignore[arg-type]
    assert len(source) == 10
    frame = next(iter(source))
    assert frame.image.shape == (370, 1226)


@pytest.mark.kitti
def test_kitti_poses_file_with_more_rows_than_images(kitti_root: Path, tmp_path: Path) -> None:
    # 5 real frames, the full real poses file (4541 rows): the first 5 rows are used
    folder = tmp_path / "sequences" / "00"
    copy_real_frames(kitti_root, "00", folder / "image_0", 5)
    shutil.copyfile(kitti_root / "sequences/00/calib.txt", folder / "calib.txt")
    (tmp_path / "poses").mkdir()
    shutil.copyfile(kitti_root / "poses/00.txt", tmp_path / "poses" / "00.txt")
    source = KittiSource(tmp_path, "00")
    assert len(source) == 5
    assert source.intrinsics == CameraIntrinsics(**KITTI_00)  # type: ignore[arg-type]
    full = read_kitti_poses(kitti_root / "poses" / "00.txt")
    assert len(full) == 4541
    np.testing.assert_allclose(source.ground_truth, rebase_poses(full[:5]), atol=1e-12)  # type: ignore[arg-type]
    assert [f.timestamp for f in source] == [None] * 5  # no times.txt


@pytest.mark.kitti
def test_image_folder_with_intrinsics_string_and_with_calib(kitti_root: Path, tmp_path: Path) -> None:
    folder = tmp_path / "drive 05"
    copy_real_frames(kitti_root, "05", folder, 3, colour=True)  # colour PNGs: converted to grey
    partial = parse_intrinsics("707.0912, 707.0912,601.8873 183.1104")
    assert partial == PartialIntrinsics(707.0912, 707.0912, 601.8873, 183.1104)
    source = ImageFolderSource(folder, intrinsics=partial)
    assert isinstance(source, FrameSource)
    assert source.intrinsics == CameraIntrinsics(**KITTI_05)  # type: ignore[arg-type]  # size from the image
    assert source.ground_truth is None and len(source) == 3 and source.name == "drive_05"
    frames = list(source)
    original = cv2.imread(str(kitti_root / "sequences/05/image_0/000002.png"), cv2.IMREAD_GRAYSCALE)
    assert frames[2].image.ndim == 2 and frames[2].image.dtype == np.uint8
    np.testing.assert_array_equal(frames[2].image, original)
    assert [f.timestamp for f in frames] == [None, None, None]

    from_calib = ImageFolderSource(folder, calib=kitti_root / "sequences/05/calib.txt")
    assert from_calib.intrinsics == source.intrinsics


@pytest.mark.kitti
def test_image_folder_inside_a_kitti_sequence_finds_calib_and_times(kitti_root: Path) -> None:
    source = ImageFolderSource(kitti_root / "sequences/00/image_0", frames=FrameRange(0, 3))
    assert source.intrinsics == CameraIntrinsics(**KITTI_00)  # type: ignore[arg-type]
    assert source.name == "00-image_0"
    assert [f.timestamp for f in source] == pytest.approx([0.0, 0.1037359, 0.2073381])


@pytest.mark.kitti
def test_image_folder_tum_ground_truth(kitti_root: Path, tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    copy_real_frames(kitti_root, "00", folder, 4)
    poses = read_kitti_poses(kitti_root / "poses/00.txt", max_rows=30)[10:16]  # 6 rows for 4 images
    tum = tmp_path / "gt.tum"
    write_tum_poses(tum, np.arange(4) * 0.1, poses[:4])  # the folder has no clock: row by row, one per image
    for fmt in ("tum", "auto"):
        intrinsics = parse_intrinsics("718.856,718.856,607.1928,185.2157")
        source = ImageFolderSource(
            folder, intrinsics=intrinsics, ground_truth=tum, gt_format=fmt, frames=FrameRange(1, 4)
        )
        gt = source.ground_truth
        assert gt is not None and gt.shape == (3, 4, 4)
        np.testing.assert_allclose(gt, rebase_poses(poses[1:4]), atol=1e-7)
    kitti_file = tmp_path / "gt.txt"
    write_kitti_poses(kitti_file, poses)  # 6 rows, 4 frames, no clock: which rows are the frames is not known
    with pytest.raises(SourceError, match="6 poses for 4 frames and nothing pairs them by time.*--gt-rows A:B"):
        ImageFolderSource(folder, intrinsics=partial_00(), ground_truth=kitti_file)
    for start in (0, 2):  # --gt-rows says
        source = ImageFolderSource(folder, intrinsics=partial_00(), ground_truth=kitti_file, gt_rows=(start, None))
        np.testing.assert_allclose(source.ground_truth, rebase_poses(poses[start:start + 4]),  # type: ignore[arg-type]
                                   atol=1e-9)
        assert source.gt_matching is not None and source.gt_matching.startswith(f"row by row from row {start}")

    for rows in (3, 6):  # a clock on one side only and another count: the rows are not the frames
        other = tmp_path / f"rows{rows}.tum"
        write_tum_poses(other, np.arange(rows) * 0.1, poses[:rows])
        with pytest.raises(SourceError, match=f"{rows} timestamped poses for 4 frames without timestamps") as exc:
            ImageFolderSource(folder, intrinsics=partial_00(), ground_truth=other, gt_format="tum")
        assert_names(exc, other)


def partial_00() -> PartialIntrinsics:
    return PartialIntrinsics(718.856, 718.856, 607.1928, 185.2157)


# --------------------------------------------------------------------------------------------------
# video


def write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> None:
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, (width, height), False)
    assert writer.isOpened(), "MJPG/.avi writer not available"
    for frame in frames:
        writer.write(frame)
    writer.release()


def flat_frames(count: int, width: int = 160, height: int = 120) -> list[np.ndarray]:
    """Frames of distinct flat grey levels (20, 40, …) plus a ramp, so each can be recognised."""
    ramp = np.tile(np.linspace(0, 60, width, dtype=np.uint8), (height, 1))
    return [ramp + np.uint8(20 * (i + 1)) for i in range(count)]


def test_video_round_trip_and_selection(tmp_path: Path) -> None:
    frames = flat_frames(8)
    video = tmp_path / "drive.avi"
    write_video(video, frames)
    source = VideoSource(video, parse_intrinsics("100,100,80,60"))
    assert isinstance(source, FrameSource)
    assert source.name == "video-drive" and source.ground_truth is None
    assert len(source) == 8 and source.frame_count == 8
    assert source.intrinsics == CameraIntrinsics(100.0, 100.0, 80.0, 60.0, 160, 120)
    read = list(source)
    assert [f.index for f in read] == list(range(8))
    for frame, original in zip(read, frames, strict=True):
        assert frame.image.shape == (120, 160) and frame.image.dtype == np.uint8
        assert np.abs(frame.image.astype(int) - original).mean() < 4  # MJPG is lossy
    assert [f.timestamp for f in read] == pytest.approx([i / 10.0 for i in range(8)])

    selected = VideoSource(video, PartialIntrinsics(100, 100, 80, 60), frames=FrameRange(1, 7, 2))
    assert len(selected) == 3
    picked = list(selected)
    assert [f.index for f in picked] == [1, 3, 5]
    assert [f.timestamp for f in picked] == pytest.approx([0.1, 0.3, 0.5])
    for frame in picked:
        assert np.abs(frame.image.astype(int) - frames[frame.index]).mean() < 4

    with pytest.raises(SourceError, match="selects no frame"):
        VideoSource(video, partial_00(), frames=FrameRange(40, 50))


def test_video_colour_frames_ground_truth_and_size_check(tmp_path: Path) -> None:
    video = tmp_path / "colour.avi"
    colour = [cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) for f in flat_frames(4)]
    height, width = colour[0].shape[:2]
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"MJPG"), 5.0, (width, height))
    for frame in colour:
        writer.write(frame)
    writer.release()
    gt_file = tmp_path / "gt.txt"
    write_kitti_poses(gt_file, fake_poses(4))  # the video has a clock, KITTI rows do not: one row per frame
    source = VideoSource(video, partial_00(), frames=FrameRange(2, 4), ground_truth=gt_file)
    assert all(f.image.ndim == 2 for f in source)
    np.testing.assert_allclose(source.ground_truth, rebase_poses(fake_poses(4)[2:4]), atol=1e-9)  # type: ignore[arg-type]
    with pytest.raises(SourceError, match="intrinsics are for 1241x376") as exc:
        VideoSource(video, CameraIntrinsics(**KITTI_00))  # type: ignore[arg-type]
    assert_names(exc, video)
    for rows in (3, 10):
        other = tmp_path / f"rows{rows}.txt"
        write_kitti_poses(other, fake_poses(rows))
        with pytest.raises(SourceError, match=f"{rows} poses without timestamps .KITTI format. for 4 timestamped"
                           ) as exc:
            VideoSource(video, partial_00(), ground_truth=other)
        assert_names(exc, other)


def test_video_that_cannot_be_opened(tmp_path: Path) -> None:
    bad = tmp_path / "bad.avi"
    bad.write_text("this is not a video\n")
    with pytest.raises(SourceError) as exc:
        VideoSource(bad, partial_00())
    assert_names(exc, bad)
    empty = tmp_path / "empty.avi"
    writer = cv2.VideoWriter(str(empty), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (64, 48), False)
    writer.release()  # no frame written
    with pytest.raises(SourceError) as exc:
        VideoSource(empty, partial_00())
    assert_names(exc, empty)
    missing = tmp_path / "missing.avi"
    with pytest.raises(SourceError, match="not found") as exc:
        VideoSource(missing, partial_00())
    assert_names(exc, missing)


# --------------------------------------------------------------------------------------------------
# synthetic KITTI layout: behaviour and every error case (no real data needed)


def test_synthetic_kitti_layout(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4, poses_rows=9)
    source = KittiSource(root, "00", frames=FrameRange(1, 4, 2))
    assert source.intrinsics == CameraIntrinsics(100.0, 110.0, 32.0, 24.0, 64, 48)
    assert [(f.index, f.timestamp) for f in source] == [(1, pytest.approx(0.1)), (3, pytest.approx(0.3))]
    np.testing.assert_array_equal(next(iter(source)).image, noise_image(1))
    np.testing.assert_allclose(source.ground_truth, rebase_poses(fake_poses(4)[[1, 3]]), atol=1e-9)  # type: ignore[arg-type]
    # the sequence folder alone finds ../../poses/00.txt
    direct = KittiSource(root / "sequences" / "00", frames=FrameRange(1, 4, 2))
    np.testing.assert_array_equal(direct.ground_truth, source.ground_truth)
    # without a poses file: no ground truth
    (root / "poses" / "00.txt").unlink()
    assert KittiSource(root, "00").ground_truth is None


def test_kitti_missing_and_empty_folders(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere"
    with pytest.raises(SourceError, match="not found") as exc:
        KittiSource(missing, "00")
    assert_names(exc, missing)
    root = make_kitti(tmp_path / "root")
    with pytest.raises(SourceError, match="sequence 07 not found") as exc:
        KittiSource(root, "7")
    assert_names(exc, root / "sequences" / "07")
    with pytest.raises(SourceError, match="which sequence"):
        KittiSource(root)
    with pytest.raises(SourceError, match="not a KITTI sequence folder"):
        KittiSource(root / "poses")
    image_0 = root / "sequences" / "00" / "image_0"
    for file in image_0.iterdir():
        file.unlink()
    with pytest.raises(SourceError, match="no images") as exc:
        KittiSource(root, "00")
    assert_names(exc, image_0)
    image_0.rmdir()
    with pytest.raises(SourceError) as exc:
        KittiSource(root / "sequences" / "00")
    assert "image_0" in str(exc.value)


def test_corrupt_image_raises_when_met(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4)
    corrupt = root / "sequences" / "00" / "image_0" / "000002.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    source = KittiSource(root, "00")  # lazily decoded: opening does not read frame 2
    seen = []
    with pytest.raises(SourceError, match="cannot read image") as exc:
        for frame in source:
            seen.append(frame.index)
    assert seen == [0, 1]
    assert_names(exc, corrupt)
    with pytest.raises(SourceError) as exc:
        KittiSource(root, "00", frames=FrameRange(2, 4))  # the first selected frame is read at once
    assert_names(exc, corrupt)


def test_image_of_another_size_raises_when_met(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4)
    odd = root / "sequences" / "00" / "image_0" / "000003.png"
    cv2.imwrite(str(odd), noise_image(3, width=32, height=48))
    source = KittiSource(root, "00")
    with pytest.raises(SourceError, match="32x48, the first frame is 64x48") as exc:
        list(source)
    assert_names(exc, odd)
    folder = ImageFolderSource(root / "sequences/00/image_0", intrinsics=partial_00())
    with pytest.raises(SourceError) as exc:
        list(folder)
    assert_names(exc, odd)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("P1: 1 0 0 0 0 1 0 0 0 0 1 0\n", "no 'P0:' line"),
        ("P0: 718.8 0 607 0 0 718.8 185 zero 0 0 1 0\n", "not a number"),
        ("P0: 718.8 0 607 0 0 718.8 185 0\n", "12 numbers"),
        ("", "no 'P0:' line"),
    ],
)
def test_bad_calib(tmp_path: Path, content: str, message: str) -> None:
    root = make_kitti(tmp_path)
    calib = root / "sequences" / "00" / "calib.txt"
    calib.write_text(content)
    with pytest.raises(SourceError, match=message) as exc:
        KittiSource(root, "00")
    assert_names(exc, calib)
    with pytest.raises(SourceError, match=message) as exc:
        read_p0_intrinsics(calib)
    assert_names(exc, calib)


def test_missing_calib(tmp_path: Path) -> None:
    root = make_kitti(tmp_path)
    calib = root / "sequences" / "00" / "calib.txt"
    calib.unlink()
    with pytest.raises(SourceError, match="not found") as exc:
        KittiSource(root, "00")
    assert_names(exc, calib)


def test_poses_with_fewer_rows_than_images(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4, poses_rows=3)
    with pytest.raises(SourceError, match="3 poses for 4 frames") as exc:
        KittiSource(root, "00", frames=FrameRange(0, 2))  # even if the selection needs fewer
    assert_names(exc, root / "poses" / "00.txt")


@pytest.mark.parametrize(
    "content",
    ["1 0 0 0 0 1 0 0 0 0 1\n", "1 0 0 0 0 1 0 0 0 0 1 x\n", "2 0 0 0 0 1 0 0 0 0 1 0\n"],
    ids=["11-columns", "not-a-number", "not-a-rotation"],
)
def test_malformed_poses(tmp_path: Path, content: str) -> None:
    root = make_kitti(tmp_path)
    poses = root / "poses" / "00.txt"
    poses.write_text(content * 4)
    with pytest.raises(TrajectoryFormatError) as exc:
        KittiSource(root, "00")
    assert isinstance(exc.value, VslamError)
    assert_names(exc, poses)


def test_the_first_pose_that_is_no_rotation_is_named_by_its_line(tmp_path: Path) -> None:
    good, mirrored = "1 0 0 0 0 1 0 0 0 0 1 0\n", "1 0 0 0 0 1 0 0 0 0 -1 0\n"  # det -1: a reflection
    path = tmp_path / "poses.txt"
    path.write_text("# comment\n" + good + good + mirrored + good + "2 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(TrajectoryFormatError, match=r"poses\.txt:4: not a rotation matrix"):
        read_kitti_poses(path)
    assert len(read_kitti_poses(path, max_rows=2)) == 2  # the rows before it are fine


def test_bad_times(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4)
    times = root / "sequences" / "00" / "times.txt"
    times.write_text("0.0\n0.1\n")
    with pytest.raises(SourceError, match="2 timestamps for 4 images") as exc:
        KittiSource(root, "00")
    assert_names(exc, times)
    times.write_text("0.0\n0.1\nabc\n0.3\n")
    with pytest.raises(SourceError, match="not a number") as exc:
        KittiSource(root, "00")
    assert_names(exc, times)


def test_frame_range_end_is_clamped_start_past_the_end_is_an_error(tmp_path: Path) -> None:
    root = make_kitti(tmp_path, n=4)
    assert KittiSource(root, "00", frames=FrameRange(2, 10)).indices == [2, 3]  # like a Python slice
    with pytest.raises(SourceError, match="selects no frame, the source has 4 frames") as exc:
        KittiSource(root, "00", frames=FrameRange(4, 10))
    assert_names(exc, root / "sequences" / "00")
    with pytest.raises(SourceError, match="selects no frame"):
        KittiSource(root, "00", frames=FrameRange(2, 2))


# --------------------------------------------------------------------------------------------------
# image folders (synthetic)


def test_image_folder_basics_and_errors(tmp_path: Path) -> None:
    missing = tmp_path / "missing"
    with pytest.raises(SourceError, match="not found") as exc:
        ImageFolderSource(missing, intrinsics=partial_00())
    assert_names(exc, missing)
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    with pytest.raises(SourceError, match="no images") as exc:
        ImageFolderSource(empty, intrinsics=partial_00())
    assert_names(exc, empty)

    folder = tmp_path / "mixed"
    folder.mkdir()
    cv2.imwrite(str(folder / "b.jpg"), cv2.cvtColor(noise_image(1), cv2.COLOR_GRAY2BGR))
    cv2.imwrite(str(folder / "a.png"), noise_image(0))
    cv2.imwrite(str(folder / "c.BMP"), noise_image(2))
    (folder / "readme.md").write_text("ignored")
    source = ImageFolderSource(folder, intrinsics=CameraIntrinsics(50, 50, 32, 24, 0, 0))
    assert [p.name for p in source.files] == ["a.png", "b.jpg", "c.BMP"]
    assert source.intrinsics == CameraIntrinsics(50, 50, 32, 24, 64, 48)  # 0x0 filled from the image
    frames = list(source)
    np.testing.assert_array_equal(frames[0].image, noise_image(0))
    np.testing.assert_array_equal(frames[2].image, noise_image(2))
    assert frames[1].image.shape == (48, 64) and frames[1].image.dtype == np.uint8

    with pytest.raises(SourceError, match="intrinsics are for 100x100"):
        ImageFolderSource(folder, intrinsics=CameraIntrinsics(50, 50, 32, 24, 100, 100))
    with pytest.raises(SourceError, match="no camera intrinsics"):
        ImageFolderSource(folder)
    calib = tmp_path / "calib.txt"  # beside the folder: found automatically
    calib.write_text(FAKE_P0)
    assert ImageFolderSource(folder).intrinsics == CameraIntrinsics(100, 110, 32, 24, 64, 48)
    with pytest.raises(SourceError, match="not both"):
        ImageFolderSource(folder, intrinsics=partial_00(), calib=calib)
    bad_calib = tmp_path / "bad_calib.txt"
    bad_calib.write_text("K: 1 2 3\n")
    with pytest.raises(SourceError, match="K needs 9 numbers") as exc:
        ImageFolderSource(folder, calib=bad_calib)
    assert_names(exc, bad_calib)
    malformed = tmp_path / "gt.txt"
    malformed.write_text("1 2 3\n")
    with pytest.raises(TrajectoryFormatError) as format_exc:
        ImageFolderSource(folder, intrinsics=partial_00(), ground_truth=malformed)
    assert_names(format_exc, malformed)


@pytest.mark.parametrize("text", ["", "1,2,3", "1,2,3,4,5", "a,b,c,d", "0,1,2,3", "1,-1,2,3", "nan,1,2,3"])
def test_parse_intrinsics_rejects(text: str) -> None:
    with pytest.raises(SourceError, match="--intrinsics"):
        parse_intrinsics(text)


def test_parse_intrinsics_and_complete() -> None:
    partial = parse_intrinsics("718.856,718.856,607.1928,185.2157")
    assert partial.complete(1241, 376) == CameraIntrinsics(**KITTI_00)  # type: ignore[arg-type]
    np.testing.assert_allclose(partial.complete(1241, 376).K[0], [718.856, 0.0, 607.1928])
