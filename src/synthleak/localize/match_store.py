"""A server's correspondences per query, on disk: each query's retrieved map images and each (query, map image)
pair's matches, so that pose estimation can be replayed under another acceptance rule or PnP threshold without
retrieving or matching again (the queries stage keeps one file per task: :mod:`synthleak.study.queries`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from synthleak.atomic_io import atomic_write_bytes

QueryMatches = tuple[np.ndarray, list[np.ndarray]]
"""One query's candidates (map image indices) and, per candidate, its (M, 2) pair matches."""


def write_matches(path: Path, queries: list[QueryMatches]) -> None:
    """Write the matches of consecutive queries (atomically)."""
    import io

    candidates = [np.asarray(c, dtype=np.int32).ravel() for c, _ in queries]
    pairs = [np.asarray(m, dtype=np.int32).reshape(-1, 2) for _, ms in queries for m in ms]
    arrays = {
        "candidates": np.concatenate(candidates) if candidates else np.zeros(0, np.int32),
        "candidate_offsets": np.cumsum([0] + [len(c) for c in candidates]).astype(np.int64),
        "pairs": np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int32),
        "pair_offsets": np.cumsum([0] + [len(p) for p in pairs]).astype(np.int64),
    }
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write_bytes(Path(path), buffer.getvalue())


def read_matches(path: Path) -> list[QueryMatches]:
    """The queries' matches :func:`write_matches` wrote (int64 arrays, as the matchers return them); a ValueError
    naming the file when it is not one."""
    try:
        with np.load(path) as data:
            candidates, cand_off = data["candidates"].astype(np.int64), data["candidate_offsets"]
            pairs, pair_off = data["pairs"].astype(np.int64), data["pair_offsets"]
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: not a matches file ({exc})") from exc
    out: list[QueryMatches] = []
    pair = 0
    for q in range(len(cand_off) - 1):
        cands = candidates[cand_off[q]:cand_off[q + 1]]
        matches = [pairs[pair_off[pair + k]:pair_off[pair + k + 1]] for k in range(len(cands))]
        pair += len(cands)
        out.append((cands, matches))
    return out
