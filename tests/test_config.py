"""The typed engine config and its TOML loading."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from vslam_core.config import EngineConfig
from vslam_core.config_file import RANGES, check_config, flat_values, load_config
from vslam_core.errors import ConfigError


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "vslam.toml"
    path.write_text(text)
    return path


def test_toml_overrides_only_what_it_names(tmp_path: Path) -> None:
    text = 'scale = "none"\n[detector]\nfast_threshold = 30\n[pose]\nransac_threshold_px = 1\n'
    config = load_config(write(tmp_path, text))
    assert config.scale == "none"
    assert config.detector.fast_threshold == 30
    assert config.pose.ransac_threshold_px == 1.0 and isinstance(config.pose.ransac_threshold_px, float)
    assert config.tracker == EngineConfig().tracker


def test_round_trip_of_the_defaults_through_a_dict(tmp_path: Path) -> None:
    lines = []
    data = EngineConfig().to_dict()
    for key, value in data.items():
        if not isinstance(value, dict):
            lines.append(f"{key} = {value!r}".replace("'", '"'))
    for section, values in data.items():
        if isinstance(values, dict):
            lines.append(f"[{section}]")
            lines += [f"{k} = {str(v).lower() if isinstance(v, bool) else repr(v).replace(chr(39), chr(34))}"
                      for k, v in values.items()]
    assert load_config(write(tmp_path, "\n".join(lines) + "\n")) == EngineConfig()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[detector]\nfast_treshold = 20\n", "'detector.fast_treshold'"),
        ("colour = 1\n", "'colour'"),
        ("[detector]\nfast_threshold = \"high\"\n", "'detector.fast_threshold': expected an integer"),
        ("[pose]\nrefine = 1\n", "'pose.refine': expected true or false"),
        ("scale = \"lidar\"\n", "'scale'"),
        ("detector = 3\n", "'detector': expected a table"),
        ("[pose\n", "not valid TOML"),
    ],
)
def test_bad_config_names_the_key(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("[", r"\[")) as info:
        load_config(write(tmp_path, text))
    assert str(tmp_path) in str(info.value)


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")


# ------------------------------------------------------------------------------------------ ranges


def _numeric_keys() -> list[str]:
    return [key for key, value in flat_values(EngineConfig()).items()
            if isinstance(value, int | float) and not isinstance(value, bool)]


def test_every_numeric_parameter_has_a_range_and_the_defaults_pass() -> None:
    keys = _numeric_keys()
    assert len(keys) > 60  # every section, MapConfig included
    assert sorted(set(keys) - set(RANGES)) == []
    assert sorted(set(RANGES) - set(keys)) == []  # no range for a key that does not exist
    check_config(EngineConfig())
    for key in keys:  # the default of each key lies in its range
        assert RANGES[key].contains(flat_values(EngineConfig())[key]), key


@pytest.mark.parametrize("key", sorted(RANGES))
def test_a_value_just_outside_each_range_is_refused(tmp_path: Path, key: str) -> None:
    valid = RANGES[key]
    value = valid.low - 1 if not math.isinf(valid.low) else valid.high + 1
    if valid.low_open and not math.isinf(valid.low):
        value = valid.low  # the open end itself is outside
    if value in valid.also:
        value = value - 1
    section, _, name = key.rpartition(".")
    is_int = isinstance(flat_values(EngineConfig())[key], int)
    text = f"{name} = {int(value) if is_int else float(value)!r}\n"
    path = write(tmp_path, (f"[{section}]\n" if section else "") + text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert f"config key {key!r}" in message and "is out of range" in message and str(valid) in message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[tracker]\nwindow_px = -5\n", "config key 'tracker.window_px': -5 is out of range [3, 101]"),
        ("[tracker]\nmax_level = -1\n", "'tracker.max_level': -1 is out of range [0, 10]"),
        ("[detector]\ntarget_tracks = 0\n", "'detector.target_tracks': 0 is out of range [1, 100000]"),
        ("[pose]\nransac_threshold_px = -1\n", "'pose.ransac_threshold_px': -1.0 is out of range (0, 100]"),
        ("[height]\ncamera_height_m = 0.001\n", "'height.camera_height_m': 0.001 is out of range 0 or [0.1, 100]"),
        ("[height]\ncamera_height_m = -1\n", "'height.camera_height_m': -1.0 is out of range"),
        ("[pose]\nransac_probability = nan\n", "'pose.ransac_probability': nan is out of range (0, 1)"),
        ("[map]\nba_window = 0\n", "'map.ba_window': 0 is out of range [1, 1000]"),
        ("[detector]\nredetect_below = 900\n", "detector.redetect_below = 900, detector.target_tracks = 800: "
                                               "redetect_below must not exceed target_tracks"),
        ("[map]\nmap_keyframes = 8\n", "map_keyframes must be at least ba_window + ba_max_fixed"),
    ],
)
def test_out_of_range_values_are_one_line_naming_key_value_and_range(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    assert message in str(info.value) and "\n" not in str(info.value)


def test_infinite_forward_backward_threshold_still_disables_the_check(tmp_path: Path) -> None:
    config = load_config(write(tmp_path, "[tracker]\nfb_threshold_px = inf\npredicted_max_level = -1\n"))
    assert math.isinf(config.tracker.fb_threshold_px)
