"""Utility against leakage, per server (a tier under a profile, over a map representation:
:mod:`synthleak.localize.servers`): what the service gives its users beside what it gives the attacker.

Utility: the genuine held-out queries localized (walk-through frames and close-ups) and their median pose error.
Leakage: the attacker queries localized (over GT-present and GT-absent pairs), presence P/R and placement success
(GT-present pairs placed within the first threshold pair) with Alg. 1 and with the best aligner. Defense: the
sweep point of ``[defense]``'s own policy (genuine queries kept, attacker queries rejected). The plot puts each
server, and each server behind each swept defense, at (genuine localized, attacker queries of GT-present pairs
localized: the queries that can place an object).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from statistics import median
from typing import Any

from matplotlib.figure import Figure

from synthleak.evaluate.plots import _MARKERS, _colour, _save
from synthleak.evaluate.tables import markdown_table, precision_recall


def _share(num: int, den: int) -> float | None:
    return round(num / den, 3) if den else None


def placement_success(rows: Sequence[dict], delta_r: float, delta_t: float) -> float | None:
    """Share of the GT-present pairs of ``rows`` decided present and placed within (``delta_r``°, ``delta_t`` m)."""
    present = [r for r in rows if r["present_gt"]]
    placed = [r for r in present if r["decision"] and r.get("rot_err_deg") is not None
              and r["rot_err_deg"] <= delta_r and r["trans_err_m"] <= delta_t]
    return _share(len(placed), len(present))


def server_rows(genuine: Sequence[dict], rows: Sequence[dict], tradeoff: Sequence[dict], thresholds: tuple,
                policy: tuple[float, int] | None = None) -> list[dict[str, Any]]:
    """One row per server (the ``tier`` column of ``rows``, in first-seen order)."""
    delta_r, delta_t = (float(v) for v in thresholds)
    out = []
    for server in dict.fromkeys(r["tier"] for r in rows):
        mine = [r for r in rows if r["tier"] == server and (r["delta_r_deg"], r["delta_t_m"]) == (delta_r, delta_t)]
        alg1 = [r for r in mine if r["aligner"] == "alg1"] or [r for r in mine if r["aligner"] == mine[0]["aligner"]]
        gen = [g for g in genuine if g["tier"] == server]
        n_gen, n_close = sum(g["n"] for g in gen), sum(g["closeups"] for g in gen)
        walk_n = n_gen - n_close
        walk_loc = sum(g["localized"] for g in gen) - sum(g["closeups_localized"] for g in gen)
        errors_r = [g["median_rot_err_deg"] for g in gen if g.get("median_rot_err_deg") is not None]
        errors_t = [g["median_trans_err_m"] for g in gen if g.get("median_trans_err_m") is not None]
        present = [r for r in alg1 if r["present_gt"]]
        absent = [r for r in alg1 if not r["present_gt"]]
        pr = precision_recall(alg1)
        by_aligner = {a: placement_success([r for r in mine if r["aligner"] == a], delta_r, delta_t)
                      for a in dict.fromkeys(r["aligner"] for r in mine)}
        best = max(by_aligner, key=lambda a: by_aligner[a] or 0.0)
        row: dict[str, Any] = {
            "server": server,
            "genuine_localized": _share(sum(g["localized"] for g in gen), n_gen),
            "walkthrough_localized": _share(walk_loc, walk_n),
            "closeups_localized": _share(sum(g["closeups_localized"] for g in gen), n_close),
            "median_rot_err_deg": round(median(errors_r), 4) if errors_r else None,
            "median_trans_err_m": round(median(errors_t), 5) if errors_t else None,
            "attacker_localized_present": _share(sum(r["n_localized"] for r in present),
                                                 sum(r["n_queries"] for r in present)),
            "attacker_localized_absent": _share(sum(r["n_localized"] for r in absent),
                                                sum(r["n_queries"] for r in absent)),
            "precision": round(pr["precision"], 3),
            "recall": round(pr["recall"], 3),
            "placed_alg1": by_aligner.get("alg1"),
            "placed_best": by_aligner[best],
            "best_aligner": best,
        }
        row["attacker_localized"] = _share(sum(r["n_localized"] for r in alg1), sum(r["n_queries"] for r in alg1))
        if policy is not None:
            point = next((t for t in tradeoff if t.get("tier") == server and (t["min_fraction"], t["min_instances"])
                          == policy), None)
            row["defense_genuine_kept"] = point["genuine_kept"] if point else None
            row["defense_attacker_rejected"] = point["attacker_rejected"] if point else None
        out.append(row)
    return out


COLUMNS = ["server", "genuine_localized", "walkthrough_localized", "closeups_localized", "median_rot_err_deg",
           "median_trans_err_m", "attacker_localized_present", "attacker_localized_absent", "precision", "recall",
           "placed_alg1", "placed_best", "best_aligner", "defense_genuine_kept", "defense_attacker_rejected"]


def server_summary_markdown(table: Sequence[dict], thresholds: tuple, policy: tuple[float, int] | None) -> str:
    """The table of :func:`server_rows`, with what each column means."""
    defense = (f"the defense at `[defense]`'s policy (min fraction {policy[0]:g}, min instances {policy[1]}): "
               "genuine queries kept and attacker queries rejected among the localized ones"
               if policy else "no defense policy in the sweep")
    return "\n".join([
        f"Utility: genuine held-out queries localized (all, walk-through frames, close-ups) and the median over "
        f"rooms of their median pose error. Leakage: attacker queries localized over GT-present and GT-absent "
        f"pairs, presence P/R with Alg. 1 and GT-present pairs placed within {thresholds[0]:g}°, "
        f"{thresholds[1]:g} m (Alg. 1, and the best aligner). Defense: {defense}.\n",
        markdown_table([{k: "–" if v is None else v for k, v in r.items()} for r in table],
                       [c for c in COLUMNS if any(c in r for r in table)], 3),
    ])


def plot_utility_vs_leakage(table: Sequence[dict], tradeoff: Sequence[dict], out: Path) -> Path:
    """Genuine queries localized (x) against attacker queries of GT-present pairs localized (y, the ones that can
    place an object; its axis ends a little above the largest share, as shares of a few per cent are usual): one
    filled point per server, and a hollow one per swept defense setting (both shares times the setting's kept /
    not rejected share)."""
    fig = Figure(figsize=(6.4, 4.8))
    ax = fig.add_subplot()
    shown = [r for r in table if r["genuine_localized"] is not None and r["attacker_localized_present"] is not None]
    for i, row in enumerate(shown):
        colour, marker = _colour(i), _MARKERS[i % len(_MARKERS)]
        x, y = row["genuine_localized"], row["attacker_localized_present"]
        points = [t for t in tradeoff if t.get("tier") == row["server"]]
        if points:
            ax.scatter([x * t["genuine_kept"] for t in points], [y * (1 - t["attacker_rejected"]) for t in points],
                       facecolors="none", edgecolors=colour, marker=marker, s=18, linewidths=0.8)
        ax.scatter([x], [y], color=colour, marker=marker, s=42, label=row["server"], zorder=3)
    ax.set_xlabel("genuine queries localized (utility)")
    ax.set_ylabel("attacker queries of present objects localized (leakage)")
    ax.set_xlim(0, 1.02)
    ax.set_ylim(0, min(1.02, max([0.05] + [1.15 * r["attacker_localized_present"] for r in shown])))
    ax.grid(alpha=0.3)
    if shown:
        ax.legend(fontsize=7, loc="best")
    ax.set_title("Utility against leakage per server (hollow: behind each swept defense)", fontsize=9)
    fig.tight_layout()
    return _save(fig, out)
