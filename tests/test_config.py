"""The typed engine config and its TOML loading."""

from __future__ import annotations

from pathlib import Path

import pytest

from vslam_core.config import EngineConfig, load_config
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
