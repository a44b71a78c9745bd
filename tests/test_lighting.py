"""Stages lit by what other tools write: an emissive mesh as the only light lights the room in every backend,
and a stage with no light at all renders with the documented default light and a warning. Lighting never
touches the ground truth: depth and instance masks stay those of the exact ray cast."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import RenderConfig, StudyConfig
from synthleak.core.types import Camera
from synthleak.geometry.poses import look_at
from synthleak.render.raycast import RaycastGT
from synthleak.render.registry import RendererUnavailable, get_renderer
from tiny_stages import write_config, write_cornell_box

BACKENDS = {
    "mitsuba": {"renderer": "mitsuba"},
    "mitsuba-llvm": {"renderer": "mitsuba", "mitsuba_variant": "llvm_ad_rgb"},
    "pyrender": {"renderer": "pyrender"},
}
CAMERA = Camera.from_hfov(96, 72, 65.0)
POSE = look_at(np.array([0.0, -2.6, 1.1]), np.array([0.0, 0.0, 0.7]))  # through the open front of the box


def _renderer(backend: str):
    try:
        return get_renderer(RenderConfig(width=CAMERA.width, height=CAMERA.height, spp=4, **BACKENDS[backend]))
    except RendererUnavailable as exc:
        pytest.skip(f"{backend}: {exc}")


def _ids(scene) -> dict[str, int]:
    return {info.prim_path.rsplit("/", 1)[-1]: iid for iid, info in scene.instances.items()}


def _assert_gt_is_the_ray_cast(scene, frame, backend: str) -> None:
    depth, instance = RaycastGT(scene.meshes).render(CAMERA, POSE)
    if backend.startswith("mitsuba"):
        assert np.array_equal(frame.instance, instance) and np.array_equal(frame.depth, depth)
        return
    assert (frame.instance == instance).mean() >= 0.99
    both = np.isfinite(depth) & np.isfinite(frame.depth)
    assert np.median(np.abs(frame.depth[both] - depth[both])) < 0.002


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_an_emissive_mesh_alone_lights_the_room(tmp_path: Path, backend: str) -> None:
    from synthleak.core.usd_read import read_render_scene

    renderer = _renderer(backend)
    scene = read_render_scene(write_cornell_box(tmp_path / "box.usda", light="emissive"))
    assert not scene.lights and scene.ambient == 0  # the ceiling patch is the only light
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an emissive mesh is a light: no default-light warning anywhere
        renderer.prepare(scene)
        frame = renderer.render(CAMERA, POSE, 3)
    ids = _ids(scene)
    grey = frame.rgb.astype(float).max(axis=2)
    for name in ("Floor", "Back", "Left", "Right"):
        seen = frame.instance == ids[name]
        assert seen.sum() > 100, name
        assert grey[seen].mean() > 25, (name, grey[seen].mean())  # lit, not just the glowing patch
    top = (frame.instance == ids["Cube"]) & (grey > 40)  # the cube's top faces the lamp (its sides do not)
    assert top.sum() > 20
    red = frame.rgb[frame.instance == ids["Left"]].astype(float).mean(axis=0)
    assert red[0] > 1.5 * red[1], red  # the walls keep their colour
    _assert_gt_is_the_ray_cast(scene, frame, backend)


@pytest.mark.parametrize("backend", ["mitsuba", "pyrender"])
def test_a_stage_without_light_renders_with_the_default_light(tmp_path: Path, backend: str) -> None:
    from synthleak.core.dataset import load_sequence
    from synthleak.render.pipeline import render_sequence

    _renderer(backend)
    config = StudyConfig(name="dark", seed=4, render=RenderConfig(width=64, height=48, spp=2, scene_frames=3,
                                                                  query_every=3, **BACKENDS[backend]))
    dark = write_cornell_box(tmp_path / "dark.usda", light="none")
    lit = write_cornell_box(tmp_path / "lit.usda", light="sphere")
    with pytest.warns(UserWarning, match=r"dark\.usda: the stage has no light.*default light"):
        dark_seq = load_sequence(render_sequence(dark, tmp_path / "a" / "box", config, "scene", progress=False))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lit_seq = load_sequence(render_sequence(lit, tmp_path / "b" / "box", config, "scene", progress=False))
    assert dark_seq.frames == lit_seq.frames and len(dark_seq.frames) == 3
    for frame in dark_seq.frames:
        rgb, hit = dark_seq.rgb(frame).astype(float), np.isfinite(dark_seq.depth(frame))
        assert rgb[hit].mean() > 30 and (rgb[hit].sum(axis=1) > 0).mean() > 0.95  # every surface lit
        assert np.array_equal(dark_seq.depth(frame), lit_seq.depth(frame))  # same poses, same ground truth
        assert np.array_equal(dark_seq.instance(frame), lit_seq.instance(frame))


def test_the_cli_prints_the_default_light_warning(tmp_path: Path) -> None:
    config = write_config(tmp_path / "tiny.toml", scene_frames=2)
    stage = write_cornell_box(tmp_path / "dark.usda", light="none")
    result = subprocess.run([sys.executable, "-m", "synthleak.cli", "render", str(config), "--stages", str(stage),
                             "--out", str(tmp_path / "out"), "--quiet"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "dark.usda: the stage has no light" in result.stderr and "default light" in result.stderr


def test_stand_ins_for_emissive_meshes() -> None:
    """A flat emitter becomes a rect light of its area facing along its normal; a closed one a sphere light of
    the same power; a glowing part next to much stronger lights gets none."""
    from synthleak.core.types import Light, RenderMesh, RenderScene
    from synthleak.render.lighting import emissive_lights, light_power

    quad = RenderMesh("panel", 1, np.array([[0, 0, 2.0], [0, 1, 2], [1, 1, 2], [1, 0, 2]]),
                      np.array([[0, 1, 2], [0, 2, 3]]), None, None, emissive=(6.0, 3.0, 3.0))  # faces -z
    cube_v = np.array([[x, y, z] for x in (0, 0.1) for y in (0, 0.1) for z in (0, 0.1)], dtype=float)
    cube_f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    bulb = RenderMesh("bulb", 2, cube_v, cube_f, None, None, emissive=(2.0, 2.0, 2.0))
    rect, sphere = emissive_lights(RenderScene([quad, bulb], [], {}))
    assert rect.kind == "rect" and rect.size == pytest.approx((1.0, 1.0)) and rect.intensity == 6.0
    assert rect.color == pytest.approx((1.0, 0.5, 0.5))
    assert np.allclose(rect.world_from_light[:3, 2], [0, 0, 1]) and np.allclose(rect.world_from_light[:3, 3],
                                                                                [0.5, 0.5, 1.99])
    assert sphere.kind == "sphere" and np.allclose(sphere.world_from_light[:3, 3], 0.05)
    assert light_power(sphere) == pytest.approx(np.pi * 2.0 * 0.06)  # pi x radiance x area
    strong = Light("sun_lamp", "sphere", np.eye(4), 100.0)
    names = [light.name for light in emissive_lights(RenderScene([quad, bulb], [strong], {}))]
    assert len(names) == 1 and names[0].startswith("emissive_1")  # the bulb is under 1% of the lamp's power
    scene = dataclasses.replace(RenderScene([quad], [], {}), lights=[strong])
    assert emissive_lights(scene)[0].kind == "rect"
