"""Descriptor matching: the fast squared-distance matcher gives the textbook ratio/mutual matches."""

from __future__ import annotations

import numpy as np
import pytest

from synthleak.localize.features import Features
from synthleak.localize.matching import match_features


def _reference(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool) -> set[tuple[int, int]]:
    """Lowe's test on true L2 distances with a full sort, written the slow obvious way."""
    dist = np.sqrt(((a[:, None, :].astype(np.float64) - b[None].astype(np.float64)) ** 2).sum(-1))
    out = set()
    for i, row in enumerate(dist):
        order = np.argsort(row, kind="stable")
        j = int(order[0])
        if 0 < ratio < 1 and len(row) > 1 and not row[j] < ratio * row[order[1]]:
            continue
        if mutual and int(np.argmin(dist[:, j])) != i:
            continue
        out.add((i, j))
    return out


@pytest.mark.parametrize(("ratio", "mutual"), [(0.8, True), (0.8, False), (0.0, True), (1.0, False)])
def test_float_matcher_equals_reference(ratio: float, mutual: bool) -> None:
    rng = np.random.default_rng(7)
    b = rng.normal(size=(120, 32)).astype(np.float32)
    # half of a are noisy copies of b rows (clear matches), half unrelated
    a = np.concatenate([b[rng.permutation(120)[:60]] + 0.05 * rng.normal(size=(60, 32)),
                        rng.normal(size=(60, 32))]).astype(np.float32)
    got = match_features(Features(np.zeros((120, 2)), a), Features(np.zeros((120, 2)), b), ratio, mutual)
    assert {tuple(m) for m in got.tolist()} == _reference(a, b, ratio, mutual)
    if ratio == 0.8 and mutual:
        assert len(got) >= 55  # the noisy copies match


def test_duplicate_descriptors_match_once_like_argmin() -> None:
    """Two identical query descriptors tie exactly: the mutual check keeps the first, as argmin would."""
    rng = np.random.default_rng(3)
    b = rng.normal(size=(40, 16)).astype(np.float32)
    a = (b[:20] + 0.01 * rng.normal(size=(20, 16))).astype(np.float32)
    a[7] = a[4]
    got = match_features(Features(np.zeros((20, 2)), a), Features(np.zeros((40, 2)), b), 0.8, True)
    assert {tuple(m) for m in got.tolist()} == _reference(a, b, 0.8, True)
    assert (4, 4) in {tuple(m) for m in got.tolist()} and 7 not in got[:, 0]
