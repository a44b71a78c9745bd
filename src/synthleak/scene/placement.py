"""Object placement in a room shell: support rules, yaw rules and collision checks.

Collision bodies are 2D footprint polygons (shapely, oriented boxes of the object's bounds) with a z interval.
Rules: floor objects stand on z = 0 inside the walls and keep the door area free; wall hangings hang flat
against a wall, centred 1.2-1.8 m high, never over an opening; ceiling lamps touch the ceiling; surface objects
stand on a support surface of an already placed piece of furniture (within its rectangle, below the next board
above it). Flat floor items (rugs, under :data:`FLAT_HEIGHT`) only avoid each other and the door area:
furniture stands on them.

Floor layouts (:data:`LAYOUTS`): ``scatter`` puts 55 % of the floor objects against a wall and the rest
anywhere, facing the room centre; ``home`` places furniture as people do (:data:`HOME_RULES`): cupboards,
beds, sofas, shelves and desks backed against a wall and facing the room, chairs and stools at a table or
desk facing it, coffee tables in front of a sofa, floor lamps, side and bedside tables beside a seat or bed,
tables aligned with the walls; yaws stay within a few degrees of the walls' directions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from shapely.affinity import affine_transform
from shapely.geometry import Polygon, box

from synthleak.assets.mesh import ObjectMesh
from synthleak.errors import SynthleakError
from synthleak.geometry.poses import make_pose, transform_points
from synthleak.scene.room import RoomShell, yaw_matrix

FLOOR_GAP = 0.03
"""Minimum horizontal clearance between floor objects (m)."""
WALL_MARGIN = 0.02
"""Minimum distance between an object and the inner face of a wall (m)."""
SURFACE_MARGIN = 0.01
"""Minimum inset of a surface object's footprint from its support rectangle's edges (m)."""
FLAT_HEIGHT = 0.05
"""Floor items lower than this (rugs) lie under furniture: they only collide with each other."""
LAYOUTS = ("scatter", "home")

HOME_RULES: dict[str, tuple[str, tuple[str, ...]]] = {
    "bed": ("wall", ()),
    "cupboard": ("wall", ()),
    "shelf": ("wall", ()),
    "desk": ("wall", ()),
    "sofa": ("wall", ()),
    "oven": ("wall", ()),
    "bicycle": ("wall", ()),
    "plant": ("wall", ()),
    "table": ("table", ()),
    "coffee_table": ("in_front", ("sofa", "armchair")),
    "chair": ("at_table", ("table", "desk")),
    "stool": ("at_table", ("table", "desk")),
    "armchair": ("facing_room", ()),
    "lamp": ("beside", ("sofa", "armchair", "bed", "desk")),
    "side_table": ("beside", ("sofa", "armchair", "bed")),
    "bedside_table": ("beside", ("bed",)),
}
"""Home layout: category -> (rule, host categories). Rules: ``wall`` (backed against a wall, facing the
room), ``table`` (aligned with the walls, free-standing or against a wall), ``in_front`` (in front of a host),
``at_table`` (at a side of a host, facing it), ``beside`` (next to a host's side, facing as it does),
``facing_room`` (against a wall or free-standing facing the room centre). A rule that finds no host or no
room falls back to ``wall``, then to anywhere aligned with the walls. Other categories: ``wall``."""
HOME_ORDER = ("wall", "table", "in_front", "facing_room", "at_table", "beside")
"""Home layout placement order of the rules (hosts before the items placed relative to them)."""


class PlacementError(SynthleakError, RuntimeError):
    """An object that does not fit in its room under the placement rules."""


@dataclass
class Item:
    """Something to place: its mesh, bounds and support rule; ``surfaces`` are the support rectangles it
    offers to surface objects (object frame: objects with ``z, x_min, x_max, y_min, y_max``)."""

    name: str
    support: str
    mesh: ObjectMesh
    symmetry: str = "none"
    surfaces: Sequence[Any] = ()
    bounds: np.ndarray = field(default=None)  # type: ignore[assignment]
    category: str = ""

    @property
    def flat(self) -> bool:
        """A rug: a floor item furniture may stand on."""
        return self.support == "floor" and float(self.bounds[1][2] - self.bounds[0][2]) < FLAT_HEIGHT

    def __post_init__(self) -> None:
        if self.bounds is None:
            self.bounds = self.mesh.bounds()
        if self.support not in ("floor", "wall", "ceiling", "surface"):
            raise ValueError(
                f"item {self.name!r}: field 'support' must be floor|wall|ceiling|surface, "
                f"got {self.support!r}"
            )


@dataclass
class Body:
    """A collision body: footprint polygon (world x, y) and height interval."""

    name: str
    footprint: Polygon
    z0: float
    z1: float
    flat: bool = False
    """A rug: only other flat bodies collide with it."""

    def hits(self, other: Body, gap: float = 0.0) -> bool:
        if self.flat != other.flat:
            return False
        if self.z1 <= other.z0 + 1e-6 or other.z1 <= self.z0 + 1e-6:
            return False
        if gap > 0:
            return self.footprint.distance(other.footprint) < gap
        return self.footprint.intersection(other.footprint).area > 1e-8


@dataclass
class Placement:
    """Where one item ended up; ``parent`` is the supporting item's name (surface objects) or the wall."""

    name: str
    world_from_object: np.ndarray
    support: str
    parent: str | None = None


def body_of(name: str, bounds: np.ndarray, world_from_object: np.ndarray, flat: bool = False) -> Body:
    """World collision body of object-frame ``bounds`` (2, 3) under a yaw-only pose."""
    (x0, y0, z0), (x1, y1, z1) = bounds
    rect = box(x0, y0, x1, y1)
    r, t = world_from_object[:3, :3], world_from_object[:3, 3]
    footprint = affine_transform(rect, [r[0, 0], r[0, 1], r[1, 0], r[1, 1], t[0], t[1]])
    return Body(name, footprint, z0 + t[2], z1 + t[2], flat)


def _yawed(yaw: float, xyz: Sequence[float]) -> np.ndarray:
    return make_pose(yaw_matrix(yaw), xyz)


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


class Placer:
    """Places items one by one into a room shell; keeps the collision bodies of everything placed so far."""

    def __init__(self, shell: RoomShell, rng: np.random.Generator, attempts: int = 80, layout: str = "scatter"
                 ) -> None:
        if layout not in LAYOUTS:
            raise ValueError(f"scenes.layout: {layout!r} is not one of {LAYOUTS}")
        self.shell = shell
        self.rng = rng
        self.attempts = attempts
        self.layout = layout
        self.bodies: list[Body] = []
        self.placed: dict[str, tuple[Item, Placement]] = {}
        x, y, h = shell.size
        self.height = h
        self.inside = shell.interior(WALL_MARGIN)
        door_h = max((o.z1 for o in shell.openings if o.kind == "door"), default=2.1)
        self.keepout = [Body("door_area", poly, 0.0, door_h) for poly in shell.keepout]

    # ------------------------------------------------------------------------------------------ checks
    def _free(self, body: Body, ignore: set[str] = frozenset(), gap: float = 0.0) -> bool:
        return not any(b.name not in ignore and body.hits(b, gap) for b in self.bodies)

    def _floor_ok(self, body: Body) -> bool:
        return (
            self.inside.contains(body.footprint)
            and not any(body.hits(k) for k in self.keepout)
            and self._free(body, gap=FLOOR_GAP)
        )

    def _commit(self, item: Item, placement: Placement) -> Placement:
        self.bodies.append(body_of(item.name, item.bounds, placement.world_from_object, item.flat))
        self.placed[item.name] = (item, placement)
        return placement

    # ------------------------------------------------------------------------------------------ rules
    def _floor(self, item: Item) -> Placement | None:
        if self.layout == "home" or item.flat:
            return self._home_floor(item)
        (x0, y0, z0), (x1, y1, _) = item.bounds
        x, y, _ = self.shell.size
        for _ in range(self.attempts):
            if self.rng.random() < 0.55:  # back against a wall, facing into the room
                wall = list(self.shell.walls.values())[int(self.rng.integers(4))]
                half = wall.length / 2 - WALL_MARGIN - max(-x0, x1) - 0.02
                if half <= 0:
                    continue
                along = float(self.rng.uniform(-half, half))
                offset = -y0 + WALL_MARGIN + float(self.rng.uniform(0.0, 0.12))
                pose = wall.world_from_wall @ make_pose(np.eye(3), [along, offset, -z0])
            else:  # free standing, facing the room centre (or any yaw for rotation-symmetric objects)
                px = float(self.rng.uniform(-x / 2, x / 2))
                py = float(self.rng.uniform(-y / 2, y / 2))
                if item.symmetry == "z":
                    yaw = float(self.rng.uniform(-np.pi, np.pi))
                else:
                    to_centre = np.arctan2(
                        -py, -px
                    )  # +y of the object should point there: yaw = angle - 90 deg
                    yaw = _wrap(to_centre - np.pi / 2 + float(self.rng.normal(0.0, np.radians(25))))
                pose = _yawed(yaw, [px, py, -z0])
            body = body_of(item.name, item.bounds, pose)
            if self._floor_ok(body):
                return Placement(item.name, pose, "floor")
        return None

    # ------------------------------------------------------------------------------------ home layout
    def _home_floor(self, item: Item) -> Placement | None:
        """The item's home rule (flat items: anywhere aligned), then the fallbacks of :data:`HOME_RULES`."""
        rule, hosts = ("aligned", ()) if item.flat else HOME_RULES.get(item.category, ("wall", ()))
        for name in dict.fromkeys((rule, "wall", "aligned")):
            for _ in range(self.attempts):
                pose = self._home_pose(name, item, hosts)
                if pose is None:
                    break
                if self._floor_ok(body_of(item.name, item.bounds, pose, item.flat)):
                    return Placement(item.name, pose, "floor")
        return None

    def _yaw_noise(self) -> float:
        return float(self.rng.normal(0.0, np.radians(2.0)))

    def _hosts(self, categories: Sequence[str]) -> list[tuple[Item, Placement]]:
        return [(it, pl) for it, pl in self.placed.values() if it.category in categories and pl.support == "floor"]

    def _home_pose(self, rule: str, item: Item, hosts: Sequence[str]) -> np.ndarray | None:
        """One candidate ``world_from_object`` of ``rule`` (None: the rule cannot apply in this room)."""
        (x0, y0, z0), (x1, y1, _) = item.bounds
        rng = self.rng
        if rule == "wall" or (rule in ("table", "facing_room") and rng.random() < 0.4):
            wall = list(self.shell.walls.values())[int(rng.integers(4))]
            half = wall.length / 2 - WALL_MARGIN - max(-x0, x1) - 0.02
            if half <= 0:
                return None
            along = float(rng.uniform(-half, half))
            offset = -y0 + WALL_MARGIN + float(rng.uniform(0.0, 0.03))
            return wall.world_from_wall @ _yawed(self._yaw_noise(), [along, offset, -z0])
        if rule in ("aligned", "table", "facing_room"):
            x, y, _ = self.shell.size
            px, py = float(rng.uniform(-x / 2, x / 2)), float(rng.uniform(-y / 2, y / 2))
            if rule == "facing_room" and item.symmetry != "z":
                yaw = np.pi / 2 * round((np.arctan2(-py, -px) - np.pi / 2) / (np.pi / 2))
            else:
                yaw = np.pi / 2 * int(rng.integers(4))
            return _yawed(float(yaw) + self._yaw_noise(), [px, py, -z0])
        placed = self._hosts(hosts)
        if not placed:
            return None
        host, host_pl = placed[int(rng.integers(len(placed)))]
        (hx0, hy0, _), (hx1, hy1, _) = host.bounds
        gap = float(rng.uniform(0.04, 0.15))
        if rule == "in_front":  # e.g. a coffee table in front of a sofa, parallel to it
            local = _yawed(self._yaw_noise(), [0.5 * (hx0 + hx1), hy1 + gap + 0.3 - y0, -z0])
        elif rule == "beside":  # next to the host's left or right side, near its back, facing as it does
            side = 1.0 if rng.random() < 0.5 else -1.0
            px = (hx1 + gap - x0) if side > 0 else (hx0 - gap - x1)
            local = _yawed(self._yaw_noise(), [px, hy0 - y0 + float(rng.uniform(0.0, 0.1)), -z0])
        elif rule == "at_table":  # at one of the host's four sides, the item's front (+y) facing the host
            side = int(rng.integers(4))
            direction = np.array([(0.0, -1.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0)][side])
            reach = 0.5 * (hy1 - hy0) if side in (0, 2) else 0.5 * (hx1 - hx0)
            span = 0.5 * (hx1 - hx0) if side in (0, 2) else 0.5 * (hy1 - hy0)
            along = float(rng.uniform(-1.0, 1.0)) * max(span - 0.5 * (x1 - x0), 0.0)
            centre = np.array([0.5 * (hx0 + hx1), 0.5 * (hy0 + hy1)])
            # the item's front edge (local y1) ends up ``gap`` from the host's edge
            xy = centre + (reach + gap + y1) * direction + along * np.array([-direction[1], direction[0]])
            local = _yawed(side * np.pi / 2 + self._yaw_noise(), [xy[0], xy[1], -z0])
        else:
            raise ValueError(f"unknown home layout rule {rule!r}")
        return host_pl.world_from_object @ local

    def _wall(self, item: Item) -> Placement | None:
        (x0, y0, z0), (x1, _, z1) = item.bounds
        height = z1 - z0
        for _ in range(self.attempts):
            wall = list(self.shell.walls.values())[int(self.rng.integers(4))]
            half = wall.length / 2 - max(-x0, x1) - 0.1
            if half <= 0:
                continue
            along = float(self.rng.uniform(-half, half))
            centre = float(self.rng.uniform(1.2, 1.8))
            centre = min(centre, self.height - 0.1 - height / 2)
            bottom = max(centre - height / 2, 0.3)
            if bottom + height > self.height - 0.05:
                continue
            blocked = any(
                o.wall == wall.name
                and along + x1 > o.x0 - 0.1
                and along + x0 < o.x1 + 0.1
                and bottom + height > o.z0 - 0.1
                and bottom < o.z1 + 0.1
                for o in self.shell.openings
            )
            if blocked:
                continue
            pose = wall.world_from_wall @ make_pose(np.eye(3), [along, -y0 + 0.001, bottom - z0])
            if self._free(body_of(item.name, item.bounds, pose), gap=0.02):
                return Placement(item.name, pose, "wall", wall.name)
        return None

    def _ceiling(self, item: Item) -> Placement | None:
        (x0, y0, z0), (x1, y1, z1) = item.bounds
        x, y, _ = self.shell.size
        reach = float(np.hypot(max(-x0, x1), max(-y0, y1))) + 0.2
        if 2 * reach >= min(x, y):
            return None
        for _ in range(self.attempts):
            px = float(self.rng.uniform(-x / 2 + reach, x / 2 - reach))
            py = float(self.rng.uniform(-y / 2 + reach, y / 2 - reach))
            yaw = (
                float(self.rng.uniform(-np.pi, np.pi))
                if item.symmetry == "z"
                else np.pi / 2 * int(self.rng.integers(4))
            )
            pose = _yawed(yaw, [px, py, self.height - z1])
            if self._free(body_of(item.name, item.bounds, pose), gap=0.05):
                return Placement(item.name, pose, "ceiling", "ceiling")
        return None

    def surfaces(self) -> list[tuple[str, Any]]:
        """(host name, support surface) of every placed floor item that offers one, in placement order."""
        return [(name, surf) for name, (it, pl) in self.placed.items() if pl.support == "floor"
                for surf in it.surfaces]

    def _surface(self, item: Item, target: tuple[str, Any] | None = None) -> Placement | None:
        (x0, y0, z0), (x1, y1, z1) = item.bounds
        hosts = [
            (name, it, pl) for name, (it, pl) in self.placed.items() if it.surfaces and pl.support == "floor"
        ]
        if target is not None:
            hosts = [h for h in hosts if h[0] == target[0]]
        if not hosts:
            return None
        for _ in range(self.attempts):
            name, host, host_pl = hosts[int(self.rng.integers(len(hosts)))]
            surf = target[1] if target is not None else host.surfaces[int(self.rng.integers(len(host.surfaces)))]
            if item.symmetry == "z":
                rel_yaw = float(self.rng.uniform(-np.pi, np.pi))
            else:  # roughly facing the same way as the host (into the room)
                rel_yaw = float(self.rng.normal(0.0, np.radians(15)))
            corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]) @ yaw_matrix(rel_yaw)[:2, :2].T
            hx = np.abs(corners[:, 0]).max() + SURFACE_MARGIN
            hy = np.abs(corners[:, 1]).max() + SURFACE_MARGIN
            if surf.x_max - surf.x_min < 2 * hx or surf.y_max - surf.y_min < 2 * hy:
                continue
            px = float(self.rng.uniform(surf.x_min + hx, surf.x_max - hx))
            py = float(self.rng.uniform(surf.y_min + hy, surf.y_max - hy))
            host_from_object = _yawed(rel_yaw, [px, py, surf.z - z0])
            if not self._clear_of_host(item, host, host_from_object):
                continue
            pose = host_pl.world_from_object @ host_from_object
            body = body_of(item.name, item.bounds, pose)
            if (self.inside.contains(body.footprint) and body.z1 <= self.height - 0.02
                    and self._free(body, ignore={name}, gap=0.02)):
                return Placement(item.name, pose, "surface", name)
        return None

    @staticmethod
    def _clear_of_host(item: Item, host: Item, host_from_object: np.ndarray) -> bool:
        """No host triangle reaches into the item's box (e.g. the board above), contact face excluded."""
        lo, hi = item.bounds
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        world = transform_points(host_from_object, corners)
        box_lo, box_hi = world.min(axis=0) + [0.0, 0.0, 0.002], world.max(axis=0)
        for part in host.mesh.parts:
            tri = part.vertices[part.faces]
            t_lo, t_hi = tri.min(axis=1), tri.max(axis=1)
            overlap = np.all((t_lo < box_hi) & (t_hi > box_lo), axis=1)
            if overlap.any():
                return False
        return True

    # ------------------------------------------------------------------------------------------ API
    def place(self, item: Item, surface: tuple[str, Any] | None = None) -> Placement | None:
        """Place one item (None when no valid pose was found within ``attempts`` tries); ``surface`` (host
        name, support surface) puts a surface item on that surface."""
        if item.name in self.placed:
            raise ValueError(f"item {item.name!r} placed twice")
        if surface is not None:
            if item.support != "surface":
                raise ValueError(f"item {item.name!r}: only surface items go on a given surface")
            placement = self._surface(item, surface)
        else:
            rule = {"floor": self._floor, "wall": self._wall, "ceiling": self._ceiling, "surface": self._surface}
            placement = rule[item.support](item)
        return None if placement is None else self._commit(item, placement)


def placement_order(items: Sequence[Item], layout: str = "scatter") -> list[Item]:
    """Floor objects first (largest footprint first; in the home layout hosts before the items placed
    relative to them, :data:`HOME_ORDER`), then wall, ceiling and surface objects."""
    rank = {"floor": 0, "wall": 1, "ceiling": 2, "surface": 3}

    def home_rank(item: Item) -> int:
        if layout != "home" or item.support != "floor":
            return 0
        rule = "aligned" if item.flat else HOME_RULES.get(item.category, ("wall", ()))[0]
        return HOME_ORDER.index(rule) if rule in HOME_ORDER else len(HOME_ORDER)

    def key(item: Item) -> tuple[int, int, float, str]:
        (x0, y0, _), (x1, y1, _) = item.bounds
        return rank[item.support], home_rank(item), -(x1 - x0) * (y1 - y0), item.name

    return sorted(items, key=key)


def place_items(
    shell: RoomShell, items: Sequence[Item], rng: np.random.Generator, layout: str = "scatter"
) -> tuple[dict[str, Placement], list[str], Placer]:
    """Place ``items`` in :func:`placement_order`; returns placements, names that did not fit, the placer."""
    placer = Placer(shell, rng, layout=layout)
    placements: dict[str, Placement] = {}
    dropped: list[str] = []
    for item in placement_order(items, layout):
        placement = placer.place(item)
        if placement is None:
            dropped.append(item.name)
        else:
            placements[item.name] = placement
    return placements, dropped, placer
