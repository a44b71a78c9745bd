"""Config validation: unknown keys and wrong types are errors naming the file and the key."""

from __future__ import annotations

import pytest

from synthleak.config import ConfigError, config_from_dict, config_to_dict, load_config


@pytest.mark.parametrize("name", ["ci-tiny", "study", "study-small", "study-paper", "ci-tiny-pyrender"])
def test_shipped_configs_load(name):
    config = load_config(name)
    assert config.name == name
    assert config.render.width > 0 and config.localize.tiers


def test_extends_merges_and_child_wins():
    small, preset = load_config("study-small"), load_config("study")
    assert small.scenes.rooms == 3 and preset.scenes.rooms == 2
    assert small.localize == preset.localize  # inherited untouched


def test_unknown_key_names_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\n[render]\nwidht = 320\n')
    with pytest.raises(ConfigError, match=r"bad\.toml.*render\.widht: unknown key"):
        load_config(path)


def test_wrong_type_names_the_key():
    with pytest.raises(ConfigError, match=r"scenes\.rooms: expected an integer"):
        config_from_dict({"name": "x", "scenes": {"rooms": "two"}})
    with pytest.raises(ConfigError, match=r"attack\.thresholds\[0\]"):
        config_from_dict({"name": "x", "attack": {"thresholds": [[10.0]]}})


def test_missing_config_is_clear():
    with pytest.raises(ConfigError, match="no such config"):
        load_config("does-not-exist")


def test_round_trip_through_plain_dict():
    config = load_config("ci-tiny")
    assert config_from_dict(config_to_dict(config), "again") == config
