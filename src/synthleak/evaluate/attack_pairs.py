"""The attack/scoring join: every (room, attacker object) pair attacked from the logged server answers and
scored against the room's ground truth, one row per (tier, aligner, thresholds); plus where the pair's queries
went on the server (the recall and false-presence funnels)."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.attack.presence_features import attack_features
from synthleak.attack.run import run_attack
from synthleak.evaluate.lookalikes import absent_kind, lookalike_ids, top_instance
from synthleak.evaluate.score import score_placement
from synthleak.evaluate.shell_share import count_shell_top
from synthleak.localize.visibility import count_retrieving, read_image_instances


@dataclass(frozen=True)
class ServerLabels:
    """What the evaluation knows of one (tier, room) map: its 3D points per instance id and the instances each
    map image sees (each None without a local map, e.g. a study against a remote server)."""

    map_points: dict[int, int] | None
    visible: dict[str, set[int]] | None

    @classmethod
    def read(cls, map_dir: Path) -> ServerLabels:
        return cls(map_points_per_instance(map_dir), read_image_instances(map_dir))


def map_points_per_instance(map_dir: Path) -> dict[int, int] | None:
    """Number of the map's 3D points per instance id (``points_instance.json``), or None without a local map
    (a study against a remote server)."""
    path = map_dir / "points_instance.json"
    if not path.is_file():
        return None
    return dict(Counter(int(instance) for instance in json.loads(path.read_text()).values()))


def server_funnel(records: list[dict[str, Any]], gt_id: int | None, points: dict[int, int] | None,
                  lookalikes: dict[int, str], visible: dict[str, set[int]] | None = None
                  ) -> dict[str, int | None]:
    """Where a pair's queries go on the server. Present pairs: the map's 3D points on the room's instance, the
    queries whose retrieved map images see it (``visible``: the map's :mod:`~synthleak.localize.visibility`;
    None where unknown) and the localized queries whose PnP inliers lie mostly on it; absent pairs: the
    localized queries whose inliers lie mostly on a look-alike (an instance sharing a SKU or the category with
    the queried object)."""
    tops = [top_instance(q.get("inlier_instance_counts") or {}) for q in records if q["success"]]
    if gt_id is None:
        return {"map_points_on_target": None, "n_retrieved_target": None, "n_target_top": None,
                "n_lookalike_top": sum(1 for t in tops if t in lookalikes)}
    return {"map_points_on_target": None if points is None else points.get(int(gt_id), 0),
            "n_retrieved_target": count_retrieving(records, int(gt_id), visible),
            "n_target_top": sum(1 for t in tops if t == int(gt_id)), "n_lookalike_top": None}


def object_rows(attack: Any, obj: Mapping[str, Any], target: Any, local: Mapping[str, np.ndarray],
                object_from_local: np.ndarray | None, records: Mapping[tuple[str, str], list[dict[str, Any]]],
                rooms: Mapping[str, Mapping[str, Any]], room_objects: Mapping[str, Mapping[int, Any]],
                servers: Mapping[tuple[str, str], ServerLabels], magnitude: float | None = None,
                kind: str | None = None, ups: Mapping[tuple[str, str], tuple[Any, Any]] | None = None
                ) -> list[dict[str, Any]]:
    """The rows of one attacker object (``obj``: its ``index.json`` entry; ``target``: its instance) against
    every server of ``records`` ((tier, room) -> the object's logged queries), before the presence decision.

    ``local``: the attacker's local poses (frames without one were not registered by SfM: left out of the
    attack and counted); ``object_from_local``: the SfM model's scoring-only registration (None: oracle);
    ``attack``: the ``[attack]`` config (aligners, thresholds); ``rooms``: the rooms' ``index.json`` entries;
    ``room_objects``: each room's GT instances by id."""
    rows: list[dict[str, Any]] = []
    for tier, room in sorted(records):
        queries = records[(tier, room)]
        sent = {q["frame"] for q in queries}
        server = {q["frame"]: None if q["cam_from_world"] is None else np.array(q["cam_from_world"])
                  for q in queries if q["success"] and q["frame"] in local}
        local_sent = {f: p for f, p in local.items() if f in sent}
        gt_id = obj.get("present_in", {}).get(room)
        gt = room_objects[room].get(gt_id) if gt_id is not None else None
        labels = servers[(tier, room)]
        funnel = server_funnel(queries, gt_id if gt is not None else None, labels.map_points,
                               lookalike_ids(obj, rooms[room]), labels.visible)
        kind_of_pair = None if gt is not None else absent_kind(obj, rooms[room])
        for aligner in attack.aligners:
            alignments = [run_attack(local_sent, server, aligner, delta_r, delta_t, n_sent=len(local_sent),
                                     ups=(ups or {}).get((tier, room)))
                          for delta_r, delta_t in attack.thresholds]
            features = attack_features(local_sent, server, alignments, attack.thresholds)
            for (delta_r, delta_t), alignment, trial in zip(attack.thresholds, alignments, features, strict=True):
                estimate = alignment.scene_from_object if alignment.ok else None
                score = score_placement(
                    estimate, None if gt is None else gt.world_from_object,
                    None if gt is None else gt.extents, target.extents,
                    symmetry=(gt or target).symmetry, object_from_local=object_from_local)
                rows.append({
                    "room": room, "object": obj["id"], "model_id": obj["model_id"],
                    "category": target.category, "tier": tier, "aligner": aligner,
                    "delta_r_deg": float(delta_r), "delta_t_m": float(delta_t), "present_gt": gt is not None,
                    "eps": float(alignment.eps), "decision": False, "n_queries": len(sent),
                    "n_no_local_pose": len(sent) - len(local_sent), "n_localized": len(server), **funnel,
                    "n_shell_top": count_shell_top(q for q in queries if q["frame"] in server),
                    **score, "magnitude": magnitude, "kind": kind,
                    "absent_kind": kind_of_pair, **trial,
                })
    return rows
