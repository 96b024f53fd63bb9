"""`vslam crop` of a video recording: the cut GOP re-encoded so the first kept frame is a key frame.

A `VideoStream` sample decodes only after the key frame that starts its GOP. A crop starting at frame START
inside a GOP would leave samples the viewer cannot decode, so the samples from the previous key frame
through the GOP are decoded, and the frames START … (next key frame or END) − 1 are re-encoded as a new GOP
(same codec and settings as `--image-codec`); `swap_samples` puts them in place of the originals.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from rerun.chunk import RrdReader, StoreEntry

from vslam.recording import RERUN_CODEC, VIDEO_SETTINGS, ImageCodec, open_encoder
from vslam.rrd.read import RecordingError

FRAME = "frame"
SAMPLE = "VideoStream:sample"
KEYFRAME = "VideoStream:is_keyframe"
CODEC = "VideoStream:codec"
DECODERS = {ImageCodec.AV1: ("libdav1d", "av1"), ImageCodec.H264: ("h264",)}

Swaps = dict[int, tuple[bytes, bool]]  # frame -> (sample, is key frame)


def video_codecs(reader: RrdReader, store: StoreEntry) -> dict[str, ImageCodec]:
    """The recording's `VideoStream` entities and their codecs (from the static `codec` component)."""
    by_value = {rerun.value: codec for codec, rerun in RERUN_CODEC.items()}
    found: dict[str, ImageCodec] = {}
    for chunk in reader.stream(store=store).filter(is_static=True).to_chunks():
        batch = chunk.to_record_batch()
        if CODEC in batch.schema.names:
            values = pc.list_flatten(batch.column(CODEC)).to_pylist()
            if values and values[-1] in by_value:
                found[chunk.entity_path] = by_value[values[-1]]
    return found


def _row_bytes(column: pa.Array, row: int) -> bytes:
    blobs = column[row].values  # the row's list of blobs
    return bytes(blobs[0].values.to_numpy(zero_copy_only=False).tobytes()) if len(blobs) else b""


def reencoded_first_gops(reader: RrdReader, store: StoreEntry, start: int, end: int) -> dict[str, Swaps]:
    """Per video entity whose first sample at or after `start` is not a key frame: the re-encoded samples
    of the frames from there up to the next key frame (or `end`)."""
    result: dict[str, Swaps] = {}
    for entity, codec in video_codecs(reader, store).items():
        rows: list[tuple[int, bytes, bool]] = []
        for chunk in reader.stream(store=store).filter(content=entity, is_static=False).to_chunks():
            batch = chunk.to_record_batch()
            if FRAME not in batch.schema.names or SAMPLE not in batch.schema.names:
                continue
            frames = batch.column(FRAME).to_pylist()
            keys: list[Any] = (batch.column(KEYFRAME).to_pylist() if KEYFRAME in batch.schema.names
                               else [None] * len(frames))
            sample_column = batch.column(SAMPLE)
            for i, frame in enumerate(frames):
                rows.append((frame, _row_bytes(sample_column, i), bool(keys[i] and keys[i][0])))
        rows.sort(key=lambda r: r[0])
        inside = [i for i, (frame, _, _) in enumerate(rows) if start <= frame < end]
        if not inside or rows[inside[0]][2]:
            continue
        first = inside[0]
        key = max((i for i in range(first) if rows[i][2]), default=None)
        if key is None:
            raise RecordingError(f"{entity}: no video key frame before frame {rows[first][0]}: cannot crop there")
        stop = next((i for i in inside if rows[i][2]), inside[-1] + 1)
        pictures = _decode(codec, [sample for _, sample, _ in rows[key:stop]])
        if len(pictures) != stop - key:
            raise RecordingError(f"{entity}: decoded {len(pictures)} of {stop - key} video frames: cannot crop")
        encoded = _encode(codec, pictures[first - key:])
        if len(encoded) != stop - first:
            raise RecordingError(f"{entity}: re-encoding gave {len(encoded)} of {stop - first} frames")
        result[entity] = {rows[i][0]: packet for i, packet in zip(range(first, stop), encoded, strict=True)}
    return result


def _decode(codec: ImageCodec, blobs: list[bytes]) -> list[np.ndarray]:
    import av

    name = next(d for d in DECODERS[codec] if d in av.codecs_available)
    decoder: Any = av.CodecContext.create(name, "r")
    pictures = []
    for blob in blobs:
        pictures += [f.to_ndarray(format="yuv420p") for f in decoder.decode(av.Packet(blob))]
    pictures += [f.to_ndarray(format="yuv420p") for f in decoder.decode(None)]
    return pictures


def _encode(codec: ImageCodec, pictures: list[np.ndarray]) -> list[tuple[bytes, bool]]:
    import av

    height, width = pictures[0].shape[0] * 2 // 3, pictures[0].shape[1]
    encoder = open_encoder(VIDEO_SETTINGS[codec], width, height, gop=len(pictures) + 1)
    packets = []
    for pts, picture in enumerate(pictures):
        frame = av.VideoFrame.from_ndarray(picture, format="yuv420p")
        frame.pts = pts
        frame.color_range = 2
        packets += encoder.encode(frame)
    packets += encoder.encode(None)
    return [(bytes(p), bool(p.is_keyframe)) for p in packets]


def swap_samples(rows: pa.RecordBatch, swaps: Swaps) -> pa.RecordBatch:
    """`rows` with the samples (and key frame flags) of the frames in `swaps` replaced."""
    frames = rows.column(FRAME).to_pylist()
    sample_column = rows.column(SAMPLE)
    blobs = [swaps[f][0] if f in swaps else _row_bytes(sample_column, i) for i, f in enumerate(frames)]
    index = rows.schema.get_field_index(SAMPLE)
    field = rows.schema.field(index)
    values = pa.array(np.frombuffer(b"".join(blobs), np.uint8))
    offsets = pa.array(np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).astype(np.int32))
    inner = pa.ListArray.from_arrays(offsets, values)
    outer = pa.ListArray.from_arrays(pa.array(np.arange(len(blobs) + 1, dtype=np.int32)), inner)
    rows = rows.set_column(index, field, outer.cast(field.type))
    if KEYFRAME in rows.schema.names:
        index = rows.schema.get_field_index(KEYFRAME)
        field = rows.schema.field(index)
        old = rows.column(KEYFRAME).to_pylist()
        keys = [[swaps[f][1]] if f in swaps else old[i] for i, f in enumerate(frames)]
        rows = rows.set_column(index, field, pa.array(keys, type=field.type))
    return rows
