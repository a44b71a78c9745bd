"""Write a :class:`~synthleak.scene.spec.SceneSpec` as a ``.usda`` stage (read back by
:mod:`synthleak.scene.usd_read`, checked by :mod:`synthleak.scene.usd_validate`).

Stage layout written by :func:`write_stage` (metres, +z up, defaultPrim ``/World``)::

    /World                      Xform, kind=assembly
      /Shell/<piece>            Xform, kind=component, xformOp:transform = world_from_object (double)
      /Objects/<object>         same, with custom ``synthleak:*`` attributes
        /<part>                 Mesh, points in the object frame, primvars:st (vertex), bound material
        /Looks/<part>           Material: UsdPreviewSurface <- UsdUVTexture(textures/<hash>.png) <- st reader
      /Lights/<light>           UsdLux Sphere/Rect/DistantLight, DomeLight "ambient" for the fill term

USD matrices act on row vectors, so the stored matrix is the transpose of our column-vector 4x4.
Light intensities, colours and sizes are float32 in USD (compose with float32-representable values for an
exact round trip); transforms, extents and custom attributes are doubles / strings and round-trip exactly.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Kind, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from synthleak.assets.mesh import TexturedPart
from synthleak.core.types import Light
from synthleak.core.usd_read import NS
from synthleak.portable import LENGTH_STEP_M, UNIT_STEP, snap, snap_pose
from synthleak.scene.spec import PlacedObject, SceneSpec
from synthleak.scene.texture_store import store_texture


def _usd_matrix(pose: np.ndarray) -> Gf.Matrix4d:
    return Gf.Matrix4d(snap_pose(pose).T.tolist())


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, tuple | set):
        return list(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def to_json(value: Any) -> str:
    """Canonical JSON (sorted keys, numpy types converted) used for ``synthleak:variantParams``."""
    return json.dumps(value, sort_keys=True, default=_json_default, separators=(",", ":"))


class _Names:
    """Valid, unique prim names below one parent."""

    def __init__(self) -> None:
        self.used: set[str] = set()

    def __call__(self, name: str) -> str:
        base = Tf.MakeValidIdentifier(name or "item")
        out, i = base, 1
        while out in self.used:
            out, i = f"{base}_{i}", i + 1
        self.used.add(out)
        return out


def _add_transform(prim: Usd.Prim, pose: np.ndarray) -> None:
    op = UsdGeom.Xformable(prim).AddTransformOp(UsdGeom.XformOp.PrecisionDouble)
    op.Set(_usd_matrix(pose))


def _write_material(stage: Usd.Stage, path: str, part: TexturedPart, stage_dir: Path) -> UsdShade.Material:
    material = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(part.roughness))
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(part.metallic))
    if part.emissive is not None:
        surface.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*part.emissive))
    material.CreateSurfaceOutput().ConnectToSource(surface.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    reader = UsdShade.Shader.Define(stage, f"{path}/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    texture = UsdShade.Shader.Define(stage, f"{path}/diffuseTexture")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(
        Sdf.AssetPath(store_texture(part.texture, stage_dir))
    )
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    )
    texture.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    texture.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    )
    return material


def _write_mesh(stage: Usd.Stage, path: str, part: TexturedPart, material: UsdShade.Material) -> None:
    verts = snap(part.vertices, LENGTH_STEP_M).astype(np.float32)
    faces = np.asarray(part.faces, dtype=np.int32)
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(verts))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([verts.min(axis=0), verts.max(axis=0)])))
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
    )
    st.Set(Vt.Vec2fArray.FromNumpy(snap(part.uv, UNIT_STEP).astype(np.float32)))
    mesh.GetPrim().CreateAttribute(NS + "partName", Sdf.ValueTypeNames.String, custom=True).Set(part.name)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def _write_instance(stage: Usd.Stage, path: str, obj: PlacedObject, stage_dir: Path) -> None:
    xform = UsdGeom.Xform.Define(stage, path)
    prim = xform.GetPrim()
    Usd.ModelAPI(prim).SetKind(Kind.Tokens.component)
    _add_transform(prim, obj.world_from_object)
    attrs: list[tuple[str, Any, Any]] = [
        ("instanceId", Sdf.ValueTypeNames.Int, int(obj.instance_id)),
        ("name", Sdf.ValueTypeNames.String, obj.name),
        ("modelId", Sdf.ValueTypeNames.String, obj.model_id),
        ("category", Sdf.ValueTypeNames.String, obj.category),
        ("symmetry", Sdf.ValueTypeNames.String, obj.symmetry),
        ("role", Sdf.ValueTypeNames.String, obj.role),
        ("support", Sdf.ValueTypeNames.String, obj.support),
        ("variantParams", Sdf.ValueTypeNames.String, to_json(obj.variant_params)),
        ("extents", Sdf.ValueTypeNames.Double3, Gf.Vec3d(*map(float, snap(obj.object_extents(), LENGTH_STEP_M)))),
    ]
    for name, type_name, value in attrs:
        prim.CreateAttribute(NS + name, type_name, custom=True).Set(value)
    names = _Names()
    names("Looks")
    if obj.mesh.parts:
        UsdGeom.Scope.Define(stage, f"{path}/Looks")
    for part in obj.mesh.parts:
        name = names(part.name)
        material = _write_material(stage, f"{path}/Looks/{name}", part, stage_dir)
        _write_mesh(stage, f"{path}/{name}", part, material)


def _write_light(stage: Usd.Stage, path: str, light: Light) -> None:
    if light.kind == "sphere":
        lux = UsdLux.SphereLight.Define(stage, path)
        lux.CreateRadiusAttr(float(light.radius))
    elif light.kind == "rect":
        lux = UsdLux.RectLight.Define(stage, path)
        lux.CreateWidthAttr(float(light.size[0]))
        lux.CreateHeightAttr(float(light.size[1]))
    elif light.kind == "distant":
        lux = UsdLux.DistantLight.Define(stage, path)
    else:
        raise ValueError(
            f"light {light.name!r}: field 'kind' must be sphere, rect or distant, got {light.kind!r}"
        )
    lux.CreateIntensityAttr(float(light.intensity))
    lux.CreateColorAttr(Gf.Vec3f(*map(float, light.color)))
    lux.GetPrim().CreateAttribute(NS + "name", Sdf.ValueTypeNames.String, custom=True).Set(light.name)
    _add_transform(lux.GetPrim(), light.world_from_light)


def stage_to_string(spec: SceneSpec, stage_dir: Path) -> str:
    """The ``.usda`` text of ``spec``; textures are written to ``stage_dir/textures/``."""
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)
    Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
    groups = {}
    for group in ("Shell", "Objects"):
        prim = UsdGeom.Xform.Define(stage, f"/World/{group}").GetPrim()
        Usd.ModelAPI(prim).SetKind(Kind.Tokens.group)
        groups[group] = _Names()
    ids = [o.instance_id for o in spec.objects]
    if len(set(ids)) != len(ids):
        raise ValueError(f"scene {spec.name!r}: field 'instance_id' has duplicates")
    for obj in spec.objects:
        group = "Shell" if obj.role == "shell" else "Objects"
        _write_instance(stage, f"/World/{group}/{groups[group](obj.name)}", obj, stage_dir)
    if spec.lights or spec.ambient > 0:
        UsdGeom.Scope.Define(stage, "/World/Lights")
        names = _Names()
        names("ambient")
        for light in spec.lights:
            _write_light(stage, f"/World/Lights/{names(light.name)}", light)
        if spec.ambient > 0:
            dome = UsdLux.DomeLight.Define(stage, "/World/Lights/ambient")
            dome.CreateIntensityAttr(float(spec.ambient))
    stage.GetRootLayer().customLayerData = {
        NS + "name": spec.name,
        NS + "kind": spec.kind,
        NS + "seed": int(spec.seed),
        NS + "roomSize": Gf.Vec3d(*map(float, spec.room_size)),
        NS + "targetInstanceId": -1 if spec.target_instance_id is None else int(spec.target_instance_id),
        NS + "ambient": float(spec.ambient),
        NS + "metadata": to_json(spec.metadata),
    }
    return stage.GetRootLayer().ExportToString()


def write_stage(spec: SceneSpec, path: Path) -> None:
    """Write ``spec`` as a ``.usda`` stage at ``path`` (textures in ``path.parent/textures``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = stage_to_string(spec, path.parent)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
