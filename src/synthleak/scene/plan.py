"""Study plan: which rooms exist, which models each room holds, and the attacker objects.

Everything is drawn from ``config.seed`` with :func:`synthleak.seeding.make_rng` (keys ``"scenes", ...``).
About ``scenes.distinct_objects`` distinct models are selected (0: no target, every room draws on its own);
each appears in at least one room and the spare slots repeat already selected models in other rooms, so most
models appear in exactly one room (as in the paper: 7 rooms, 4-10 objects each, 38 distinct objects).
Rooms that get surface objects (vases, lamps...) also get a piece of furniture with a support surface.
Every selected model gets one attacker object: its variant with seed ``derive_seed(seed, "attacker", model)``.

The hard world (``[scenes]`` knobs, all off by default): ``material_sharing`` gives model slots shared catalogue
SKUs (:func:`synthleak.assets.materials.assign_materials`, one assignment per model and study seed, so a room's
instance and the attacker's variant of a model use the same SKUs); ``distractors = [min, max]`` adds per room
furniture models that are never attacker objects, drawn from the selected models' categories and from models
sharing their SKUs (look-alike products); ``clutter`` and ``layout`` are handed to the composer. Distractors use
their own random streams, so a study without them is drawn exactly as before.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from synthleak.config import ConfigError, StudyConfig
from synthleak.scene.styles import room_styles
from synthleak.seeding import derive_seed, make_rng

FIRST_OBJECT_ID = 100
"""Furniture instance ids start here (shell pieces use 1..99)."""
FIRST_DISTRACTOR_ID = 300
"""Distractor instance ids start here."""
FIRST_PROP_ID = 1000
"""Clutter prop instance ids start here (instance masks are 16-bit)."""
OBJECT_KINDS = ("selected", "distractor", "prop")
ATTACKER_TARGET_ID = 100
"""Instance id of the photographed object in every attacker stage."""


@dataclass(frozen=True)
class ObjectPlan:
    """One furniture instance of a room."""

    instance_id: int
    model_id: str
    variant_seed: int
    kind: str = "selected"
    """``selected`` (a variant of an attacker object: "present") or ``distractor`` (never an attacker object)."""
    materials: tuple[tuple[str, str], ...] = ()
    """(slot, SKU id) of the slots that use shared catalogue SKUs."""

    @property
    def name(self) -> str:
        return f"{self.model_id}_{self.instance_id}"


@dataclass(frozen=True)
class RoomPlan:
    """One room: its size, style index, light count, objects."""

    name: str
    seed: int
    size: tuple[float, float, float]
    style: int
    lights: int
    objects: tuple[ObjectPlan, ...]
    magnitude: float
    material_sharing: float = 0.0
    """Probability that a clutter prop's slot uses a shared SKU (furniture SKUs are in ``objects``)."""
    study_seed: int = 0
    """The study seed of the props' material assignment (0 without material sharing)."""
    clutter: float = 0.0
    layout: str = "scatter"


@dataclass(frozen=True)
class AttackerPlan:
    """One attacker object: a variant of ``model_id`` photographed in the inventory hall."""

    object_id: str
    model_id: str
    variant_seed: int
    magnitude: float
    kinds: tuple[str, ...]
    materials: tuple[tuple[str, str], ...] = ()

    @property
    def stage(self) -> str:
        return f"attacker_{self.object_id}.usda"


@dataclass
class StudyPlan:
    seed: int
    rooms: list[RoomPlan]
    attackers: list[AttackerPlan]
    present_in: dict[str, dict[str, int]] = field(default_factory=dict)
    """model id -> {room name: instance id} (planned; composition may drop an object that does not fit)."""


def model_offers_support(model) -> bool:
    """True if ``model`` (an ObjectModel) is a floor object with support surfaces (tables, shelves...)."""
    return model.support == "floor" and _offers_support(model)


@functools.lru_cache(maxsize=1024)
def _offers_support(model) -> bool:
    from synthleak.assets.library import build_model

    # geometry only: tiny stand-in textures skip the (slow) texture synthesis
    textures = {name: np.zeros((4, 4, 3), np.uint8) for name in model.textures}
    return bool(build_model(model, None, textures)[1])


def is_prop(model) -> bool:
    """True for clutter props (``role = "prop"``), which are never selected, distractors or attacker objects."""
    return getattr(model, "role", "furniture") == "prop"


def _pool(config: StudyConfig, library: Mapping) -> list[str]:
    wanted = list(config.scenes.models)
    if not wanted:
        return sorted(m for m in library if not is_prop(library[m]))
    unknown = [m for m in wanted if m not in library]
    if unknown:
        raise ConfigError(f"scenes.models: unknown model id(s) {unknown} (library has {len(library)} models)")
    props = [m for m in wanted if is_prop(library[m])]
    if props:
        raise ConfigError(f"scenes.models: {props} are clutter props, not furniture that can be attacked")
    return sorted(set(wanted))


def _room_size(config: StudyConfig, rng: np.random.Generator) -> tuple[float, float, float]:
    sc = config.scenes
    x = float(rng.uniform(*sc.room_size_x))
    y = float(rng.uniform(*sc.room_size_y))
    h = float(rng.uniform(*sc.room_height))
    return round(x, 3), round(y, 3), round(h, 3)


SURFACE_PER_HOST = 2
"""At most this many surface objects per piece of host furniture in a room."""


def _assign(
    counts: list[int],
    selected: list[str],
    hosts: set[str],
    needs_host: set[str],
    rng: np.random.Generator,
    max_count: int,
) -> list[list[str]]:
    """Distribute ``selected`` over rooms of ``counts`` slots: every model once, spare slots repeat models
    (fewest appearances first); a room holds at most ``SURFACE_PER_HOST`` surface objects per host."""
    rooms: list[list[str]] = [[] for _ in counts]

    def spare(room: list[str]) -> int:  # surface objects the room's hosts can still take
        return SURFACE_PER_HOST * sum(m in hosts for m in room) - sum(m in needs_host for m in room)

    def free(i: int) -> int:
        return counts[i] - len(rooms[i])

    shuffled = [selected[i] for i in rng.permutation(len(selected))]
    groups = [
        [m for m in shuffled if m in hosts],
        [m for m in shuffled if m in needs_host],
        [m for m in shuffled if m not in hosts and m not in needs_host],
    ]
    # every model once: hosts first, then surface objects where hosts have room, then the rest
    for group, is_surface in zip(groups, (False, True, False), strict=True):
        for model in group:
            score = [(free(i) > 0, spare(r) > 0 if is_surface else 0, free(i)) for i, r in enumerate(rooms)]
            i = max(range(len(rooms)), key=lambda k: score[k])
            if is_surface and spare(rooms[i]) <= 0:  # no host with room anywhere: add a host repeat
                options = [h for h in groups[0] if h not in rooms[i]]
                if options:
                    rooms[i].append(options[int(rng.integers(len(options)))])
            rooms[i].append(model)
    appearances = {m: sum(m in r for r in rooms) for m in selected}
    # spare slots: repeat models not yet in the room, least used first (random tie-break)
    for i, room in enumerate(rooms):
        while free(i) > 0:
            candidates = [m for m in selected if m not in room and (m not in needs_host or spare(room) > 0)]
            if not candidates:
                break
            least = min(appearances[m] for m in candidates)
            pick = [m for m in candidates if appearances[m] == least]
            model = pick[int(rng.integers(len(pick)))]
            room.append(model)
            appearances[model] += 1
    # repair: a room whose surface objects outnumber its hosts' capacity gets another host
    host_list = sorted(h for h in hosts if h in selected)
    for room in rooms:
        while spare(room) < 0:
            options = [h for h in host_list if h not in room]
            if not options:
                break
            host = options[int(rng.integers(len(options)))]
            replaceable = [
                j for j, m in enumerate(room) if m not in needs_host and m not in hosts and appearances[m] > 1
            ]
            if replaceable:
                j = replaceable[int(rng.integers(len(replaceable)))]
                appearances[room[j]] -= 1
                room[j] = host
            elif len(room) < max_count:
                room.append(host)
            else:
                break
            appearances[host] += 1
    return rooms


def plan_study(
    config: StudyConfig,
    library: Mapping,
    *,
    attacker_magnitude: float | None = None,
    attacker_kinds: Sequence[str] | None = None,
) -> StudyPlan:
    """The deterministic study plan for ``config`` over ``library`` (model id -> ObjectModel)."""
    sc = config.scenes
    seed = int(config.seed)
    if sc.rooms < 1:
        raise ConfigError("scenes.rooms: need at least one room")
    lo, hi = sc.objects_per_room
    if not 1 <= lo <= hi:
        raise ConfigError(f"scenes.objects_per_room: need 1 <= min <= max, got {sc.objects_per_room}")
    pool = _pool(config, library)
    if not pool:
        raise ConfigError("scenes.models: the object library is empty")
    rng = make_rng(seed, "scenes", "plan")
    counts = [int(rng.integers(lo, hi + 1)) for _ in range(sc.rooms)]
    counts = [min(c, len(pool)) for c in counts]
    hosts = {m for m in pool if model_offers_support(library[m])}
    needs_host = {m for m in pool if library[m].support == "surface"}
    if not hosts:
        pool = [m for m in pool if m not in needs_host] or pool  # surface objects cannot stand anywhere
    if sc.distinct_objects > 0:
        distinct = min(sc.distinct_objects, len(pool))
        while sum(counts) < distinct and any(c < min(hi, len(pool)) for c in counts):
            i = int(np.argmin(counts))
            counts[i] += 1
        distinct = min(distinct, sum(counts))
        selected = sorted(pool[i] for i in rng.choice(len(pool), size=distinct, replace=False))
        if needs_host & set(selected) and not hosts & set(selected) and hosts:
            # a surface object needs something to stand on: swap the last non-surface pick for a host
            swap = [m for m in selected if m not in needs_host]
            host = sorted(hosts)[int(rng.integers(len(hosts)))]
            selected.remove(swap[-1] if swap else selected[-1])
            selected = sorted({*selected, host})
        rooms_models = _assign(counts, selected, hosts, needs_host, rng, max(hi, max(counts)))
    else:
        rooms_models = []
        for count in counts:
            picks = [pool[i] for i in sorted(rng.choice(len(pool), size=count, replace=False))]
            rooms_models.append(picks)
        rooms_models = _assign_hosts_only(rooms_models, hosts, needs_host, rng)

    magnitude = float(sc.scene_variant_magnitude)
    sharing = float(sc.material_sharing)
    materials = _materials_of(library, seed, sharing)
    selected_models = sorted({m for models in rooms_models for m in models})
    rooms: list[RoomPlan] = []
    present_in: dict[str, dict[str, int]] = {}
    for i, models in enumerate(rooms_models):
        name = f"room_{i:03d}"
        room_rng = make_rng(seed, "scenes", name, "layout")
        size = _room_size(config, room_rng)
        style = int(room_rng.integers(len(room_styles())))
        lights = int(room_rng.integers(sc.lights_per_room[0], sc.lights_per_room[1] + 1))
        objects = []
        for j, model_id in enumerate(sorted(models)):
            iid = FIRST_OBJECT_ID + j
            objects.append(
                ObjectPlan(iid, model_id, derive_seed(seed, "scenes", name, "object", iid, model_id),
                           materials=materials(model_id))
            )
            present_in.setdefault(model_id, {})[name] = iid
        picks = draw_distractors(library, selected_models, materials, sc.distractors,
                                 make_rng(seed, "scenes", name, "distractors"))
        for j, model_id in enumerate(picks):
            iid = FIRST_DISTRACTOR_ID + j
            objects.append(ObjectPlan(iid, model_id, derive_seed(seed, "scenes", name, "object", iid, model_id),
                                      kind="distractor", materials=materials(model_id)))
        rooms.append(
            RoomPlan(name, derive_seed(seed, "scenes", name), size, style, lights, tuple(objects), magnitude,
                     material_sharing=sharing, study_seed=seed if sharing > 0 else 0, clutter=float(sc.clutter),
                     layout=sc.layout)
        )
    kinds = tuple(attacker_kinds if attacker_kinds is not None else sc.attacker_variant_kinds)
    a_mag = float(sc.attacker_variant_magnitude if attacker_magnitude is None else attacker_magnitude)
    attackers = [
        AttackerPlan(f"a{k:02d}_{model_id}", model_id, derive_seed(seed, "attacker", model_id), a_mag, kinds,
                     materials(model_id))
        for k, model_id in enumerate(sorted(present_in))
    ]
    return StudyPlan(seed, rooms, attackers, present_in)


def _materials_of(library: Mapping, seed: int, sharing: float):
    """model id -> its (slot, SKU) pairs that use shared SKUs (memoised; empty without sharing)."""
    from synthleak.assets.materials import UNIQUE, assign_materials

    @functools.cache
    def materials(model_id: str) -> tuple[tuple[str, str], ...]:
        if sharing <= 0.0:
            return ()
        assignment = assign_materials(library[model_id], seed, sharing)
        return tuple((slot, sku) for slot, sku in sorted(assignment.items()) if sku != UNIQUE)

    return materials


def draw_distractors(library: Mapping, selected: Sequence[str], materials, count: tuple[int, int],
                     rng: np.random.Generator) -> list[str]:
    """Distractor model ids for one room: furniture that is never an attacker object, drawn without
    replacement from look-alikes of the selected models (their categories, or sharing one of their SKUs);
    the rest of the library only when look-alikes run out. A distractor that does not fit the room (a vase
    without a table to stand on) is dropped by the composer, as any object."""
    lo, hi = count
    if hi <= 0:
        return []
    n = int(rng.integers(lo, hi + 1))
    chosen = set(selected)
    categories = {library[m].category for m in selected}
    skus = {sku for m in selected for _, sku in materials(m)}
    free = [m for m in sorted(library) if m not in chosen and not is_prop(library[m])]
    alike = [m for m in free if library[m].category in categories or skus & {s for _, s in materials(m)}]
    others = [m for m in free if m not in alike]
    picks: list[str] = []
    for group in (alike, others):
        order = [group[i] for i in rng.permutation(len(group))]
        picks += order[: n - len(picks)]
    return sorted(picks)


def _assign_hosts_only(
    rooms: list[list[str]], hosts: set[str], needs_host: set[str], rng: np.random.Generator
) -> list[list[str]]:
    """Independent per-room draws: add / swap in a host where a surface object has nothing to stand on."""
    out = []
    for room in rooms:
        room = list(room)
        if any(m in needs_host for m in room) and not any(m in hosts for m in room) and hosts:
            candidates = sorted(hosts)
            host = candidates[int(rng.integers(len(candidates)))]
            replaceable = [j for j, m in enumerate(room) if m not in needs_host]
            if replaceable:
                room[replaceable[int(rng.integers(len(replaceable)))]] = host
            else:
                room[-1] = host
        out.append(room)
    return out
