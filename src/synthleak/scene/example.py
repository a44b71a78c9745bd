"""A small, self-contained example stage (``scenes_usd/example/room_example.usda``): a room shell with low
resolution textures, a box table with a box on it, two ceiling lights. It documents the stage layout and is
regenerated with ``python -m synthleak.scene.example [OUT.usda]``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from synthleak.assets.mesh import ObjectMesh
from synthleak.assets.textures import make_texture
from synthleak.geometry.poses import make_pose
from synthleak.paths import scenes_usd_dir
from synthleak.scene.room import build_room_shell, ceiling_lights, yaw_matrix
from synthleak.scene.shell_geometry import merge_parts, planar_box
from synthleak.scene.spec import PlacedObject, SceneSpec
from synthleak.scene.styles import room_styles
from synthleak.scene.usd_write import write_stage
from synthleak.seeding import make_rng

EXAMPLE_SEED = 2023


def _box(name: str, lo, hi, tex: np.ndarray):
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return planar_box(name, lo, hi, tex, lo, hi, roughness=0.6)


def example_spec() -> SceneSpec:
    """The example room (deterministic)."""
    size = (4.0, 3.5, 2.5)
    style = room_styles()[0]
    shell = build_room_shell(size, style, make_rng(EXAMPLE_SEED, "example", "shell"), texture_size=128)
    rng = make_rng(EXAMPLE_SEED, "example", "objects")
    wood = make_texture("wood", rng, (0.5, 0.33, 0.2), 64)
    legs = [
        _box("leg", (sx * 0.5 - 0.03, sy * 0.3 - 0.03, 0.0), (sx * 0.5 + 0.03, sy * 0.3 + 0.03, 0.72), wood)
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    top = _box("top", (-0.55, -0.35, 0.72), (0.55, 0.35, 0.75), wood)
    table = ObjectMesh([merge_parts("table", [*legs, top])])
    box_tex = make_texture("pattern", rng, (0.2, 0.4, 0.7), 64)
    box = ObjectMesh([_box("box", (-0.1, -0.08, 0.0), (0.1, 0.08, 0.15), box_tex)])
    table_pose = make_pose(yaw_matrix(0.3), [0.4, 0.2, 0.0])
    box_pose = table_pose @ make_pose(yaw_matrix(-0.2), [0.1, 0.05, 0.75])
    objects = [
        *shell.pieces,
        PlacedObject(
            100,
            "table_100",
            "example_table",
            "table",
            "2",
            table_pose,
            table,
            {"example": True},
            support="floor",
            extents=table.extents(),
        ),
        PlacedObject(
            101,
            "box_101",
            "example_box",
            "box",
            "2",
            box_pose,
            box,
            {"example": True},
            support="surface",
            extents=box.extents(),
        ),
    ]
    lights = ceiling_lights(size, 2, style, make_rng(EXAMPLE_SEED, "example", "lights"))
    return SceneSpec(
        "room_example",
        "room",
        objects,
        lights,
        size,
        EXAMPLE_SEED,
        None,
        0.0625,
        {"style": style.name, "supported_by": {"101": 100}},
    )


def main(argv: list[str]) -> None:
    out = Path(argv[0]) if argv else scenes_usd_dir() / "example" / "room_example.usda"
    write_stage(example_spec(), out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1:])
