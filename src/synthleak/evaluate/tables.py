"""Results rows -> presence precision/recall tables (paper Table 1 and the appendix per-object table),
placement summaries, and the results files.

A results row is a plain dict, one per (room, attacker object, tier, aligner, thresholds[, variant]):
see :data:`COLUMNS`. ``decision`` is the leave-one-scene-out presence decision
(:func:`apply_presence_decisions` fills it). Conventions: precision with no positive decision is 0 (the
paper's tables print 0 for objects never decided present); recall with no GT-present pair is NaN.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.atomic_io import atomic_write_text
from synthleak.attack.presence import PresenceRecord, leave_one_scene_out
from synthleak.evaluate.metrics import DEFAULT_THRESHOLDS
from synthleak.portable import POSE_STEP, result_float, snap

COLUMNS: tuple[str, ...] = (
    "room", "object", "model_id", "category", "tier", "aligner", "delta_r_deg", "delta_t_m", "present_gt",
    "eps", "decision", "n_queries", "n_no_local_pose", "n_localized", "n_retrieved_target", "n_target_top",
    "map_points_on_target", "absent_kind", "n_lookalike_top", "rot_err_deg", "trans_err_m", "iou3d",
    "scene_from_object_est", "magnitude", "kind", "decision_eps", "decision_clf", "clf_score", "clf_fallback",
    "second_eps", "rot_spread", "trans_spread", "disagree_rot_deg", "disagree_trans_m",
)
"""Stable column order of the results files; extra keys follow, sorted."""

CONFIG_KEYS: tuple[str, ...] = ("tier", "aligner", "delta_r_deg", "delta_t_m", "magnitude", "kind")
"""Fields that identify one attack configuration (one leave-one-scene-out experiment)."""

FLOAT_COLUMNS = ("delta_r_deg", "delta_t_m", "eps", "rot_err_deg", "trans_err_m", "iou3d", "magnitude")



# --------------------------------------------------------------------------------------------- helpers


def sort_key(value: Any) -> tuple:
    """Total order over mixed numbers / strings / None (None last), for deterministic grouping."""
    if value is None:
        return (2, "")
    if isinstance(value, bool | int | float):
        return (0, float(value), "")
    return (1, 0.0, str(value))


def group_rows(rows: Iterable[dict], fields: Sequence[str]) -> dict[tuple, list[dict]]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for k, row in enumerate(rows):
        missing = [f for f in fields if f not in row]
        if missing:
            raise ValueError(f"rows[{k}]: missing field(s) {missing}")
        groups[tuple(row[f] for f in fields)].append(row)
    return dict(sorted(groups.items(), key=lambda kv: tuple(sort_key(v) for v in kv[0])))


def _fmt(value: float, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, float) and math.isinf(value):
        return "∞"
    return f"{value:.{digits}f}"


def _thr_label(delta_r: float, delta_t: float) -> str:
    return f"{delta_r:g}°, {delta_t:g}m"


def precision_recall(rows: Sequence[dict]) -> dict[str, float | int]:
    """Counts and P/R of the ``decision`` against ``present_gt`` over rows."""
    tp = sum(1 for r in rows if r["decision"] and r["present_gt"])
    fp = sum(1 for r in rows if r["decision"] and not r["present_gt"])
    fn = sum(1 for r in rows if not r["decision"] and r["present_gt"])
    tn = len(rows) - tp - fp - fn
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / (tp + fn) if tp + fn else math.nan
    return {"tp": tp, "fp": fp, "fn": fn, "tn": tn, "precision": precision, "recall": recall,
            "n_present": tp + fn, "n_pairs": len(rows)}


# --------------------------------------------------------------------------------------------- presence


PRESENCE_RULES = ("eps", "classifier")
"""``attack.presence``: the paper's ε rule or the classifier of :mod:`synthleak.attack.presence_classifier`."""


def apply_presence_decisions(rows: Sequence[dict], rule: str = "eps") -> list[dict]:
    """Copies of ``rows`` with the presence decisions of leave-one-scene-out within each attack configuration.

    ``decision_eps`` is the paper's ε rule (with ``eps_plus`` / ``eps_minus``); when the rows carry the
    attacker-side trial features, ``decision_clf`` / ``clf_score`` / ``clf_fallback`` are the classifier's.
    ``decision`` is the ``rule``'s (``classifier`` needs the features)."""
    if rule not in PRESENCE_RULES:
        raise ValueError(f"attack.presence: unknown rule {rule!r} (known: {', '.join(PRESENCE_RULES)})")
    out = [dict(r) for r in rows]
    for group in group_rows(out, CONFIG_KEYS).values():
        records = [
            PresenceRecord(r["room"], r["object"], float(r["eps"]), bool(r["present_gt"])) for r in group
        ]
        for row, dec in zip(group, leave_one_scene_out(records), strict=True):
            row["decision"] = row["decision_eps"] = dec.decision
            row["eps_plus"] = dec.eps_plus
            row["eps_minus"] = dec.eps_minus
    from synthleak.attack.presence_classifier import classifier_decisions, has_features

    if has_features(out):
        for row, clf in zip(out, classifier_decisions(out, [r["decision_eps"] for r in out]), strict=True):
            row.update(clf)
            if rule == "classifier":
                row["decision"] = clf["decision_clf"]
    elif rule == "classifier":
        raise ValueError("attack.presence = 'classifier': the rows carry no trial features "
                         "(synthleak.attack.presence_features)")
    return out


def presence_pr_per_room(rows: Sequence[dict]) -> list[dict]:
    """Precision/recall per (configuration, room), plus a pooled ``room = "all"`` row per configuration."""
    return _pr_by(rows, "room")


def presence_pr_per_object(rows: Sequence[dict]) -> list[dict]:
    """Precision/recall per (configuration, attacker object) over all rooms, plus pooled ``"all"`` rows."""
    return _pr_by(rows, "object")


def _pr_by(rows: Sequence[dict], field: str) -> list[dict]:
    out = []
    for key, group in group_rows(rows, CONFIG_KEYS).items():
        base = dict(zip(CONFIG_KEYS, key, strict=True))
        for (name,), sub in group_rows(group, [field]).items():
            out.append({**base, field: name, **precision_recall(sub)})
        out.append({**base, field: "all", **precision_recall(group)})
    return out


def random_guess_precision(rows: Sequence[dict]) -> float:
    """Precision of guessing at random: the fraction of distinct (room, object) pairs that are present."""
    pairs = {(r["room"], r["object"]): bool(r["present_gt"]) for r in rows}
    return sum(pairs.values()) / len(pairs) if pairs else math.nan


def _pr_table(rows: Sequence[dict], field: str, title: str) -> str:
    """One markdown table per (aligner, magnitude, kind, tier): rows = ``field``, columns = thresholds x P/R."""
    blocks = []
    sections = group_rows(rows, ["aligner", "magnitude", "kind", "tier"])
    for (aligner, magnitude, kind, tier), sec_rows in sections.items():
        thresholds = sorted({(r["delta_r_deg"], r["delta_t_m"]) for r in sec_rows})
        stats = {}
        for r in _pr_by(sec_rows, field):
            stats[(r[field], r["delta_r_deg"], r["delta_t_m"])] = r
        names = sorted({r[field] for r in sec_rows}, key=sort_key) + ["all"]
        heading = f"**{title}** — tier `{tier}`, aligner `{aligner}`"
        if magnitude is not None or kind is not None:
            heading += f", variant magnitude {magnitude}, kind {kind}"
        cols = [f"{_thr_label(*th)} {pr}" for th in thresholds for pr in ("P", "R")]
        lines = [heading, "", "| " + " | ".join([field, *cols]) + " |", "|" + "---|" * (len(cols) + 1)]
        for name in names:
            cells = []
            for th in thresholds:
                s = stats.get((name, *th))
                cells += [_fmt(s["precision"]), _fmt(s["recall"])] if s else ["–", "–"]
            lines.append("| " + " | ".join([str(name), *cells]) + " |")
        lines += ["", f"Random-guess precision: {_fmt(random_guess_precision(sec_rows))}"]
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks) + "\n"


def table1_markdown(rows: Sequence[dict]) -> str:
    """Paper Table 1: presence precision/recall per room, column groups = tiers x threshold pairs."""
    return _pr_table(rows, "room", "Presence precision (P) / recall (R) per room")


def table2_markdown(rows: Sequence[dict]) -> str:
    """Appendix per-object table: presence precision/recall per attacker object over all rooms."""
    return _pr_table(rows, "object", "Presence precision (P) / recall (R) per object")


# --------------------------------------------------------------------------------------------- placement


def _finite_or(value: Any, default: float) -> float:
    if value is None:
        return default
    value = float(value)
    return default if math.isnan(value) else value


def placement_stats(
    rows: Sequence[dict],
    decided_only: bool = False,
    thresholds: Sequence[tuple[float, float]] = DEFAULT_THRESHOLDS,
) -> list[dict]:
    """Placement statistics of GT-present pairs per configuration (``decided_only``: also decided present).

    A pair without an estimate counts with infinite errors (medians) and IoU 0; success rates use the
    (degrees, metres) ``thresholds``.
    """
    out = []
    chosen = [r for r in rows if r["present_gt"] and (r["decision"] or not decided_only)]
    for key, group in group_rows(chosen, CONFIG_KEYS).items():
        rot = np.array([_finite_or(r.get("rot_err_deg"), math.inf) for r in group])
        trans = np.array([_finite_or(r.get("trans_err_m"), math.inf) for r in group])
        iou = np.array([_finite_or(r.get("iou3d"), 0.0) for r in group])
        stat = dict(zip(CONFIG_KEYS, key, strict=True))
        stat.update({
            "n": len(group),
            "n_placed": int(np.isfinite(rot).sum()),
            "median_rot_err_deg": float(np.median(rot)),
            "median_trans_err_m": float(np.median(trans)),
            "median_iou3d": float(np.median(iou)),
            "mean_iou3d": float(np.mean(iou)),
        })
        for dr, dt in thresholds:
            stat[f"success_{dr:g}deg_{dt:g}m"] = float(np.mean((rot <= dr) & (trans <= dt)))
        out.append(stat)
    return out


def placement_summary(
    rows: Sequence[dict], thresholds: Sequence[tuple[float, float]] = DEFAULT_THRESHOLDS
) -> str:
    """Markdown: placement errors, IoU and success rates per tier x aligner x thresholds, for all GT-present
    pairs and for the GT-present pairs the attack also decided present."""
    blocks = []
    for decided, title in ((False, "all GT-present pairs"), (True, "GT-present pairs decided present")):
        stats = placement_stats(rows, decided_only=decided, thresholds=thresholds)
        succ = [f"succ {dr:g}°/{dt:g}m" for dr, dt in thresholds]
        header = ["tier", "aligner", "δr, δt", "magnitude", "kind", "n", "placed", "med rot °", "med trans m",
                  "med IoU", "mean IoU", *succ]
        lines = [f"**Placement, {title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for s in stats:
            cells = [str(s["tier"]), str(s["aligner"]), _thr_label(s["delta_r_deg"], s["delta_t_m"]),
                     "–" if s["magnitude"] is None else f"{s['magnitude']:g}", str(s["kind"] or "–"),
                     str(s["n"]), str(s["n_placed"]), _fmt(s["median_rot_err_deg"], 1),
                     _fmt(s["median_trans_err_m"], 3), _fmt(s["median_iou3d"]), _fmt(s["mean_iou3d"])]
            cells += [_fmt(s[f"success_{dr:g}deg_{dt:g}m"]) for dr, dt in thresholds]
            lines.append("| " + " | ".join(cells) + " |")
        if not stats:
            lines.append("| " + " | ".join(["–"] * len(header)) + " |")
        blocks.append("\n".join(lines))
    return "\n\n".join(blocks) + "\n"


# --------------------------------------------------------------------------------------------- files


def _is_pose(value: Any) -> bool:
    """A 4x4 matrix of finite numbers (an array or nested lists), such as ``scene_from_object_est``."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return array.shape == (4, 4) and bool(np.all(np.isfinite(array)))


def plain(value: Any) -> Any:
    """JSON-ready value: numpy scalars/arrays to Python, NaN/inf to None; floats on the portable results grid
    (:func:`synthleak.portable.result_float`: 6 significant digits), 4x4 poses on the pose grid (1e-9, so that
    a rotation read back is still orthonormal to 1e-8)."""
    if isinstance(value, np.ndarray | list | tuple) and len(value) == 4 and _is_pose(value):
        return [[round(float(v), 9) + 0.0 for v in row] for row in snap(np.asarray(value, dtype=np.float64), POSE_STEP)]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, np.bool_ | bool):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        value = float(value)
        return result_float(value) if math.isfinite(value) else None
    return value


def recall_funnel(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Per tier, the GT-present pairs step by step: the object has 3D points in the room's map, at least one
    attacker query localizes, one localizes with most PnP inliers on the object, the pair is decided present
    (first aligner and thresholds of the rows); then their queries step by step: sent, those whose retrieved
    map images see the room's instance of the object (``n_retrieved_target``: a miss before it is the
    retrieval's; "–" where unknown, e.g. a remote server), those localized (a miss between the two is matching
    or PnP), those localized with most inliers on the object. Rows of variant sweeps (``magnitude`` set) are
    left out."""
    main = [r for r in rows if r.get("present_gt") and r.get("magnitude") is None]
    if not main:
        return []
    first = main[0]
    config = (first["aligner"], first["delta_r_deg"], first["delta_t_m"])
    out = []
    for (tier,), group in group_rows(main, ["tier"]).items():
        pairs = [r for r in group if (r["aligner"], r["delta_r_deg"], r["delta_t_m"]) == config]
        points = [r.get("map_points_on_target") for r in pairs]
        sent = sum(r["n_queries"] for r in pairs)
        out.append({
            "tier": tier,
            "present pairs": len(pairs),
            "object in map": sum(1 for p in points if p),
            "median map points": float(np.median([p for p in points if p is not None])) if any(
                p is not None for p in points) else math.nan,
            "a query localized": sum(1 for r in pairs if r["n_localized"] > 0),
            "localized on the object": sum(1 for r in pairs if (r.get("n_target_top") or 0) > 0),
            f"decided present ({config[0]}, {config[1]:g}°, {config[2]:g}m)": sum(1 for r in pairs if r["decision"]),
            "queries sent": sent,
            "retrieved images see the object": _retrieving(pairs),
            "queries localized": sum(r["n_localized"] for r in pairs),
            "queries on the object": sum(r.get("n_target_top") or 0 for r in pairs),
        })
    return out


def _retrieving(pairs: Sequence[dict]) -> int | str:
    """The queries whose retrieved map images see the object, summed over the pairs; "–" unless every pair's
    ``n_retrieved_target`` is known."""
    if not pairs or any(r.get("n_retrieved_target") is None for r in pairs):
        return "–"
    return sum(r["n_retrieved_target"] for r in pairs)


def recall_funnel_markdown(rows: Sequence[dict]) -> str:
    """:func:`recall_funnel` as a markdown table (an explanatory line when there are no present pairs)."""
    funnel = recall_funnel(rows)
    if not funnel:
        return "No GT-present pairs.\n"
    return markdown_table(funnel, list(funnel[0]), digits=0)


def markdown_table(rows: Sequence[dict], columns: Sequence[str], digits: int = 3) -> str:
    """A markdown table, one line per row; floats with ``digits`` decimals, NaN as "–"."""
    def cell(value: Any) -> str:
        if isinstance(value, float):
            return "–" if math.isnan(value) else f"{value:.{digits}f}"
        return str(value)

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def ordered_columns(rows: Sequence[dict]) -> list[str]:
    extra = sorted({k for r in rows for k in r} - set(COLUMNS))
    return [*COLUMNS, *extra]


def _csv_cell(value: Any) -> str:
    value = plain(value)
    if value is None:
        return ""
    if isinstance(value, list | dict):
        return json.dumps(value, separators=(",", ":"))
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(result_float(value)) if math.isfinite(value) else f"{value}"
    return str(value)


def write_results(rows: Sequence[dict], out_dir: str | Path, stem: str = "results") -> tuple[Path, Path]:
    """Write ``<stem>.csv`` and ``<stem>.json`` (same columns, stable order, deterministic formatting).

    Missing / NaN values are empty cells in CSV and ``null`` in JSON; poses are JSON nested lists. Each file is
    written atomically (a reader sees the old file or the whole new one).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    columns = ordered_columns(rows)
    csv_path, json_path = out_dir / f"{stem}.csv", out_dir / f"{stem}.json"
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([_csv_cell(row.get(c)) for c in columns])
    atomic_write_text(csv_path, buffer.getvalue())
    payload = [{c: plain(row.get(c)) for c in columns} for row in rows]
    atomic_write_text(json_path, json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
    return csv_path, json_path


def read_results(path: str | Path) -> list[dict]:
    """Rows back from a results JSON (``null`` in float columns becomes NaN)."""
    rows = json.loads(Path(path).read_text())
    for row in rows:
        for col in FLOAT_COLUMNS:
            if col in row and row[col] is None and col != "magnitude":
                row[col] = math.nan
    return rows


# --------------------------------------------------------------------------------------------- presence rules


def _f1(precision: float, recall: float) -> float:
    if math.isnan(recall) or precision + recall == 0:
        return math.nan if math.isnan(recall) else 0.0
    return 2 * precision * recall / (precision + recall)


def presence_rule_comparison(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """Per attack configuration (variant sweeps left out): P, R and F1 of the ε rule (``decision_eps``) and of
    the classifier (``decision_clf``) on the same held-out rows, and which wins on F1 (``tie`` if equal)."""
    main = [r for r in rows if r.get("magnitude") is None and "decision_clf" in r]
    out = []
    for key, group in group_rows(main, ["tier", "aligner", "delta_r_deg", "delta_t_m"]).items():
        row: dict[str, Any] = dict(zip(("tier", "aligner", "delta_r_deg", "delta_t_m"), key, strict=True))
        for name, column in (("eps", "decision_eps"), ("clf", "decision_clf")):
            pr = precision_recall([{**r, "decision": r[column]} for r in group])
            row |= {f"P {name}": pr["precision"], f"R {name}": pr["recall"],
                    f"F1 {name}": _f1(pr["precision"], pr["recall"]), f"TP/FP {name}": f"{pr['tp']}/{pr['fp']}"}
        row["n_pairs"] = len(group)
        row["fallbacks"] = sum(1 for r in group if r.get("clf_fallback"))
        f_eps, f_clf = row["F1 eps"], row["F1 clf"]
        row["wins"] = ("tie" if f_eps == f_clf or (math.isnan(f_eps) and math.isnan(f_clf))
                       else "classifier" if f_clf > f_eps else "eps")
        out.append(row)
    return out


def presence_rules_markdown(rows: Sequence[dict], rule: str = "eps") -> str:
    """Report section: :func:`presence_rule_comparison` as a table (empty without classifier decisions)."""
    table = presence_rule_comparison(rows)
    if not table:
        return ""
    head = ["tier", "aligner", "δr, δt", "P ε", "R ε", "F1 ε", "TP/FP ε", "P clf", "R clf", "F1 clf", "TP/FP clf",
            "pairs", "fallbacks", "wins"]
    lines = ["## Presence: the paper's ε rule against a classifier (held-out rooms)\n",
             "Both decide each room from the other rooms only (leave-one-scene-out): the ε rule with per-object "
             "ε⁺/ε⁻ medians, the classifier (logistic regression, `synthleak.attack.presence_classifier`) from "
             "attacker-side features: ε at each threshold pair, share of queries localized, second-best hypothesis, "
             "inlier residual spread, placement agreement across threshold pairs, the ε rule's margin. "
             "`fallbacks`: rooms whose training rooms hold one class (ε rule kept). The `decision` column of the "
             f"results uses `{rule}` (`[attack] presence`).\n",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in table:
        cells = [r["tier"], r["aligner"], _thr_label(r["delta_r_deg"], r["delta_t_m"]),
                 _fmt(r["P eps"]), _fmt(r["R eps"]), _fmt(r["F1 eps"]), r["TP/FP eps"],
                 _fmt(r["P clf"]), _fmt(r["R clf"]), _fmt(r["F1 clf"]), r["TP/FP clf"],
                 str(r["n_pairs"]), str(r["fallbacks"]), r["wins"]]
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    return "\n".join(lines) + "\n"
