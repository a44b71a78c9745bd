"""Accuracy of the genuine (held-out) queries per server: the server works as a server should."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.core.dataset import load_sequence
from synthleak.evaluate.query_log import read_query_log
from synthleak.geometry.poses import camera_centre, rotation_error_deg


def genuine_localization(logs: Mapping[tuple[str, str], Path], scenes: Mapping[str, Path]) -> list[dict[str, Any]]:
    """Per (tier, room) of ``logs`` (query log paths): genuine queries sent, localized (close-ups apart) and the
    median rotation / camera-centre errors against the room's GT poses (``scenes``: room -> scene sequence)."""
    out = []
    for (tier, room), log in sorted(logs.items()):
        scene = load_sequence(scenes[room])
        genuine = [q for q in read_query_log(log) if q["genuine"]]
        closeups = [q for q in genuine if q.get("closeup")]
        rot, trans = [], []
        for q in genuine:
            if q["success"]:
                est, gt = np.array(q["cam_from_world"]), scene.pose(q["frame"])
                rot.append(rotation_error_deg(est[:3, :3], gt[:3, :3]))
                trans.append(float(np.linalg.norm(camera_centre(est) - camera_centre(gt))))
        out.append({"tier": tier, "room": room, "n": len(genuine), "localized": len(rot),
                    "closeups": len(closeups), "closeups_localized": sum(1 for q in closeups if q["success"]),
                    "median_rot_err_deg": float(np.median(rot)) if rot else float("nan"),
                    "median_trans_err_m": float(np.median(trans)) if trans else float("nan")})
    return out
