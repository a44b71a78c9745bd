"""Two-view verification (:mod:`synthleak.localize.two_view`): the essential-matrix check per (query, map image)
pair, on exact synthetic views and on a ray-cast box room's point and line maps."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import ConfigError, LocalizeConfig, config_to_dict, load_config
from synthleak.core.dataset import load_sequence, pycolmap_camera
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at, rotation_error_deg
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.line_cloud import equivalent_line_threshold, line_min_inliers
from synthleak.localize.two_view import essential_inliers
from synthleak.seeding import derive_seed

CAMERA = Camera.from_hfov(320, 240, 65.0)
BASE = dict(max_keypoints=1024, pairs_per_image=6)
VERIFIED = 15  # COLMAP's two-view min_num_inliers


def project(pose: np.ndarray, pts: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    pc = pts @ pose[:3, :3].T + pose[:3, 3]
    uv = pc[:, :2] / pc[:, 2:3] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    return uv, (pc[:, 2] > 0.3) & np.all((uv > 0) & (uv < [camera.width, camera.height]), axis=1)


def two_exact_views(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two views 0.6 m apart of 3000 random points in a room: both views' pixels of every point, and the
    indices of the points both see."""
    a = look_at([2.5, -2.0, 1.4], [2.3, 2.0, 1.1])
    b = look_at([3.1, -1.8, 1.5], [2.0, 2.0, 1.0])
    pts = rng.uniform([0.0, 0.0, 0.0], [5.0, 4.0, 2.6], (3000, 3))
    uv_a, seen_a = project(a, pts, CAMERA)
    uv_b, seen_b = project(b, pts, CAMERA)
    return uv_a, uv_b, np.nonzero(seen_a & seen_b)[0]


def test_essential_inliers_are_the_true_matches_of_two_exact_views():
    """Two views 0.6 m apart of points in a room, 40 % of the matches replaced by random pixels: the true matches
    (0.5 px noise) are inliers at 4 px, and almost no random one is (a random pixel lies in the 8 px wide band
    around its epipolar line with probability about 2 %)."""
    rng = np.random.default_rng(derive_seed(0, "two-view-test"))
    uv_a, uv_b, seen = two_exact_views(rng)
    seen = seen[:300]
    uv_a, uv_b = uv_a[seen] + rng.normal(0, 0.5, (len(seen), 2)), uv_b[seen] + rng.normal(0, 0.5, (len(seen), 2))
    wrong = rng.random(len(seen)) < 0.4
    uv_b[wrong] = rng.uniform([0, 0], [CAMERA.width, CAMERA.height], (int(wrong.sum()), 2))
    cam = pycolmap_camera(CAMERA)
    mask = essential_inliers(uv_a, uv_b, cam, cam, 4.0)
    assert mask[~wrong].mean() > 0.98, mask[~wrong].mean()
    assert mask[wrong].mean() < 0.08, mask[wrong].mean()
    assert np.array_equal(mask, essential_inliers(uv_a, uv_b, cam, cam, 4.0))  # seeded: the same mask
    assert not essential_inliers(uv_a[:4], uv_b[:4], cam, cam, 4.0).any()  # under the 5-point sample: none


def test_the_trial_cap_from_min_inliers_keeps_every_decision():
    """``min_inliers`` caps RANSAC's trials at what finds a model with that many inliers at 0.999 confidence:
    on pairs of 15 to 60 matches, some with 15 or more true ones and some all chance, each pair's verdict (at
    least 15 inliers or not) is the uncapped one, and a pair kept keeps nearly the same inliers."""
    rng = np.random.default_rng(derive_seed(0, "two-view-cap-test"))
    uv_a, uv_b, seen = two_exact_views(rng)
    cam = pycolmap_camera(CAMERA)
    verdicts = []
    for trial in range(40):
        n, true = int(rng.integers(15, 61)), int(rng.integers(0, 2)) * int(rng.integers(VERIFIED + 2, 31))
        pick = rng.choice(seen, n, replace=False)
        qa = uv_a[pick] + rng.normal(0, 0.5, (n, 2))
        qb = uv_b[pick] + rng.normal(0, 0.5, (n, 2))
        qb[min(true, n):] = rng.uniform([0, 0], [CAMERA.width, CAMERA.height], (n - min(true, n), 2))
        full = essential_inliers(qa, qb, cam, cam, 4.0, seed=trial)
        capped = essential_inliers(qa, qb, cam, cam, 4.0, seed=trial, min_inliers=VERIFIED)
        assert (full.sum() >= VERIFIED) == (capped.sum() >= VERIFIED), (n, true, full.sum(), capped.sum())
        if full.sum() >= VERIFIED:
            assert (full == capped).mean() > 0.9
        verdicts.append(full.sum() >= VERIFIED)
    assert 5 < sum(verdicts) < 35  # both verdicts were tested


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("twoview") / "room_000"
    return ts.write_sequence(out, ts.make_room(seed=0), CAMERA, ts.walkthrough_poses(16), query_every=4)


@pytest.fixture(scope="module")
def other_room(tmp_path_factory) -> Path:
    return ts.write_sequence(tmp_path_factory.mktemp("twoview-other") / "room_other", ts.make_room(seed=11), CAMERA,
                             ts.walkthrough_poses(6), query_every=1)


@pytest.fixture(scope="module", params=["points", "line-cloud"])
def servers(request, scene, tmp_path_factory) -> tuple[Localizer, Localizer]:
    """(unverified, verified) servers over one map of ``scene`` (the map does not depend on the check)."""
    config = LocalizeConfig(**BASE, representation=request.param)
    map_dir = build_map(scene, "sift", tmp_path_factory.mktemp(request.param) / "sift", config, progress=False)
    return Localizer.load(map_dir, config), Localizer.load(map_dir, replace(config, two_view_min_inliers=VERIFIED))


def test_verified_servers_localize_genuine_queries_as_the_unverified_ones(scene, servers):
    """The check keeps a subset of the matches, most of them on genuine queries, and the pose from it is as good:
    within 1 cm and 0.2° of the unverified server's, and within 5 cm, 1° of the truth. The result reports the
    matches before the check (the count the success rule reads)."""
    plain, verified = servers
    seq = load_sequence(scene)
    for frame in seq.query_frames:
        query = plain.extractor(seq.rgb(frame))
        candidates = plain.candidates(query)
        every = plain.correspondences(query, candidates)
        kept, before = verified.verified_correspondences(query, candidates)
        assert before == len(every) and 0.6 * len(every) < len(kept) < len(every), (len(kept), len(every))
        assert {tuple(m) for m in kept.tolist()} <= {tuple(m) for m in every.tolist()}
        a, b = plain.localize_features(query), verified.localize_features(query)
        assert a.success and b.success, (frame, a.num_inliers, b.num_inliers)
        assert b.num_matches == a.num_matches == len(every)
        gt = seq.cam_from_world[frame]
        for pose, tol_m, tol_deg in ((a.cam_from_world, 0.05, 1.0), (b.cam_from_world, 0.05, 1.0)):
            assert np.linalg.norm(camera_centre(pose) - camera_centre(gt)) < tol_m
            assert rotation_error_deg(pose[:3, :3], gt[:3, :3]) < tol_deg
        assert np.linalg.norm(camera_centre(a.cam_from_world) - camera_centre(b.cam_from_world)) < 0.01
        assert rotation_error_deg(a.cam_from_world[:3, :3], b.cam_from_world[:3, :3]) < 0.2


def test_no_pair_of_another_room_passes_so_no_ransac_runs(servers, other_room):
    """Every view of another room has matches (unverified) but no map image with 15 essential-matrix inliers:
    nothing reaches PnP or the line solver, and the server says not localized with the unverified count."""
    plain, verified = servers
    seq = load_sequence(other_room)
    for frame in seq.frames:
        query = plain.extractor(seq.rgb(frame))
        candidates = plain.candidates(query)
        kept, before = verified.verified_correspondences(query, candidates)
        assert before > 60 and len(kept) == 0, (frame, before, len(kept))
        result = verified.localize_features(query)
        assert not result.success and result.num_matches == before and result.num_inliers == 0


@pytest.mark.parametrize("servers", ["line-cloud"], indirect=True)
def test_the_line_count_is_read_on_the_matches_before_the_check(servers, scene):
    """A line server's success count comes from the unverified number of matches, as without the check."""
    plain, verified = servers
    assert verified.data.lines is not None
    seq = load_sequence(scene)
    query = plain.extractor(seq.rgb(seq.query_frames[0]))
    kept, before = verified.verified_correspondences(query, verified.candidates(query))
    threshold = equivalent_line_threshold(verified.max_error_px, CAMERA)
    count = line_min_inliers(before, verified.min_inliers, verified.max_error_px, threshold, CAMERA)
    assert count > line_min_inliers(len(kept), verified.min_inliers, verified.max_error_px, threshold, CAMERA)
    assert verified.pose_from_matches(query, kept[:count - 1], CAMERA, before).success is False  # too few


def test_the_setting_is_checked_and_keeps_the_keys_of_configs_without_it(tmp_path):
    assert "two_view_min_inliers" not in config_to_dict(LocalizeConfig())
    assert config_to_dict(LocalizeConfig(two_view_min_inliers=15))["two_view_min_inliers"] == 15
    bad = tmp_path / "bad.toml"
    bad.write_text('extends = "ci-tiny"\n[localize]\ntwo_view_min_inliers = -1\n')
    with pytest.raises(ConfigError, match=r"bad\.toml.*two_view_min_inliers"):
        load_config(bad)
