"""Retrieval: the vocabulary-tree bag of words finds the map images a query was taken next to (float and
binary descriptors), the map records its retrieval parameters and what each map image sees, and on ci-tiny
the default retrieval localizes nearly every attacker query that exhaustive matching localizes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.features import Features
from synthleak.localize.retrieval import BowIndex, BowParams
from synthleak.localize.visibility import read_image_instances, retrieved_sees, visible_instances

CAMERA = Camera.from_hfov(320, 240, 65.0)
CONFIG = LocalizeConfig(max_keypoints=1024, pairs_per_image=5, retrieval="bow", top_k=3)


@pytest.fixture(scope="module")
def quads() -> list[ts.Quad]:
    return ts.make_room(seed=0)


@pytest.fixture(scope="module")
def scene(quads, tmp_path_factory) -> Path:
    """30 walk-through frames around the box room; every 5th (2, 7, ...) held out as a query."""
    return ts.write_sequence(tmp_path_factory.mktemp("box") / "room_000", quads, CAMERA, ts.walkthrough_poses(30),
                             query_every=5)


@pytest.fixture(scope="module", params=["sift", "orb"])
def box_map(request, scene, tmp_path_factory) -> tuple[str, Path]:
    tier = request.param
    return tier, build_map(scene, tier, tmp_path_factory.mktemp("map") / tier, CONFIG, progress=False)


def nearest_map_images(names: list[str], seq, frame: str, n: int = 2) -> set[str]:
    """The ``n`` map images whose camera centres are closest to the query's (on the walk-through loop: the
    frames just before and after it)."""
    centre = camera_centre(seq.cam_from_world[frame])
    return set(sorted(names, key=lambda m: float(np.linalg.norm(camera_centre(seq.cam_from_world[m]) - centre)))[:n])


def test_top_k_holds_the_map_image_the_query_was_taken_next_to(scene, box_map):
    tier, map_dir = box_map
    seq = load_sequence(scene)
    loc = Localizer.load(map_dir, CONFIG)
    assert loc.data.features[0].binary == (tier == "orb")
    for frame in seq.query_frames:
        query = loc.extractor(seq.rgb(frame))
        retrieved = [loc.data.names[i] for i in loc.candidates(query)]
        assert len(retrieved) == CONFIG.top_k
        assert nearest_map_images(loc.data.names, seq, frame) & set(retrieved), (tier, frame, retrieved)
        result = loc.localize_features(query)
        assert result.retrieved == sorted(retrieved)  # the result names what it matched against


@pytest.mark.parametrize("box_map", ["sift"], indirect=True)
def test_a_close_up_retrieves_a_map_image_that_sees_the_object(quads, scene, box_map):
    """An attacker-like query (one box filling the view) retrieves a map image where that box is visible.
    SIFT only: a bag of ORB's bits ranks the first image seeing one of the boxes 6th of 24 here (k-means on 0/1
    bits makes poor words; docs/retrieval.md), so ORB's top 3 misses it."""
    tier, map_dir = box_map
    visible = read_image_instances(map_dir)
    loc = Localizer.load(map_dir, CONFIG)
    for box in (100, 101):
        corners = np.array([c for q in quads if q.instance_id == box
                            for c in (q.origin, q.origin + q.size_u * q.u + q.size_v * q.v)])
        centre = corners.mean(0)
        to_room = np.array([2.5, 2.0, 1.4]) - centre
        to_room[2] = 0.0
        eye = centre + 1.0 * to_room / np.linalg.norm(to_room) + [0.0, 0.0, 0.5]
        rgb, mask = ts.render_image(quads, CAMERA, look_at(eye, centre))
        assert (mask == box).mean() > 0.3
        seen_by = {n for n, ids in visible.items() if box in ids}
        assert seen_by and seen_by != set(visible)  # the box is seen by some map images, not all
        result = loc.localize(rgb)
        assert retrieved_sees(result.retrieved, box, visible), (tier, box, result.retrieved)


def test_map_records_retrieval_parameters_and_visible_instances(scene, box_map):
    tier, map_dir = box_map
    meta = json.loads((map_dir / "map.json").read_text())
    params = BowParams(branching=CONFIG.bow_branching, depth=CONFIG.bow_depth)
    assert meta["retrieval"] == {"method": "bow", "top_k": 3, "bow": params.to_json()}
    assert meta["retrieval"]["bow"]["num_words"] == CONFIG.bow_branching ** CONFIG.bow_depth
    with np.load(map_dir / "bow.npz") as arrays:
        assert BowIndex.from_arrays(arrays).params == params
    # A query-time change (top k, method) is recorded without rebuilding the map.
    before = (map_dir / "features.npz").stat().st_mtime_ns
    other = LocalizeConfig(**{**CONFIG.__dict__, "top_k": 20, "retrieval": "exhaustive"})
    build_map(scene, tier, map_dir, other, progress=False)
    assert (map_dir / "features.npz").stat().st_mtime_ns == before
    assert json.loads((map_dir / "map.json").read_text())["retrieval"]["top_k"] == 20
    build_map(scene, tier, map_dir, CONFIG, progress=False)
    # image_instances.json: the instances covering >= 0.5 % of each map image's GT mask.
    seq = load_sequence(scene)
    doc = json.loads((map_dir / "image_instances.json").read_text())
    assert doc["min_fraction"] == 0.005 and doc["min_pixels"] == int(np.ceil(0.005 * 320 * 240))
    assert list(doc["images"]) == seq.map_frames
    for name in seq.map_frames[::7]:
        mask = np.asarray(Image.open(seq.instance_path(name))).astype(np.int64)
        ids, counts = np.unique(mask, return_counts=True)
        expected = {str(i): int(c) for i, c in zip(ids, counts, strict=True) if i and c >= doc["min_pixels"]}
        assert doc["images"][name] == expected and expected


def test_visible_instances_threshold():
    mask = np.zeros((100, 100), np.int64)
    mask[:10, :5] = 7   # 50 px = 0.5 %: visible
    mask[50, :49] = 8   # 49 px: not
    mask[60:, :] = 3
    assert visible_instances(mask) == {3: 4000, 7: 50}


@pytest.mark.parametrize("dim", [64, 128, 256])
def test_learned_float_descriptors_of_any_dimension(dim):
    """Images made of recurring local patterns (descriptor = pattern + noise); a query showing part of image 3's
    patterns, with fresh noise, ranks image 3 first."""
    rng = np.random.default_rng(dim)

    def unit(x: np.ndarray) -> np.ndarray:
        return (x / np.linalg.norm(x, axis=-1, keepdims=True)).astype(np.float32)

    patterns = unit(rng.normal(size=(400, dim)))
    noise = 0.15 / np.sqrt(dim)  # about 15 % of a descriptor's norm
    members = [rng.choice(len(patterns), 150, replace=False) for _ in range(12)]
    images = [Features(rng.uniform(0, 300, (150, 2)), unit(patterns[m] + noise * rng.normal(size=(150, dim))))
              for m in members]
    query = Features(np.zeros((60, 2)), unit(patterns[members[3][:60]] + noise * rng.normal(size=(60, dim))))
    for scoring in ("l1", "l2"):
        index = BowIndex.build(images, BowParams(branching=16, depth=2, scoring=scoring))
        assert index.query(query, 1)[0] == 3
        again = BowIndex.from_arrays(index.to_arrays())
        np.testing.assert_array_equal(again.scores(query), index.scores(query))
    # Deterministic: the same map gives the same index, byte for byte.
    a, b = BowIndex.build(images, BowParams(8, 2)).to_arrays(), BowIndex.build(images, BowParams(8, 2)).to_arrays()
    assert all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("binary", [False, True])
def test_kmeans_pp_seeding_is_scipys_draw_for_draw(binary):
    """The O(n k) seeding picks the rows scipy's ``kmeans2(minit="++")`` picks, leaves the generator in the
    same state, and the trained centres are scipy's on the portable grid (``CENTRE_STEP``), byte for byte."""
    import warnings

    from scipy.cluster.vq import kmeans2

    from synthleak.localize.retrieval import CENTRE_STEP, _kmeans
    from synthleak.portable import snap

    data = np.random.default_rng(5).random((3000, 256 if binary else 128)).astype(np.float32)
    if binary:
        data = (data > 0.5).astype(np.float32)  # ORB/AKAZE descriptors are clustered as 0/1 bits
    ours, theirs = np.random.default_rng(11), np.random.default_rng(11)
    centres = _kmeans(data, 32, 10, ours)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected, _ = kmeans2(data.astype(np.float64), 32, iter=10, minit="++", rng=theirs)
    np.testing.assert_array_equal(centres, snap(expected, CENTRE_STEP).astype(np.float32))
    assert ours.uniform() == theirs.uniform()


def test_bad_bow_parameters_are_named():
    with pytest.raises(ValueError, match="scoring"):
        BowParams(scoring="cosine")
    with pytest.raises(ValueError, match="branching"):
        BowParams(branching=1)


def test_ci_tiny_retrieval_keeps_the_exhaustive_localizations(ci_tiny_study):
    """The study's own retrieval (ci-tiny's default) against exhaustive matching on the same maps and the same
    cached query features: at least 75 % of the attacker queries exhaustive matching localizes still localize
    (measured: 18 of 23 since the attacker photographs each object in its own setting, issue 30; 18 of 19 in the
    one inventory hall before: the retrieval's recall is worth a look, docs/retrieval.md)."""
    from synthleak.config import load_config
    from synthleak.core.dataset import load_sequence
    from synthleak.study import load_features, read_query_log

    config = load_config("ci-tiny")
    assert config.localize.retrieval != "exhaustive"
    exhaustive_config = LocalizeConfig(**{**config.localize.__dict__, "retrieval": "exhaustive"})
    both = exhaustive = retrieval = 0
    for tier in config.localize.tiers:
        for map_dir in sorted((ci_tiny_study / "maps" / tier).iterdir()):
            meta = json.loads((map_dir / "map.json").read_text())
            assert meta["retrieval"]["method"] == config.localize.retrieval
            loc = Localizer.load(map_dir, exhaustive_config)
            assert len(loc.data.names) > config.localize.top_k  # the retrieval leaves map images out
            for q in read_query_log(ci_tiny_study / "queries" / tier / map_dir.name / "queries.jsonl"):
                if q["genuine"]:
                    continue
                assert len(q["retrieved"]) == config.localize.top_k
                features, _ = load_features(ci_tiny_study / "features" / tier / q["sequence"] / f"{q['frame']}.npz")
                camera = load_sequence(ci_tiny_study / "dataset" / q["sequence"]).camera
                full = loc.localize_features(features, camera).success
                exhaustive += full
                retrieval += q["success"]
                both += full and q["success"]
    assert exhaustive >= 10, exhaustive  # enough localized attacker queries for the ratio to mean something
    assert both >= 0.75 * exhaustive, (both, retrieval, exhaustive)


def test_ci_tiny_funnel_counts_queries_whose_retrieval_sees_the_object(ci_tiny_study):
    """The study's results and report carry the funnel step, recomputed here from the query log and the GT masks
    of the map images (``image_instances.json``)."""
    from synthleak.core.dataset import read_index
    from synthleak.study import read_query_log

    index = read_index(ci_tiny_study / "dataset" / "stages")
    rows = [r for r in json.loads((ci_tiny_study / "results" / "results.json").read_text())
            if r["present_gt"] and r.get("magnitude") is None]
    assert rows
    for r in rows:
        map_dir = ci_tiny_study / "maps" / r["tier"] / r["room"]
        visible = read_image_instances(map_dir)
        gt_id = next(o for o in index["attacker_objects"] if o["id"] == r["object"])["present_in"][r["room"]]
        log = [q for q in read_query_log(ci_tiny_study / "queries" / r["tier"] / r["room"] / "queries.jsonl")
               if not q["genuine"] and q["attacker_object"] == r["object"]]
        assert r["n_retrieved_target"] == sum(retrieved_sees(q["retrieved"], gt_id, visible) for q in log)
        assert r["n_localized"] <= r["n_queries"] == len(log)
    assert sum(r["n_retrieved_target"] for r in rows) > 0
    report = (ci_tiny_study / "report.md").read_text()
    assert "retrieved images see the object" in report
