"""How much of each walk-through frame shows furniture and clutter, from the ground-truth instance masks.

A frame's *furniture coverage* is the fraction of its pixels on non-shell instances (not floor, walls,
ceiling, door or window backdrop). Views of bare walls make the attack's job easier than in a real home and
make the map say little about the furniture, so the testbed reports it per sequence.
"""

from __future__ import annotations

from typing import Any

import numpy as np

LOW_COVERAGE = 0.10
"""A frame below this furniture coverage sees mostly the room shell."""


def furniture_coverage(instance: np.ndarray, shell_ids: set[int] | frozenset[int]) -> float:
    """Fraction of the pixels of an instance-id image that lie on non-shell instances (0: background)."""
    ids = np.asarray(instance)
    on = (ids > 0) & ~np.isin(ids, np.fromiter(shell_ids, dtype=np.int64, count=len(shell_ids)))
    return float(on.mean())


def sequence_coverage(seq: Any) -> dict[str, Any]:
    """Coverage statistics of a rendered scene sequence (``core.dataset.Sequence``): walk-through frames
    (map and held-out, not the close-ups) and close-ups separately."""
    shell = {int(o.instance_id) for o in seq.objects if o.role == "shell"}
    closeups = set(seq.split.get("closeup", []))
    walk = [furniture_coverage(seq.instance(f), shell) for f in seq.frames if f not in closeups]
    close = [furniture_coverage(seq.instance(f), shell) for f in sorted(closeups)]
    return {
        "sequence": seq.name,
        "frames": len(walk),
        "median_coverage": float(np.median(walk)) if walk else float("nan"),
        "share_below_10pct": float(np.mean(np.array(walk) < LOW_COVERAGE)) if walk else float("nan"),
        "closeups": len(close),
        "closeup_median_coverage": float(np.median(close)) if close else float("nan"),
    }
