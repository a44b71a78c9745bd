"""Room shell: textured floor, four walls (one with a door, usually one with a window), ceiling, door leaf
and an outdoor backdrop behind the window. Each piece is its own :class:`PlacedObject` (role ``shell``,
ids 1..99).

Room frame: the interior is ``x in [-X/2, X/2]``, ``y in [-Y/2, Y/2]``, ``z in [0, H]``; walls are outside it.
A wall's object frame has x along the wall, its front (+y) facing into the room, z up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from shapely.geometry import Polygon, box

from synthleak.assets.mesh import ObjectMesh
from synthleak.assets.textures import make_texture
from synthleak.core.types import Light
from synthleak.geometry.poses import make_pose
from synthleak.scene.shell_geometry import box_with_holes, planar_box
from synthleak.scene.spec import PlacedObject
from synthleak.scene.styles import ShellStyle

WALL_THICKNESS = 0.12
SLAB_THICKNESS = 0.1
WALL_NAMES = ("wall_south", "wall_north", "wall_west", "wall_east")
SHELL_IDS = {
    "floor": 1,
    "ceiling": 2,
    "wall_south": 3,
    "wall_north": 4,
    "wall_west": 5,
    "wall_east": 6,
    "door": 7,
    "backdrop": 8,
}


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation about +z by ``yaw`` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Opening:
    """A hole in a wall, in the wall's frame: ``x0..x1`` along the wall, ``z0..z1`` above the floor."""

    wall: str
    kind: str  # door | window
    x0: float
    x1: float
    z0: float
    z1: float


@dataclass(frozen=True)
class Wall:
    """One wall: ``world_from_wall`` (x along the wall, +y into the room, origin on the inner face at floor
    level) and its interior ``length``."""

    name: str
    world_from_wall: np.ndarray
    length: float


@dataclass
class RoomShell:
    """The shell pieces and what placement needs to know about the room."""

    size: tuple[float, float, float]
    pieces: list[PlacedObject]
    walls: dict[str, Wall]
    openings: list[Opening]
    keepout: list[Polygon] = field(default_factory=list)
    """Floor regions that must stay free (in front of the door)."""

    def interior(self, margin: float = 0.0) -> Polygon:
        x, y, _ = self.size
        return box(-x / 2 + margin, -y / 2 + margin, x / 2 - margin, y / 2 - margin)


def room_walls(size: tuple[float, float, float]) -> dict[str, Wall]:
    """Inner-face frames of the four walls (south y-, north y+, west x-, east x+)."""
    x, y, _ = size
    specs = {
        "wall_south": (0.0, (0.0, -y / 2), x),
        "wall_north": (np.pi, (0.0, y / 2), x),
        "wall_west": (-np.pi / 2, (-x / 2, 0.0), y),
        "wall_east": (np.pi / 2, (x / 2, 0.0), y),
    }
    return {
        name: Wall(name, make_pose(yaw_matrix(yaw), [cx, cy, 0.0]), length)
        for name, (yaw, (cx, cy), length) in specs.items()
    }


def shell_texture(
    style: ShellStyle, surface: str, rng: np.random.Generator, size: int, span: float
) -> np.ndarray:
    kind, colour = style.finishes[surface].draw(rng)
    return surface_texture(kind, colour, rng, size, span)


def surface_texture(kind: str, colour: tuple[float, float, float], rng: np.random.Generator, size: int,
                    span: float) -> np.ndarray:
    """:func:`make_texture` of a surface ``span`` metres across, its structures roughly as large in metres as on
    a ~1 m object, however large the surface."""
    feature_scale = float(np.clip(1.5 / max(span, 0.5), 0.3, 1.0))
    return make_texture(kind, rng, colour, size, feature_scale=feature_scale)


def _shell_piece(
    name: str, parts: list, world_from_object: np.ndarray, support: str, extents
) -> PlacedObject:
    return PlacedObject(
        instance_id=SHELL_IDS[name],
        name=name,
        model_id=f"shell_{name.split('_')[0]}",
        category="shell",
        symmetry="none",
        world_from_object=world_from_object,
        mesh=ObjectMesh(parts),
        role="shell",
        support=support,
        extents=np.asarray(extents, dtype=np.float64),
    )


def _draw_openings(walls: dict[str, Wall], height: float, rng: np.random.Generator) -> list[Opening]:
    names = list(walls)
    door_wall = names[int(rng.integers(4))]
    length = walls[door_wall].length
    width = float(rng.uniform(0.8, 0.95))
    half = length / 2 - 0.3 - width / 2
    xc = float(rng.uniform(-half, half))
    openings = [Opening(door_wall, "door", xc - width / 2, xc + width / 2, 0.0, min(2.05, height - 0.3))]
    if rng.random() < 0.85:
        others = [n for n in names if n != door_wall]
        win_wall = others[int(rng.integers(len(others)))]
        length = walls[win_wall].length
        width = float(rng.uniform(0.8, min(1.6, length - 1.2)))
        half = length / 2 - 0.4 - width / 2
        xc = float(rng.uniform(-half, half))
        sill = float(rng.uniform(0.8, 1.0))
        top = min(sill + float(rng.uniform(1.0, 1.3)), height - 0.25)
        openings.append(Opening(win_wall, "window", xc - width / 2, xc + width / 2, sill, top))
    return openings


def build_room_shell(
    size: tuple[float, float, float],
    style: ShellStyle,
    rng: np.random.Generator,
    *,
    openings: bool = True,
    texture_size: int = 1024,
) -> RoomShell:
    """Floor, ceiling, four walls (with a door and usually a window), door leaf and window backdrop."""
    x, y, h = (float(v) for v in size)
    t, s = WALL_THICKNESS, SLAB_THICKNESS
    walls = room_walls((x, y, h))
    holes = _draw_openings(walls, h, rng) if openings else []
    pieces: list[PlacedObject] = []

    # floor (top at z = 0) and ceiling (bottom at z = h), both covering the walls' footprint
    for name, z in (("floor", -s), ("ceiling", h)):
        ext = np.array([x + 2 * t, y + 2 * t, s])
        lo, hi = np.array([-ext[0] / 2, -ext[1] / 2, 0.0]), np.array([ext[0] / 2, ext[1] / 2, s])
        tex = shell_texture(
            style, name, rng, texture_size if name == "floor" else texture_size // 2, max(x, y)
        )
        part = planar_box(name, lo, hi, tex, lo, hi, roughness=0.7 if name == "floor" else 0.9)
        pieces.append(_shell_piece(name, [part], make_pose(np.eye(3), [0, 0, z]), "none", ext))

    wall_tex = shell_texture(style, "wall", rng, texture_size, max(x, y))
    for name, wall in walls.items():
        extra = t if name in ("wall_south", "wall_north") else 0.0  # south/north walls close the corners
        wall_holes = [(o.x0, o.x1, o.z0, o.z1) for o in holes if o.wall == name]
        part = box_with_holes(name, wall.length, t, h, wall_holes, wall_tex, x_extra=extra, roughness=0.9)
        world_from_object = wall.world_from_wall @ make_pose(np.eye(3), [0.0, -t / 2, 0.0])
        pieces.append(_shell_piece(name, [part], world_from_object, "floor", (wall.length + 2 * extra, t, h)))

    for opening in holes:
        wall = walls[opening.wall]
        width, height = opening.x1 - opening.x0, opening.z1 - opening.z0
        xc = 0.5 * (opening.x0 + opening.x1)
        if opening.kind == "door":  # a closed door leaf, set 2 cm back from the inner face
            ext = np.array([width - 0.01, 0.04, height - 0.005])
            tex = shell_texture(style, "door", rng, min(512, texture_size), 2.0)
            lo, hi = np.array([-ext[0] / 2, -ext[1] / 2, 0.0]), np.array([ext[0] / 2, ext[1] / 2, ext[2]])
            part = planar_box("door", lo, hi, tex, lo, hi, roughness=0.5)
            pose = wall.world_from_wall @ make_pose(np.eye(3), [xc, -0.02 - ext[1] / 2, 0.002])
            pieces.append(_shell_piece("door", [part], pose, "floor", ext))
        else:  # outdoor backdrop panel 1.5 m outside the window, so views through it hit a surface
            ext = np.array([width + 2.4, 0.05, height + 1.6])
            tex = shell_texture(style, "backdrop", rng, min(512, texture_size), 3.0)
            lo, hi = np.array([-ext[0] / 2, -ext[1] / 2, 0.0]), np.array([ext[0] / 2, ext[1] / 2, ext[2]])
            part = planar_box("backdrop", lo, hi, tex, lo, hi, roughness=0.9)
            z0 = opening.z0 - 0.8
            pose = wall.world_from_wall @ make_pose(np.eye(3), [xc, -t - 1.5, z0])
            pieces.append(_shell_piece("backdrop", [part], pose, "none", ext))

    keepout = []
    for opening in holes:
        if opening.kind == "door":
            wall = walls[opening.wall]
            corners = np.array([[opening.x0 - 0.15, 0.0, 0.0], [opening.x1 + 0.15, 1.0, 0.0]])
            pts = corners @ wall.world_from_wall[:3, :3].T + wall.world_from_wall[:3, 3]
            keepout.append(box(*pts[:, :2].min(axis=0), *pts[:, :2].max(axis=0)))
    return RoomShell((x, y, h), pieces, walls, holes, keepout)


def f32(value: float) -> float:
    """Round to the nearest float32 (USD stores light values as float), for exact round trips."""
    return float(np.float32(value))


def ceiling_lights(
    size: tuple[float, float, float],
    count: int,
    style: ShellStyle,
    rng: np.random.Generator,
    *,
    prefix: str = "light",
) -> list[Light]:
    """``count`` ceiling lights (rect panels just below the ceiling or sphere bulbs 0.3 m below it), spread
    over a jittered grid of the ceiling."""
    x, y, h = size
    cols = int(np.ceil(np.sqrt(count * x / y)))
    rows = int(np.ceil(count / cols))
    cells = [(i, j) for j in range(rows) for i in range(cols)]
    order = rng.permutation(len(cells))[:count]
    lights = []
    for k, idx in enumerate(sorted(order)):
        i, j = cells[idx]
        cx = -x / 2 + (i + 0.5 + rng.uniform(-0.2, 0.2)) * x / cols
        cy = -y / 2 + (j + 0.5 + rng.uniform(-0.2, 0.2)) * y / rows
        tint = np.clip(np.asarray(style.light_colour) * rng.uniform(0.95, 1.05, 3), 0.0, 1.0)
        colour = tuple(f32(c) for c in tint)
        level = float(rng.uniform(*style.light_intensity))
        if rng.random() < 0.5:
            side = f32(rng.uniform(0.4, 0.7))
            # radiance giving roughly the intensity of a sphere light of ``level`` W/sr
            pose = make_pose(np.eye(3), [f32(cx), f32(cy), f32(h - 0.01)])
            lights.append(
                Light(f"{prefix}_{k}", "rect", pose, f32(level / (side * side)), colour, size=(side, side))
            )
        else:
            pose = make_pose(np.eye(3), [f32(cx), f32(cy), f32(h - 0.3)])
            lights.append(Light(f"{prefix}_{k}", "sphere", pose, f32(level), colour, radius=f32(0.06)))
    return lights
