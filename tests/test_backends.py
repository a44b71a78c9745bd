"""Render backends agree on ground truth: pyrender, blender (where bpy imports), mitsuba, the exact ray cast.

A tiny in-memory stage (textured floor, two boxes, a cylinder, a sphere and a rect light) is seen by 5 cameras
at 96x72. Per available backend: instance masks and z-depth match the pixel-centre ray cast, unprojected depth
lies on the mesh, and the same seed gives the same bytes. Blender tests need bpy (Python 3.11, numpy<2):
run them in the separate venv, ``/work/venv-blender/bin/python -m pytest tests/test_backends.py``.
"""

from __future__ import annotations

import importlib.util
from itertools import combinations

import numpy as np
import pytest
import trimesh

from synthleak.config import RenderConfig
from synthleak.core.types import Camera, Light, RenderMesh, RenderScene
from synthleak.geometry.poses import invert, look_at, make_pose
from synthleak.render.base import Frame

W, H = 96, 72
CONFIG = RenderConfig(width=W, height=H, spp=4)


# ---------------------------------------------------------------------------------------------- stage


def _checker(n: int = 64, cells: int = 8) -> np.ndarray:
    """A checkerboard with a red top-left cell marker (shows a flipped v at a glance)."""
    idx = (np.arange(n) * cells // n)
    board = ((idx[:, None] + idx[None, :]) % 2).astype(np.uint8)
    tex = np.where(board[..., None] == 1, 200, 60).astype(np.uint8).repeat(3, axis=2)
    tex[: n // cells, : n // cells] = (220, 30, 30)
    return tex


def _textured_box(name: str, iid: int, centre: tuple[float, float, float], size: tuple[float, float, float],
                  color: tuple[float, float, float]) -> RenderMesh:
    box = trimesh.creation.box(extents=size)
    verts = np.asarray(box.vertices) + np.asarray(centre)
    uv = (verts[:, :2] - verts[:, :2].min(0)) / np.ptp(verts[:, :2], axis=0)
    return RenderMesh(name, iid, verts, np.asarray(box.faces), uv, None, base_color=color)


def tiny_stage() -> RenderScene:
    """Floor (4x4 m, textured), two boxes, a cylinder; instance ids 1, 7, 300, 4096 (tests the high byte)."""
    floor_v = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], dtype=np.float64)
    floor_uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    floor = RenderMesh("floor", 1, floor_v, np.array([[0, 1, 2], [0, 2, 3]]), floor_uv, _checker())
    cyl = trimesh.creation.cylinder(radius=0.25, height=0.9, sections=24)
    cyl_v = np.asarray(cyl.vertices) + [0.6, 0.5, 0.45]
    meshes = [
        floor,
        _textured_box("box_a", 7, (-0.5, 0.2, 0.3), (0.6, 0.5, 0.6), (0.8, 0.3, 0.2)),
        _textured_box("box_b", 300, (0.3, -0.6, 0.2), (0.4, 0.4, 0.4), (0.2, 0.5, 0.8)),
        RenderMesh("cylinder", 4096, cyl_v, np.asarray(cyl.faces), None, None, base_color=(0.3, 0.8, 0.3)),
    ]
    lights = [
        Light("bulb", "sphere", make_pose(np.eye(3), [0.5, -0.5, 2.2]), intensity=6.0, radius=0.05),
        Light("panel", "rect", make_pose(np.eye(3), [-0.8, 0.8, 2.4]), intensity=8.0, size=(0.5, 0.5)),
    ]
    return RenderScene(meshes=meshes, lights=lights, instances={}, ambient=0.05, source="tiny_stage")


def cameras() -> list[tuple[Camera, np.ndarray]]:
    """5 views; the last has an off-centre principal point (catches cx/cy sign and half-pixel errors)."""
    cam = Camera.from_hfov(W, H, 65.0)
    off = Camera(W, H, cam.fx, cam.fy, cam.cx + 7.0, cam.cy - 5.0)
    eyes = [(2.5, -2.2, 1.6), (-2.4, -2.0, 1.2), (0.0, 2.6, 2.0), (2.6, 1.5, 0.8), (-1.8, 2.2, 1.8)]
    targets = [(0, 0, 0.3), (0.2, 0.1, 0.2), (0, 0, 0), (0, -0.2, 0.4), (0.3, -0.3, 0.2)]
    views = [(cam, look_at(np.array(e), np.array(t))) for e, t in zip(eyes, targets, strict=True)]
    views[-1] = (off, views[-1][1])
    return views


# ---------------------------------------------------------------------------------------------- backends


def _has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _make_pyrender():
    from synthleak.render.pyrender_backend import create_pyrender_renderer

    return create_pyrender_renderer(CONFIG)


def _make_blender():
    from synthleak.render.blender_backend import create_blender_renderer

    return create_blender_renderer(CONFIG)


def _make_mitsuba():
    from synthleak.render.registry import get_renderer

    return get_renderer(CONFIG)


BACKENDS = {
    "pyrender": (_make_pyrender, "pyrender", "pyrender not installed (pip install pyrender; apt libegl1)"),
    "blender": (_make_blender, "bpy", "no bpy here: use /work/venv-blender (pip install -e .[blender])"),
    "mitsuba": (_make_mitsuba, "mitsuba", "mitsuba not installed"),
}

_FRAMES: dict[str, list[Frame]] = {}


def _frames(name: str) -> list[Frame]:
    """Render the 5 views once per backend per session (seeded by view index)."""
    factory, module, reason = BACKENDS[name]
    if not _has(module):
        pytest.skip(reason)
    if name not in _FRAMES:
        renderer = factory()
        renderer.prepare(tiny_stage())
        _FRAMES[name] = [renderer.render(cam, pose, seed=i) for i, (cam, pose) in enumerate(cameras())]
    return _FRAMES[name]


@pytest.fixture(scope="module")
def reference() -> list[tuple[np.ndarray, np.ndarray]]:
    """Exact pixel-centre ray cast (synthleak.render.raycast) of every view."""
    from synthleak.render.raycast import RaycastGT

    gt = RaycastGT(tiny_stage().meshes)
    return [gt.render(cam, pose) for cam, pose in cameras()]


# ---------------------------------------------------------------------------------------------- checks


def _interior(instance: np.ndarray) -> np.ndarray:
    """Pixels whose 4-neighbours carry the same id (drops a 1-px band at every instance edge)."""
    p = np.pad(instance, 1, mode="edge")
    c = p[1:-1, 1:-1]
    return (c == p[:-2, 1:-1]) & (c == p[2:, 1:-1]) & (c == p[1:-1, :-2]) & (c == p[1:-1, 2:])


def assert_masks_agree(a: np.ndarray, b: np.ndarray, what: str, min_iou: float = 0.98) -> None:
    keep = _interior(a) & _interior(b)
    assert keep.mean() > 0.7, f"{what}: too few interior pixels ({keep.mean():.2f})"
    for iid in np.union1d(np.unique(a[keep]), np.unique(b[keep])):
        if iid == 0:
            continue
        ma, mb = (a == iid) & keep, (b == iid) & keep
        if ma.sum() + mb.sum() < 20:  # a sliver of a few pixels is all edge band
            continue
        iou = (ma & mb).sum() / (ma | mb).sum()
        assert iou >= min_iou, f"{what}: instance {iid} IoU {iou:.4f} < {min_iou}"


def assert_depths_agree(a: np.ndarray, b: np.ndarray, inst_a: np.ndarray, inst_b: np.ndarray,
                        what: str) -> None:
    both = np.isfinite(a) & np.isfinite(b) & _interior(inst_a) & _interior(inst_b) & (inst_a == inst_b)
    assert both.sum() > 0.25 * a.size, f"{what}: only {both.sum()} comparable pixels"
    diff = np.abs(a[both].astype(np.float64) - b[both])
    assert np.median(diff) < 2e-3, f"{what}: median |dz| {np.median(diff) * 1e3:.3f} mm"
    p99 = np.quantile(diff, 0.99)
    assert p99 < 1e-2, f"{what}: 99th percentile |dz| {p99 * 1e3:.2f} mm"


def _unproject(camera: Camera, cam_from_world: np.ndarray, depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    pts = np.stack([(u + 0.5 - camera.cx) / camera.fx * z, (v + 0.5 - camera.cy) / camera.fy * z, z], axis=1)
    world_from_cam = invert(cam_from_world)
    return pts @ world_from_cam[:3, :3].T + world_from_cam[:3, 3]


@pytest.fixture(scope="module")
def stage_mesh() -> trimesh.Trimesh:
    meshes = tiny_stage().meshes
    return trimesh.util.concatenate([trimesh.Trimesh(m.vertices, m.faces, process=False) for m in meshes])


# ---------------------------------------------------------------------------------------------- tests

PER_BACKEND = ["pyrender", "blender", "mitsuba"]


@pytest.mark.parametrize("name", PER_BACKEND)
def test_frame_format(name: str) -> None:
    for frame in _frames(name):
        assert frame.rgb.shape == (H, W, 3) and frame.rgb.dtype == np.uint8
        assert frame.depth.shape == (H, W) and frame.depth.dtype == np.float32
        assert frame.instance.shape == (H, W) and frame.instance.dtype == np.uint16
        assert np.all(np.isinf(frame.depth) == (frame.instance == 0)), "depth is +inf exactly where id is 0"
        lit = frame.rgb[frame.instance > 0].mean()
        assert 15 < lit < 240, f"{name}: mean RGB {lit:.1f} on objects (black or blown out)"
    ids = set().union(*(np.unique(f.instance).tolist() for f in _frames(name)))
    assert {1, 7, 300, 4096} <= ids, f"{name}: instance ids seen {sorted(ids)}"


@pytest.mark.parametrize("name", PER_BACKEND)
def test_ground_truth_matches_raycast(name: str, reference) -> None:
    for i, (frame, (ref_depth, ref_inst)) in enumerate(zip(_frames(name), reference, strict=True)):
        assert_masks_agree(frame.instance, ref_inst, f"{name} view {i} vs raycast")
        assert_depths_agree(frame.depth, ref_depth, frame.instance, ref_inst, f"{name} view {i} vs raycast")


@pytest.mark.parametrize("name", PER_BACKEND)
def test_ids_exact_at_pixel_centres(name: str, reference) -> None:
    """Stricter than IoU: a half-pixel or flipped principal point would mismatch whole edge bands."""
    for i, (frame, (_, ref_inst)) in enumerate(zip(_frames(name), reference, strict=True)):
        wrong = int(np.count_nonzero(frame.instance != ref_inst))
        assert wrong <= 0.002 * frame.instance.size, f"{name} view {i}: {wrong} pixels with another id"


@pytest.mark.parametrize("name", PER_BACKEND)
def test_unprojected_depth_lies_on_mesh(name: str, stage_mesh: trimesh.Trimesh) -> None:
    rng = np.random.default_rng(0)
    for i, (frame, (cam, pose)) in enumerate(zip(_frames(name), cameras(), strict=True)):
        mask = np.isfinite(frame.depth) & _interior(frame.instance)
        sample = np.zeros_like(mask)
        v, u = np.nonzero(mask)
        pick = rng.choice(len(v), size=min(400, len(v)), replace=False)
        sample[v[pick], u[pick]] = True
        pts = _unproject(cam, pose, frame.depth, sample)
        _, dist, _ = trimesh.proximity.closest_point(stage_mesh, pts)
        frac = np.mean(dist < 2e-3)
        assert frac >= 0.99, f"{name} view {i}: only {frac:.3f} of unprojected pixels within 2 mm of the mesh"


def test_backends_agree_pairwise() -> None:
    names = [n for n in PER_BACKEND if _has(BACKENDS[n][1])]
    if len(names) < 2:
        pytest.skip(f"only {names} available here")
    for a, b in combinations(names, 2):
        for i, (fa, fb) in enumerate(zip(_frames(a), _frames(b), strict=True)):
            assert_masks_agree(fa.instance, fb.instance, f"{a} vs {b} view {i}")
            assert_depths_agree(fa.depth, fb.depth, fa.instance, fb.instance, f"{a} vs {b} view {i}")


@pytest.mark.parametrize("name", PER_BACKEND)
def test_same_seed_same_bytes(name: str) -> None:
    first = _frames(name)[0]
    factory, _, _ = BACKENDS[name]
    renderer = factory()
    renderer.prepare(tiny_stage())
    cam, pose = cameras()[0]
    again = renderer.render(cam, pose, seed=0)
    assert again.rgb.tobytes() == first.rgb.tobytes(), f"{name}: RGB differs for the same seed"
    assert again.depth.tobytes() == first.depth.tobytes(), f"{name}: depth differs for the same seed"
    assert again.instance.tobytes() == first.instance.tobytes(), f"{name}: instance ids differ"


def test_pyrender_texture_orientation() -> None:
    """Looking straight down at the floor: the red marker (texture row 0 = top, v = 1) lands at -x, +y."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    from synthleak.render.pyrender_backend import PyrenderRenderer

    scene = tiny_stage()
    scene.meshes = scene.meshes[:1]
    renderer = PyrenderRenderer(shadows=False)
    renderer.prepare(scene)
    cam = Camera(W, H, 60.0, 60.0, W / 2, H / 2)
    # Camera above the floor looking down, image x = world +x, image y (down) = world -y.
    pose = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 5.0])
    frame = renderer.render(cam, pose, seed=0)
    red = (frame.rgb[..., 0].astype(int) - frame.rgb[..., 1]) > 60
    v, u = np.nonzero(red)
    assert len(v) > 4, "red marker not visible"
    # World (-1.75, 1.75) -> u + 0.5 = cx + f x / z = 48 - 21 = 27, v + 0.5 = cy - f y / z = 36 - 21 = 15.
    assert abs(u.mean() + 0.5 - 27.0) < 1.0 and abs(v.mean() + 0.5 - 15.0) < 1.0, (u.mean(), v.mean())


def test_unavailable_backend_message(monkeypatch) -> None:
    """Without a usable GL platform the constructor fails and says how to install it."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    import synthleak.render.pyrender_backend as pb

    def broken():
        raise pb.PyrenderUnavailable(f"renderer 'pyrender' is unavailable (no EGL); {pb.INSTALL_HINT}")

    monkeypatch.setattr(pb, "_pyrender", broken)
    with pytest.raises(ImportError, match="apt-get install libegl1"):
        pb.create_pyrender_renderer(CONFIG)


def test_blender_ids_above_15_bits(reference) -> None:
    """Ids >= 32768 need the material index pass for bit 15 (Blender caps pass_index at 32767)."""
    if not _has("bpy"):
        pytest.skip(BACKENDS["blender"][2])
    from synthleak.render.blender_backend import BlenderRenderer

    scene = tiny_stage()
    scene.meshes[3].instance_id = 40000  # the cylinder, 4096 in the reference
    renderer = BlenderRenderer(spp=1)
    renderer.prepare(scene)
    cam, pose = cameras()[0]
    depth, instance = renderer.render_ground_truth(cam, pose)
    ref_depth, ref_inst = reference[0]
    expected = np.where(ref_inst == 4096, 40000, ref_inst).astype(np.uint16)
    assert 40000 in instance
    assert np.count_nonzero(instance != expected) <= 0.002 * instance.size
    assert_depths_agree(depth, ref_depth, instance, expected, "blender GT without override")


def test_blender_unavailable_message() -> None:
    """Where bpy does not import (the main venv) the constructor fails and names the separate venv."""
    if _has("bpy"):
        pytest.skip("bpy is importable here")
    from synthleak.render.blender_backend import create_blender_renderer

    with pytest.raises(ImportError, match=r"pip install -e '\.\[blender\]'"):
        create_blender_renderer(CONFIG)


def test_registry_factories(monkeypatch) -> None:
    """``config.renderer`` reaches these backends through render.registry (wired lazily by name there)."""
    registry = pytest.importorskip("synthleak.render.registry")
    from synthleak.render import blender_backend, pyrender_backend

    monkeypatch.setattr(registry, "_FACTORIES", dict(registry._FACTORIES))  # restored after the test
    pairs = [("pyrender", "pyrender", pyrender_backend), ("blender", "bpy", blender_backend)]
    for name, module, backend in pairs:
        if name not in registry.available_renderers():
            registry.register_renderer(name, getattr(backend, f"create_{name}_renderer"), backend.INSTALL_HINT)
        config = RenderConfig(renderer=name, width=W, height=H)
        if _has(module):
            assert registry.get_renderer(config).name == name
        else:
            with pytest.raises(registry.RendererUnavailable, match="install"):
                registry.get_renderer(config)


def test_blender_one_scene_per_process() -> None:
    """bpy is one Blender per process: a renderer whose scene was replaced says so instead of rendering it."""
    if not _has("bpy"):
        pytest.skip(BACKENDS["blender"][2])
    first, second = _make_blender(), _make_blender()
    first.prepare(tiny_stage())
    second.prepare(tiny_stage())
    cam, pose = cameras()[0]
    with pytest.raises(RuntimeError, match="prepare"):
        first.render(cam, pose, seed=0)


@pytest.fixture(scope="module")
def usd_room(tmp_path_factory) -> RenderScene:
    """The example room written as a USD stage and read back (synthleak.scene.usd_write, synthleak.core.usd_read)."""
    try:
        from synthleak.core.usd_read import read_render_scene
        from synthleak.scene.example import example_spec
        from synthleak.scene.usd_write import write_stage
    except ImportError as exc:  # the scene package is built alongside: skip rather than fail
        pytest.skip(f"scene USD I/O not available: {exc}")
    path = tmp_path_factory.mktemp("stage") / "room_example.usda"
    write_stage(example_spec(), path)
    return read_render_scene(path)


@pytest.mark.parametrize("name", ["pyrender", "blender"])
def test_real_usd_stage_matches_raycast(name: str, usd_room: RenderScene) -> None:
    """A real stage (shell with door and window backdrop, table, box, rect + sphere light) from inside."""
    from synthleak.render.raycast import RaycastGT

    factory, module, reason = BACKENDS[name]
    if not _has(module):
        pytest.skip(reason)
    renderer = factory()
    renderer.prepare(usd_room)
    gt = RaycastGT(usd_room.meshes)
    cam = Camera.from_hfov(W, H, 70.0)
    views = [((-1.5, -1.3, 1.6), (0.4, 0.2, 0.5)), ((1.6, 1.2, 1.2), (0.3, 0.0, 0.6)),
             ((1.5, -1.2, 2.0), (-2.0, 0.5, 1.0))]
    for i, (eye, target) in enumerate(views):
        pose = look_at(np.array(eye), np.array(target))
        frame = renderer.render(cam, pose, seed=i)
        ref_depth, ref_inst = gt.render(cam, pose)
        assert 15 < frame.rgb.mean() < 240, f"{name} view {i}: mean RGB {frame.rgb.mean():.1f}"
        assert np.count_nonzero(frame.instance != ref_inst) <= 0.002 * frame.instance.size
        assert_masks_agree(frame.instance, ref_inst, f"{name} USD view {i}")
        assert_depths_agree(frame.depth, ref_depth, frame.instance, ref_inst, f"{name} USD view {i}")


def test_pyrender_renderers_coexist() -> None:
    """Dropping one renderer must not break another (pyrender's EGL teardown terminates the display)."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    import gc

    cam, pose = cameras()[0]
    first, second = _make_pyrender(), _make_pyrender()
    first.prepare(tiny_stage())
    second.prepare(tiny_stage())
    expected = first.render(cam, pose, seed=0)
    del first
    gc.collect()
    again = second.render(cam, pose, seed=0)
    assert again.rgb.tobytes() == expected.rgb.tobytes()
    assert np.array_equal(again.instance, expected.instance)


def test_pyrender_coincident_surfaces_in_scene_order() -> None:
    """Two coplanar quads: the mesh listed first wins the depth test in colour and ids, whichever order
    pyrender's node set would iterate in (it follows memory addresses, so it changed between processes)."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    from synthleak.render.pyrender_backend import PyrenderRenderer

    quad = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    colours = {1: (0.9, 0.1, 0.1), 2: (0.1, 0.1, 0.9)}
    cam = Camera(32, 24, 30.0, 30.0, 16.0, 12.0)
    pose = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 3.0])  # above the quads, looking down
    for first, second in ((1, 2), (2, 1)):
        for _ in range(3):  # fresh scenes: new node objects at new addresses each time
            meshes = [RenderMesh(f"quad{i}", i, quad, faces, None, None, base_color=colours[i])
                      for i in (first, second)]
            renderer = PyrenderRenderer(shadows=False)
            renderer.prepare(RenderScene(meshes=meshes, lights=[], instances={}, ambient=1.0))
            frame = renderer.render(cam, pose, seed=0)
            assert np.all(frame.instance[4:20, 6:26] == first), (first, np.unique(frame.instance))
            red_wins = frame.rgb[12, 16, 0] > frame.rgb[12, 16, 2]
            assert red_wins == (first == 1), frame.rgb[12, 16]


def test_pyrender_shadow_filter_matches_stock_shader() -> None:
    """The 16-read shadow filter renders the image of pyrender's own 36-read filter (up to a grey level at
    the odd pixel), and the shadows are there (a box on the floor, lit by a panel off to one side)."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    from pyrender.shader_program import ShaderProgramCache

    from synthleak.render import pyrender_backend as pb

    scene = tiny_stage()
    scene.meshes = scene.meshes[:2]  # the floor and box_a
    scene.lights = [Light("panel", "rect", make_pose(np.eye(3), [-0.5, 1.3, 1.6]), intensity=150.0,
                          size=(0.3, 0.3))]
    cam = Camera.from_hfov(W, H, 70.0)
    pose = look_at((0.0, -2.5, 3.0), (-0.4, 0.2, 0.0))
    shadowed, flat = pb.PyrenderRenderer(shadows=True), pb.PyrenderRenderer(shadows=False)
    renderer = pb._GL[0]._renderer
    from pathlib import Path

    assert "texel * vec2(float(x - 1)" in Path(renderer._program_cache.shader_dir, "mesh.frag").read_text()
    shadowed.prepare(scene)
    ours = shadowed.render(cam, pose, seed=0).rgb.astype(int)
    patched_cache = renderer._program_cache
    renderer._program_cache = ShaderProgramCache()  # pyrender's shaders
    try:
        shadowed.prepare(scene)
        stock = shadowed.render(cam, pose, seed=0).rgb.astype(int)
    finally:
        renderer._program_cache = patched_cache
    flat.prepare(scene)
    unshadowed = flat.render(cam, pose, seed=0).rgb.astype(int)
    assert np.abs(ours - stock).max() <= 1 and (ours != stock).any(-1).mean() < 0.005
    darker = (unshadowed - ours).max(-1) > 20
    assert darker.mean() > 0.02, f"shadow covers {darker.mean():.2%} of the image"


def four_bulb_stage() -> RenderScene:
    """``tiny_stage`` lit by four bulbs and the panel: pyrender's shader sums the bulbs in the order they are
    bound, and float sums (fused multiply-adds) round differently in another order."""
    scene = tiny_stage()
    bulbs = [((0.5, -0.5, 2.2), 6.0), ((-1.0, 1.0, 2.0), 5.0), ((1.2, 1.1, 1.8), 4.5), ((-1.3, -1.2, 2.4), 7.0)]
    scene.lights = [Light(f"bulb{i}", "sphere", make_pose(np.eye(3), p), intensity=s, radius=0.05)
                    for i, (p, s) in enumerate(bulbs)] + scene.lights[1:]
    return scene


def four_bulb_frames() -> list[np.ndarray]:
    """RGB, depth and ids of the 5 views of :func:`four_bulb_stage` from a fresh pyrender scene."""
    from synthleak.render.pyrender_backend import PyrenderRenderer

    renderer = PyrenderRenderer(shadows=True)
    renderer.prepare(four_bulb_stage())
    frames = [renderer.render(cam, pose, seed=0) for cam, pose in cameras()]
    return [a for f in frames for a in (f.rgb, f.depth, f.instance)]


_FOUR_BULB_SCRIPT = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_backends import four_bulb_frames
np.savez(sys.argv[2], *four_bulb_frames())
"""


def test_pyrender_same_bytes_in_fresh_scenes_and_processes(tmp_path) -> None:
    """Lights are bound in stage order: pyrender iterated a set whose order followed memory addresses, so two
    runs of one config differed by a grey level at a few pixels (ci-tiny-pyrender: 7 attacker frames, lit by 3-4
    bulbs). Two scenes in this process and one in another process with another llvmpipe thread count give the
    same bytes."""
    if not _has("pyrender"):
        pytest.skip(BACKENDS["pyrender"][2])
    import os
    import subprocess
    import sys
    from pathlib import Path

    from synthleak.render.pyrender_backend import PyrenderRenderer

    names = [light.name for light in four_bulb_stage().lights]
    for _ in range(6):  # fresh scenes: new light nodes at new addresses each time
        renderer = PyrenderRenderer(shadows=True)
        renderer.prepare(four_bulb_stage())
        assert [node.name for node in renderer._scene.light_nodes] == names
    first, again = four_bulb_frames(), four_bulb_frames()
    out = tmp_path / "frames.npz"
    import synthleak

    package_root = str(Path(synthleak.__file__).parents[1])  # the synthleak this process imported
    env = {**os.environ, "LP_NUM_THREADS": "1", "PYOPENGL_PLATFORM": "egl",
           "PYTHONPATH": os.pathsep.join(p for p in (package_root, os.environ.get("PYTHONPATH")) if p)}
    subprocess.run([sys.executable, "-c", _FOUR_BULB_SCRIPT, str(Path(__file__).parent), str(out)], env=env,
                   check=True, timeout=300)
    with np.load(out) as data:
        other = [data[f"arr_{i}"] for i in range(len(data.files))]
    assert first[0].mean() > 40  # lit
    for i, (a, b, c) in enumerate(zip(first, again, other, strict=True)):
        assert a.tobytes() == b.tobytes(), f"array {i}: differs between two scenes in one process"
        assert a.tobytes() == c.tobytes(), f"array {i}: differs in another process"
