"""Why an absent object can look present: the room's look-alikes of an attacker object, from ``index.json``.

For an attacker object and a room that does not hold it, a room instance is a *look-alike* when it shares a
material SKU with the attacked model (the same printed laminate, fabric, ...) or is of the same category (a
different product of the same kind). The kind of an absent pair is ``shares_sku`` when the room holds an
instance sharing a SKU, else ``same_category`` when it holds one of the category, else ``unrelated``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

ABSENT_KINDS = ("shares_sku", "same_category", "unrelated")


def room_instances(room: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Every placed non-shell instance of a room entry of ``index.json``: selected objects, distractors, props."""
    return [*room.get("objects", []), *room.get("distractors", []), *room.get("props", [])]


def _skus(entry: Mapping[str, Any]) -> set[str]:
    return set(entry.get("skus", {}).values())


def lookalike_ids(attacker: Mapping[str, Any], room: Mapping[str, Any]) -> dict[int, str]:
    """Instance id -> ``shares_sku`` / ``same_category`` for the room's look-alikes of ``attacker`` (an
    ``attacker_objects`` entry), its own model's instances excluded."""
    skus = _skus(attacker)
    out = {}
    for inst in room_instances(room):
        if inst["model_id"] == attacker["model_id"]:
            continue
        if skus & _skus(inst):
            out[int(inst["instance_id"])] = "shares_sku"
        elif inst["category"] == attacker["category"]:
            out[int(inst["instance_id"])] = "same_category"
    return out


def absent_kind(attacker: Mapping[str, Any], room: Mapping[str, Any]) -> str | None:
    """The kind of the pair (``None`` when the room holds the attacked model: a present pair)."""
    if any(inst["model_id"] == attacker["model_id"] for inst in room.get("objects", [])):
        return None
    kinds = set(lookalike_ids(attacker, room).values())
    return next((k for k in ABSENT_KINDS if k in kinds), "unrelated")


def top_instance(counts: Mapping[str, int]) -> int | None:
    """The instance id with most PnP inliers (ties: the smaller id), None without inliers."""
    if not counts:
        return None
    return int(max(counts, key=lambda k: (counts[k], -int(k))))
