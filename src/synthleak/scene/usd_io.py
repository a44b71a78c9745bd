"""USD stages: write a :class:`SceneSpec` as ``.usda``, read it back (spec or render scene), validate.

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

The readers also accept stages written by other tools: instances are prims with ``synthleak:instanceId``, else
``kind = component`` prims, else top-level children of the default prim; ``metersPerUnit`` and a Y up axis are
converted to metres and +z up; anything unsupported raises a python warning that names the prim.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Kind, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade, UsdValidation, Vt

from synthleak.assets.mesh import ObjectMesh, TexturedPart
from synthleak.errors import StageError
from synthleak.render.base import InstanceInfo, RenderMesh, RenderScene
from synthleak.scene.spec import Light, PlacedObject, SceneSpec
from synthleak.scene.texture_store import load_texture, store_texture

NS = "synthleak:"
_DEFAULT_COLOUR = (0.7, 0.7, 0.7)


# ----------------------------------------------------------------------------------------------- writing


def _usd_matrix(pose: np.ndarray) -> Gf.Matrix4d:
    return Gf.Matrix4d(np.asarray(pose, dtype=np.float64).T.tolist())


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
    verts = np.asarray(part.vertices, dtype=np.float32)
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
    st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(part.uv, dtype=np.float32)))
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
        ("extents", Sdf.ValueTypeNames.Double3, Gf.Vec3d(*map(float, obj.object_extents()))),
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


# ----------------------------------------------------------------------------------------------- reading


def open_stage(path: Path) -> Usd.Stage:
    """Open a stage, raising :class:`StageError` (naming the file) if it is missing, corrupt or broken."""
    path = Path(path)
    if not path.is_file():
        raise StageError(f"{path}: no such USD file")
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise StageError(f"{path}: cannot read USD stage: {str(exc).strip()}") from exc
    if stage is None:
        raise StageError(f"{path}: cannot read USD stage")
    errors = stage.GetCompositionErrors()
    if errors:
        details = "; ".join(str(e).strip().replace("\n", " ") for e in errors[:5])
        raise StageError(f"{path}: composition errors (broken reference or sublayer?): {details}")
    return stage


@dataclass
class _Part:
    prim_path: str
    name: str
    object_from_mesh: np.ndarray
    vertices: np.ndarray  # mesh frame (after unit conversion handled by the caller)
    faces: np.ndarray
    uv: np.ndarray | None
    texture: np.ndarray | None
    base_color: tuple[float, float, float]
    roughness: float
    metallic: float
    emissive: tuple[float, float, float] | None


@dataclass
class _Instance:
    prim: Usd.Prim
    instance_id: int
    world_from_object: np.ndarray  # converted to metres / z up
    attrs: dict[str, Any]
    parts: list[_Part] = field(default_factory=list)


@dataclass
class _StageContent:
    path: Path
    instances: list[_Instance]
    lights: list[Light]
    ambient: float
    data: dict[str, Any]


def _attr(prim: Usd.Prim, name: str) -> Any:
    attr = prim.GetAttribute(NS + name)
    return attr.Get() if attr and attr.HasAuthoredValue() else None


def _conversion(stage: Usd.Stage) -> tuple[np.ndarray, float]:
    """(rotation to +z up, metres per unit) of a stage."""
    scale = float(UsdGeom.GetStageMetersPerUnit(stage))
    rot = np.eye(3)
    if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y:
        rot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    return rot, scale


def _to_world(rot: np.ndarray, scale: float, usd_pose: Gf.Matrix4d) -> np.ndarray:
    """Column-vector pose in metres / z up from a USD (row-vector, stage-unit) matrix."""
    pose = np.array(usd_pose, dtype=np.float64).T
    out = np.eye(4)
    out[:3, :3] = rot @ pose[:3, :3]
    out[:3, 3] = scale * (rot @ pose[:3, 3])
    return out


def _to_object(rot: np.ndarray, scale: float, usd_pose: Gf.Matrix4d) -> np.ndarray:
    """``world_from_object`` of an instance prim: :func:`_to_world`, with the object's own axes converted to
    +z up as well, so that an instance of a Y-up stage has +z up in its object frame (its extents are
    [width, depth, height] and attacker orbits circle its vertical axis, as for synthleak's own objects)."""
    pose = _to_world(rot, scale, usd_pose)
    pose[:3, :3] = pose[:3, :3] @ rot.T
    return pose


def _triangulate(counts: np.ndarray, indices: np.ndarray, left_handed: bool) -> np.ndarray:
    """Fan triangulation; returns (T, 3) positions into the face-vertex (corner) list."""
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    c0 = starts[face]
    tris = np.stack([c0, c0 + k + 1, c0 + k + 2], axis=1)
    return tris[:, [0, 2, 1]] if left_handed else tris


def _connected_shader(inp: UsdShade.Input) -> tuple[UsdShade.Shader | None, str]:
    if not inp or not inp.HasConnectedSource():
        return None, ""
    sources = inp.GetConnectedSources()[0]
    if not sources:
        return None, ""
    info = sources[0]
    return UsdShade.Shader(info.source.GetPrim()), info.sourceName


def _packaged_texture(resolved: str) -> np.ndarray:
    """RGB uint8 texture stored inside a USDZ package (``/path/file.usdz[inner.png]``)."""
    from io import BytesIO

    from PIL import Image
    from pxr import Ar

    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
    if asset is None:
        raise OSError(f"cannot open {resolved}")
    with Image.open(BytesIO(bytes(asset.GetBuffer()))) as img:
        return np.asarray(img.convert("RGB"), dtype=np.uint8).copy()


@dataclass
class _Material:
    texture: np.ndarray | None = None
    base_color: tuple[float, float, float] = _DEFAULT_COLOUR
    roughness: float = 0.6
    metallic: float = 0.0
    emissive: tuple[float, float, float] | None = None
    varname: str = "st"


class _Reader:
    """Reads every instance, part and light of one stage."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.stage = open_stage(self.path)
        self.rot, self.scale = _conversion(self.stage)
        self.cache = UsdGeom.XformCache(Usd.TimeCode.Default())
        self.textures: dict[str, np.ndarray] = {}
        self.materials: dict[str, _Material] = {}

    def warn(self, prim: Usd.Prim, what: str) -> None:
        warnings.warn(f"{self.path}: prim {prim.GetPath()}: {what}", stacklevel=3)

    def fail(self, prim: Usd.Prim, what: str) -> StageError:
        return StageError(f"{self.path}: prim {prim.GetPath()}: {what}")

    # --- materials
    def material(self, prim: Usd.Prim) -> _Material:
        bound, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not bound:
            return _Material()
        key = str(bound.GetPath())
        if key not in self.materials:
            self.materials[key] = self._read_material(bound)
        return self.materials[key]

    def _read_material(self, material: UsdShade.Material) -> _Material:
        out = _Material()
        shader = material.ComputeSurfaceSource()[0]
        if not shader:
            self.warn(material.GetPrim(), "material has no surface shader; using a grey base colour")
            return out
        if shader.GetShaderId() != "UsdPreviewSurface":
            self.warn(
                shader.GetPrim(), f"shader {shader.GetShaderId()!r} is not UsdPreviewSurface; grey used"
            )
            return out
        for name in ("roughness", "metallic"):
            inp = shader.GetInput(name)
            if inp and inp.Get() is not None:
                setattr(out, name, float(inp.Get()))
        emissive = shader.GetInput("emissiveColor")
        if emissive and emissive.Get() is not None and any(float(c) > 0 for c in emissive.Get()):
            out.emissive = tuple(float(c) for c in emissive.Get())
        diffuse = shader.GetInput("diffuseColor")
        source, _ = _connected_shader(diffuse)
        if source is None:
            if diffuse and diffuse.Get() is not None:
                out.base_color = tuple(float(c) for c in diffuse.Get())
            return out
        if source.GetShaderId() != "UsdUVTexture":
            self.warn(
                source.GetPrim(), f"diffuseColor from {source.GetShaderId()!r} is unsupported; grey used"
            )
            return out
        file_input = source.GetInput("file")
        asset = file_input.Get() if file_input else None
        if asset is None or not asset.path:
            self.warn(source.GetPrim(), "UsdUVTexture without a file; grey used")
            return out
        resolved = asset.resolvedPath
        packaged = bool(resolved) and resolved.endswith("]") and "[" in resolved  # inside a .usdz package
        if not resolved or (not packaged and not Path(resolved).is_file()):
            raise self.fail(source.GetPrim(), f"texture {asset.path!r} not found")
        if resolved not in self.textures:
            try:
                self.textures[resolved] = _packaged_texture(resolved) if packaged else load_texture(Path(resolved))
            except OSError as exc:
                raise self.fail(source.GetPrim(), f"texture {asset.path!r} unreadable: {exc}") from exc
        out.texture = self.textures[resolved]
        reader, _ = _connected_shader(source.GetInput("st"))
        if reader is not None and reader.GetInput("varname") and reader.GetInput("varname").Get():
            out.varname = str(reader.GetInput("varname").Get())
        return out

    # --- meshes
    def part(self, mesh_prim: Usd.Prim, instance_prim: Usd.Prim) -> _Part:
        mesh = UsdGeom.Mesh(mesh_prim)
        points = mesh.GetPointsAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if points is None or len(points) == 0:
            raise self.fail(mesh_prim, "mesh has no points")
        if counts is None or indices is None or len(counts) == 0:
            raise self.fail(mesh_prim, "mesh has no faces (faceVertexCounts / faceVertexIndices)")
        points = np.asarray(points, dtype=np.float64) * self.scale
        counts = np.asarray(counts, dtype=np.int64)
        indices = np.asarray(indices, dtype=np.int64)
        if counts.sum() != len(indices) or indices.min() < 0 or indices.max() >= len(points):
            raise self.fail(mesh_prim, "faceVertexCounts / faceVertexIndices inconsistent with the points")
        if (counts < 3).any():
            self.warn(mesh_prim, "faces with fewer than 3 vertices are dropped")
        scheme = mesh.GetSubdivisionSchemeAttr().Get()
        if scheme not in (None, UsdGeom.Tokens.none) and mesh.GetSubdivisionSchemeAttr().HasAuthoredValue():
            self.warn(mesh_prim, f"subdivisionScheme {scheme!r} ignored (rendered as the control cage)")
        if UsdGeom.Subset.GetAllGeomSubsets(mesh):
            self.warn(mesh_prim, "GeomSubsets (per-face materials) ignored; the mesh binding is used")
        left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
        corners = _triangulate(counts, indices, left)
        material = self.material(mesh_prim)
        uv, faces, verts = None, indices[corners], points
        primvar = self._uv_primvar(mesh, material.varname)
        if primvar is not None:
            values = np.asarray(primvar.ComputeFlattened(), dtype=np.float64).reshape(-1, 2)
            interp = primvar.GetInterpolation()
            if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(values) == len(points):
                uv = values
            elif interp == UsdGeom.Tokens.faceVarying and len(values) == len(indices):
                verts, uv, faces = points[indices], values, corners  # unweld: one vertex per corner
            else:
                self.warn(
                    mesh_prim, f"texture coordinates with interpolation {interp!r} unsupported; ignored"
                )
        if uv is None and material.texture is not None:
            self.warn(mesh_prim, "textured material but no usable texture coordinates; base colour used")
        rel, _ = self.cache.ComputeRelativeTransform(mesh_prim, instance_prim)
        object_from_mesh = np.array(rel, dtype=np.float64).T
        object_from_mesh[:3, 3] *= self.scale
        object_from_mesh[:3] = self.rot @ object_from_mesh[:3]  # the object frame is +z up too (see _to_object)
        name = _attr(mesh_prim, "partName") or mesh_prim.GetName()
        return _Part(
            prim_path=str(mesh_prim.GetPath()),
            name=str(name),
            object_from_mesh=object_from_mesh,
            vertices=verts,
            faces=faces.astype(np.int64),
            uv=uv,
            texture=material.texture if uv is not None else None,
            base_color=material.base_color,
            roughness=material.roughness,
            metallic=material.metallic,
            emissive=material.emissive,
        )

    @staticmethod
    def _uv_primvar(mesh: UsdGeom.Mesh, varname: str) -> UsdGeom.Primvar | None:
        api = UsdGeom.PrimvarsAPI(mesh)
        primvar = api.GetPrimvar(varname)
        if primvar and primvar.HasValue():
            return primvar
        for candidate in api.GetPrimvarsWithValues():
            if candidate.GetTypeName() in (
                Sdf.ValueTypeNames.TexCoord2fArray,
                Sdf.ValueTypeNames.Float2Array,
            ):
                return candidate
        return None

    # --- instances
    def root(self) -> Usd.Prim:
        prim = self.stage.GetDefaultPrim()
        return prim if prim else self.stage.GetPseudoRoot()

    def instance_root(self, prim: Usd.Prim, root: Usd.Prim) -> Usd.Prim:
        """Nearest ancestor (or self) with an instance id or of kind component, else the top-level one."""
        chain = []
        p = prim
        while p and p != root and p.GetPath() != Sdf.Path.absoluteRootPath:
            chain.append(p)
            p = p.GetParent()
        for p in chain:
            if p.HasAttribute(NS + "instanceId") or Usd.ModelAPI(p).GetKind() == Kind.Tokens.component:
                return p
        return chain[-1] if chain else prim

    def read(self) -> _StageContent:
        root = self.root()
        lights: list[Light] = []
        dome = 0.0
        groups: dict[str, list[Usd.Prim]] = {}
        order: list[Usd.Prim] = []
        for prim in Usd.PrimRange(root, Usd.TraverseInstanceProxies()):
            if prim.IsA(UsdLux.DomeLight):
                dome += self._light_intensity(prim)
            elif (
                prim.HasAPI(UsdLux.LightAPI)
                or prim.IsA(UsdLux.BoundableLightBase)
                or prim.IsA(UsdLux.NonboundableLightBase)
            ):
                light = self.light(prim)
                if light is not None:
                    lights.append(light)
            elif prim.IsA(UsdGeom.Mesh):
                imageable = UsdGeom.Imageable(prim)
                if (
                    imageable.ComputeVisibility() != UsdGeom.Tokens.invisible
                    and imageable.ComputePurpose() != UsdGeom.Tokens.guide
                ):
                    inst = self.instance_root(prim, root)
                    if str(inst.GetPath()) not in groups:
                        groups[str(inst.GetPath())] = []
                        order.append(inst)
                    groups[str(inst.GetPath())].append(prim)
            elif prim.IsA(UsdGeom.Gprim) or prim.IsA(UsdGeom.PointInstancer):
                self.warn(prim, f"{prim.GetTypeName()} prims are not supported (only Mesh); skipped")
            elif prim.HasAttribute(NS + "instanceId") and str(prim.GetPath()) not in groups:
                groups[str(prim.GetPath())] = []
                order.append(prim)
        tagged = [p for p in order if p.HasAttribute(NS + "instanceId")]
        used = [int(p.GetAttribute(NS + "instanceId").Get()) for p in tagged]
        if len(set(used)) != len(used):
            raise StageError(f"{self.path}: duplicate synthleak:instanceId values")
        next_id = max(used, default=0) + 1
        instances = []
        for prim in order:
            if prim.HasAttribute(NS + "instanceId"):
                iid = int(prim.GetAttribute(NS + "instanceId").Get())
            else:
                iid, next_id = next_id, next_id + 1
            pose = _to_object(self.rot, self.scale, self.cache.GetLocalToWorldTransform(prim))
            attrs = {
                name: _attr(prim, name)
                for name in (
                    "name",
                    "modelId",
                    "category",
                    "symmetry",
                    "role",
                    "support",
                    "variantParams",
                    "extents",
                )
            }
            inst = _Instance(prim, iid, pose, attrs)
            inst.parts = [self.part(mesh, prim) for mesh in groups[str(prim.GetPath())]]
            instances.append(inst)
        data = dict(self.stage.GetRootLayer().customLayerData or {})
        ambient = float(data[NS + "ambient"]) if NS + "ambient" in data else dome
        return _StageContent(self.path, instances, lights, ambient, data)

    @staticmethod
    def _light_intensity(prim: Usd.Prim) -> float:
        api = UsdLux.LightAPI(prim)
        intensity = api.GetIntensityAttr().Get() or 0.0
        exposure = api.GetExposureAttr().Get() or 0.0
        return float(intensity) * float(2.0**exposure) if exposure else float(intensity)

    def light(self, prim: Usd.Prim) -> Light | None:
        api = UsdLux.LightAPI(prim)
        pose = _to_world(self.rot, self.scale, self.cache.GetLocalToWorldTransform(prim))
        colour = api.GetColorAttr().Get()
        common = {
            "name": str(_attr(prim, "name") or prim.GetName()),
            "world_from_light": pose,
            "intensity": self._light_intensity(prim),
            "color": tuple(float(c) for c in colour) if colour is not None else (1.0, 1.0, 1.0),
        }
        if prim.IsA(UsdLux.SphereLight):
            return Light(
                kind="sphere",
                radius=float(UsdLux.SphereLight(prim).GetRadiusAttr().Get()) * self.scale,
                **common,
            )
        if prim.IsA(UsdLux.RectLight):
            rect = UsdLux.RectLight(prim)
            size = (
                float(rect.GetWidthAttr().Get()) * self.scale,
                float(rect.GetHeightAttr().Get()) * self.scale,
            )
            return Light(kind="rect", size=size, **common)
        if prim.IsA(UsdLux.DistantLight):
            return Light(kind="distant", **common)
        self.warn(prim, f"light type {prim.GetTypeName()} unsupported; skipped")
        return None


def _extents(inst: _Instance) -> np.ndarray:
    if inst.attrs["extents"] is not None:
        return np.array(inst.attrs["extents"], dtype=np.float64)
    if not inst.parts:
        return np.zeros(3)
    pts = np.concatenate(
        [p.vertices @ p.object_from_mesh[:3, :3].T + p.object_from_mesh[:3, 3] for p in inst.parts]
    )
    return pts.max(axis=0) - pts.min(axis=0)


def _params(inst: _Instance, path: Path) -> dict[str, Any]:
    text = inst.attrs["variantParams"]
    if not text:
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise StageError(
            f"{path}: prim {inst.prim.GetPath()}: synthleak:variantParams is not JSON: {exc}"
        ) from exc


def _text(inst: _Instance, name: str, default: str) -> str:
    value = inst.attrs[name]
    return str(value) if value is not None else default


def _target(data: dict[str, Any]) -> int | None:
    value = data.get(NS + "targetInstanceId", -1)
    return None if value is None or int(value) < 0 else int(value)


def read_scene_spec(path: Path) -> SceneSpec:
    """Read a stage back into a :class:`SceneSpec` (object-frame meshes, exact transforms and attributes)."""
    reader = _Reader(Path(path))  # keeps the stage (and its prims) alive
    content = reader.read()
    objects = []
    for inst in content.instances:
        parts = []
        for p in inst.parts:
            verts = p.vertices @ p.object_from_mesh[:3, :3].T + p.object_from_mesh[:3, 3]
            texture = p.texture
            if texture is None:
                texture = np.full((1, 1, 3), np.round(np.clip(p.base_color, 0, 1) * 255), dtype=np.uint8)
            uv = p.uv if p.uv is not None else np.zeros((len(verts), 2))
            parts.append(
                TexturedPart(p.name, verts, p.faces, uv, texture, p.roughness, p.metallic, p.emissive)
            )
        objects.append(
            PlacedObject(
                instance_id=inst.instance_id,
                name=_text(inst, "name", inst.prim.GetName()),
                model_id=_text(inst, "modelId", inst.prim.GetName()),
                category=_text(inst, "category", "unknown"),
                symmetry=_text(inst, "symmetry", "none"),
                world_from_object=inst.world_from_object,
                mesh=ObjectMesh(parts),
                variant_params=_params(inst, content.path),
                role=_text(inst, "role", "object"),
                support=_text(inst, "support", "floor"),
                extents=_extents(inst),
            )
        )
    lights = content.lights
    data = content.data
    metadata = json.loads(data[NS + "metadata"]) if data.get(NS + "metadata") else {}
    return SceneSpec(
        name=str(data.get(NS + "name", content.path.stem)),
        kind=str(data.get(NS + "kind", "room")),
        objects=objects,
        lights=lights,
        room_size=tuple(float(v) for v in data.get(NS + "roomSize", (0.0, 0.0, 0.0))),
        seed=int(data.get(NS + "seed", 0)),
        target_instance_id=_target(data),
        ambient=content.ambient,
        metadata=metadata,
    )


def read_render_scene(path: Path) -> RenderScene:
    """Flatten any stage to world-space triangle meshes (metres, +z up), instance ids, lights, ambient."""
    reader = _Reader(Path(path))  # keeps the stage (and its prims) alive
    content = reader.read()
    meshes: list[RenderMesh] = []
    instances: dict[int, InstanceInfo] = {}
    for inst in content.instances:
        for p in inst.parts:
            world_from_mesh = inst.world_from_object @ p.object_from_mesh
            verts = p.vertices @ world_from_mesh[:3, :3].T + world_from_mesh[:3, 3]
            meshes.append(
                RenderMesh(
                    name=p.prim_path,
                    instance_id=inst.instance_id,
                    vertices=verts,
                    faces=p.faces,
                    uv=p.uv,
                    texture=p.texture,
                    base_color=p.base_color,
                    roughness=p.roughness,
                    metallic=p.metallic,
                    emissive=p.emissive,
                )
            )
        instances[inst.instance_id] = InstanceInfo(
            instance_id=inst.instance_id,
            name=_text(inst, "name", inst.prim.GetName()),
            model_id=_text(inst, "modelId", inst.prim.GetName()),
            category=_text(inst, "category", "unknown"),
            symmetry=_text(inst, "symmetry", "none"),
            role=_text(inst, "role", "object"),
            world_from_object=inst.world_from_object,
            extents=_extents(inst),
            variant_params=_params(inst, content.path),
            prim_path=str(inst.prim.GetPath()),
            support=_text(inst, "support", "floor"),
        )
    return RenderScene(
        meshes=meshes,
        lights=content.lights,
        instances=instances,
        ambient=content.ambient,
        source=str(path),
        kind=str(content.data.get(NS + "kind", "room")),
        target_instance_id=_target(content.data),
    )


# ----------------------------------------------------------------------------------------------- validation


def validate_stage(path: Path) -> list[str]:
    """Error messages of all ``pxr.UsdValidation`` validators (a validator that itself raises is skipped)."""
    stage = open_stage(Path(path))
    messages: list[str] = []
    for validator in UsdValidation.ValidationRegistry().GetOrLoadAllValidators():
        name = validator.GetMetadata().name
        try:
            errors = UsdValidation.ValidationContext([validator]).Validate(stage)
        except Tf.ErrorException:
            continue
        for error in errors:
            if error.GetType() == UsdValidation.ValidationErrorType.Error:
                messages.append(f"{path}: {name}: {error.GetMessage()}")
    return messages
