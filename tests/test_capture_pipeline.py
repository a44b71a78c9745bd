"""The photographic capture model wired into the render pipeline (``[render] capture_map``, ``capture_genuine``,
``capture_attacker``): ``ideal`` keeps today's bytes and keys, other profiles photograph the frames with seeded
devices and noise, keep the ground truth exact and record what they did in ``capture.json``.

Tiny in-memory scenes of tests/test_render.py at 64x48-96x72 (a few seconds of CPU); the end-to-end
``ci-tiny-photo`` test is marked slow.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from synthleak.cache import cache_key
from synthleak.config import (
    ConfigError,
    RenderConfig,
    StudyConfig,
    config_from_dict,
    config_to_dict,
    load_config,
)
from synthleak.core.dataset import DatasetError, OpenCVCamera, encode_png, frame_name, load_sequence
from synthleak.core.types import Camera, RenderScene
from synthleak.executors import LocalExecutor
from synthleak.portable import snap_pose
from synthleak.render import pipeline
from synthleak.render.dataset import CAPTURE_RECORDS, PENDING_RECORDS
from synthleak.render.distortion import project_camera_points, sample_positions
from synthleak.render.mitsuba_backend import MitsubaRenderer
from synthleak.render.pipeline import plan_poses, render_scene_sequence, write_manifest
from synthleak.seeding import derive_seed
from test_render import attacker_scene, room_scene, tiny_config, tree_hashes
from tiny_stages import write_config

SMALL = dict(width=64, height=48, spp=2, scene_frames=4, attacker_frames=2, query_every=2)
"""4 walk-through frames (queries: 1 and 3) and 2 orbit frames at 64x48."""
PHOTO = dict(width=96, height=72, spp=2, scene_frames=4, query_every=2)
"""The registration checks need a few hundred object pixels."""
ALL_IDEAL = dict(capture_map="ideal", capture_genuine="ideal", capture_attacker="ideal")
GT_FILES = ("depth/", "instance/", "bop/scene_gt", "bop/scene_camera", "bop/mask", "bop/depth/", "colmap/",
            "objects.json", "split.json")


@pytest.fixture(scope="module")
def room() -> tuple[RenderScene, dict]:
    return room_scene()


def render_study(out: Path, config: StudyConfig, room: tuple[RenderScene, dict]) -> Path:
    """A room and an attacker sequence of ``config`` under ``out`` (and the manifest)."""
    render_scene_sequence(room[0], out / "scenes" / "room_000", config, "scene", progress=False)
    render_scene_sequence(attacker_scene(), out / "attackers" / "a00", config, "attacker", progress=False)
    write_manifest(out, config)
    return out


def without_manifest(hashes: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in hashes.items() if k != "manifest.json"}


# ------------------------------------------------------------------------------------------ ideal: unchanged
def test_ideal_keeps_the_bytes_and_the_content_keys(tmp_path, room):
    for folder in ("plain", "explicit"):
        (tmp_path / folder).mkdir()
    plain = load_config(write_config(tmp_path / "plain" / "tiny.toml"))
    explicit = load_config(write_config(tmp_path / "explicit" / "tiny.toml", **ALL_IDEAL))
    assert explicit == plain
    assert config_to_dict(explicit) == config_to_dict(plain)
    assert not any(k.startswith("capture") for k in config_to_dict(plain)["render"])
    assert not any(k.startswith("capture") for k in config_to_dict(RenderConfig()))
    render_key = cache_key("render", plain.seed, config_to_dict(plain)["scenes"], config_to_dict(plain)["render"])
    assert render_key == cache_key("render", explicit.seed, config_to_dict(explicit)["scenes"],
                                   config_to_dict(explicit)["render"])

    a = render_study(tmp_path / "a", plain, room)
    b = render_study(tmp_path / "b", explicit, room)
    assert tree_hashes(a) == tree_hashes(b)  # the manifest included
    assert not list(a.rglob(CAPTURE_RECORDS)) and not list(a.rglob(PENDING_RECORDS))
    assert "capture" not in json.loads((a / "manifest.json").read_text())

    # the images are the backend's own 8-bit encoding, untouched
    rc = plain.render
    camera = Camera.from_hfov(rc.width, rc.height, rc.hfov_deg)
    renderer = MitsubaRenderer(spp=rc.spp)
    renderer.prepare(room[0])
    for i, pose in enumerate(plan_poses(room[0], plain, "scene", "room_000")):
        frame = renderer.render(camera, snap_pose(pose), derive_seed(plain.seed, "render", "room_000", i))
        assert (a / "scenes" / "room_000" / "images" / frame_name(i)).read_bytes() == encode_png(frame.rgb)


# ------------------------------------------------------------------------------------------- phone / web-photo
@pytest.fixture(scope="module")
def photo_pair(tmp_path_factory, room) -> tuple[Path, Path]:
    """The same room rendered ideal and photographed with ``phone`` (map and genuine)."""
    out = tmp_path_factory.mktemp("capture")
    ideal, phone = out / "ideal" / "room_000", out / "phone" / "room_000"
    render_scene_sequence(room[0], ideal, tiny_config(**PHOTO), "scene", progress=False)
    config = tiny_config(**PHOTO, capture_map="phone", capture_genuine="phone")
    render_scene_sequence(room[0], phone, config, "scene", progress=False)
    return ideal, phone


def lens_projection_agreement(seq_dir: Path, canon: dict[int, trimesh.Trimesh], lens: bool = True
                              ) -> tuple[int, int]:
    """:func:`test_render.bop_projection_agreement` through each frame's own camera (its lens distortion, by
    :func:`synthleak.render.distortion.project_camera_points`; ``lens=False``: its pinhole part only)."""
    seq = load_sequence(seq_dir)
    gt = json.loads((seq_dir / "bop" / "scene_gt.json").read_text())
    visible_total, agree_total = 0, 0
    for name in seq.frames:
        own = seq.camera_of(name)
        cam = own if lens else Camera(own.width, own.height, own.fx, own.fy, own.cx, own.cy)
        depth, inst = seq.depth(name), seq.instance(name)
        for entry in gt[str(int(name.removesuffix(".png")))]:
            iid = entry["obj_id"]
            if iid not in canon:
                continue
            pts, _ = trimesh.sample.sample_surface(canon[iid], 600, seed=iid)
            cam_pts = pts @ np.array(entry["cam_R_m2c"]).reshape(3, 3).T + np.array(entry["cam_t_m2c"]) / 1000.0
            cam_pts = cam_pts[cam_pts[:, 2] > 0.05]
            projected = project_camera_points(cam, cam_pts)
            assert projected is not None, name
            uv = np.floor(np.stack(projected, axis=1)).astype(int)
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
            uv, z = uv[inside], cam_pts[inside, 2]
            visible = np.abs(depth[uv[:, 1], uv[:, 0]] - z) < 0.02  # the surface point is what the pixel sees
            visible_total += int(visible.sum())
            agree_total += int((inst[uv[visible, 1], uv[visible, 0]] == iid).sum())
    return visible_total, agree_total


def test_phone_photos_differ_and_keep_the_ground_truth_exact(photo_pair, room):
    ideal, phone = photo_pair
    hi, hp = tree_hashes(ideal), tree_hashes(phone)
    # the same poses, objects and split; the depth and masks are the lens's own (ray cast through it)
    same = [k for k in hi if k in ("bop/scene_gt.json", "objects.json", "split.json")]
    assert len(same) == 3 and all(hp[k] == hi[k] for k in same)
    images = [k for k in hi if k.startswith("images/")]
    assert images and all(hp[k] != hi[k] for k in images)
    a, b = load_sequence(ideal), load_sequence(phone)
    assert a.frames == b.frames and all(np.array_equal(a.pose(f), b.pose(f)) for f in a.frames)
    for frame in b.frames:
        cam = b.camera_of(frame)  # each photo on its phone's lens, the render's size and principal point
        assert isinstance(cam, OpenCVCamera) and cam.k1 != 0.0 and (cam.width, cam.height) == (96, 72)
        assert (cam.cx, cam.cy) == (a.camera.cx, a.camera.cy)
        assert not np.array_equal(a.depth(frame), b.depth(frame))

    # the photo shows the scene where the ideal render seen through the frame's lens does: no shift between the
    # two, and the warped render is closer to the photo than the render itself
    corr = []
    for frame in a.frames:
        map_x, map_y = sample_positions(b.camera_of(frame), a.camera)
        grey_a = cv2.cvtColor(a.rgb(frame), cv2.COLOR_RGB2GRAY).astype(np.float32)
        warped = cv2.remap(grey_a, map_x, map_y, cv2.INTER_LINEAR).astype(np.float64)
        photo = cv2.cvtColor(b.rgb(frame), cv2.COLOR_RGB2GRAY).astype(np.float64)
        (dx, dy), _ = cv2.phaseCorrelate(*[(g - g.mean()) / (g.std() + 1e-9) for g in (warped, photo)])
        assert abs(dx) < 0.3 and abs(dy) < 0.3, (frame, dx, dy)
        inner = (slice(4, -4), slice(4, -4))
        corr.append([np.corrcoef(g[inner].ravel(), photo[inner].ravel())[0, 1] for g in (warped, grey_a)])
    assert np.mean(corr, axis=0)[0] > np.mean(corr, axis=0)[1], corr
    # and the ground truth of the photographed sequence is registered: object points land where the depth says,
    # projected through each frame's own lens
    visible, agree = lens_projection_agreement(phone, room[1])
    assert visible > 100 and agree / visible > 0.95
    pin_visible, _ = lens_projection_agreement(phone, room[1], lens=False)
    assert pin_visible < visible  # the lens matters: its pinhole part alone sees fewer points where they are


def test_phone_photos_are_seeded_and_recorded(photo_pair, room, tmp_path):
    _, phone = photo_pair
    config = tiny_config(**PHOTO, capture_map="phone", capture_genuine="phone")
    again = tmp_path / "room_000"
    render_scene_sequence(room[0], again, config, "scene", progress=False)
    assert tree_hashes(again) == tree_hashes(phone)  # same seed, same bytes

    seq = load_sequence(phone)
    records = json.loads((phone / CAPTURE_RECORDS).read_text())
    assert sorted(records) == seq.frames and not (phone / PENDING_RECORDS).exists()
    for i, frame in enumerate(seq.frames):
        record = records[frame]
        assert record["profile"] == "phone"
        assert {"defocus", "exposure", "noise", "demosaic", "white_balance", "jpeg"} <= set(record["effects"])
        assert record["device_seed"] == derive_seed(config.seed, "capture-device", "room_000", i)
        assert record["seed"] == derive_seed(config.seed, "capture-noise", "room_000", i)
        assert record["output_size"] == [96, 72]
    write_manifest(phone.parent, config)
    manifest = json.loads((phone.parent / "manifest.json").read_text())
    assert manifest["capture"] == {"map": "phone", "genuine": "phone", "attacker": "ideal"}
    assert manifest["config"]["render"]["capture_map"] == "phone"

    # resume: a lost frame is photographed again with the same bytes and record; another profile is refused
    (again / "images" / "000001.png").unlink()
    render_scene_sequence(room[0], again, config, "scene", progress=False)
    assert tree_hashes(again) == tree_hashes(phone)
    with pytest.raises(DatasetError, match=r"capture\.json: frame 000000\.png .* profile 'phone'.*'ideal'"):
        render_scene_sequence(room[0], again, tiny_config(**PHOTO), "scene", progress=False)


def test_map_genuine_and_attacker_frames_get_their_own_profiles(tmp_path, room, monkeypatch):
    monkeypatch.setattr(pipeline, "FRAMES_PER_TASK", 1)  # tasks of genuine (ideal) frames only record them too
    ideal = render_study(tmp_path / "ideal", tiny_config(**SMALL), room)
    mixed = render_study(tmp_path / "mixed", tiny_config(**SMALL, capture_map="phone",
                                                         capture_attacker="web-photo"), room)
    split = json.loads((mixed / "scenes" / "room_000" / "split.json").read_text())
    assert split["query"] == ["000001.png", "000003.png"]
    records = json.loads((mixed / "scenes" / "room_000" / CAPTURE_RECORDS).read_text())
    for frame in split["map"] + split["query"]:
        genuine = frame in split["query"]
        assert records[frame]["profile"] == ("ideal" if genuine else "phone")
        same = (ideal / "scenes" / "room_000" / "images" / frame).read_bytes() == \
            (mixed / "scenes" / "room_000" / "images" / frame).read_bytes()
        assert same == genuine  # genuine queries stay ideal here, map frames are photographed
    attacker = json.loads((mixed / "attackers" / "a00" / CAPTURE_RECORDS).read_text())
    assert sorted(attacker) == ["000000.png", "000001.png"]
    seq = load_sequence(mixed / "attackers" / "a00")
    for frame, record in attacker.items():
        assert record["profile"] == "web-photo" and "resize_skipped" not in record
        assert {"distortion", "resize", "recompress"} <= set(record["effects"])
        assert record["resize_scale"] == [1.0, 1.0]  # services never enlarge: a 64x48 photo keeps its size
        assert record["output_size"] == [64, 48]
        cam = seq.camera_of(frame)  # each photo on its own lens, drawn per photo
        assert isinstance(cam, OpenCVCamera) and (cam.width, cam.height) == (64, 48) and cam.k1 != 0.0
        assert record["camera"]["model"] == "OPENCV" and record["camera"]["params"][4] == cam.k1
    assert seq.camera_of("000000.png") != seq.camera_of("000001.png")
    assert without_manifest(tree_hashes(ideal / "attackers")) != without_manifest(tree_hashes(mixed / "attackers"))


def test_pyrender_frames_are_linearised_with_gamma_2_2(tmp_path, room):
    pytest.importorskip("pyrender")
    from synthleak.render.registry import RendererUnavailable

    config = tiny_config(**{**SMALL, "scene_frames": 2}, renderer="pyrender", capture_map="phone")
    try:
        out = render_scene_sequence(room[0], tmp_path / "room_000", config, "scene", progress=False)
    except RendererUnavailable as exc:
        pytest.skip(str(exc))
    records = json.loads((out / CAPTURE_RECORDS).read_text())
    assert records["000000.png"]["profile"] == "phone" and records["000001.png"]["profile"] == "ideal"


# ------------------------------------------------------------------------------------------------ config
@pytest.mark.parametrize("key", ["capture_map", "capture_genuine", "capture_attacker"])
def test_an_unknown_profile_is_a_config_error_naming_the_key(tmp_path, key):
    path = write_config(tmp_path / "bad.toml", **{key: "dslr"})
    with pytest.raises(ConfigError, match=rf"render\.{key}: unknown name 'dslr' \(known: ideal, phone,") as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}: ")


def test_the_photo_preset():
    config = load_config("ci-tiny-photo")
    tiny = load_config("ci-tiny")
    assert (config.render.capture_map, config.render.capture_genuine, config.render.capture_attacker) == (
        "phone", "phone", "web-photo")
    assert config.description
    assert config_from_dict(config_to_dict(config), str(config.name)) == config
    others = {k: v for k, v in config_to_dict(config.render).items() if not k.startswith("capture")}
    assert others == config_to_dict(tiny.render)  # same cameras, frames and names: only the RGB differs


def test_pending_records_are_merged_after_an_interruption(tmp_path, room):
    """A run stopped after some frames (records pending, no capture.json) finishes with the same bytes."""
    config = tiny_config(**SMALL, capture_map="phone")
    full = render_scene_sequence(room[0], tmp_path / "full" / "room_000", config, "scene", progress=False)
    cut = tmp_path / "cut" / "room_000"
    render_scene_sequence(room[0], cut, config, "scene", progress=False)
    records = json.loads((cut / CAPTURE_RECORDS).read_text())
    (cut / CAPTURE_RECORDS).unlink()
    (cut / PENDING_RECORDS).mkdir()
    for frame in ("000000.png", "000001.png"):  # written before their frames' RGB, not merged yet
        (cut / PENDING_RECORDS / frame.replace(".png", ".json")).write_text(json.dumps(records[frame]))
    for frame in ("000002.png", "000003.png"):
        (cut / "images" / frame).unlink()
    shutil.rmtree(cut / "bop" / "rgb")
    render_scene_sequence(room[0], cut, config, "scene", progress=False)
    assert tree_hashes(cut) == tree_hashes(full)


def test_workers_give_the_same_photos(tmp_path, room, monkeypatch):
    """Frames photographed in two worker processes, one frame per task: the same bytes as in one process."""
    monkeypatch.setattr(pipeline, "FRAMES_PER_TASK", 1)
    config = tiny_config(**SMALL, capture_map="phone", capture_genuine="phone-low-light")
    serial = render_scene_sequence(room[0], tmp_path / "serial" / "room_000", config, "scene", progress=False)
    with LocalExecutor(2) as executor:
        parallel = render_scene_sequence(room[0], tmp_path / "parallel" / "room_000", config, "scene",
                                         progress=False, executor=executor)
    assert tree_hashes(parallel) == tree_hashes(serial)
    profiles = {f: r["profile"] for f, r in json.loads((serial / CAPTURE_RECORDS).read_text()).items()}
    assert profiles == {"000000.png": "phone", "000001.png": "phone-low-light", "000002.png": "phone",
                        "000003.png": "phone-low-light"}


# ------------------------------------------------------------------------------------------------ end to end
@pytest.mark.slow
def test_ci_tiny_photo_generates_and_its_genuine_queries_localize(tmp_path):
    import subprocess
    import sys

    from synthleak.localize.localizer import Localizer
    from synthleak.localize.mapping import build_map

    out = tmp_path / "photo"
    subprocess.run([sys.executable, "-m", "synthleak.cli", "generate", "ci-tiny-photo", "--out", str(out),
                    "--quiet"], check=True, timeout=1800)
    config = load_config("ci-tiny-photo")
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["capture"] == {"map": "phone", "genuine": "phone", "attacker": "web-photo"}
    rooms = sorted((out / "scenes").iterdir())
    attackers = sorted((out / "attackers").iterdir())
    assert len(rooms) == config.scenes.rooms and attackers
    for seq_dir in rooms + attackers:
        seq = load_sequence(seq_dir)
        records = json.loads((seq_dir / CAPTURE_RECORDS).read_text())
        assert sorted(records) == seq.frames == [frame_name(i) for i in range(len(seq.frames))]
        expected = {"web-photo"} if seq_dir.parent.name == "attackers" else {"phone"}
        assert {r["profile"] for r in records.values()} == expected

    room = rooms[0]
    map_dir = build_map(room, "sift", tmp_path / "map", config.localize, progress=False)
    localizer = Localizer.load(map_dir, config.localize)
    seq = load_sequence(room)
    localized = sum(localizer.localize(seq.rgb(frame)).success for frame in seq.query_frames)
    print(f"ci-tiny-photo {room.name}: {localized} of {len(seq.query_frames)} genuine queries localized")
    assert localized >= 0.8 * len(seq.query_frames)
