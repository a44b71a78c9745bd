"""Read any USD stage (synthleak's own or one written by another tool) into world-space meshes, instances
and lights: :func:`read_stage` gives the instances with their parts in their object frames, and
:func:`read_render_scene` flattens them into the :class:`~synthleak.core.types.RenderScene` a renderer
consumes (the asset importer reads USD models through it too).

Instances are prims with ``synthleak:instanceId``, else ``kind = component`` prims, else top-level children of
the default prim; ``metersPerUnit`` and a Y up axis are converted to metres and +z up; anything unsupported
raises a python warning that names the prim. The layout synthleak writes is described in
:mod:`synthleak.scene.usd_write`; USD matrices act on row vectors, so a stored matrix is the transpose of our
column-vector 4x4.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from pxr import Ar, Gf, Kind, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade

from synthleak.core.types import InstanceInfo, Light, RenderMesh, RenderScene
from synthleak.errors import StageError

NS = "synthleak:"
"""Namespace of synthleak's custom attributes and layer data."""
_DEFAULT_COLOUR = (0.7, 0.7, 0.7)


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
class StagePart:
    """One mesh prim of an instance: triangles in the mesh frame, placed by ``object_from_mesh``."""

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
class StageInstance:
    """One instance prim: its id, ``world_from_object`` (metres, +z up), ``synthleak:*`` attributes, parts."""

    prim: Usd.Prim
    instance_id: int
    world_from_object: np.ndarray  # converted to metres / z up
    attrs: dict[str, Any]
    parts: list[StagePart] = field(default_factory=list)

    def text(self, name: str, default: str) -> str:
        """The string attribute ``synthleak:<name>``, ``default`` where it is not authored."""
        value = self.attrs[name]
        return str(value) if value is not None else default

    def extents(self) -> np.ndarray:
        """``synthleak:extents``, else the bounding-box size of the parts in the object frame."""
        if self.attrs["extents"] is not None:
            return np.array(self.attrs["extents"], dtype=np.float64)
        if not self.parts:
            return np.zeros(3)
        pts = np.concatenate(
            [p.vertices @ p.object_from_mesh[:3, :3].T + p.object_from_mesh[:3, 3] for p in self.parts]
        )
        return pts.max(axis=0) - pts.min(axis=0)

    def variant_params(self, path: Path) -> dict[str, Any]:
        """``synthleak:variantParams`` decoded (``{}`` where absent); a :class:`StageError` naming ``path``."""
        text = self.attrs["variantParams"]
        if not text:
            return {}
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise StageError(
                f"{path}: prim {self.prim.GetPath()}: synthleak:variantParams is not JSON: {exc}"
            ) from exc


@dataclass
class StageContent:
    """Everything read from one stage; holds the stage so that its prims stay valid."""

    stage: Usd.Stage
    path: Path
    instances: list[StageInstance]
    lights: list[Light]
    ambient: float
    data: dict[str, Any]
    """The root layer's ``customLayerData``."""

    @property
    def target_instance_id(self) -> int | None:
        value = self.data.get(NS + "targetInstanceId", -1)
        return None if value is None or int(value) < 0 else int(value)


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


def _load_texture(source: Path | BytesIO) -> np.ndarray:
    """(H, W, 3) uint8 array of an image file (alpha dropped, greyscale expanded)."""
    with Image.open(source) as img:
        return np.asarray(img.convert("RGB"), dtype=np.uint8).copy()


def _packaged_texture(resolved: str) -> np.ndarray:
    """RGB uint8 texture stored inside a USDZ package (``/path/file.usdz[inner.png]``)."""
    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
    if asset is None:
        raise OSError(f"cannot open {resolved}")
    return _load_texture(BytesIO(bytes(asset.GetBuffer())))


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
                self.textures[resolved] = _packaged_texture(resolved) if packaged else _load_texture(Path(resolved))
            except OSError as exc:
                raise self.fail(source.GetPrim(), f"texture {asset.path!r} unreadable: {exc}") from exc
        out.texture = self.textures[resolved]
        reader, _ = _connected_shader(source.GetInput("st"))
        if reader is not None and reader.GetInput("varname") and reader.GetInput("varname").Get():
            out.varname = str(reader.GetInput("varname").Get())
        return out

    # --- meshes
    def part(self, mesh_prim: Usd.Prim, instance_prim: Usd.Prim) -> StagePart:
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
        return StagePart(
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

    def read(self) -> StageContent:
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
            inst = StageInstance(prim, iid, pose, attrs)
            inst.parts = [self.part(mesh, prim) for mesh in groups[str(prim.GetPath())]]
            instances.append(inst)
        data = dict(self.stage.GetRootLayer().customLayerData or {})
        ambient = float(data[NS + "ambient"]) if NS + "ambient" in data else dome
        return StageContent(self.stage, self.path, instances, lights, ambient, data)

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


def read_stage(path: Path) -> StageContent:
    """Every instance (with its parts), light and the ambient term of the stage at ``path``."""
    return _Reader(Path(path)).read()


def read_render_scene(path: Path) -> RenderScene:
    """Flatten any stage to world-space triangle meshes (metres, +z up), instance ids, lights, ambient."""
    content = read_stage(path)
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
            name=inst.text("name", inst.prim.GetName()),
            model_id=inst.text("modelId", inst.prim.GetName()),
            category=inst.text("category", "unknown"),
            symmetry=inst.text("symmetry", "none"),
            role=inst.text("role", "object"),
            world_from_object=inst.world_from_object,
            extents=inst.extents(),
            variant_params=inst.variant_params(content.path),
            prim_path=str(inst.prim.GetPath()),
            support=inst.text("support", "floor"),
        )
    return RenderScene(
        meshes=meshes,
        lights=content.lights,
        instances=instances,
        ambient=content.ambient,
        source=str(path),
        kind=str(content.data.get(NS + "kind", "room")),
        target_instance_id=content.target_instance_id,
    )
