"""Figures of the study (matplotlib object API, no pyplot state, Agg canvas, deterministic PNG bytes).

Every function takes plain data (results rows / summary dicts / poses) and an output path and returns it.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Polygon, Rectangle
from scipy.spatial import ConvexHull

from synthleak.evaluate.tables import precision_recall, sort_key

_COLOURS = [
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
    "#17becf",
]
_MARKERS = ["o", "s", "^", "D", "v", "P", "X", "*"]


def _colour(k: int) -> str:
    return _COLOURS[k % len(_COLOURS)]


def _save(fig: Figure, out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": None})
    return out


def _sorted(values) -> list:
    return sorted(set(values), key=sort_key)


def _thr(row: dict) -> str:
    return f"{row['delta_r_deg']:g}°/{row['delta_t_m']:g}m"


# --------------------------------------------------------------------------------------------- presence


def plot_presence_pr(pr_rows: Sequence[dict], out: str | Path) -> Path:
    """Bars of pooled precision and recall per tier x thresholds (one panel per aligner), room values as dots.

    ``pr_rows``: output of :func:`synthleak.evaluate.tables.presence_pr_per_room`.
    """
    aligners = _sorted(r["aligner"] for r in pr_rows) or ["–"]
    n_labels = max(len({(r["tier"], r["delta_r_deg"], r["delta_t_m"]) for r in pr_rows if r["aligner"] == a})
                   for a in aligners) if pr_rows else 1
    panel = max(4.4, 0.5 * n_labels)  # wide enough for one rotated label per bar pair
    fig = Figure(figsize=(max(5.0, panel * len(aligners)), 4.0), layout="constrained")
    for a_idx, aligner in enumerate(aligners):
        ax = fig.add_subplot(1, len(aligners), a_idx + 1)
        rows = [r for r in pr_rows if r["aligner"] == aligner]
        labels = _sorted((r["tier"], r["delta_r_deg"], r["delta_t_m"]) for r in rows)
        x = np.arange(len(labels))
        for m_idx, (metric, offset) in enumerate((("precision", -0.2), ("recall", 0.2))):
            pooled = []
            for lab_idx, lab in enumerate(labels):
                match = [r for r in rows if (r["tier"], r["delta_r_deg"], r["delta_t_m"]) == lab]
                allrow = [r for r in match if r["room"] == "all"]
                pooled.append(allrow[0][metric] if allrow else math.nan)
                per_room = [r[metric] for r in match if r["room"] != "all"]
                ax.plot(np.full(len(per_room), lab_idx + offset), per_room, ".", color="k", ms=3)
            ax.bar(x + offset, pooled, width=0.4, color=_colour(m_idx), label=metric)
        ax.set_xticks(x, [f"{t} {dr:g}°/{dt:g}m" for t, dr, dt in labels], fontsize=7, rotation=45, ha="right",
                      rotation_mode="anchor")
        ax.set_ylim(0, 1.05)
        ax.set_title(f"presence, aligner {aligner}", fontsize=9)
        ax.legend(fontsize=7)
    return _save(fig, out)


# --------------------------------------------------------------------------------------------- placement


def _cdf(ax, values: np.ndarray, label: str, colour: str, style: str) -> None:
    values = np.sort(values)
    if values.size == 0:
        return
    y = np.arange(1, values.size + 1) / values.size
    finite = np.isfinite(values)
    ax.step(values[finite], y[finite], where="post", label=label, color=colour, linestyle=style)


def plot_placement_cdfs(rows: Sequence[dict], out: str | Path) -> Path:
    """CDFs of rotation and translation errors of GT-present pairs at the tightest alignment thresholds, a line
    per tier (colour) x aligner (line style); the other threshold pairs are in the report's tables.

    Pairs without an estimate count as infinite error (the curve never reaches 1 then).
    """
    present = [r for r in rows if r["present_gt"]]
    thresholds = _sorted((r["delta_r_deg"], r["delta_t_m"]) for r in present)
    present = [r for r in present if thresholds and (r["delta_r_deg"], r["delta_t_m"]) == thresholds[0]]
    keys = _sorted((r["tier"], r["aligner"]) for r in present)
    tiers = _sorted(k[0] for k in keys)
    aligners = _sorted(k[1] for k in keys)
    fig = Figure(figsize=(11, 3.8), layout="constrained")
    ax_r, ax_t = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    styles = ["-", "--", ":", "-."]
    for key in keys:
        group = [r for r in present if (r["tier"], r["aligner"]) == key]
        rot = np.array([np.inf if r.get("rot_err_deg") is None or math.isnan(r["rot_err_deg"])
                        else r["rot_err_deg"] for r in group])
        trans = np.array([np.inf if r.get("trans_err_m") is None or math.isnan(r["trans_err_m"])
                          else r["trans_err_m"] for r in group])
        colour = _colour(tiers.index(key[0]))
        style = styles[aligners.index(key[1]) % len(styles)]
        _cdf(ax_r, rot, f"{key[0]} {key[1]}", colour, style)
        _cdf(ax_t, trans, f"{key[0]} {key[1]}", colour, style)
    ax_r.set_xscale("symlog", linthresh=1.0)
    ax_t.set_xscale("symlog", linthresh=0.01)
    ax_r.set_xlabel("rotation error (deg, symmetry-aware)")
    ax_t.set_xlabel("centre error (m)")
    for ax in (ax_r, ax_t):
        ax.set_ylabel("fraction of present pairs")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    if keys:
        fig.suptitle(f"placement of GT-present pairs, aligned at {thresholds[0][0]:g}°/{thresholds[0][1]:g} m",
                     fontsize=9)
        handles = [Line2D([], [], color=_colour(k), label=tier) for k, tier in enumerate(tiers)]
        handles += [Line2D([], [], color="black", linestyle=styles[k % len(styles)], label=aligner)
                    for k, aligner in enumerate(aligners)]
        fig.legend(handles=handles, loc="outside right upper", fontsize=7)
    return _save(fig, out)


def _footprint(pose: np.ndarray, extents: Sequence[float]) -> np.ndarray:
    """Top-down (x, y) outline (convex hull of the 8 projected corners) of a placed object's box."""
    ex, ey, ez = (float(v) for v in extents)
    corners = np.array([[sx * ex / 2, sy * ey / 2, z] for sx in (-1, 1) for sy in (-1, 1) for z in (0.0, ez)])
    world = corners @ np.asarray(pose)[:3, :3].T + np.asarray(pose)[:3, 3]
    xy = world[:, :2]
    try:
        hull = ConvexHull(xy)
        return xy[hull.vertices]
    except Exception:  # degenerate (flat) footprint: draw the points' bounding segment
        return xy[[np.argmin(xy[:, 0]), np.argmax(xy[:, 0])]]


def plot_room_topdown(
    room_size: Sequence[float],
    objects: Sequence[tuple[str, np.ndarray, Sequence[float]]],
    estimates: Sequence[tuple[str, np.ndarray, Sequence[float]]],
    cameras: np.ndarray | None = None,
    out: str | Path = "room_topdown.png",
    room_min: Sequence[float] = (0.0, 0.0),
    title: str = "",
) -> Path:
    """Top-down map: room outline, GT boxes solid, estimated boxes dashed (same colour per object name),
    an arrow for each object's +x axis, and optional camera centres of (N, 4, 4) ``cam_from_world`` poses.

    The room spans ``room_min`` to ``room_min + room_size[:2]`` in x, y.
    """
    names = _sorted([o[0] for o in objects] + [e[0] for e in estimates])
    colour = {name: _colour(k) for k, name in enumerate(names)}
    fig = Figure(figsize=(6, 6), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    ax.add_patch(Rectangle(tuple(room_min[:2]), room_size[0], room_size[1], fill=False, color="k", lw=1.5))
    for dashed, items in ((False, objects), (True, estimates)):
        for name, pose, extents in items:
            if pose is None:
                continue
            pose = np.asarray(pose, dtype=np.float64)
            outline = _footprint(pose, extents)
            ax.add_patch(Polygon(outline, closed=True, fill=not dashed, alpha=0.25 if not dashed else 1.0,
                                 facecolor=colour[name], edgecolor=colour[name],
                                 linestyle="--" if dashed else "-", lw=1.5,
                                 label=None if dashed else name))
            scale = float(np.cbrt(np.linalg.det(pose[:3, :3])))
            centre = pose[:3, 3][:2]
            axis = pose[:3, 0][:2] / max(scale, 1e-12) * 0.5 * float(extents[0])
            ax.annotate("", xy=tuple(centre + axis), xytext=tuple(centre),
                        arrowprops={"arrowstyle": "->", "color": colour[name],
                                    "linestyle": "--" if dashed else "-"})
    if cameras is not None and len(cameras):
        cams = np.asarray(cameras, dtype=np.float64)
        centres = -np.einsum("nji,nj->ni", cams[:, :3, :3], cams[:, :3, 3])
        ax.plot(centres[:, 0], centres[:, 1], ".", color="0.5", ms=2, label="cameras")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or "GT (solid) vs estimated (dashed)", fontsize=9)
    if names:
        ax.legend(fontsize=6, loc="upper right")
    return _save(fig, out)


# --------------------------------------------------------------------------------------------- defense


def plot_defense_tradeoff(tradeoff_rows: Sequence[dict], out: str | Path, group_field: str = "tier") -> Path:
    """Paper Fig. 6: genuine queries kept vs attacker queries rejected, a line per min fraction X, points
    per min-instances k (annotated); one panel per value of ``group_field``. Rows with
    ``genuine_closeup_kept`` add a dashed line per X: the genuine close-ups kept.

    ``tradeoff_rows``: output of :func:`synthleak.evaluate.defense_sweep.defense_tradeoff`.
    """
    groups = [g for g in _sorted(r.get(group_field, "all") for r in tradeoff_rows) if g != "all"]
    if len(groups) != 1:  # the pooled panel, last; redundant when there is a single group
        groups.append("all")
    fig = Figure(figsize=(4.2 * len(groups), 4.0), layout="constrained")
    for g_idx, group in enumerate(groups):
        ax = fig.add_subplot(1, len(groups), g_idx + 1)
        rows = [r for r in tradeoff_rows if r.get(group_field, "all") == group]
        for x_idx, frac in enumerate(_sorted(r["min_fraction"] for r in rows)):
            line = sorted((r for r in rows if r["min_fraction"] == frac), key=lambda r: r["min_instances"])
            xs = [r["attacker_rejected"] for r in line]
            ys = [r["genuine_kept"] for r in line]
            ax.plot(xs, ys, "-", marker=_MARKERS[x_idx % len(_MARKERS)], color=_colour(x_idx), ms=4,
                    label=f"X = {100 * frac:g}%")
            if any(math.isfinite(r.get("genuine_closeup_kept", math.nan)) for r in line):
                ax.plot(xs, [r["genuine_closeup_kept"] for r in line], "--", marker=_MARKERS[x_idx % len(_MARKERS)],
                        color=_colour(x_idx), ms=3, mfc="none", alpha=0.8, label=f"X = {100 * frac:g}%, close-ups")
            for r, px, py in zip(line, xs, ys, strict=True):
                if math.isfinite(px) and math.isfinite(py):
                    ax.annotate(str(r["min_instances"]), (px, py), fontsize=6, xytext=(2, 2),
                                textcoords="offset points")
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("attacker queries rejected")
        ax.set_ylabel("genuine queries kept")
        ax.set_title(f"{group_field} {group}", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    return _save(fig, out)


# --------------------------------------------------------------------------------------------- sweep


def leakage_vs_magnitude(
    rows: Sequence[dict], success_threshold: tuple[float, float] = (30.0, 0.5)
) -> list[dict]:
    """Per (tier, aligner, thresholds, kind, magnitude): pooled presence P/R and placement success rate of
    GT-present pairs at ``success_threshold`` (degrees, metres)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        if r.get("magnitude") is None:
            continue
        key = (r["tier"], r["aligner"], r["delta_r_deg"], r["delta_t_m"], r["kind"], r["magnitude"])
        groups[key].append(r)
    out = []
    dr, dt = success_threshold
    for key in sorted(groups, key=lambda k: tuple(sort_key(v) for v in k)):
        group = groups[key]
        present = [r for r in group if r["present_gt"]]
        ok = [
            (r.get("rot_err_deg") is not None and r["rot_err_deg"] <= dr
             and r.get("trans_err_m") is not None and r["trans_err_m"] <= dt)
            for r in present
        ]
        pr = precision_recall(group)
        out.append({
            "tier": key[0], "aligner": key[1], "delta_r_deg": key[2], "delta_t_m": key[3], "kind": key[4],
            "magnitude": key[5], "precision": pr["precision"], "recall": pr["recall"],
            "placement_success": float(np.mean(ok)) if ok else math.nan, "n_pairs": len(group),
        })
    return out


def plot_leakage_vs_magnitude(
    rows: Sequence[dict], out: str | Path, success_threshold: tuple[float, float] = (30.0, 0.5)
) -> Path:
    """Presence precision / recall and placement success vs attacker-variant magnitude: a panel row per
    tier, a line per variant kind (x aligner x thresholds when several)."""
    stats = leakage_vs_magnitude(rows, success_threshold)
    tiers = _sorted(s["tier"] for s in stats) or ["–"]
    lines = _sorted((s["kind"], s["aligner"], s["delta_r_deg"], s["delta_t_m"]) for s in stats)
    multi = len({ln[1:] for ln in lines}) > 1
    at = f"@{success_threshold[0]:g}°/{success_threshold[1]:g}m"
    metrics = (("precision", "presence precision"), ("recall", "presence recall"),
               ("placement_success", f"placement success {at}"))
    fig = Figure(figsize=(12, 3.2 * len(tiers)), layout="constrained")
    for t_idx, tier in enumerate(tiers):
        for m_idx, (metric, label) in enumerate(metrics):
            ax = fig.add_subplot(len(tiers), 3, t_idx * 3 + m_idx + 1)
            for l_idx, line in enumerate(lines):
                pts = sorted((s["magnitude"], s[metric]) for s in stats
                             if s["tier"] == tier and (s["kind"], s["aligner"], s["delta_r_deg"],
                                                       s["delta_t_m"]) == line)
                if not pts:
                    continue
                name = str(line[0]) + (f" {line[1]} {line[2]:g}°/{line[3]:g}m" if multi else "")
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", marker=_MARKERS[l_idx % len(_MARKERS)],
                        color=_colour(l_idx), label=name, ms=4)
            ax.set_ylim(-0.02, 1.02)
            ax.set_xlabel("attacker variant magnitude")
            ax.set_title(f"{tier}: {label}", fontsize=9)
            ax.grid(alpha=0.3)
            if m_idx == 0 and lines:
                ax.legend(fontsize=6)
    return _save(fig, out)


def plot_leakage_vs_world(rows: Sequence[dict], out: str | Path, aligner: str,
                          thresholds: tuple[float, float]) -> Path:
    """One panel per swept knob: precision (solid) and recall (dashed) against its value, a colour per tier,
    for one aligner and threshold pair."""
    from synthleak.evaluate.world_sweep import WORLD_PARAMS, leakage_vs_world

    stats = [s for s in leakage_vs_world(rows)
             if s["aligner"] == aligner and (s["delta_r_deg"], s["delta_t_m"]) == tuple(thresholds)]
    params = [p for p in WORLD_PARAMS if any(s["sweep_param"] == p for s in stats)] or ["–"]
    tiers = _sorted(s["tier"] for s in stats)
    fig = Figure(figsize=(4.6 * len(params), 3.6), layout="constrained")
    for p_idx, param in enumerate(params):
        ax = fig.add_subplot(1, len(params), p_idx + 1)
        for t_idx, tier in enumerate(tiers):
            pts = sorted((s["sweep_value"], s["precision"], s["recall"]) for s in stats
                         if s["sweep_param"] == param and s["tier"] == tier)
            xs = [p[0] for p in pts]
            marker = _MARKERS[t_idx % len(_MARKERS)]
            ax.plot(xs, [p[1] for p in pts], "-", marker=marker, color=_colour(t_idx), ms=4, label=f"{tier} P")
            ax.plot(xs, [p[2] for p in pts], "--", marker=marker, color=_colour(t_idx), ms=4, mfc="none",
                    label=f"{tier} R")
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel(param)
        ax.set_title(f"presence vs {param} ({aligner}, {thresholds[0]:g}°/{thresholds[1]:g} m)", fontsize=9)
        ax.grid(alpha=0.3)
        if tiers:
            ax.legend(fontsize=7)
    return _save(fig, out)
