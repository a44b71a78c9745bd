"""Blender (bpy as a Python module, Cycles on CPU) backend: path-traced RGB with GT from render passes.

bpy 5.0 needs Python 3.11 and numpy<2, so it lives in its own venv (``pip install -e .[blender]``).

Per frame two Cycles renders of the same bpy scene, each written to a multilayer EXR (``media_type =
'MULTI_LAYER_IMAGE'``, 32-bit float) and read back with the ``OpenEXR`` package:

* RGB: ``config.spp`` samples, 1-px box pixel filter (mitsuba's ``box``), fixed seed, no denoiser, no
  adaptive sampling; the linear Combined pass is sRGB-encoded here.
* ground truth: 1 sample with the narrowest pixel filter Cycles allows (0.01 px), so the single camera ray
  passes within 0.005 px of the pixel centre ``(u + 0.5, v + 0.5)``, with a black emission material
  override (no shading cost). The Z pass is z-depth (Cycles writes 1e10 where nothing is hit: +inf here).
  The 16-bit instance id is split over the object index pass (``pass_index``, low 15 bits; Blender caps it
  at 32767) and the material index pass (bit 15; scenes with such ids render GT without the override).

Scene: one object per :class:`RenderMesh` (flat-shaded, UVs per loop, image textures through a Principled
BSDF; Blender images start at the bottom row, as our uv convention does), ``sphere`` -> point light with
``radius``, ``rect`` -> rectangular area light (emits along -z, like ours), ``distant`` -> sun, ``ambient``
-> uniform world colour. Light units follow mitsuba's: point power = 4 pi I (W), area power = pi L A,
sun strength = irradiance. ``integrator = "direct"`` is Cycles with 0 bounces, ``"path"`` has
``max_depth - 2`` bounces (mitsuba's depth counts the camera and light segments).
Camera: OpenCV -> Blender axes ``diag(1, -1, -1)``, horizontal sensor fit,
principal point through ``shift_x`` / ``shift_y`` (both in units of the image width under that fit).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.config import RenderConfig
from synthleak.core.types import Camera, Light, RenderMesh, RenderScene
from synthleak.errors import MissingDependencyError
from synthleak.render.base import Frame

INSTALL_HINT = (
    "bpy needs Python 3.11 and numpy<2, so use a separate venv: python3.11 -m venv /work/venv-blender && "
    "/work/venv-blender/bin/pip install -e '.[blender]' (bpy 5.0.1, OpenEXR, numpy<2)"
)
_CV_TO_BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])
_NO_HIT = 1e9
"""Cycles writes 1e10 into the Z pass where a ray escapes; anything beyond this is +inf."""
_SENSOR_WIDTH_MM = 36.0
_owner: list[object] = []
"""The renderer whose scene bpy holds now (bpy is one Blender instance per process)."""


class BlenderUnavailable(MissingDependencyError):
    """bpy or OpenEXR cannot be imported here; the message says how to install them."""


def _modules() -> tuple[Any, Any]:
    try:
        import bpy
        import OpenEXR
    except ImportError as exc:
        msg = f"renderer 'blender' is unavailable ({exc}); install: {INSTALL_HINT}"
        raise BlenderUnavailable(msg) from exc
    return bpy, OpenEXR


def linear_to_srgb_uint8(rgb: np.ndarray) -> np.ndarray:
    """Linear radiance (H, W, 3) -> sRGB-encoded uint8 (clipped, rounded), as the mitsuba backend does."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def _srgb_to_linear(c: tuple[float, float, float]) -> list[float]:
    x = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).tolist()


def blender_camera_matrix(cam_from_world: np.ndarray) -> np.ndarray:
    """Blender camera ``matrix_world`` (looks along -z, +y up) for an OpenCV ``cam_from_world``."""
    pose = np.asarray(cam_from_world, dtype=np.float64)
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = pose[:3, :3].T
    world_from_cam[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return world_from_cam @ _CV_TO_BLENDER


def camera_shift(camera: Camera) -> tuple[float, float]:
    """(shift_x, shift_y) for a principal point (cx, cy), horizontal sensor fit (units of the width)."""
    return (camera.width / 2.0 - camera.cx) / camera.width, (camera.cy - camera.height / 2.0) / camera.width


class BlenderRenderer:
    """Renderer protocol implementation; see the module docstring. One per process (bpy is a singleton)."""

    name = "blender"

    def __init__(self, spp: int = 8, integrator: str = "direct", max_depth: int = 3,
                 threads: int = 0) -> None:
        if spp < 1:
            raise ValueError(f"render.spp: must be >= 1, got {spp}")
        if integrator not in ("direct", "path"):
            raise ValueError(f"render.integrator: {integrator!r} is not 'direct' or 'path'")
        self._bpy, self._exr = _modules()
        self.spp, self.threads = spp, threads
        # mitsuba's max_depth counts the camera segment and the light segment: depth 2 = direct light only.
        self.max_bounces = 0 if integrator == "direct" else max(int(max_depth) - 2, 0)
        self._tmp = tempfile.TemporaryDirectory(prefix="synthleak-blender-")
        self._camera: Any = None
        self._gt_override: Any = None

    # ------------------------------------------------------------------------------------ scene building

    def prepare(self, scene: RenderScene) -> None:
        """Reset Blender to an empty file and build the scene: meshes, materials, lights, world, camera."""
        bpy = self._bpy
        if not scene.meshes:
            raise ValueError("blender: the scene has no meshes")
        bpy.ops.wm.read_factory_settings(use_empty=True)
        _owner[:] = [self]
        bscene = bpy.context.scene
        for i, mesh in enumerate(scene.meshes):
            self._add_mesh(bscene, mesh, i)
        for light in scene.lights:
            self._add_light(bscene, light)
        world = bpy.data.worlds.new("ambient")
        background = _node_tree(world).nodes["Background"]
        background.inputs["Color"].default_value = (*([float(max(scene.ambient, 0.0))] * 3), 1.0)
        background.inputs["Strength"].default_value = 1.0
        bscene.world = world
        cam_data = bpy.data.cameras.new("camera")
        cam_data.sensor_fit = "HORIZONTAL"
        cam_data.sensor_width = _SENSOR_WIDTH_MM
        cam_data.clip_start = 0.01
        cam_data.clip_end = 1000.0
        self._camera = bpy.data.objects.new("camera", cam_data)
        bscene.collection.objects.link(self._camera)
        bscene.camera = self._camera
        self._gt_override = None
        if max(int(m.instance_id) for m in scene.meshes) <= 0x7FFF:
            self._gt_override = self._flat_material()
        self._configure(bscene)

    def _flat_material(self) -> Any:
        """A black emission-only material: the GT pass then skips all shading and light sampling."""
        material = self._bpy.data.materials.new("synthleak_gt_override")
        tree = _node_tree(material)
        tree.nodes.clear()
        emission = tree.nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 0.0
        output = tree.nodes.new("ShaderNodeOutputMaterial")
        tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
        return material

    def _add_mesh(self, bscene: Any, mesh: RenderMesh, index: int) -> None:
        bpy = self._bpy
        verts, faces = mesh.checked_arrays()
        if not 0 <= int(mesh.instance_id) <= 0xFFFF:
            raise ValueError(f"mesh {mesh.name!r}: instance_id {mesh.instance_id} does not fit uint16")
        data = bpy.data.meshes.new(f"m{index}_{mesh.name}")
        data.vertices.add(len(verts))
        data.vertices.foreach_set("co", verts.astype(np.float32).ravel())
        data.loops.add(faces.size)
        data.loops.foreach_set("vertex_index", faces.astype(np.int32).ravel())
        data.polygons.add(len(faces))
        data.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
        data.polygons.foreach_set("use_smooth", np.zeros(len(faces), dtype=bool))
        textured = mesh.texture is not None and mesh.uv is not None
        if textured:
            uv = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2)
            if len(uv) != len(verts):
                raise ValueError(f"mesh {mesh.name!r}: {len(uv)} uvs for {len(verts)} vertices")
            layer = data.uv_layers.new(name="UVMap")
            layer.data.foreach_set("uv", uv[faces].astype(np.float32).ravel())  # v = 0 at the bottom, as ours
        data.update()
        data.validate()
        material = self._material(mesh, index, textured)
        material.pass_index = int(mesh.instance_id) >> 15
        data.materials.append(material)
        obj = bpy.data.objects.new(f"o{index}_{mesh.name}", data)
        obj.pass_index = int(mesh.instance_id) & 0x7FFF
        bscene.collection.objects.link(obj)

    def _material(self, mesh: RenderMesh, index: int, textured: bool) -> Any:
        bpy = self._bpy
        material = bpy.data.materials.new(f"mat{index}_{mesh.name}")
        nodes = _node_tree(material).nodes
        bsdf = nodes.get("Principled BSDF") or nodes.new("ShaderNodeBsdfPrincipled")
        if textured:
            tex = np.asarray(mesh.texture, dtype=np.uint8)[..., :3]
            h, w = tex.shape[:2]
            image = bpy.data.images.new(f"tex{index}_{mesh.name}", width=w, height=h, alpha=False)
            rgba = np.concatenate([tex, np.full((h, w, 1), 255, np.uint8)], axis=2)[::-1]  # bottom row first
            image.colorspace_settings.name = "sRGB"  # before the pixels: changing it regenerates the image
            image.pixels.foreach_set((rgba.astype(np.float32) / 255.0).ravel())
            image.update()
            node = nodes.new("ShaderNodeTexImage")
            node.image = image
            node.interpolation = "Linear"
            material.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            bsdf.inputs["Base Color"].default_value = (*_srgb_to_linear(mesh.base_color), 1.0)
        bsdf.inputs["Roughness"].default_value = float(np.clip(mesh.roughness, 0.05, 1.0))
        bsdf.inputs["Metallic"].default_value = float(np.clip(mesh.metallic, 0.0, 1.0))
        if mesh.emissive is not None and max(mesh.emissive) > 0:
            bsdf.inputs["Emission Color"].default_value = (*[float(c) for c in mesh.emissive], 1.0)
            bsdf.inputs["Emission Strength"].default_value = 1.0
        return material

    def _add_light(self, bscene: Any, light: Light) -> None:
        bpy = self._bpy
        color = np.clip(np.asarray(light.color, dtype=np.float64), 0.0, None)
        scale = float(color.max()) if color.max() > 0 else 1.0
        if light.kind == "sphere":
            data = bpy.data.lights.new(light.name, type="POINT")
            data.energy = 4.0 * math.pi * float(light.intensity) * scale
            data.shadow_soft_size = float(light.radius)
        elif light.kind == "rect":
            data = bpy.data.lights.new(light.name, type="AREA")
            data.shape = "RECTANGLE"
            data.size, data.size_y = float(light.size[0]), float(light.size[1])
            area = float(light.size[0]) * float(light.size[1])
            data.energy = math.pi * float(light.intensity) * area * scale
        elif light.kind == "distant":
            data = bpy.data.lights.new(light.name, type="SUN")
            data.energy = float(light.intensity) * scale
            data.angle = 0.0
        else:
            raise ValueError(f"light {light.name!r}: unknown kind {light.kind!r} (sphere | rect | distant)")
        data.color = tuple(float(c) / scale for c in color)
        obj = bpy.data.objects.new(light.name, data)
        obj.matrix_world = self._matrix(np.asarray(light.world_from_light, dtype=np.float64))
        obj.visible_camera = False  # lights are not geometry: no hit in the Z / index passes, as in mitsuba
        bscene.collection.objects.link(obj)

    def _matrix(self, m: np.ndarray) -> Any:
        from mathutils import Matrix

        return Matrix([[float(x) for x in row] for row in m])

    def _configure(self, bscene: Any) -> None:
        bscene.render.engine = "CYCLES"
        cycles = bscene.cycles
        cycles.device = "CPU"
        cycles.use_denoising = False
        cycles.use_adaptive_sampling = False
        cycles.use_animated_seed = False
        cycles.max_bounces = int(self.max_bounces)
        cycles.sample_clamp_indirect = 0.0
        bscene.render.use_persistent_data = True
        if self.threads > 0:
            bscene.render.threads_mode = "FIXED"
            bscene.render.threads = int(self.threads)
        bscene.render.resolution_percentage = 100
        bscene.render.film_transparent = False
        bscene.render.use_compositing = False
        bscene.render.use_sequencer = False
        layer = bscene.view_layers[0]
        layer.use_pass_z = True
        layer.use_pass_object_index = True
        layer.use_pass_material_index = True
        settings = bscene.render.image_settings
        settings.media_type = "MULTI_LAYER_IMAGE"  # bpy 5.0: the only file format left is multilayer EXR
        if settings.file_format != "OPEN_EXR_MULTILAYER":
            raise RuntimeError(f"blender: expected multilayer EXR output, got {settings.file_format!r}")
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"

    # ------------------------------------------------------------------------------------ rendering

    def _require_scene(self) -> None:
        if self._camera is None:
            raise RuntimeError("BlenderRenderer.render before prepare(scene)")
        if not _owner or _owner[0] is not self:
            raise RuntimeError("BlenderRenderer: another BlenderRenderer prepared a scene since "
                               "(bpy holds one scene per process); call prepare(scene) again")

    def _render_exr(self, camera: Camera, cam_from_world: np.ndarray, spp: int, seed: int,
                    filter_type: str, filter_width: float) -> dict[str, np.ndarray]:
        self._require_scene()
        if abs(camera.fx - camera.fy) > 1e-9 * camera.fx:
            raise ValueError(f"blender needs square pixels: fx={camera.fx} fy={camera.fy}")
        bscene = self._bpy.context.scene
        bscene.render.resolution_x, bscene.render.resolution_y = camera.width, camera.height
        cam = self._camera.data
        cam.lens = camera.fx * _SENSOR_WIDTH_MM / camera.width
        cam.shift_x, cam.shift_y = camera_shift(camera)
        self._camera.matrix_world = self._matrix(blender_camera_matrix(cam_from_world))
        bscene.cycles.samples = int(spp)
        bscene.cycles.seed = int(seed) & 0x7FFFFFFF
        bscene.cycles.pixel_filter_type = filter_type
        bscene.cycles.filter_width = float(filter_width)
        path = Path(self._tmp.name) / "frame.exr"
        bscene.render.filepath = str(path)
        with _quiet_stdout():
            self._bpy.ops.render.render(write_still=True)
        return _read_exr(self._exr, path)

    def render_rgb(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> np.ndarray:
        """sRGB uint8 (H, W, 3): ``spp`` samples, 1-px box filter."""
        return linear_to_srgb_uint8(self.render_linear(camera, cam_from_world, seed))

    def render_linear(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> np.ndarray:
        """Linear radiance (H, W, 3) of the EXR's Combined pass, before :func:`linear_to_srgb_uint8`."""
        channels = self._render_exr(camera, cam_from_world, self.spp, seed, "BOX", 1.0)
        return _pass(channels, "Combined", "RGB")

    def render_ground_truth(self, camera: Camera, cam_from_world: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
        """(z-depth float32, +inf no hit; instance uint16) from one centred sample per pixel.

        Shading is switched off (material override, no bounces) unless an id needs bit 15, which lives
        in the per-mesh material's pass index."""
        self._require_scene()
        bscene = self._bpy.context.scene
        layer = bscene.view_layers[0]
        try:
            if self._gt_override is not None:
                layer.material_override = self._gt_override
                bscene.cycles.max_bounces = 0
            channels = self._render_exr(camera, cam_from_world, 1, 0, "BOX", 0.01)
        finally:
            layer.material_override = None
            bscene.cycles.max_bounces = self.max_bounces
        depth = _pass(channels, "Depth", "Z")[..., 0].astype(np.float32)
        low = np.rint(_pass(channels, "Object Index", "X")[..., 0]).astype(np.int64)
        high = np.rint(_pass(channels, "Material Index", "X")[..., 0]).astype(np.int64)
        depth[~(depth < _NO_HIT)] = np.inf
        instance = ((high << 15) | low).astype(np.uint16)
        instance[~np.isfinite(depth)] = 0
        return depth, instance

    def render(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> Frame:
        depth, instance = self.render_ground_truth(camera, cam_from_world)
        linear = self.render_linear(camera, cam_from_world, seed)
        return Frame(rgb=linear_to_srgb_uint8(linear), depth=depth, instance=instance, linear=linear)


def _node_tree(idblock: Any) -> Any:
    """The shader node tree of a material or world (always present in bpy 5; ``use_nodes`` before)."""
    if idblock.node_tree is None:
        idblock.use_nodes = True
    return idblock.node_tree


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence Blender's per-tile progress lines (printed by C code straight to file descriptor 1)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def _read_exr(openexr: Any, path: Path) -> dict[str, np.ndarray]:
    """All channels of a multilayer EXR (Blender 5 writes one part per pass) as (H, W) float arrays."""
    with openexr.File(str(path), separate_channels=True) as f:
        return {name: np.array(ch.pixels) for part in f.parts for name, ch in part.channels.items()}


def _pass(channels: dict[str, np.ndarray], name: str, components: str) -> np.ndarray:
    """(H, W, len(components)) of pass ``name`` (channel names ``<layer>.<pass>.<component>``)."""
    out = []
    for comp in components:
        hits = [k for k in channels if k.split(".")[-2:] == [name, comp]]
        if not hits:
            raise RuntimeError(f"blender: pass {name}.{comp} missing from the EXR (have {sorted(channels)})")
        out.append(channels[hits[0]])
    return np.stack(out, axis=-1)


def create_blender_renderer(config: RenderConfig) -> BlenderRenderer:
    """Registry factory: ``[render] renderer = "blender"``; uses ``spp``, ``integrator``, ``max_depth``."""
    return BlenderRenderer(spp=config.spp, integrator=config.integrator, max_depth=config.max_depth)
