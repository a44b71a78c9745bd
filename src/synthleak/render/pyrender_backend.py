"""pyrender (OpenGL raster) backend, headless on CPU through Mesa's software EGL.

Fast preview-quality RGB with the same ground truth as the other backends:

* RGB: pyrender's metallic-roughness shader (4x MSAA), flat-shaded faces as in mitsuba, sRGB textures,
  ``sphere`` lights as point lights, ``rect`` lights as spot lights along -z of their frame (radiant
  intensity ``radiance * area``), ``distant`` lights as directional lights, ``ambient`` as ambient light
  and background colour.
  Light units match mitsuba's (W/sr, irradiance): pyrender's BRDF carries the 1/pi of a Lambertian.
  Optional shadow maps for spot and directional lights (pyrender has none for point lights), filtered as
  pyrender filters them (3x3 bilinear PCF) with 16 texture reads instead of 36 (see :func:`_shader_dir`).
* depth and instance ids: one flat-colour segmentation pass with multisampling off, so every pixel is
  rasterised at its centre ``(u + 0.5, v + 0.5)`` (GL's rasterisation rule, the same convention as
  :class:`~synthleak.render.base.Camera`). The 16-bit id is packed into R (high byte) and G (low byte);
  z-depth is pyrender's linearised z-buffer (24-bit, near plane ``ZNEAR``).

pyrender's ``IntrinsicsCamera`` (``P[0,2] = 1 - 2 cx / W``, ``P[1,2] = 2 cy / H - 1``) puts an OpenCV
camera point (x, y, z) at column ``cx + fx x / z`` and, after pyrender flips the read-back image, row
``cy + fy y / z``, with ``cx``, ``cy`` measured from the image corner: the convention of ``Camera`` as is (no
half-pixel shift, no cy flip); ``tests/test_backends.py`` checks it against the exact ray cast.

Renders are deterministic (no random sampling; ``seed`` is unused).
"""

from __future__ import annotations

import atexit
import functools
import os
import shutil
import tempfile
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.config import RenderConfig
from synthleak.core.types import Camera, Light, RenderMesh, RenderScene
from synthleak.render.base import Frame
from synthleak.render.lighting import emissive_lights

INSTALL_HINT = (
    "pip install -e '.[pyrender]' (pyrender 0.1.45, pins PyOpenGL 3.1.0) and the Mesa EGL libraries "
    "(Debian: apt-get install libegl1 libgl1-mesa-dri); headless rendering uses PYOPENGL_PLATFORM=egl"
)
ZNEAR = 0.05
"""Near clip plane (m): surfaces closer than this to the camera are not rendered."""
ZFAR = 1000.0
# OpenCV camera axes (x right, y down, z forward) -> OpenGL camera axes (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
_RECT_CONE = np.radians(80.0)
"""Outer cone half-angle of the spot light standing in for a rect (hemispherical) light."""


_GL: list[Any] = []
"""One ``OffscreenRenderer`` (one EGL context) per process, shared by every PyrenderRenderer: pyrender's
EGL teardown calls ``eglTerminate`` on the process-wide display, so deleting one renderer's context while
another is alive breaks the other (EGL_BAD_DISPLAY)."""


_MESHES: dict[int, tuple[RenderMesh, Any]] = {}
"""The pyrender meshes of the last scene prepared in this process, by ``id`` of their :class:`RenderMesh` (kept
alive here, so an id is not reused): the lighting conditions of one stage (:mod:`synthleak.render.light_conditions`
shares their meshes) get the same pyrender meshes, so switching between them draws what the GL context holds
instead of uploading every mesh and texture again."""


def _shared_mesh(pr: Any, mesh: RenderMesh) -> Any:
    """The pyrender mesh of ``mesh``: the one made for this very object by an earlier :meth:`prepare`, else new."""
    cached = _MESHES.get(id(mesh))
    if cached is not None and cached[0] is mesh:
        return cached[1]
    primitive = _flat_primitive(pr, mesh)
    pmesh = pr.Mesh([primitive], name=mesh.name)
    # pyrender 0.1.45's Mesh.bounds uses np.infty (gone in numpy 2): preset the cached bounds.
    pmesh._bounds = np.asarray(primitive.bounds, dtype=np.float64).copy()
    _MESHES[id(mesh)] = (mesh, pmesh)
    return pmesh


class PyrenderUnavailable(ImportError):
    """pyrender or a headless OpenGL platform is missing; the message says how to install it."""


def _pyrender() -> Any:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        import pyrender
    except Exception as exc:  # ImportError, or OpenGL failing to load libEGL
        msg = f"renderer 'pyrender' is unavailable ({exc}); install: {INSTALL_HINT}"
        raise PyrenderUnavailable(msg) from exc
    return pyrender


def _flat_primitive(pyrender: Any, mesh: RenderMesh) -> Any:
    """A pyrender primitive with per-face normals (vertices unshared) and the mesh's material."""
    verts, faces = mesh.checked_arrays()
    tri = verts[faces]  # (F, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    textured = mesh.texture is not None and mesh.uv is not None
    texcoords = None
    texture = None
    if textured:
        uv = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2)
        if len(uv) != len(verts):
            raise ValueError(f"mesh {mesh.name!r}: {len(uv)} uvs for {len(verts)} vertices")
        # pyrender uploads image row 0 at t = 1, so v = 0 samples the bottom row: our convention as is.
        texcoords = uv[faces].reshape(-1, 2).astype(np.float32)
        image = np.ascontiguousarray(np.asarray(mesh.texture, dtype=np.uint8)[..., :3])
        texture = pyrender.Texture(source=image, source_channels="RGB")
    base = (1.0, 1.0, 1.0) if textured else _srgb_to_linear(mesh.base_color)
    emissive = None
    if mesh.emissive is not None and max(mesh.emissive) > 0:
        # pyrender's shader adds emissive_factor squared when there is no emissive texture.
        emissive = np.sqrt(np.clip(np.asarray(mesh.emissive, dtype=np.float64), 0.0, None))
    material = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=(*base, 1.0),
        baseColorTexture=texture,
        metallicFactor=float(np.clip(mesh.metallic, 0.0, 1.0)),
        roughnessFactor=float(np.clip(mesh.roughness, 0.05, 1.0)),
        emissiveFactor=emissive,
        doubleSided=True,  # no back-face culling: ground truth sees both sides, like the ray cast
    )
    return pyrender.Primitive(
        positions=tri.reshape(-1, 3).astype(np.float32),
        normals=np.repeat(normal, 3, axis=0).astype(np.float32),
        texcoord_0=texcoords,
        material=material,
        mode=4,  # GL_TRIANGLES
    )


def _srgb_to_linear(c: tuple[float, float, float]) -> tuple[float, float, float]:
    x = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    return (float(lin[0]), float(lin[1]), float(lin[2]))


def _linear_to_srgb(x: float) -> float:
    x = float(np.clip(x, 0.0, 1.0))
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1.0 / 2.4) - 0.055


def _light_node(pyrender: Any, light: Light) -> tuple[Any, np.ndarray]:
    """A pyrender light and its pose (pyrender lights shine along -z of their node, like ours)."""
    pose = np.asarray(light.world_from_light, dtype=np.float64)
    color = np.clip(np.asarray(light.color, dtype=np.float64), 0.0, None)
    if light.kind == "sphere":
        return pyrender.PointLight(color=color, intensity=float(light.intensity)), pose
    if light.kind == "rect":
        area = float(light.size[0]) * float(light.size[1])
        spot = pyrender.SpotLight(color=color, intensity=float(light.intensity) * area,
                                  innerConeAngle=0.0, outerConeAngle=float(_RECT_CONE))
        return spot, pose
    if light.kind == "distant":
        return pyrender.DirectionalLight(color=color, intensity=float(light.intensity)), pose
    raise ValueError(f"light {light.name!r}: unknown kind {light.kind!r} (sphere | rect | distant)")


def gl_camera_pose(cam_from_world: np.ndarray) -> np.ndarray:
    """pyrender (OpenGL) camera node pose ``world_from_cam_gl`` for an OpenCV ``cam_from_world``."""
    pose = np.asarray(cam_from_world, dtype=np.float64)
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = pose[:3, :3].T
    world_from_cam[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return world_from_cam @ _CV_TO_GL


def encode_ids(ids: np.ndarray) -> np.ndarray:
    """uint16 ids -> (N, 3) uint8 colours: R = high byte, G = low byte, B = 0."""
    ids = np.asarray(ids, dtype=np.uint16)
    return np.stack([ids >> 8, ids & 0xFF, np.zeros_like(ids)], axis=-1).astype(np.uint8)


def decode_ids(rgb: np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode_ids` for an (H, W, 3) uint8 image."""
    rgb = np.asarray(rgb)
    return (rgb[..., 0].astype(np.uint16) << 8) | rgb[..., 1].astype(np.uint16)


_DRAW_ORDER: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
"""pyrender scene -> its mesh nodes in the order the meshes were added (see :func:`_patch_renderer`)."""


_PCF_16_READS = """float PCF(sampler2D depths, vec2 size, vec2 uv, float compare){
    // pyrender's filter, 3x3 bilinear lookups one texel apart, gathered: they cover a 4x4 texel block,
    // each texel weighted by how many lookups reach it, separably (1 - f, 1, 1, f) per axis; sum 9.
    vec2 texel = vec2(1.0) / size;
    vec2 f = fract(uv * size + 0.5);
    vec2 corner = floor(uv * size + 0.5) / size;
    vec4 wx = vec4(1.0 - f.x, 1.0, 1.0, f.x);
    vec4 wy = vec4(1.0 - f.y, 1.0, 1.0, f.y);
    float result = 0.0;
    for (int x = 0; x < 4; x++) {
        float column = 0.0;
        for (int y = 0; y < 4; y++) {
            column += wy[y] * texture2DCompare(depths, corner + texel * vec2(float(x - 1), float(y - 1)), compare);
        }
        result += wx[x] * column;
    }
    return result / 9.0;
}

"""


def _shader_dir(pyrender: Any) -> str | None:
    """A per-process copy of pyrender's shaders whose shadow filter makes 16 texture reads, not 36.

    pyrender's ``PCF`` averages 9 bilinear shadow lookups (4 reads each) one texel apart; the same weighted
    sum over the 4x4 texels they touch needs 16 reads. The image is the same up to float rounding (one pixel
    in 15 frames of a room differed by one grey level) and a shadowed 640x480 frame renders ~30% faster on
    llvmpipe. ``None`` (pyrender's own shaders) when the installed ``mesh.frag`` is not the expected one."""
    stock = os.path.join(os.path.dirname(pyrender.__file__), "shaders")
    try:
        frag = Path(stock, "mesh.frag").read_text()
    except OSError:
        return None
    start, end = frag.find("float PCF(sampler2D depths"), frag.find("float shadow_calc(")
    if start < 0 or end < start or "float texture2DCompare(" not in frag:
        return None
    target = tempfile.mkdtemp(prefix="synthleak-pyrender-shaders-")
    atexit.register(shutil.rmtree, target, True)
    for name in os.listdir(stock):
        shutil.copy(os.path.join(stock, name), target)
    with open(os.path.join(target, "mesh.frag"), "w") as handle:
        handle.write(frag[:start] + _PCF_16_READS + frag[end:])
    return target


@functools.cache
def _ordered_lights_scene(pyrender: Any) -> type:
    """A ``pyrender.Scene`` whose ``light_nodes`` come in the order the lights were added.

    pyrender's ``light_nodes`` is a union of sets, iterated in an order that follows the nodes' memory
    addresses, so it changed from process to process; the shader sums the lights of a kind in the order they
    were bound, and float addition is not associative: with three or more lights of a kind a few pixels per
    frame came out one grey level apart between two runs of the same config (``tests/test_backends.py``)."""

    class OrderedLightsScene(pyrender.Scene):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            self._light_order: list = []
            super().__init__(*args, **kwargs)

        def add_node(self, node: Any, parent_node: Any = None) -> None:
            super().add_node(node, parent_node)
            if node.light is not None:
                self._light_order.append(node)

        def remove_node(self, node: Any) -> None:
            super().remove_node(node)
            self._light_order = [n for n in self._light_order if n in self.nodes]

        @property
        def light_nodes(self) -> list:
            return list(self._light_order)

    return OrderedLightsScene


def _patch_renderer(pyrender: Any, renderer: Any) -> None:
    """Make a ``pyrender.Renderer`` draw scenes prepared here in a fixed order, with cheaper shadow filtering.

    * Draw order: pyrender sorts mesh nodes by the distance of their node origin from the camera and breaks
      ties in the iteration order of a set of nodes, which follows memory addresses. Our meshes all sit at
      the identity pose, so the order (and with it which of two coincident surfaces wins the depth test, in
      frames and shadow maps) could change from process to process. Scenes in ``_DRAW_ORDER`` are drawn in
      the order their meshes were added, opaque before transparent, whatever the camera.
    * Shaders from :func:`_shader_dir`.
    Bound to one ``Renderer`` instance: if pyrender rebuilds its renderer, the new one is pyrender's own."""
    sorted_nodes = renderer._sorted_mesh_nodes

    def nodes_in_insertion_order(scene: Any) -> list:
        order = _DRAW_ORDER.get(scene)
        if order is None:
            return sorted_nodes(scene)
        return [n for n in order if not n.mesh.is_transparent] + [n for n in order if n.mesh.is_transparent]

    renderer._sorted_mesh_nodes = nodes_in_insertion_order
    shaders = _shader_dir(pyrender)
    if shaders is not None:
        from pyrender.shader_program import ShaderProgramCache

        renderer._program_cache.clear()
        renderer._program_cache = ShaderProgramCache(shader_dir=shaders)


class PyrenderRenderer:
    """Renderer protocol implementation; see the module docstring."""

    name = "pyrender"
    rgb_encoding = "gamma2.2"
    """Frames carry no linear radiance: the shader writes ``pow(c, 1/2.2)``, rounded to 8 bits by OpenGL, so the
    capture model takes :func:`synthleak.render.capture.gamma22_to_linear` of ``rgb`` (highlights above 1.0 are
    already clipped and the shadows carry 8-bit banding)."""

    def __init__(self, shadows: bool = True) -> None:
        self._pr = _pyrender()
        self.shadows = shadows
        self._scene: Any = None
        self._seg_map: dict[Any, np.ndarray] = {}
        self._cam_node: Any = None
        self._check_context()

    def _check_context(self) -> None:
        """Fail at construction, not at the first frame, when no GL context can be made."""
        try:
            self._viewport(8, 8)
        except Exception as exc:
            raise PyrenderUnavailable(
                f"renderer 'pyrender' cannot create a headless OpenGL context "
                f"(PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')}): {exc}; install: {INSTALL_HINT}"
            ) from exc

    def _viewport(self, width: int, height: int) -> Any:
        if not _GL:
            _GL.append(self._pr.OffscreenRenderer(width, height))
            _patch_renderer(self._pr, _GL[0]._renderer)
        renderer = _GL[0]
        if (renderer.viewport_width, renderer.viewport_height) != (width, height):
            renderer.viewport_width, renderer.viewport_height = width, height
        return renderer

    def prepare(self, scene: RenderScene) -> None:
        """Build the pyrender scene once: one node per mesh, its id colour, the lights."""
        pr = self._pr
        if not scene.meshes:
            raise ValueError("pyrender: the scene has no meshes")
        ambient = float(max(scene.ambient, 0.0))
        bg = _linear_to_srgb(ambient)  # the background shows the ambient environment, as in mitsuba
        pscene = _ordered_lights_scene(pr)(bg_color=(bg, bg, bg, 1.0), ambient_light=(ambient, ambient, ambient))
        seg_map: dict[Any, np.ndarray] = {}
        order = []
        if not any(id(m) in _MESHES and _MESHES[id(m)][0] is m for m in scene.meshes):
            _MESHES.clear()  # another stage: the last one's meshes are not needed again
        for mesh in scene.meshes:
            if not 0 <= int(mesh.instance_id) <= 0xFFFF:
                raise ValueError(f"mesh {mesh.name!r}: instance_id {mesh.instance_id} does not fit uint16")
            node = pscene.add(_shared_mesh(pr, mesh))
            order.append(node)
            seg_map[node] = encode_ids(np.array(mesh.instance_id))
        for light in (*scene.lights, *emissive_lights(scene)):  # emissive meshes light through stand-ins
            plight, pose = _light_node(pr, light)
            pscene.add(plight, pose=pose, name=light.name)
        self._cam_node = pscene.add(pr.IntrinsicsCamera(1.0, 1.0, 0.5, 0.5, znear=ZNEAR, zfar=ZFAR))
        _DRAW_ORDER[pscene] = order
        self._scene, self._seg_map = pscene, seg_map

    def _set_camera(self, camera: Camera, cam_from_world: np.ndarray) -> None:
        cam = self._cam_node.camera
        cam.fx, cam.fy = float(camera.fx), float(camera.fy)
        cam.cx, cam.cy = float(camera.cx), float(camera.cy)
        self._scene.set_pose(self._cam_node, gl_camera_pose(cam_from_world))

    def render_ground_truth(self, camera: Camera, cam_from_world: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
        """(z-depth float32 (H, W), +inf no hit; instance uint16 (H, W)) from the segmentation pass."""
        if self._scene is None:
            raise RuntimeError("PyrenderRenderer.render before prepare(scene)")
        self._set_camera(camera, cam_from_world)
        flags = self._pr.RenderFlags.SEG | self._pr.RenderFlags.SKIP_CULL_FACES
        seg, depth = self._viewport(camera.width, camera.height).render(
            self._scene, flags=flags, seg_node_map=self._seg_map
        )
        depth = np.asarray(depth, dtype=np.float32).copy()
        depth[depth <= 0] = np.inf
        return depth, decode_ids(seg)

    def render_rgb(self, camera: Camera, cam_from_world: np.ndarray) -> np.ndarray:
        """sRGB uint8 (H, W, 3) (pyrender's gamma-2.2 output)."""
        if self._scene is None:
            raise RuntimeError("PyrenderRenderer.render before prepare(scene)")
        rf = self._pr.RenderFlags
        self._set_camera(camera, cam_from_world)
        flags = rf.SKIP_CULL_FACES
        if self.shadows:
            flags |= rf.SHADOWS_SPOT | rf.SHADOWS_DIRECTIONAL
        color, _ = self._viewport(camera.width, camera.height).render(self._scene, flags=flags)
        return np.ascontiguousarray(color[..., :3], dtype=np.uint8)

    def render(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> Frame:
        del seed  # rasterisation takes no random samples
        depth, instance = self.render_ground_truth(camera, cam_from_world)
        return Frame(rgb=self.render_rgb(camera, cam_from_world), depth=depth, instance=instance)

    def close(self) -> None:
        """Drop this renderer's scene (the shared GL context stays for the next renderer)."""
        self._scene, self._seg_map, self._cam_node = None, {}, None


def create_pyrender_renderer(config: RenderConfig) -> PyrenderRenderer:
    """Registry factory: ``[render] renderer = "pyrender"``; ``spp``/``filter`` do not apply (4x MSAA);
    ``raster_shadows`` switches the shadow maps."""
    return PyrenderRenderer(shadows=config.raster_shadows)
