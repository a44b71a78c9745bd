"""Presence/absence decision from the inlier ratio eps (paper Sec. 3.3 and 5.2).

The attacker has learned, per object, the median inlier ratio over training scenes where the object is
present (eps⁺) and absent (eps⁻). In a new scene the object is decided present iff
``|eps − eps⁺| < |eps − eps⁻|`` (a tie is "absent"). Fallbacks:

* no eps⁺ (the object is present in no training scene, paper Sec. 5.2): present iff ``eps > eps⁻``;
* no eps⁻ (present in every training scene; the paper never meets this case): eps⁻ is taken as 0, the
  inlier ratio of "nothing aligns", so the rule becomes ``eps > eps⁺ / 2``;
* neither: eps⁻ = 0 and no eps⁺, so present iff ``eps > 0`` (anything consistent came back at all).

:func:`leave_one_scene_out` evaluates this as the paper does: every object is tried against every room,
and each room's decision uses medians over the OTHER rooms only.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PresenceRecord:
    """One (room, attacker object) trial: the attack's eps and whether the object is really there."""

    room: str
    object: str
    eps: float
    present_gt: bool


@dataclass(frozen=True)
class PresenceDecision:
    """A record with the training statistics used for it and the decision."""

    room: str
    object: str
    eps: float
    present_gt: bool
    eps_plus: float | None
    eps_minus: float | None
    decision: bool


def _check_eps(value: float | None, name: str, optional: bool) -> float | None:
    if value is None:
        if optional:
            return None
        raise ValueError(f"{name}: required")
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or value > 1.0:
        raise ValueError(f"{name}: an inlier ratio must lie in [0, 1], got {value}")
    return value


def decide_presence(eps: float, eps_plus: float | None, eps_minus: float | None) -> bool:
    """Present iff ``|eps − eps⁺| < |eps − eps⁻|``; see the module docstring for missing statistics."""
    eps = _check_eps(eps, "eps", optional=False)
    eps_plus = _check_eps(eps_plus, "eps_plus", optional=True)
    eps_minus = _check_eps(eps_minus, "eps_minus", optional=True)
    if eps_minus is None:
        eps_minus = 0.0
    if eps_plus is None:
        return eps > eps_minus
    return abs(eps - eps_plus) < abs(eps - eps_minus)


def presence_margin(eps: float, eps_plus: float | None, eps_minus: float | None) -> float:
    """The ε rule as a signed score: > 0 exactly when :func:`decide_presence` says present
    (``|eps − eps⁻| − |eps − eps⁺|``, or ``eps − eps⁻`` without eps⁺; eps⁻ = 0 when missing)."""
    eps_minus = 0.0 if eps_minus is None else float(eps_minus)
    if eps_plus is None:
        return float(eps) - eps_minus
    return abs(float(eps) - eps_minus) - abs(float(eps) - float(eps_plus))


def leave_one_scene_out(records: list[PresenceRecord]) -> list[PresenceDecision]:
    """Decide every record with eps⁺/eps⁻ = medians of the same object's eps over the other rooms.

    Records must come from one attack configuration (tier, aligner, thresholds); a duplicate
    (room, object) pair raises ValueError. Output order follows the input.
    """
    by_object: dict[str, list[PresenceRecord]] = defaultdict(list)
    seen: set[tuple[str, str]] = set()
    for k, rec in enumerate(records):
        key = (rec.room, rec.object)
        if key in seen:
            raise ValueError(f"records[{k}]: duplicate (room, object) pair {key}")
        seen.add(key)
        _check_eps(rec.eps, f"records[{k}].eps", optional=False)
        by_object[rec.object].append(rec)
    out: list[PresenceDecision] = []
    for rec in records:
        others = [r for r in by_object[rec.object] if r.room != rec.room]
        plus = [r.eps for r in others if r.present_gt]
        minus = [r.eps for r in others if not r.present_gt]
        eps_plus = float(np.median(plus)) if plus else None
        eps_minus = float(np.median(minus)) if minus else None
        out.append(
            PresenceDecision(rec.room, rec.object, float(rec.eps), bool(rec.present_gt), eps_plus, eps_minus,
                             decide_presence(rec.eps, eps_plus, eps_minus))
        )
    return out
