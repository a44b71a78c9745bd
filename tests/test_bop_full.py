"""The whole BOP layout (render/bop_full.py): gt_info, masks, 16-bit depth, models in mm."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from synthleak.core.dataset import frame_name
from synthleak.core.types import Camera, InstanceInfo, Light, RenderMesh, RenderScene
from synthleak.geometry.poses import look_at, make_pose, transform_points
from synthleak.render.base import Frame
from synthleak.render.bop_full import depth_png, diameter, write_bop_extras, write_bop_models
from synthleak.render.dataset import write_frame, write_sequence_metadata
from synthleak.render.raycast import RaycastGT

W, H = 96, 72
FRONT, BACK, FLOOR = 101, 102, 1


def _box_mesh(name: str, iid: int, extents, pose: np.ndarray, colour) -> tuple[RenderMesh, InstanceInfo]:
    box = trimesh.creation.box(extents)
    box.apply_translation((0, 0, extents[2] / 2))  # canonical: bottom centre at the origin
    rng = np.random.default_rng(iid)
    tex = np.clip(np.asarray(colour) * 255 + rng.integers(-20, 20, (16, 16, 3)), 0, 255).astype(np.uint8)
    v = np.asarray(box.vertices)
    uv = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], axis=0)
    mesh = RenderMesh(name, iid, transform_points(pose, v), np.asarray(box.faces), uv, tex)
    role = "shell" if name == "floor" else "object"
    info = InstanceInfo(
        iid, name, f"model_{name}", name, "4" if name == "back" else "none", role, pose, np.array(extents, float)
    )
    return mesh, info


def box_scene() -> RenderScene:
    """A floor, a front box (101) and a box behind it (102), both seen from the camera of ``box_poses``."""
    items = [
        _box_mesh("floor", FLOOR, (6.0, 6.0, 0.02), make_pose(np.eye(3), (0, 0, -0.02)), (0.5, 0.5, 0.5)),
        _box_mesh("front", FRONT, (0.4, 0.3, 0.5), make_pose(np.eye(3), (0.0, 0.0, 0.0)), (0.8, 0.2, 0.2)),
        _box_mesh("back", BACK, (0.6, 0.4, 0.7), make_pose(np.eye(3), (0.15, 1.2, 0.0)), (0.2, 0.3, 0.8)),
    ]
    return RenderScene(
        meshes=[m for m, _ in items], lights=[], instances={i.instance_id: i for _, i in items}, source="boxes"
    )


def box_poses(n: int = 2) -> list[np.ndarray]:
    """Cameras in front of the boxes (-y side), looking at them along +y (the front box occludes the back)."""
    return [look_at((0.05 * k, -2.2, 0.9), (0.05 * k, 0.5, 0.3)) for k in range(n)]


def write_box_sequence(seq_dir: Path, scene: RenderScene | None = None, n: int = 2) -> tuple[Path, RenderScene]:
    """A sequence folder with exact ray-cast frames (flat-shaded RGB) and the standard metadata."""
    scene = scene or box_scene()
    camera = Camera.from_hfov(W, H, 60.0)
    poses = box_poses(n)
    frames = [frame_name(i) for i in range(n)]
    write_sequence_metadata(
        seq_dir,
        camera=camera,
        frames=frames,
        poses=poses,
        instances=[scene.instances[i] for i in sorted(scene.instances)],
        split={"map": frames[:-1], "query": frames[-1:]},
    )
    gt = RaycastGT(scene.meshes)
    colours = {m.instance_id: m.texture.reshape(-1, 3).mean(0) for m in scene.meshes}
    for name, pose in zip(frames, poses, strict=True):
        depth, inst = gt.render(camera, pose)
        rgb = np.zeros((H, W, 3), np.uint8)
        for iid, col in colours.items():
            rgb[inst == iid] = col.astype(np.uint8)
        write_frame(seq_dir, name, Frame(rgb, depth, inst))
    return seq_dir, scene


@pytest.fixture(scope="module")
def bop_seq(tmp_path_factory) -> tuple[Path, RenderScene]:
    seq_dir, scene = write_box_sequence(tmp_path_factory.mktemp("bop") / "room_000")
    write_bop_extras(seq_dir, scene, depth_scale=0.1)
    return seq_dir, scene


def test_gt_info_counts_and_visibility(bop_seq) -> None:
    seq_dir, _ = bop_seq
    gt = json.loads((seq_dir / "bop" / "scene_gt.json").read_text())
    info = json.loads((seq_dir / "bop" / "scene_gt_info.json").read_text())
    assert sorted(info, key=int) == sorted(gt, key=int)
    for key, entries in gt.items():
        assert len(info[key]) == len(entries)
        inst = cv2.imread(str(seq_dir / "instance" / f"{int(key):06d}.png"), cv2.IMREAD_UNCHANGED)
        by_id = {}
        for gt_id, (entry, gi) in enumerate(zip(entries, info[key], strict=True)):
            obj = entry["obj_id"]
            by_id[obj] = gi
            assert set(gi) == {
                "bbox_obj",
                "bbox_visib",
                "px_count_all",
                "px_count_valid",
                "px_count_visib",
                "visib_fract",
            }
            assert gi["px_count_visib"] == int((inst == obj).sum())
            visib = cv2.imread(str(seq_dir / "bop" / "mask_visib" / f"{int(key):06d}_{gt_id:06d}.png"), 0)
            full = cv2.imread(str(seq_dir / "bop" / "mask" / f"{int(key):06d}_{gt_id:06d}.png"), 0)
            assert np.array_equal(visib > 0, inst == obj)
            assert not np.any((visib > 0) & (full == 0))  # visible part lies inside the full silhouette
            if gi["px_count_visib"]:
                ys, xs = np.nonzero(inst == obj)
                assert gi["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
        front, back = by_id[FRONT], by_id[BACK]
        assert front["visib_fract"] == pytest.approx(1.0)
        assert front["px_count_all"] == front["px_count_visib"] == front["px_count_valid"]
        assert 0.0 < back["visib_fract"] < 0.9  # partly hidden behind the front box
        assert back["px_count_all"] > back["px_count_visib"]
        assert by_id[FLOOR]["visib_fract"] < 1.0


def test_depth_png_matches_float_depth(bop_seq) -> None:
    seq_dir, _ = bop_seq
    cams = json.loads((seq_dir / "bop" / "scene_camera.json").read_text())
    for key, cam in cams.items():
        assert cam["depth_scale"] == 0.1
        png = cv2.imread(str(seq_dir / "bop" / "depth" / f"{int(key):06d}.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16
        depth = np.load(seq_dir / "depth" / f"{int(key):06d}.npy")
        hit = np.isfinite(depth)
        assert np.all(png[~hit] == 0) and np.all(png[hit] > 0)
        assert np.abs(png[hit] * cam["depth_scale"] - depth[hit] * 1000.0).max() < 1.0


def test_depth_png_out_of_range_is_invalid() -> None:
    with pytest.warns(UserWarning, match="do not fit"):
        png = depth_png(np.array([[1.0, 7.0, np.inf]], np.float32), 0.1)
    assert png.tolist() == [[10000, 0, 0]]


def test_models_in_millimetres(bop_seq, tmp_path) -> None:
    seq_dir, scene = bop_seq
    info = json.loads((seq_dir / "bop" / "models" / "models_info.json").read_text())
    assert sorted(info, key=int) == [str(i) for i in sorted(scene.instances)]
    ply = trimesh.load(seq_dir / "bop" / "models" / f"obj_{FRONT:06d}.ply", process=False)
    ext = np.array([400.0, 300.0, 500.0])
    assert np.allclose(ply.extents, ext, atol=1e-3)
    assert np.allclose(ply.bounds[0], [-200.0, -150.0, 0.0], atol=1e-3)
    front = info[str(FRONT)]
    assert front["diameter"] == pytest.approx(float(np.linalg.norm(ext)), abs=1e-3)
    assert [front[f"size_{a}"] for a in "xyz"] == pytest.approx(ext.tolist(), abs=1e-3)
    assert front["min_z"] == pytest.approx(0.0, abs=1e-6)
    assert "symmetries_discrete" not in front and "symmetries_continuous" not in front
    sym = info[str(BACK)]["symmetries_discrete"]  # declared "4": 90, 180, 270 degrees about +z
    assert len(sym) == 3 and all(len(s) == 16 for s in sym)
    assert np.allclose(np.reshape(sym[0], (4, 4))[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert diameter(np.array([[0.0, 0, 0], [3, 4, 0]])) == pytest.approx(5.0)
    # the header is the ASCII layout bop_toolkit's inout.load_ply parses
    head = (seq_dir / "bop" / "models" / f"obj_{FRONT:06d}.ply").read_text().split("end_header")[0]
    assert "format ascii 1.0" in head and "property list uchar int vertex_indices" in head
    assert "property float nx" in head
    path = write_bop_models(tmp_path / "models", scene, [FRONT])
    assert json.loads(path.read_text()).keys() == {str(FRONT)}


def test_real_pipeline_sequence_gets_bop_extras(tmp_path) -> None:
    """A sequence rendered by the real pipeline (mitsuba, tiny) takes the extras without glue."""
    from synthleak.config import RenderConfig, StudyConfig
    from synthleak.render.pipeline import render_scene_sequence

    scene = box_scene()
    config = StudyConfig(
        name="t", seed=3, render=RenderConfig(width=48, height=36, spp=1, scene_frames=3, query_every=3)
    )
    scene.lights.append(Light("sun", "distant", look_at((0, 0, 0), (0.2, 0.3, -1)), 2.0))
    out = render_scene_sequence(scene, tmp_path / "room", config, "scene", progress=False)
    write_bop_extras(out, scene)
    info = json.loads((out / "bop" / "scene_gt_info.json").read_text())
    inst = cv2.imread(str(out / "instance" / "000000.png"), cv2.IMREAD_UNCHANGED)
    gt = json.loads((out / "bop" / "scene_gt.json").read_text())
    for entry, gi in zip(gt["0"], info["0"], strict=True):
        assert gi["px_count_visib"] == int((inst == entry["obj_id"]).sum())


def test_depth_pruned_silhouettes_equal_casting_every_pixel(bop_seq) -> None:
    """The rays gt_info_for skips (visible surface beyond the object's farthest vertex) would all miss:
    the pruned full masks equal a ray cast of every pixel of the image against the object alone."""
    from synthleak.core.dataset import load_sequence
    from synthleak.render.bop_full import ObjectSilhouette, gt_info_for, instance_model_meshes

    seq_dir, scene = bop_seq
    seq = load_sequence(seq_dir)
    camera = seq.camera
    meshes = instance_model_meshes(scene)
    gt = json.loads((seq_dir / "bop" / "scene_gt.json").read_text())
    u, v = (g.ravel() for g in np.meshgrid(np.arange(W), np.arange(H)))
    pruned_rays = 0
    for key, entries in gt.items():
        depth, inst = seq.depth(int(key)), seq.instance(int(key))
        for entry in entries:
            obj = int(entry["obj_id"])
            pose = make_pose(np.asarray(entry["cam_R_m2c"], float).reshape(3, 3),
                             np.asarray(entry["cam_t_m2c"], float) / 1000.0)
            silhouette = ObjectSilhouette(*meshes[obj])
            every_pixel = silhouette.hits(camera, pose, u, v).reshape(H, W)
            _, with_depth = gt_info_for(camera, pose, silhouette, inst == obj, np.isfinite(depth), depth=depth)
            _, without = gt_info_for(camera, pose, silhouette, inst == obj, np.isfinite(depth))
            assert np.array_equal(with_depth, every_pixel | (inst == obj))
            assert np.array_equal(with_depth, without)
            pruned_rays += int((np.isfinite(depth) & (inst != obj)).sum())
    assert pruned_rays > 0


def test_bop_extras_can_be_switched_off(tmp_path) -> None:
    """``[render] bop_extras = false``: the pipeline writes the core BOP files only; the rest is unchanged."""
    from synthleak.config import RenderConfig, StudyConfig
    from synthleak.render.pipeline import render_scene_sequence

    render = dict(width=48, height=36, spp=1, scene_frames=2, query_every=2)
    lit = box_scene()  # lit, and the same sequence name (it seeds the camera path): the images must match
    lit.lights.append(Light("lamp", "sphere", make_pose(np.eye(3), (0.0, -1.0, 2.5)), 8.0))
    on = render_scene_sequence(lit, tmp_path / "on" / "room", StudyConfig("t", 3, render=RenderConfig(**render)),
                               "scene", progress=False)
    off = render_scene_sequence(lit, tmp_path / "off" / "room",
                                StudyConfig("t", 3, render=RenderConfig(**render, bop_extras=False)),
                                "scene", progress=False)
    assert (on / "bop" / "scene_gt_info.json").is_file() and (on / "bop" / "mask").is_dir()
    assert sorted(p.name for p in (off / "bop").iterdir()) == ["rgb", "scene_camera.json", "scene_gt.json"]
    assert (on / "images" / "000001.png").read_bytes() == (off / "images" / "000001.png").read_bytes()
    assert cv2.imread(str(on / "images" / "000001.png")).mean() > 10  # not two black images


@pytest.mark.parametrize("links", [True, False])
def test_bop_scene_folders_hold_rgb(tmp_path, monkeypatch, links) -> None:
    """bop_toolkit looks for ``<scene>/rgb/<im_id:06d>.png``: every frame's image is there (a hard link to
    ``images/`` where the file system allows one, a copy otherwise; same bytes), also without the extras,
    and a resumed run remakes a missing or stale one."""
    import os

    from synthleak.config import RenderConfig, StudyConfig
    from synthleak.render.pipeline import render_scene_sequence

    if not links:
        def no_links(*args, **kwargs):
            raise OSError(1, "Operation not permitted (no hard links here)")

        monkeypatch.setattr(os, "link", no_links)
    config = StudyConfig("t", 3, render=RenderConfig(width=48, height=36, spp=1, scene_frames=3, query_every=3,
                                                     bop_extras=False))
    scene = box_scene()
    scene.lights.append(Light("lamp", "sphere", make_pose(np.eye(3), (0.0, -1.0, 2.5)), 8.0))
    seq = render_scene_sequence(scene, tmp_path / "room", config, "scene", progress=False)
    images = sorted((seq / "images").iterdir())
    rgb = sorted((seq / "bop" / "rgb").iterdir())
    assert [p.name for p in rgb] == [p.name for p in images] == ["000000.png", "000001.png", "000002.png"]
    gt = json.loads((seq / "bop" / "scene_gt.json").read_text())
    assert sorted(f"{int(k):06d}.png" for k in gt) == [p.name for p in rgb]  # im_id names, as BOP tools expect
    for image, copy in zip(images, rgb, strict=True):
        assert copy.read_bytes() == image.read_bytes()
        assert os.path.samefile(image, copy) == links
    rgb[1].unlink()
    replaced = images[2].with_suffix(".new")  # the image replaced by a new file (a re-render): a stale link
    replaced.write_bytes(images[2].read_bytes())
    os.replace(replaced, images[2])
    render_scene_sequence(scene, tmp_path / "room", config, "scene", progress=False)
    for image, copy in zip(images, rgb, strict=True):
        assert copy.read_bytes() == image.read_bytes()
        assert os.path.samefile(image, copy) == links


def test_mesh_behind_the_camera_is_clipped_not_cast_everywhere(bop_seq) -> None:
    """The floor reaches behind the camera: its cast box comes from the mesh clipped at the camera plane
    (smaller than the 3x enlarged image), and the enlarged silhouette's counts and box equal a ray cast of
    every pixel of the enlarged image."""
    from synthleak.core.dataset import load_sequence
    from synthleak.render.bop_full import ObjectSilhouette, _region, gt_info_for, instance_model_meshes

    seq_dir, scene = bop_seq
    seq = load_sequence(seq_dir)
    camera = seq.camera
    entry = next(e for e in json.loads((seq_dir / "bop" / "scene_gt.json").read_text())["0"]
                 if e["obj_id"] == FLOOR)
    pose = make_pose(np.asarray(entry["cam_R_m2c"], float).reshape(3, 3),
                     np.asarray(entry["cam_t_m2c"], float) / 1000.0)
    floor = ObjectSilhouette(*instance_model_meshes(scene)[FLOOR])
    z = transform_points(pose, floor.vertices)[:, 2]
    assert z.min() < 0 < z.max(), "the fixture's floor should straddle the camera plane"
    u0, u1, v0, v1, _ = _region(camera, pose, floor.vertices, floor.faces, enlarge=True)
    assert 0 < (u1 - u0) * (v1 - v0) < 0.8 * 9 * W * H
    u, v = (g.ravel() for g in np.meshgrid(np.arange(-W, 2 * W), np.arange(-H, 2 * H)))
    hit = floor.hits(camera, pose, u, v)
    depth, inst = seq.depth(0), seq.instance(0)
    info, _ = gt_info_for(camera, pose, floor, inst == FLOOR, np.isfinite(depth), enlarge=True, depth=depth)
    assert info["px_count_all"] == int(hit.sum()) > 0
    hu, hv = u[hit], v[hit]
    assert info["bbox_obj"] == [int(hu.min()), int(hv.min()), int(hu.max() - hu.min()), int(hv.max() - hv.min())]


def test_distorted_camera_beyond_the_lens_range_is_bounded_not_cast_everywhere(bop_seq, monkeypatch) -> None:
    """A barrel lens (k1 < 0) seeing the floor beyond its fold radius: the cast box comes from the lens image of
    what it can see (:func:`~synthleak.render.distortion.lens_image_bounds`), smaller than the 3x enlarged
    image, and the enlarged silhouette's counts and box equal a ray cast of every enlarged pixel; no ray lies
    beyond the fold (where the polynomial's radius turns back)."""
    import synthleak.render.bop_full as bop_full
    from synthleak.core.dataset import OpenCVCamera
    from synthleak.render.bop_full import ObjectSilhouette, _region, gt_info_for, instance_model_meshes
    from synthleak.render.distortion import lens_image_bounds, normalized_rays, radial_fold_radius

    seq_dir, scene = bop_seq
    pinhole = Camera.from_hfov(W, H, 60.0)
    camera = OpenCVCamera(W, H, pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy, k1=-0.3, k2=0.02)
    entry = next(e for e in json.loads((seq_dir / "bop" / "scene_gt.json").read_text())["0"]
                 if e["obj_id"] == FLOOR)
    pose = make_pose(np.asarray(entry["cam_R_m2c"], float).reshape(3, 3),
                     np.asarray(entry["cam_t_m2c"], float) / 1000.0)
    floor = ObjectSilhouette(*instance_model_meshes(scene)[FLOOR])
    bounded = []
    monkeypatch.setattr(bop_full, "lens_image_bounds", lambda *a: bounded.append(1) or lens_image_bounds(*a))
    u0, u1, v0, v1, _ = _region(camera, pose, floor.vertices, floor.faces, enlarge=True)
    assert bounded, "the fixture's floor should reach past the lens's range"
    assert 0 < (u1 - u0) * (v1 - v0) < 0.8 * 9 * W * H
    u, v = (g.ravel() for g in np.meshgrid(np.arange(-W, 2 * W), np.arange(-H, 2 * H)))
    x, y = normalized_rays(camera, u + 0.5, v + 0.5)
    ray = np.isfinite(x)
    assert 0 < ray.sum() < len(u) and np.all(x[ray] ** 2 + y[ray] ** 2 < radial_fold_radius(-0.3, 0.02, 0.0) ** 2)
    hit = floor.hits(camera, pose, u, v)
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    visible = np.zeros((H, W), bool)
    visible[v[hit & inside], u[hit & inside]] = True  # unoccluded: every in-image hit is visible
    info, _ = gt_info_for(camera, pose, floor, visible, visible, enlarge=True)
    assert info["px_count_all"] == int(hit.sum()) > 0
    hu, hv = u[hit], v[hit]
    assert info["bbox_obj"] == [int(hu.min()), int(hv.min()), int(hu.max() - hu.min()), int(hv.max() - hv.min())]
