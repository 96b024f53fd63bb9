"""A user's engine config: read from TOML (`load_config`) or nested dicts (`config_from_dict`), every key checked
against its field's type, the valid range of every numeric parameter, and the rules between parameters.

`check_config` is run on every config a user gives (a TOML file, or a CLI option that sets a value such as
``--camera-height``): a value out of range is one `ConfigError` line naming the key, the value and the range,
before anything runs. Ranges are what the code can work with (OpenCV's limits, a ratio in [0, 1], a count of
points a model needs), with generous upper bounds; they do not judge whether a value is a good idea.
`tests/test_config.py` checks that every numeric field has a range here and that the defaults pass.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, get_args, get_origin, get_type_hints

from vslam_core.config import EngineConfig
from vslam_core.errors import ConfigError

INF = math.inf


@dataclass(frozen=True)
class Range:
    """low ≤ value ≤ high (or < when open on that side); `also`: single values allowed outside, with a
    meaning (e.g. 0 = the source's own camera height)."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    also: tuple[float, ...] = ()
    note: str = ""

    def contains(self, value: float) -> bool:
        if value in self.also:
            return True
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return bool(above and below)  # NaN: both False

    def interval(self) -> str:
        def number(v: float) -> str:
            if math.isinf(v):
                return "inf" if v > 0 else "-inf"
            return f"{v:g}"

        low_open = self.low_open or math.isinf(self.low)
        high_open = self.high_open or math.isinf(self.high)
        return f"{'(' if low_open else '['}{number(self.low)}, {number(self.high)}{')' if high_open else ']'}"

    def __str__(self) -> str:
        text = self.interval()
        if self.also:
            text = " or ".join(f"{v:g}" for v in self.also) + f" or {text}"
        return text + (f" ({self.note})" if self.note else "")


def closed(low: float, high: float = INF, note: str = "") -> Range:
    return Range(low, high, note=note)


def positive(high: float = INF, note: str = "") -> Range:
    """(0, high]"""
    return Range(0.0, high, low_open=True, note=note)


FRACTION = closed(0.0, 1.0)
PIXEL_SIZE = positive(1000.0)
FAST = closed(1, 255)
COUNT = closed(0, 10_000_000)
ITERATIONS = closed(1, 1_000_000)
PYRAMID = closed(0, 10)

#: dotted config key -> valid range (every int and float field of `EngineConfig` and its sections)
RANGES: dict[str, Range] = {
    "threads": closed(1, 256),
    # detector
    "detector.fast_threshold": FAST,
    "detector.target_tracks": closed(1, 100_000),
    "detector.redetect_below": closed(0, 100_000),
    "detector.grid_rows": closed(1, 100),
    "detector.grid_cols": closed(1, 100),
    "detector.min_distance_px": closed(0, 1000),
    "detector.min_coverage": closed(0.0, 1.0),
    # tracker (OpenCV's calcOpticalFlowPyrLK needs a window > 2 px and maxLevel ≥ 0)
    "tracker.window_px": closed(3, 101),
    "tracker.max_level": PYRAMID,
    "tracker.predicted_max_level": closed(-1, 10, note="-1: no prediction"),
    "tracker.backward_max_level": PYRAMID,
    "tracker.max_iterations": closed(1, 1000),
    "tracker.epsilon": positive(10.0),
    "tracker.fb_threshold_px": Range(0.0, INF, low_open=True, note="inf: no forward-backward check"),
    "tracker.border_px": closed(0, 1000),
    "tracker.retry_failed_share": FRACTION,
    # pose (the 5-point solver needs 5 correspondences; RANSAC's confidence lies strictly between 0 and 1)
    "pose.ransac_probability": Range(0.0, 1.0, low_open=True, high_open=True),
    "pose.ransac_threshold_px": positive(100.0),
    "pose.ransac_max_iterations": ITERATIONS,
    "pose.seed": closed(0, 2**63 - 1),
    "pose.chirality_max_depth": Range(0.0, INF, low_open=True, high_open=True),
    "pose.chirality_far_depth": Range(0.0, INF, low_open=True, high_open=True),
    "pose.min_tracks": closed(5, 100_000),
    "pose.hold_reversed_frames": closed(1, 1000),
    "pose.min_inliers": closed(5, 100_000),
    "pose.min_parallax_px": closed(0.0, 1000.0),
    "pose.stationary_px": closed(0.0, 1000.0),
    "pose.keyframe_parallax_px": closed(0.0, 1000.0),
    # health
    "health.dark_mean": closed(0.0, 255.0),
    "health.bright_saturated": FRACTION,
    "health.blur_sharpness": closed(0.0, 1e9),
    "health.noise_sigma": closed(0.0, 255.0),
    "health.brightness_jump": closed(0.0, 255.0),
    "health.warn_tracks": COUNT,
    "health.warn_inlier_ratio": FRACTION,
    "health.ambiguous_chirality": FRACTION,
    "health.rotation_parallax_px": closed(0.0, 1000.0),
    "health.step_jump": closed(1.0, 1000.0),
    # height scale
    "height.camera_height_m": Range(0.1, 100.0, also=(0.0,), note="0: the source's own"),
    "height.road_top_deg": closed(0.0, 60.0),
    "height.road_half_width_deg": positive(80.0),
    "height.road_tracks": closed(1, 100_000),
    "height.road_fast_threshold": FAST,
    "height.max_tilt_deg": positive(90.0),
    "height.inlier_fraction": positive(1.0),
    "height.ransac_iterations": ITERATIONS,
    "height.min_road_points": closed(3, 100_000),
    "height.window": closed(1, 1000),
    "height.max_jump": positive(100.0),
    "height.doubtful_jump": positive(100.0),
    "height.doubtful_tilt_deg": positive(90.0),
    "height.doubtful_inliers": COUNT,
    # map backend
    "map.keyframe_parallax_px": positive(10_000.0),
    "map.keyframe_overlap": FRACTION,
    "map.keyframe_min_landmarks": COUNT,
    "map.keyframe_max_frames": closed(1, 100_000),
    "map.min_triangulation_deg": Range(0.0, 90.0, high_open=True),
    "map.max_reprojection_px": PIXEL_SIZE,
    "map.cull_reprojection_px": PIXEL_SIZE,
    "map.min_observations": closed(1, 1000),
    "map.map_keyframes": closed(1, 100_000),
    "map.cull_redundant_share": FRACTION,
    "map.cull_observers": closed(1, 1000),
    "map.cull_scale": positive(1000.0),
    "map.cull_separation": closed(1, 100_000),
    "map.pnp_min_landmarks": closed(4, 100_000),
    "map.pnp_threshold_px": PIXEL_SIZE,
    "map.pnp_iterations": ITERATIONS,
    "map.pnp_min_inliers": closed(4, 100_000),
    "map.pnp_min_inlier_ratio": FRACTION,
    "map.max_rotation_disagreement_deg": positive(180.0),
    "map.front_end_agreement_deg": positive(180.0),
    "map.ba_window": closed(1, 1000),
    "map.ba_max_fixed": closed(0, 1000),
    "map.ba_iterations": closed(1, 1000),
    "map.ba_huber_px": PIXEL_SIZE,
    "map.init_parallax_px": positive(10_000.0),
    "map.init_wait_frames": closed(0, 1_000_000),
    "map.attempt_min_ray_angle_deg": closed(0, 180),
    "map.init_min_landmarks": closed(1, 100_000),
    "map.none_min_triangulation_deg": Range(0.0, 90.0, high_open=True),
    "map.slow_depth_frames": positive(1e9),
    "map.slow_min_triangulation_deg": Range(0.0, 90.0, high_open=True),
    "map.none_ba_iterations": closed(1, 1000),
    "map.none_step_sigma": closed(0.0, 10.0),
    "map.ba_max_landmarks": closed(1, 10_000_000),
    "map.adjust_at_end_keyframes": closed(1, 10_000_000),
    "map.rotation_prior_deg": closed(0.0, 180.0),
    "map.none_rotation_prior_deg": closed(0.0, 180.0),
    "map.adjust_at_end_rotation_prior_deg": closed(0.0, 180.0),
    "map.adjust_at_end_step_sigma": closed(0.0, 10.0),
    "map.sideways_forward_share": closed(0.0, 1.0),
    "map.sideways_keyframes": closed(2, 10_000),
    "map.sideways_min_step_depth": closed(0.0, 10.0),
    "map.rotation_prior_inflation": closed(0.0, 1e6),
    "map.none_rotation_prior_inflation": closed(0.0, 1e6),
    "map.rotation_prior_floor_deg": closed(0.0, 180.0),
    "map.rotation_prior_cap_deg": closed(0.0, 180.0),
    "map.scale_sigma_gt": positive(100.0),
    "map.scale_sigma_height": positive(10.0),
    "map.reloc_keyframes": closed(1, 1000),
    "map.reloc_fast_threshold": FAST,
    "map.reloc_ratio": positive(1.0),
    "map.reloc_threshold_px": PIXEL_SIZE,
    "map.reloc_iterations": ITERATIONS,
    "map.reloc_min_inliers": closed(4, 100_000),
    "map.local_map_keyframes": closed(1, 1000),
    "map.local_map_radius_px": positive(10_000.0),
    "map.local_map_max_distance": closed(0, 256),
    "map.local_map_ratio": positive(1.0),
    "map.local_map_levels": closed(1, 8),
    "map.local_map_scale": Range(1.0, 2.0, low_open=True),
    "map.reloc_radius_px": positive(10_000.0),
    "map.reloc_widenings": closed(0, 10),
    "map.search_min_radius_px": positive(10_000.0),
    "map.search_motion_fraction": closed(0.0, 10.0),
    "map.search_widenings": closed(0, 10),
    "map.search_band_px": closed(0.0, 10_000.0),
    "map.search_rival_px": closed(0.0, 10_000.0),
    "map.step_fit_min_inliers": closed(0, 10_000),
    "map.step_fit_max_ratio": closed(1.0, 100.0),
    "map.relative_step_min_points": closed(0, 10_000),
    "map.relative_step_min_deg": Range(0.0, 90.0, high_open=True),
    "map.relative_step_min_interval_s": closed(0.0, 3600.0),
    "map.starving_min_triangulation_deg": Range(0.0, 90.0, high_open=True),
    "map.none_pnp_min_inlier_ratio": FRACTION,
    "map.low_ratio_pnp_min_ratio": FRACTION,
    "map.none_low_ratio_pnp_min_ratio": FRACTION,
    "map.low_ratio_direction_deg": closed(0.0, 180.0),
    "map.keyframe_observation_px": PIXEL_SIZE,
    # loop closing
    "loop.features": closed(10, 100_000),
    "loop.fast_threshold": FAST,
    "loop.vocabulary_words": closed(2, 1_000_000),
    "loop.vocabulary_keyframes": closed(1, 1000),
    "loop.min_separation_keyframes": closed(1, 100_000),
    "loop.min_score_ratio": positive(10.0),
    "loop.max_candidates": closed(1, 100),
    "loop.match_ratio": positive(1.0),
    "loop.pnp_threshold_px": PIXEL_SIZE,
    "loop.pnp_iterations": ITERATIONS,
    "loop.min_inliers": closed(6, 100_000),
    "loop.min_inlier_ratio": FRACTION,
    "loop.consistency": closed(1, 100),
    "loop.cooldown_keyframes": closed(0, 100_000),
    "loop.odometry_sigma_deg": positive(180.0),
    "loop.odometry_sigma_m": positive(1000.0),
    "loop.none_odometry_sigma_deg": positive(180.0),
    "loop.none_odometry_sigma_m": positive(1000.0),
    "loop.loop_sigma_deg": positive(180.0),
    "loop.loop_sigma_m": positive(1000.0),
}


@dataclass(frozen=True)
class Rule:
    """A relation between parameters: `holds(values)` over the dotted keys it names."""

    keys: tuple[str, ...]
    holds: Callable[..., bool]
    text: str


RULES: tuple[Rule, ...] = (
    Rule(("detector.redetect_below", "detector.target_tracks"), lambda below, target: below <= target,
         "redetect_below must not exceed target_tracks"),
    Rule(("pose.min_inliers", "pose.min_tracks"), lambda inliers, tracks: inliers <= tracks,
         "min_inliers must not exceed min_tracks"),
    Rule(("map.map_keyframes", "map.ba_window", "map.ba_max_fixed"), lambda kept, window, fixed: kept >= window + fixed,
         "map_keyframes must be at least ba_window + ba_max_fixed (the BA window's landmarks must not be forgotten)"),
    Rule(("map.map_keyframes", "map.reloc_keyframes"), lambda kept, reloc: kept >= reloc,
         "map_keyframes must be at least reloc_keyframes"),
)


def flat_values(config: EngineConfig) -> dict[str, Any]:
    """Every leaf value of the config under its dotted key (``tracker.window_px``)."""
    values: dict[str, Any] = {}

    def walk(obj: Any, prefix: str) -> None:
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if dataclasses.is_dataclass(value):
                walk(value, f"{prefix}{f.name}.")
            else:
                values[prefix + f.name] = value

    walk(config, "")
    return values


def range_problem(key: str, value: Any) -> str | None:
    """'-5 is out of range [3, 101]' when `value` is outside `key`'s range, else None."""
    valid = RANGES.get(key)
    if valid is None or isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if valid.contains(value):
        return None
    return f"{value!r} is out of range {valid}"


def check_config(config: EngineConfig) -> None:
    """`ConfigError` (one line) for the first value out of its range, then for the first broken rule."""
    values = flat_values(config)
    for key, value in values.items():
        if (problem := range_problem(key, value)) is not None:
            raise ConfigError(f"config key {key!r}: {problem}")
    for rule in RULES:
        if not rule.holds(*(values[key] for key in rule.keys)):
            given = ", ".join(f"{key} = {values[key]!r}" for key in rule.keys)
            raise ConfigError(f"config keys {given}: {rule.text}")


def _check_value(key: str, value: Any, annotation: Any) -> Any:
    """Check one TOML value against a dataclass field's annotation; ints are accepted for floats."""
    origin = get_origin(annotation)
    if origin is Literal:
        allowed = get_args(annotation)
        if value not in allowed:
            raise ConfigError(f"config key {key!r}: {value!r} is not one of {', '.join(map(repr, allowed))}")
        return value
    if origin in (typing.Union, types.UnionType):
        for option in get_args(annotation):
            try:
                return _check_value(key, value, option)
            except ConfigError:
                continue
        raise ConfigError(f"config key {key!r}: {value!r} has the wrong type")
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"config key {key!r}: expected a number, got {type(value).__name__}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key {key!r}: expected an integer, got {type(value).__name__}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config key {key!r}: expected true or false, got {type(value).__name__}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"config key {key!r}: expected a string, got {type(value).__name__}")
        return value
    raise ConfigError(f"config key {key!r}: unsupported type")  # pragma: no cover - all fields covered


def _build(cls: type, data: dict[str, Any], prefix: str) -> Any:
    """Build dataclass `cls` from a TOML table, recursing into nested dataclass fields."""
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"unknown config key {prefix + unknown[0]!r} (known: {', '.join(sorted(names))})")
    values: dict[str, Any] = {}
    for name, value in data.items():
        annotation = hints[name]
        if dataclasses.is_dataclass(annotation):
            if not isinstance(value, dict):
                raise ConfigError(f"config key {prefix + name!r}: expected a table [{prefix + name}]")
            values[name] = _build(annotation, value, f"{prefix}{name}.")  # type: ignore[arg-type]
        else:
            values[name] = _check_value(prefix + name, value, annotation)
    return cls(**values)


def config_from_dict(data: dict[str, Any]) -> EngineConfig:
    """Build an `EngineConfig` from nested dicts (as TOML gives them), checking every key, its type and its
    range (and the rules between keys)."""
    config: EngineConfig = _build(EngineConfig, data, "")
    check_config(config)
    return config


def load_config(path: str | Path) -> EngineConfig:
    """Read an `EngineConfig` from a TOML file; keys left out keep their defaults."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a BOM (Windows editors) is not TOML
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read config ({exc.__class__.__name__})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    try:
        return config_from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
