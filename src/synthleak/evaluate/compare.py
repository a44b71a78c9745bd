"""Attack variants side by side on the same queries: aligners, or local models (oracle vs SfM).

Every variant's rows come from the same query logs, so the (room, object) pairs are the same. Per group (tier,
thresholds[, aligner]) and variant: presence precision/recall, the share of GT-present pairs placed within
``success`` (degrees, metres; a pair left unplaced fails), and the median errors over the GT-present pairs that
*every* variant placed (``n_common``), so one variant placing an extra hard pair does not move its medians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from synthleak.evaluate.tables import _fmt, _thr_label, group_rows, precision_recall, sort_key

PAIR_FIELDS = ("room", "object", "tier", "delta_r_deg", "delta_t_m", "magnitude", "kind")
"""What identifies one attack of a (room, object) pair across variants."""


def _err(row: dict, key: str) -> float:
    value = row.get(key)
    return math.inf if value is None or not math.isfinite(float(value)) else float(value)


def side_by_side(
    rows_by_variant: Mapping[str, Sequence[dict]],
    keys: Sequence[str] = ("tier", "delta_r_deg", "delta_t_m"),
    success: tuple[float, float] = (10.0, 0.25),
) -> list[dict[str, Any]]:
    """One dict per (group of ``keys``, variant), groups in sorted order, variants in the given order.

    A pair is one attack of one (room, object): ``PAIR_FIELDS`` plus ``aligner`` where ``keys`` holds it (each
    variant's rows must have one aligner per group otherwise, as when the variants are the aligners)."""
    pair = tuple(f for f in (*PAIR_FIELDS, "aligner") if f in PAIR_FIELDS or f in keys)
    grouped = {name: group_rows(rows, keys) for name, rows in rows_by_variant.items()}
    groups = sorted({g for by in grouped.values() for g in by}, key=sort_key)
    out = []
    for group in groups:
        present = {name: {tuple(r.get(f) for f in pair): r for r in by.get(group, []) if r["present_gt"]}
                   for name, by in grouped.items()}
        common = set.intersection(*[{p for p, r in rows.items() if math.isfinite(_err(r, "rot_err_deg"))}
                                    for rows in present.values()]) if present else set()
        for name, by in grouped.items():
            rows = by.get(group, [])
            pres = present[name]
            ok = [_err(r, "rot_err_deg") <= success[0] and _err(r, "trans_err_m") <= success[1]
                  for r in pres.values()]
            rot = [_err(pres[p], "rot_err_deg") for p in common]
            trans = [_err(pres[p], "trans_err_m") for p in common]
            pr = precision_recall(rows)
            out.append({
                **dict(zip(keys, group, strict=True)), "variant": name, "n_present": len(pres),
                "n_placed": sum(1 for r in pres.values() if math.isfinite(_err(r, "rot_err_deg"))),
                "precision": pr["precision"], "recall": pr["recall"],
                "success": float(np.mean(ok)) if ok else math.nan, "n_common": len(common),
                "median_rot_err_deg": float(np.median(rot)) if rot else math.nan,
                "median_trans_err_m": float(np.median(trans)) if trans else math.nan,
            })
    return out


def side_by_side_markdown(
    rows_by_variant: Mapping[str, Sequence[dict]],
    keys: Sequence[str] = ("tier", "delta_r_deg", "delta_t_m"),
    success: tuple[float, float] = (10.0, 0.25),
    variant_label: str = "variant",
) -> str:
    """:func:`side_by_side` as a markdown table (thresholds as one column)."""
    stats = side_by_side(rows_by_variant, keys, success)
    shown = [k for k in keys if k not in ("delta_r_deg", "delta_t_m")]
    header = [*shown, "δr, δt", variant_label, "present", "placed", "P", "R",
              f"succ {success[0]:g}°/{success[1]:g}m", "common", "med rot °", "med trans m"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for s in stats:
        cells = [str(s[k]) for k in shown]
        cells += [_thr_label(s["delta_r_deg"], s["delta_t_m"]) if "delta_r_deg" in s else "all", str(s["variant"]),
                  str(s["n_present"]), str(s["n_placed"]), _fmt(s["precision"]), _fmt(s["recall"]),
                  _fmt(s["success"]), str(s["n_common"]), _fmt(s["median_rot_err_deg"]),
                  _fmt(s["median_trans_err_m"], 3)]
        lines.append("| " + " | ".join(cells) + " |")
    if not stats:
        lines.append("| " + " | ".join(["–"] * len(header)) + " |")
    return "\n".join(lines) + "\n"


__all__ = ["PAIR_FIELDS", "side_by_side", "side_by_side_markdown"]
