"""Renderer, ground truth, dataset writer/reader and pipeline (tiny in-memory scenes, real mitsuba)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pycolmap
import pytest
import trimesh

from synthleak.config import ConfigError, RenderConfig, StudyConfig, config_from_dict
from synthleak.core.dataset import DatasetError, load_sequence
from synthleak.core.types import Camera, InstanceInfo, Light, RenderMesh, RenderScene
from synthleak.geometry.poses import camera_centre, invert, look_at, make_pose, transform_points
from synthleak.render.mitsuba_backend import MitsubaRenderer
from synthleak.render.pipeline import (
    StageError,
    plan_poses,
    render_scene_sequence,
    render_sequence,
    write_manifest,
)
from synthleak.render.raycast import RaycastGT
from synthleak.render.registry import RendererUnavailable, get_renderer
from synthleak.render.trajectories import orbit, walkthrough
from synthleak.seeding import make_rng

ROOM = (4.0, 3.5, 2.6)


# ------------------------------------------------------------------------------------------ scene helpers
def noise_texture(rng: np.random.Generator, size: int = 64) -> np.ndarray:
    """Blocky colour noise, upsampled so SIFT-like structure survives a tiny render."""
    small = rng.integers(0, 256, (size // 8, size // 8, 3), dtype=np.uint8)
    return np.ascontiguousarray(np.repeat(np.repeat(small, 8, axis=0), 8, axis=1))


def textured(name: str, iid: int, mesh: trimesh.Trimesh, world_from_object: np.ndarray, rng) -> RenderMesh:
    """A RenderMesh in world coordinates with planar-projected UVs (canonical frame) and a noise texture."""
    canon = np.asarray(mesh.vertices, dtype=np.float64)
    lo, hi = canon.min(axis=0), canon.max(axis=0)
    uv = (canon[:, [0, 2]] - lo[[0, 2]]) / np.maximum(hi - lo, 1e-9)[[0, 2]]
    uv[:, 0] = (uv[:, 0] + 0.37 * (canon[:, 1] - lo[1])) % 1.0
    return RenderMesh(
        name, iid, transform_points(world_from_object, canon), np.asarray(mesh.faces), uv, noise_texture(rng)
    )


def canonical_box(extents) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents)
    box.apply_translation((0, 0, extents[2] / 2))
    return box


def info(iid: int, name: str, pose: np.ndarray, extents, role: str = "object", support: str = "floor"):
    return InstanceInfo(
        iid,
        name,
        f"model_{name}",
        name,
        "none",
        role,
        pose,
        np.asarray(extents, float),
        {},
        f"/World/{name}",
        support,
    )


def room_scene(seed: int = 0) -> tuple[RenderScene, dict[int, trimesh.Trimesh]]:
    """A 4 x 3.5 x 2.6 m room (floor, walls, ceiling as shell instances) with three textured objects.

    Returns the scene and each object's canonical-frame mesh (for projection checks)."""
    rng = np.random.default_rng(seed)
    sx, sy, sz = ROOM
    meshes, instances, canon = [], {}, {}
    shell = {
        "floor": (make_pose(np.eye(3), (sx / 2, sy / 2, 0.0)), (sx, sy, 0.02), (0, 0, -0.01)),
        "ceiling": (make_pose(np.eye(3), (sx / 2, sy / 2, sz)), (sx, sy, 0.02), (0, 0, 0.01)),
        "wall_s": (make_pose(np.eye(3), (sx / 2, 0.0, 0.0)), (sx, 0.02, sz), (0, -0.01, sz / 2)),
        "wall_n": (make_pose(np.eye(3), (sx / 2, sy, 0.0)), (sx, 0.02, sz), (0, 0.01, sz / 2)),
        "wall_w": (make_pose(np.eye(3), (0.0, sy / 2, 0.0)), (0.02, sy, sz), (-0.01, 0, sz / 2)),
        "wall_e": (make_pose(np.eye(3), (sx, sy / 2, 0.0)), (0.02, sy, sz), (0.01, 0, sz / 2)),
    }
    for k, (name, (pose, ext, offset)) in enumerate(shell.items()):
        box = trimesh.creation.box(ext)
        box.apply_translation(offset)
        meshes.append(textured(name, 1 + k, box, pose, rng))
        instances[1 + k] = info(1 + k, name, pose, ext, role="shell")

    def yawed(yaw_deg, xyz):
        c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
        return make_pose([[c, -s, 0], [s, c, 0], [0, 0, 1]], xyz)

    objects = {
        101: ("cabinet", canonical_box((0.9, 0.45, 1.1)), yawed(0, (1.2, 3.0, 0.0))),
        102: ("table", canonical_box((1.0, 0.7, 0.75)), yawed(25, (2.9, 1.0, 0.0))),
        103: ("stool", trimesh.creation.cylinder(0.22, 0.5, sections=24), yawed(0, (0.6, 0.9, 0.0))),
    }
    for iid, (name, mesh, pose) in objects.items():
        if name == "stool":
            mesh.apply_translation((0, 0, 0.25))
        canon[iid] = mesh
        meshes.append(textured(name, iid, mesh, pose, rng))
        instances[iid] = info(iid, name, pose, mesh.extents)
    lights = [
        Light("lamp", "sphere", make_pose(np.eye(3), (sx / 2, sy / 2, sz - 0.3)), 4.0),
        Light("panel", "rect", make_pose(np.eye(3), (1.0, 1.0, sz - 0.01)), 3.0, size=(0.6, 0.6)),
    ]
    return RenderScene(meshes, lights, instances, ambient=0.15, source="test-room", kind="room"), canon


def attacker_scene(support: str = "floor", seed: int = 1) -> RenderScene:
    """One object (id 1) on a textured floor (id 2), placed and yawed off the origin."""
    rng = np.random.default_rng(seed)
    c, s = np.cos(0.7), np.sin(0.7)
    pose = make_pose([[c, -s, 0], [s, c, 0], [0, 0, 1]], (3.0, -2.0, 0.0 if support != "ceiling" else 2.2))
    obj = canonical_box((0.5, 0.4, 0.8))
    floor = trimesh.creation.box((8, 8, 0.02))
    floor.apply_translation((3.0, -2.0, -0.01))
    meshes = [textured("obj", 1, obj, pose, rng), textured("floor", 2, floor, np.eye(4), rng)]
    instances = {
        1: info(1, "chair", pose, obj.extents, support=support),
        2: info(2, "floor", np.eye(4), (8, 8, 0.02), role="shell"),
    }
    lights = [Light("sun", "distant", look_at((0, 0, 0), (0.3, 0.2, -1.0)) @ np.eye(4), 2.0)]
    return RenderScene(
        meshes, lights, instances, ambient=0.3, source="test-attacker", kind="attacker", target_instance_id=1
    )


def tiny_config(seed: int = 5, **render) -> StudyConfig:
    base = dict(width=120, height=90, spp=4, scene_frames=6, attacker_frames=4, query_every=3)
    return StudyConfig(name="tiny", seed=seed, render=RenderConfig(**{**base, **render}))


def tree_hashes(root: Path) -> dict[str, str]:
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def room():
    return room_scene()


@pytest.fixture(scope="module")
def rendered_room(tmp_path_factory, room):
    out = tmp_path_factory.mktemp("seq") / "room_000"
    render_scene_sequence(room[0], out, tiny_config(), "scene", progress=False)
    return out


# --------------------------------------------------------------------------------------------- GT checks
def test_gt_unprojects_onto_the_instance_surface(rendered_room, room):
    scene, _ = room
    rec = pycolmap.Reconstruction(str(rendered_room / "colmap"))
    cam = rec.cameras[1]
    fx, fy, cx, cy = cam.params
    seq = load_sequence(rendered_room)
    by_id = {}
    for m in scene.meshes:
        by_id[m.instance_id] = trimesh.Trimesh(m.vertices, m.faces, process=False)
    rng = np.random.default_rng(0)
    distances, checked_ids = [], set()
    for image in rec.images.values():
        cam_from_world = np.vstack([image.cam_from_world().matrix(), [0, 0, 0, 1]])
        depth, inst = seq.depth(image.name), seq.instance(image.name)
        v, u = np.nonzero(np.isfinite(depth))
        pick = rng.choice(len(u), size=min(400, len(u)), replace=False)
        u, v = u[pick], v[pick]
        z = depth[v, u].astype(np.float64)
        cam_pts = np.stack([(u + 0.5 - cx) / fx * z, (v + 0.5 - cy) / fy * z, z], axis=1)
        world = transform_points(invert(cam_from_world), cam_pts)
        for iid in np.unique(inst[v, u]):
            sel = inst[v, u] == iid
            _, dist, _ = trimesh.proximity.closest_point(by_id[int(iid)], world[sel])
            distances.append(dist)
            checked_ids.add(int(iid))
    distances = np.concatenate(distances)
    assert len(distances) > 1500
    assert {101, 102, 103} & checked_ids, "no furniture seen by the walk-through"
    assert np.mean(distances < 0.002) >= 0.99, np.percentile(distances, [50, 99])


def bop_projection_agreement(seq_dir: Path, canon: dict[int, trimesh.Trimesh]) -> tuple[int, int]:
    """Object surface points projected with the BOP GT poses: (how many land where the GT depth sees them, how
    many of those the instance mask gives to the object)."""
    import json

    seq = load_sequence(seq_dir)
    gt = json.loads((seq_dir / "bop" / "scene_gt.json").read_text())
    cams = json.loads((seq_dir / "bop" / "scene_camera.json").read_text())
    visible_total, agree_total = 0, 0
    for name in seq.frames:
        key = str(int(name.removesuffix(".png")))
        K = np.array(cams[key]["cam_K"]).reshape(3, 3)
        depth, inst = seq.depth(name), seq.instance(name)
        for entry in gt[key]:
            iid = entry["obj_id"]
            if iid not in canon:
                continue
            pts, _ = trimesh.sample.sample_surface(canon[iid], 600, seed=iid)
            cam_pts = pts @ np.array(entry["cam_R_m2c"]).reshape(3, 3).T + np.array(entry["cam_t_m2c"]) / 1000.0
            front = cam_pts[:, 2] > 0.05
            proj = cam_pts[front] @ K.T
            uv = np.floor(proj[:, :2] / proj[:, 2:3]).astype(int)
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < seq.camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < seq.camera.height)
            uv, z = uv[inside], cam_pts[front][inside, 2]
            visible = np.abs(depth[uv[:, 1], uv[:, 0]] - z) < 0.02  # the surface point is what the pixel sees
            visible_total += int(visible.sum())
            agree_total += int((inst[uv[visible, 1], uv[visible, 0]] == iid).sum())
    return visible_total, agree_total


def test_bop_object_poses_project_into_the_instance_mask(rendered_room, room):
    visible_total, agree_total = bop_projection_agreement(rendered_room, room[1])
    assert visible_total > 300  # a transposed rotation or metres-as-mm would leave almost nothing visible
    assert agree_total / visible_total > 0.95


def test_colmap_export_reads_back_exactly(rendered_room, room):
    poses = plan_poses(room[0], tiny_config(), "scene", "room_000")
    rec = pycolmap.Reconstruction(str(rendered_room / "colmap"))
    assert rec.num_images() == len(poses) and rec.num_points3D() == 0
    cam = rec.cameras[1]
    expect = Camera.from_hfov(120, 90, 65.0)
    assert cam.model == pycolmap.CameraModelId.PINHOLE
    assert np.allclose(cam.params, [expect.fx, expect.fy, expect.cx, expect.cy], rtol=0, atol=1e-12)
    for image in rec.images.values():
        index = int(image.name.removesuffix(".png"))
        got = image.cam_from_world().matrix()
        # images.txt holds q and t on the 1e-9 grid (synthleak.portable.POSE_STEP): R, quadratic in q, within 4 steps
        assert np.abs(got - poses[index][:3]).max() < 5e-9
    seq = load_sequence(rendered_room)
    assert seq.kind == "scene" and len(seq.frames) == 6
    assert all(np.abs(seq.cam_from_world[f] - poses[i]).max() < 5e-9 for i, f in enumerate(seq.frames))
    assert seq.split["query"] == ["000002.png", "000005.png"]
    assert sorted(seq.split["map"] + seq.split["query"]) == seq.frames
    assert seq.rgb(0).shape == (90, 120, 3) and seq.instance("000001").dtype == np.uint16


def test_attacker_sequence_is_stored_in_the_object_frame(tmp_path, rendered_room):
    scene = attacker_scene()
    out = render_scene_sequence(scene, tmp_path / "a01", tiny_config(), "attacker", progress=False)
    seq = load_sequence(out)
    assert seq.kind == "attacker" and seq.frame == "object" and seq.target_instance_id == 1
    assert np.allclose(seq.objects_by_id()[1].world_from_object, np.eye(4))
    world_poses = plan_poses(scene, tiny_config(), "attacker", "a01")
    world_from_object = scene.instances[1].world_from_object
    box = canonical_box((0.5, 0.4, 0.8))  # the target in its canonical (object) frame
    distances = []
    for i, name in enumerate(seq.frames):
        cam_from_object = seq.cam_from_object[name]
        assert np.allclose(cam_from_object, world_poses[i] @ world_from_object, atol=1e-12)
        # the object's canonical centre projects near the image centre and is the visible instance there
        centre = transform_points(cam_from_object, [[0, 0, 0.4]])[0]
        u, v = (seq.camera.K @ centre)[:2] / centre[2]
        assert abs(u - 60) < 25 and abs(v - 45) < 20
        assert (seq.instance(name) == 1).mean() > 0.15
        # the rendered depth of the target's pixels, taken back through object_from_cam, lies on the canonical box
        depth, on_target = seq.depth(name), seq.instance(name) == 1
        v_px, u_px = np.nonzero(on_target & np.isfinite(depth))
        z = depth[v_px, u_px].astype(np.float64)
        k = seq.camera.K
        cam_pts = np.stack([(u_px + 0.5 - k[0, 2]) / k[0, 0] * z, (v_px + 0.5 - k[1, 2]) / k[1, 1] * z, z], axis=1)
        distances.append(trimesh.proximity.closest_point(box, transform_points(invert(cam_from_object), cam_pts))[1])
    distances = np.concatenate(distances)
    assert len(distances) > 1000 and np.mean(distances < 0.002) >= 0.99, np.percentile(distances, [50, 99])
    # one name per frame: an attacker sequence has no cam_from_world, a scene sequence no cam_from_object
    with pytest.raises(DatasetError, match=r"objects\.json.*'object'.*cam_from_object"):
        seq.cam_from_world  # noqa: B018
    with pytest.raises(DatasetError, match=r"objects\.json.*'world'.*cam_from_world"):
        load_sequence(rendered_room).cam_from_object  # noqa: B018


# --------------------------------------------------------------------------------------------- mitsuba
def silhouette_iou(camera: Camera, pose: np.ndarray) -> float:
    obj = canonical_box((0.8, 0.5, 0.9))
    stool = trimesh.creation.cylinder(0.2, 0.6, sections=32)
    meshes = [
        RenderMesh("box", 1, obj.vertices + (0.3, 0, 0), obj.faces, None, None, emissive=(1, 1, 1)),
        RenderMesh("cyl", 2, stool.vertices + (-0.7, 0.4, 0.3), stool.faces, None, None, emissive=(1, 1, 1)),
    ]
    renderer = MitsubaRenderer(spp=64)
    renderer.prepare(RenderScene(meshes, [], {}))
    frame = renderer.render(camera, pose, seed=3)
    lit = frame.rgb[..., 0] >= 188  # linear coverage > 0.5 in sRGB
    mask = frame.instance > 0
    return float((lit & mask).sum() / (lit | mask).sum())


@pytest.mark.parametrize("principal_point", [None, (70.3, 40.6)])
def test_mitsuba_silhouette_matches_raycast_mask(principal_point):
    camera = Camera.from_hfov(160, 120, 60.0)
    if principal_point:  # off-centre principal point must move mitsuba's image like the ray cast's
        camera = Camera(160, 120, camera.fx, camera.fy, *principal_point)
    pose = look_at((2.5, -2.2, 1.6), (0.0, 0.1, 0.4))
    assert silhouette_iou(camera, pose) > 0.98


def test_mitsuba_texture_orientation():
    """Texture row 0 is the top (uv v = 1), column 0 the left (u = 0), as a wall facing the camera shows."""
    tex = np.zeros((32, 32, 3), np.uint8)
    tex[:16, :16] = (255, 0, 0)  # top-left red
    tex[:16, 16:] = (0, 255, 0)  # top-right green
    tex[16:, :] = (0, 0, 255)  # bottom blue
    verts = np.array([[-1, 2, 0], [1, 2, 0], [1, 2, 2], [-1, 2, 2]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    renderer = MitsubaRenderer(spp=4)
    lamp = Light("lamp", "sphere", make_pose(np.eye(3), (0, 0.5, 1.0)), 6.0)
    renderer.prepare(RenderScene([RenderMesh("wall", 1, verts, faces, uv, tex)], [lamp], {}))
    rgb = renderer.render(Camera.from_hfov(64, 48, 40.0), look_at((0, 0.5, 1.0), (0, 2, 1.0)), 1).rgb.astype(int)
    top_left, top_right, bottom = rgb[8, 16], rgb[8, 48], rgb[40, 32]
    assert top_left[0] > 150 > top_left[1] and top_right[1] > 150 > top_right[0] and bottom[2] > 150 > bottom[0]


def test_raycast_depth_is_z_depth():
    """A plane at z = 2 in camera coordinates has depth exactly 2 everywhere (not the ray length)."""
    plane = RenderMesh(
        "p",
        7,
        np.array([[-5, -5, 2], [5, -5, 2], [5, 5, 2], [-5, 5, 2]], float),
        np.array([[0, 1, 2], [0, 2, 3]]),
        None,
        None,
    )
    depth, inst = RaycastGT([plane]).render(Camera.from_hfov(40, 30, 90.0), np.eye(4))
    assert np.all(inst == 7) and np.abs(depth - 2.0).max() < 1e-6


# ------------------------------------------------------------------------------------ pipeline behaviour
def test_determinism_and_resume(tmp_path, room):
    scene = room[0]
    config = tiny_config(seed=11, scene_frames=5)
    a, b = tmp_path / "a" / "room_000", tmp_path / "b" / "room_000"
    render_scene_sequence(scene, a, config, "scene", progress=False)
    render_scene_sequence(scene, b, config, "scene", progress=False)
    write_manifest(a.parent, config)
    write_manifest(b.parent, config)
    full = tree_hashes(a.parent)
    assert full == tree_hashes(b.parent)  # same seed, same bytes, manifest included
    bop_extras = ("bop/scene_gt_info.json", "bop/mask/", "bop/mask_visib/", "bop/depth/", "bop/models/")
    core = [k for k in full if not any(part in k for part in bop_extras)]
    assert len(core) == 5 * 4 + 7 + 1  # 3 files per frame and its bop/rgb link, 7 metadata files, the manifest
    assert sum("bop/mask_visib/" in k for k in full) > 0  # the full BOP layout is written too
    # simulate an interrupt: frames partly missing, a stray temp file, metadata not yet written
    (b / "images" / "000002.png").unlink()
    (b / "depth" / "000004.npy").unlink()
    (b / "instance" / "000004.png").unlink()
    (b / "split.json").unlink()
    (b / "images" / ".tmp-000003.png.x1y2").write_bytes(b"half a png")
    depth1 = b / "depth" / "000001.npy"  # a truncated file (e.g. copied by hand) is not a complete frame
    depth1.write_bytes(depth1.read_bytes()[:-100])
    image0 = b / "images" / "000000.png"
    image0.write_bytes(image0.read_bytes()[:200])
    (b.parent / "manifest.json").unlink()
    render_scene_sequence(scene, b, config, "scene", progress=False)
    write_manifest(b.parent, config)
    assert tree_hashes(b.parent) == full
    c = tmp_path / "c" / "room_000"
    render_scene_sequence(scene, c, tiny_config(seed=12, scene_frames=5), "scene", progress=False)
    assert tree_hashes(c)["images/000000.png"] != full["room_000/images/000000.png"]


def test_registry():
    assert get_renderer(RenderConfig(renderer="mitsuba")).name == "mitsuba"
    for name in ("pyrender", "blender"):  # registered; either usable or a clear install hint
        try:
            assert get_renderer(RenderConfig(renderer=name)).name == name
        except RendererUnavailable as exc:
            assert name in str(exc) and "install" in str(exc)
    with pytest.raises(RendererUnavailable, match="nosuch"):
        get_renderer(RenderConfig(renderer="nosuch"))
    with pytest.raises(ValueError, match="integrator"):
        get_renderer(RenderConfig(integrator="bidir"))


# ------------------------------------------------------------------------------------------------ errors
def test_clear_errors(tmp_path, rendered_room):
    with pytest.raises(StageError, match="room_404.usda"):
        render_sequence(tmp_path / "room_404.usda", tmp_path / "out", tiny_config(), "scene", progress=False)
    with pytest.raises(ConfigError, match="render.sppp"):
        config_from_dict({"name": "x", "render": {"sppp": 4}})
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(rendered_room, broken)
    images = broken / "colmap" / "images.txt"
    images.write_text(_corrupt(images.read_text()))
    with pytest.raises(DatasetError, match=r"images\.txt.*000003\.png.*non-finite"):
        load_sequence(broken)
    (broken / "objects.json").write_text("{}")
    images.write_text((rendered_room / "colmap" / "images.txt").read_text())
    with pytest.raises(DatasetError, match=r"objects\.json.*'instances'"):
        load_sequence(broken)


def _corrupt(text: str) -> str:
    """Replace the translation x of image 000003.png with nan."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.endswith("000003.png"):
            tok = line.split()
            tok[5] = "nan"
            lines[i] = " ".join(tok)
    return "\n".join(lines) + "\n"


def test_broken_stage_reference(tmp_path):
    stage = tmp_path / "room_broken.usda"
    stage.write_text(
        '#usda 1.0\n(\n    defaultPrim = "World"\n)\n\ndef Xform "World" (\n'
        "    references = @./missing_mesh.usda@\n)\n{\n}\n"
    )
    with pytest.raises(StageError, match="room_broken.usda"):
        render_sequence(stage, tmp_path / "out", tiny_config(), "scene", progress=False)


# ------------------------------------------------------------------------------------------ trajectories
def test_walkthrough_stays_in_the_room_at_eye_height(room):
    scene, _ = room
    poses = walkthrough(scene, 40, make_rng(0, "t"))
    centres = np.array([camera_centre(p) for p in poses])
    assert np.all(centres[:, 0] > 0.5) and np.all(centres[:, 0] < ROOM[0] - 0.5)
    assert np.all(centres[:, 1] > 0.5) and np.all(centres[:, 1] < ROOM[1] - 0.5)
    assert np.all((centres[:, 2] >= 1.3) & (centres[:, 2] <= 1.8))
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert steps.max() < 0.6  # consecutive frames are close
    forward = np.array([p[2, :3] for p in poses])
    assert np.all(np.degrees(np.arccos(np.clip(np.sum(forward[1:] * forward[:-1], 1), -1, 1))) < 30)
    assert np.all(forward[:, 2] < 0.05)  # looking slightly down at the furniture
    again = walkthrough(scene, 40, make_rng(0, "t"))
    assert all(np.array_equal(x, y) for x, y in zip(poses, again, strict=True))


@pytest.mark.parametrize("support", ["floor", "wall", "ceiling"])
def test_orbit_frames_the_target(support):
    scene = attacker_scene(support)
    poses = orbit(scene, 1, 24, make_rng(0, "o", support))
    obj = scene.instances[1]
    camera = Camera.from_hfov(640, 480, 65.0)
    centre_world = transform_points(obj.world_from_object, [[0, 0, 0.4]])[0]
    corners = np.array([[x, y, z] for x in (-0.25, 0.25) for y in (-0.2, 0.2) for z in (0, 0.8)])
    azimuths, elevations = [], []
    for pose in poses:
        cam_pts = transform_points(pose @ obj.world_from_object, corners)
        assert np.all(cam_pts[:, 2] > 0.1)
        uv = cam_pts @ camera.K.T
        uv = uv[:, :2] / uv[:, 2:]
        span = (uv.max(0) - uv.min(0)) / [640, 480]
        assert span.max() > 0.35  # the object fills a large part of the frame
        eye_obj = transform_points(invert(obj.world_from_object), [camera_centre(pose)])[0] - [0, 0, 0.4]
        azimuths.append(np.degrees(np.arctan2(eye_obj[0], eye_obj[1])))
        elevations.append(np.degrees(np.arcsin(eye_obj[2] / np.linalg.norm(eye_obj))))
        assert np.linalg.norm(camera_centre(pose) - centre_world) > 0.5
    azimuths, elevations = np.array(azimuths), np.array(elevations)
    if support == "wall":
        assert np.all(np.abs(azimuths) <= 76)
    else:
        assert np.ptp(np.unwrap(np.radians(azimuths))) > np.radians(300)
    if support == "ceiling":
        assert np.all(elevations < -5)
    elif support == "floor":
        assert np.all((elevations > 5) & (elevations < 65))


# ------------------------------------------------------------------------ real stages (`synthleak scenes`)
@pytest.fixture(scope="module")
def real_dataset(tmp_path_factory):
    """ci-tiny stages from synthleak's stage writer, rendered tiny: 3 walk-through, 2 orbit frames."""
    from synthleak.config import load_config
    from synthleak.render.pipeline import generate

    base = load_config("ci-tiny")
    config = StudyConfig(
        **{
            **base.__dict__,
            "render": RenderConfig(
                **{
                    **base.render.__dict__,
                    "width": 120,
                    "height": 90,
                    "spp": 1,
                    "scene_frames": 3,
                    "attacker_frames": 2,
                    "query_every": 3,
                }
            ),
        }
    )
    out = tmp_path_factory.mktemp("study")
    generate(config, out, progress=False)
    return out, config


def test_real_stages_ground_truth_and_layout(real_dataset):
    from synthleak.core.usd_read import read_render_scene

    out, _ = real_dataset
    index = __import__("json").loads((out / "stages" / "index.json").read_text())
    manifest = __import__("json").loads((out / "manifest.json").read_text())
    room = index["rooms"][0]
    seq = load_sequence(out / "scenes" / room["name"])
    scene = read_render_scene(out / "stages" / room["stage"])
    meshes: dict[int, list] = {}
    for m in scene.meshes:
        meshes.setdefault(m.instance_id, []).append(trimesh.Trimesh(m.vertices, m.faces, process=False))
    distances = []
    for name in seq.frames:
        depth, inst = seq.depth(name), seq.instance(name)
        v, u = np.nonzero(np.isfinite(depth))
        z = depth[v, u].astype(np.float64)
        K = seq.camera.K
        cam_pts = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0] * z, (v + 0.5 - K[1, 2]) / K[1, 1] * z, z], axis=1)
        world = transform_points(invert(seq.cam_from_world[name]), cam_pts)
        for iid in np.unique(inst[v, u]):
            sel = inst[v, u] == iid
            mesh = trimesh.util.concatenate(meshes[int(iid)])
            distances.append(trimesh.proximity.closest_point(mesh, world[sel][::7])[1])
    distances = np.concatenate(distances)
    assert len(distances) > 500 and np.mean(distances < 0.002) >= 0.99
    assert {p for p in manifest["files"]} >= {f"scenes/{room['name']}/images/000000.png", "stages/index.json"}
    assert manifest["packages"]["mitsuba"] and manifest["seed"] == index["seed"]
    for entry in index["attacker_objects"]:
        att = load_sequence(out / "attackers" / entry["id"])
        assert att.kind == "attacker" and att.target_instance_id == entry["target_instance_id"]
        target = att.objects_by_id()[att.target_instance_id]
        assert np.allclose(target.world_from_object, np.eye(4))
        # the canonical-frame centre of the target is in view, in front, and the target is what is seen
        for name in att.frames:
            centre = transform_points(att.cam_from_object[name], [[0, 0, target.extents[2] / 2]])[0]
            uv = (att.camera.K @ centre)[:2] / centre[2]
            assert centre[2] > 0 and np.all(np.abs(uv - [60, 45]) < [40, 30])
            assert (att.instance(name) == att.target_instance_id).mean() > 0.05


def test_real_stage_errors(real_dataset, tmp_path):
    out, config = real_dataset
    stages = out / "stages"
    room_stage = next(stages.glob("room_*.usda"))
    # a stage whose mesh reference points at a file that does not exist
    broken = tmp_path / "room_broken.usda"
    text = room_stage.read_text()
    dangling = '\ndef Xform "Dangling" (\n    prepend references = @./no_such_mesh.usda@\n)\n{\n}\n'
    broken.write_text(text + dangling)
    with pytest.raises(StageError, match=r"room_broken\.usda.*no_such_mesh"):
        render_sequence(broken, tmp_path / "seq", config, "scene", progress=False)
    # an index naming a stage file that is gone: clear error, nothing rendered is lost
    import shutil

    copy = tmp_path / "stages"
    shutil.copytree(stages, copy)
    room_stage_copy = copy / room_stage.name
    room_stage_copy.unlink()
    before = tree_hashes(out / "scenes")
    from synthleak.render.pipeline import render_stages

    with pytest.raises(StageError, match=room_stage.name):
        render_stages(config, copy, out, progress=False)
    assert tree_hashes(out / "scenes") == before


def test_resume_refuses_another_config(tmp_path, room):
    out = tmp_path / "room_000"
    render_scene_sequence(room[0], out, tiny_config(seed=1, scene_frames=2), "scene", progress=False)
    with pytest.raises(DatasetError, match=r"cameras\.txt.*other cameras"):
        config = tiny_config(seed=1, scene_frames=2, width=100)
        render_scene_sequence(room[0], out, config, "scene", progress=False)
    with pytest.raises(DatasetError, match=r"images\.txt.*other cameras or poses"):
        render_scene_sequence(room[0], out, tiny_config(seed=2, scene_frames=2), "scene", progress=False)
