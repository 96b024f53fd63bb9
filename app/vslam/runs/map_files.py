"""`vslam run --save-map / --map` and `vslam inspect-map`: the CLI's side of saved maps
(vslam_core/mapping/storage.py holds the format)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from vslam_core.config import EngineConfig
    from vslam_core.pipeline import Engine
    from vslam_core.sources.base import FrameSource

# The map backend, its bundle adjustment and the map's files (polars) are imported by the functions that use them:
# `save_map_problem` is checked on every `vslam run`, which a refused run should not pay for.


def save_map_problem(path: Path | None, prior: Path | None, config: EngineConfig) -> str | None:
    """Why `--save-map PATH` cannot be done, if so (checked before the run starts)."""
    if path is None:
        return None
    if prior is not None:
        return "--save-map and --map together: a localisation run does not build a map to save"
    if config.backend != "map":
        return "--save-map needs --backend map (the vo backend keeps no map)"
    if path.exists():
        return f"{path}: already exists (a saved map is never overwritten; choose a new folder)"
    return None


def map_saver(path: Path, source: FrameSource, config: EngineConfig,
              adjust: bool = True) -> Callable[[Engine], None]:
    """The run's `finish` step that writes the map to `path`, after a global bundle adjustment of every keyframe
    and landmark (vslam_core/mapping/global_adjustment.py): the run's own (`map.adjust_at_end`, so the trajectory
    output and the map agree), else one here unless `adjust` is False."""
    from vslam_core import __version__
    from vslam_core.mapping.global_adjustment import GlobalAdjusted, adjust_map
    from vslam_core.mapping.storage import camera_dict, save_map, snapshot
    from vslam_core.mapping.tracking import MapTracking
    from vslam_core.sources.base import describe_indices

    def save(engine: Engine) -> None:
        assert isinstance(engine, MapTracking)
        if engine.loop is not None:
            engine.loop.finish(engine.mapping.map)
        places = engine.loop.places if engine.loop is not None else {}
        header: dict[str, Any] = {"vslam_version": __version__, "camera": camera_dict(source.intrinsics),
                                  "scale": config.scale, "source": source.name,
                                  "frames": describe_indices(source.indices)}
        adjusted = engine.adjusted_at_end if isinstance(engine.adjusted_at_end, GlobalAdjusted) else None
        if adjusted is None and adjust:  # the run's own adjustment, when it made one as it ended, else one here
            adjusted = adjust_map(engine.mapping.map, source.intrinsics.K, engine.settings, config.scale)
        if adjusted is not None:
            header["global_adjustment"] = {
                "keyframes": adjusted.keyframes, "landmarks": adjusted.landmarks,
                "observations": adjusted.observations,
                "mean_error_px": [round(adjusted.mean_error_before, 4), round(adjusted.mean_error_after, 4)],
                "culled_observations": adjusted.culled_observations, "culled_landmarks": adjusted.culled_landmarks}
        save_map(path, snapshot(engine.mapping.map, places, source.indices, header))

    return save


def map_summary(path: Path) -> dict[str, Any]:
    """The header of a saved map (keyframes, landmarks, extent, the drive it came from)."""
    from vslam_core.mapping.storage import read_header

    return read_header(path)


def format_map_summary(path: Path, header: dict[str, Any]) -> str:
    camera = header.get("camera", {})
    extent = header.get("extent_m", [0.0, 0.0, 0.0])
    return "\n".join([
        f"map         {path} (format version {header['version']}, written by vslam {header.get('vslam_version')})",
        f"drive       {header.get('source')} frames {header.get('frames')}, scale {header.get('scale')}",
        f"camera      {camera.get('width')}x{camera.get('height')}, fx {camera.get('fx')}, fy {camera.get('fy')}, "
        f"cx {camera.get('cx')}, cy {camera.get('cy')}, lens {camera.get('model')}",
        f"keyframes   {header.get('keyframes')}",
        f"landmarks   {header.get('landmarks')}",
        f"extent      {extent[0]:.1f} x {extent[1]:.1f} x {extent[2]:.1f} m (x right, y down, z forward of the "
        "first frame)",
    ])
