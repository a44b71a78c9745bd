"""Learned tiers with the real published weights (the ``[learned]`` extra and its weight packages).

Skipped, naming the extra, where torch/kornia or the weight packages are not installed; ``.ci/run`` installs them.
Fixtures: a rendered pair of one library object in the attacker hall (mitsuba, 320x240), the view turned by 30
degrees and the object recoloured at magnitude 0.5; the ``ci-tiny`` study's renders with ``tiers = ["xfeat"]``.
"""

from __future__ import annotations

import importlib.metadata
import json
import shutil
import socket
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import LocalizeConfig
from synthleak.core.types import Camera
from synthleak.localize import Localizer, build_map, get_tier
from synthleak.localize import testscene as ts

LEARNED = ["xfeat", "xfeat-lighterglue", "disk-lightglue", "aliked-lightglue"]
SKIP = "the [learned] extra is not installed (README, 'Learned tiers'): "


def _require_learned() -> None:
    for module in ("torch", "kornia"):
        pytest.importorskip(module, reason=SKIP + f"{module} missing")
    from synthleak.localize import deep

    for package in deep.WEIGHT_PACKAGES:
        try:
            importlib.metadata.distribution(package)
        except importlib.metadata.PackageNotFoundError:
            pytest.skip(SKIP + f"weight package {package} missing")


@pytest.fixture(autouse=True)
def learned_installed():
    _require_learned()


# ---------------------------------------------------------------- weights: strict, recorded, never downloaded


def _file_tensors(key: str) -> dict:
    import torch

    from synthleak.localize import deep

    state = torch.load(deep.find_weights(key), map_location="cpu", weights_only=True)
    return state["extractor"] if key == "disk" else state


@pytest.mark.parametrize("tier", LEARNED)
def test_each_tier_loads_every_tensor_of_its_real_weights(tier):
    import torch

    from synthleak.localize import deep

    spec = get_tier(tier)
    record = spec.weights_record()
    assert set(record) == {deep.WEIGHTS[k].name for k in spec.weights}
    for entry in record.values():
        assert len(entry["sha256"]) == 64 and entry["source"].startswith("scm-")
    extractor = spec.make_extractor(4096)
    model = {"xfeat": lambda e: e._model.net, "xfeat-lighterglue": lambda e: e._model.net,
             "disk-lightglue": lambda e: e._model, "aliked-lightglue": lambda e: e._model}[tier](extractor)
    file = _file_tensors(spec.weights[0])
    own = model.state_dict()
    assert set(file) <= set(own) and len(own) - len(file) <= 1  # ALIKED computes its dkd.hw_grid itself
    assert all(torch.equal(own[k], file[k]) for k in file)
    if spec.learned_matcher:
        matcher = spec.make_matcher()._model
        prefix = "matcher." if tier == "xfeat-lighterglue" else ""
        mapped = deep._lightglue_keys(_file_tensors(spec.weights[1]), matcher.conf.n_layers, prefix)
        own = matcher.state_dict()
        used = [k for k in mapped if k in own]
        assert set(own) - set(used) == {"confidence_thresholds"}  # the one buffer LightGlue computes itself
        assert all(torch.equal(own[k], mapped[k]) for k in used)
    assert spec.keypoint_budget(100_000) == spec.max_keypoints and spec.keypoint_budget(256) == 256


def test_a_weight_file_that_does_not_fit_is_refused(tmp_path):
    import torch

    from synthleak.localize import deep

    state = dict(_file_tensors("xfeat"))
    variants = {
        "missing ['block1.0.layer.0.weight']": {k: v for k, v in state.items() if k != "block1.0.layer.0.weight"},
        "unexpected ['extra.weight']": state | {"extra.weight": torch.zeros(1)},
        "reshaped ['block1.0.layer.0.weight']": state | {"block1.0.layer.0.weight": torch.zeros(4, 1, 1, 1)},
    }
    for i, (expected, bad) in enumerate(variants.items()):
        folder = tmp_path / str(i)
        folder.mkdir()
        torch.save(bad, folder / "xfeat.pt")
        with pytest.raises(deep.WeightsMismatchError) as info:
            deep.load_xfeat(64, weights_dir=folder)
        assert str(info.value).startswith(str(folder / "xfeat.pt")) and expected in str(info.value)
    torch.save(state, tmp_path / "xfeat.pt")  # an exact copy in weights_dir is used first and recorded as such
    record = get_tier("xfeat").weights_record(tmp_path)
    assert record["xfeat.pt"]["source"] == "weights_dir"
    assert record["xfeat.pt"]["sha256"] == deep.file_sha256(tmp_path / "xfeat.pt")


def test_missing_weights_or_torch_name_the_extra_and_nothing_is_written(tmp_path, monkeypatch):
    from synthleak.localize import deep

    scene = ts.write_sequence(tmp_path / "scene" / "room_000", ts.make_room(seed=0), Camera.from_hfov(64, 48, 65.0),
                              ts.walkthrough_poses(8)[:3], query_every=3)
    monkeypatch.setitem(deep.WEIGHTS, "disk", deep.WeightFile("disk-depth-save.pth", "scm-not-installed", "x"))
    with pytest.raises(deep.WeightsNotFoundError) as info:
        build_map(scene, "disk-lightglue", tmp_path / "map", progress=False, weights_dir=tmp_path / "w")
    message = str(info.value)
    assert "[learned]" in message and "scm-not-installed" in message and str(tmp_path / "w") in message
    assert "never downloaded" in message and "--no-deps" in message
    assert not (tmp_path / "map").exists()
    monkeypatch.setitem(sys.modules, "kornia", None)  # import kornia now raises ImportError
    with pytest.raises(deep.MissingDependencyError, match=r"\[learned\]"):
        get_tier("xfeat").make_extractor(64)


def test_no_download_is_ever_attempted(monkeypatch):
    import kornia.core.download
    import torch.hub

    from synthleak.localize import deep

    attempts = []

    def refuse(*args, **kwargs):
        attempts.append(args[:1])
        raise AssertionError("network access attempted")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(urllib.request, "urlopen", refuse)
    monkeypatch.setattr(torch.hub, "download_url_to_file", refuse)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", refuse)
    monkeypatch.setattr(kornia.core.download, "load_state_dict_from_url", refuse)
    monkeypatch.setattr(kornia.core.download, "_download_url_to_file", refuse)
    rgb, _ = ts.render_image(ts.make_room(seed=0), Camera.from_hfov(96, 64, 65.0), ts.walkthrough_poses(8)[0])
    for tier in LEARNED:
        spec = get_tier(tier)
        features = spec.make_extractor(128)(rgb)
        assert len(features) > 10 and features.image_size == (96, 64)
        assert len(spec.make_matcher()(features, features)) > 10  # an image matches itself
    assert attempts == []
    import os

    assert all(os.environ.get(k) == v for k, v in deep.OFFLINE_ENV.items())


# ---------------------------------------------------------------- robustness: a rendered pair of one object


@pytest.fixture(scope="module")
def object_pair(tmp_path_factory) -> dict:
    """The library armchair and its colour variant (magnitude 0.5) in the attacker hall, seen from azimuths 30
    degrees apart at 25 degrees elevation (mitsuba, 320x240, 4 spp): RGB, depth, instances, poses."""
    from synthleak.assets.library import load_library
    from synthleak.config import RenderConfig
    from synthleak.geometry.poses import look_at
    from synthleak.render.pipeline import load_stage
    from synthleak.render.registry import get_renderer
    from synthleak.render.trajectories import orbit_distance
    from synthleak.scene.attacker_env import compose_attacker
    from synthleak.scene.plan import ATTACKER_TARGET_ID, AttackerPlan
    from synthleak.scene.usd_write import write_stage

    out = tmp_path_factory.mktemp("pair")
    library = load_library()
    camera = Camera.from_hfov(320, 240, 65.0)
    views = []
    for k, (magnitude, azimuth) in enumerate([(0.0, 20.0), (0.5, 50.0)]):
        spec = compose_attacker(AttackerPlan("a00_armchair", "armchair", 5, magnitude, ("colour",)), library, seed=3)
        write_stage(spec, out / f"stage_{k}.usda")
        scene = load_stage(out / f"stage_{k}.usda")
        info = scene.instances[ATTACKER_TARGET_ID]
        extents = np.asarray(info.extents)
        centre = np.asarray(info.world_from_object)[:3, 3] + [0.0, 0.0, 0.5 * extents[2]]
        a, e = np.radians(azimuth), np.radians(25.0)
        eye = centre + orbit_distance(extents, 65.0, 0.75, 0.9) * np.array(
            [np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)])
        pose = look_at(eye, centre)
        renderer = get_renderer(RenderConfig(width=320, height=240, spp=4, integrator="direct", filter="box"))
        renderer.prepare(scene)
        frame = renderer.render(camera, pose, 0)
        assert (frame.instance == ATTACKER_TARGET_ID).mean() > 0.1
        views.append((frame, pose))
    assert not np.array_equal(views[0][0].rgb, views[1][0].rgb)
    return {"views": views, "camera": camera, "target": ATTACKER_TARGET_ID}


def verified_on_object(pair: dict, tier: str, max_keypoints: int = 1024, matcher=None) -> tuple[int, int]:
    """(matches whose first keypoint lies on the object and reprojects, through its GT depth and both GT poses,
    within 3 px of its partner; all matches) of ``tier``'s extractor and matcher (or ``matcher``) on the pair."""
    spec = get_tier(tier)
    extractor, matcher = spec.make_extractor(max_keypoints), matcher or spec.make_matcher()
    (f0, pose0), (f1, pose1) = pair["views"]
    a, b = extractor(f0.rgb), extractor(f1.rgb)
    m = matcher(a, b)
    kp0, kp1 = a.keypoints[m[:, 0]], b.keypoints[m[:, 1]]
    pixel = np.floor(kp0).astype(int)
    depth = f0.depth[pixel[:, 1], pixel[:, 0]]
    on_object = f0.instance[pixel[:, 1], pixel[:, 0]] == pair["target"]
    k = pair["camera"].K
    in_cam0 = (np.linalg.inv(k) @ np.c_[kp0, np.ones(len(kp0))].T) * depth
    cam1_from_cam0 = pose1 @ np.linalg.inv(pose0)
    projected = k @ (cam1_from_cam0[:3, :3] @ in_cam0 + cam1_from_cam0[:3, 3:])
    error = np.linalg.norm((projected[:2] / projected[2]).T - kp1, axis=1)
    correct = (error < 3.0) & np.isfinite(depth) & (depth > 0)
    return int((correct & on_object).sum()), len(m)


@pytest.fixture(scope="module")
def sift_verified(object_pair) -> int:
    verified, total = verified_on_object(object_pair, "sift")
    assert verified >= 10 and verified < total  # the check finds SIFT's correct matches and rejects others
    return verified


@pytest.mark.parametrize("tier", LEARNED)
def test_learned_tier_verifies_more_matches_on_a_recoloured_object_than_sift(object_pair, sift_verified, tier):
    matcher = None
    if tier == "xfeat":  # XFeat with plain mutual NN (R2D2+NN): the tier's 0.9 ratio test trades matches for
        from synthleak.localize.matching import match_features  # fewer chance localizations (see tiers.py)

        matcher = lambda a, b: match_features(a, b, 0.0, True)  # noqa: E731
    verified, total = verified_on_object(object_pair, tier, matcher=matcher)
    assert verified > sift_verified, (tier, verified, total, sift_verified)


# ---------------------------------------------------------------- localization


def test_a_learned_matcher_only_sees_the_top_k_retrieved_images(tmp_path):
    camera = Camera.from_hfov(160, 120, 65.0)
    scene = ts.write_sequence(tmp_path / "scene" / "room_000", ts.make_room(seed=0), camera,
                              ts.walkthrough_poses(40)[:8], query_every=4)
    config = LocalizeConfig(max_keypoints=256, pairs_per_image=2, retrieval="exhaustive", top_k=2)
    map_dir = build_map(scene, "xfeat-lighterglue", tmp_path / "map", config, progress=False)
    meta = json.loads((map_dir / "map.json").read_text())
    assert set(meta["weights"]) == {"xfeat.pt", "xfeat-lighterglue.pt"} and meta["keypoint_budget"] == 256
    assert meta["settings"]["weights_sha256"] == {k: v["sha256"] for k, v in meta["weights"].items()}
    assert meta["settings"]["tier_definition"]["match_threshold"] == get_tier("xfeat-lighterglue").match_threshold
    before = (map_dir / "map.json").stat().st_mtime_ns  # the same inputs and tier: the map is reused
    assert build_map(scene, "xfeat-lighterglue", map_dir, config, progress=False) == map_dir
    assert (map_dir / "map.json").stat().st_mtime_ns == before
    loc = Localizer.load(map_dir, config)
    calls = []
    matcher = loc.matcher
    loc.matcher = lambda a, b: calls.append(len(b)) or matcher(a, b)
    from synthleak.core.dataset import load_sequence

    seq = load_sequence(scene)
    result = loc.localize(seq.rgb(seq.query_frames[0]))
    assert len(calls) == 2 < meta["num_images"]
    assert result.success and np.linalg.norm(result.cam_from_world[:3, 3] - seq.cam_from_world[
        seq.query_frames[0]][:3, 3]) < 0.1


def _xfeat_study(source: Path, out: Path) -> Path:
    from synthleak.config import config_from_dict, config_to_dict, load_config
    from synthleak.study import run_study

    data = config_to_dict(load_config("ci-tiny"))
    data["localize"]["tiers"] = ["xfeat"]
    shutil.copytree(source / "dataset", out / "dataset")  # the same renders: only maps, queries, attack run
    run_study(config_from_dict(data, "ci-tiny-xfeat"), out, progress=False)
    return out


@pytest.mark.slow
def test_ci_tiny_with_xfeat_end_to_end_gives_the_same_bytes_twice(ci_tiny_study, tmp_path):
    first = _xfeat_study(ci_tiny_study, tmp_path / "a")
    second = _xfeat_study(ci_tiny_study, tmp_path / "b")
    genuine = json.loads((first / "results" / "genuine_localization.json").read_text())
    assert genuine and all(r["tier"] == "xfeat" and r["localized"] >= 0.9 * r["n"] for r in genuine), genuine
    rows = json.loads((first / "results" / "results.json").read_text())
    assert rows and {r["tier"] for r in rows} == {"xfeat"}
    meta = json.loads(next((first / "maps" / "xfeat").glob("*/map.json")).read_text())
    assert meta["weights"]["xfeat.pt"]["sha256"] == get_tier("xfeat").weights_record()["xfeat.pt"]["sha256"]
    files = sorted(p.relative_to(first) for p in first.rglob("*")
                   if p.is_file() and (p.suffix in (".npz", ".jsonl", ".bin") or p.name == "results.json"))
    assert len([f for f in files if f.suffix == ".npz" and "maps" in f.parts]) >= 6
    assert any(f.suffix == ".jsonl" for f in files)
    for rel in files:
        assert (second / rel).read_bytes() == (first / rel).read_bytes(), rel
