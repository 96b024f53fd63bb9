"""`--image-codec`: size, encoding time and fidelity of the recorded camera frames per codec setting.

    python -m benchmarks.codecs ../shared/data/kitti --sequence 00 --frames 0:300 [--csv codecs.csv]

Per setting (JPEG q75 and the video settings offered), two measurements:
- the frames alone, in this process: encoding ms per frame (one thread, the frame conversion included),
  KB per frame of the images, and PSNR of the decoded frames (PyAV: libdav1d / h264; JPEG: OpenCV) against
  the source PNGs (the 1241-px width, not the padding);
- the full recording (`vslam run --detail full`, default threads, each in a fresh process one after the
  other): KB per frame of the whole `.rrd`, and wall-clock seconds of the run against the JPEG run (the
  encoder runs on the recorder's second thread, beside the engine).
"""

from __future__ import annotations

import argparse
import multiprocessing
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import polars as pl

from vslam.recording.video import VIDEO_SETTINGS, ImageCodec, VideoSettings, even, open_encoder, to_video_frame
from vslam_core.sources.base import FrameRange
from vslam_core.sources.kitti import KittiSource


def _svt(preset: str, crf: str, extra: str) -> VideoSettings:
    return VideoSettings("libsvtav1", {"preset": preset, "crf": crf,
                                       "svtav1-params": "pred-struct=1:lookahead=0" + extra})


def _x264(preset: str, crf: str) -> VideoSettings:
    return VideoSettings("libx264", {"preset": preset, "crf": crf, "tune": "zerolatency", "bf": "0"})


#: (label, codec, settings or JPEG quality): the settings measured. The first of each codec is the offered one.
SETTINGS: list[tuple[str, ImageCodec, VideoSettings | int]] = [
    ("jpeg q75", ImageCodec.JPEG, 75),
    ("av1 svt preset 13 crf 41 rtc lp 1 (offered)", ImageCodec.AV1, VIDEO_SETTINGS[ImageCodec.AV1]),
    ("av1 svt preset 13 crf 44 rtc lp 1", ImageCodec.AV1, _svt("13", "44", ":rtc=1:lp=1")),
    ("av1 svt preset 10 crf 41 rtc (offered until issue 56)", ImageCodec.AV1, _svt("10", "41", ":rtc=1")),
    ("av1 svt preset 10 crf 40 rtc", ImageCodec.AV1, _svt("10", "40", ":rtc=1")),
    ("av1 svt preset 10 crf 42 rtc", ImageCodec.AV1, _svt("10", "42", ":rtc=1")),
    ("av1 svt preset 8 crf 40 rtc", ImageCodec.AV1, _svt("8", "40", ":rtc=1")),
    ("h264 x264 faster crf 25 (offered)", ImageCodec.H264, VIDEO_SETTINGS[ImageCodec.H264]),
    ("h264 x264 veryfast crf 24", ImageCodec.H264, _x264("veryfast", "24")),
    ("h264 x264 veryfast crf 25", ImageCodec.H264, _x264("veryfast", "25")),
]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0**2 / mse) if mse > 0 else float("inf")


def frames_alone(images: list[np.ndarray], codec: ImageCodec, setting: VideoSettings | int) -> dict[str, float]:
    """Encoding ms per frame, KB per frame and mean PSNR of the images encoded on their own."""
    import av

    sizes, errors, start = [], [], time.perf_counter()
    if isinstance(setting, int):
        blobs = [cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, setting])[1].tobytes() for im in images]
        seconds = time.perf_counter() - start
        for image, blob in zip(images, blobs, strict=True):
            sizes.append(len(blob))
            errors.append(psnr(image, cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_GRAYSCALE)))
    else:
        height, width = images[0].shape
        encoder = open_encoder(setting, even(width), even(height))
        packets = []
        for pts, image in enumerate(images):
            packets += encoder.encode(to_video_frame(image, pts))
        packets += encoder.encode(None)
        seconds = time.perf_counter() - start
        decoder = av.CodecContext.create("libdav1d" if codec == ImageCodec.AV1 else "h264", "r")
        decoded = []
        for packet in packets:
            sizes.append(packet.size)
            decoded += decoder.decode(packet)
        decoded += decoder.decode(None)
        assert len(decoded) == len(images), (len(decoded), len(images))
        for image, frame in zip(images, decoded, strict=True):
            luma = frame.to_ndarray(format="gray")[:height, :width]  # full range: Y is the grey level
            errors.append(psnr(image, luma))
    return {"encode_ms": 1000.0 * seconds / len(images), "image_kb": float(np.mean(sizes)) / 1024.0,
            "psnr_db": float(np.mean(errors)), "psnr_min_db": float(np.min(errors))}


def _recording(args: tuple[str, str, str, str, VideoSettings | int]) -> dict[str, float]:
    """One full-detail run in a fresh process: KB per frame of the file and the run's wall-clock seconds."""
    from vslam.recording import Detail, Recorder, video
    from vslam_core.config import EngineConfig
    from vslam_core.pipeline import run_odometry

    root, sequence, frames, codec_name, setting = args
    codec = ImageCodec(codec_name)
    if isinstance(setting, VideoSettings):
        video.VIDEO_SETTINGS[codec] = setting
    source = KittiSource(root, sequence=sequence, frames=FrameRange.parse(frames))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.rrd"
        start = time.perf_counter()
        recorder = Recorder(path, source, EngineConfig(), {"name": "codecs"}, Detail.FULL,
                            setting if isinstance(setting, int) else 75, codec)
        run_odometry(source, EngineConfig(), sinks=(recorder.log_frame,))
        recorder.close()
        seconds = time.perf_counter() - start
        return {"file_kb": path.stat().st_size / 1024.0 / len(source), "run_s": seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root")
    parser.add_argument("--sequence", default="00")
    parser.add_argument("--frames", default="0:300")
    parser.add_argument("--csv", type=Path)
    args = parser.parse_args()
    source = KittiSource(args.root, sequence=args.sequence, frames=FrameRange.parse(args.frames))
    images = [frame.image for frame in source]
    rows = []
    context = multiprocessing.get_context("spawn")
    for label, codec, setting in SETTINGS:
        alone = frames_alone(images, codec, setting)
        with context.Pool(1) as pool:
            recorded = pool.apply(_recording, ((args.root, args.sequence, args.frames, codec.value, setting),))
        rows.append({"setting": label, **alone, **recorded})
        print(rows[-1], flush=True)
    table = pl.DataFrame(rows)
    jpeg_run = table["run_s"][0]
    table = table.with_columns((pl.col("run_s") / jpeg_run * 100.0 - 100.0).alias("run_vs_jpeg_pct"))
    with pl.Config(tbl_rows=-1, tbl_cols=-1, tbl_width_chars=200, float_precision=1):
        print(table)
    if args.csv is not None:
        table.write_csv(args.csv)


if __name__ == "__main__":
    main()
