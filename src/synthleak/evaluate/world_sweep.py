"""Leakage against the hard-world knobs: presence precision / recall per tier at each swept value of
``material_sharing`` or ``clutter`` (rows tagged ``sweep_param`` / ``sweep_value`` by the study)."""

from __future__ import annotations

from collections.abc import Sequence

from synthleak.evaluate.tables import group_rows, precision_recall

WORLD_PARAMS = ("material_sharing", "clutter")


def leakage_vs_world(rows: Sequence[dict]) -> list[dict]:
    """Per (sweep_param, tier, aligner, thresholds, sweep_value): pooled presence P/R over the value's rooms."""
    out = []
    tagged = [r for r in rows if r.get("sweep_param") in WORLD_PARAMS]
    keys = ["sweep_param", "tier", "aligner", "delta_r_deg", "delta_t_m", "sweep_value"]
    for key, group in group_rows(tagged, keys).items():
        pr = precision_recall(group)
        out.append({**dict(zip(keys, key, strict=True)), "precision": pr["precision"], "recall": pr["recall"],
                    "fp": pr["fp"], "tp": pr["tp"], "n_pairs": len(group)})
    return out
