"""`synthleak show`: contact sheets of sequences and plan views of stages (synthleak.inspect)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from synthleak.assets.mesh import ObjectMesh, TexturedPart
from synthleak.core.dataset import DatasetError
from synthleak.core.types import Light
from synthleak.inspect import contact_sheet, id_colour, plan_view, projected_boxes
from synthleak.inspect.contact_sheet import BAR_W, find_sequence
from synthleak.scene.spec import PlacedObject, SceneSpec
from test_bop_full import BACK, FRONT, H, W, write_box_sequence


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds")
    seq_dir, scene = write_box_sequence(root / "scenes" / "room_000", n=3)
    return root, seq_dir, scene


def test_contact_sheet_size_and_boxes_on_objects(dataset, tmp_path) -> None:
    root, seq_dir, _ = dataset
    out = contact_sheet(root, tmp_path / "sheet.png", frames=2)
    sheet = cv2.imread(str(out), cv2.IMREAD_COLOR)[..., ::-1]
    assert sheet.shape == (2 * H, 4 * W + BAR_W, 3)
    again = contact_sheet(seq_dir, tmp_path / "again.png", sequence=None, frames=2)
    assert again.read_bytes() == out.read_bytes()  # deterministic; dataset and sequence paths agree
    inst = cv2.imread(str(seq_dir / "instance" / "000000.png"), cv2.IMREAD_UNCHANGED)
    boxes = projected_boxes(seq_dir, "000000.png")
    assert set(boxes) == {FRONT, BACK}  # the floor (shell) gets no box
    # the front box is unoccluded and box-shaped: its projected 3D box is its silhouette's box (pixel centres)
    ys, xs = np.nonzero(inst == FRONT)
    lo, hi = boxes[FRONT].min(axis=0) - 0.5, boxes[FRONT].max(axis=0) - 0.5
    assert np.all(np.abs(lo - [xs.min(), ys.min()]) <= 2.0) and np.all(np.abs(hi - [xs.max(), ys.max()]) <= 2.0)
    for obj in (FRONT, BACK):  # every box lies within its object's mask box (occluded parts included: 2 px)
        ys, xs = np.nonzero(inst == obj)
        assert boxes[obj][:, 0].min() - 0.5 >= xs.min() - 2 and boxes[obj][:, 0].max() - 0.5 <= xs.max() + 2
        assert boxes[obj][:, 1].max() - 0.5 <= ys.max() + 2
    # the overlay panel shows the front box's colour on its drawn edges, inside the mask's box (+2 px)
    panel = sheet[:H, 3 * W + BAR_W :]
    drawn = np.all(panel == id_colour(FRONT), axis=-1)
    ys, xs = np.nonzero(inst == FRONT)
    dy, dx = np.nonzero(drawn)
    assert len(dx) > 10
    inside = (dx >= xs.min() - 2) & (dx <= xs.max() + 2) & (dy >= ys.min() - 12) & (dy <= ys.max() + 2)
    assert inside.mean() > 0.8  # the rest is its id label above the box
    # the instance panel uses the fixed palette
    assert tuple(sheet[ys[0], 2 * W + BAR_W + xs[0]]) == id_colour(FRONT)


def test_contact_sheet_errors(dataset, tmp_path) -> None:
    root, _, _ = dataset
    with pytest.raises(DatasetError, match="no sequence 'nope'.*room_000"):
        contact_sheet(root, tmp_path / "x.png", sequence="nope")
    assert find_sequence(root, "room_000").name == "room_000"
    study = tmp_path / "study"  # a study folder holds its dataset in dataset/
    study.mkdir()
    (study / "dataset").symlink_to(root, target_is_directory=True)
    assert find_sequence(study, "room_000") == study / "dataset" / "scenes" / "room_000"
    with pytest.raises(ValueError, match="frames must be >= 1"):
        contact_sheet(root, tmp_path / "x.png", frames=0)


def _box_part(name: str, extents, colour) -> TexturedPart:
    import trimesh

    box = trimesh.creation.box(extents)
    box.apply_translation((0, 0, extents[2] / 2))
    v = np.asarray(box.vertices)
    tex = np.full((4, 4, 3), np.asarray(colour) * 255, dtype=np.uint8)
    return TexturedPart(name, v, np.asarray(box.faces), (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], 0), tex)


def _pose(x: float, y: float, yaw_deg: float = 0.0) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return np.array([[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def test_plan_view_with_camera_path(tmp_path) -> None:
    from synthleak.core.usd_read import read_render_scene
    from synthleak.scene.usd_write import write_stage

    objects = [
        PlacedObject(
            1,
            "floor",
            "floor",
            "floor",
            "none",
            _pose(0, 0),
            ObjectMesh([_box_part("f", (4, 4, 0.02), (0.6,) * 3)]),
            role="shell",
        ),
        PlacedObject(
            2,
            "wall",
            "wall",
            "wall",
            "none",
            _pose(0, 2),
            ObjectMesh([_box_part("w", (4, 0.1, 2.5), (0.8,) * 3)]),
            role="shell",
        ),
        PlacedObject(
            101,
            "front",
            "box_a",
            "box",
            "none",
            _pose(0, 0, 30),
            ObjectMesh([_box_part("a", (0.4, 0.3, 0.5), (0.8, 0.2, 0.2))]),
        ),
        PlacedObject(
            102,
            "back",
            "box_b",
            "box",
            "4",
            _pose(0.15, 1.2),
            ObjectMesh([_box_part("b", (0.6, 0.4, 0.7), (0.2, 0.3, 0.8))]),
        ),
    ]
    spec = SceneSpec("plan", "room", objects, [Light("sun", "distant", np.eye(4), 2.0)], room_size=(4, 4, 2.5))
    stage = tmp_path / "stages" / "room_000.usda"
    stage.parent.mkdir()
    write_stage(spec, stage)
    seq_dir, _ = write_box_sequence(tmp_path / "scenes" / "room_000", read_render_scene(stage), n=3)
    out = plan_view(stage, tmp_path / "plan.png", seq_dir)
    image = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert image.shape == (700, 700, 3)
    assert plan_view(stage, tmp_path / "plan2.png", seq_dir).read_bytes() == out.read_bytes()
    assert plan_view(stage, tmp_path / "plan3.png").read_bytes() != out.read_bytes()
    # the object colour (edge) of 101 appears in the plan
    rgb = image[..., ::-1].reshape(-1, 3)
    assert np.any(np.all(np.abs(rgb.astype(int) - id_colour(101)) <= 3, axis=1))
