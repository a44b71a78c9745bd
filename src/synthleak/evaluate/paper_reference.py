"""The paper's presence figures (Chelani et al., CVPR 2023, Table 1) and this study's tier ordering beside them."""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise
from statistics import fmean

from synthleak.evaluate.tables import group_rows, markdown_table, precision_recall
from synthleak.localize.servers import base_tier

PAPER_THRESHOLDS: tuple[tuple[float, float], ...] = ((10.0, 0.25), (30.0, 0.5), (60.0, 2.0))
"""Table 1's threshold pairs (δr in degrees, δt in metres), in the order of its columns."""

PAPER_TABLE1: dict[str, list[tuple[float, ...]]] = {
    # per scene (IKEA-Scenes 1..7): (P, R) at 10°/0.25 m, then 30°/0.5 m, then 60°/2 m
    "SuperPoint+SuperGlue": [
        (0.6, 0.85, 0.75, 0.85, 0.67, 0.85), (0.36, 0.4, 0.36, 0.5, 0.37, 0.6),
        (0.55, 0.71, 0.36, 0.57, 0.25, 0.43), (0.17, 0.4, 0.23, 0.6, 0.14, 0.4),
        (0.33, 0.6, 0.4, 0.8, 0.44, 0.8), (0.25, 0.6, 0.28, 0.6, 0.22, 0.4), (0.5, 0.5, 0.5, 0.33, 0.33, 0.5),
    ],
    "R2D2+NN": [
        (0.57, 0.57, 0.36, 0.57, 0.28, 0.57), (0.34, 0.4, 0.3, 0.3, 0.35, 0.6), (0.31, 0.71, 0.47, 1.0, 0.41, 1.0),
        (0.34, 0.6, 0.28, 0.4, 0.2, 0.4), (0.5, 0.6, 0.34, 0.4, 0.5, 0.6), (0.22, 0.4, 0.3, 0.6, 0.33, 0.8),
        (0.6, 0.5, 0.5, 0.5, 0.38, 0.5),
    ],
    "SIFT+NN": [
        (0.33, 0.57, 0.45, 0.71, 0.33, 0.43), (0.33, 0.4, 0.26, 0.5, 0.28, 0.6), (0.3, 0.42, 0.5, 0.42, 0.44, 1.0),
        (0.15, 0.4, 0.15, 0.4, 0.17, 0.4), (0.22, 0.4, 0.25, 0.4, 0.33, 0.4), (0.14, 0.2, 0.2, 0.2, 0.25, 0.6),
        (0.0, 0.0, 0.14, 0.17, 0.0, 0.0),
    ],
}
"""Table 1 of the paper, transcribed from its LaTeX source."""

PAPER_ANALOGUE: dict[str, str] = {
    "sift": "SIFT+NN",
    "xfeat": "R2D2+NN",
    "xfeat-lighterglue": "SuperPoint+SuperGlue",
    "disk-lightglue": "SuperPoint+SuperGlue",
    "aliked-lightglue": "SuperPoint+SuperGlue",
}
"""The paper's tier that each of ours stands in for (learned detector + plain NN, or + a learned matcher)."""


def paper_means() -> list[dict]:
    """Table 1 as the mean over the seven scenes: one row per (paper tier, threshold pair)."""
    out = []
    for tier, scenes in PAPER_TABLE1.items():
        for i, (dr, dt) in enumerate(PAPER_THRESHOLDS):
            out.append({"tier": tier, "delta_r_deg": dr, "delta_t_m": dt,
                        "precision": round(fmean(s[2 * i] for s in scenes), 2),
                        "recall": round(fmean(s[2 * i + 1] for s in scenes), 2)})
    return out


def tier_ordering(rows: Sequence[dict], aligner: str = "alg1") -> list[dict]:
    """Per tier of this study (``aligner``'s rows): pooled P/R at each threshold pair and attacker queries localized.

    ``queries_present`` / ``queries_absent`` count localized attacker queries over present / absent pairs."""
    mine = [r for r in rows if r["aligner"] == aligner]
    out = []
    for (tier,), group in sorted(group_rows(mine, ["tier"]).items()):
        first = (group[0]["delta_r_deg"], group[0]["delta_t_m"])
        pairs = [r for r in group if (r["delta_r_deg"], r["delta_t_m"]) == first]
        row: dict = {"tier": tier, "paper_analogue": PAPER_ANALOGUE.get(base_tier(tier), "-"),
                     "queries_present": _localized(pairs, True), "queries_absent": _localized(pairs, False)}
        for (dr, dt), sub in group_rows(group, ["delta_r_deg", "delta_t_m"]).items():
            pr = precision_recall(sub)
            row[f"P {dr:g}°, {dt:g}m"] = round(pr["precision"], 2)
            row[f"R {dr:g}°, {dt:g}m"] = round(pr["recall"], 2)
        out.append(row)
    return out


def _localized(rows: Sequence[dict], present: bool) -> str:
    chosen = [r for r in rows if bool(r["present_gt"]) == present]
    return f"{sum(int(r['n_localized']) for r in chosen)}/{sum(int(r['n_queries']) for r in chosen)}"


PRESENCE_RULES = {"eps": "ε rule", "classifier": "presence classifier"}
"""How the report names each ``[attack] presence`` rule."""


def _suffix(server: str) -> str:
    """A server name's ``@profile+representation`` part ('' for a plain tier)."""
    return server[len(base_tier(server)):]


def _verdict(ours: Sequence[dict], key_r: str, suffix: str) -> str:
    """The paper's claim (learned > SIFT in recall) tested among the servers of one profile and representation
    ('' where they include no learned tier beside ``sift``)."""
    group = [r for r in ours if _suffix(r["tier"]) == suffix and key_r in r]
    sift = next((r for r in group if base_tier(r["tier"]) == "sift"), None)
    learned = [r for r in group if base_tier(r["tier"]) in PAPER_ANALOGUE and base_tier(r["tier"]) != "sift"]
    where = f" (servers `*{suffix}`)" if suffix else " here"
    if not (learned and sift):
        return ""
    better = [r["tier"] for r in learned if r[key_r] > sift[key_r]]
    if better:
        names = ", ".join(f"`{t}`" for t in better)
        return f"Learned tiers with a higher recall than `{sift['tier']}`{where}: {names}."
    return f"No learned tier has a higher recall than `{sift['tier']}`{where} (the paper found the opposite)."


def _ranked(rows: Sequence[dict], key: str, label: str) -> str:
    """``label`` of each row by decreasing ``key``, joined by ``>``, or ``=`` between equal values."""
    ordered = sorted(rows, key=lambda r: -r[key])
    parts = [label.format(ordered[0]["tier"], ordered[0][key])] if ordered else []
    for before, row in pairwise(ordered):
        parts += [" = " if row[key] == before[key] else " > ", label.format(row["tier"], row[key])]
    return "".join(parts)


def tier_ordering_markdown(rows: Sequence[dict], aligner: str = "alg1", presence: str = "eps") -> str:
    """The paper's tier ordering (mean of Table 1 over its scenes) beside this study's, with a one-line verdict;
    ``presence``: the rule behind the rows' ``decision`` column (``[attack] presence``)."""
    paper = paper_means()
    first = PAPER_THRESHOLDS[0]
    paper_rows = []
    for tier in PAPER_TABLE1:
        row: dict = {"tier": tier}
        for m in (p for p in paper if p["tier"] == tier):
            row[f"P {m['delta_r_deg']:g}°, {m['delta_t_m']:g}m"] = m["precision"]
            row[f"R {m['delta_r_deg']:g}°, {m['delta_t_m']:g}m"] = m["recall"]
        paper_rows.append(row)
    ours = tier_ordering(rows, aligner)
    columns = [f"{k} {dr:g}°, {dt:g}m" for dr, dt in PAPER_THRESHOLDS for k in ("P", "R")]
    key_r = f"R {first[0]:g}°, {first[1]:g}m"
    paper_order = _ranked(paper_rows, key_r, "{} ({:.2f})")
    ours_order = _ranked([r for r in ours if key_r in r], key_r, "`{}` ({:.2f})") or "-"
    verdicts = [_verdict(ours, key_r, suffix) for suffix in dict.fromkeys(_suffix(r["tier"]) for r in ours)]
    tested = [v for v in verdicts if v]
    verdict = (" ".join(tested) if tested
               else "This study ran no learned tier beside `sift`: the paper's ordering is not tested.")
    return "\n".join([
        f"Recall at {first[0]:g}°, {first[1]:g} m, paper (Table 1, mean over its 7 scenes): {paper_order}.",
        f"This study (aligner `{aligner}`, {PRESENCE_RULES.get(presence, presence)}, pooled over rooms): "
        f"{ours_order}. {verdict}\n",
        markdown_table(paper_rows, ["tier", *columns], 2),
        markdown_table(ours, ["tier", "paper_analogue", *[c for c in columns if any(c in r for r in ours)],
                              "queries_present", "queries_absent"], 2),
    ])
