"""benchmarks/capture_gap.py end to end on a tiny generated dataset: real stages, mitsuba renders, real
matchers and pycolmap PnP (2 pairs, sift + orb, 160x120)."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("capture_gap", ROOT / "benchmarks" / "capture_gap.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """ci-tiny's stages rendered at 160x120 with few frames (the benchmark renders B itself)."""
    from synthleak.config import load_config
    from synthleak.render.pipeline import generate

    config = load_config("ci-tiny")
    config = replace(config, render=replace(config.render, width=160, height=120, scene_frames=12,
                                            attacker_frames=2, query_every=4, bop_extras=False))
    out = tmp_path_factory.mktemp("capture_gap") / "dataset"
    generate(config, out, progress=False)
    return out


def test_capture_gap_table(tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cg = _benchmark()
    out = tmp_path / "gap.json"
    assert cg.main([str(tiny_dataset), "--pairs", "2", "--tiers", "sift,orb", "--json", str(out),
                    "--no-progress", "--min-coverage", "0.03"]) == 0
    result = json.loads(out.read_text())
    names = [row["condition"] for row in result["rows"]]
    expected = ["viewpoint", "light", *cg.EFFECT_GROUPS,
                *[f for f in cg.EFFECT_FIELDS if f not in {g for v in cg.EFFECT_GROUPS.values() for g in v}],
                *[f"all:{p}" for p in cg.ALL_PROFILES]]
    assert names == expected
    assert len(result["pairs"]) == 2
    assert result["resolution"] == [160, 120]
    rows = {row["condition"]: row for row in result["rows"]}
    for tier in ("sift", "orb"):
        view = rows["viewpoint"][tier]
        assert view["pairs"] == 2
        assert view["mean_verified"] > 0, view
        # verified matches are a subset of the matches
        assert all(r["verified"] <= r["matches"] for r in view["per_pair"])
    # the single effects the phone profile has run on every pair; those it lacks say so
    for name in ("sensor", "defocus", "distortion", "jpeg", "all:phone", "all:web-photo"):
        assert rows[name]["status"] == "" and rows[name]["sift"]["pairs"] == 2, rows[name]["status"]
    assert rows["recompress"]["status"] == "off in phone" and rows["recompress"]["sift"]["pairs"] == 0
    # every capture is a slice of one drawn device: the sensor row's photo really differs from the render
    sensor = rows["sensor"]["sift"]["per_pair"][0]
    assert "noise" in sensor["capture_effects"]
    table = capsys.readouterr().out
    assert "| viewpoint |" in table and "| all:web-photo |" in table

    # deterministic: a second run gives the same numbers
    again = tmp_path / "again.json"
    cg.main([str(tiny_dataset), "--pairs", "2", "--tiers", "sift,orb", "--json", str(again), "--no-progress",
             "--min-coverage", "0.03"])
    assert json.loads(again.read_text())["rows"] == result["rows"]


def test_bad_dataset_is_named(tmp_path: Path) -> None:
    cg = _benchmark()
    with pytest.raises(cg.DatasetError, match="stages/index.json"):
        cg.dataset_dir(tmp_path)
