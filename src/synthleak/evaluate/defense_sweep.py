"""Offline sweep of the query defense of paper Sec. 6 over logged server decisions (paper Fig. 6).

The defense counts the scene instances (objects, room-shell pieces included) that contribute at least a
fraction X of the PnP inliers of the instance contributing the most, and rejects a query when fewer than
k instances qualify (background id 0 never counts). From the logged inlier counts per instance we replay
it for every (X, k) of a grid and report, among the queries the server localized without the defense, the
fraction of genuine queries kept and the fraction of attacker queries rejected.

A logged query is a dict: ``room``, ``tier``, ``genuine`` (bool), ``attacker_object`` (str or None),
``success_without_defense`` (bool), ``inlier_instance_counts`` ({instance_id: count}; JSON keys may be
strings), optionally ``closeup`` (bool: a genuine close-up of one object or a small group, which the paper
found the defense cannot tell from an attacker's query).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from synthleak.localize.defense import contributing_instances


def qualifying_instances(inlier_instance_counts: Mapping[Any, int], min_fraction: float) -> int:
    """Number of instances with at least ``min_fraction`` of the top instance's inlier count.

    Same rule as the server's :func:`synthleak.localize.defense.contributing_instances` (which it calls, so
    the sweep replays the live defense exactly): background id 0 and zero counts do not count.
    """
    return len(contributing_instances(inlier_instance_counts, min_fraction))


def passes_defense(
    inlier_instance_counts: Mapping[Any, int], min_fraction: float, min_instances: int
) -> bool:
    """True iff at least ``min_instances`` instances carry ``min_fraction`` of the top instance's inliers."""
    return qualifying_instances(inlier_instance_counts, min_fraction) >= min_instances


def _check_query(k: int, q: Mapping[str, Any]) -> None:
    for name in ("room", "tier", "genuine", "success_without_defense", "inlier_instance_counts"):
        if name not in q:
            raise ValueError(f"queries[{k}]: missing field {name!r}")
    if not isinstance(q["inlier_instance_counts"], Mapping):
        raise ValueError(f"queries[{k}].inlier_instance_counts: expected a mapping instance_id -> count")
    for key, count in q["inlier_instance_counts"].items():
        if not isinstance(count, int | np.integer) or count < 0:
            raise ValueError(
                f"queries[{k}].inlier_instance_counts[{key!r}]: expected a count >= 0, got {count!r}"
            )


def defense_tradeoff(
    queries: Sequence[Mapping[str, Any]],
    min_fractions: Sequence[float] = (0.05, 0.1, 0.2, 0.3),
    min_instances: Sequence[int] = (1, 2, 3, 4, 5, 6),
    by: Sequence[str] = ("tier",),
) -> list[dict]:
    """Genuine-kept / attacker-rejected fractions per group and grid point.

    Groups are the values of the ``by`` fields, plus one pooled group whose ``by`` fields are ``"all"``.

    Only queries with ``success_without_defense`` count (a query the server could not localize anyway is
    neither kept nor rejected by the defense). A fraction with no query to count is NaN. When any query has
    ``closeup`` set, the rows also give the kept fractions of the genuine walk-through queries and of the
    genuine close-ups separately.
    """
    for k, q in enumerate(queries):
        _check_query(k, q)
    localized = [q for q in queries if q["success_without_defense"]]
    groups: dict[tuple, list[Mapping[str, Any]]] = defaultdict(list)
    for q in localized:
        groups[tuple(q[f] for f in by)].append(q)
    keyed = sorted(groups.items(), key=lambda kv: tuple(str(v) for v in kv[0]))
    if by:
        keyed.append((tuple("all" for _ in by), localized))
    out = []
    split_closeups = any("closeup" in q for q in queries)
    for key, group in keyed:
        genuine = [q for q in group if q["genuine"]]
        attacker = [q for q in group if not q["genuine"]]
        close = [bool(q.get("closeup")) for q in genuine]
        for x in min_fractions:
            n_gen = [qualifying_instances(q["inlier_instance_counts"], x) for q in genuine]
            n_att = [qualifying_instances(q["inlier_instance_counts"], x) for q in attacker]
            for k in min_instances:
                kept = sum(n >= k for n in n_gen)
                rejected = sum(n < k for n in n_att)
                row = {
                    **dict(zip(by, key, strict=True)),
                    "min_fraction": float(x),
                    "min_instances": int(k),
                    "n_genuine": len(genuine),
                    "n_attacker": len(attacker),
                    "genuine_kept": kept / len(genuine) if genuine else math.nan,
                    "attacker_rejected": rejected / len(attacker) if attacker else math.nan,
                }
                if split_closeups:
                    for name, want in (("walkthrough", False), ("closeup", True)):
                        counts = [n for n, c in zip(n_gen, close, strict=True) if c == want]
                        row[f"n_genuine_{name}"] = len(counts)
                        row[f"genuine_{name}_kept"] = (sum(n >= k for n in counts) / len(counts)
                                                       if counts else math.nan)
                out.append(row)
    return out
