"""Which images a study sends to each room's server (its query plan)."""

from __future__ import annotations

from typing import Any

from synthleak.core.dataset import load_sequence, read_index
from synthleak.study.context import StudyContext


def query_plan(ctx: StudyContext, room: str) -> list[dict]:
    """Every image sent to one room's server: its genuine held-out frames (unless a variant-sweep point) and
    every attacker frame (``attack.queries_per_object`` of them, spread evenly around each orbit).

    ``sequence`` is the sequence folder relative to its dataset; ``genuine`` says which one."""
    plan = []
    if ctx.genuine:
        scene = load_sequence(ctx.paths.scene(room))
        closeups = set(scene.split.get("closeup", []))
        plan += [{"sequence": f"scenes/{room}", "frame": f, "genuine": True, "attacker_object": None}
                 | ({"closeup": f in closeups} if closeups else {}) for f in scene.split["query"]]
    per_object = ctx.config.attack.queries_per_object
    for obj in read_index(ctx.paths.dataset / "stages")["attacker_objects"]:
        seq = load_sequence(ctx.paths.attacker(obj["id"]))
        frames = seq.frames
        if 0 < per_object < len(frames):  # spread evenly around the orbit
            step = len(frames) / per_object
            frames = [frames[int(k * step)] for k in range(per_object)]
        plan += [{"sequence": f"attackers/{obj['id']}", "frame": f, "genuine": False,
                  "attacker_object": obj["id"]} for f in frames]
    return plan


def query_plans(ctx: StudyContext) -> dict[str, list[dict]]:
    """Each room's query plan, with ``_image`` (the image's path) and ``_camera`` (its intrinsics) added."""
    sequences: dict[Any, Any] = {}
    plans = {}
    for room in sorted({room for _, room in ctx.servers()}):
        plan = query_plan(ctx, room)
        for item in plan:
            folder = ctx.paths.sequence(item["sequence"], item["genuine"])
            seq = sequences.get(folder) or sequences.setdefault(folder, load_sequence(folder))
            item |= {"_image": str(seq.image_path(item["frame"])), "_camera": seq.camera_of(item["frame"])}
        plans[room] = plan
    return plans
