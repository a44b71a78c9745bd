"""Compose a room :class:`SceneSpec` from its :class:`RoomPlan`: shell, placed variants, ceiling lights.

Placement is retried with fresh placement seeds (up to ``attempts``) when an object does not fit; the best
attempt (fewest dropped selected objects, then fewest dropped objects, then the earliest) is kept and the
dropped objects are listed in the spec's metadata. Clutter props (:mod:`synthleak.scene.clutter`) are placed
after the furniture. ``metadata["supported_by"]`` maps each surface object's (or prop's) instance id to its
host's.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from synthleak.assets.materials import with_materials
from synthleak.assets.variants import Variant, variant
from synthleak.core.types import Light
from synthleak.scene.clutter import place_clutter
from synthleak.scene.placement import Body, Item, Placer, place_items
from synthleak.scene.plan import RoomPlan
from synthleak.scene.room import build_room_shell, ceiling_lights, f32
from synthleak.scene.spec import PlacedObject, SceneSpec
from synthleak.scene.styles import ShellStyle, room_styles
from synthleak.seeding import make_rng


def _light_clear(light: Light, bodies: list[Body]) -> bool:
    """A light does not sit inside or just above an object (e.g. a ceiling lamp or a tall wardrobe)."""
    from shapely.geometry import Point, box

    x, y, z = light.world_from_light[:3, 3]
    if light.kind == "rect":
        w, h = light.size
        shape, z0, z1 = box(x - w / 2, y - h / 2, x + w / 2, y + h / 2), z - 0.3, z + 0.02
    else:
        shape, z0, z1 = (
            Point(x, y).buffer(light.radius + 0.1),
            z - light.radius - 0.2,
            z + light.radius + 0.05,
        )
    return not any(b.z1 > z0 and b.z0 < z1 and b.footprint.intersects(shape) for b in bodies)


def room_lights(plan: RoomPlan, style: ShellStyle, bodies: list[Body], tries: int = 20) -> list[Light]:
    """Ceiling lights clear of the placed objects (re-drawn up to ``tries`` times, then the last draw)."""
    lights: list[Light] = []
    for attempt in range(tries):
        rng = make_rng(plan.seed, "lights", attempt)
        lights = ceiling_lights(plan.size, plan.lights, style, rng)
        if all(_light_clear(light, bodies) for light in lights):
            break
    return lights


def _room_object(obj_id: int, name: str, v: Variant, item: Item, pose: np.ndarray, role: str) -> PlacedObject:
    return PlacedObject(
        instance_id=obj_id,
        name=name,
        model_id=v.model.model_id,
        category=v.model.category,
        symmetry=v.model.symmetry,
        world_from_object=pose,
        mesh=item.mesh,
        variant_params=v.record(),
        role=role,
        support=v.model.support,
        extents=item.mesh.extents(),
    )


def compose_room(plan: RoomPlan, library: Mapping, *, attempts: int = 8) -> SceneSpec:
    """The room's scene: shell pieces, placed object variants (ids from the plan; distractors have role
    ``object`` like the selected furniture), clutter props (role ``prop``), lights and ambient."""
    style = room_styles()[plan.style]
    shell = build_room_shell(plan.size, style, make_rng(plan.seed, "shell"))
    variants, items = {}, []
    for obj in plan.objects:
        model = with_materials(library[obj.model_id], dict(obj.materials))
        v = variant(model, obj.variant_seed, plan.magnitude)
        variants[obj.name] = (obj, v)
        items.append(Item(obj.name, model.support, v.build(), model.symmetry, v.support_surfaces(),
                          category=model.category))
    selected = {obj.name for obj in plan.objects if obj.kind == "selected"}
    best: tuple[tuple[int, int], dict, list[str], Placer, int] | None = None
    for attempt in range(attempts):
        placements, dropped, placer = place_items(
            shell, items, make_rng(plan.seed, "placement", attempt), plan.layout
        )
        lost = (len(selected.intersection(dropped)), len(dropped))  # selected objects count first
        if best is None or lost < best[0]:
            best = (lost, placements, dropped, placer, attempt)
        if not dropped:
            break
    assert best is not None
    _, placements, dropped, placer, attempt = best
    props = place_clutter(plan, library, placer)
    objects: list[PlacedObject] = list(shell.pieces)
    supported_by: dict[str, int] = {}
    ids = {name: obj.instance_id for name, (obj, _) in variants.items()}
    for item in items:
        if item.name not in placements:
            continue
        obj, v = variants[item.name]
        placement = placements[item.name]
        objects.append(_room_object(obj.instance_id, obj.name, v, item, placement.world_from_object, "object"))
        if placement.support == "surface":
            supported_by[str(obj.instance_id)] = ids[placement.parent]
    for prop in props:
        objects.append(_room_object(prop.instance_id, prop.item.name, prop.variant, prop.item,
                                    prop.placement.world_from_object, "prop"))
        if prop.placement.support == "surface":
            supported_by[str(prop.instance_id)] = ids[prop.placement.parent]
    objects.sort(key=lambda o: o.instance_id)
    ambient_rng = make_rng(plan.seed, "ambient")
    metadata = {
        "style": style.name,
        "openings": [
            {"wall": o.wall, "kind": o.kind, "x0": o.x0, "x1": o.x1, "z0": o.z0, "z1": o.z1}
            for o in shell.openings
        ],
        "dropped": sorted(dropped),
        "placement_attempt": attempt,
        "supported_by": supported_by,
    }
    if plan.layout != "scatter" or props:  # the clean world's stages keep their bytes
        metadata |= {"layout": plan.layout, "props": len(props)}
    return SceneSpec(
        name=plan.name,
        kind="room",
        objects=objects,
        lights=room_lights(plan, style, placer.bodies),
        room_size=plan.size,
        seed=plan.seed,
        target_instance_id=None,
        ambient=f32(ambient_rng.uniform(*style.ambient)),
        metadata=metadata,
    )
