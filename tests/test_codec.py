"""`--image-codec av1|h264`: the camera frames as a Rerun `VideoStream` that verifies, decodes, snapshots with
the frame visible, and survives `crop` mid-GOP (the cut GOP re-encoded from a key frame)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_helpers import VO, need_vulkan, vslam
from PIL import Image
from rerun.chunk import RrdReader

from vslam.recording.video import GOP_FRAMES, INLINE_RESIZE_PIXELS, ImageCodec, resize_area
from vslam.rrd.crop import crop_recording
from vslam.rrd.crop_video import _decode
from vslam.rrd.read import rerun_binary
from vslam.viewer.headless import snapshot
from vslam.viewer.processes import ViewerError

ROOT = Path(__file__).resolve().parents[1]
IMAGE = "/world/camera/image"
FRAMES = 35  # up to the end of CROP: every AV1-encoded frame costs (the fixture was 26 s of 52)
CROP = (25, 35)  # starts mid-GOP: key frames at 0, 20


def _run(path: Path, codec: str, frames: int = FRAMES) -> Path:
    done = vslam("run", *VO, "--frames", f"0:{frames}", "--image-codec", codec, "-o", path, env={"RERUN_STRICT": "1"})
    assert done.returncode == 0, done.stderr
    return path


@pytest.fixture(scope="module")
def av1(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _run(tmp_path_factory.mktemp("codec") / "av1.rrd", "av1")


@pytest.fixture(scope="module")
def cropped(av1: Path) -> Path:
    out = av1.parent / "cropped.rrd"
    crop_recording(av1, CROP, out)
    return out


def samples(path: Path) -> tuple[list[int], list[bytes], list[bool]]:
    frames, blobs, keys = [], [], []
    for chunk in RrdReader(path).stream().filter(content=IMAGE, is_static=False).to_chunks():
        batch = chunk.to_record_batch()
        if "VideoStream:sample" not in batch.schema.names:
            continue
        frames += batch.column("frame").to_pylist()
        blobs += [bytes(row[0]) for row in batch.column("VideoStream:sample").to_pylist()]
        keys += [row[0] for row in batch.column("VideoStream:is_keyframe").to_pylist()]
    order = np.argsort(frames)
    return [frames[i] for i in order], [blobs[i] for i in order], [keys[i] for i in order]


def verify(path: Path) -> None:
    done = subprocess.run([rerun_binary(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout


def test_av1_recording_verifies_one_sample_per_frame_key_frames_every_gop(av1: Path) -> None:
    verify(av1)
    frames, blobs, keys = samples(av1)
    assert frames == list(range(FRAMES))
    assert [i for i, key in enumerate(keys) if key] == list(range(0, FRAMES, GOP_FRAMES))
    pictures = _decode(ImageCodec.AV1, blobs)
    assert len(pictures) == FRAMES
    assert float(np.std(pictures[-1])) > 10  # a picture, not a flat frame


def test_crop_mid_gop_starts_with_a_reencoded_key_frame(av1: Path, cropped: Path) -> None:
    verify(cropped)
    frames, blobs, keys = samples(cropped)
    assert frames == list(range(*CROP))
    assert keys[0], "the first kept sample must be a key frame"
    assert len(_decode(ImageCodec.AV1, blobs)) == len(frames)  # decodes from the first sample on


def test_crop_reencodes_only_up_to_the_next_key_frame(av1: Path, tmp_path: Path) -> None:
    out = tmp_path / "across.rrd"
    crop_recording(av1, (15, 25), out)
    frames, blobs, keys = samples(out)
    _, original, _ = samples(av1)
    assert frames == list(range(15, 25))
    assert keys[0] and keys[5]  # frame 15 (re-encoded) and 20 (the original key frame)
    assert blobs[5:] == original[20:25]  # from the next key frame on, the samples are the originals
    assert len(_decode(ImageCodec.AV1, blobs)) == 10


def _visible(picture: Path) -> float:
    """Spread of grey levels in the middle of the frame view (a blank or undecoded view is flat)."""
    pixels = np.asarray(Image.open(picture).convert("L"), np.float64)
    h, w = pixels.shape
    return float(np.std(pixels[h // 4: 3 * h // 4, w // 4: 3 * w // 4]))


@pytest.mark.parametrize("which", ["whole", "cropped"])
def test_snapshot_shows_the_video_frame(which: str, av1: Path, cropped: Path, tmp_path: Path) -> None:
    need_vulkan()
    path, frame = (av1, 30) if which == "whole" else (cropped, CROP[0])
    # the smallest window the viewer takes (vslam.viewer.headless.MIN_SIZE): only the frame view is checked
    shots = {p.stem: p for p in snapshot(path, frame, tmp_path, timeout_s=180, window_size=(320, 240),
                                         only=("frame",))}
    assert _visible(shots["frame"]) > 15, f"the frame view of {path.name} at frame {frame} looks blank"


def test_h264_snapshot_without_ffmpeg_names_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    h264 = _run(tmp_path / "h264.rrd", "h264", frames=10)  # frame 5 is in it
    verify(h264)
    monkeypatch.setattr("shutil.which", lambda _name: None)
    with pytest.raises(ViewerError, match="ffmpeg") as caught:
        snapshot(h264, 5, tmp_path / "out")
    assert "\n" not in str(caught.value)


def test_eval_report_recordings_take_the_codec(tmp_path: Path) -> None:
    report = tmp_path / "report"
    done = vslam("eval", "synthetic", "--frames", "0:25", "--image-codec", "h264", "--report", report)
    assert done.returncode == 0, done.stderr
    (recording,) = report.glob("*.rrd")
    frames, blobs, keys = samples(recording)
    assert frames == list(range(25)) and keys == [i % GOP_FRAMES == 0 for i in range(25)]
    assert blobs[0].startswith(b"\0\0\0\1")  # Annex B: H.264, not AV1's OBUs


def test_the_half_size_resize_runs_in_bands_and_equals_opencvs_bit_for_bit(kitti_root: Path, tum_root: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """`resize_area` keeps OpenCV's thread pool out of the recording (its threads spin on the engine's cores):
    bands of a whole-factor shrink average the same source rows as one `cv2.resize`; other sizes are one call."""
    def grey(sequence: str) -> np.ndarray:
        return cv2.imread(str(kitti_root / "sequences" / sequence / "image_0" / "000010.png"), cv2.IMREAD_UNCHANGED)

    colour = cv2.imread(str(sorted((tum_root / "rgbd_dataset_freiburg1_desk" / "rgb").glob("*.png"))[0]))
    # KITTI 05 halves exactly, 00 (1241 wide) by a width factor that is not whole, TUM in colour; then two
    # shrinks whose height factor is not whole (one call)
    cases = [(grey("05"), (613, 185)), (grey("00"), (620, 188)), (colour, (320, 240)),
             (grey("05")[:369], (613, 185)), (colour, (427, 320))]
    resize, outputs = cv2.resize, []

    def spy(image: np.ndarray, size: tuple[int, int], **kwargs: object) -> np.ndarray:
        outputs.append(size[0] * size[1])
        return resize(image, size, **kwargs)

    for index, (image, size) in enumerate(cases):
        assert size[0] * size[1] > INLINE_RESIZE_PIXELS  # one call would go to the pool
        expected = resize(image, size, interpolation=cv2.INTER_AREA)
        outputs.clear()
        with monkeypatch.context() as patch:
            patch.setattr(cv2, "resize", spy)
            np.testing.assert_array_equal(resize_area(image, size), expected)
        whole_factor = index < 3
        assert (max(outputs) < INLINE_RESIZE_PIXELS) == whole_factor and (len(outputs) > 1) == whole_factor
