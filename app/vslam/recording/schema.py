"""The recording schema as data: what a vslam recording holds, what is required, and which command reads what.

`docs/recording-schema.md` is its prose form; `vslam check` (`vslam.rrd.check`) validates any recording against
it; the `Recorder`, `record_external` and the logging API (`vslam.log`) write it and state its version in the run
properties (``schema_version``).

Versions: 1 = the first documented schema (the drift trajectory's and ground-truth links' hover component is
``frame_index``, never ``frame``: no component may share a timeline's name); 2 = the engine config
(``/__properties/config``) as two components, ``key`` and ``value`` (JSON), instead of one per key
(`vslam.common.config_columns`; readers take both).
"""

from __future__ import annotations

from dataclasses import dataclass

#: The schema these recordings follow (run property ``schema_version``).
SCHEMA_VERSION = 2

#: The timelines: ``frame`` (the source's frame index, a sequence) is required, ``time`` (seconds: a duration
#: since the start, or a date and time for Unix stamps) optional.
FRAME_TIMELINE = "frame"
TIME_TIMELINE = "time"
TIMELINES = (FRAME_TIMELINE, TIME_TIMELINE)

#: Who reads what (the names `vslam check` prints after a problem).
INSPECT = "inspect"
COMPARE = "compare"
CROP = "crop"
REPAIR = "repair"
SNAPSHOT = "snapshot"
OPEN = "open"
VIEWER = (OPEN, SNAPSHOT)
EVERY_COMMAND = (INSPECT, COMPARE, CROP, REPAIR, SNAPSHOT, OPEN)

#: Health levels of ``/health:status`` (and ``/metrics/health/status``: 0, 1, 2).
HEALTH_STATUSES = ("ok", "warn", "fail")


@dataclass(frozen=True)
class EntitySpec:
    """One entity of the schema. `components`: the columns it must have when present (``Archetype:component``,
    or a bare name for `AnyValues`); `static`: logged once (True) or per frame on ``frame`` (False); `readers`:
    the commands that read it (a problem with it affects them)."""

    path: str
    components: tuple[str, ...]
    static: bool
    required: bool
    readers: tuple[str, ...]
    what: str


def _series(group: str, names: tuple[str, ...], readers: tuple[str, ...], what: str) -> list[EntitySpec]:
    return [EntitySpec(f"/metrics/{group}/{name}", ("Scalars:scalars",), False, False, readers, what) for name in names]


ENTITIES: tuple[EntitySpec, ...] = (
    # and a rotation: Transform3D:mat3x3 (vslam writes it), :quaternion or :rotation_axis_angle
    EntitySpec("/world/camera", ("Transform3D:translation",), False, True, EVERY_COMMAND,
               "T_world_cam per frame (world = camera frame of the first frame, RDF, metres)"),
    EntitySpec("/world", ("ViewCoordinates:xyz",), True, False, VIEWER, "the world's axes: RDF"),
    EntitySpec("/world/camera/image", ("Pinhole:image_from_camera", "Pinhole:resolution"), True, False, VIEWER,
               "the camera's pinhole K (ideal intrinsics, pixels)"),
    EntitySpec("/world/trajectory/estimate", ("LineStrips3D:strips",), False, False, VIEWER,
               "one segment per frame: previous → current camera position"),
    EntitySpec("/world/trajectory/ground_truth", ("LineStrips3D:strips",), False, False, (INSPECT, COMPARE, *VIEWER),
               "one segment per frame of the ground truth (same world)"),
    EntitySpec("/world/trajectory/estimate_sim3", ("LineStrips3D:strips",), True, False, (INSPECT, COMPARE),
               "scale none: the whole estimate after Sim(3) alignment (errors are then of it)"),
    EntitySpec("/world/trajectory/estimate_refined", ("LineStrips3D:strips",), True, False, (INSPECT,),
               "map backend: the refined path the run is scored on (its error series are then of it)"),
    EntitySpec("/world/camera/image/corners", ("Points2D:positions",), False, False, VIEWER,
               "corners detected in this frame (raw image pixels)"),
    EntitySpec("/world/camera/image/flow", ("Arrows2D:origins", "Arrows2D:vectors", "Arrows2D:class_ids"), False,
               False, VIEWER, "one arrow per track, previous → current pixel, class = fate (5 inlier)"),
    # `reasons` may be absent: the Rerun SDK's `AnyValues` drops an empty string, so a run whose every frame has
    # no reason (reasons="") is written without the component; readers take it as "" everywhere
    EntitySpec("/health", ("status",), False, False, (INSPECT, COMPARE),
               "per frame: status ok|warn|fail and comma-separated reason codes"),
    EntitySpec("/events", ("TextLog:text", "TextLog:level"), False, False, VIEWER,
               "text log: one row a frame, an instance per event"),
    EntitySpec("/events/at_end", ("TextLog:text", "TextLog:level"), False, False, VIEWER,
               "text log of what is known when the run ends (drift ranking, last loop searches), at its frames"),
    EntitySpec("/report", ("TextDocument:text",), True, False, (INSPECT, COMPARE),
               "Markdown verdict; its metrics table (t_err, r_err, ATE) is read back"),
    EntitySpec("/overview/path", ("LineStrips2D:strips",), True, False, VIEWER,
               "the whole drive from above when the run ends, coloured by each frame's error or health"),
    EntitySpec("/overview/summary", ("TextDocument:text",), True, False, VIEWER,
               "a short Markdown summary: the run, its figures, the worst stretches"),
    EntitySpec("/world/trajectory/drift", ("LineStrips3D:strips", "frame_index"), False, False, VIEWER,
               "the estimate coloured by each frame's own error (ground truth), one segment per frame"),
    EntitySpec("/world/trajectory/gt_links", ("LineStrips3D:strips", "frame_index"), True, False, VIEWER,
               "estimate → ground-truth lines every 10 frames"),
    # only `mode` expected: map recordings written before `pnp_failure` existed stay valid
    EntitySpec("/tracking", ("mode",), False, False, VIEWER,
               "map backend, per frame: where the pose came from (mode) and why tracking against the map gave none "
               "(pnp_failure: too_few_in_view, too_few_matched, ransac, disagrees; \"\" when it gave one)"),
    *_series("health", ("status",), (INSPECT, COMPARE, *VIEWER), "health as 0 ok, 1 warn, 2 fail"),
    *_series("tracks", ("alive", "new_corners", "fb_rejected", "road_points"), (INSPECT, COMPARE, *VIEWER),
             "track counts"),
    *_series("ransac", ("inliers", "chirality_margin"), (INSPECT, COMPARE, *VIEWER), "RANSAC"),
    *_series("ratio", ("inlier_ratio",), (INSPECT, COMPARE, *VIEWER), "inlier ratio"),
    *_series("motion", ("rotation_deg", "scale"), VIEWER, "this frame's motion"),
    *_series("error", ("position_m",), (INSPECT, COMPARE, *VIEWER), "position error against the ground truth (m)"),
    *_series("angle_error", ("heading_deg", "translation_direction_deg"), (INSPECT, COMPARE, *VIEWER),
             "angle errors against the ground truth (°)"),
    *_series("gt_check", ("gt_sampson_px", "fit_sampson_px", "sampson_ratio", "gt_rotation_deg"),
             (INSPECT, COMPARE, *VIEWER), "the ground truth's relative motion against the frame's inliers"),
    *_series("drift", ("rotation_deg", "translation_m", "translation_pct", "scale_ratio"),
             (INSPECT, COMPARE, *VIEWER), "drift attribution: each frame's own step error"),
    *_series("timing_ms", ("decode", "track", "essential", "chirality", "detect", "record"),
             (INSPECT, COMPARE, *VIEWER), "time per stage (ms)"),
    *_series("accelerometer", ("x", "y", "z"), VIEWER,
             "the source's accelerometer: gravity in the camera frame (m/s², x right, y down, z forward)"),
)

#: Run properties (static, ``/__properties/run``, all strings): required keys, then optional ones.
PROPERTIES_ENTITY = "/__properties/run"
REQUIRED_PROPERTIES: dict[str, tuple[str, ...]] = {
    "schema_version": EVERY_COMMAND,
    "name": (INSPECT, COMPARE, CROP),
    "source": (INSPECT, COMPARE),
    "frames": (INSPECT, COMPARE, CROP),
    "frame_count": (INSPECT, COMPARE, CROP),
}
OPTIONAL_PROPERTIES = ("recording_id", "source_path", "scale", "backend", "detail", "pipeline", "inject", "stopped",
                       "cropped_from", "vslam_version", "opencv_version", "rerun_version", "calibration_model",
                       "calibration_K", "calibration_coefficients", "calibration_size", "calibration_origin")


def spec(path: str) -> EntitySpec | None:
    """The schema's entry for an entity path, or None."""
    return next((entity for entity in ENTITIES if entity.path == path), None)
