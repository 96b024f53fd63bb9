"""Checks on what a user asked for that go beyond one value's type: ports, options that would be silently
ignored, implausible inputs (warnings) and a run that tracked nothing.

Each returns a one-line message (or None); the CLI prints it and picks the exit code.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

from vslam_core.config import EngineConfig
from vslam_core.config_file import range_problem
from vslam_core.errors import ConfigError
from vslam_core.results import STANDING_STILL
from vslam_core.scale import default_camera_height
from vslam_core.sources.base import FrameSource, source_notes
from vslam_core.sources.calibration import principal_point_problem, principal_point_warning

if TYPE_CHECKING:
    from vslam_core.pipeline import RunResult

#: exit code of a run in which no frame could be tracked (the recording and trajectory are still written)
EXIT_NOTHING_TRACKED = 3
#: a camera higher than this above the road is not on a car (warning only)
PLAUSIBLE_CAMERA_HEIGHT_M = 10.0
#: fields of view (degrees) beyond which a focal length is taken for a mistake (warning only): a pinhole model
#: past 150° is unusable (fisheye lenses have their own models), under 1° is a telescope
WIDEST_PINHOLE_DEG = 150.0
NARROWEST_DEG = 1.0
#: fx / fy beyond this (or under its inverse): pixels this far from square are a mistake (swapped values, one
#: axis resized), not a camera (warning only)
WIDEST_PIXEL_ASPECT = 1.5


def camera_height_problem(metres: float | None) -> str | None:
    """`--camera-height` against the range of `height.camera_height_m`."""
    if metres is None:
        return None
    problem = range_problem("height.camera_height_m", metres)
    return None if problem is None else f"--camera-height {metres:g}: {problem.partition(' is ')[2]}"


def with_camera_height(config: EngineConfig, metres: float | None, source: FrameSource,
                       option: str = "--camera-height", scale_option: str = "--scale height") -> EngineConfig:
    """`--camera-height` (a manifest's `camera_height` column: `option`, `scale_option`) into the config, checked
    before anything runs: its range, that it goes with scale height, and that scale height knows the camera's
    height. `ConfigError` in one line."""
    problem = camera_height_problem(metres)
    if problem is not None:
        raise ConfigError(problem.replace("--camera-height", option))
    if metres is not None:
        if config.scale != "height":
            raise ConfigError(f"{option} only applies with {scale_option}")
        config = config.with_camera_height(metres)
    if config.scale == "height":
        default_camera_height(source.camera_height, config)  # raises ConfigError naming --camera-height
    return config


def output_problem(output: Path | None, detail_off: bool) -> str | None:
    """`-o FILE` with `--detail off` would be dropped without a word."""
    if output is not None and detail_off:
        return f"--output {output}: --detail off writes no recording (drop one of the two)"
    return None


def same_file_problem(recording: Path | None, trajectory: Path | None) -> str | None:
    """`-o x.rrd --trajectory-out x.rrd`: one run cannot write two outputs into one file."""
    if recording is None or trajectory is None:
        return None
    if recording.resolve() == trajectory.resolve():
        return (f"--output {recording} and --trajectory-out {trajectory} are the same file: give the recording and "
                "the trajectory two paths")
    return None


def input_warnings(source: FrameSource, config: EngineConfig) -> list[str]:
    """Inputs that are valid but probably a mistake, and what the source noticed (e.g. a log's out-of-order
    stamps): one line each."""
    warnings = source_notes(source)
    k = source.intrinsics
    refused = principal_point_problem(k)  # open_source refuses it; a source made otherwise is warned about
    if (off_centre := refused or principal_point_warning(k)) is not None:
        warnings.append(off_centre)
    warnings += _camera_warnings(source)
    if len(source) == 1:
        warnings.append(f"the selection holds one frame ({source.indices[0]}): a motion needs two, nothing will be "
                        "tracked (check --frames: END is clamped to the source's frames, STEP may skip the rest)")
    height: float | None = config.height.camera_height_m or None
    if config.scale == "height":
        try:
            height = default_camera_height(source.camera_height, config)
        except ConfigError:
            height = None  # reported as an error elsewhere
    if height is not None and height > PLAUSIBLE_CAMERA_HEIGHT_M:
        warnings.append(f"camera height {height:g} m above the road: implausible for a car (over "
                        f"{PLAUSIBLE_CAMERA_HEIGHT_M:g} m; is it in metres?)")
    return warnings


def _camera_warnings(source: FrameSource) -> list[str]:
    """A focal length no real camera has: a field of view over `WIDEST_PINHOLE_DEG` for a pinhole (e.g.
    ``--intrinsics 1,1,607,185``: 179.8°) or under `NARROWEST_DEG` (a focal length in the wrong unit)."""
    k = source.intrinsics
    warnings = []
    for name, focal, pixels in (("fx", k.fx, k.width), ("fy", k.fy, k.height)):
        if pixels <= 0 or focal <= 0:
            continue
        fov = math.degrees(2.0 * math.atan(pixels / (2.0 * focal)))
        too_wide = fov > WIDEST_PINHOLE_DEG and k.model in ("none", "plumb_bob", "rational_polynomial")
        if too_wide or fov < NARROWEST_DEG:
            warnings.append(f"focal length {name} {focal:g} px gives a {fov:.1f}° field of view across {pixels} px: "
                            "implausible for this camera (are the intrinsics fx,fy,cx,cy in pixels of this image?)")
    if k.fx > 0 and k.fy > 0 and max(k.fx / k.fy, k.fy / k.fx) > WIDEST_PIXEL_ASPECT:
        ratio = max(k.fx, k.fy) / min(k.fx, k.fy)
        warnings.append(f"focal lengths fx {k.fx:g} and fy {k.fy:g} px differ by {ratio:.2f}x: pixels that far from "
                        "square are implausible (fx,fy,cx,cy in this order? one axis resized?)")
    return warnings


def nothing_tracked(result: RunResult) -> str | None:
    """A run of two frames or more in which no frame's motion could be measured for a failure. A camera that
    did not move (every frame `stationary` or `low_parallax`, a parked car) is a valid log: its held pose is
    the right answer."""
    if result.frames < 2 or result.tracked > 0:
        return None
    if all(reason in STANDING_STILL for reason in result.held_reasons):
        return None
    why = ""
    if result.held_reasons:
        reason, count = max(result.held_reasons.items(), key=lambda item: item[1])
        why = f" (mostly {reason}: {count} frames)"
    return (f"no frame could be tracked: {result.held} of {result.frames} frames held the first pose{why}; "
            "the outputs were written")
