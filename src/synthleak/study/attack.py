"""The attack stage: every (room, attacker object) pair attacked from the query logs and scored."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.attack.gravity import local_ups, scene_ups
from synthleak.attack.local_poses import attacker_local_poses
from synthleak.attack.run import takes_up_directions
from synthleak.cache import cache_key, done_key
from synthleak.config import StudyConfig
from synthleak.core.dataset import load_sequence, read_index
from synthleak.evaluate.attack_pairs import ServerLabels, object_rows
from synthleak.evaluate.defense_online import without_defense
from synthleak.evaluate.query_log import read_query_log
from synthleak.evaluate.tables import apply_presence_decisions, read_results, write_results
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.paths import StudyPaths


def attack_rows(config: StudyConfig, paths: StudyPaths, logs: dict[tuple[str, str], Path],
                magnitude: float | None = None, kind: str | None = None, undefended: bool = False
                ) -> list[dict[str, Any]]:
    """One results row per (room, attacker object, tier, aligner, thresholds) of ``logs``, presence decided
    leave-one-scene-out and placement scored against the room's ground truth. The attacker objects are those
    of ``paths.dataset`` (a variant-sweep point's own; rows tagged ``magnitude`` and ``kind``). ``undefended``:
    attack the answers the server gave before its online defense refused some (the same logged queries)."""
    rooms = {room["name"]: room for room in read_index(paths.scene_dataset / "stages")["rooms"]}
    room_objects = {name: load_sequence(paths.scene(name)).objects_by_id() for name in rooms}
    by_object: dict[tuple[str, str], dict[str, list[dict]]] = {}  # each log parsed once, not once per object
    for name, log in logs.items():
        for q in read_query_log(log):
            q = without_defense(q) if undefended else q
            by_object.setdefault(name, {}).setdefault(q["attacker_object"], []).append(q)
    servers = {name: ServerLabels.read(paths.map_dir(*name)) for name in logs}
    objects = []
    for obj in read_index(paths.dataset / "stages")["attacker_objects"]:
        seq = load_sequence(paths.attacker(obj["id"]))
        local, object_from_local = attacker_local_poses(config.attack.local_model, seq, paths.sfm_dir(obj["id"]),
                                                        config.seed)
        objects.append((obj, seq.objects_by_id()[seq.target_instance_id], local, object_from_local))
    ups = attacker_ups(config, objects, by_object)
    rows: list[dict[str, Any]] = []
    for obj, target, local, object_from_local in objects:
        records = {name: by_object.get(name, {}).get(obj["id"], []) for name in logs}
        rows += object_rows(config.attack, obj, target, local, object_from_local, records, rooms, room_objects,
                            servers, magnitude, kind, ups.get(obj["id"]))
    return apply_presence_decisions(rows, config.attack.presence)


def attacker_ups(config: StudyConfig, objects: list[tuple[Any, Any, dict[str, Any], Any]],
                 by_object: dict[tuple[str, str], dict[str, list[dict]]]
                 ) -> dict[str, dict[tuple[str, str], tuple[Any, Any]]]:
    """Per attacked object and server, the (local, scene) up directions the ``upright`` aligner needs, from the
    attacker's data alone (:mod:`synthleak.attack.gravity`; the scene's from Alg. 1 at the tightest thresholds);
    empty when no configured aligner takes them."""
    if not any(takes_up_directions(aligner) for aligner in config.attack.aligners):
        return {}
    local_by_object = {obj["id"]: local for obj, _, local, _ in objects}
    local_up = local_ups(local_by_object)
    answers = {name: {obj: {q["frame"]: None if not q["success"] or q["cam_from_world"] is None
                            else np.array(q["cam_from_world"]) for q in queries}
                      for obj, queries in per_object.items() if obj is not None}
               for name, per_object in by_object.items()}
    delta_r, delta_t = min(config.attack.thresholds)
    scene = scene_ups(local_by_object, local_up, answers, delta_r, delta_t)
    return {obj: {name: (up, scene_up) for name, scene_up in scene.items()} for obj, up in local_up.items()}


def _digest(log: Path) -> str | None:
    """The sha256 of a query log's bytes (None while it is missing)."""
    return hashlib.sha256(log.read_bytes()).hexdigest() if log.is_file() else None


class AttackStage(Stage):
    """``results/results.{csv,json}``, keyed by the query logs (their content keys and their bytes: a log redone
    under the same key, ``--force queries`` after a code change, re-runs the attack) and the ``[attack]`` section
    (a threshold change re-runs only the attack and the report)."""

    name = "attack"
    reads = ("queries", "sfm")

    def units(self, ctx: StudyContext) -> list[Unit]:
        query_keys = [(done_key(log.parent), _digest(log)) for _, log in sorted(ctx.logs().items())]
        return [Unit(ctx.paths.results, cache_key("attack", query_keys, ctx.section("attack")))]

    def make(self, ctx: StudyContext, todo: list[Unit]) -> list[dict[str, Any]]:
        if not todo:
            return read_results(ctx.paths.results / "results.json")
        rows = attack_rows(ctx.config, ctx.paths, ctx.logs())
        write_results(rows, ctx.paths.results)
        return rows
