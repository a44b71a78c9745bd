"""The query defense online (paper Sec. 6): what it costs the attack and genuine users on the same queries.

With ``[defense] enabled = true`` a study's in-process localizers run the
:class:`~synthleak.localize.defense.DefensePolicy` on every query, so each query record holds the served
answer (``success``, ``cam_from_world``: a refused query is "not localized") plus, from the server's side,
``defense_accepted`` (the policy's decision; None when PnP did not localize the query) and, for a refused
query, ``withheld_cam_from_world`` (the pose PnP found and the server withheld).
:func:`without_defense` rebuilds the undefended answer of the very same query, so the attack runs with and
without the defense on the same queries without localizing twice. A remote server (``--server URL``)
applies its own policy and tells the client only success and pose: its records carry no decision, and the
with/without comparison needs the in-process server.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from synthleak.evaluate.defense_sweep import passes_defense
from synthleak.evaluate.tables import group_rows, placement_stats, precision_recall
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.wire_pose import as_served


def online_policy(defense: Any) -> DefensePolicy | None:
    """The policy a study's server applies (``[defense]`` of its config), or None when not enabled."""
    return DefensePolicy.from_config(defense) if defense.enabled else None


def log_fields(result: Any, policy: DefensePolicy | None) -> dict[str, Any]:
    """What a query record gains from an in-process server running ``policy`` (nothing without one: pass None
    for an HTTP answer, which carries no decision)."""
    if policy is None or not policy.enabled:
        return {}
    decision = getattr(result, "defense", None)
    fields: dict[str, Any] = {"defense_accepted": None if decision is None else bool(decision.accepted)}
    if result.withheld_cam_from_world is not None:  # as the server would have sent it without the defense
        withheld = as_served(result.withheld_cam_from_world)
        fields["withheld_cam_from_world"] = [[float(v) for v in row] for row in withheld]
    return fields


def holds_decisions(records: Sequence[Mapping[str, Any]]) -> bool:
    """True when the records come from a server that ran the defense in process (decisions logged)."""
    return any("defense_accepted" in q for q in records)


def without_defense(record: Mapping[str, Any]) -> dict[str, Any]:
    """The record as the server would have answered without the defense (the same query)."""
    out = dict(record)
    withheld = out.pop("withheld_cam_from_world", None)
    if withheld is not None:
        out["success"], out["cam_from_world"] = True, withheld
    return out


def localized_without_defense(record: Mapping[str, Any]) -> bool:
    """True when PnP localized the query (whatever the defense then answered)."""
    return bool(record["success"]) or record.get("withheld_cam_from_world") is not None


def online_vs_offline(records: Sequence[Mapping[str, Any]], min_fraction: float, min_instances: int
                      ) -> dict[str, Any]:
    """Each logged online decision against the offline sweep's rule replayed on the logged inlier counts
    (:func:`~synthleak.evaluate.defense_sweep.passes_defense`, same X and k)."""
    checked = [q for q in records if q.get("defense_accepted") is not None]
    differ = [q for q in checked if bool(q["defense_accepted"]) != passes_defense(
        q["inlier_instance_counts"], min_fraction, min_instances)]
    served = [q for q in records if "defense_accepted" in q and bool(q["success"]) != bool(
        q["defense_accepted"])]
    return {"n_decisions": len(checked), "n_differ": len(differ), "n_served_differ": len(served),
            "differ": [(q["tier"], q["room"], q.get("sequence"), q["frame"]) for q in differ[:10]]}


def _share(part: int, whole: int) -> float:
    return part / whole if whole else math.nan


def refused_shares(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Per tier (and ``all``): among the queries PnP localized, the share the defense refused; genuine
    walk-through frames, genuine close-ups and attacker queries separately."""
    localized = [q for q in records if q.get("defense_accepted") is not None]
    out = []
    groups = group_rows(localized, ["tier"])
    for (tier,), group in [*groups.items(), (("all",), localized)]:
        row: dict[str, Any] = {"tier": tier}
        kinds = {"genuine": [q for q in group if q["genuine"]],
                 "walkthrough": [q for q in group if q["genuine"] and not q.get("closeup")],
                 "closeup": [q for q in group if q["genuine"] and q.get("closeup")],
                 "attacker": [q for q in group if not q["genuine"]]}
        for name, qs in kinds.items():
            refused = sum(1 for q in qs if not q["defense_accepted"])
            row[f"n_{name}"] = len(qs)
            row[f"{name}_refused"] = _share(refused, len(qs))
        out.append(row)
    return out


def attack_with_and_without(rows_without: Sequence[dict], rows_with: Sequence[dict],
                            thresholds: Sequence[tuple[float, float]]) -> list[dict[str, Any]]:
    """Per attack configuration: presence P/R, attacker queries localized and placement of the GT-present
    pairs (median errors, success at ``thresholds``), ``<name> without`` and ``<name> with`` the defense."""
    place = {name: {tuple(s[k] for k in _KEYS): s for s in placement_stats(rows, thresholds=thresholds)}
             for name, rows in (("without", rows_without), ("with", rows_with))}
    grouped = {"without": group_rows(rows_without, _KEYS), "with": group_rows(rows_with, _KEYS)}
    out = []
    for key in grouped["without"]:
        row: dict[str, Any] = dict(zip(_KEYS, key, strict=True))
        for name in ("without", "with"):
            rows = grouped[name].get(key, [])
            pr = precision_recall(rows)
            stat = place[name].get(key, {})
            row[f"P {name}"], row[f"R {name}"] = pr["precision"], pr["recall"]
            row[f"localized {name}"] = sum(r["n_localized"] for r in rows)
            row[f"med rot ° {name}"] = stat.get("median_rot_err_deg", math.nan)
            row[f"med trans m {name}"] = stat.get("median_trans_err_m", math.nan)
            for dr, dt in thresholds:
                row[f"succ {dr:g}°/{dt:g}m {name}"] = stat.get(f"success_{dr:g}deg_{dt:g}m", math.nan)
        out.append(row)
    return out


_KEYS = ["tier", "aligner", "delta_r_deg", "delta_t_m"]


def _pair(row: Mapping[str, Any], name: str, digits: int) -> str:
    def cell(value: Any) -> str:
        if isinstance(value, float):
            return "–" if math.isnan(value) else "∞" if math.isinf(value) else f"{value:.{digits}f}"
        return str(value)

    return f"{cell(row[f'{name} without'])} → {cell(row[f'{name} with'])}"


def comparison_markdown(compare: Sequence[Mapping[str, Any]], thresholds: Sequence[tuple[float, float]]) -> str:
    """:func:`attack_with_and_without` as one markdown table, each cell ``without → with``."""
    succ = [(f"succ {dr:g}°/{dt:g}m", 2) for dr, dt in thresholds]
    columns = [("P", 2), ("R", 2), ("localized", 0), ("med rot °", 1), ("med trans m", 3), *succ]
    lines = ["| tier | aligner | δr, δt | " + " | ".join(c for c, _ in columns) + " |",
             "|" + "---|" * (3 + len(columns))]
    for r in compare:
        cells = [str(r["tier"]), str(r["aligner"]), f"{r['delta_r_deg']:g}°, {r['delta_t_m']:g}m"]
        lines.append("| " + " | ".join(cells + [_pair(r, c, d) for c, d in columns]) + " |")
    return "\n".join(lines) + "\n"


def report_section(defense: Any, records: Sequence[Mapping[str, Any]], rows_without: Sequence[dict] | None,
                   rows_with: Sequence[dict], thresholds: Sequence[tuple[float, float]], results: Path
                   ) -> list[str]:
    """Report lines for a study run with the defense online; writes ``results/defense_online.json`` and
    ``results/results_no_defense.{csv,json}`` (the attack on the answers before the defense).
    ``rows_without`` is None when the logs hold no decisions (a remote server)."""
    from synthleak.atomic_io import atomic_write_text
    from synthleak.evaluate.tables import markdown_table, write_results

    head = [f"## The defense online (X = {defense.min_fraction:g}, k = {defense.min_instances})\n"]
    if rows_without is None or not holds_decisions(records):
        return head + ["The server's decisions are not in the query logs (a remote server tells only success "
                       "and pose): the comparison with and without the defense needs the in-process server.\n"]
    write_results(rows_without, results, stem="results_no_defense")
    check = online_vs_offline(records, defense.min_fraction, defense.min_instances)
    refused = refused_shares(records)
    compare = attack_with_and_without(rows_without, rows_with, thresholds)
    atomic_write_text(results / "defense_online.json", json.dumps(
        {"check": check, "refused": refused, "attack": compare}, indent=1, default=str) + "\n")
    agree = check["n_decisions"] - check["n_differ"]
    return head + [
        "The study's server applied the policy to every query; the attack without it runs on the same "
        "queries (their answers before the defense, `results/results_no_defense.*`). Online decisions equal "
        f"to the offline sweep's rule on the logged inlier counts: {agree}/{check['n_decisions']}.\n",
        "Among the queries PnP localized, the share the defense refused (genuine walk-through frames, genuine "
        "close-ups, attacker queries):\n",
        markdown_table(refused, list(refused[0])),
        "The attack without → with the defense (presence P/R, attacker queries localized, placement of all "
        "GT-present pairs):\n",
        comparison_markdown(compare, thresholds)]
