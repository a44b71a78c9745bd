"""Clutter: small prop models (``role = "prop"``) on floors, walls and furniture tops.

At clutter level ``c`` a room gets, each count stochastically rounded: ``c * FLOOR_PER_M2`` floor props per m²
of floor (at most one rug), ``c * WALL_PER_M`` wall props per metre of wall, and ``c * SURFACE_PER_M2`` props per
m² of every support surface of the placed furniture (table tops, shelf boards). Each prop is a variant of a
random prop model (colour, scale and shape at :data:`PROP_MAGNITUDE`) with the study's material assignment, placed
with the room's collision and support rules; a prop that does not fit is left out. Everything is drawn from
``make_rng(room seed, "clutter", ...)``, so a room without clutter draws nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from synthleak.assets.materials import assign_materials, with_materials
from synthleak.assets.variants import Variant, variant
from synthleak.scene.placement import FLAT_HEIGHT, Item, Placement, Placer
from synthleak.scene.plan import FIRST_PROP_ID, RoomPlan, is_prop
from synthleak.seeding import derive_seed, make_rng

FLOOR_PER_M2 = 0.25
WALL_PER_M = 0.1
SURFACE_PER_M2 = 4.0
PROP_MAGNITUDE = 0.6
"""Variant magnitude of props: the same prop model looks different from room to room."""


@dataclass
class PlacedProp:
    """One placed clutter prop: its instance id, variant, the item placed and where."""

    instance_id: int
    variant: Variant
    item: Item
    placement: Placement


def _count(rng: np.random.Generator, expected: float) -> int:
    """Stochastic rounding: ``floor(expected)`` plus one with probability ``frac(expected)``."""
    whole = int(np.floor(expected))
    return whole + int(rng.random() < expected - whole)


def _is_flat(model) -> bool:
    return model.support == "floor" and float(model.size[2]) < FLAT_HEIGHT


def place_clutter(plan: RoomPlan, library: Mapping, placer: Placer) -> list[PlacedProp]:
    """Place the room's clutter props with ``placer`` (after the furniture); returns the props placed."""
    if plan.clutter <= 0:
        return []
    props = sorted(m for m in library if is_prop(library[m]))
    by_support = {s: [m for m in props if library[m].support == s] for s in ("floor", "wall", "surface")}
    rng = make_rng(plan.seed, "clutter", "counts")
    x, y, _ = plan.size
    requests: list[tuple[str, tuple | None]] = []
    requests += [("floor", None)] * _count(rng, plan.clutter * FLOOR_PER_M2 * x * y)
    requests += [("wall", None)] * _count(rng, plan.clutter * WALL_PER_M * 2 * (x + y))
    for host, surface in placer.surfaces():
        area = (surface.x_max - surface.x_min) * (surface.y_max - surface.y_min)
        requests += [("surface", (host, surface))] * _count(rng, plan.clutter * SURFACE_PER_M2 * area)
    placed: list[PlacedProp] = []
    rugs = 0
    for k, (support, surface) in enumerate(requests):
        choices = by_support[support]
        if support == "floor" and rugs:
            choices = [m for m in choices if not _is_flat(library[m])]
        if not choices:
            continue
        pick_rng = make_rng(plan.seed, "clutter", "prop", k)
        model_id = choices[int(pick_rng.integers(len(choices)))]
        model = library[model_id]
        if plan.material_sharing > 0:
            model = with_materials(model, assign_materials(model, plan.study_seed, plan.material_sharing))
        iid = FIRST_PROP_ID + len(placed)
        v = variant(model, derive_seed(plan.seed, "clutter", "variant", k), PROP_MAGNITUDE)
        item = Item(f"{model_id}_{iid}", model.support, v.build(), model.symmetry, (), category=model.category)
        placement = placer.place(item, surface=surface)
        if placement is None:
            continue
        rugs += int(item.flat)
        placed.append(PlacedProp(iid, v, item, placement))
    return placed
