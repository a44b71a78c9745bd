"""How many localized attacker queries the server localizes on the room's shell (issue 30, step 4).

A query's PnP inliers are labelled with the map's instance ids (``inlier_instance_counts`` of the query log);
shell pieces (floor, walls, ceiling, door, window backdrop) have ids ``1..99``, furniture ``>= 100``
(:data:`synthleak.scene.plan.FIRST_OBJECT_ID`), 0 is unlabelled. A localized query lies *mostly on the shell*
when more than half of its inliers are on shell ids. Such a query matched the attacker's background to the
room's background, by chance: it is not the look-alike leak the paper measures (Chelani et al., CVPR 2023,
Sec. 4: the attacker's images show the object, not the room). The issue's target is a share under 10 %; the
``hloc`` servers, which accept any pose with 3 inliers, cannot meet it (docs/learned-tiers.md, "The PnP threshold").
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from synthleak.scene.plan import FIRST_OBJECT_ID

MOSTLY = 0.5
"""A query is on the shell when its shell inliers are more than this fraction of all its inliers."""


def _counts(counts: Mapping[Any, Any], where: str) -> dict[int, int]:
    if not isinstance(counts, Mapping):
        raise ValueError(f"{where}: field 'inlier_instance_counts' must map instance id -> count, got {counts!r}")
    out = {}
    for key, value in counts.items():
        try:
            iid = int(key)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: field 'inlier_instance_counts' has a non-integer id {key!r}") from exc
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise ValueError(f"{where}: field 'inlier_instance_counts[{key!r}]' must be a count >= 0, got {value!r}")
        out[iid] = out.get(iid, 0) + value
    return out


def shell_fraction(counts: Mapping[Any, Any], where: str = "query") -> float:
    """Fraction of a query's PnP inliers on shell instances (ids ``1..FIRST_OBJECT_ID-1``); NaN without any."""
    c = _counts(counts, where)
    total = sum(c.values())
    if total == 0:
        return math.nan
    return sum(v for k, v in c.items() if 0 < k < FIRST_OBJECT_ID) / total


def mostly_on_shell(counts: Mapping[Any, Any], where: str = "query") -> bool:
    """More than half of the query's inliers on the shell (False for a query without inliers)."""
    fraction = shell_fraction(counts, where)
    return not math.isnan(fraction) and fraction > MOSTLY


def count_shell_top(records: Iterable[Mapping[str, Any]]) -> int:
    """Localized (``success``) query records whose inliers lie mostly on the shell."""
    return sum(1 for q in records if q["success"] and mostly_on_shell(q.get("inlier_instance_counts") or {},
                                                                           f"query {q.get('frame')!r}"))


def _share(n: int, d: int) -> float:
    return n / d if d else math.nan


def _summary(tier: str, localized: Mapping[str, int], shell: Mapping[str, int]) -> dict[str, Any]:
    row: dict[str, Any] = {"tier": tier}
    for part in ("present", "absent", "all"):
        row[f"n_localized_{part}"] = localized[part]
        row[f"n_shell_top_{part}"] = shell[part]
        row[f"shell_share_{part}"] = _share(shell[part], localized[part])
    return row


def shell_share_from_logs(records: Iterable[Mapping[str, Any]], index: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Per tier, the localized attacker queries of the query-log ``records`` and those mostly on the shell,
    for GT-present pairs, GT-absent pairs and all (``index``: the study's ``stages/index.json``, whose
    ``attacker_objects[*].present_in`` says which rooms hold each object). Genuine queries are left out."""
    present_in = {o["id"]: set(o.get("present_in", {})) for o in index["attacker_objects"]}
    localized: dict[str, dict[str, int]] = {}
    shell: dict[str, dict[str, int]] = {}
    for q in records:
        obj = q.get("attacker_object")
        if q.get("genuine") or obj is None:
            continue
        if obj not in present_in:
            raise ValueError(f"query {q.get('frame')!r} of room {q.get('room')!r}: field 'attacker_object' "
                             f"{obj!r} is not an attacker object of index.json")
        if not q["success"]:
            continue
        tier = q["tier"]
        part = "present" if q["room"] in present_in[obj] else "absent"
        on_shell = mostly_on_shell(q.get("inlier_instance_counts") or {}, f"query {q.get('frame')!r}")
        for key in (part, "all"):
            localized.setdefault(tier, {"present": 0, "absent": 0, "all": 0})[key] += 1
            shell.setdefault(tier, {"present": 0, "absent": 0, "all": 0})[key] += int(on_shell)
    return [_summary(t, localized[t], shell[t]) for t in sorted(localized)]


def shell_share(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The same per-tier summary from the results rows (their pair fields ``n_localized`` and ``n_shell_top``,
    each pair counted once: the first aligner and thresholds); [] when the rows lack ``n_shell_top`` (results
    written before the field)."""
    seen: set[tuple[str, str, str]] = set()
    localized: dict[str, dict[str, int]] = {}
    shell: dict[str, dict[str, int]] = {}
    for r in rows:
        if r.get("n_shell_top") is None:
            return []
        pair = (r["tier"], r["room"], r["object"])
        if pair in seen:
            continue
        seen.add(pair)
        part = "present" if r["present_gt"] else "absent"
        for key in (part, "all"):
            localized.setdefault(r["tier"], {"present": 0, "absent": 0, "all": 0})[key] += int(r["n_localized"])
            shell.setdefault(r["tier"], {"present": 0, "absent": 0, "all": 0})[key] += int(r["n_shell_top"])
    return [_summary(t, localized[t], shell[t]) for t in sorted(localized)]


def shell_share_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The report's table: per tier, localized attacker queries mostly on the shell, present / absent / all."""
    summary = shell_share(rows)
    if not summary:
        return "No localized attacker queries with inlier labels (or results written before `n_shell_top`).\n"
    lines = ["| tier | present: on shell / localized | absent: on shell / localized | all: share |",
             "|---|---|---|---|"]
    for s in summary:
        cells = [f"{s[f'n_shell_top_{p}']}/{s[f'n_localized_{p}']} ({_pct(s[f'shell_share_{p}'])})"
                 for p in ("present", "absent")]
        lines.append(f"| {s['tier']} | {cells[0]} | {cells[1]} | {_pct(s['shell_share_all'])} |")
    return "\n".join(lines) + "\n"


def _pct(value: float) -> str:
    return "–" if math.isnan(value) else f"{100 * value:.0f} %"
