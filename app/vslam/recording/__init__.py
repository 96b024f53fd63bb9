"""Turn the engine's per-frame results into Rerun entities (the only module that logs to Rerun).

Entity layout (world = camera frame of the first frame, RDF: x right, y down, z forward):

    /world                              ViewCoordinates.RDF (static)
    /world/camera                       Transform3D T_world_cam per frame
    /world/camera/image                 Pinhole (static) + JPEG frame
    /world/camera/car                   static wireframe box: the car, which the 3-D view follows
    /world/camera/image/corners         Points2D: corners detected in this frame (track id on hover)
    /world/camera/image/flow            Arrows2D: previous → current position per track, class = fate,
                                        track id and age on hover (the arrow tips are the tracked corners)
    /world/candidates                   the four (R, t) decompositions of E placed at the keyframe: a point
                                        and three axes each, chirality count and chosen flag on hover
    /world/points                       triangulated inliers of this frame (world coordinates)
    /world/road/points, /world/road/plane   --scale height: the road points the plane was fitted to, and
                                        an outline of that plane ahead of the camera (world coordinates)
    /world/camera/image/road            --scale height: those road points in the image
    /world/trajectory/estimate          one line segment per frame (O(1) per frame)
    /world/trajectory/ground_truth      same, from the source's ground truth
    /metrics/...                        per-frame scalars (tracks, RANSAC, motion, error, drift, timing_ms)
    /world/trajectory/{drift,gt_links}  with ground truth, static at the end: the estimate coloured by each
                                        frame's own error, estimate → truth lines (`vslam.recording.drift`)
    /events                             text log: initialisation, re-detections, held frames
    /health                             per frame: status ok / fail and reason codes (for `vslam inspect`)
    /report                             static Markdown written at the end: the run's metrics table

With --backend map also /tracking, /metrics/tracking/*, /metrics/ba/*, /world/map/** and the image's
landmarks and reprojection lines: see `vslam.recording.map_backend`. The odometry backend writes none of them.

Detail levels: full = all of it; standard (the default, `DEFAULT_DETAIL`) = no triangulated points and no
per-track hover data; summary = no image and no per-point data (camera pose, trajectories, series, events);
off = no file.

Every per-frame row is buffered and sent as columns every `FLUSH_SECONDS` (or `FLUSH_FRAMES`) and on close: one
`send_columns` per entity instead of one `log` per entity per frame, which cost ~80–200 µs of Python
each (~25 a frame). Styles that never change are logged once, static.

Modules: `recorder` (the `Recorder` and the front end's entities), `map` (the map backend's entities),
`columns` (the column buffer), `metrics` (the series), `drift` (each frame's own error against the ground
truth), `layout` (the default blueprint), `levels` (detail levels, image codecs), `styles` (colours, legends),
`external` (another system's trajectory file as a recording of the same entities, for `vslam eval --trajectory
--report`), `schema` (all of the above as data, versioned: docs/recording-schema.md, `vslam check`). Another
pipeline's frames are written by the same `Recorder` through the logging API, `vslam.log`.
"""

from typing import TYPE_CHECKING

from vslam_core.lazy import lazy_names

#: Where each name lives: imported on first use (PEP 562), so `from vslam.recording import Detail` in the CLI
#: does not load the recorder, its video encoder and the map entities.
_HOMES = {
    "blueprint": "layout",
    "FLUSH_BYTES": "columns", "FLUSH_FRAMES": "columns", "ColumnBuffer": "columns",
    "MapRecording": "map_backend",
    "HEALTH_LEVELS": "metrics", "MAP_METRICS": "metrics", "MAP_STAGES": "metrics", "METRICS": "metrics",
    "MODE_LEVELS": "metrics", "STAGES": "metrics", "frame_metrics": "metrics", "map_frame_metrics": "metrics",
    "Recorder": "recorder", "road_outline": "front_end", "version_properties": "stream",
    "APPLICATION_ID": "styles", "FATE_STYLE": "styles", "Detail": "levels", "ImageCodec": "levels",
    "JPEG_QUALITY": "levels", "HALF_SIZE_JPEG_QUALITY": "levels", "DEFAULT_DETAIL": "levels",
    "CAR_ENTITY": "layout", "EYE_OFFSET": "layout",
    "DRIFT_ENTITY": "drift", "LINKS_ENTITY": "drift", "WORST": "drift",
    "ExternalRun": "external", "RunFrames": "external", "record_external": "external",
    "RERUN_CODEC": "video", "VIDEO_SETTINGS": "video", "open_encoder": "video",
    "SCHEMA_VERSION": "schema", "EntitySpec": "schema", "ENTITIES": "schema", "EVERY_COMMAND": "schema",
    "FRAME_TIMELINE": "schema", "HEALTH_STATUSES": "schema", "REQUIRED_PROPERTIES": "schema", "TIMELINES": "schema",
}

if TYPE_CHECKING:
    from vslam.recording.columns import FLUSH_BYTES, FLUSH_FRAMES, ColumnBuffer
    from vslam.recording.drift import DRIFT_ENTITY, LINKS_ENTITY, WORST
    from vslam.recording.external import ExternalRun, RunFrames, record_external
    from vslam.recording.front_end import road_outline
    from vslam.recording.layout import CAR_ENTITY, EYE_OFFSET, blueprint
    from vslam.recording.levels import DEFAULT_DETAIL, HALF_SIZE_JPEG_QUALITY, JPEG_QUALITY, Detail, ImageCodec
    from vslam.recording.map_backend import MapRecording
    from vslam.recording.metrics import (
        HEALTH_LEVELS,
        MAP_METRICS,
        MAP_STAGES,
        METRICS,
        MODE_LEVELS,
        STAGES,
        frame_metrics,
        map_frame_metrics,
    )
    from vslam.recording.recorder import Recorder
    from vslam.recording.schema import (
        ENTITIES,
        EVERY_COMMAND,
        FRAME_TIMELINE,
        HEALTH_STATUSES,
        REQUIRED_PROPERTIES,
        SCHEMA_VERSION,
        TIMELINES,
        EntitySpec,
    )
    from vslam.recording.stream import version_properties
    from vslam.recording.styles import APPLICATION_ID, FATE_STYLE
    from vslam.recording.video import RERUN_CODEC, VIDEO_SETTINGS, open_encoder


__getattr__ = lazy_names(__name__, _HOMES)

__all__ = [
    "APPLICATION_ID",
    "CAR_ENTITY",
    "ColumnBuffer",
    "DEFAULT_DETAIL",
    "DRIFT_ENTITY",
    "Detail",
    "ENTITIES",
    "EVERY_COMMAND",
    "EYE_OFFSET",
    "EntitySpec",
    "ExternalRun",
    "FATE_STYLE",
    "FLUSH_BYTES",
    "FLUSH_FRAMES",
    "FRAME_TIMELINE",
    "HEALTH_LEVELS",
    "HEALTH_STATUSES",
    "HALF_SIZE_JPEG_QUALITY",
    "ImageCodec",
    "JPEG_QUALITY",
    "LINKS_ENTITY",
    "MAP_METRICS",
    "MAP_STAGES",
    "METRICS",
    "MODE_LEVELS",
    "MapRecording",
    "REQUIRED_PROPERTIES",
    "RERUN_CODEC",
    "Recorder",
    "RunFrames",
    "SCHEMA_VERSION",
    "STAGES",
    "TIMELINES",
    "VIDEO_SETTINGS",
    "WORST",
    "blueprint",
    "frame_metrics",
    "map_frame_metrics",
    "open_encoder",
    "record_external",
    "road_outline",
    "version_properties",
]
