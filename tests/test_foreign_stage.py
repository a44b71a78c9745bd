"""A stage as other tools write it: Y up, centimetres, a textured asset referenced from its own layer and placed
twice through instanceable prims, a variant-set selection, a payload and an unbound (default) material.

Ground truth must come out in metres, +z up, exact: unprojected depth lies on the independently computed
world geometry (trimesh closest point < 2 mm for >= 99 % of the pixels), and each placement gets its own id.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdShade

from synthleak.core.types import Camera
from synthleak.geometry.poses import invert, look_at
from synthleak.render.raycast import RaycastGT

CM = 0.01
HALF = np.array([20.0, 10.0, 30.0])  # asset box half sizes in cm (x, y = up, z); it stands on y = 0
ZUP_FROM_YUP = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
PLACEMENTS = {  # prim name: (translate cm, rotateY degrees, variant "size" selection)
    "Box_1": ((50.0, 0.0, -100.0), 30.0, None),
    "Box_2": ((-80.0, 0.0, -150.0), -20.0, "large"),
}
LARGE = 1.5


def _box_points() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cube with 6 quads: points (8, 3) cm y-up, face vertex counts and indices."""
    x, y, z = HALF
    pts = np.array([[sx * x, y + sy * y, sz * z] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return pts, np.full(6, 4), np.array(quads).ravel()


def _mesh(stage: Usd.Stage, path: str, pts: np.ndarray, counts, indices, uv: bool) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    mesh.CreateFaceVertexCountsAttr([int(c) for c in counts])
    mesh.CreateFaceVertexIndicesAttr([int(i) for i in indices])
    if uv:
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
            "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
        )
        st.Set([Gf.Vec2f(*c) for _ in range(len(counts)) for c in ((0, 0), (1, 0), (1, 1), (0, 1))])
    return mesh


def _new_stage(path: Path, default: str) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetDefaultPrim(stage.DefinePrim(f"/{default}", "Xform"))
    return stage


def write_asset(folder: Path) -> Path:
    """asset.usda: /Box (component) with a textured cube under /Box/Geom and a variant set 'size'."""
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[:8, :8] = texture[8:, 8:] = (200, 40, 40)
    texture[:8, 8:] = texture[8:, :8] = (240, 220, 60)
    cv2.imwrite(str(folder / "box_tex.png"), texture[..., ::-1])
    stage = _new_stage(folder / "asset.usda", "Box")
    box = stage.GetDefaultPrim()
    Usd.ModelAPI(box).SetKind(Kind.Tokens.component)
    geom = UsdGeom.Xform.Define(stage, "/Box/Geom")
    pts, counts, indices = _box_points()
    mesh = _mesh(stage, "/Box/Geom/Cube", pts, counts, indices, uv=True)
    material = UsdShade.Material.Define(stage, "/Box/Looks/Paint")
    surface = UsdShade.Shader.Define(stage, "/Box/Looks/Paint/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, "/Box/Looks/Paint/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, "/Box/Looks/Paint/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./box_tex.png")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    vset = box.GetVariantSets().AddVariantSet("size")
    for name in ("small", "large"):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        with vset.GetVariantEditContext():
            if name == "large":
                geom.AddScaleOp().Set(Gf.Vec3f(LARGE, LARGE, LARGE))
    vset.SetVariantSelection("small")
    stage.GetRootLayer().Save()
    return folder / "asset.usda"


def write_floor(folder: Path) -> Path:
    """floor.usda (loaded as a payload): a 6 x 6 m quad at y = 0 with no material (default grey)."""
    stage = _new_stage(folder / "floor.usda", "Floor")
    Usd.ModelAPI(stage.GetDefaultPrim()).SetKind(Kind.Tokens.component)
    pts = np.array([[-300.0, 0, -300], [-300, 0, 300], [300, 0, 300], [300, 0, -300]])
    _mesh(stage, "/Floor/Quad", pts, [4], [0, 1, 2, 3], uv=False)
    stage.GetRootLayer().Save()
    return folder / "floor.usda"


def write_room(folder: Path) -> Path:
    write_asset(folder)
    write_floor(folder)
    stage = _new_stage(folder / "room.usda", "World")
    floor = stage.DefinePrim("/World/Floor", "Xform")
    floor.GetPayloads().AddPayload("./floor.usda")
    for name, (t, yaw, variant) in PLACEMENTS.items():
        prim = stage.DefinePrim(f"/World/{name}", "Xform")
        prim.GetReferences().AddReference("./asset.usda")
        prim.SetInstanceable(True)
        xf = UsdGeom.Xformable(prim)
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*t))
        xf.AddRotateYOp(UsdGeom.XformOp.PrecisionDouble).Set(yaw)
        if variant:
            prim.GetVariantSets().GetVariantSet("size").SetVariantSelection(variant)
    stage.GetRootLayer().Save()
    return folder / "room.usda"


def expected_world_meshes() -> dict[str, trimesh.Trimesh]:
    """The geometry in metres, +z up, computed with numpy (not pxr) from the authored numbers."""
    pts, _, indices = _box_points()
    quads = indices.reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    out = {}
    for name, (t, yaw, variant) in PLACEMENTS.items():
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        rot_y = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        local = pts * (LARGE if variant == "large" else 1.0)
        world_cm = local @ rot_y.T + np.asarray(t)
        out[name] = trimesh.Trimesh(CM * world_cm @ ZUP_FROM_YUP.T, faces, process=False)
    floor = np.array([[-300.0, 0, -300], [-300, 0, 300], [300, 0, 300], [300, 0, -300]])
    out["Floor"] = trimesh.Trimesh(CM * floor @ ZUP_FROM_YUP.T, [[0, 1, 2], [0, 2, 3]], process=False)
    return out


def unprojected(camera: Camera, cam_from_world: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) world points of every pixel centre at its z-depth."""
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    depth = np.where(np.isfinite(depth), depth, 0.0)  # background pixels are never used
    cam = np.stack([(u - camera.cx) / camera.fx * depth, (v - camera.cy) / camera.fy * depth, depth], axis=-1)
    world_from_cam = invert(cam_from_world)
    return cam @ world_from_cam[:3, :3].T + world_from_cam[:3, 3]


def assert_on_surface(points_by_name: dict[str, np.ndarray], meshes: dict[str, trimesh.Trimesh]) -> None:
    total, good = 0, 0
    for name, pts in points_by_name.items():
        if len(pts):
            _, dist, _ = trimesh.proximity.closest_point(meshes[name], pts)
            total, good = total + len(pts), good + int((dist < 0.002).sum())
    assert total > 100
    assert good / total >= 0.99, f"only {good}/{total} unprojected pixels within 2 mm of the surface"


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    return write_room(tmp_path_factory.mktemp("foreign"))


def test_stage_really_uses_instancing_variants_and_payloads(room: Path) -> None:
    stage = Usd.Stage.Open(str(room))
    assert stage.GetPrimAtPath("/World/Box_1").IsInstance() and stage.GetPrimAtPath("/World/Box_2").IsInstance()
    assert stage.GetPrimAtPath("/World/Box_2").GetVariantSets().GetVariantSelection("size") == "large"
    assert stage.GetPrimAtPath("/World/Floor").HasAuthoredPayloads()
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 0.01


def test_foreign_stage_reads_in_metres_with_one_id_per_placement(room: Path) -> None:
    from synthleak.core.usd_read import read_render_scene

    scene = read_render_scene(room)
    by_path = {info.prim_path: iid for iid, info in scene.instances.items()}
    assert set(by_path) == {"/World/Floor", "/World/Box_1", "/World/Box_2"}
    assert len(set(by_path.values())) == 3
    expected = expected_world_meshes()
    for mesh in scene.meshes:
        name = scene.instances[mesh.instance_id].prim_path.rsplit("/", 1)[-1]
        got = np.unique(np.round(mesh.vertices, 9), axis=0)  # face-varying UVs unweld the corners
        assert np.allclose(got, np.unique(np.round(expected[name].vertices, 9), axis=0), atol=1e-6)
        if name.startswith("Box"):
            assert mesh.texture is not None and mesh.uv is not None  # UsdPreviewSurface texture kept
        else:
            assert mesh.texture is None and np.allclose(mesh.base_color, 0.7)  # unbound: default grey
    extents = scene.instances[by_path["/World/Box_2"]].extents
    assert np.allclose(np.sort(extents), np.sort(2 * HALF * CM * LARGE))


def test_foreign_stage_exact_gt_by_raycast(room: Path) -> None:
    from synthleak.core.usd_read import read_render_scene

    scene = read_render_scene(room)
    names = {iid: info.prim_path.rsplit("/", 1)[-1] for iid, info in scene.instances.items()}
    camera = Camera.from_hfov(96, 72, 60.0)
    pose = look_at((0.0, -3.4, 1.2), (-0.1, 1.2, 0.1))  # z up, metres: both boxes stand at y ~ 1.0-1.5
    depth, instance = RaycastGT(scene.meshes).render(camera, pose)
    seen = {names[i] for i in np.unique(instance) if i}
    assert {"Box_1", "Box_2", "Floor"} <= seen
    pts = unprojected(camera, pose, depth)
    assert_on_surface({names[i]: pts[instance == i] for i in np.unique(instance) if i}, expected_world_meshes())


def test_foreign_stage_through_the_render_pipeline(room: Path, tmp_path: Path) -> None:
    from synthleak.config import RenderConfig, StudyConfig
    from synthleak.core.dataset import load_sequence
    from synthleak.render.pipeline import render_sequence

    config = StudyConfig(
        name="foreign", seed=2, render=RenderConfig(width=64, height=48, spp=1, scene_frames=3, query_every=3)
    )
    out = render_sequence(room, tmp_path / "foreign", config, "scene", progress=False)
    seq = load_sequence(out)
    objects = json.loads((out / "objects.json").read_text())["instances"]
    names = {o["instance_id"]: o["prim_path"].rsplit("/", 1)[-1] for o in objects}
    assert sorted(names.values()) == ["Box_1", "Box_2", "Floor"]
    expected = expected_world_meshes()
    points: dict[str, list[np.ndarray]] = {n: [] for n in expected}
    for frame in seq.frames:
        depth, instance = seq.depth(frame), seq.instance(frame)
        assert set(np.unique(instance).tolist()) <= {0, *names}
        pts = unprojected(seq.camera, seq.pose(frame), depth)
        for iid, name in names.items():
            points[name].append(pts[instance == iid])
    assert_on_surface({n: np.concatenate(p) for n, p in points.items()}, expected)


ATTACKER_WRAPPER = """#usda 1.0
(
    customLayerData = {
        int "synthleak:targetInstanceId" = 1
    }
    defaultPrim = "World"
    metersPerUnit = 0.01
    upAxis = "Y"
)

def Xform "World"
{
    def "Box" (
        prepend references = @./asset.usda@
    )
    {
        custom int synthleak:instanceId = 1
    }
}
"""
"""An attacker setup around a foreign asset without editing it (docs/your-own-models.md): a layer that
references it, tags it with an instance id and names that id as the target."""


def test_folder_of_foreign_stages_renders_without_an_index(tmp_path: Path) -> None:
    """A folder of stages from another tool (no index.json): each stage that no other stage of the folder
    references renders as a scene sequence, a stage naming a target instance as an attacker sequence; a single
    stage file renders too. Through the real CLI."""
    import subprocess
    import sys

    from synthleak.core.dataset import load_sequence
    from tiny_stages import write_config

    folder = tmp_path / "stages"
    folder.mkdir()
    write_room(folder)  # room.usda references asset.usda and loads floor.usda as a payload
    (folder / "attacker_box.usda").write_text(ATTACKER_WRAPPER)
    config = write_config(tmp_path / "tiny.toml")
    out = tmp_path / "dataset"
    result = subprocess.run([sys.executable, "-m", "synthleak.cli", "render", str(config), "--stages", str(folder),
                             "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (out / "scenes").iterdir()) == ["room"]
    assert sorted(p.name for p in (out / "attackers").iterdir()) == ["attacker_box"]
    room = load_sequence(out / "scenes" / "room")
    assert len(room.frames) == 4 and all(room.image_path(f).is_file() for f in room.frames)
    attacker = load_sequence(out / "attackers" / "attacker_box")
    assert attacker.kind == "attacker" and attacker.target_instance_id == 1 and len(attacker.frames) == 2
    for seq in (room, attacker):  # no light in these stages: the default light (and a warning) lights them
        hit = np.isfinite(seq.depth(seq.frames[0]))
        lit = seq.rgb(seq.frames[0]).max(axis=-1) > 10
        assert hit.sum() > 100 and (lit & hit).sum() > 0.6 * hit.sum(), (seq.name, (lit & hit).sum(), hit.sum())
    assert "the stage has no light" in result.stderr
    assert (out / "manifest.json").is_file()

    single = tmp_path / "single"
    result = subprocess.run([sys.executable, "-m", "synthleak.cli", "render", str(config), "--stages",
                             str(folder / "room.usda"), "--out", str(single), "--quiet"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert [p.name for p in (single / "scenes").iterdir()] == ["room"] and not (single / "attackers").exists()
    assert (single / "scenes" / "room" / "images" / "000000.png").read_bytes() == room.image_path(0).read_bytes()
