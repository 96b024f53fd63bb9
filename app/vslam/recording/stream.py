"""One recording stream to a `.rrd` file: opened, given the world every run recording shares, flushed
without hanging, and closed. Used by the `Recorder` (a vslam run) and `record_external` (another system's
trajectory), so both files have the same frames, styles and guarantees."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import rerun as rr
import rerun.blueprint as rrb

import vslam_core
from vslam.common import OutputError, hold_stuck_writer, likely_errno, write_failure
from vslam.recording.layout import CAR_ENTITY
from vslam.recording.levels import scaled_size
from vslam.recording.styles import APPLICATION_ID, CAR_COLOUR, ESTIMATE_COLOUR, GROUND_TRUTH_COLOUR
from vslam_core.sources.base import CameraIntrinsics

#: How long to wait for Rerun's writer thread to catch up before calling the file unwritable (a slow disk)…
WRITE_TIMEOUT_S = 120.0
#: … asking this often whether it has caught up, and giving up at once when the disk is full.
FLUSH_STEP_S = 0.25


def open_stream(path: Path, recording_id: str | None, layout: rrb.Blueprint, name: str,
                live_url: str | None = None) -> rr.RecordingStream:
    """A stream writing to `path` with the default blueprint `layout` and the recording's `name`; with
    `live_url` (``rerun+http://…/proxy``, `vslam.viewer.live`) also streaming to that viewer (a second sink).

    Reproducible: no wall-clock start time (``send_properties=False``) and no log-time column, so two runs
    of the same input compare equal. Fewer, larger chunks than Rerun's default (0.2 s / 2 MiB): each chunk
    carries its own schema, and at ~3 frames a chunk the schemas alone were ~16 KB per frame."""
    batcher = rr.ChunkBatcherConfig(flush_tick=1.0, flush_num_bytes=8 * 2**20)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id, send_properties=False,
                             batcher_config=batcher)
    rec.set_log_time_enabled(False)
    if live_url is None:
        rec.save(path, default_blueprint=layout)
    else:
        rec.set_sinks(rr.FileSink(path), rr.GrpcSink(live_url), default_blueprint=layout)
    rec.send_recording_name(name)
    return rec


def log_world(rec: rr.RecordingStream, camera: CameraIntrinsics | None, image_scale: float = 1.0) -> None:
    """What every run recording declares once: the world's axes (RDF: x right, y down, z forward, the camera
    frame of the first frame), the pinhole of ``/world/camera/image`` when the camera is known, the car
    around the camera that the 3-D view follows, and the styles of the two trajectories. `image_scale`: the
    size the frames are stored at, as a fraction of the source's (`IMAGE_SCALE`)."""
    rec.log("/world", rr.ViewCoordinates.RDF, static=True)
    if camera is not None:
        drawn: list[rr.AsComponents] = []
        if image_scale != 1.0:
            # drawn over the pinhole's whole image plane, smoothly; an instance pose is not passed on to the
            # overlays below the image: they stay in the source's pixels
            width, height = scaled_size(camera.width, camera.height, image_scale)
            drawn = [rr.InstancePoses3D(scales=[[camera.width / width, camera.height / height, 1.0]]),
                     rr.EncodedImage.from_fields(magnification_filter="Linear")]
        rec.log("/world/camera/image", pinhole(camera), *drawn, static=True)
    # metres, camera frame: 1.6 m wide, roof to road under a camera 1.65 m up, 0.5 m of bonnet ahead of it
    rec.log(CAR_ENTITY, rr.Boxes3D(centers=[[0.0, 0.75, -1.5]], half_sizes=[[0.8, 0.9, 2.0]], colors=[CAR_COLOUR],
                                 radii=[0.02]),  # thin edges: the car must not hide the lines around it
            static=True)
    rec.log("/world/trajectory/estimate", rr.LineStrips3D.from_fields(colors=ESTIMATE_COLOUR, radii=0.12), static=True)
    # wider than the estimate and drawn 0.2 m lower (+y in RDF; the viewer's lines are flat ribbons that flicker
    # into each other at one depth): where the two coincide, the ground truth is a blue band on either side of it
    rec.log("/world/trajectory/ground_truth", rr.Transform3D(translation=[0.0, 0.2, 0.0]),
            rr.LineStrips3D.from_fields(colors=GROUND_TRUTH_COLOUR, radii=0.2), static=True)


def pinhole(camera: CameraIntrinsics) -> rr.Pinhole:
    """The camera's pinhole (ideal intrinsics K), RDF, its image plane drawn 1 m ahead."""
    return rr.Pinhole(image_from_camera=camera.K, resolution=[camera.width, camera.height],
                      camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=1.0)


class StreamStopped(OutputError):
    """Rerun's writer stopped (full disk); `stuck`: a flush of it never returned (see `flush_or_stop`)."""

    def __init__(self, message: str, stuck: bool) -> None:
        super().__init__(message)
        self.stuck = stuck


def flush_or_stop(rec: rr.RecordingStream, path: Path) -> None:
    """Wait until Rerun's writer thread has written what was sent to `path`. That thread only logs its write
    errors (silenced in `vslam/__init__.py`) and stops; the flush then fails: `StreamStopped`.

    Rerun 0.41 has a race there: a flush queued just as the file sink's thread dies on ENOSPC is never
    answered, and the stream's forwarding thread waits for it forever (seen as a hung run on a full disk).
    So the flush is asked for in steps, a full disk ends the wait at once, and a stream whose flush timed
    out is `stuck`: `close_stream` must not disconnect it."""
    deadline = time.monotonic() + WRITE_TIMEOUT_S
    while True:
        started = time.monotonic()
        try:
            rec.flush(timeout_sec=FLUSH_STEP_S)
            return
        except RuntimeError:
            timed_out = time.monotonic() - started >= 0.9 * FLUSH_STEP_S
            if timed_out and time.monotonic() < deadline and likely_errno(path) is None:
                continue  # a slow disk: keep waiting
            raise StreamStopped(write_failure(path), stuck=timed_out) from None


def close_stream(rec: rr.RecordingStream, stuck: bool) -> None:
    """Disconnect `rec` (writing the footer), or hold it if `stuck`: disconnecting or dropping it would wait
    forever."""
    if stuck:
        hold_stuck_writer(rec)
    else:
        rec.disconnect()

def version_properties() -> dict[str, str]:
    """The versions a recording states: vslam's, OpenCV's and Rerun's."""
    return {"vslam_version": vslam_core.__version__, "opencv_version": cv2.__version__,
            "rerun_version": rr.__version__}
