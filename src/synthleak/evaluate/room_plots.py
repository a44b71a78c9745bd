"""Top-down plot per room of a study: GT boxes and the estimates the attack decided present."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.core.dataset import load_sequence
from synthleak.evaluate.plots import plot_room_topdown
from synthleak.localize.servers import study_servers


def room_plots(config: Any, rooms: Sequence[Mapping[str, Any]], scenes: Mapping[str, Path],
               rows: Sequence[dict[str, Any]], out_dir: Path) -> list[Path]:
    """``<room>_topdown.png`` in ``out_dir`` per room (``rooms``: the ``index.json`` entries; ``scenes``: room ->
    scene sequence): the first server (tier), last aligner and middle thresholds of ``config``."""
    tier, aligner = study_servers(config.localize)[0].name, config.attack.aligners[-1]
    delta_r, delta_t = config.attack.thresholds[len(config.attack.thresholds) // 2]
    out = []
    for room in rooms:
        scene = load_sequence(scenes[room["name"]])
        objects = [(f"{o.model_id}#{o.instance_id}", o.world_from_object, o.extents)
                   for o in scene.objects if o.role == "object"]
        size = np.asarray(room["size"][:2], dtype=float)  # the room interior is centred on the origin
        chosen = [r for r in rows if r["room"] == room["name"] and r["tier"] == tier and r["aligner"] == aligner
                  and r["delta_r_deg"] == delta_r and r["delta_t_m"] == delta_t and r["decision"]
                  and r["scene_from_object_est"] is not None]
        estimates = []
        for r in chosen:
            gt_name = next((name for name, *_ in objects if name.startswith(f"{r['model_id']}#")), r["object"])
            extents = next((e for name, _, e in objects if name == gt_name), (0.5, 0.5, 0.5))
            estimates.append((gt_name, np.array(r["scene_from_object_est"]), extents))
        cams = np.array([scene.pose(f) for f in scene.frames])
        out.append(plot_room_topdown(
            size, objects, estimates, cameras=cams, out=out_dir / f"{room['name']}_topdown.png",
            room_min=-size / 2, title=f"{room['name']}: GT (solid) vs decided-present estimates (dashed), "
            f"{tier}/{aligner} {delta_r:g}°/{delta_t:g} m"))
    return out
