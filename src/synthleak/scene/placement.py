"""Object placement in a room shell: support rules, yaw rules and collision checks.

Collision bodies are 2D footprint polygons (shapely, oriented boxes of the object's bounds) with a z interval.
Rules: floor objects stand on z = 0 inside the walls (mostly backed against a wall or facing the room
centre) and keep the door area free; wall hangings hang flat against a wall, centred 1.2-1.8 m high, never
over an opening; ceiling lamps touch the ceiling; surface objects stand on a support surface of an already
placed piece of furniture (within its rectangle, below the next board above it).
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

    def hits(self, other: Body, gap: float = 0.0) -> bool:
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


def body_of(name: str, bounds: np.ndarray, world_from_object: np.ndarray) -> Body:
    """World collision body of object-frame ``bounds`` (2, 3) under a yaw-only pose."""
    (x0, y0, z0), (x1, y1, z1) = bounds
    rect = box(x0, y0, x1, y1)
    r, t = world_from_object[:3, :3], world_from_object[:3, 3]
    footprint = affine_transform(rect, [r[0, 0], r[0, 1], r[1, 0], r[1, 1], t[0], t[1]])
    return Body(name, footprint, z0 + t[2], z1 + t[2])


def _yawed(yaw: float, xyz: Sequence[float]) -> np.ndarray:
    return make_pose(yaw_matrix(yaw), xyz)


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


class Placer:
    """Places items one by one into a room shell; keeps the collision bodies of everything placed so far."""

    def __init__(self, shell: RoomShell, rng: np.random.Generator, attempts: int = 80) -> None:
        self.shell = shell
        self.rng = rng
        self.attempts = attempts
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
        self.bodies.append(body_of(item.name, item.bounds, placement.world_from_object))
        self.placed[item.name] = (item, placement)
        return placement

    # ------------------------------------------------------------------------------------------ rules
    def _floor(self, item: Item) -> Placement | None:
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

    def _surface(self, item: Item) -> Placement | None:
        (x0, y0, z0), (x1, y1, z1) = item.bounds
        hosts = [
            (name, it, pl) for name, (it, pl) in self.placed.items() if it.surfaces and pl.support == "floor"
        ]
        if not hosts:
            return None
        for _ in range(self.attempts):
            name, host, host_pl = hosts[int(self.rng.integers(len(hosts)))]
            surf = host.surfaces[int(self.rng.integers(len(host.surfaces)))]
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
            if self.inside.contains(body.footprint) and self._free(body, ignore={name}, gap=0.02):
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
    def place(self, item: Item) -> Placement | None:
        """Place one item (None when no valid pose was found within ``attempts`` tries)."""
        if item.name in self.placed:
            raise ValueError(f"item {item.name!r} placed twice")
        rule = {"floor": self._floor, "wall": self._wall, "ceiling": self._ceiling, "surface": self._surface}
        placement = rule[item.support](item)
        return None if placement is None else self._commit(item, placement)


def placement_order(items: Sequence[Item]) -> list[Item]:
    """Floor objects first (largest footprint first), then wall, ceiling and surface objects."""
    rank = {"floor": 0, "wall": 1, "ceiling": 2, "surface": 3}

    def key(item: Item) -> tuple[int, float, str]:
        (x0, y0, _), (x1, y1, _) = item.bounds
        return rank[item.support], -(x1 - x0) * (y1 - y0), item.name

    return sorted(items, key=key)


def place_items(
    shell: RoomShell, items: Sequence[Item], rng: np.random.Generator
) -> tuple[dict[str, Placement], list[str], Placer]:
    """Place ``items`` in :func:`placement_order`; returns placements, names that did not fit, the placer."""
    placer = Placer(shell, rng)
    placements: dict[str, Placement] = {}
    dropped: list[str] = []
    for item in placement_order(items):
        placement = placer.place(item)
        if placement is None:
            dropped.append(item.name)
        else:
            placements[item.name] = placement
    return placements, dropped, placer
