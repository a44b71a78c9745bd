"""How good the attacker's SfM local models are, per attacker object (scoring against the GT orbit poses)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from synthleak.evaluate.tables import markdown_table

MIN_REGISTERED = 0.9
"""Share of an orbit SfM must register for the object to count as reconstructed."""
MAX_SCALE_ERROR = 0.03
"""Largest relative error of the metric scale (from the known object size) still counted as right."""


def sfm_objects(models: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per object from its :class:`~synthleak.attack.local_model.SfmLocalModel`: registered share,
    views registered in a wrong place, scale error, median local-pose errors, build seconds, and ``problem``
    (why SfM fails on it, empty when it does not)."""
    rows = []
    for obj, model in sorted(models.items()):
        n = len(model.registered) + len(model.unregistered)
        stats = model.stats
        mis = len(stats.get("misregistered", []))
        scale_error = float(stats.get("scale_error", math.nan))
        problems = []
        if not model.ok:
            problems.append(model.message)
        elif len(model.registered) < MIN_REGISTERED * n:
            problems.append(f"{len(model.unregistered)} views not registered (too few matches to link them)")
        if mis:
            problems.append(f"{mis} views registered in a wrong place")
        if model.ok and not abs(scale_error) <= MAX_SCALE_ERROR:
            problems.append(f"scale {100 * scale_error:+.0f} % from {stats.get('n_object_points', 0)} object points")
        rows.append({
            "object": obj, "registered": f"{len(model.registered)}/{n}",
            "registered_frac": len(model.registered) / n if n else math.nan, "misregistered": mis,
            "scale_error_pct": 100 * scale_error, "object_points": stats.get("n_object_points", 0),
            "median_rot_deg": stats.get("median_rot_deg", math.nan),
            "median_centre_m": stats.get("median_centre_m", math.nan),
            "seconds": stats.get("seconds", math.nan), "problem": "; ".join(problems),
        })
    return rows


def sfm_objects_markdown(models: Mapping[str, Any]) -> str:
    """:func:`sfm_objects` as a markdown table with a pooled line (registered share, |scale error| median,
    total build time)."""
    rows = sfm_objects(models)
    if rows:
        frac = sum(int(r["registered"].split("/")[0]) for r in rows) / max(
            1, sum(int(r["registered"].split("/")[1]) for r in rows))
        errors = sorted(abs(r["scale_error_pct"]) for r in rows if math.isfinite(r["scale_error_pct"]))
        rows.append({"object": "all", "registered": f"{100 * frac:.1f} %", "misregistered":
                     sum(r["misregistered"] for r in rows), "object_points": math.nan, "median_rot_deg": math.nan,
                     "median_centre_m": math.nan,
                     "scale_error_pct": errors[len(errors) // 2] if errors else math.nan,
                     "seconds": sum(r["seconds"] for r in rows if math.isfinite(r["seconds"])),
                     "problem": f"{sum(1 for r in rows if r['problem'])} objects with a problem"})
    return markdown_table(rows, ["object", "registered", "misregistered", "scale_error_pct", "object_points",
                                 "median_rot_deg", "median_centre_m", "seconds", "problem"], 2)


__all__ = ["MAX_SCALE_ERROR", "MIN_REGISTERED", "sfm_objects", "sfm_objects_markdown"]
