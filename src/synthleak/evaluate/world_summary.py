"""The world a study ran in: its hard-world knobs, what each room holds and how much furniture each
walk-through sees (from the GT instance masks)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from synthleak.core.dataset import load_sequence
from synthleak.evaluate.coverage import sequence_coverage
from synthleak.evaluate.tables import markdown_table


def world_summary(config: Any, rooms: Sequence[Mapping[str, Any]], scenes: Mapping[str, Path]) -> dict[str, Any]:
    """The knobs of ``config`` and, per room (``rooms``: the ``index.json`` entries; ``scenes``: room -> scene
    sequence), its instances and the furniture coverage of its frames."""
    sc, rc = config.scenes, config.render
    out = []
    for room in rooms:
        coverage = sequence_coverage(load_sequence(scenes[room["name"]]))
        out.append({"room": room["name"], "selected": len(room["objects"]),
                    "distractors": len(room.get("distractors", [])), "props": len(room.get("props", [])),
                    **{k: v for k, v in coverage.items() if k != "sequence"}})
    return {"knobs": {"material_sharing": sc.material_sharing, "distractors": list(sc.distractors),
                      "clutter": sc.clutter, "layout": sc.layout, "walkthrough": rc.walkthrough,
                      "genuine_closeup_fraction": rc.genuine_closeup_fraction},
            "rooms": out}


def world_markdown(world: Mapping[str, Any]) -> list[str]:
    """The report's section on the world of :func:`world_summary`."""
    knobs = ", ".join(f"{k} = {v}" for k, v in world["knobs"].items())
    columns = ["room", "selected", "distractors", "props", "frames", "median_coverage", "share_below_10pct",
               "closeups", "closeup_median_coverage"]
    return ["## The world\n",
            f"Difficulty knobs: {knobs}. Coverage: fraction of a frame's pixels on furniture and props (not the "
            "room shell), from the GT instance masks; `share_below_10pct`: walk-through frames under 10 %.\n",
            markdown_table(world["rooms"], columns, digits=3)]
