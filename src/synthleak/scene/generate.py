"""Write every USD stage of a study: ``room_XXX.usda``, ``attacker_<id>.usda``, ``textures/`` and
``index.json`` (layout in docs/DATASET.md, ``stages/index.json``).

Re-running gives byte-identical files. A stage is skipped when the previous ``index.json`` lists it with the
same ``plan_key`` (hash of its plan entry, the model definition files and :data:`STAGE_FORMAT`) and the file
on disk still has the recorded SHA-256 (and its textures exist).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from synthleak.config import StudyConfig
from synthleak.core.dataset import INDEX_NAME, DatasetError, read_index
from synthleak.paths import scenes_usd_dir
from synthleak.progress import progress_display
from synthleak.scene.attacker_settings import SETTINGS_FORMAT
from synthleak.scene.plan import ATTACKER_TARGET_ID, AttackerPlan, RoomPlan, StudyPlan, plan_study
from synthleak.scene.usd_write import write_stage

STAGE_FORMAT = 1
"""Bump when the composer's output changes for the same plan (invalidates skip keys)."""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _model_digest(library: Mapping, model_ids: Sequence[str]) -> dict[str, str]:
    out = {}
    for mid in sorted(set(model_ids)):
        source = Path(library[mid].source)
        out[mid] = hashlib.sha256(source.read_bytes()).hexdigest() if source.is_file() else mid
    return out


def _styles_digest() -> str:
    digest = hashlib.sha256()
    for name in ("room_styles.toml", "attacker_hall.toml"):
        digest.update((scenes_usd_dir() / name).read_bytes())
    return digest.hexdigest()


def _non_default(entry: Any) -> Any:
    """Plain data of a plan dataclass without the fields left at their defaults (recursively), so a knob
    added with a default that keeps the old behaviour keeps the old plans' keys."""
    if dataclasses.is_dataclass(entry):
        out = {}
        for f in dataclasses.fields(entry):
            value = getattr(entry, f.name)
            if f.default is not dataclasses.MISSING and value == f.default:
                continue
            out[f.name] = _non_default(value)
        return out
    if isinstance(entry, list | tuple):
        return [_non_default(v) for v in entry]
    return entry


def _plan_key(entry: Any, library: Mapping, model_ids: Sequence[str], seed: int) -> str:
    payload = {
        "format": STAGE_FORMAT,
        "seed": seed,
        "plan": _non_default(entry),
        "models": _model_digest(library, model_ids),
        "styles": _styles_digest(),
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _textures_present(stage: Path) -> bool:
    refs = re.findall(r"@(\./textures/[^@]+)@", stage.read_text())
    return all((stage.parent / ref).is_file() for ref in refs)


def _reusable(old: dict[str, Any] | None, key: str, path: Path) -> bool:
    return (
        old is not None
        and old.get("plan_key") == key
        and path.is_file()
        and old.get("sha256") == _sha256(path)
        and _textures_present(path)
    )


def _load_old_index(out_dir: Path) -> dict[str, Any]:
    """The previous ``index.json`` (:func:`synthleak.core.dataset.read_index`); none or a malformed one: ``{}``
    (every stage is rebuilt)."""
    try:
        return read_index(out_dir)
    except (OSError, DatasetError):
        return {}


def _instance_entry(placed) -> dict[str, Any]:
    """index.json entry of one placed instance (``skus``: slot -> shared SKU id, only when it uses any)."""
    entry = {
        "instance_id": placed.instance_id,
        "model_id": placed.model_id,
        "name": placed.name,
        "category": placed.category,
        "support": placed.support,
        "variant": placed.variant_params,
    }
    skus = placed.variant_params.get("materials", {})
    return entry | ({"skus": dict(skus)} if skus else {})


def _room_entry(plan: RoomPlan, library: Mapping, out_dir: Path) -> dict[str, Any]:
    from synthleak.scene.compose import compose_room

    spec = compose_room(plan, library)
    path = out_dir / f"{plan.name}.usda"
    write_stage(spec, path)
    by_id = {o.instance_id: o for o in spec.objects}
    kinds: dict[str, list[dict[str, Any]]] = {"selected": [], "distractor": []}
    for obj in plan.objects:
        placed = by_id.get(obj.instance_id)
        if placed is not None:
            kinds[obj.kind].append(_instance_entry(placed))
    dropped = [
        {"instance_id": o.instance_id, "model_id": o.model_id}
        for o in plan.objects
        if o.instance_id not in by_id
    ]
    entry = {
        "name": plan.name,
        "stage": path.name,
        "size": list(plan.size),
        "style": spec.metadata["style"],
        "seed": plan.seed,
        "lights": len(spec.lights),
        "objects": kinds["selected"],
        "dropped": dropped,
        "supported_by": spec.metadata["supported_by"],
        "sha256": _sha256(path),
    }
    props = [_instance_entry(o) for o in spec.objects if o.role == "prop"]
    if kinds["distractor"] or props or plan.layout != "scatter":  # the clean world's index keeps its bytes
        entry |= {"distractors": kinds["distractor"], "props": props, "layout": plan.layout}
    return entry


def _attacker_entry(plan: AttackerPlan, library: Mapping, seed: int, out_dir: Path, hall_cache: list) -> dict:
    from synthleak.scene.attacker_env import compose_attacker

    spec = compose_attacker(plan, library, seed)  # its own setting (scene.attacker_settings)
    path = out_dir / plan.stage
    write_stage(spec, path)
    target = next(o for o in spec.objects if o.instance_id == ATTACKER_TARGET_ID)
    entry = {
        "id": plan.object_id,
        "model_id": plan.model_id,
        "category": target.category,
        "support": target.support,
        "stage": path.name,
        "setting": spec.metadata["style"],
        "target_instance_id": ATTACKER_TARGET_ID,
        "variant": target.variant_params,
        "sha256": _sha256(path),
    }
    return entry | ({"skus": dict(plan.materials)} if plan.materials else {})


def _run(
    tasks: list[tuple[str, str, Callable[[], dict]]], old: Mapping[str, dict], progress: bool
) -> dict[str, dict]:
    """Run (name, plan_key, build) tasks, reusing old entries whose stage is unchanged on disk."""
    out: dict[str, dict] = {}
    with progress_display(progress) as bar:
        task_id = bar.add_task("stages", total=len(tasks))
        for name, key, build in tasks:
            bar.update(task_id, description=f"stages {name}")
            previous = old.get(name)
            stage = previous.get("_path") if previous else None
            if previous is not None and stage is not None and _reusable(previous, key, Path(stage)):
                entry = {k: v for k, v in previous.items() if k != "_path"}
            else:
                entry = build()
            entry["plan_key"] = key
            out[name] = entry
            bar.advance(task_id)
    return out


def _hard(scenes) -> bool:
    """Any hard-world knob set (the clean world's index.json keeps its bytes)."""
    return bool(scenes.material_sharing or max(scenes.distractors) or scenes.clutter or scenes.layout != "scatter")


def write_study_stages(
    config: StudyConfig,
    out_dir: Path,
    *,
    attacker_magnitude: float | None = None,
    attacker_kinds: Sequence[str] | None = None,
    progress: bool = True,
) -> Path:
    """Compose and write all stages of ``config`` into ``out_dir``; returns the path of ``index.json``.

    ``attacker_magnitude`` / ``attacker_kinds`` override the config's attacker variant settings (a
    magnitude sweep); the attacker variant seeds stay the same, so sweep variants lie on one line.
    """
    from synthleak.assets.library import load_library

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    library = load_library()
    plan: StudyPlan = plan_study(
        config, library, attacker_magnitude=attacker_magnitude, attacker_kinds=attacker_kinds
    )
    old_index = _load_old_index(out_dir)
    old_rooms = {
        r["name"]: {**r, "_path": str(out_dir / r["stage"])}
        for r in old_index.get("rooms", [])
        if isinstance(r, dict) and "name" in r and "stage" in r
    }
    old_attackers = {
        a["id"]: {**a, "_path": str(out_dir / a["stage"])}
        for a in old_index.get("attacker_objects", [])
        if isinstance(a, dict) and "id" in a and "stage" in a
    }

    room_tasks = [
        (
            room.name,
            _plan_key(room, library, [o.model_id for o in room.objects], plan.seed),
            (lambda room=room: _room_entry(room, library, out_dir)),
        )
        for room in plan.rooms
    ]
    hall_cache: list = []
    attacker_tasks = [
        (
            a.object_id,
            _plan_key((a, SETTINGS_FORMAT), library, [a.model_id], plan.seed),
            (lambda a=a: _attacker_entry(a, library, plan.seed, out_dir, hall_cache)),
        )
        for a in plan.attackers
    ]
    rooms = _run(room_tasks, old_rooms, progress)
    attackers = _run(attacker_tasks, old_attackers, progress)

    by_model = {a.model_id: a.object_id for a in plan.attackers}
    present_in: dict[str, dict[str, int]] = {a.object_id: {} for a in plan.attackers}
    for room in rooms.values():
        for obj in room["objects"]:
            obj["attacker_object"] = by_model[obj["model_id"]]
            present_in[obj["attacker_object"]][room["name"]] = obj["instance_id"]
    for object_id, entry in attackers.items():
        entry["present_in"] = dict(sorted(present_in[object_id].items()))
    sc = config.scenes
    index = {
        "format": STAGE_FORMAT,
        "seed": plan.seed,
        "study": config.name,
        "scene_variant_magnitude": sc.scene_variant_magnitude,
        "attacker_variant_magnitude": plan.attackers[0].magnitude
        if plan.attackers
        else sc.attacker_variant_magnitude,
        "attacker_variant_kinds": list(plan.attackers[0].kinds)
        if plan.attackers
        else list(sc.attacker_variant_kinds),
        "distinct_objects": len(plan.attackers),
        **({"material_sharing": sc.material_sharing, "distractors": list(sc.distractors), "clutter": sc.clutter,
            "layout": sc.layout} if _hard(sc) else {}),
        "rooms": [rooms[r.name] for r in plan.rooms],
        "attacker_objects": [attackers[a.object_id] for a in plan.attackers],
    }
    path = out_dir / INDEX_NAME
    tmp = path.with_name(INDEX_NAME + ".tmp")
    tmp.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)
    return path
