"""The dataset contract (synthleak.core.dataset): encodings, the sequence reader, the stage index reader."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from synthleak.core.dataset import (
    DatasetError,
    encode_npy,
    encode_png,
    frame_complete,
    frame_name,
    load_sequence,
    read_depth,
    read_index,
    read_instance,
    read_rgb,
)
from synthleak.core.types import Camera, InstanceInfo
from synthleak.geometry.poses import look_at
from synthleak.render.base import Frame
from synthleak.render.dataset import write_frame, write_sequence_metadata

RNG = np.random.default_rng(3)
RGB = RNG.integers(0, 256, (12, 16, 3), dtype=np.uint8)
IDS = RNG.choice(np.array([0, 1, 7, 300, 1000, 65535], dtype=np.uint16), (12, 16))


def _pil(data: bytes) -> Image.Image:
    return Image.open(io.BytesIO(data))


def test_png_encodings_read_back_exactly_and_as_pillow_reads_them(tmp_path: Path) -> None:
    rgb_png, ids_png = tmp_path / "rgb.png", tmp_path / "ids.png"
    rgb_png.write_bytes(encode_png(RGB))
    ids_png.write_bytes(encode_png(IDS))
    assert encode_png(RGB) == rgb_png.read_bytes()  # deterministic bytes
    assert np.array_equal(read_rgb(rgb_png), RGB)  # RGB order kept (OpenCV stores BGR)
    assert np.array_equal(np.asarray(_pil(rgb_png.read_bytes()).convert("RGB")), RGB)
    ids = read_instance(ids_png)
    assert ids.dtype == np.uint16 and np.array_equal(ids, IDS)  # 16-bit ids above 255 survive
    assert np.array_equal(np.asarray(_pil(ids_png.read_bytes())).astype(np.int64), IDS.astype(np.int64))
    rgba = np.dstack([RGB, RNG.integers(0, 256, (12, 16), dtype=np.uint8)])
    assert np.array_equal(np.asarray(_pil(encode_png(rgba)).convert("RGBA")), rgba)
    (tmp_path / "rgba.png").write_bytes(encode_png(rgba))
    assert np.array_equal(read_rgb(tmp_path / "rgba.png"), RGB)  # alpha dropped, colours kept


def test_decoders_name_the_file(tmp_path: Path) -> None:
    eight_bit = tmp_path / "ids8.png"
    eight_bit.write_bytes(encode_png(IDS.astype(np.uint8)))
    with pytest.raises(DatasetError, match=r"ids8\.png.*not 16-bit"):
        read_instance(eight_bit)
    with pytest.raises(DatasetError, match=r"nope\.png.*missing or unreadable"):
        read_rgb(tmp_path / "nope.png")
    depth = tmp_path / "d.npy"
    depth.write_bytes(encode_npy(np.zeros((12, 16), np.float64)))
    with pytest.raises(DatasetError, match=r"d\.npy.*float32 \(12, 16\).*float64"):
        read_depth(depth, (12, 16))


def _sequence(root: Path, split: dict | None, frame: str = "world") -> Path:
    camera = Camera.from_hfov(16, 12, 60.0)
    frames = [frame_name(i) for i in range(3)]
    poses = [look_at((0.3 * i, -3.0, 1.0), (0.0, 0.0, 0.5)) for i in range(3)]
    target = InstanceInfo(1, "box", "box", "box", "none", "object", np.eye(4), np.array([1.0, 1.0, 1.0]))
    write_sequence_metadata(root, camera=camera, frames=frames, poses=poses, instances=[target], frame=frame,
                            target_instance_id=1 if frame == "object" else None, split=split)
    for name in frames:
        write_frame(root, name, Frame(RGB, np.full((12, 16), 2.0, np.float32), IDS))
    return root


def test_sequence_reader(tmp_path: Path) -> None:
    seq = load_sequence(_sequence(tmp_path / "room", {"map": ["000000.png", "000001.png"], "query": ["000002.png"]}))
    assert seq.map_frames == ["000000.png", "000001.png"] and seq.query_frames == ["000002.png"]
    assert seq.instance_path("000002.png") == tmp_path / "room" / "instance" / "000002.png"
    assert np.array_equal(seq.rgb(2), RGB) and np.array_equal(seq.instance("000001"), IDS)
    assert seq.depth(0).dtype == np.float32 and all(frame_complete(seq.root, f) for f in seq.frames)
    assert seq.pose(1) is seq.cam_from_world["000001.png"]
    no_split = load_sequence(_sequence(tmp_path / "orbit", None, frame="object"))
    assert no_split.map_frames == no_split.frames and no_split.query_frames == []  # every frame maps
    assert set(no_split.cam_from_object) == set(no_split.frames)
    with pytest.raises(DatasetError, match=r"no such sequence folder"):
        load_sequence(tmp_path / "nowhere")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (None, r"index\.json: stage index does not exist"),
        ("{", r"index\.json: not valid JSON"),
        ("[]", r"index\.json: expected a JSON object"),
        ('{"rooms": []}', r"index\.json: field 'attacker_objects' must be a list"),
        ('{"rooms": [{"name": "r"}], "attacker_objects": []}', r"index\.json: rooms\[0\]\.stage must be a string"),
        ('{"rooms": [], "attacker_objects": [{"id": 3, "stage": "a.usda"}]}',
         r"index\.json: attacker_objects\[0\]\.id must be a string"),
    ],
)
def test_stage_index_errors_name_the_file_and_the_field(tmp_path: Path, text: str | None, message: str) -> None:
    if text is not None:
        (tmp_path / "index.json").write_text(text)
    with pytest.raises(DatasetError, match=message):
        read_index(tmp_path)


def test_stage_index_reads_back(tmp_path: Path) -> None:
    index = {"seed": 1, "rooms": [{"name": "room_000", "stage": "room_000.usda"}],
             "attacker_objects": [{"id": "a", "stage": "attacker_a.usda"}]}
    (tmp_path / "index.json").write_text(json.dumps(index))
    assert read_index(tmp_path) == index
