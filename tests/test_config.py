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
    assert small.localize.tiers == preset.localize.tiers  # inherited untouched ...
    assert (small.localize.top_k, preset.localize.top_k) == (20, 40)  # ... where the child does not set it
    assert small.localize.servers and not preset.localize.servers


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


BAD_VALUES = [  # (section, key, value, what the message must say)
    ("localize", "tiers", ["siftt"], r"localize\.tiers\[0\]: unknown name 'siftt'.*sift"),
    ("localize", "tiers", [], r"localize\.tiers: must not be empty"),
    ("localize", "retrieval", "boww", r"localize\.retrieval: unknown name 'boww'.*exhaustive"),
    ("localize", "top_k", 0, r"localize\.top_k: must be >= 1"),
    ("localize", "max_keypoints", 0, r"localize\.max_keypoints: must be >= 1"),
    ("localize", "pnp_max_error_px", -1.0, r"localize\.pnp_max_error_px: must be >= 0"),
    ("localize", "min_inliers", -1, r"localize\.min_inliers: must be >= 0"),
    ("localize", "pairs_per_image", 0, r"localize\.pairs_per_image: must be >= 1"),
    ("attack", "aligners", ["alg2"], r"attack\.aligners\[0\]: unknown name 'alg2'.*alg1"),
    ("attack", "local_model", "sfmm", r"attack\.local_model: unknown name 'sfmm'.*oracle"),
    ("attack", "thresholds", [[-10.0, 0.25]], r"attack\.thresholds\[0\]\[0\]: must be > 0"),
    ("attack", "thresholds", [[10.0, 0.0]], r"attack\.thresholds\[0\]\[1\]: must be > 0"),
    ("attack", "queries_per_object", -1, r"attack\.queries_per_object: must be >= 0"),
    ("render", "renderer", "mitsubaa", r"render\.renderer: unknown name 'mitsubaa'.*mitsuba"),
    ("render", "width", -320, r"render\.width: must be >= 1, got -320"),
    ("render", "height", 0, r"render\.height: must be >= 1, got 0"),
    ("render", "scene_frames", 0, r"render\.scene_frames: must be >= 1"),
    ("render", "attacker_frames", 0, r"render\.attacker_frames: must be >= 1"),
    ("render", "query_every", 1, r"render\.query_every: must be >= 2"),
    ("render", "spp", 0, r"render\.spp: must be >= 1"),
    ("render", "max_depth", 0, r"render\.max_depth: must be >= 1"),
    ("render", "hfov_deg", 180.0, r"render\.hfov_deg: must be in \(0, 180\)"),
    ("render", "integrator", "pathh", r"render\.integrator: unknown name 'pathh'.*direct"),
    ("render", "filter", "boxx", r"render\.filter: unknown name 'boxx'.*gaussian"),
    ("render", "mitsuba_variant", "cuda_rgb", r"render\.mitsuba_variant: unknown name 'cuda_rgb'.*llvm_ad_rgb"),
    ("scenes", "rooms", 0, r"scenes\.rooms: must be >= 1"),
    ("scenes", "objects_per_room", [5, 3], r"scenes\.objects_per_room: \[min, max\] must be ordered, got \[5, 3\]"),
    ("scenes", "objects_per_room", [-1, 3], r"scenes\.objects_per_room\[0\]: must be >= 0"),
    ("scenes", "room_size_x", [6.0, 4.0], r"scenes\.room_size_x: \[min, max\] must be ordered"),
    ("scenes", "room_size_y", [0.0, 4.0], r"scenes\.room_size_y\[0\]: must be > 0"),
    ("scenes", "room_height", [2.5, -2.8], r"scenes\.room_height\[1\]: must be > 0"),
    ("scenes", "lights_per_room", [3, 2], r"scenes\.lights_per_room: \[min, max\] must be ordered"),
    ("scenes", "distinct_objects", -1, r"scenes\.distinct_objects: must be >= 0"),
    ("scenes", "scene_variant_magnitude", -0.1, r"scenes\.scene_variant_magnitude: must be >= 0"),
    ("scenes", "attacker_variant_kinds", ["color"], r"scenes\.attacker_variant_kinds\[0\]: unknown name 'color'"),
    ("attack", "presence", "vote", r"attack\.presence: unknown name 'vote'.*classifier"),
    ("defense", "min_fraction", 0.0, r"defense\.min_fraction: must be in \(0, 1\]"),
    ("defense", "min_fraction", 1.5, r"defense\.min_fraction: must be in \(0, 1\]"),
    ("defense", "min_instances", 0, r"defense\.min_instances: must be >= 1"),
    ("defense", "sweep_fractions", [0.1, 0.0], r"defense\.sweep_fractions\[1\]: must be in \(0, 1\]"),
    ("defense", "sweep_min_instances", [0], r"defense\.sweep_min_instances\[0\]: must be >= 1"),
    ("sweep", "kinds", ["hue"], r"sweep\.kinds\[0\]: unknown name 'hue'.*colour"),
    ("sweep", "magnitudes", [0.2, -0.1], r"sweep\.magnitudes\[1\]: must be >= 0"),
]


@pytest.mark.parametrize(("section", "key", "value", "message"), BAD_VALUES,
                         ids=[f"{s}.{k}={v}" for s, k, v, _ in BAD_VALUES])
def test_names_and_ranges_are_checked_when_the_config_loads(tmp_path, section, key, value, message):
    import json

    path = tmp_path / "bad.toml"
    path.write_text(f'extends = "ci-tiny"\n[{section}]\n{key} = {json.dumps(value)}\n')
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}: ")


def test_every_field_has_a_rule():
    """New config fields get their range or allowed names next to them (one line in the class's RULES)."""
    import dataclasses

    from synthleak.config import SECTIONS, StudyConfig

    for cls in (StudyConfig, *SECTIONS.values()):
        names = {f.name for f in dataclasses.fields(cls)}
        assert set(cls.RULES) == names - set(SECTIONS), cls.__name__


def test_an_empty_config_file_is_refused(tmp_path):
    for text in ("", "# only a comment\n\n"):
        path = tmp_path / "empty.toml"
        path.write_text(text)
        with pytest.raises(ConfigError, match=rf"{path}: the config file is empty"):
            load_config(path)


def test_extends_is_looked_up_beside_the_file_first(tmp_path):
    (tmp_path / "base.toml").write_text('extends = "ci-tiny"\nname = "base"\n[render]\nwidth = 96\nheight = 72\n')
    (tmp_path / "child.toml").write_text('extends = "base"\nname = "child"\n[scenes]\nrooms = 1\n')
    child = load_config(tmp_path / "child.toml")
    assert (child.render.width, child.render.height, child.scenes.rooms) == (96, 72, 1)
    assert child.seed == load_config("ci-tiny").seed  # ci-tiny came from render_configs/
    # a file named like a shipped config shadows it for its neighbours, and may extend the shipped one itself
    (tmp_path / "ci-tiny.toml").write_text('extends = "ci-tiny"\nname = "ci-tiny"\n[render]\nwidth = 80\n')
    (tmp_path / "uses_local.toml").write_text('extends = "ci-tiny"\nname = "uses_local"\n')
    assert load_config(tmp_path / "uses_local.toml").render.width == 80


def test_extends_nonexistent_names_the_file_that_says_it(tmp_path):
    middle = tmp_path / "middle.toml"
    middle.write_text('extends = "nonexistent"\n')
    child = tmp_path / "child.toml"
    child.write_text('extends = "middle"\n')
    with pytest.raises(ConfigError, match=rf"^{middle}: extends: no config 'nonexistent'"):
        load_config(child)


def test_loading_a_config_imports_neither_torch_nor_mitsuba():
    import subprocess
    import sys

    code = ("import sys; from synthleak.config import load_config; load_config('study-paper'); "
            "print(sorted(m for m in ('torch', 'mitsuba', 'drjit', 'kornia') if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
