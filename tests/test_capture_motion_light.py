"""Motion blur in the capture model (:mod:`synthleak.render.motion_blur`) and light that changes between captures
(:mod:`synthleak.render.light_conditions`, ``[render] light_map / light_genuine / light_attacker``).

Motion blur runs on a synthetic 160x120 frame (a sharp checkerboard and a depth map); the lighting tests render
the tiny room of tests/test_render.py with mitsuba at 64x48 (a few seconds of CPU).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace

import numpy as np
import pytest

from synthleak.config import ConfigError, RenderConfig, config_to_dict
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera, InstanceInfo, RenderMesh
from synthleak.errors import StageError
from synthleak.render.capture import capture
from synthleak.render.devices import draw_device, profile
from synthleak.render.light_conditions import (
    LIGHTING_RECORDS,
    SUN_NAME,
    apply_condition,
    draw_condition,
    lighting_seed,
    window_normal,
)
from synthleak.render.motion_blur import MotionBlur, apply_motion_blur
from synthleak.render.pipeline import render_scene_sequence, write_manifest
from test_render import room_scene, tiny_config, tree_hashes

W, H = 160, 120
CAMERA = Camera.from_hfov(W, H, 65.0)
INTRINSICS = (CAMERA.fx, CAMERA.fy, CAMERA.cx, CAMERA.cy)
SMALL = dict(width=64, height=48, spp=2, scene_frames=4, attacker_frames=2, query_every=2)


def checkerboard(square: int = 8) -> np.ndarray:
    v, u = np.mgrid[0:H, 0:W]
    board = (((u // square) + (v // square)) % 2).astype(np.float32)
    return np.repeat((0.05 + 0.4 * board)[..., None], 3, axis=2) * np.array([1.0, 0.9, 0.8], np.float32)


def sharpness(x: np.ndarray) -> float:
    """Mean squared horizontal + vertical gradient of the luminance."""
    g = x.mean(axis=2)
    return float((np.diff(g, axis=1) ** 2).mean() + (np.diff(g, axis=0) ** 2).mean())


# ---------------------------------------------------------------------------------------------- motion blur
def test_a_static_camera_without_shake_is_the_identity():
    x = checkerboard()
    depth = np.full((H, W), 2.0, np.float32)
    still = MotionBlur()
    out, record = apply_motion_blur(x, still, 1 / 15, INTRINSICS, depth)
    assert np.array_equal(out, x) and record["motion_blur_px"] == 0.0 and record["motion_blur_samples"] == 1
    # in the capture chain too: a still phone gives the bytes of the phone without motion blur
    base = replace(draw_device("phone", 3), jpeg=None)
    lin = checkerboard()
    a = capture(lin, replace(base, motion_blur=still), 7, depth, camera=CAMERA)
    b = capture(lin, replace(base, motion_blur=None), 7, depth, camera=CAMERA)
    assert np.array_equal(a.rgb, b.rgb)
    assert a.record["shutter_s"] == b.record["shutter_s"] and "motion_blur" in a.record["effects"]


def test_blur_length_follows_the_shutter_time():
    x = checkerboard()
    shake = MotionBlur(angular_velocity_deg_s=(3.0, 8.0, 0.0))
    lengths, sharp = [], []
    for shutter in (1 / 250, 1 / 60, 1 / 15, 1 / 4):
        out, record = apply_motion_blur(x, shake, shutter, INTRINSICS)
        lengths.append(record["motion_blur_px"])
        sharp.append(sharpness(out))
    assert all(b > a for a, b in zip(lengths, lengths[1:], strict=False))
    # small rotations: the length is proportional to the shutter time; fx * omega * T at the centre, up to
    # (1 + tan^2) more at the edges of a 65 deg field of view (the longest path is reported)
    assert lengths[3] / lengths[0] == pytest.approx(250 / 4, rel=0.02)
    at_centre = CAMERA.fx * np.radians(np.hypot(3.0, 8.0)) / 15
    assert at_centre < lengths[2] < 1.8 * at_centre
    assert all(b < a for a, b in zip(sharp, sharp[1:], strict=False))
    assert sharp[-1] < 0.5 * sharpness(x)

    # through capture: the auto-exposure's shutter sets it (phone 1/30 s, phone-low-light 1/15 s, same shake)
    depth = np.full((H, W), 2.0, np.float32)
    rates = []
    for name in ("phone", "phone-low-light"):
        params = replace(profile(name), motion_blur=shake)
        record = capture(checkerboard() * 0.2, params, 0, depth, camera=CAMERA).record
        rates.append((record["shutter_s"], record["motion_blur_px"], record["motion_blur_shutter_s"]))
    (t1, px1, s1), (t2, px2, s2) = rates
    assert t1 == s1 and t2 == s2 and t2 == pytest.approx(2 * t1)  # AE meters before the blur: same shutter
    assert px2 == pytest.approx(2 * px1, rel=0.05)


def test_translation_blur_is_depth_aware():
    """A sideways step blurs the near half of the frame ten times as much as the far half."""
    x = checkerboard(square=4)
    depth = np.full((H, W), 10.0, np.float32)
    depth[:, : W // 2] = 1.0
    step = MotionBlur(velocity_m_s=(1.5, 0.0, 0.0))  # a brisk sideways walk, 1/30 s: 6.4 px at 1 m here
    out, record = apply_motion_blur(x, step, 1 / 30, INTRINSICS, depth)
    near_px = CAMERA.fx * 1.5 / 30 / 1.0
    assert record["motion_blur_px"] == pytest.approx(near_px, rel=0.05)
    near, far = (slice(10, H - 10), slice(10, W // 2 - 10)), (slice(10, H - 10), slice(W // 2 + 10, W - 10))

    def across(img: np.ndarray) -> float:  # horizontal gradient energy: the direction of the motion
        return float((np.diff(img.mean(axis=2), axis=1) ** 2).mean())

    assert across(out[near]) < 0.3 * across(x[near])
    assert across(out[far]) > 0.6 * across(x[far])
    assert np.array_equal(out[:, :, :].mean(axis=2)[:, W // 2 + 10 :] != 0, np.ones((H, W // 2 - 10), bool))
    # a point at infinity does not move with the camera
    _, still = apply_motion_blur(x, step, 1 / 30, INTRINSICS, np.full((H, W), np.inf, np.float32))
    assert still["motion_blur_px"] == 0.0
    with pytest.raises(ConfigError, match="motion_blur: a moving camera .* needs the frame's depth"):
        apply_motion_blur(x, step, 1 / 30, INTRINSICS, None)


def test_rotation_blur_agrees_with_the_reprojection_of_each_sample():
    """The homography fast path equals remapping each sample from unprojected rays (the depth-aware path)."""
    x = checkerboard(square=5)
    depth = np.full((H, W), 3.0, np.float32)
    shake = MotionBlur(angular_velocity_deg_s=(4.0, -6.0, 10.0))
    fast, rf = apply_motion_blur(x, shake, 1 / 15, INTRINSICS, depth)
    tiny_step = replace(shake, velocity_m_s=(1e-9, 0.0, 0.0))  # forces the remap path, no visible translation
    slow, rs = apply_motion_blur(x, tiny_step, 1 / 15, INTRINSICS, depth)
    assert rf["motion_blur_samples"] == rs["motion_blur_samples"] > 2
    diff = np.abs(fast - slow)  # OpenCV interpolates at 1/32 px: a step of the 0.4 checkerboard is 0.0125
    assert diff.max() < 0.01 and diff.mean() < 2e-4
    assert sharpness(fast) < 0.7 * sharpness(x)


def test_motion_blur_is_seeded_per_photo():
    lin = checkerboard() * 0.1
    depth = np.full((H, W), 2.0, np.float32)
    drawn = [draw_device("phone-low-light", s).motion_blur for s in range(4)]
    assert len({d.angular_velocity_deg_s for d in drawn}) == 4
    assert draw_device("phone-low-light", 2) == draw_device("phone-low-light", 2)
    a = capture(lin, draw_device("web-photo", 5), 11, depth, camera=CAMERA)
    b = capture(lin, draw_device("web-photo", 5), 11, depth, camera=CAMERA)
    assert np.array_equal(a.rgb, b.rgb) and a.record == b.record
    assert profile("ideal").motion_blur is None and draw_device("ideal", 1).motion_blur is None
    # the other draws are those of before: motion blur's draws come last in the stream
    rng = np.random.default_rng(9)
    z = rng.standard_normal(4)
    rng.random(10), rng.uniform(1e-8, 1.0, size=4)
    shake_z, shake_u = rng.standard_normal(3), rng.random()
    phone = draw_device("phone", 9)
    assert phone.exposure.ev_bias_stops == pytest.approx(float(np.clip(0.2 * z[0], -0.5, 0.5)))
    speed = float(np.exp(np.log(0.3) + (np.log(1.2) - np.log(0.3)) * shake_u))
    assert phone.motion_blur.angular_velocity_deg_s == pytest.approx(
        (speed * shake_z[0], speed * shake_z[1], 0.5 * speed * shake_z[2]))


def test_phone_low_light_blurs_more_than_phone():
    mean = {}
    for name in ("phone", "phone-low-light"):
        lin = checkerboard() * (0.2 if name == "phone" else 0.01)
        depth = np.full((H, W), 2.0, np.float32)
        mean[name] = np.mean([capture(lin, draw_device(name, s), s, depth, camera=CAMERA).record["motion_blur_px"]
                              for s in range(12)])
    assert mean["phone-low-light"] > 2 * mean["phone"] > 0


def test_bad_motion_blur_parameters_are_config_errors():
    with pytest.raises(ConfigError, match=r"motion_blur\.angular_velocity_deg_s"):
        MotionBlur(angular_velocity_deg_s=(1.0, 2.0))  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"motion_blur\.max_samples"):
        MotionBlur(max_samples=1)
    with pytest.raises(ConfigError, match="motion_blur: needs the camera intrinsics"):
        capture(checkerboard(), replace(profile("ideal"), motion_blur=MotionBlur()), 0)


# ------------------------------------------------------------------------------------------ lighting conditions
def test_conditions_are_drawn_within_their_ranges():
    scene, _ = room_scene()
    conditions = [draw_condition(scene, "map", s) for s in range(40)]
    assert {c.daytime for c in conditions} == {True, False}
    assert all(2700 - 1e-6 <= c.lamp_temperature_k <= 6500 + 1e-6 for c in conditions)
    assert all(any(c.lamps_on) or c.daytime for c in conditions)
    assert any(not all(c.lamps_on) for c in conditions)
    assert draw_condition(scene, "map", 3) == draw_condition(scene, "map", 3)
    assert all(c.sun_irradiance == 0 for c in conditions)  # the test room has no window

    lit = apply_condition(scene, conditions[0])
    assert all(m.vertices is n.vertices for m, n in zip(lit.meshes, scene.meshes, strict=True))  # geometry shared
    assert lit.instances is scene.instances and [lt.intensity for lt in scene.lights] == [4.0, 3.0]  # untouched
    assert lit.ambient == pytest.approx(scene.ambient * conditions[0].ambient_scale)
    assert len(lit.lights) == sum(conditions[0].lamps_on)


def test_a_window_lets_the_sun_in():
    scene, _ = room_scene()
    panel = RenderMesh("backdrop", 50, np.array([[5.5, 0, 0], [5.5, 3.5, 0], [5.5, 3.5, 2.6], [5.5, 0, 2.6]]),
                       np.array([[0, 1, 2], [0, 2, 3]]), None, None)
    pose = np.eye(4)
    pose[:3, 3] = (5.5, 1.75, 0.0)
    info = InstanceInfo(50, "backdrop", "shell_backdrop", "shell", "none", "shell", pose, np.array([0.05, 3.5, 2.6]))
    windowed = dataclasses.replace(scene, meshes=[*scene.meshes, panel], instances={**scene.instances, 50: info})
    out = window_normal(windowed)
    assert out is not None and out[0] > 0.99  # the room spans x in [0, 4]: the window faces +x
    days = [c for c in (draw_condition(windowed, "genuine", s) for s in range(20)) if c.daytime]
    assert days and all(c.sun_irradiance >= 1.0 for c in days)
    for c in days:
        d = np.asarray(c.sun_direction)
        assert d[2] < -0.5 and d[0] < -0.3  # down and into the room through the +x window
        sun = [light for light in apply_condition(windowed, c).lights if light.name == SUN_NAME]
        assert len(sun) == 1 and np.allclose(-sun[0].world_from_light[:3, 2], d)


def test_lighting_config_keys_keep_the_content_keys():
    assert not any(k.startswith("light_") for k in config_to_dict(RenderConfig()))
    assert config_to_dict(RenderConfig(light_map="varied"))["light_map"] == "varied"
    with pytest.raises(ConfigError, match="light_genuine"):
        from synthleak.config import config_from_dict

        config_from_dict({"name": "x", "render": {"light_genuine": "sometimes"}})


@pytest.fixture(scope="module")
def lit_room(tmp_path_factory):
    room = room_scene()[0]
    out = tmp_path_factory.mktemp("light")
    same = render_scene_sequence(room, out / "same" / "room_000", tiny_config(**SMALL), "scene", progress=False)
    config = tiny_config(**SMALL, light_map="varied", light_genuine="varied")
    varied = render_scene_sequence(room, out / "varied" / "room_000", config, "scene", progress=False)
    return room, same, varied, config


def _mean_rgb(seq_dir, frame: str) -> np.ndarray:
    rgb = load_sequence(seq_dir).rgb(frame).astype(np.float64) / 255.0
    return (rgb**2.2).reshape(-1, 3).mean(axis=0)


def test_map_and_genuine_frames_are_lit_differently(lit_room, tmp_path):
    room, same, varied, config = lit_room
    record = json.loads((varied / LIGHTING_RECORDS).read_text())
    split = json.loads((varied / "split.json").read_text())
    assert record["frames"] == {**{f: "map" for f in split["map"]}, **{f: "genuine" for f in split["query"]}}
    cond = {k: draw_condition(room, k, lighting_seed(config.seed, k, "room_000")) for k in ("map", "genuine")}
    assert record["conditions"]["map"] == json.loads(json.dumps(cond["map"].to_json()))
    assert not (same / LIGHTING_RECORDS).exists()

    # each kind's frames against the same frames under the stage's lights: one condition per kind
    ratio = {f: _mean_rgb(varied, f) / _mean_rgb(same, f) for f in split["map"] + split["query"]}
    rb = {k: [ratio[f][0] / ratio[f][2] for f in (split["map"] if k == "map" else split["query"])]
          for k in ("map", "genuine")}
    warm = max(cond, key=lambda k: 1e6 / cond[k].lamp_temperature_k)  # the warmer lamps: more red over blue
    cool = "map" if warm == "genuine" else "genuine"
    assert 1e6 / cond[warm].lamp_temperature_k - 1e6 / cond[cool].lamp_temperature_k > 20  # seed 5 draws these
    assert min(rb[warm]) > max(rb[cool]) * 1.05
    lum = {k: np.mean([ratio[f] @ [0.2126, 0.7152, 0.0722] for f in (split["map"] if k == "map" else split["query"])])
           for k in ("map", "genuine")}
    assert abs(np.log(lum["map"] / lum["genuine"])) > 0.05

    # ground truth unchanged, and the same bytes again
    hs, hv = tree_hashes(same), tree_hashes(varied)
    assert all(hs[k] == hv[k] for k in hs if k.startswith(("depth/", "instance/", "colmap/", "objects.json")))
    again = render_scene_sequence(room, tmp_path / "room_000", config, "scene", progress=False)
    assert tree_hashes(again) == hv
    write_manifest(tmp_path, config)
    assert json.loads((tmp_path / "manifest.json").read_text())["lighting"] == {
        "map": "varied", "genuine": "varied", "attacker": "same"}
    # resuming under other lighting is refused, naming the file
    with pytest.raises(StageError, match=r"lighting\.json: the sequence was rendered under other lighting"):
        render_scene_sequence(room, again, tiny_config(**SMALL), "scene", progress=False)


def test_pyrender_renders_varied_lighting(tmp_path):
    pytest.importorskip("pyrender")
    from synthleak.render.registry import RendererUnavailable

    room = room_scene()[0]
    config = tiny_config(**{**SMALL, "scene_frames": 2}, renderer="pyrender", light_map="varied",
                         light_genuine="varied")
    try:
        out = render_scene_sequence(room, tmp_path / "room_000", config, "scene", progress=False)
    except RendererUnavailable as exc:
        pytest.skip(str(exc))
    a, b = (_mean_rgb(out, f) for f in ("000000.png", "000001.png"))
    assert json.loads((out / LIGHTING_RECORDS).read_text())["frames"] == {"000000.png": "map",
                                                                         "000001.png": "genuine"}
    assert not np.allclose(a / a.sum(), b / b.sum(), atol=1e-3)


def test_workers_render_each_condition_with_its_own_renderer(lit_room, tmp_path, monkeypatch):
    """Two worker processes, one frame per task, photographed too: the serial bytes (a worker keeps one prepared
    renderer per condition, and a frame never takes another condition's)."""
    from synthleak.executors import LocalExecutor
    from synthleak.render import pipeline

    room, _, varied, config = lit_room
    monkeypatch.setattr(pipeline, "FRAMES_PER_TASK", 1)
    with LocalExecutor(2) as executor:
        parallel = render_scene_sequence(room, tmp_path / "room_000", config, "scene", progress=False,
                                         executor=executor)
    assert tree_hashes(parallel) == tree_hashes(varied)
    photo = replace(config, render=replace(config.render, capture_map="phone-low-light", light_attacker="varied"))
    serial = render_scene_sequence(room, tmp_path / "photo" / "room_000", photo, "scene", progress=False)
    with LocalExecutor(2) as executor:
        both = render_scene_sequence(room, tmp_path / "photo2" / "room_000", photo, "scene", progress=False,
                                     executor=executor)
    assert tree_hashes(both) == tree_hashes(serial)
    records = json.loads((serial / "capture.json").read_text())
    assert all("motion_blur" in r["effects"] for f, r in records.items() if r["profile"] == "phone-low-light")
