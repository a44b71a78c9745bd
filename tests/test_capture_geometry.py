"""Lens distortion and resize in the photographic capture (src/synthleak/render/capture.py, distortion.py): the
photo's camera (COLMAP ``OPENCV``, scaled by the resize) and its ray-cast ground truth must describe the
distorted, resized photo exactly, the dataset must carry per-frame cameras, and a distorted query must localize
with its distortion. Checks use OpenCV's own distortion code (``cv2.undistortPointsIter``) as the reference.

Tiny in-memory scenes of tests/test_render.py at 96x72 and the ray-cast box room of tests/test_localize.py.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
import trimesh
from fastapi.testclient import TestClient

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import OpenCVCamera, encode_png, load_sequence
from synthleak.core.types import Camera
from synthleak.errors import ConfigError
from synthleak.geometry.poses import camera_centre, invert, rotation_error_deg, transform_points
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.client import HttpLocalizer
from synthleak.localize.images import fit_to_pixels
from synthleak.localize.server import create_app
from synthleak.render import devices
from synthleak.render.bop_full import write_bop_extras
from synthleak.render.capture import (
    CaptureParams,
    Distortion,
    Resize,
    capture,
    output_camera,
    pipeline_encoding,
    srgb8_to_linear,
)
from synthleak.render.mitsuba_backend import MitsubaRenderer
from synthleak.render.pipeline import render_scene_sequence
from synthleak.seeding import derive_seed
from test_render import room_scene, tiny_config

LENS = Distortion(k1=-0.12, k2=0.03, p1=4e-4, p2=-3e-4)
"""A clearly visible barrel distortion (a few px at the corners of a 96 px frame)."""
GEOMETRY = CaptureParams(name="lens-test", distortion=LENS, resize=Resize(longest_px=72))
"""Distortion and a resize to 72x54, nothing else: the photo is the remapped render, resized."""
RENDER = dict(width=96, height=72, spp=2, scene_frames=4, query_every=2)
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)


def cv_rays(camera: OpenCVCamera, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Normalised (x, y) of pixel coordinates (u, v) by OpenCV (the reference implementation)."""
    pts = np.stack([u, v], axis=1).astype(np.float64).reshape(-1, 1, 2)
    return cv2.undistortPointsIter(pts, camera.K, camera.dist_coeffs, None, None, CRITERIA).reshape(-1, 2)


@pytest.fixture(scope="module")
def room():
    return room_scene()


@pytest.fixture(scope="module")
def lens_sequence(tmp_path_factory, room) -> Path:
    """The room's walk-through: map frames photographed with :data:`GEOMETRY`, queries with ``phone``."""
    mp = pytest.MonkeyPatch()
    mp.setitem(devices.PROFILES, "lens-test", devices.DeviceProfile(GEOMETRY, devices.Variation()))
    try:
        out = tmp_path_factory.mktemp("lens") / "room_000"
        config = tiny_config(**RENDER, capture_map="lens-test", capture_genuine="phone", bop_extras=False)
        render_scene_sequence(room[0], out, config, "scene", progress=False)
        write_bop_extras(out, room[0])
    finally:
        mp.undo()
    return out


# ------------------------------------------------------------------------------------------------ cameras
def test_the_photo_camera_is_opencv_and_scaled(lens_sequence):
    seq = load_sequence(lens_sequence)
    assert seq.split["map"] == ["000000.png", "000002.png"]
    render = Camera.from_hfov(96, 72, tiny_config().render.hfov_deg)
    expected = output_camera(render, GEOMETRY)
    for frame in seq.map_frames:
        cam = seq.camera_of(frame)
        assert cam == expected and isinstance(cam, OpenCVCamera)
        assert (cam.width, cam.height) == (72, 54) and seq.rgb(frame).shape == (54, 72, 3)
        assert seq.depth(frame).shape == seq.instance(frame).shape == (54, 72)
        # the pixel-corner convention: a centred principal point stays at W/2, the focal scales by W'/W
        assert (cam.cx, cam.cy) == (36.0, 27.0)
        assert cam.fx / render.fx == pytest.approx(0.75 * output_camera(render, replace(GEOMETRY, resize=None)).fx
                                                   / render.fx, rel=1e-12)
        assert cam.fx > 0.75 * render.fx  # barrel: zoomed in to keep every sample inside the render
    phone = devices.draw_device("phone", derive_seed(tiny_config().seed, "capture-device", "room_000", 1))
    assert seq.camera_of("000001.png") == output_camera(render, phone) != render

    # COLMAP reads back one OPENCV camera per distinct camera, each image on its own
    rec = pycolmap.Reconstruction(str(lens_sequence / "colmap"))
    assert len(rec.cameras) == 3  # one for both resized map frames, one per phone device
    for image in rec.images.values():
        cam = rec.cameras[image.camera_id]
        ours = seq.camera_of(image.name)
        assert cam.model.name == "OPENCV" and (cam.width, cam.height) == (ours.width, ours.height)
        np.testing.assert_array_equal(cam.params, [ours.fx, ours.fy, ours.cx, ours.cy, ours.k1, ours.k2, ours.p1,
                                                   ours.p2])
    # BOP: each image's cam_K and its OpenCV coefficients
    bop = json.loads((lens_sequence / "bop" / "scene_camera.json").read_text())
    for frame in seq.frames:
        entry, cam = bop[str(int(frame[:6]))], seq.camera_of(frame)
        assert entry["cam_K"] == cam.K.ravel().tolist() and entry["cam_dist"] == cam.dist_coeffs.tolist()
    records = json.loads((lens_sequence / "capture.json").read_text())
    assert records["000000.png"]["effects"] == ["distortion", "encode", "resize"]
    assert records["000000.png"]["camera"]["model"] == "OPENCV" and "resize_skipped" not in records["000000.png"]


# ------------------------------------------------------------------------------------------- ground truth
def test_distorted_resized_depth_unprojects_onto_the_meshes(lens_sequence, room):
    scene, _ = room
    seq = load_sequence(lens_sequence)
    by_id = {m.instance_id: trimesh.Trimesh(m.vertices, m.faces, process=False) for m in scene.meshes}
    distances, ids = [], set()
    for frame in seq.frames:
        cam, depth, inst = seq.camera_of(frame), seq.depth(frame), seq.instance(frame)
        v, u = np.nonzero(np.isfinite(depth))
        assert len(u) == depth.size  # a closed room: every pixel of the photo has ground truth
        xy = cv_rays(cam, u + 0.5, v + 0.5)
        z = depth[v, u].astype(np.float64)
        world = transform_points(invert(seq.cam_from_world[frame]), np.column_stack([xy * z[:, None], z]))
        for iid in np.unique(inst[v, u]):
            sel = inst[v, u] == iid
            distances.append(trimesh.proximity.closest_point(by_id[int(iid)], world[sel])[1])
            ids.add(int(iid))
    distances = np.concatenate(distances)
    assert len(distances) > 10000 and {101, 102, 103} & ids
    assert np.mean(distances < 0.002) >= 0.99, np.percentile(distances, [50, 99])
    # the pinhole reading of the same pixels (distortion ignored) is off the surfaces: the test can fail
    cam = seq.camera_of("000000.png")
    depth, inst = seq.depth(0), seq.instance(0)
    v, u = np.nonzero(np.isfinite(depth))
    z = depth[v, u].astype(np.float64)
    pin = np.column_stack([(u + 0.5 - cam.cx) / cam.fx * z, (v + 0.5 - cam.cy) / cam.fy * z, z])
    world = transform_points(invert(seq.cam_from_world["000000.png"]), pin)
    far = [trimesh.proximity.closest_point(by_id[int(i)], world[inst[v, u] == i])[1] for i in np.unique(inst[v, u])]
    assert np.mean(np.concatenate(far) < 0.002) < 0.8


def test_the_photo_is_the_render_seen_through_the_lens(lens_sequence, room):
    """The photo agrees with an independent warp of the ideal render (OpenCV's undistortion, then the resize)."""
    from PIL import Image

    seq = load_sequence(lens_sequence)
    config = tiny_config(**RENDER)
    render = Camera.from_hfov(96, 72, config.render.hfov_deg)
    renderer = MitsubaRenderer(spp=2)
    renderer.prepare(room[0])
    frame = renderer.render(render, seq.cam_from_world["000000.png"], derive_seed(config.seed, "render", "room_000", 0))
    lens_cam = output_camera(render, replace(GEOMETRY, resize=None))
    u, v = np.meshgrid(np.arange(96) + 0.5, np.arange(72) + 0.5)
    xy = cv_rays(lens_cam, u.ravel(), v.ravel())
    map_x = (render.fx * xy[:, 0] + render.cx - 0.5).reshape(72, 96).astype(np.float32)
    map_y = (render.fy * xy[:, 1] + render.cy - 0.5).reshape(72, 96).astype(np.float32)
    assert map_x.min() >= 0 and map_x.max() <= 95 and map_y.min() >= 0 and map_y.max() <= 71  # all inside
    warped = pipeline_encoding(cv2.remap(frame.linear, map_x, map_y, cv2.INTER_LINEAR))
    expected = np.asarray(Image.fromarray(warped).resize((72, 54), Image.Resampling.LANCZOS)).astype(float)
    photo = seq.rgb("000000.png").astype(float)
    plain = np.asarray(Image.fromarray(frame.rgb).resize((72, 54), Image.Resampling.LANCZOS)).astype(float)
    assert np.abs(photo - expected).mean() < 1.0, np.abs(photo - expected).mean()
    assert np.abs(photo - plain).mean() > 3.0 * np.abs(photo - expected).mean() + 1.0  # the lens shows


def test_bop_boxes_come_from_the_distorted_masks(lens_sequence):
    info = json.loads((lens_sequence / "bop" / "scene_gt_info.json").read_text())
    gt = json.loads((lens_sequence / "bop" / "scene_gt.json").read_text())
    seq = load_sequence(lens_sequence)
    checked = 0
    for key, entries in info.items():
        inst = seq.instance(int(key))
        for gt_id, (entry, obj) in enumerate(zip(entries, gt[key], strict=True)):
            visible = inst == obj["obj_id"]
            full = cv2.imread(str(lens_sequence / "bop" / "mask" / f"{int(key):06d}_{gt_id:06d}.png"), 0) > 0
            assert full.shape == inst.shape and not (visible & ~full).any()
            if visible.any():
                ys, xs = np.nonzero(visible)
                assert entry["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
                assert entry["px_count_visib"] == visible.sum()
                checked += 1
    assert checked >= 8


# -------------------------------------------------------------------------------------------- refusals
def test_a_folding_distortion_is_refused_naming_the_field():
    camera = Camera.from_hfov(96, 72, 65.0)
    folding = CaptureParams(name="fisheye-ish", distortion=Distortion(k1=-0.6))
    with pytest.raises(ConfigError, match=r"capture profile fisheye-ish: distortion\.k1/k2/k3 = -0\.6.*folds"):
        output_camera(camera, folding)
    with pytest.raises(ConfigError, match=r"distortion\.k1/k2/k3.*folds"):
        capture(np.full((72, 96, 3), 0.5, np.float32), folding, 0, camera=camera)
    with pytest.raises(ConfigError, match=r"capture parameter distortion\.p1: must be in"):
        Distortion(p1=0.2)
    with pytest.raises(ConfigError, match=r"distortion: needs the render's camera"):
        capture(np.full((72, 96, 3), 0.5, np.float32), CaptureParams(distortion=LENS), 0)
    # without a camera, a profile's own lens gives one (its defocus focal length and sensor width)
    phone = devices.draw_device("phone", 3)
    photo = capture(np.full((72, 96, 3), 0.2, np.float32), phone, 0, depth=np.full((72, 96), 2.0, np.float32))
    f = phone.defocus.focal_length_mm / phone.defocus.sensor_width_mm * 96
    assert photo.record["camera"]["params"][0] == output_camera(Camera(96, 72, f, f, 48.0, 36.0), phone).fx
    output_camera(camera, CaptureParams(distortion=Distortion(k1=-0.3)))  # strong but monotonic: accepted


def test_devices_draw_their_lens_and_ideal_has_none():
    camera = Camera.from_hfov(1920, 1080, 70.0)
    assert devices.draw_device("ideal", 3).distortion is None and devices.IDEAL.is_ideal
    for name, (lo, hi) in (("phone", (-0.05, 0.01)), ("web-photo", (-0.15, 0.05))):
        lenses = [devices.draw_device(name, seed).distortion for seed in range(40)]
        k1 = np.array([d.k1 for d in lenses])
        assert lo <= k1.min() < k1.max() <= hi and len(set(k1)) == 40
        assert devices.draw_device(name, 7) == devices.draw_device(name, 7)
        for d in lenses:  # every drawn lens is accepted at a wide phone field of view
            output_camera(camera, CaptureParams(distortion=d))
    big = devices.draw_device("web-photo", 11)
    assert output_camera(camera, big).width == big.resize.longest_px  # the resize is on


# ------------------------------------------------------------------------------------------- localization
@pytest.fixture(scope="module")
def box_localizer(tmp_path_factory) -> tuple[Localizer, list]:
    quads = ts.make_room(seed=0)
    camera = Camera.from_hfov(320, 240, 65.0)
    scene = ts.write_sequence(tmp_path_factory.mktemp("boxroom") / "room_000", quads, camera,
                              ts.walkthrough_poses(30), query_every=5)
    config = LocalizeConfig(max_keypoints=2048, pairs_per_image=8)
    return Localizer.load(build_map(scene, "sift", tmp_path_factory.mktemp("boxmap") / "sift", config,
                                    progress=False), config), quads


def test_a_distorted_query_localizes_with_its_distortion(box_localizer):
    localizer, quads = box_localizer
    render = Camera.from_hfov(320, 240, 65.0)
    gt = ts.walkthrough_poses(30)[7]  # a query frame of the walk-through (7 % 5 == 5 // 2), not in the map
    rgb, _ = ts.render_image(quads, render, gt)
    params = CaptureParams(name="lens", distortion=Distortion(k1=-0.15, k2=0.04, p1=5e-4, p2=-4e-4))
    photo = capture(srgb8_to_linear(rgb), params, 0, camera=render)
    cam = output_camera(render, params)

    def errors(result) -> tuple[float, float]:
        assert result.success
        est = result.cam_from_world
        centre = float(np.linalg.norm(camera_centre(est) - camera_centre(gt)))
        return centre, rotation_error_deg(est[:3, :3], gt[:3, :3])

    dist, angle = errors(localizer.localize(photo.rgb, cam))
    assert dist < 0.02 and angle < 0.3, (dist, angle)
    pin = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    pin_result = localizer.localize(photo.rgb, pin)
    if pin_result.success:  # the lens ignored: a worse pose (or none)
        assert max(errors(pin_result)[0] / max(dist, 1e-4), errors(pin_result)[1] / max(angle, 1e-3)) > 2.0

    # a query larger than the map's images is downscaled with its camera: the lens stays
    small, scaled = fit_to_pixels(photo.rgb, cam, 160 * 120)
    assert small.shape == (120, 160, 3) and scaled.dist_coeffs.tolist() == cam.dist_coeffs.tolist()
    assert (scaled.fx, scaled.cx) == (cam.fx / 2, cam.cx / 2)

    # over HTTP, as a phone app sends it: the distortion travels with the intrinsics
    http = HttpLocalizer("http://testserver")
    http._client = TestClient(create_app(localizer))
    remote = http.localize(photo.rgb, cam)
    np.testing.assert_allclose(remote.cam_from_world, localizer.localize(photo.rgb, cam).cam_from_world, atol=1e-9)
    png = encode_png(photo.rgb)
    missing = http._client.post("/localize", content=png, params={"k1": "-0.1"})
    assert missing.status_code == 422 and "intrinsics" in missing.json()["detail"]
    wrong = http._client.post("/localize", content=png, params={"fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                                                                "cy": cam.cy, "k1": "nan"})
    assert wrong.status_code == 422 and "k1" in wrong.json()["detail"]


def _focal_scale_every_halving(render: Camera, coeffs: tuple[float, ...]) -> float | None:
    """The focal scale as 60 halvings of [0.5, 4] give it, none skipped (the reference of the early stop)."""
    from synthleak.render.distortion import _pixel_grid, undistort_normalized

    dist = np.array(coeffs)
    u, v = _pixel_grid(render, border_only=True)

    def inside(s: float) -> bool:
        try:
            x, y = undistort_normalized((u - render.cx) / (s * render.fx), (v - render.cy) / (s * render.fy), dist)
        except ValueError:
            return False
        ur, vr = render.fx * x + render.cx, render.fy * y + render.cy
        return bool(np.all((ur >= 0.5) & (ur <= render.width - 0.5) & (vr >= 0.5) & (vr <= render.height - 0.5)))

    lo, hi = 0.5, 4.0
    if not inside(hi):
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if inside(mid) else (mid, hi)
    return np.ceil(hi * 1e6) / 1e6


def test_the_focal_scale_stops_halving_early_with_the_same_bits():
    from synthleak.render.distortion import focal_scale

    rng = np.random.default_rng(7)
    for width, height in ((96, 72), (480, 360), (640, 480)):
        render = Camera.from_hfov(width, height, 65.0)
        for _ in range(12):
            coeffs = (float(rng.uniform(-0.15, 0.05)), float(rng.uniform(-0.02, 0.06)),
                      float(rng.normal(0, 5e-4)), float(rng.normal(0, 5e-4)), 0.0)
            focal_scale.cache_clear()
            assert focal_scale(render, coeffs) == _focal_scale_every_halving(render, coeffs), (width, coeffs)
    # a camera drawn twice is computed once per process
    focal_scale.cache_clear()
    output_camera(render, CaptureParams(distortion=LENS))
    output_camera(render, CaptureParams(distortion=LENS))
    assert focal_scale.cache_info().hits == 1
