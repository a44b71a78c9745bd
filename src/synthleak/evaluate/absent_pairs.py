"""Where false presence comes from: GT-absent pairs by kind (shares a SKU / same category / unrelated).

Results rows carry ``absent_kind`` (None for present pairs) and ``n_lookalike_top`` (localized attacker
queries whose PnP inliers lie mostly on a look-alike of the queried object; see
:mod:`synthleak.evaluate.lookalikes`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from synthleak.evaluate.lookalikes import ABSENT_KINDS
from synthleak.evaluate.tables import group_rows, markdown_table, precision_recall


def _main_rows(rows: Sequence[dict]) -> list[dict]:
    """Rows of the main study (not of a variant sweep)."""
    return [r for r in rows if r.get("magnitude") is None]


def absent_funnel(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Per tier (first aligner and thresholds of the rows): GT-absent pairs, those with a localized attacker
    query, those with a query localized mostly on a look-alike, those decided present; overall and per kind."""
    main = [r for r in _main_rows(rows) if not r.get("present_gt")]
    if not main:
        return []
    first = main[0]
    config = (first["aligner"], first["delta_r_deg"], first["delta_t_m"])
    out = []
    for (tier,), group in group_rows(main, ["tier"]).items():
        pairs = [r for r in group if (r["aligner"], r["delta_r_deg"], r["delta_t_m"]) == config]
        for kind in ("all", *ABSENT_KINDS):
            chosen = pairs if kind == "all" else [r for r in pairs if r.get("absent_kind") == kind]
            out.append({
                "tier": tier,
                "absent pairs": kind,
                "n": len(chosen),
                "a query localized": sum(1 for r in chosen if r["n_localized"] > 0),
                "localized on a look-alike": sum(1 for r in chosen if (r.get("n_lookalike_top") or 0) > 0),
                "queries localized": f"{sum(r['n_localized'] for r in chosen)}/{sum(r['n_queries'] for r in chosen)}",
                f"decided present ({config[0]}, {config[1]:g}°, {config[2]:g}m)": sum(
                    1 for r in chosen if r["decision"]),
            })
    return out


def absent_funnel_markdown(rows: Sequence[dict]) -> str:
    funnel = absent_funnel(rows)
    if not funnel:
        return "No GT-absent pairs.\n"
    return markdown_table(funnel, list(funnel[0]), digits=0)


def presence_by_absent_kind(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Per (tier, aligner, thresholds): recall, precision over all pairs, and for each kind of absent pair the
    false positives among them and the precision when only absent pairs of that kind are counted."""
    out = []
    for (tier, aligner, dr, dt), group in group_rows(_main_rows(rows), ["tier", "aligner", "delta_r_deg",
                                                                  "delta_t_m"]).items():
        present = [r for r in group if r["present_gt"]]
        overall = precision_recall(group)
        row: dict[str, Any] = {"tier": tier, "aligner": aligner, "δr, δt": f"{dr:g}°, {dt:g}m",
                               "R": overall["recall"], "P": overall["precision"]}
        for kind in ABSENT_KINDS:
            absent = [r for r in group if not r["present_gt"] and r.get("absent_kind") == kind]
            fp = sum(1 for r in absent if r["decision"])
            row[f"FP {kind}"] = f"{fp}/{len(absent)}"
            row[f"P {kind}"] = precision_recall(present + absent)["precision"] if absent else math.nan
        out.append(row)
    return out


def presence_by_absent_kind_markdown(rows: Sequence[dict]) -> str:
    """One table per aligner (rows: tier x thresholds)."""
    stats = presence_by_absent_kind(rows)
    if not stats:
        return "No results.\n"
    blocks = []
    for (aligner,), group in group_rows(stats, ["aligner"]).items():
        columns = [c for c in group[0] if c != "aligner"]
        blocks.append(f"**aligner `{aligner}`**\n\n" + markdown_table(group, columns, digits=2))
    return "\n".join(blocks)
