"""Server profiles (``[localize] profile``): ``strict`` is the tiers as registered, ``hloc`` HLoc's defaults.

Maps are built from a six-frame 160x120 box room (:mod:`synthleak.localize.testscene`) with the SIFT tier: a few
seconds of CPU.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from synthleak.cache import cache_key
from synthleak.config import ConfigError, LocalizeConfig, config_from_dict, config_to_dict, load_config
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.localize import testscene as ts
from synthleak.localize.localizer import Localizer
from synthleak.localize.mapping import build_map
from synthleak.localize.store import MapError
from synthleak.localize.tiers import (
    PROFILE_FIELDS,
    PROFILES,
    TIERS,
    get_tier,
    list_tiers,
    profile_fixes,
    profile_names,
    profile_tier,
)
from synthleak.study.tiers import check_tiers_installed, tier_weights

# The built-in tiers' definitions before server profiles existed: ``strict`` must give exactly these.
TODAY = {
    "orb": dict(ratio=0.75, mutual=True, pnp_max_error_px=12.0, min_inliers=20, needs_torch=False,
                max_keypoints=0, learned_matcher=False, weights=(), match_threshold=0.0),
    "akaze": dict(ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=False,
                  max_keypoints=0, learned_matcher=False, weights=(), match_threshold=0.0),
    "sift": dict(ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=False,
                 max_keypoints=0, learned_matcher=False, weights=(), match_threshold=0.0),
    "kornia-sift": dict(ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=True,
                        max_keypoints=0, learned_matcher=False, weights=(), match_threshold=0.0),
    "xfeat": dict(ratio=0.9, mutual=True, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
                  max_keypoints=4096, learned_matcher=False, weights=("xfeat",), match_threshold=0.0),
    "xfeat-lighterglue": dict(ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
                              max_keypoints=1024, learned_matcher=True, weights=("xfeat", "xfeat-lighterglue"),
                              match_threshold=0.3),
    "disk-lightglue": dict(ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
                           max_keypoints=1024, learned_matcher=True, weights=("disk", "disk-lightglue"),
                           match_threshold=0.3),
    "aliked-lightglue": dict(ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
                             max_keypoints=1024, learned_matcher=True, weights=("aliked-n16", "aliked-lightglue"),
                             match_threshold=0.3),
}

# HLoc's defaults (docs/learned-tiers.md, "Server profiles"): (ratio, mutual, match_threshold, min_inliers, PnP px)
HLOC = {
    "orb": (0.0, True, 0.0, 3, 12.0),  # NN-mutual, on Hamming distances
    "akaze": (0.0, True, 0.0, 3, 12.0),
    "sift": (0.8, True, 0.0, 3, 12.0),  # NN-ratio
    "kornia-sift": (0.8, True, 0.0, 3, 12.0),
    "xfeat": (0.0, True, 0.0, 3, 12.0),  # NN-mutual (HLoc has no XFeat)
    "xfeat-lighterglue": (0.0, False, 0.1, 3, 12.0),  # LightGlue's filter_threshold
    "disk-lightglue": (0.0, False, 0.1, 3, 12.0),
    "aliked-lightglue": (0.0, False, 0.1, 3, 12.0),
}

STRICT_MAP_SETTINGS = {"tier", "max_keypoints", "pairs_per_image", "bow", "visible_min_fraction", "format_version"}
"""``map.json`` settings of a classic-tier map before profiles existed."""


def test_profiles_are_strict_and_hloc():
    assert profile_names() == ["strict", "hloc"]
    assert LocalizeConfig().profile == "strict"


@pytest.mark.parametrize("name", sorted(TODAY))
def test_strict_leaves_every_tier_as_it_was(name):
    tier = profile_tier(name, "strict")
    assert tier is get_tier(name) is TIERS[name]
    assert tier.definition() == {"name": name, **TODAY[name]}  # what maps and keys record: as before
    assert dataclasses.asdict(tier) == {"name": name, **TODAY[name], "ratio_both_ways": False}


def test_strict_tier_listing_is_the_plain_one():
    assert list_tiers("strict") == list_tiers()
    assert {t["name"] for t in list_tiers()} >= set(TODAY)


@pytest.mark.parametrize("name", sorted(HLOC))
def test_hloc_gives_hlocs_defaults_and_keeps_the_features(name):
    ratio, mutual, match_threshold, min_inliers, pnp = HLOC[name]
    tier = profile_tier(name, "hloc")
    assert (tier.ratio, tier.mutual, tier.match_threshold, tier.min_inliers, tier.pnp_max_error_px) == HLOC[name]
    strict = dataclasses.asdict(get_tier(name))
    changed = {k for k, v in dataclasses.asdict(tier).items() if v != strict[k]}
    assert changed <= set(PROFILE_FIELDS)  # extractor, keypoint budget, weights: as in strict
    assert get_tier(name) == TIERS[name] and get_tier(name).definition() == {"name": name, **TODAY[name]}
    # HLoc's NN-ratio tests the ratio from both sides (hloc/matchers/nearest_neighbor.py:51-58); NN-mutual has none
    assert tier.ratio_both_ways == (name in ("sift", "kornia-sift"))
    assert ("ratio_both_ways" in tier.definition()) == tier.ratio_both_ways


def test_hloc_covers_every_built_in_tier():
    assert set(PROFILES["hloc"]) == set(TODAY)


def test_profile_errors_name_the_profile_and_tier(monkeypatch):
    with pytest.raises(ValueError, match="unknown server profile 'colmap'.*strict, hloc"):
        profile_tier("sift", "colmap")
    monkeypatch.setitem(PROFILES, "broken", {"sift": {"max_keypoints": 10}})
    with pytest.raises(ValueError, match="'broken', tier 'sift': max_keypoints cannot be set by a profile"):
        profile_tier("sift", "broken")
    with pytest.raises(ValueError, match="'broken' has no values for tier 'orb'"):
        profile_tier("orb", "broken")
    with pytest.raises(ConfigError, match="localize.profile: server profile 'broken' has no values for tier 'orb'"):
        check_tiers_installed(["orb"], "broken")


def test_unknown_profile_in_a_config_names_the_file_and_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\n[localize]\nprofile = "colmap"\n')
    known = r"unknown name 'colmap' \(known: strict, hloc\)"
    with pytest.raises(ConfigError, match=rf"bad\.toml: localize\.profile: {known}"):
        load_config(path)
    path.write_text('name = "bad"\n[localize]\nprofile = 1\n')
    with pytest.raises(ConfigError, match=r"bad\.toml: localize\.profile: expected"):
        load_config(path)


def test_a_config_reads_profile_hloc(tmp_path):
    path = tmp_path / "hloc.toml"
    path.write_text('extends = "ci-tiny"\n[localize]\nprofile = "hloc"\n')
    config = load_config(path)
    assert config.localize.profile == "hloc"
    assert config_to_dict(config)["localize"]["profile"] == "hloc"
    assert config_from_dict(config_to_dict(config), "again").localize.profile == "hloc"


def _plain(value):
    """``config_to_dict`` as it was before profiles: ``asdict``, tuples as lists."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


@pytest.mark.parametrize("name", ["ci-tiny", "ci-tiny-hard", "ci-tiny-sfm"])  # the study presets run both profiles
def test_strict_configs_keep_their_content_keys(name):
    config = load_config(name)
    assert config.localize.profile == "strict"
    before = _plain(dataclasses.asdict(config))
    del before["localize"]["profile"]
    del before["localize"]["representation"]  # added after profiles, left out at "points" the same way
    del before["localize"]["servers"]  # likewise, left out while empty (every server of the config)
    del before["localize"]["two_view_min_inliers"]  # likewise, left out while 0 (no two-view check)
    del before["localize"]["pnp_solver"]  # likewise, left out at its default (colmap)
    for key in ("capture_map", "capture_genuine", "capture_attacker",  # the render keys added after profiles
                "light_map", "light_genuine", "light_attacker"):
        del before["render"][key]
    assert config_to_dict(config) == before
    assert cache_key(config_to_dict(config)) == cache_key(before)
    assert config_from_dict(config_to_dict(config), "again") == config
    hloc = dataclasses.replace(config, localize=dataclasses.replace(config.localize, profile="hloc"))
    assert cache_key(config_to_dict(hloc)) != cache_key(before)


def test_tier_keys_stay_under_strict_and_carry_the_definition_under_hloc():
    assert tier_weights("sift") == tier_weights("sift", "strict") == []
    assert tier_weights("orb", "strict") == []
    (entry,) = tier_weights("sift", "hloc")
    assert entry["profile"] == "hloc" and entry["weights"] == {}
    assert entry["tier"] == profile_tier("sift", "hloc").definition() and entry["tier"]["ratio_both_ways"]
    assert tier_weights("orb", "hloc") != tier_weights("akaze", "hloc")


# ---------------------------------------------------------------- maps


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("profilebox") / "room_000"
    return ts.write_sequence(out, ts.make_room(seed=0), Camera.from_hfov(160, 120, 65.0),
                             ts.walkthrough_poses(40)[:6], query_every=3)


def test_maps_record_the_profile_and_strict_maps_keep_their_keys(room, tmp_path):
    strict_cfg = LocalizeConfig(max_keypoints=512, pairs_per_image=3)
    hloc_cfg = dataclasses.replace(strict_cfg, profile="hloc")
    map_dir = tmp_path / "sift"

    build_map(room, "sift", map_dir, strict_cfg, progress=False)
    meta = json.loads((map_dir / "map.json").read_text())
    assert set(meta["settings"]) == STRICT_MAP_SETTINGS and "profile" not in meta
    strict = Localizer.load(map_dir, strict_cfg)
    assert (strict.min_inliers, strict.max_error_px, strict.tier) == (15, 12.0, get_tier("sift"))
    with pytest.raises(MapError, match=r"map\.json: built with \[localize\] profile = 'strict'.*'hloc'"):
        Localizer.load(map_dir, hloc_cfg)

    build_map(room, "sift", map_dir, hloc_cfg, progress=False)  # another profile: rebuilt in place
    meta = json.loads((map_dir / "map.json").read_text())
    assert set(meta["settings"]) == STRICT_MAP_SETTINGS | {"profile", "tier_definition"}
    assert meta["settings"]["profile"] == "hloc"
    definition = meta["settings"]["tier_definition"]
    assert (definition["ratio"], definition["mutual"], definition["min_inliers"],
            definition["pnp_max_error_px"], definition["ratio_both_ways"]) == (0.8, True, 3, 12.0, True)
    loc = Localizer.load(map_dir, hloc_cfg)
    assert (loc.min_inliers, loc.max_error_px, loc.tier) == (3, 12.0, profile_tier("sift", "hloc"))
    with pytest.raises(MapError, match=r"built with \[localize\] profile = 'hloc'.*'strict'"):
        Localizer.load(map_dir, strict_cfg)
    seq = load_sequence(room)
    result = loc.localize(seq.rgb(seq.query_frames[0]))
    assert result.success and result.num_inliers >= 3

    build_map(room, "orb", tmp_path / "orb", hloc_cfg, progress=False)
    orb = json.loads((tmp_path / "orb" / "map.json").read_text())["settings"]["tier_definition"]
    assert (orb["ratio"], orb["mutual"], orb["min_inliers"]) == (0.0, True, 3) and "ratio_both_ways" not in orb


def test_a_config_override_tunes_strict_servers_and_leaves_hlocs_values(room, tmp_path):
    """The study presets set ``pnp_max_error_px`` for their strict servers (HLoc's 12 px as a share of the width):
    a strict server takes it, an ``hloc`` server keeps HLoc's 12 px and 3 inliers on any image size."""
    strict_cfg = LocalizeConfig(max_keypoints=512, pairs_per_image=3, pnp_max_error_px=4.0, min_inliers=20)
    hloc_cfg = dataclasses.replace(strict_cfg, profile="hloc")
    build_map(room, "sift", tmp_path / "strict", strict_cfg, progress=False)
    build_map(room, "sift", tmp_path / "hloc", hloc_cfg, progress=False)
    strict = Localizer.load(tmp_path / "strict", strict_cfg)
    hloc = Localizer.load(tmp_path / "hloc", hloc_cfg)
    assert (strict.max_error_px, strict.min_inliers) == (4.0, 20)
    assert (hloc.max_error_px, hloc.min_inliers) == (12.0, 3)
    seq = load_sequence(room)
    rgb = seq.rgb(seq.query_frames[0])
    tight = strict.localize(rgb)
    loose = Localizer.load(tmp_path / "strict", dataclasses.replace(strict_cfg, pnp_max_error_px=0.0)).localize(rgb)
    assert tight.success and loose.success and tight.num_inliers < loose.num_inliers  # 4 px keeps fewer than 12 px
    assert hloc.localize(rgb).success
    assert profile_fixes("sift", "hloc") >= {"pnp_max_error_px", "min_inliers"}
    assert profile_fixes("sift", "strict") == frozenset() == profile_fixes("sift", ["strict", "hloc"])


@pytest.mark.parametrize("tier", ["sift", "orb"])
def test_maps_built_together_are_the_bytes_of_maps_built_alone(room, tmp_path, tier, monkeypatch):
    """A tier's servers (strict and hloc profiles, points and line clouds) built by one ``build_maps`` share the
    frames' features and each pair's scores, and every file of every map is the bytes of that map built alone."""
    from synthleak.localize import mapping

    base = LocalizeConfig(max_keypoints=512, pairs_per_image=3)
    configs = {"strict": base, "hloc": dataclasses.replace(base, profile="hloc"),
               "hloc+line-cloud": dataclasses.replace(base, profile="hloc", representation="line-cloud")}
    for name, config in configs.items():
        build_map(room, tier, tmp_path / "alone" / name, config, progress=False)
    extracted: list[int] = []
    from synthleak.localize.tiers import Tier

    original = Tier.make_extractor
    monkeypatch.setattr(Tier, "make_extractor", lambda self, *a: extracted.append(1) or original(self, *a))
    mapping.build_maps(room, tier, [(tmp_path / "together" / name, config) for name, config in configs.items()],
                       progress=False)
    assert len(extracted) == 1  # one extraction for the three maps
    for name in configs:
        alone, together = tmp_path / "alone" / name, tmp_path / "together" / name
        files = sorted(p.relative_to(alone) for p in alone.rglob("*") if p.is_file())
        assert files == sorted(p.relative_to(together) for p in together.rglob("*") if p.is_file())
        for rel in files:
            if rel.suffix == ".npz":  # (a zip member records the time it was written)
                import numpy as np

                with np.load(alone / rel) as a, np.load(together / rel) as b:
                    assert sorted(a.files) == sorted(b.files)
                    assert all(a[k].dtype == b[k].dtype and a[k].tobytes() == b[k].tobytes() for k in a.files), rel
            else:
                assert (alone / rel).read_bytes() == (together / rel).read_bytes(), (name, rel)
