"""The three extension points (docs/ARCHITECTURE.md): feature tiers, renderers and aligners are registries that
config validation, the CLI help and the docs' lists read; one registration makes a new entry usable everywhere."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from synthleak import cli
from synthleak.attack import align
from synthleak.config import ConfigError, LocalizeConfig, RenderConfig, config_from_dict
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.localize import Localizer, build_map, tiers
from synthleak.localize import testscene as ts
from synthleak.localize.features import OpenCVExtractor
from synthleak.localize.matching import match_features
from synthleak.render import registry

ARCHITECTURE = Path(__file__).resolve().parents[1] / "docs" / "ARCHITECTURE.md"


@pytest.fixture
def scratch_registries(monkeypatch):
    """Registrations made by a test are undone after it."""
    monkeypatch.setattr(tiers, "TIERS", dict(tiers.TIERS))
    monkeypatch.setattr(tiers, "_FACTORIES", dict(tiers._FACTORIES))
    monkeypatch.setattr(align, "ALIGNERS", dict(align.ALIGNERS))
    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))
    monkeypatch.setattr(registry, "_INSTALL_HINTS", dict(registry._INSTALL_HINTS))


def _documented(label: str) -> list[str]:
    """The names listed on docs/ARCHITECTURE.md's line ``<label>: `a`, `b`, ...``."""
    lines = [line for line in ARCHITECTURE.read_text().splitlines() if line.startswith(f"{label}:")]
    assert len(lines) == 1, f"docs/ARCHITECTURE.md: one line starting {label!r} expected"
    return re.findall(r"`([^`]+)`", lines[0])


def test_the_docs_list_exactly_the_registered_names() -> None:
    assert _documented("Registered tiers") == tiers.tier_names()
    assert _documented("Registered renderers") == registry.available_renderers()
    assert _documented("Registered aligners") == align.aligner_names()


def _help(command: str, capsys) -> str:
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args([command, "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_cli_help_lists_the_registered_tiers(capsys) -> None:
    text = _help("map", capsys)
    assert "{tiers}" not in text
    assert all(name in text for name in tiers.tier_names())
    assert "kornia-sift, xfeat, xfeat-lighterglue, disk-lightglue, aliked-lightglue: the [learned] extra" in text


# ------------------------------------------------------------------------------------------------- tiers
def _orb_extractor(tier: tiers.Tier, max_keypoints: int, weights_dir: Path | None) -> OpenCVExtractor:
    return OpenCVExtractor("orb", max_keypoints)


def _cross_check_matcher(tier: tiers.Tier, weights_dir: Path | None) -> tiers.Matcher:
    return lambda a, b: match_features(a, b, 1.0, True)  # mutual nearest neighbours, no ratio test


def test_a_registered_tier_maps_localizes_and_validates(scratch_registries, tmp_path) -> None:
    """One register_tier call: the config accepts the name, the help lists it, build_map and Localizer use its
    extractor and matcher, and its own PnP threshold and inlier minimum apply where the config says 0."""
    tier = tiers.register_tier(tiers.Tier("orb-mutual", ratio=1.0, mutual=True, pnp_max_error_px=8.0,
                                          min_inliers=25, max_keypoints=1500), _orb_extractor, _cross_check_matcher)
    with pytest.raises(ConfigError, match=r"f\.toml: localize\.tiers\[0\]: unknown name 'orbb'.*orb-mutual"):
        config_from_dict({"localize": {"tiers": ["orbb"]}}, "f.toml")
    assert config_from_dict({"localize": {"tiers": ["orb-mutual"]}}, "f.toml").localize.tiers == ["orb-mutual"]
    assert "orb-mutual" in cli.tiers_help()

    camera = Camera.from_hfov(320, 240, 65.0)
    scene = ts.write_sequence(tmp_path / "room_000", ts.make_room(seed=0), camera, ts.walkthrough_poses(40)[:6],
                              query_every=3)
    config = LocalizeConfig(max_keypoints=4096, pairs_per_image=4)
    assert config.pnp_max_error_px == 0.0 and config.min_inliers == 0  # the tier's own
    map_dir = build_map(scene, "orb-mutual", tmp_path / "map", config, progress=False)
    loc = Localizer.load(map_dir, config)
    assert loc.tier is tier and (loc.max_error_px, loc.min_inliers) == (8.0, 25)
    assert max(len(f.keypoints) for f in loc.data.features) <= 1500  # the tier's keypoint budget
    seq = load_sequence(scene)
    results = [loc.localize(seq.rgb(frame)) for frame in seq.query_frames]
    assert any(r.success for r in results)
    for frame, result in zip(seq.query_frames, results, strict=True):
        if result.success:
            centre_error = np.linalg.norm(np.linalg.inv(result.cam_from_world)[:3, 3]
                                          - np.linalg.inv(seq.cam_from_world[frame])[:3, 3])
            assert centre_error < 0.1 and result.num_inliers >= 25
    assert Localizer.load(map_dir, LocalizeConfig(pnp_max_error_px=4.0, min_inliers=40)).max_error_px == 4.0


def test_unknown_tier_names_the_registered_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown localization tier 'surf'.*orb, akaze, sift"):
        tiers.get_tier("surf")


# ---------------------------------------------------------------------------------------- aligners, renderers
def test_a_registered_aligner_is_accepted_and_loaded_on_first_use(scratch_registries) -> None:
    align.register_aligner("alg1-again", "synthleak.attack.align:align_alg1")  # lazy: imported when asked for
    assert "alg1-again" in align.aligner_names()
    assert config_from_dict({"attack": {"aligners": ["alg1-again"]}}, "f.toml").attack.aligners == ["alg1-again"]
    assert align.get_aligner("alg1-again") is align.align_alg1
    with pytest.raises(ConfigError, match=r"f\.toml: attack\.aligners\[1\]: unknown name 'alg3'.*alg1-again"):
        config_from_dict({"attack": {"aligners": ["alg1", "alg3"]}}, "f.toml")


def test_a_registered_renderer_is_accepted_and_built(scratch_registries) -> None:
    registry.register_renderer("mitsuba-again", "synthleak.render.mitsuba_backend:create_mitsuba_renderer")
    config = config_from_dict({"render": {"renderer": "mitsuba-again", "spp": 3}}, "f.toml")
    renderer = registry.get_renderer(config.render)
    assert (renderer.name, renderer.spp) == ("mitsuba", 3)
    registry.register_renderer("nowhere", "synthleak.render.no_such_backend:create", "pip install nowhere")
    with pytest.raises(registry.RendererUnavailable, match=r"'nowhere' cannot run here.*pip install nowhere"):
        registry.get_renderer(RenderConfig(renderer="nowhere"))
    with pytest.raises(ConfigError, match=r"f\.toml: render\.renderer: unknown name 'povray'.*mitsuba-again"):
        config_from_dict({"render": {"renderer": "povray"}}, "f.toml")
