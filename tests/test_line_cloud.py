"""Line-cloud maps (Speciale et al. CVPR 2019): the lift, the p6L LO-RANSAC solver, maps that hold no 3D point,
and localization against them on a ray-cast box room (:mod:`synthleak.localize.testscene`)."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from synthleak.config import ConfigError, LocalizeConfig, config_to_dict, load_config
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at, rotation_error_deg
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.line_cloud import (
    GRID,
    LINE_NOISE_FLOOR_PX,
    LineRansacOptions,
    chance_inlier_probability,
    equivalent_line_threshold,
    estimate_pose_from_lines,
    lift_to_lines,
    line_min_inliers,
    line_residuals_px,
    read_line_map,
)
from synthleak.localize.representations import REPRESENTATIONS
from synthleak.localize.store import MapError
from synthleak.seeding import derive_seed

CAMERA = Camera.from_hfov(320, 240, 65.0)
POINTS = LocalizeConfig(max_keypoints=1024, pairs_per_image=6)
LINES = LocalizeConfig(max_keypoints=1024, pairs_per_image=6, representation="line-cloud")


def synthetic_view(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cam_from_world, world points seen by it, their exact pixels) in a 5 x 4 x 2.6 m room."""
    rng = np.random.default_rng(derive_seed(seed, "synthetic-view"))
    pose = look_at([2.5, -2.0, 1.4], [2.3, 2.0, 1.1])
    pts = rng.uniform([0.0, 0.0, 0.0], [5.0, 4.0, 2.6], (4 * n, 3))
    pc = pts @ pose[:3, :3].T + pose[:3, 3]
    uv = pc[:, :2] / pc[:, 2:3] * [CAMERA.fx, CAMERA.fy] + [CAMERA.cx, CAMERA.cy]
    seen = (pc[:, 2] > 0.3) & np.all((uv > 0) & (uv < [CAMERA.width, CAMERA.height]), axis=1)
    return pose, pts[seen][:n], uv[seen][:n]


def pose_errors(estimate: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    dist = float(np.linalg.norm(camera_centre(estimate) - camera_centre(gt)))
    return dist, rotation_error_deg(estimate[:3, :3], gt[:3, :3])


def as_matrix(est: dict) -> np.ndarray:
    pose = np.eye(4)
    pose[:3] = est["cam_from_world"].matrix()
    return pose


# ---------------------------------------------------------------- the lift and the solver


def test_lift_draws_seeded_unit_lines_through_the_points_without_them():
    _, pts, _ = synthetic_view(200, seed=1)
    d, a = lift_to_lines(pts, seed=7)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-8)
    assert np.abs(np.sum(a * d, axis=1)).max() < 1e-8  # anchors: each line's point nearest the origin
    off_line = np.linalg.norm(np.cross(pts - a, d), axis=1)  # the point lies on its line...
    assert off_line.max() < 1e-8
    assert np.median(np.linalg.norm(pts - a, axis=1)) > 0.3  # ...but the anchor is not the point
    assert np.abs(np.round(a / GRID) - a / GRID).max() < 1e-6 and np.abs(np.round(d / GRID) - d / GRID).max() < 1e-6
    d2, a2 = lift_to_lines(pts, seed=7)
    assert np.array_equal(d, d2) and np.array_equal(a, a2)
    assert not np.allclose(lift_to_lines(pts, seed=8)[0], d)
    # uniform directions: the mean of unit vectors is near zero, each axis' |component| has mean 1/2
    d_many, _ = lift_to_lines(np.zeros((20000, 3)), seed=3)
    assert np.abs(d_many.mean(0)).max() < 0.02
    assert np.allclose(np.abs(d_many).mean(0), 0.5, atol=0.01)


def test_noise_free_pose_is_recovered_to_1e_6():
    gt, pts, uv = synthetic_view(60, seed=2)
    d, a = lift_to_lines(pts, seed=5)
    assert np.abs(line_residuals_px(gt, uv, d, a, CAMERA)[0]).max() < 1e-5  # the convention: x^T l = 0
    est = estimate_pose_from_lines(uv, d, a, CAMERA, LineRansacOptions(max_error_px=2.0), seed=0)
    assert est is not None and est["num_inliers"] == len(uv) and est["inlier_mask"].all()
    assert np.abs(as_matrix(est) - gt).max() < 1e-6


def test_noisy_matches_with_outliers_are_recovered():
    gt, pts, uv = synthetic_view(300, seed=3)
    d, a = lift_to_lines(pts, seed=6)
    rng = np.random.default_rng(derive_seed(3, "noise"))
    kp = uv + rng.normal(0.0, 1.0, uv.shape)
    outliers = rng.random(len(kp)) < 0.4
    kp[outliers] = rng.uniform([0, 0], [CAMERA.width, CAMERA.height], (int(outliers.sum()), 2))
    est = estimate_pose_from_lines(kp, d, a, CAMERA, LineRansacOptions(max_error_px=4.0), seed=0)
    assert est is not None
    dist, angle = pose_errors(as_matrix(est), gt)
    assert dist < 0.03 and angle < 0.3, (dist, angle)
    mask = est["inlier_mask"]
    assert mask[~outliers].mean() > 0.95
    assert mask[outliers].mean() < 0.1  # a line is a weaker constraint than a point: a few outliers pass
    again = estimate_pose_from_lines(kp, d, a, CAMERA, LineRansacOptions(max_error_px=4.0), seed=0)
    assert np.array_equal(as_matrix(again), as_matrix(est))  # seeded


def test_too_few_matches_give_no_pose():
    _, pts, uv = synthetic_view(5, seed=4)
    d, a = lift_to_lines(pts, seed=1)
    assert estimate_pose_from_lines(uv, d, a, CAMERA) is None


# ---------------------------------------------------------------- config


def test_representation_is_a_registered_name_and_left_out_of_keys_at_its_default(tmp_path):
    assert list(REPRESENTATIONS)[:2] == ["points", "line-cloud"]  # (other representations may follow)
    assert LocalizeConfig().representation == "points"
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\n[localize]\nrepresentation = "mesh"\n')
    known = re.escape(", ".join(REPRESENTATIONS))
    with pytest.raises(ConfigError, match=rf"bad\.toml: localize\.representation: unknown name 'mesh' "
                                          rf"\(known: {known}\)"):
        load_config(path)
    path.write_text('extends = "ci-tiny"\n')
    assert "representation" not in config_to_dict(load_config(path))["localize"]
    path.write_text('extends = "ci-tiny"\n[localize]\nrepresentation = "line-cloud"\n')
    assert config_to_dict(load_config(path))["localize"]["representation"] == "line-cloud"


# ---------------------------------------------------------------- maps on a ray-cast room


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("linebox") / "room_000"
    return ts.write_sequence(out, ts.make_room(seed=0), CAMERA, ts.walkthrough_poses(16), query_every=4)


@pytest.fixture(scope="module")
def point_map(scene, tmp_path_factory) -> Path:
    return build_map(scene, "sift", tmp_path_factory.mktemp("pmap") / "sift", POINTS, progress=False)


@pytest.fixture(scope="module")
def line_map(scene, tmp_path_factory) -> Path:
    return build_map(scene, "sift", tmp_path_factory.mktemp("lmap") / "sift", LINES, progress=False)


def stored_triples(map_dir: Path) -> np.ndarray:
    """Every run of 3 consecutive numbers in every file of a map folder (npz arrays flattened, JSON numbers in
    document order, any other file's bytes read as float32 and float64): wherever 3D coordinates could be."""
    runs = []

    def windows(values: np.ndarray) -> None:
        with np.errstate(invalid="ignore", over="ignore"):
            values = np.asarray(values, np.float64).ravel()
        values = values[np.isfinite(values)]
        if values.size >= 3:
            runs.append(np.lib.stride_tricks.sliding_window_view(values, 3))

    def numbers(doc) -> list[float]:
        if isinstance(doc, dict):
            return [x for v in doc.values() for x in numbers(v)]
        if isinstance(doc, list):
            return [x for v in doc for x in numbers(v)]
        return [float(doc)] if isinstance(doc, int | float) and not isinstance(doc, bool) else []

    files = sorted(p for p in map_dir.rglob("*") if p.is_file())
    assert files
    for path in files:
        if path.suffix == ".npz":
            with np.load(path) as data:
                for key in data.files:
                    if np.issubdtype(data[key].dtype, np.number):
                        windows(data[key])
        elif path.suffix == ".json":
            doc = json.loads(path.read_text())
            windows(np.array(numbers(doc)))
            windows(np.array([float(k) for k in _keys(doc) if _is_number(k)]))
        else:
            raw = path.read_bytes()
            for dtype in (np.float32, np.float64):
                size = np.dtype(dtype).itemsize
                for offset in range(size):
                    chunk = raw[offset:len(raw) - (len(raw) - offset) % size]
                    windows(np.frombuffer(chunk, dtype))
    return np.concatenate(runs)


def _keys(doc) -> list[str]:
    if isinstance(doc, dict):
        return [*doc, *(k for v in doc.values() for k in _keys(v))]
    if isinstance(doc, list):
        return [k for v in doc for k in _keys(v)]
    return []


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def leaked_fraction(map_dir: Path, points: np.ndarray, radius: float = 0.01) -> float:
    """Fraction of ``points`` within ``radius`` of a triple stored in the map folder."""
    dist, _ = cKDTree(stored_triples(map_dir)).query(points, distance_upper_bound=radius)
    return float(np.isfinite(dist).mean())


def test_line_map_stores_lines_through_the_points_and_no_point(point_map, line_map):
    with np.load(point_map / "points.npz") as data:
        xyz = data["xyz"]
    assert len(xyz) > 300
    meta = json.loads((line_map / "map.json").read_text())
    assert meta["settings"]["representation"] == "line-cloud"
    assert "representation" not in json.loads((point_map / "map.json").read_text())["settings"]
    assert not (line_map / "points.npz").exists() and not (line_map / "sfm").exists()
    lines = read_line_map(line_map).lines
    assert len(lines) == len(xyz) == meta["num_points"]
    # the same triangulation, lifted: each point lies on its line (the 1e-9 grid), at a random place along it
    assert np.linalg.norm(np.cross(xyz - lines.anchors, lines.directions), axis=1).max() < 1e-6
    assert leaked_fraction(point_map, xyz) > 0.99  # the detector finds the points of a point map...
    assert leaked_fraction(line_map, xyz) < 0.01  # ...and (almost) none in a line map


def test_servers_refuse_a_map_of_another_representation(point_map, line_map):
    with pytest.raises(MapError, match=r"map\.json: built with \[localize\] representation = 'line-cloud', but "
                                       r"this server's config has representation = 'points'"):
        Localizer.load(line_map, POINTS)
    with pytest.raises(MapError, match="built with \\[localize\\] representation = 'points'"):
        Localizer.load(point_map, LINES)


def assert_localizes_like_the_point_map(scene: Path, point_map: Path, other_map: Path,
                                        other: LocalizeConfig) -> None:
    """Every genuine query of ``scene`` localizes on both maps (inlier counts summing to the inliers), the other
    map's median pose errors within 3x the point map's (2 cm, 0.3° floors) and under 5 cm, 1°."""
    seq = load_sequence(scene)
    servers = {"points": Localizer.load(point_map, POINTS), "other": Localizer.load(other_map, other)}
    errors: dict[str, list[tuple[float, float]]] = {"points": [], "other": []}
    for frame in seq.query_frames:
        query = servers["points"].extractor(seq.rgb(frame))
        gt = seq.cam_from_world[frame]
        for name, loc in servers.items():
            result = loc.localize_features(query)
            assert result.success, (name, frame, result.num_inliers, result.num_matches)
            assert result.num_inliers >= loc.min_inliers
            assert sum(result.inlier_instance_counts.values()) == result.num_inliers
            errors[name].append(pose_errors(result.cam_from_world, gt))
    p_dist, p_angle = np.median(np.array(errors["points"]), axis=0)
    l_dist, l_angle = np.median(np.array(errors["other"]), axis=0)
    assert l_dist < max(3 * p_dist, 0.02) and l_angle < max(3 * p_angle, 0.3), (l_dist, l_angle, p_dist, p_angle)
    assert l_dist < 0.05 and l_angle < 1.0


def test_line_map_localizes_like_the_point_map(scene, point_map, line_map):
    assert_localizes_like_the_point_map(scene, point_map, line_map, LINES)


@pytest.fixture(scope="module")
def other_room(tmp_path_factory) -> Path:
    """Eight views of another box room: every match to the fixture's maps is wrong."""
    return ts.write_sequence(tmp_path_factory.mktemp("other") / "room_other", ts.make_room(seed=11), CAMERA,
                             ts.walkthrough_poses(8), query_every=1)


def test_line_server_rejects_another_room_as_the_point_server_does(line_map, point_map, other_room):
    """At the point server's 12 px a keypoint near any image line is an inlier, and a line cloud localized every
    view of another room; at the equivalent threshold (:func:`equivalent_line_threshold`) and the equivalent
    success count (:func:`line_min_inliers`) it rejects them too."""
    seq = load_sequence(other_room)
    points, lines = Localizer.load(point_map, POINTS), Localizer.load(line_map, LINES)
    assert equivalent_line_threshold(12.0, CAMERA) == pytest.approx(LINE_NOISE_FLOOR_PX)
    for frame in seq.frames:
        query = points.extractor(seq.rgb(frame))
        for name, loc in (("points", points), ("lines", lines)):
            result = loc.localize_features(query)
            assert not result.success, (name, frame, result.num_inliers, result.num_matches)


def test_line_min_inliers_matches_the_point_servers_chance_rate():
    """The chance model of :func:`line_min_inliers`: a band is likelier to catch a stray keypoint than the disc,
    so a line server needs more inliers, more so with more matches; never fewer than the point server's."""
    p_point = chance_inlier_probability(12.0, CAMERA, lines=False)
    p_line = chance_inlier_probability(2.0, CAMERA, lines=True)
    assert p_point == pytest.approx(np.pi * 144 / (320 * 240)) and p_line > 3 * p_point
    counts = [line_min_inliers(n, 15, 12.0, 2.0, CAMERA) for n in (15, 40, 150, 900)]
    assert counts[0] == 16  # 15 of 15 matches: the point server's chance rate is out of a line server's reach
    assert 15 < counts[1] < counts[2] < counts[3] <= 900
    assert line_min_inliers(10, 15, 12.0, 2.0, CAMERA) == 15  # too few matches for either server
    # a band as selective as the disc and as many trials: 3 more, for the 3 more free inliers of a 6-line sample
    assert line_min_inliers(150, 15, 12.0, np.pi * 12.0 ** 2 / (2 * 400.0), CAMERA, line_trials=10_000) == 18


def test_line_server_accepts_no_more_wrong_room_views_than_the_point_server(line_map, point_map, other_room):
    """At a success count low enough for chance inliers (the most the point server finds on a view of another
    room, so it accepts at least one), the line server at its equivalent count (:func:`line_min_inliers`) accepts
    at most as many of those views as the point server; at the point server's own count it would accept more:
    a 2 px band catches more stray keypoints than a 12 px disc."""
    seq = load_sequence(other_room)
    points = Localizer.load(point_map, POINTS)
    queries = [points.extractor(seq.rgb(frame)) for frame in seq.frames[:4]]
    point_inliers = np.array([points.localize_features(q).num_inliers for q in queries])
    low = int(point_inliers.max())
    assert 4 <= low < points.min_inliers, point_inliers
    lines = Localizer.load(line_map, replace(LINES, min_inliers=low))
    results = [lines.localize_features(q) for q in queries]
    line_inliers = np.array([r.num_inliers for r in results])
    accepted = {"points": int(np.sum(point_inliers >= low)), "lines": sum(r.success for r in results),
                "lines at the point count": int(np.sum(line_inliers >= low))}
    assert accepted["points"] >= 1, accepted
    assert accepted["lines"] <= accepted["points"], (accepted, point_inliers, line_inliers)
    assert accepted["lines at the point count"] > accepted["points"], (accepted, point_inliers, line_inliers)
    for r in results:  # the rule applied: the equivalent count for each view's number of matches
        assert r.success == (r.num_inliers >= line_min_inliers(r.num_matches, low, 12.0, 2.0, CAMERA))


def test_line_server_takes_the_query_lens(scene, line_map):
    """A query whose keypoints went through a lens (k1 = -0.15) and that says so (an ``OPENCV`` camera) localizes
    on a line cloud as well as the pinhole query; the same keypoints said to be pinhole do not."""
    from dataclasses import asdict

    from synthleak.core.dataset import OpenCVCamera
    from synthleak.localize.features import Features
    from synthleak.render.distortion import distort_normalized

    seq = load_sequence(scene)
    lines = Localizer.load(line_map, LINES)
    lens = OpenCVCamera(**asdict(CAMERA), k1=-0.15)
    frame = seq.query_frames[0]
    query = lines.extractor(seq.rgb(frame))
    x, y = distort_normalized((query.keypoints[:, 0] - CAMERA.cx) / CAMERA.fx,
                              (query.keypoints[:, 1] - CAMERA.cy) / CAMERA.fy, lens.dist_coeffs)
    distorted = Features(np.stack([x * CAMERA.fx + CAMERA.cx, y * CAMERA.fy + CAMERA.cy], axis=1).astype(
        query.keypoints.dtype), query.descriptors)
    gt = seq.cam_from_world[frame]
    with_lens = lines.localize_features(distorted, lens)
    assert with_lens.success
    dist, angle = pose_errors(with_lens.cam_from_world, gt)
    assert dist < 0.05 and angle < 1.0, (dist, angle)
    ignored = lines.localize_features(distorted, CAMERA)
    assert not ignored.success or pose_errors(ignored.cam_from_world, gt)[0] > 2 * dist
