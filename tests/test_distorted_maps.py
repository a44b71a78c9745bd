"""Maps built from distorted mapping frames (``capture_map = "phone"``; issue 30): ``build_map`` undoes each
frame's own lens (``Sequence.camera_of``) before the epipolar filter and the triangulation, so the map's points lie
on the scene's surfaces, where the same photos read as pinhole frames give fewer, displaced points.

The ray-cast box room of tests/test_localize.py (``synthleak.localize.testscene``) at 240x180, photographed
through a strong barrel lens (k1 = -0.2: ~10 px at the corners) by the capture model, with exact ray-cast
depth and instance ids for the distorted camera. The same room photographed as an attacker's web photos (two
lenses, two sizes) checks that the attacker's SfM (``sfm_local_poses``) runs on each photo's own camera.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pycolmap
import pytest
import trimesh
from PIL import Image

from synthleak.attack.local_model import camera_groups, local_pose_errors, sfm_local_poses
from synthleak.config import LocalizeConfig
from synthleak.core.dataset import OpenCVCamera, load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, quat_wxyz_from_matrix
from synthleak.localize import build_map
from synthleak.localize import testscene as ts
from synthleak.localize.mapping import ideal_keypoints
from synthleak.localize.tiers import profile_tier
from synthleak.render.capture import CaptureParams, Distortion, Resize, capture, output_camera, srgb8_to_linear
from synthleak.render.distortion import camera_rays

RENDER = Camera.from_hfov(240, 180, 65.0)
LENS = CaptureParams(name="strong-lens", distortion=Distortion(k1=-0.2))
FRAMES = 16
CONFIG = LocalizeConfig(max_keypoints=1024, pairs_per_image=6)
ON_SURFACE_M = 0.02
"""A triangulated point this close to a quad is on the scene's surface."""


def distorted_gt(scene: ts.QuadScene, camera: OpenCVCamera, cam_from_world: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Exact z-depth and instance ids of the distorted ``camera``: one ray per pixel centre through its lens."""
    x, y = camera_rays(camera)
    rot = cam_from_world[:3, :3]
    dirs = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1) @ rot
    origin = camera_centre(cam_from_world)
    tri, ray, loc = scene._intersector.intersects_id(np.broadcast_to(origin, dirs.shape), dirs, multiple_hits=False,
                                                     return_locations=True)
    depth = np.full(x.size, np.inf)
    inst = np.zeros(x.size, np.uint16)
    depth[ray] = (loc - origin) @ rot[2]
    inst[ray] = [scene.quads[t // 2].instance_id for t in tri]
    return depth.reshape(x.shape).astype(np.float32), inst.reshape(x.shape)


def colmap_line(camera: Camera) -> str:
    params = [camera.fx, camera.fy, camera.cx, camera.cy]
    if isinstance(camera, OpenCVCamera):
        params += [camera.k1, camera.k2, camera.p1, camera.p2]
    model = "OPENCV" if isinstance(camera, OpenCVCamera) else "PINHOLE"
    return f"1 {model} {camera.width} {camera.height} " + " ".join(repr(float(v)) for v in params) + "\n"


@pytest.fixture(scope="module")
def box_room(tmp_path_factory) -> dict:
    """The walk-through rendered pinhole, then photographed through :data:`LENS` (``lens``) and the same photos
    with the lens left out of cameras.txt (``as_pinhole``)."""
    quads = ts.make_room(seed=0)
    poses = ts.walkthrough_poses(FRAMES)
    root = tmp_path_factory.mktemp("distorted")
    pinhole = ts.write_sequence(root / "pinhole" / "room_000", quads, RENDER, poses, query_every=0)
    lens = root / "lens" / "room_000"
    shutil.copytree(pinhole, lens)
    camera = output_camera(RENDER, LENS)
    assert isinstance(camera, OpenCVCamera) and camera.k1 == -0.2
    scene = ts.QuadScene(quads)
    for i, pose in enumerate(poses):
        stem = f"{i:06d}"
        rgb = np.asarray(Image.open(pinhole / "images" / f"{stem}.png"))
        Image.fromarray(capture(srgb8_to_linear(rgb), LENS, 0, camera=RENDER).rgb).save(lens / "images" / f"{stem}.png")
        depth, inst = distorted_gt(scene, camera, pose)
        np.save(lens / "depth" / f"{stem}.npy", depth)
        Image.fromarray(inst).save(lens / "instance" / f"{stem}.png")
    (lens / "colmap" / "cameras.txt").write_text(colmap_line(camera))
    as_pinhole = root / "as_pinhole" / "room_000"
    shutil.copytree(lens, as_pinhole)
    (as_pinhole / "colmap" / "cameras.txt").write_text(colmap_line(
        Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)))
    verts, faces = [], []
    for q in quads:
        n = len(verts)
        verts += [q.origin, q.origin + q.size_u * q.u, q.origin + q.size_u * q.u + q.size_v * q.v,
                  q.origin + q.size_v * q.v]
        faces += [[n, n + 1, n + 2], [n, n + 2, n + 3]]
    mesh = trimesh.Trimesh(np.array(verts), np.array(faces), process=False)
    maps = {name: build_map(seq, "sift", root / "maps" / name, CONFIG, progress=False)
            for name, seq in (("pinhole", pinhole), ("lens", lens), ("as_pinhole", as_pinhole))}
    return {"seqs": {"pinhole": pinhole, "lens": lens, "as_pinhole": as_pinhole}, "maps": maps, "mesh": mesh,
            "camera": camera}


def surface_distances(map_dir: Path, mesh: trimesh.Trimesh) -> np.ndarray:
    with np.load(map_dir / "points.npz") as data:
        xyz = data["xyz"]
    assert len(xyz) > 0
    return trimesh.proximity.closest_point(mesh, xyz)[1]


def test_the_lens_sequence_has_its_distorted_camera_and_ground_truth(box_room):
    seq = load_sequence(box_room["seqs"]["lens"])
    assert seq.camera_of("000000.png") == box_room["camera"] and seq.camera_of("000000.png").k1 == -0.2
    # the ground truth is the distorted photo's: its depth unprojects through the lens onto the quads
    depth = seq.depth("000003.png")
    x, y = camera_rays(box_room["camera"])
    cam_pts = np.stack([x * depth, y * depth, depth], axis=-1).reshape(-1, 3)[::7]
    world = (cam_pts - seq.cam_from_world["000003.png"][:3, 3]) @ seq.cam_from_world["000003.png"][:3, :3]
    assert np.percentile(trimesh.proximity.closest_point(box_room["mesh"], world)[1], 99) < 1e-3


def test_a_map_from_distorted_frames_lies_on_the_surfaces(box_room):
    mesh = box_room["mesh"]
    lens, as_pinhole, pinhole = (surface_distances(box_room["maps"][k], mesh) for k in ("lens", "as_pinhole",
                                                                                         "pinhole"))
    on_lens, on_pin, on_ideal = (float(np.mean(d < ON_SURFACE_M)) for d in (lens, as_pinhole, pinhole))
    print(f"points: lens {len(lens)} (median {np.median(lens) * 1000:.1f} mm, {on_lens:.3f} on the surface), "
          f"as pinhole {len(as_pinhole)} (median {np.median(as_pinhole) * 1000:.1f} mm, {on_pin:.3f}), "
          f"ideal pinhole render {len(pinhole)} (median {np.median(pinhole) * 1000:.1f} mm, {on_ideal:.3f})")
    # as good as a map of the undistorted renders of the same poses
    assert len(lens) > 0.8 * len(pinhole) and len(lens) > 1000
    assert np.median(lens) < 0.008 and np.median(lens) < 1.5 * np.median(pinhole) + 0.001
    assert on_lens > 0.75 and on_lens > on_ideal - 0.05
    # the same photos with the lens ignored: displaced points, mostly off the surfaces
    assert np.median(as_pinhole) > 5.0 * np.median(lens)
    assert on_pin < 0.5 * on_lens


def test_the_map_keeps_the_detected_keypoints_with_each_frames_camera(box_room):
    seq = load_sequence(box_room["seqs"]["lens"])
    map_dir = box_room["maps"]["lens"]
    extractor = profile_tier("sift", CONFIG.profile).make_extractor(CONFIG.max_keypoints, None)
    rec = pycolmap.Reconstruction(str(map_dir / "sfm"))
    with np.load(map_dir / "features.npz") as data:
        names = [str(n) for n in data["names"]]
        for i in (0, 5):
            np.testing.assert_array_equal(data[f"kp_{i}"], extractor(seq.rgb(names[i])).keypoints)
    # sfm/: the frames on their OPENCV camera; the detected keypoints reproject through the lens
    cams = {c.model.name for c in rec.cameras.values()}
    assert cams == {"OPENCV"}
    errors = []
    for point in rec.points3D.values():
        for el in point.track.elements:
            image = rec.images[el.image_id]
            uv = rec.cameras[image.camera_id].img_from_cam(image.cam_from_world() * point.xyz)
            errors.append(np.linalg.norm(uv - image.points2D[el.point2D_idx].xy))
    assert len(errors) > 600 and np.percentile(errors, 95) < 2.0, np.percentile(errors, [50, 95])


def test_pinhole_frames_keep_their_keypoints_bit_for_bit(box_room):
    seq = load_sequence(box_room["seqs"]["pinhole"])
    extractor = profile_tier("sift", CONFIG.profile).make_extractor(CONFIG.max_keypoints, None)
    features = [extractor(seq.rgb(n)) for n in seq.map_frames[:3]]
    assert all(a is f.keypoints for a, f in zip(ideal_keypoints(seq, seq.map_frames[:3], features), features,
                                                strict=True))
    rec = pycolmap.Reconstruction(str(box_room["maps"]["pinhole"] / "sfm"))
    assert [(c.camera_id, c.model.name) for c in rec.cameras.values()] == [(1, "PINHOLE")]
    assert camera_groups(seq, seq.frames) == {seq.camera: seq.frames}  # the attacker's SfM: one camera, as before
    # a distorted frame's keypoints move: the lens is undone
    lens = load_sequence(box_room["seqs"]["lens"])
    moved = ideal_keypoints(lens, lens.map_frames[:1], [extractor(lens.rgb(lens.map_frames[0]))])[0]
    assert not np.array_equal(moved, extractor(lens.rgb(lens.map_frames[0])).keypoints)


# ------------------------------------------------------------------------------------- the attacker's SfM
LENSES = (Distortion(k1=-0.2), Distortion(k1=-0.1, k2=0.02, p1=5e-4, p2=-4e-4))
ORBIT = 20


def write_cameras(seq_dir: Path, cameras: list[Camera], poses: list[np.ndarray]) -> None:
    """cameras.txt with one line per distinct camera and images.txt with each frame's CAMERA_ID."""
    ids: dict[Camera, int] = {}
    for cam in cameras:
        ids.setdefault(cam, len(ids) + 1)
    (seq_dir / "colmap" / "cameras.txt").write_text(
        "".join(colmap_line(cam).replace("1 ", f"{i} ", 1) for cam, i in ids.items()))
    lines = []
    for i, (cam, pose) in enumerate(zip(cameras, poses, strict=True)):
        q, t = quat_wxyz_from_matrix(pose[:3, :3]), pose[:3, 3]
        lines.append(f"{i + 1} {' '.join(f'{x:.17g}' for x in (*q, *t))} {ids[cam]} {i:06d}.png\n\n")
    (seq_dir / "colmap" / "images.txt").write_text("".join(lines))


@pytest.fixture(scope="module")
def web_photos(tmp_path_factory) -> dict[str, Path]:
    """The box room's walk-through as an attacker's photo set: two lenses in turn, the second half resized to
    180x135 (four COLMAP cameras), its most seen box the target; ``as_pinhole``: the lenses left out."""
    quads = ts.make_room(seed=0)
    poses = ts.walkthrough_poses(ORBIT)
    root = tmp_path_factory.mktemp("web_photos")
    seq_dir = ts.write_sequence(root / "lens" / "a00", quads, RENDER, poses, query_every=0)
    scene, cameras, pixels = ts.QuadScene(quads), [], {}
    for i, pose in enumerate(poses):
        params = CaptureParams(name="web", distortion=LENSES[i % 2],
                               resize=Resize(longest_px=180) if i >= ORBIT // 2 else None)
        stem, cam = f"{i:06d}", output_camera(RENDER, params)
        rgb = np.asarray(Image.open(seq_dir / "images" / f"{stem}.png"))
        photo = capture(srgb8_to_linear(rgb), params, 0, camera=RENDER).rgb
        assert photo.shape == (cam.height, cam.width, 3)
        Image.fromarray(photo).save(seq_dir / "images" / f"{stem}.png")
        depth, inst = distorted_gt(scene, cam, pose)
        np.save(seq_dir / "depth" / f"{stem}.npy", depth)
        Image.fromarray(inst).save(seq_dir / "instance" / f"{stem}.png")
        cameras.append(cam)
        for iid, n in zip(*np.unique(inst, return_counts=True), strict=True):
            pixels[int(iid)] = pixels.get(int(iid), 0) + int(n)
    objects = json.loads((seq_dir / "objects.json").read_text())
    boxes = [k for k in pixels if k >= 100]  # a box (the walls are flat: no object size)
    objects |= {"frame": "object", "target_instance_id": max(boxes, key=lambda k: (pixels[k], k))}
    (seq_dir / "objects.json").write_text(json.dumps(objects))
    (seq_dir / "split.json").unlink()
    write_cameras(seq_dir, cameras, poses)
    as_pinhole = root / "as_pinhole" / "a00"
    shutil.copytree(seq_dir, as_pinhole)
    write_cameras(as_pinhole, [Camera(c.width, c.height, c.fx, c.fy, c.cx, c.cy) for c in cameras], poses)
    return {"lens": seq_dir, "as_pinhole": as_pinhole}


def test_the_attackers_sfm_uses_each_photos_own_camera(web_photos, tmp_path):
    seq = load_sequence(web_photos["lens"])
    assert len(set(seq.cameras.values())) == 4 and {seq.camera_of(f).width for f in seq.frames} == {240, 180}
    extents = seq.objects_by_id()[seq.target_instance_id].extents
    model = sfm_local_poses(seq, extents, tmp_path / "lens", seed=0)
    errors = local_pose_errors(model, seq)
    print(f"SfM with the lenses: {model.message}, {errors}, rmse {model.registration_rmse_m:.4f} m")
    assert model.ok and len(model.registered) >= ORBIT - 2
    assert errors["median_rot_deg"] < 0.5 and model.registration_rmse_m < 0.03
    # COLMAP's cameras are the photos' own: OPENCV, each image on its frame's intrinsics and size
    rec = pycolmap.Reconstruction(str(next((tmp_path / "lens" / "sparse").iterdir())))
    for image_id in rec.reg_image_ids():
        image = rec.images[image_id]
        cam, ours = rec.cameras[image.camera_id], seq.camera_of(image.name)
        assert cam.model.name == "OPENCV" and (cam.width, cam.height) == (ours.width, ours.height)
        np.testing.assert_array_equal(cam.params, [ours.fx, ours.fy, ours.cx, ours.cy, ours.k1, ours.k2, ours.p1,
                                                   ours.p2])
    # the same photos with the lenses ignored: worse local poses (or fewer of them)
    pin_seq = load_sequence(web_photos["as_pinhole"])
    pin = sfm_local_poses(pin_seq, extents, tmp_path / "as_pinhole", seed=0)
    pin_errors = local_pose_errors(pin, pin_seq)
    print(f"SfM as pinhole: {pin.message}, {pin_errors}, rmse {pin.registration_rmse_m:.4f} m")
    assert not pin.ok or len(pin.registered) < len(model.registered) or (
        pin_errors["median_rot_deg"] > 2.0 * errors["median_rot_deg"]
        and pin.registration_rmse_m > 2.0 * model.registration_rmse_m)
