"""Paired-point maps (Lee et al. CVPR 2023): the seeded pairing, lines through both points of a pair, maps that
hold no 3D point, and localization against them on a ray-cast box room (:mod:`synthleak.localize.testscene`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import ConfigError, LocalizeConfig, config_to_dict, load_config
from synthleak.core.dataset import load_sequence
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.paired_points import (
    MIN_PAIR_DISTANCE_M,
    PAIRED_LINES_FILE,
    PairedLines,
    lift_pairs,
    pair_points,
    pair_seed,
    read_paired_point_map,
    write_paired_lines,
)
from synthleak.localize.representations import REPRESENTATIONS
from synthleak.localize.store import MapError
from synthleak.seeding import derive_seed
from test_line_cloud import CAMERA, POINTS, assert_localizes_like_the_point_map, leaked_fraction

PAIRED = LocalizeConfig(max_keypoints=1024, pairs_per_image=6, representation="paired-point")
LINES = LocalizeConfig(max_keypoints=1024, pairs_per_image=6, representation="line-cloud")


def off_line(points: np.ndarray, directions: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Distance of each point to its line."""
    return np.linalg.norm(np.cross(points - anchors, directions), axis=1)


def clustered_points(clusters: int, per_cluster: int, seed: int) -> np.ndarray:
    """Points in tight (5 cm) clusters across a 5 x 4 x 2.6 m room: random pairs often fall in one cluster."""
    rng = np.random.default_rng(derive_seed(seed, "clusters"))
    centres = rng.uniform([0.0, 0.0, 0.0], [5.0, 4.0, 2.6], (clusters, 3))
    return (centres[:, None] + rng.uniform(-0.025, 0.025, (clusters, per_cluster, 3))).reshape(-1, 3)


# ---------------------------------------------------------------- the pairing and the lift


def test_pairing_is_seeded_disjoint_and_keeps_pairs_apart():
    pts = clustered_points(40, 10, seed=1)[:-1]  # 399 points: one left over
    pairs, single = pair_points(pts, seed=3)
    assert pairs.shape == (199, 2) and single is not None
    assert np.array_equal(np.sort(np.append(pairs.ravel(), single)), np.arange(len(pts)))  # each point once
    dist = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    assert dist.min() >= MIN_PAIR_DISTANCE_M
    naive, _ = pair_points(pts, seed=3, min_distance=0.0)  # the plain random pairing has close pairs here
    assert (np.linalg.norm(pts[naive[:, 0]] - pts[naive[:, 1]], axis=1) < MIN_PAIR_DISTANCE_M).sum() >= 2
    again, single_again = pair_points(pts, seed=3)
    assert np.array_equal(again, pairs) and single_again == single
    assert not np.array_equal(pair_points(pts, seed=4)[0], pairs)
    one_cluster = clustered_points(1, 10, seed=2)  # no pair can be far apart: kept as they are, each point once
    close, none = pair_points(one_cluster, seed=0)
    assert none is None and np.array_equal(np.sort(close.ravel()), np.arange(10))


def test_each_line_passes_through_both_points_of_its_pair_and_an_odd_point_gets_its_own():
    pts = clustered_points(30, 7, seed=5)  # 210 points
    pts = pts[:-1]  # 209: 104 pairs and one single
    lines = lift_pairs(pts, seed=11)
    assert len(lines) == 105 and lines.line.shape == (209,)
    assert np.array_equal(np.bincount(lines.line), [2] * 104 + [1])
    d, a = lines.directions[lines.line], lines.anchors[lines.line]
    assert np.allclose(np.linalg.norm(lines.directions, axis=1), 1.0, atol=1e-8)
    assert off_line(pts, d, a).max() < 1e-8  # both points of every pair on their line (a 1e-9 grid, |X| < 7 m)
    assert np.abs(np.sum(lines.anchors * lines.directions, axis=1)).max() < 1e-8  # anchors: nearest the origin
    assert np.median(np.linalg.norm(pts - a, axis=1)) > 0.3  # the anchor is not the point
    again = lift_pairs(pts, seed=11)
    assert all(np.array_equal(x, y) for x, y in zip((lines.directions, lines.anchors, lines.line),
                                                     (again.directions, again.anchors, again.line), strict=True))


def test_paired_point_is_a_registered_representation(tmp_path):
    assert "paired-point" in REPRESENTATIONS
    path = tmp_path / "c.toml"
    path.write_text('extends = "ci-tiny"\n[localize]\nrepresentation = ["points", "paired-point"]\n')
    assert config_to_dict(load_config(path))["localize"]["representation"] == ["points", "paired-point"]
    path.write_text('extends = "ci-tiny"\n[localize]\nrepresentation = "paired-points"\n')
    with pytest.raises(ConfigError, match=r"unknown name 'paired-points' \(known: .*paired-point"):
        load_config(path)


# ---------------------------------------------------------------- maps on a ray-cast room


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("pairbox") / "room_000"
    return ts.write_sequence(out, ts.make_room(seed=0), CAMERA, ts.walkthrough_poses(16), query_every=4)


@pytest.fixture(scope="module")
def point_map(scene, tmp_path_factory) -> Path:
    return build_map(scene, "sift", tmp_path_factory.mktemp("pmap") / "sift", POINTS, progress=False)


@pytest.fixture(scope="module")
def paired_map(scene, tmp_path_factory) -> Path:
    return build_map(scene, "sift", tmp_path_factory.mktemp("ppmap") / "sift", PAIRED, progress=False)


def test_paired_map_stores_lines_through_both_points_and_no_point(point_map, paired_map):
    with np.load(point_map / "points.npz") as data:
        xyz, instance = data["xyz"], data["instance"]
    assert len(xyz) > 300
    meta = json.loads((paired_map / "map.json").read_text())
    assert meta["settings"]["representation"] == "paired-point"
    assert not (paired_map / "points.npz").exists() and not (paired_map / "sfm").exists()
    assert not (paired_map / "lines.npz").exists()
    with np.load(paired_map / PAIRED_LINES_FILE) as data:
        assert len(data["directions"]) == (len(xyz) + 1) // 2  # each line once
        assert {k: data[k].shape for k in ("line", "instance", "track_length")} == {
            k: (len(xyz),) for k in ("line", "instance", "track_length")}
    data = read_paired_point_map(paired_map)
    assert len(data.lines) == len(xyz) == meta["num_points"] and len(data.xyz) == 0
    assert np.array_equal(data.instance, instance)  # each slot keeps its own point's label
    # the same triangulation, paired: both points of each line lie on it (the 1e-9 grid)
    assert off_line(xyz, data.lines.directions, data.lines.anchors).max() < 1e-8
    assert leaked_fraction(point_map, xyz) > 0.99  # the detector finds the points of a point map...
    assert leaked_fraction(paired_map, xyz) < 0.01  # ...and (almost) none in a paired-point map


def test_paired_lines_are_the_same_bytes_for_the_same_map_content(point_map, paired_map, tmp_path):
    """The lines are seeded from the map's tier and inputs: lifting the same points again gives the same file."""
    with np.load(point_map / "points.npz") as data:
        xyz, instance, track = data["xyz"], data["instance"], data["track_length"]
    digest = json.loads((paired_map / "map.json").read_text())["inputs_sha256"]
    write_paired_lines(tmp_path / "again.npz", lift_pairs(xyz, pair_seed("sift", digest)), instance, track)
    assert (tmp_path / "again.npz").read_bytes() == (paired_map / PAIRED_LINES_FILE).read_bytes()
    write_paired_lines(tmp_path / "other.npz", lift_pairs(xyz, pair_seed("sift", "0" * 64)), instance, track)
    assert (tmp_path / "other.npz").read_bytes() != (paired_map / PAIRED_LINES_FILE).read_bytes()


def test_servers_refuse_a_map_of_another_representation_paired(point_map, paired_map):
    with pytest.raises(MapError, match=r"built with \[localize\] representation = 'paired-point', but this "
                                       r"server's config has representation = 'line-cloud'"):
        Localizer.load(paired_map, LINES)
    with pytest.raises(MapError, match="built with \\[localize\\] representation = 'points'"):
        Localizer.load(point_map, PAIRED)


def test_paired_map_localizes_like_the_point_map(scene, point_map, paired_map):
    assert_localizes_like_the_point_map(scene, point_map, paired_map, PAIRED)


def test_the_two_points_of_a_line_keep_their_own_instance_in_the_counts(scene, paired_map, tmp_path):
    """Relabel the map so one point of each line (a seeded coin picks which) is instance 1 and the other instance
    2: a localization's inlier counts hold both, about evenly (a label per line would hold one)."""
    relabelled = shutil.copytree(paired_map, tmp_path / "sift")
    with np.load(paired_map / PAIRED_LINES_FILE) as data:
        d, m, line, track = data["directions"], data["moments"], data["line"], data["track_length"]
    first = np.full(len(d), len(line))
    np.minimum.at(first, line, np.arange(len(line)))
    coin = np.random.default_rng(derive_seed(0, "relabel")).random(len(d)) < 0.5
    labels = np.where((np.arange(len(line)) == first[line]) ^ coin[line], 1, 2)
    write_paired_lines(relabelled / PAIRED_LINES_FILE, PairedLines(d, np.cross(d, m), line), labels, track)
    seq = load_sequence(scene)
    loc = Localizer.load(relabelled, PAIRED)
    for frame in seq.query_frames[:2]:
        result = loc.localize_features(loc.extractor(seq.rgb(frame)))
        assert result.success
        counts = result.inlier_instance_counts
        assert set(counts) == {1, 2} and min(counts.values()) >= 0.25 * result.num_inliers, counts
        assert sum(counts.values()) == result.num_inliers
