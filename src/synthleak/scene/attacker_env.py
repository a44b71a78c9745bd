"""The attacker's environment: ONE target object at the centre of a setting drawn for that object.

By default each object gets its own setting (:mod:`synthleak.scene.attacker_settings`: an inventory hall, a
home, a shop floor, a photo studio with paper sweeps or a courtyard; each wall drawn on its own, so groups of
orbit views see different backgrounds), sharing no surface with the rooms' shells. :func:`hall_shell` is the
former one-hall-per-study environment (``scenes_usd/attacker_hall.toml``), used when a hall is passed to
:func:`compose_attacker`. The target stands with its canonical frame at the origin (identity rotation), so
``world_from_object`` is a pure translation:

* floor objects stand on the floor at the centre;
* surface objects stand on a plain pedestal (shell piece ``pedestal``);
* wall hangings hang on a free-standing wall panel (shell piece ``panel``), centred at 1.5 m;
* ceiling lamps hang under a suspended ceiling panel (shell piece ``canopy``) 2.6 m above the floor.
"""

from __future__ import annotations

import functools

import numpy as np

from synthleak.assets.mesh import ObjectMesh
from synthleak.core.types import Light
from synthleak.geometry.poses import make_pose
from synthleak.scene.attacker_settings import OWN_KINDS, draw_setting, setting_texture
from synthleak.scene.plan import ATTACKER_TARGET_ID, AttackerPlan
from synthleak.scene.room import RoomShell, build_room_shell, ceiling_lights, f32, surface_texture
from synthleak.scene.shell_geometry import planar_box
from synthleak.scene.spec import PlacedObject, SceneSpec
from synthleak.scene.styles import ShellStyle, attacker_styles
from synthleak.seeding import make_rng

PEDESTAL_HEIGHT = 0.8
PANEL_CENTRE = 1.5
CANOPY_HEIGHT = 2.6
PROP_IDS = {"pedestal": 9, "panel": 10, "canopy": 11}


@functools.lru_cache(maxsize=4)
def hall_shell(seed: int, style_index: int = 0) -> tuple[ShellStyle, RoomShell]:
    """The inventory hall's shell (one per study: every attacker object is photographed in the same hall).

    Cached: treat the returned shell as read-only."""
    styles = attacker_styles()
    style = styles[style_index % len(styles)]
    assert style.size is not None
    return style, build_room_shell(style.size, style, make_rng(seed, "attacker_hall", "shell"))


def _prop_texture(style: ShellStyle, surface: str, rng: np.random.Generator, size: int, span: float) -> np.ndarray:
    """A prop's texture: a (kind, colour) of the style's finish: a setting's own kind, or (the former hall's
    styles) a kind of :func:`~synthleak.assets.textures.make_texture`."""
    kind, colour = style.finishes[surface].draw(rng)
    if kind in OWN_KINDS:
        return setting_texture(kind, colour, rng, size)
    return surface_texture(kind, colour, rng, size, span)


def _prop(
    name: str,
    ext: np.ndarray,
    world_from_object: np.ndarray,
    texture: np.ndarray,
    support: str,
    roughness: float = 0.7,
) -> PlacedObject:
    lo, hi = np.array([-ext[0] / 2, -ext[1] / 2, 0.0]), np.array([ext[0] / 2, ext[1] / 2, ext[2]])
    part = planar_box(name, lo, hi, texture, lo, hi, roughness=roughness)
    return PlacedObject(
        instance_id=PROP_IDS[name],
        name=name,
        model_id=f"shell_{name}",
        category="shell",
        symmetry="none",
        world_from_object=world_from_object,
        mesh=ObjectMesh([part]),
        role="shell",
        support=support,
        extents=np.asarray(ext, dtype=np.float64),
    )


def _target_pose_and_props(
    support: str, mesh: ObjectMesh, style: ShellStyle, rng: np.random.Generator
) -> tuple[np.ndarray, list[PlacedObject]]:
    (x0, y0, z0), (x1, y1, z1) = mesh.bounds()
    if support == "floor":
        return make_pose(np.eye(3), [0.0, 0.0, -z0]), []
    if support == "surface":
        side = max(x1 - x0, y1 - y0) + 0.2
        ext = np.array([side, side, PEDESTAL_HEIGHT])
        tex = _prop_texture(style, "pedestal", rng, 512, side)
        pedestal = _prop("pedestal", ext, make_pose(np.eye(3), [0.0, 0.0, 0.0]), tex, "floor", 0.5)
        return make_pose(np.eye(3), [0.0, 0.0, PEDESTAL_HEIGHT - z0]), [pedestal]
    if support == "wall":
        height = z1 - z0
        bottom = max(PANEL_CENTRE - height / 2, 0.3)
        ext = np.array([max(x1 - x0 + 1.2, 1.6), 0.08, max(bottom + height + 0.6, 2.2)])
        tex = _prop_texture(style, "panel", rng, 1024, ext[0])
        panel_pose = make_pose(np.eye(3), [0.0, y0 - 0.001 - ext[1] / 2, 0.0])
        panel = _prop("panel", ext, panel_pose, tex, "floor", 0.9)
        return make_pose(np.eye(3), [0.0, 0.0, bottom - z0]), [panel]
    if support == "ceiling":
        side = max(x1 - x0, y1 - y0) + 2.0
        ext = np.array([side, side, 0.06])
        tex = _prop_texture(style, "panel", rng, 1024, side)
        canopy = _prop("canopy", ext, make_pose(np.eye(3), [0.0, 0.0, CANOPY_HEIGHT]), tex, "none", 0.9)
        return make_pose(np.eye(3), [0.0, 0.0, CANOPY_HEIGHT - z1]), [canopy]
    raise ValueError(f"attacker target: field 'support' must be floor|wall|surface|ceiling, got {support!r}")


def hall_lights(style: ShellStyle, seed: int, object_id: str, count: tuple[int, int] = (4, 7)) -> list[Light]:
    """Ceiling lights of the setting (rect panels / sphere bulbs spread over its ceiling; ``count``: [lo, hi)
    lights), drawn per object."""
    assert style.size is not None
    rng = make_rng(seed, "attacker", object_id, "lights")
    return ceiling_lights(style.size, int(rng.integers(*count)), style, rng, prefix="hall_light")


def compose_attacker(
    plan: AttackerPlan,
    library,
    seed: int,
    hall: tuple[ShellStyle, RoomShell] | None = None,
) -> SceneSpec:
    """The attacker stage of one object: its setting's shell (``hall``: the given hall's instead), optional prop
    (pedestal / panel / canopy), the target."""
    from synthleak.assets.materials import with_materials
    from synthleak.assets.variants import variant

    model = with_materials(library[plan.model_id], dict(plan.materials))
    v = variant(model, plan.variant_seed, plan.magnitude, plan.kinds)
    mesh = v.build()
    metadata: dict = {"attacker_object": plan.object_id}
    if hall is not None:
        style, shell = hall
        metadata["style"] = style.name
        n_lights = (4, 7)
    else:
        setting = draw_setting(seed, plan.object_id, mesh.extents())
        style, shell = setting.style, setting.shell
        n_lights = setting.kind.lights
        metadata |= {"style": style.name, "setting": {k: [kind, list(c)] for k, (kind, c) in
                                                       sorted(setting.surfaces.items())}}
    prop_rng = make_rng(seed, "attacker", plan.object_id, "props")
    pose, props = _target_pose_and_props(model.support, mesh, style, prop_rng)
    target = PlacedObject(
        instance_id=ATTACKER_TARGET_ID,
        name=plan.object_id,
        model_id=model.model_id,
        category=model.category,
        symmetry=model.symmetry,
        world_from_object=pose,
        mesh=mesh,
        variant_params=v.record(),
        role="object",
        support=model.support,
        extents=mesh.extents(),
    )
    ambient = f32(make_rng(seed, "attacker", plan.object_id, "ambient").uniform(*style.ambient))
    return SceneSpec(
        name=f"attacker_{plan.object_id}",
        kind="attacker",
        objects=[*shell.pieces, *props, target],
        lights=hall_lights(style, seed, plan.object_id, n_lights),
        room_size=shell.size,
        seed=plan.variant_seed,
        target_instance_id=ATTACKER_TARGET_ID,
        ambient=ambient,
        metadata=metadata,
    )
