"""The query log: one JSON line per image sent to a (tier, room) server, what the attacker saw and, from an
in-process server, the server-side labels the evaluation reads (inliers per instance, retrieved map images,
the online defense's decision)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.evaluate.defense_online import localized_without_defense, log_fields
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.wire_pose import as_served


def query_line(item: Mapping[str, Any], tier: str, room: str, result: Any, defense: DefensePolicy | None,
               remote: bool, served: bool = False) -> str:
    """The log line of one query: the plan entry ``item`` (its ``_``-prefixed keys left out) and the server's
    ``result``; ``remote``: an HTTP answer (it names no retrieved map images, so the funnel step stays unknown).
    ``served``: the pose came over HTTP already; an in-process one is logged as the service protocol would carry
    it (:func:`~synthleak.localize.wire_pose.as_served`), so in-process and HTTP studies log the same bits."""
    plan = {k: v for k, v in item.items() if not k.startswith("_")}
    pose = result.cam_from_world
    if pose is not None and not served:
        pose = as_served(pose)
    return json.dumps({
        **plan, "tier": tier, "room": room, "success": bool(result.success),
        "cam_from_world": None if pose is None else np.asarray(pose).tolist(),
        "num_inliers": int(getattr(result, "num_inliers", 0) or 0),
        "inlier_instance_counts": {str(k): int(v) for k, v in
                                   sorted((getattr(result, "inlier_instance_counts", None) or {}).items())},
        **log_fields(result, defense),
        **({} if remote else {"retrieved": list(result.retrieved)}),
    }, sort_keys=True)


def read_query_log(path: Path) -> list[dict[str, Any]]:
    """The query records of one (tier, room)."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def defense_queries(logs: Mapping[tuple[str, str], Path]) -> list[dict[str, Any]]:
    """The logged query decisions in the form the offline defense sweep reads (a query the online defense
    refused counts as localized without the defense)."""
    return [{"tier": q["tier"], "room": q["room"], "genuine": q["genuine"], "attacker_object": q["attacker_object"],
             "success_without_defense": localized_without_defense(q),
             "inlier_instance_counts": q["inlier_instance_counts"]}
            | ({"closeup": q["closeup"]} if "closeup" in q else {})
            for _, log in sorted(logs.items()) for q in read_query_log(log)]
