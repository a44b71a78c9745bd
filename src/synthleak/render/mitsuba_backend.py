"""mitsuba 3 photoreal RGB (``scalar_rgb``, or the vectorised ``llvm_ad_rgb``); depth and instance ids come
from :mod:`raycast`.

The scene is built in memory: ``mi.Mesh`` objects filled from arrays, ``bitmap`` textures from uint8 sRGB
arrays (two-sided principled BSDFs), sphere lights as ``point`` emitters, distant lights as ``directional``
emitters; rect lights and ``ambient`` depend on ``lighting`` (see :class:`MitsubaRenderer`). A ``box``
reconstruction filter and a ``multijitter`` sampler seeded per frame make renders bitwise deterministic
(also across thread counts, measured).
"""

from __future__ import annotations

import glob
import os
import re
from dataclasses import replace
from typing import Any

import numpy as np

from synthleak.config import RenderConfig
from synthleak.core.types import Camera, Light, RenderMesh, RenderScene
from synthleak.executors import worker_thread_cap
from synthleak.render.base import Frame
from synthleak.render.raycast import RaycastGT, pixel_rays
from synthleak.render.registry import FILTERS, INTEGRATORS, MITSUBA_VARIANTS

VARIANT = "scalar_rgb"
"""The default variant: runs anywhere the wheel installs."""
VARIANTS = MITSUBA_VARIANTS
LLVM_MIN_VERSION = 16
"""drjit's LLVM backend aborts the process with Debian 12's LLVM 15 (measured); LLVM 19 works (measured)."""
_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
)
EACH_LIGHT = "synthleak_each_light"
"""Name of the one-pass integrator registered for the LLVM variant (see :func:`_register_each_light`)."""
SAMPLER = "multijitter"
"""Seeded like ``independent`` but stratified: at 4 spp it halves the seed-to-seed anti-aliasing noise
(0.33 vs 0.71 levels) and raises SIFT keypoint repeatability across seeds from 69% to 79% (measured,
640x480 room view); at 1 spp both are identical."""
# OpenCV camera axes (x right, y down, z forward) -> mitsuba sensor axes (x left, y up, z forward).
_CV_TO_MI = np.diag([-1.0, -1.0, 1.0, 1.0])


def _llvm_version(path: str) -> int | None:
    match = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", os.path.basename(path)) or re.search(r"llvm-(\d+)", path)
    return int(match.group(1)) if match else None


def find_libllvm() -> str:
    """Path of the LLVM shared library for drjit's LLVM backend: ``DRJIT_LIBLLVM_PATH`` if set, else the newest
    ``libLLVM`` of version >= :data:`LLVM_MIN_VERSION` in the system library folders. Raises ImportError with
    the fix when there is none (drjit itself would pick any version and abort the process on LLVM 15)."""
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        if not os.path.isfile(given):
            raise ImportError(f"DRJIT_LIBLLVM_PATH={given!r}: no such file (the LLVM shared library, version "
                              f">= {LLVM_MIN_VERSION})")
        return given
    found = [(v, p) for pattern in _LLVM_GLOBS for p in glob.glob(pattern) if (v := _llvm_version(p)) is not None]
    usable = sorted(vp for vp in found if vp[0] >= LLVM_MIN_VERSION)
    if not usable:
        seen = ", ".join(sorted({p for _, p in found})) or "none"
        raise ImportError(
            f"render.mitsuba_variant 'llvm_ad_rgb' needs the LLVM shared library, version >= {LLVM_MIN_VERSION} "
            f"(found: {seen}); on Debian 12: apt-get install libllvm19, or set DRJIT_LIBLLVM_PATH, or use "
            f"mitsuba_variant = 'scalar_rgb'"
        )
    return usable[-1][1]


def _mitsuba(variant: str = VARIANT) -> Any:
    if variant not in VARIANTS:
        raise ValueError(f"render.mitsuba_variant: {variant!r} is not one of {', '.join(VARIANTS)}")
    if variant.startswith("llvm"):  # before drjit is imported: it tries (and complains about) the path then
        os.environ["DRJIT_LIBLLVM_PATH"] = find_libllvm()  # read when drjit first starts its LLVM backend
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("renderer 'mitsuba' needs mitsuba 3: pip install 'mitsuba>=3.5'") from exc
    if mi.variant() != variant:
        mi.set_variant(variant)
        if variant.startswith("llvm"):
            _register_each_light(mi)
    return mi


def _register_each_light(mi: Any) -> None:
    """Register :data:`EACH_LIGHT`: the ``direct`` integrator's job for delta lights, without its noise.

    For every camera sample it intersects once, adds the radiance of an emissive surface hit, then adds
    every emitter's contribution with its own shadow ray and BSDF evaluation: delta emitters (point,
    directional) exactly, emissive meshes (area emitters) from one point sampled on them, as the scalar
    variant's first pass does (with the same soft-shadow grain). Summing all lights per sample (mitsuba's
    ``direct`` picks one at random per sample) leaves no light-selection noise, and one primary intersection
    serves every light (the per-light passes of the scalar variant trace it once per pass); a miss is black
    (deterministic lighting has no environment emitter)."""

    class EachLight(mi.SamplingIntegrator):
        def sample(self, scene, sampler, ray, medium=None, active=True):  # noqa: ANN001, ANN201
            si = scene.ray_intersect(ray, active)
            valid = active & si.is_valid()
            result = mi.Spectrum(si.emitter(scene, valid).eval(si, valid))
            bsdf, ctx = si.bsdf(ray), mi.BSDFContext()
            for emitter in scene.emitters():
                delta = mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta)
                sample = mi.Point2f(0.5, 0.5) if delta else sampler.next_2d(valid)
                ds, weight = emitter.sample_direction(si, sample, valid)
                lit = valid & (ds.pdf != 0.0)
                lit &= ~scene.ray_test(si.spawn_ray_to(ds.p), lit)
                result[lit] += bsdf.eval(ctx, si, si.to_local(ds.d), lit) * weight
            return result, valid, []

        def aov_names(self):  # noqa: ANN201
            return []

    mi.register_integrator(EACH_LIGHT, lambda props: EachLight(props))


def linear_to_srgb_uint8(rgb: np.ndarray) -> np.ndarray:
    """Linear radiance (H, W, 3) -> sRGB-encoded uint8 (clipped, rounded)."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def sensor_to_world(cam_from_world: np.ndarray) -> np.ndarray:
    """mitsuba sensor ``to_world`` for an OpenCV ``cam_from_world``."""
    pose = np.asarray(cam_from_world, dtype=np.float64)
    rot, t = pose[:3, :3], pose[:3, 3]
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = rot.T
    world_from_cam[:3, 3] = -rot.T @ t
    return world_from_cam @ _CV_TO_MI


def _srgb_to_linear(c: tuple[float, float, float]) -> list[float]:
    x = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).tolist()


def _bsdf(mi: Any, mesh: RenderMesh) -> Any:
    if mesh.texture is not None:
        tex = np.ascontiguousarray(np.asarray(mesh.texture, dtype=np.uint8)[..., :3])
        base: dict[str, Any] = {
            "type": "bitmap",
            "bitmap": mi.Bitmap(tex, pixel_format=mi.Bitmap.PixelFormat.RGB),
            "raw": False,  # uint8 textures are sRGB-encoded: mitsuba linearises them
            "filter_type": "bilinear",
            "wrap_mode": "repeat",
        }
    else:
        # base_color is given in sRGB like the textures: linearise it.
        base = {"type": "rgb", "value": _srgb_to_linear(mesh.base_color)}
    principled = {
        "type": "principled",
        "base_color": base,
        "roughness": float(np.clip(mesh.roughness, 0.05, 1.0)),
        "metallic": float(np.clip(mesh.metallic, 0.0, 1.0)),
        "specular": 0.3,
    }
    # Two-sided: thin shell pieces and inward-facing walls must not render black from behind.
    return mi.load_dict({"type": "twosided", "bsdf": principled})


def _mesh(mi: Any, mesh: RenderMesh, index: int) -> Any:
    verts, faces = mesh.checked_arrays()
    textured = mesh.texture is not None and mesh.uv is not None
    props = mi.Properties()
    props["bsdf"] = _bsdf(mi, mesh)
    if mesh.emissive is not None and max(mesh.emissive) > 0:
        props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": list(mesh.emissive)}})
    m = mi.Mesh(
        f"m{index}_{mesh.instance_id}",
        len(verts),
        len(faces),
        props=props,
        has_vertex_normals=False,
        has_vertex_texcoords=textured,
    )
    params = mi.traverse(m)
    params["vertex_positions"] = np.ascontiguousarray(verts.astype(np.float32).ravel())
    params["faces"] = np.ascontiguousarray(faces.astype(np.uint32).ravel())
    if textured:
        uv = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2).copy()
        if len(uv) != len(verts):
            raise ValueError(f"mesh {mesh.name!r}: {len(uv)} uvs for {len(verts)} vertices")
        uv[:, 1] = 1.0 - uv[:, 1]  # ours: v = 0 at the texture's bottom row; mitsuba: v = 0 at the top
        params["vertex_texcoords"] = np.ascontiguousarray(uv.astype(np.float32).ravel())
    params.update()
    return m


def _light(light: Light) -> dict[str, Any]:
    """The physical translation: sphere -> point, rect -> rectangle area emitter, distant -> directional."""
    pose = np.asarray(light.world_from_light, dtype=np.float64)
    color = [float(c) * float(light.intensity) for c in light.color]
    if light.kind == "sphere":
        return {
            "type": "point",
            "position": pose[:3, 3].tolist(),
            "intensity": {"type": "rgb", "value": color},
        }
    if light.kind == "rect":
        # mitsuba's rectangle spans [-1, 1]^2 with normal +z; ours faces -z of its frame.
        scale = np.diag([light.size[0] / 2.0, light.size[1] / 2.0, 1.0, 1.0])
        flip = np.diag([1.0, -1.0, -1.0, 1.0])
        return {
            "type": "rectangle",
            "to_world": _transform(pose @ flip @ scale),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": color}},
        }
    if light.kind == "distant":
        return {
            "type": "directional",
            "direction": (-pose[:3, 2]).tolist(),
            "irradiance": {"type": "rgb", "value": color},
        }
    raise ValueError(f"light {light.name!r}: unknown kind {light.kind!r} (sphere | rect | distant)")


RECT_GRID = 1
"""Point lights per rect light side. More than 1 puts several unequal emitters in one pass, whose random
selection is visible grain (measured: 4.6 levels mean seed-to-seed difference with 2 x 2 vs < 1 with 1)."""
AMBIENT_RING = 4


def _deterministic_lights(light: Light) -> list[dict[str, Any]]:
    """Noise-free translation: a rect light becomes ``RECT_GRID**2`` point lights of its power along the
    normal (radiance x area) 1 cm in front of the rectangle; other kinds as in :func:`_light`."""
    if light.kind != "rect":
        return [_light(light)]
    pose = np.asarray(light.world_from_light, dtype=np.float64)
    n = RECT_GRID
    each = float(light.intensity) * light.size[0] * light.size[1] / (n * n)
    color = [float(c) * each for c in light.color]
    out = []
    for gx in (np.arange(n) + 0.5) / n - 0.5:
        for gy in (np.arange(n) + 0.5) / n - 0.5:
            local = np.array([gx * light.size[0], gy * light.size[1], -0.01, 1.0])
            out.append(
                {
                    "type": "point",
                    "position": (pose @ local)[:3].tolist(),
                    "intensity": {"type": "rgb", "value": color},
                }
            )
    return out


def _ambient_directions() -> tuple[np.ndarray, float]:
    """Unit directions *towards* the fill lights standing in for a constant environment, and the
    irradiance of each per unit radiance: zenith plus a ring at 30 degrees elevation, so an open
    upward-facing surface receives pi x radiance like under a uniform sky."""
    ring = np.radians(45.0 + 90.0 * np.arange(AMBIENT_RING))
    el = np.radians(30.0)
    dirs = [np.array([0.0, 0.0, 1.0])]
    dirs += [np.array([np.cos(a) * np.cos(el), np.sin(a) * np.cos(el), np.sin(el)]) for a in ring]
    cos_sum = 1.0 + AMBIENT_RING * np.sin(el)
    return np.array(dirs), np.pi / cos_sum


def _transform(matrix: np.ndarray) -> Any:
    import mitsuba as mi  # the variant is set by the caller

    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64).tolist())


class MitsubaRenderer:
    """Renderer protocol implementation; see the module docstring.

    ``lighting="deterministic"`` (default) renders one pass per light and sums them: the direct
    integrator then has a single emitter per pass, so there is no light-selection noise, only
    anti-aliasing at silhouettes. A rect light becomes a point light of the same on-axis intensity
    (radiance x area) at its centre; ``ambient`` becomes directional fill lights, one pass each, skipped
    in a frame where none of the visible surface points (every 4th pixel of the ray-cast ground truth)
    sees that direction. ``lighting="physical"`` uses rectangle area emitters and a ``constant``
    environment in one pass: softer, more faithful shadows, but Monte Carlo grain that SIFT detects as
    spurious features.

    ``variant="llvm_ad_rgb"`` renders the same scene description vectorised (drjit's LLVM backend). With
    ``direct`` + deterministic lighting it renders all lights in one pass with :data:`EACH_LIGHT` instead of
    one pass per light (same image up to anti-aliasing samples; no dark-pass test needed). Each variant is
    bitwise deterministic on its own (also across thread counts, measured); the two give different bytes.
    A worker's thread cap (:func:`synthleak.executors.worker_thread_cap`) caps mitsuba's thread pool.
    """

    name = "mitsuba"

    def __init__(
        self,
        spp: int = 2,
        integrator: str = "direct",
        max_depth: int = 3,
        filter: str = "box",
        lighting: str = "deterministic",
        variant: str = VARIANT,
    ) -> None:
        if lighting not in ("deterministic", "physical"):
            raise ValueError(f"lighting: {lighting!r} is not 'deterministic' or 'physical'")
        if integrator not in INTEGRATORS:
            raise ValueError(f"render.integrator: {integrator!r} is not one of {', '.join(INTEGRATORS)}")
        if filter not in FILTERS:
            raise ValueError(f"render.filter: {filter!r} is not one of {', '.join(FILTERS)}")
        if spp < 1:
            raise ValueError(f"render.spp: must be >= 1, got {spp}")
        self.lighting = lighting
        self.spp, self.integrator, self.max_depth, self.filter = spp, integrator, max_depth, filter
        self.variant = variant
        _mitsuba(variant)  # an unknown variant or a missing libLLVM fails here, not at the first frame
        cap = worker_thread_cap()
        if cap is not None:
            import drjit as dr

            dr.set_thread_count(cap)
        self._scenes: list[Any] = []
        self._gt: RaycastGT | None = None

    @property
    def one_pass(self) -> bool:
        """All lights in one pass with :data:`EACH_LIGHT` (LLVM variant, ``direct``, deterministic lighting)."""
        return self.variant != "scalar_rgb" and self.integrator == "direct" and self.lighting == "deterministic"

    def _light_groups(self, scene: RenderScene) -> list[tuple[list[dict[str, Any]], np.ndarray | None]]:
        """Emitter dicts grouped into render passes, each with its fill direction (None: a scene light)."""
        if self.lighting == "physical":
            group = [_light(light) for light in scene.lights if light.intensity > 0]
            if scene.ambient > 0:
                group.append({"type": "constant", "radiance": {"type": "rgb", "value": float(scene.ambient)}})
            return [(group, None)] if group else []
        groups: list[tuple[list[dict[str, Any]], np.ndarray | None]] = [
            (_deterministic_lights(light), None) for light in scene.lights if light.intensity > 0
        ]
        if scene.ambient > 0:
            directions, irradiance = _ambient_directions()
            for direction in directions:
                value = irradiance * float(scene.ambient)
                emitter = {
                    "type": "directional",
                    "direction": (-direction).tolist(),
                    "irradiance": {"type": "rgb", "value": [value] * 3},
                }
                groups.append(([emitter], direction))
        return groups

    def prepare(self, scene: RenderScene) -> None:
        """Convert the scene once: the ray-cast BVH for ground truth, then one mitsuba scene per pass."""
        mi = _mitsuba(self.variant)  # also switches back if another renderer in this process set another variant
        self._gt = RaycastGT(scene.meshes)
        groups = self._light_groups(scene)
        if self.one_pass:
            integrator: dict[str, Any] = {"type": EACH_LIGHT}
            groups = [([emitter for group, _ in groups for emitter in group], None)]
        elif self.integrator == "direct":
            integrator = {"type": "direct"}
        else:
            integrator = {"type": "path", "max_depth": int(self.max_depth)}
        dummy = self._sensor(Camera(8, 8, 8.0, 8.0, 4.0, 4.0), np.eye(4))
        self._scenes, self._fill_directions = [], []
        shapes = {f"mesh_{i:04d}": _mesh(mi, mesh, i) for i, mesh in enumerate(scene.meshes)}
        # Emissive meshes glow in the first pass only (else the sum would count their radiance per pass); a
        # single pass needs no dark copies.
        dark = {
            f"mesh_{i:04d}": _mesh(mi, replace(mesh, emissive=None), i)
            for i, mesh in enumerate(scene.meshes)
            if mesh.emissive is not None and max(mesh.emissive) > 0
        } if len(groups) > 1 else {}
        for k, (group, direction) in enumerate(groups or [([], None)]):
            base: dict[str, Any] = {"type": "scene", "integrator": integrator, "sensor": dummy, **shapes}
            if k > 0:
                base.update(dark)
            for j, emitter in enumerate(group):
                base[f"emitter_{j:03d}"] = emitter
            self._scenes.append(mi.load_dict(base))
            self._fill_directions.append(direction)

    def _dark_passes(self, camera: Camera, cam_from_world: np.ndarray, depth: np.ndarray) -> set[int]:
        """Fill-light passes that cannot reach any visible surface of this view (every 4th pixel tested)."""
        assert self._gt is not None
        if all(d is None for d in self._fill_directions):
            return set()
        origin, dirs = pixel_rays(camera, cam_from_world)
        z = depth.reshape(-1).astype(np.float64)
        sel = np.zeros((camera.height, camera.width), dtype=bool)
        sel[::4, ::4] = True
        sel = sel.reshape(-1) & np.isfinite(z)
        if not sel.any():
            return {k for k, d in enumerate(self._fill_directions) if d is not None}
        points = origin + dirs[sel] * (z[sel] - 1e-3)[:, None]  # 1 mm in front of the surface
        dark = set()
        for k, direction in enumerate(self._fill_directions):
            if direction is not None and self._gt.any_hit(points, np.broadcast_to(direction, points.shape)).all():
                dark.add(k)
        return dark

    def _sensor(self, camera: Camera, cam_from_world: np.ndarray) -> dict[str, Any]:
        if abs(camera.fx - camera.fy) > 1e-9 * camera.fx:
            raise ValueError(f"mitsuba needs square pixels: fx={camera.fx} fy={camera.fy}")
        hfov = float(np.degrees(2.0 * np.arctan(0.5 * camera.width / camera.fx)))
        return {
            "type": "perspective",
            "fov": hfov,
            "fov_axis": "x",
            # Fractions of the film size; measured: mitsuba moves the image opposite to the offset's sign,
            # so a principal point right of / below the centre is a negative offset.
            "principal_point_offset_x": -(camera.cx - camera.width / 2.0) / camera.width,
            "principal_point_offset_y": -(camera.cy - camera.height / 2.0) / camera.height,
            "near_clip": 0.01,
            "far_clip": 1000.0,
            "to_world": _transform(sensor_to_world(cam_from_world)),
            "film": {
                "type": "hdrfilm",
                "width": camera.width,
                "height": camera.height,
                "rfilter": {"type": self.filter},
                "pixel_format": "rgb",
            },
            "sampler": {"type": SAMPLER, "sample_count": self.spp},
        }

    def render_rgb(
        self,
        camera: Camera,
        cam_from_world: np.ndarray,
        seed: int,
        skip: set[int] | frozenset[int] = frozenset(),
    ) -> np.ndarray:
        """sRGB uint8 (H, W, 3) from mitsuba alone (``skip``: pass indices known to contribute nothing)."""
        return linear_to_srgb_uint8(self.render_linear(camera, cam_from_world, seed, skip))

    def render_linear(
        self,
        camera: Camera,
        cam_from_world: np.ndarray,
        seed: int,
        skip: set[int] | frozenset[int] = frozenset(),
    ) -> np.ndarray:
        """Linear radiance float64 (H, W, 3), the sum of the passes, before :func:`linear_to_srgb_uint8`."""
        if not self._scenes:
            raise RuntimeError("MitsubaRenderer.render before prepare(scene)")
        mi = _mitsuba(self.variant)
        sensor = mi.load_dict(self._sensor(camera, cam_from_world))
        total = np.zeros((camera.height, camera.width, 3))
        for k, scene in enumerate(self._scenes):  # passes sum linearly; each gets its own sample stream
            if k in skip:
                continue
            pass_seed = (int(seed) + 0x9E3779B9 * k) & 0xFFFFFFFF
            total += np.asarray(mi.render(scene, sensor=sensor, seed=pass_seed, spp=self.spp))[..., :3]
        return total

    def render(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> Frame:
        if self._gt is None:
            raise RuntimeError("MitsubaRenderer.render before prepare(scene)")
        depth, instance = self._gt.render(camera, cam_from_world)
        linear = self.render_linear(camera, cam_from_world, seed, self._dark_passes(camera, cam_from_world, depth))
        return Frame(rgb=linear_to_srgb_uint8(linear), depth=depth, instance=instance, linear=linear)


def create_mitsuba_renderer(config: RenderConfig) -> MitsubaRenderer:
    """Registry factory: ``[render] renderer = "mitsuba"`` (``spp``, ``integrator``, ``max_depth``, ``filter``,
    ``mitsuba_variant``)."""
    return MitsubaRenderer(
        spp=config.spp,
        integrator=config.integrator,
        max_depth=config.max_depth,
        filter=config.filter,
        variant=config.mitsuba_variant,
    )
