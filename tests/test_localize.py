"""Localization service: GT-pose mapping, PnP localization, tiers, the Sec. 6 defense, HTTP.

Fixtures: a tiny study rendered by the mitsuba pipeline (1 room, 3 objects, 320x240, 40 walk-through
frames; genuine held-out queries) and small textured box rooms ray cast with embree
(:mod:`synthleak.localize.testscene`) where a test needs a controlled view (defense close-up, tiers,
a different environment).
"""

from __future__ import annotations

import io
import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from synthleak.config import LocalizeConfig, config_from_dict
from synthleak.core.dataset import encode_png, load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at, rotation_error_deg
from synthleak.localize import DefensePolicy, Localizer, build_map, decide, get_tier
from synthleak.localize import testscene as ts
from synthleak.localize.client import HttpLocalizer, LocalizationServiceError
from synthleak.localize.defense import contributing_instances
from synthleak.localize.localizer import InvalidImageError
from synthleak.localize.server import create_app, response_from_result

CONFIG = LocalizeConfig(max_keypoints=2048, pairs_per_image=8)
CAMERA = Camera.from_hfov(320, 240, 65.0)


def pose_errors(estimate: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """(centre error in metres, rotation error in degrees)."""
    dist = float(np.linalg.norm(camera_centre(estimate) - camera_centre(gt)))
    return dist, rotation_error_deg(estimate[:3, :3], gt[:3, :3])


# ---------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def study_scene(tmp_path_factory) -> Path:
    """A tiny study rendered by the real pipeline (mitsuba): ``scenes/room_000``."""
    from synthleak.render.pipeline import generate

    config = config_from_dict({
        "name": "localize-test", "seed": 3,
        "scenes": {"rooms": 1, "objects_per_room": [3, 3], "room_size_x": [3.5, 4.0],
                   "room_size_y": [3.0, 3.5],
                   "room_height": [2.5, 2.5], "lights_per_room": [2, 2]},
        "render": {"width": 320, "height": 240, "scene_frames": 40, "attacker_frames": 2, "query_every": 5,
                   "spp": 4, "integrator": "direct", "filter": "box"},
    })
    out = tmp_path_factory.mktemp("study")
    generate(config, out, progress=False)
    scenes = sorted((out / "scenes").iterdir())
    assert scenes, "the pipeline wrote no scene sequence"
    return scenes[0]


@pytest.fixture(scope="module")
def study_map(study_scene, tmp_path_factory) -> Path:
    return build_map(study_scene, "sift", tmp_path_factory.mktemp("map") / "sift", CONFIG, progress=False)


@pytest.fixture(scope="module")
def study_localizer(study_map) -> Localizer:
    return Localizer.load(study_map, CONFIG)


@pytest.fixture(scope="module")
def box_quads() -> list[ts.Quad]:
    return ts.make_room(seed=0)


@pytest.fixture(scope="module")
def box_scene(box_quads, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("boxroom") / "room_000"
    return ts.write_sequence(out, box_quads, CAMERA, ts.walkthrough_poses(30), query_every=5)


@pytest.fixture(scope="module")
def box_map(box_scene, tmp_path_factory) -> Path:
    return build_map(box_scene, "sift", tmp_path_factory.mktemp("boxmap") / "sift", CONFIG, progress=False)


@pytest.fixture(scope="module")
def tiny_box_scene(box_quads, tmp_path_factory) -> Path:
    """Six consecutive frames (queries: frames 1 and 4) for the slower tiers."""
    out = tmp_path_factory.mktemp("tinybox") / "room_000"
    return ts.write_sequence(out, box_quads, CAMERA, ts.walkthrough_poses(40)[:6], query_every=3)


@pytest.fixture(scope="module")
def small_box_scene(box_quads, tmp_path_factory) -> Path:
    """The six frames at 160x120, for the (slow on CPU) torch tiers."""
    out = tmp_path_factory.mktemp("smallbox") / "room_000"
    camera = Camera.from_hfov(160, 120, 65.0)
    return ts.write_sequence(out, box_quads, camera, ts.walkthrough_poses(40)[:6], query_every=3)


# ---------------------------------------------------------------- mapping + in-process localization


def test_genuine_queries_localize_accurately(study_scene, study_localizer):
    seq = load_sequence(study_scene)
    assert len(seq.query_frames) >= 5
    assert not set(seq.query_frames) & set(seq.map_frames)
    errors, localized = [], 0
    for frame in seq.query_frames:
        result = study_localizer.localize(seq.rgb(frame))
        if result.success:
            localized += 1
            errors.append(pose_errors(result.cam_from_world, seq.cam_from_world[frame]))
            assert result.num_inliers >= get_tier("sift").min_inliers
            assert sum(result.inlier_instance_counts.values()) == result.num_inliers
    assert localized >= 0.9 * len(seq.query_frames)
    dist, angle = np.median(np.array(errors), axis=0)
    assert dist < 0.05 and angle < 1.0, (dist, angle)


def test_map_points_lie_on_surfaces_and_carry_instances(study_scene, study_map):
    seq = load_sequence(study_scene)
    meta = json.loads((study_map / "map.json").read_text())
    assert meta["tier"] == "sift" and meta["num_images"] == len(seq.map_frames)
    rec = pycolmap.Reconstruction(str(study_map / "sfm"))
    assert rec.num_points3D() == meta["num_points"] > 500
    labels = json.loads((study_map / "points_instance.json").read_text())
    assert len(labels) == rec.num_points3D()
    # Triangulated points agree with the GT depth of the images that observe them.
    gaps, agree, total = [], 0, 0
    for image in list(rec.images.values())[:8]:
        depth = seq_depth(study_scene, image.name)
        mask = np.asarray(Image.open(study_scene / "instance" / image.name)).astype(np.int64)
        pose = np.eye(4)
        pose[:3] = image.cam_from_world().matrix()
        for p2d in image.points2D:
            if not p2d.has_point3D():
                continue
            xyz = rec.point3D(p2d.point3D_id).xyz
            z = (pose[:3, :3] @ xyz + pose[:3, 3])[2]
            u, v = (int(c) for c in p2d.xy)
            gaps.append(abs(z - depth[v, u]) / depth[v, u])
            total += 1
            agree += labels[str(p2d.point3D_id)] == mask[v, u]
    assert np.median(gaps) < 0.01
    assert agree / total > 0.9


def seq_depth(scene: Path, name: str) -> np.ndarray:
    return np.load(scene / "depth" / (Path(name).stem + ".npy"))


def test_build_map_reuses_a_matching_map(study_scene, study_map):
    before = (study_map / "map.json").stat().st_mtime_ns
    assert build_map(study_scene, "sift", study_map, CONFIG, progress=False) == study_map
    assert (study_map / "map.json").stat().st_mtime_ns == before


def test_localization_is_deterministic_and_bow_retrieval_works(study_scene, study_map, study_localizer):
    seq = load_sequence(study_scene)
    frame = seq.query_frames[1]
    a, b = study_localizer.localize(seq.rgb(frame)), study_localizer.localize(seq.rgb(frame))
    assert a.success and np.array_equal(a.cam_from_world, b.cam_from_world)
    bow = Localizer.load(study_map, LocalizeConfig(max_keypoints=2048, retrieval="bow", top_k=5))
    result = bow.localize(seq.rgb(frame))
    assert result.success
    dist, angle = pose_errors(result.cam_from_world, seq.cam_from_world[frame])
    assert dist < 0.05 and angle < 1.0


def test_other_environment_is_not_localized(study_localizer, box_localizer):
    other = ts.make_room(seed=11)
    for pose in ts.walkthrough_poses(4)[::2]:
        rgb, _ = ts.render_image(other, CAMERA, pose)
        for loc in (study_localizer, box_localizer):
            result = loc.localize(rgb)
            assert not result.success or result.num_inliers < 30, result.num_inliers


def test_bad_query_images_raise(study_localizer):
    with pytest.raises(InvalidImageError):
        study_localizer.localize(b"not an image")
    with pytest.raises(InvalidImageError):
        study_localizer.localize(np.zeros((10, 10, 3), np.uint8))  # size differs from the map camera


def test_bad_sequence_and_map_folders_are_named(tmp_path, box_scene):
    from synthleak.core.dataset import DatasetError
    from synthleak.localize.store import MapError

    with pytest.raises(DatasetError, match="no such sequence folder"):
        build_map(tmp_path / "nowhere", "sift", tmp_path / "map", progress=False)
    with pytest.raises(MapError, match="map.json: missing"):
        Localizer.load(tmp_path / "empty")


def test_pairs_from_poses_picks_near_cameras_looking_the_same_way():
    from synthleak.localize.pairs import pairs_from_poses

    poses = [look_at([x, 0, 1], [x, 5, 1]) for x in (0.0, 0.2, 0.4, 3.0)]
    poses.append(look_at([0.1, 0, 1], [0.1, -5, 1]))  # near camera 0 but looking the other way
    pairs = pairs_from_poses(poses, pairs_per_image=1)
    assert (0, 1) in pairs and (1, 2) in pairs and (2, 3) in pairs
    assert not any(4 in p for p in pairs)


# ---------------------------------------------------------------- defense


@pytest.fixture(scope="module")
def box_localizer(box_map) -> Localizer:
    return Localizer.load(box_map, CONFIG)


def closeup_pose(quads: list[ts.Quad], instance_id: int, distance: float) -> np.ndarray:
    """A camera facing the box face that points at the room centre."""
    box = [q for q in quads if q.instance_id == instance_id]
    corners = np.array([c for q in box for c in (q.origin, q.origin + q.size_u * q.u + q.size_v * q.v)])
    lo, hi = corners.min(0), corners.max(0)
    centre = (lo + hi) / 2
    to_room = np.array([2.5, 2.0]) - centre[:2]
    axis = int(np.argmax(np.abs(to_room)))
    face = centre.copy()
    face[axis] = hi[axis] if to_room[axis] > 0 else lo[axis]
    normal = np.zeros(3)
    normal[axis] = np.sign(to_room[axis])
    return look_at(face + distance * normal + [0, 0, 0.3], face)


def test_defense_rejects_single_object_view_and_accepts_wide_view(box_quads, box_scene, box_map, tmp_path):
    log = tmp_path / "decisions.jsonl"
    policy = DefensePolicy(min_fraction=0.1, min_instances=3, enabled=True)
    defended = Localizer.load(box_map, CONFIG, defense=policy, decision_log=log)
    plain = Localizer.load(box_map, CONFIG)

    pose = closeup_pose(box_quads, 100, 0.8)
    rgb, mask = ts.render_image(box_quads, CAMERA, pose)
    assert (mask == 100).mean() > 0.6  # the view is dominated by one object
    undefended = plain.localize(rgb)
    assert undefended.success  # the view localizes without the defense...
    assert pose_errors(undefended.cam_from_world, pose)[0] < 0.05
    result = defended.localize(rgb)
    assert not result.success and result.cam_from_world is None  # ...and is rejected with it
    assert result.defense is not None and not result.defense.accepted
    assert len(result.defense.contributing) < 3
    # the refused pose stays on the server side: logged for studies, never in the HTTP answer
    assert np.array_equal(result.withheld_cam_from_world, undefended.cam_from_world)
    assert response_from_result(result) == {"success": False}

    seq = load_sequence(box_scene)
    wide = defended.localize(seq.rgb(seq.query_frames[0]))
    assert wide.success and wide.defense.accepted and len(wide.defense.contributing) >= 3

    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [r["accepted"] for r in records] == [False, True]
    assert all(r["counts"] and r["num_inliers"] > 0 for r in records)
    # Offline sweeps re-decide from the logged counts without PnP.
    counts = {int(k): v for k, v in records[0]["counts"].items()}
    assert decide(counts, 0.1, 3) is False and decide(counts, 0.0, 1) is True


def test_decide_counts_instances_relative_to_the_top_one():
    counts = {101: 100, 102: 30, 103: 9, 0: 50}
    assert contributing_instances(counts, 0.1) == [101, 102]  # background 0 never counts
    assert decide(counts, 0.1, 2) and not decide(counts, 0.1, 3)
    assert decide(counts, 0.05, 3)
    assert not decide({}, 0.1, 1) and decide({}, 0.1, 0)
    with pytest.raises(ValueError, match="min_fraction"):
        DefensePolicy(min_fraction=1.5)


# ---------------------------------------------------------------- HTTP service


def png_bytes(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.fixture(scope="module")
def client(study_localizer) -> TestClient:
    return TestClient(create_app(study_localizer, max_upload_bytes=2_000_000))


def test_http_response_carries_only_the_documented_fields(client, study_scene):
    seq = load_sequence(study_scene)
    response = client.post("/localize", content=seq.image_path(seq.query_frames[0]).read_bytes(),
                           headers={"Content-Type": "image/png"})
    assert response.status_code == 200
    data = response.json()
    assert set(data) == {"success", "cam_from_world"} and data["success"] is True
    assert set(data["cam_from_world"]) == {"rotation", "translation"}
    assert len(data["cam_from_world"]["rotation"]) == 4 and len(data["cam_from_world"]["translation"]) == 3
    noise = np.random.default_rng(0).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    assert client.post("/localize", content=png_bytes(noise)).json() == {"success": False}


@pytest.mark.parametrize(
    ("body", "params", "status", "message"),
    [
        (b"", {}, 400, "empty"),
        (b"definitely not an image", {}, 400, "not a decodable image"),
        ("1x1", {}, 400, ">= 16"),
        ("64x48", {}, 400, "pass intrinsics"),
        ("query", {"fx": "nan", "fy": 250, "cx": 160, "cy": 120}, 422, "finite"),
        ("query", {"fx": -250, "fy": 250, "cx": 160, "cy": 120}, 422, "> 0"),
        ("query", {"fx": 250, "fy": 250, "cx": 500, "cy": 120}, 422, "outside"),
        ("query", {"fx": 250, "fy": 250, "cx": 160, "cy": 120, "width": 640}, 422, "does not match"),
        ("query", {"fx": 250}, 422, "all of fx, fy, cx, cy"),
        ("query", {"fx": "abc", "fy": 250, "cx": 160, "cy": 120}, 422, "not a number"),
        (b"x" * 2_000_001, {}, 413, "exceeds"),
    ],
)
def test_http_bad_input_gets_4xx_and_the_server_keeps_serving(
    client, study_scene, body, params, status, message
):
    seq = load_sequence(study_scene)
    if body == "1x1":
        body = png_bytes(np.zeros((1, 1, 3), np.uint8))
    elif body == "64x48":
        body = png_bytes(np.zeros((48, 64, 3), np.uint8))
    elif body == "query":
        body = seq.image_path(seq.query_frames[0]).read_bytes()
    response = client.post("/localize", content=body, params=params)
    assert response.status_code == status, response.text
    assert message in response.json()["detail"]
    assert client.get("/health").json() == {"status": "ok"}


def test_http_streamed_upload_over_the_limit_is_rejected(client):
    def chunks():
        for _ in range(30):
            yield b"y" * 100_000  # no Content-Length: the server counts while streaming

    response = client.post("/localize", content=chunks())
    assert response.status_code == 413
    assert client.get("/health").status_code == 200


def test_http_intrinsics_are_used(client, study_scene, study_localizer):
    seq = load_sequence(study_scene)
    cam = study_localizer.camera
    body = seq.image_path(seq.query_frames[2]).read_bytes()
    response = client.post("/localize", content=body, params={"fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                                                                "cy": cam.cy, "width": 320, "height": 240})
    assert response.status_code == 200 and response.json()["success"] is True


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_http_client_matches_in_process_localizer_over_uvicorn(study_scene, study_localizer):
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(study_localizer), host="127.0.0.1", port=port,
                                           log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 20
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        seq = load_sequence(study_scene)
        with HttpLocalizer(f"http://127.0.0.1:{port}") as remote:
            assert remote.health()
            for frame in seq.query_frames[:3]:
                rgb = seq.rgb(frame)
                local, over_http = study_localizer.localize(rgb), remote.localize(rgb)
                assert over_http.success == local.success
                if local.success:
                    np.testing.assert_allclose(over_http.cam_from_world, local.cam_from_world, atol=1e-9)
                    assert over_http.num_inliers == 0 and over_http.inlier_instance_counts == {}
            with pytest.raises(LocalizationServiceError) as info:
                remote.localize(b"garbage")
            assert info.value.status_code == 400
            encoded = encode_png(seq.rgb(seq.query_frames[0]))
            assert remote.localize(encoded, camera=study_localizer.camera).success
    finally:
        server.should_exit = True
        thread.join(timeout=10)


# ---------------------------------------------------------------- tiers


def run_tier(scene: Path, tier: str, out: Path, weights_dir: Path | None = None, **config) -> list:
    cfg = LocalizeConfig(**{"max_keypoints": 1024, "pairs_per_image": 3, **config})
    map_dir = build_map(scene, tier, out, cfg, progress=False, weights_dir=weights_dir)
    assert json.loads((map_dir / "map.json").read_text())["tier"] == tier
    loc = Localizer.load(map_dir, cfg, weights_dir=weights_dir)
    seq = load_sequence(scene)
    return [(loc.localize(seq.rgb(f)), seq.cam_from_world[f]) for f in seq.query_frames]


@pytest.mark.parametrize("tier", ["orb", "akaze"])
def test_opencv_tiers_localize(tiny_box_scene, tmp_path, tier):
    import cv2

    from synthleak.localize.features import MissingFeatureError

    if tier == "akaze" and not hasattr(cv2, "AKAZE_create"):  # OpenCV 5 moved AKAZE to contrib
        with pytest.raises(MissingFeatureError, match="opencv-contrib"):
            run_tier(tiny_box_scene, tier, tmp_path / tier)
        return
    results = run_tier(tiny_box_scene, tier, tmp_path / tier)
    assert any(r.success for r, _ in results)
    for result, gt in results:
        if result.success:
            dist, angle = pose_errors(result.cam_from_world, gt)
            assert dist < 0.1 and angle < 2.0


def assert_blank_images_not_localized(map_dir: Path, cfg: LocalizeConfig) -> None:
    """Uniform black, grey and white images: no features (descriptors as wide as the map's) and not localized."""
    loc = Localizer.load(map_dir, cfg)
    width = next(f.descriptors.shape[1] for f in loc.data.features if len(f))
    for level in (0, 128, 255):
        blank = np.full((loc.camera.height, loc.camera.width, 3), level, np.uint8)
        features = loc.extractor(blank)
        assert len(features) == 0 and features.descriptors.shape == (0, width), (level, features.descriptors.shape)
        result = loc.localize(png_bytes(blank))
        assert not result.success and result.cam_from_world is None


@pytest.mark.parametrize("tier", ["sift", "orb", "akaze"])
def test_blank_images_are_not_localized_by_the_classic_tiers(tiny_box_scene, tmp_path, tier):
    import cv2

    if tier == "akaze" and not hasattr(cv2, "AKAZE_create"):
        pytest.skip("OpenCV without AKAZE")
    cfg = LocalizeConfig(max_keypoints=1024, pairs_per_image=3)
    assert_blank_images_not_localized(build_map(tiny_box_scene, tier, tmp_path / tier, cfg, progress=False), cfg)


def test_blank_images_are_not_localized_by_kornia_sift(small_box_scene, tmp_path):
    pytest.importorskip("torch", reason="torch not installed: pip install torch==2.13.0 kornia")
    pytest.importorskip("kornia", reason="kornia not installed: pip install torch==2.13.0 kornia")
    cfg = LocalizeConfig(max_keypoints=256, pairs_per_image=3)
    map_dir = build_map(small_box_scene, "kornia-sift", tmp_path / "ksift", cfg, progress=False)
    assert_blank_images_not_localized(map_dir, cfg)


def test_unknown_tier_is_named():
    with pytest.raises(ValueError, match="unknown localization tier 'surf'.*sift"):
        get_tier("surf")


def test_kornia_sift_tier(small_box_scene, tmp_path):
    pytest.importorskip("torch", reason="torch not installed: pip install torch==2.13.0 kornia")
    pytest.importorskip("kornia", reason="kornia not installed: pip install torch==2.13.0 kornia")
    results = run_tier(small_box_scene, "kornia-sift", tmp_path / "ksift", max_keypoints=256)
    assert any(r.success for r, _ in results)
    for result, gt in results:
        if result.success:
            assert pose_errors(result.cam_from_world, gt)[0] < 0.1
