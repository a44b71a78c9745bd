"""USD stages: exact round trip, validation, world-space flattening against the built variants, errors,
and stages written by other tools (units, Y up, quads, faceVarying UVs)."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, Vt
from scipy.spatial.transform import Rotation

from synthleak.assets.mesh import ObjectMesh, TexturedPart
from synthleak.config import config_from_dict
from synthleak.core.types import Light
from synthleak.core.usd_read import read_render_scene
from synthleak.errors import StageError
from synthleak.geometry.poses import make_pose, transform_points
from synthleak.scene.generate import write_study_stages
from synthleak.scene.spec import PlacedObject, SceneSpec
from synthleak.scene.texture_store import encode_png, store_texture, texture_key
from synthleak.scene.usd_read import read_scene_spec
from synthleak.scene.usd_validate import validate_stage
from synthleak.scene.usd_write import write_stage


def _box_part(name: str, rng: np.random.Generator, size=(0.5, 0.4, 0.3)) -> TexturedPart:
    import trimesh

    b = trimesh.creation.box(size)
    b.apply_translation((0.0, 0.0, size[2] / 2))
    return TexturedPart(
        name=name,
        vertices=np.asarray(b.vertices, dtype=np.float64),
        faces=np.asarray(b.faces, dtype=np.int64),
        uv=rng.random((len(b.vertices), 2)),
        texture=rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
        roughness=0.25,
        metallic=0.5,
    )


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    return make_pose(Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.uniform(-3, 3, 3))


@pytest.fixture()
def handmade_spec() -> SceneSpec:
    rng = np.random.default_rng(5)
    objects = []
    for i in range(3):
        parts = [_box_part(f"part {k}/x", rng) for k in range(2)]
        parts[1].emissive = (1.0, 0.5, 0.25)
        objects.append(
            PlacedObject(
                instance_id=100 + i,
                name=f"obj {i}",
                model_id=f"model_{i}",
                category="chair",
                symmetry=["none", "2", "z"][i],
                world_from_object=_random_pose(rng),
                mesh=ObjectMesh(parts),
                variant_params={"seed": 2**62 + i, "scale": [1.0 / 3, 0.1, 2.0], "nested": {"a": 0.1 + 0.2}},
                role="shell" if i == 0 else "object",
                support=["none", "floor", "surface"][i],
                extents=rng.uniform(0.1, 2.0, 3),
            )
        )
    lights = [
        Light("sun", "distant", _random_pose(rng), 2.5, (1.0, 0.5, 0.25)),
        Light(
            "bulb", "sphere", make_pose(np.eye(3), [0.1, 0.2, 2.3]), 8.0, (0.75, 0.875, 1.0), radius=0.0625
        ),
        Light("panel", "rect", make_pose(np.eye(3), [-1.0, 0.5, 2.5]), 30.0, size=(0.5, 0.25)),
    ]
    return SceneSpec(
        "handmade",
        "attacker",
        objects,
        lights,
        (4.25, 3.5, 2.75),
        2**61 + 3,
        101,
        0.0625,
        {"style": "x", "list": [1, 2]},
    )


def test_round_trip_exact(tmp_path: Path, handmade_spec: SceneSpec) -> None:
    path = tmp_path / "scene.usda"
    write_stage(handmade_spec, path)
    back = read_scene_spec(path)
    assert (back.name, back.kind, back.seed, back.target_instance_id) == (
        "handmade",
        "attacker",
        2**61 + 3,
        101,
    )
    assert back.room_size == handmade_spec.room_size and back.ambient == handmade_spec.ambient
    assert back.metadata == handmade_spec.metadata
    assert [o.instance_id for o in back.objects] == [100, 101, 102]
    for a, b in zip(handmade_spec.objects, back.objects, strict=True):
        np.testing.assert_allclose(b.world_from_object, a.world_from_object, atol=1e-9, rtol=0)
        np.testing.assert_allclose(b.object_extents(), a.object_extents(), atol=5e-7, rtol=0)  # the 1 um grid
        assert (b.name, b.model_id, b.category, b.symmetry, b.role, b.support) == (
            a.name,
            a.model_id,
            a.category,
            a.symmetry,
            a.role,
            a.support,
        )
        assert b.variant_params == json.loads(json.dumps(a.variant_params))
        assert [p.name for p in b.mesh.parts] == [p.name for p in a.mesh.parts]
        for pa, pb in zip(a.mesh.parts, b.mesh.parts, strict=True):
            np.testing.assert_allclose(pb.vertices, pa.vertices, atol=1e-6)
            np.testing.assert_array_equal(pb.faces, pa.faces)
            np.testing.assert_allclose(pb.uv, pa.uv, atol=1e-6)
            np.testing.assert_array_equal(pb.texture, pa.texture)
            assert (pb.roughness, pb.metallic, pb.emissive) == (pa.roughness, pa.metallic, pa.emissive)
    assert [(l.name, l.kind) for l in back.lights] == [
        ("sun", "distant"),
        ("bulb", "sphere"),
        ("panel", "rect"),
    ]
    for a, b in zip(handmade_spec.lights, back.lights, strict=True):
        np.testing.assert_allclose(b.world_from_light, a.world_from_light, atol=1e-9, rtol=0)
        assert (b.intensity, b.color) == (a.intensity, a.color)
    assert back.lights[1].radius == 0.0625 and back.lights[2].size == (0.5, 0.25)
    assert validate_stage(path) == []


def test_stage_conventions(tmp_path: Path, handmade_spec: SceneSpec) -> None:
    path = tmp_path / "scene.usda"
    write_stage(handmade_spec, path)
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/World")
    prim = stage.GetPrimAtPath("/World/Objects/obj_1")
    assert Usd.ModelAPI(prim).GetKind() == Kind.Tokens.component
    # row-vector convention: a point maps as [p, 1] @ M
    usd_m = np.array(UsdGeom.Xformable(prim).GetLocalTransformation(), dtype=np.float64)
    p = np.array([0.3, -0.2, 0.7])
    pose = handmade_spec.objects[1].world_from_object
    np.testing.assert_allclose(
        (np.append(p, 1.0) @ usd_m)[:3], transform_points(pose, p[None])[0], atol=1e-12
    )
    assert prim.GetAttribute("synthleak:instanceId").Get() == 101
    assert prim.GetAttribute("synthleak:extents").GetTypeName() == Sdf.ValueTypeNames.Double3
    texts = sorted(p.name for p in (tmp_path / "textures").iterdir())
    assert texts == sorted(
        {f"{texture_key(p.texture)}.png" for o in handmade_spec.objects for p in o.mesh.parts}
    )


def test_texture_store_content_addressed(tmp_path: Path) -> None:
    tex = np.random.default_rng(1).integers(0, 256, (16, 20, 3), dtype=np.uint8)
    rel = store_texture(tex, tmp_path)
    assert rel == store_texture(tex.copy(), tmp_path)
    assert (tmp_path / rel).read_bytes() == encode_png(tex)
    other = tex.copy()
    other[0, 0, 0] ^= 1
    assert store_texture(other, tmp_path) != rel


# ------------------------------------------------------------------------------------------- study stages


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from synthleak.assets.library import load_library

    models = sorted(load_library())[:3]
    config = config_from_dict(
        {
            "name": "usd-tiny",
            "seed": 11,
            "scenes": {
                "rooms": 1,
                "objects_per_room": [2, 3],
                "distinct_objects": 3,
                "models": models,
                "lights_per_room": [2, 2],
            },
        }
    )
    out = tmp_path_factory.mktemp("stages")
    write_study_stages(config, out, progress=False)
    return out


def test_our_stages_validate(study: Path) -> None:
    stages = sorted(study.glob("*.usda"))
    assert any(p.name.startswith("room_") for p in stages) and any(
        p.name.startswith("attacker_") for p in stages
    )
    for stage in stages:
        assert validate_stage(stage) == [], stage


def test_render_scene_matches_built_variants(study: Path) -> None:
    from synthleak.assets.variants import variant_from_record

    index = json.loads((study / "index.json").read_text())
    for stage_name in [index["rooms"][0]["stage"], index["attacker_objects"][0]["stage"]]:
        spec = read_scene_spec(study / stage_name)
        scene = read_render_scene(study / stage_name)
        assert set(scene.instances) == {o.instance_id for o in spec.objects}
        assert scene.kind == spec.kind and scene.target_instance_id == spec.target_instance_id
        assert all(0 < o.instance_id < 100 for o in spec.objects if o.role == "shell")
        assert all(o.instance_id >= 100 for o in spec.objects if o.role == "object")
        checked = 0
        for obj in spec.objects:
            if obj.role != "object":
                continue
            built = variant_from_record(obj.variant_params).build()
            meshes = [m for m in scene.meshes if m.instance_id == obj.instance_id]
            assert len(meshes) == len(built.parts)
            for part, mesh in zip(built.parts, meshes, strict=True):
                np.testing.assert_allclose(
                    mesh.vertices, transform_points(obj.world_from_object, part.vertices), atol=1e-6, rtol=0
                )
                np.testing.assert_array_equal(mesh.faces, part.faces)
                np.testing.assert_allclose(mesh.uv, part.uv, atol=1e-6)
                np.testing.assert_array_equal(mesh.texture, part.texture)
            info = scene.instances[obj.instance_id]
            np.testing.assert_allclose(info.world_from_object, obj.world_from_object, atol=1e-12)
            np.testing.assert_allclose(info.extents, built.extents(), atol=5e-7, rtol=0)  # on the 1 um grid
            assert (info.model_id, info.support) == (obj.model_id, obj.support)
            checked += 1
        assert checked >= 1
        if spec.kind == "attacker":
            assert spec.target_instance_id == 100 and scene.instances[100].role == "object"


# ------------------------------------------------------------------------------------------- errors


def test_errors_name_the_file(tmp_path: Path, handmade_spec: SceneSpec) -> None:
    with pytest.raises(StageError, match="nothing.usda"):
        read_render_scene(tmp_path / "nothing.usda")
    corrupt = tmp_path / "corrupt.usda"
    corrupt.write_text('#usda 1.0\ndef Xform "World" {\n  this is not usd ((\n')
    with pytest.raises(StageError, match="corrupt.usda"):
        read_scene_spec(corrupt)
    with pytest.raises(StageError, match="corrupt.usda"):
        validate_stage(corrupt)

    stage_dir = tmp_path / "s"
    write_stage(handmade_spec, stage_dir / "scene.usda")
    shutil.rmtree(stage_dir / "textures")
    with pytest.raises(StageError, match=r"scene\.usda.*not found"):
        read_render_scene(stage_dir / "scene.usda")

    broken = tmp_path / "broken_ref.usda"
    stage = Usd.Stage.CreateNew(str(broken))
    prim = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(prim)
    prim.GetReferences().AddReference("./does_not_exist.usda")
    stage.GetRootLayer().Save()
    with pytest.raises(StageError, match="broken_ref.usda"):
        read_render_scene(broken)

    empty = tmp_path / "empty_mesh.usda"
    stage = Usd.Stage.CreateNew(str(empty))
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    UsdGeom.Mesh.Define(stage, "/World/thing")
    stage.GetRootLayer().Save()
    with pytest.raises(StageError, match=r"empty_mesh\.usda.*/World/thing.*no points"):
        read_render_scene(empty)


def test_validation_reports_problems(tmp_path: Path) -> None:
    bad = tmp_path / "bad.usda"
    stage = Usd.Stage.CreateNew(str(bad))
    UsdGeom.Xform.Define(stage, "/World")  # no defaultPrim, no upAxis, no metersPerUnit
    stage.GetRootLayer().Save()
    assert validate_stage(bad), "validators must flag a stage without defaultPrim / units"


# ------------------------------------------------------------------------------------------- foreign stages


def test_foreign_stage_units_up_axis_quads(tmp_path: Path) -> None:
    path = tmp_path / "foreign.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres
    root = UsdGeom.Xform.Define(stage, "/Root").GetPrim()
    stage.SetDefaultPrim(root)
    chair = UsdGeom.Xform.Define(stage, "/Root/Chair")
    Usd.ModelAPI(chair.GetPrim()).SetKind(Kind.Tokens.component)
    chair.AddTranslateOp().Set(Gf.Vec3d(100.0, 50.0, -200.0))
    quad = UsdGeom.Mesh.Define(stage, "/Root/Chair/seat")
    pts = np.array([[0, 0, 0], [10, 0, 0], [10, 0, 10], [0, 0, 10]], dtype=np.float32)
    quad.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    quad.CreateFaceVertexCountsAttr([4])
    quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(quad).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    st.Set(Vt.Vec2fArray.FromNumpy(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32)))
    table = UsdGeom.Xform.Define(stage, "/Root/Table")  # no kind: a top-level child is an instance too
    top = UsdGeom.Mesh.Define(stage, "/Root/Table/top")
    top.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    top.CreateFaceVertexCountsAttr([3, 3])
    top.CreateFaceVertexIndicesAttr([0, 1, 2, 0, 2, 3])
    UsdGeom.Sphere.Define(stage, "/Root/Table/knob")
    stage.GetRootLayer().Save()
    del table

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = read_render_scene(path)
    assert any("/Root/Table/knob" in str(w.message) for w in caught)
    assert sorted(scene.instances) == [1, 2]
    seat = next(m for m in scene.meshes if m.name == "/Root/Chair/seat")
    # fan-triangulated quad; faceVarying UVs unwelded to one vertex per face corner
    np.testing.assert_array_equal(seat.faces, [[0, 1, 2], [0, 2, 3]])
    assert seat.uv.shape == (4, 2)
    # cm -> m, Y up -> Z up: (x, y, z) -> (x, -z, y)
    expected = (pts + [100.0, 50.0, -200.0]) * 0.01
    expected = expected[:, [0, 2, 1]] * [1, -1, 1]
    np.testing.assert_allclose(seat.vertices, expected, atol=1e-6)
    info = scene.instances[1] if scene.instances[1].prim_path == "/Root/Chair" else scene.instances[2]
    np.testing.assert_allclose(info.world_from_object[:3, 3], [1.0, 2.0, 0.5], atol=1e-9)
    # the object frame is converted like the world: +z up (an unrotated Y-up prim is the identity rotation)
    np.testing.assert_allclose(info.world_from_object[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(info.extents, [0.1, 0.1, 0.0], atol=1e-6)  # the seat quad lies flat (z = height)


def test_example_stage_is_current_layout(tmp_path: Path) -> None:
    from synthleak.paths import scenes_usd_dir
    from synthleak.scene.example import example_spec

    shipped = scenes_usd_dir() / "example" / "room_example.usda"
    assert validate_stage(shipped) == []
    scene = read_render_scene(shipped)
    assert {100, 101} <= set(scene.instances) and all(0 < i < 100 for i in set(scene.instances) - {100, 101})
    spec = example_spec()
    write_stage(spec, tmp_path / "room_example.usda")
    back = read_scene_spec(tmp_path / "room_example.usda")
    box, table = (next(o for o in back.objects if o.instance_id == i) for i in (101, 100))
    # the box stands on the table top (0.75 m) within 5 mm
    lowest = transform_points(box.world_from_object, np.concatenate([p.vertices for p in box.mesh.parts]))[
        :, 2
    ].min()
    assert abs(lowest - 0.75) < 0.005 and table.support == "floor"
