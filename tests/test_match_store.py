"""A server's kept correspondences (src/synthleak/localize/match_store.py): written and read back exactly, and a
file that is not one is named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from synthleak.localize.match_store import read_matches, write_matches


def test_correspondences_read_back_as_written(tmp_path: Path):
    rng = np.random.default_rng(0)
    queries = [(np.array([3, 0, 7]), [rng.integers(0, 900, (n, 2)) for n in (5, 0, 12)]),
               (np.zeros(0, np.int64), []),  # a query with no features: nothing retrieved
               (np.array([1]), [rng.integers(0, 900, (40, 2))])]
    path = tmp_path / "00000.npz"
    write_matches(path, queries)
    back = read_matches(path)
    assert len(back) == len(queries)
    for (cands, pairs), (cands_back, pairs_back) in zip(queries, back, strict=True):
        assert np.array_equal(cands, cands_back) and cands_back.dtype == np.int64
        assert len(pairs) == len(pairs_back)
        assert all(np.array_equal(a, b) and b.shape == (len(a), 2) and b.dtype == np.int64
                   for a, b in zip(pairs, pairs_back, strict=True))


def test_a_file_that_is_not_one_is_named(tmp_path: Path):
    path = tmp_path / "00003.npz"
    path.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"00003\.npz: not a matches file"):
        read_matches(path)
