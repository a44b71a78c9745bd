"""Descriptor matching: the fast squared-distance matcher gives the textbook ratio/mutual matches."""

from __future__ import annotations

import numpy as np
import pytest

from synthleak.localize.features import Features
from synthleak.localize.matching import match_features


def _reference(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool) -> set[tuple[int, int]]:
    """Lowe's test on true L2 (float) or Hamming (uint8) distances with a full sort, the slow obvious way."""
    if a.dtype == np.uint8:
        bits_a, bits_b = np.unpackbits(a, axis=1), np.unpackbits(b, axis=1)
        dist = (bits_a[:, None, :] != bits_b[None]).sum(-1).astype(np.float64)
    else:
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


@pytest.mark.parametrize(("ratio", "mutual"), [(0.75, True), (0.8, False), (0.0, True)])
def test_binary_matcher_equals_reference(ratio: float, mutual: bool) -> None:
    """Hamming distances from the +-1 BLAS product are exact: same matches as counting differing bits,
    including ties (duplicated rows, small distances)."""
    rng = np.random.default_rng(11)
    b = rng.integers(0, 256, size=(150, 61), dtype=np.uint8)  # AKAZE's 488-bit descriptors
    flips = rng.random((75, 61 * 8)) < 0.05
    noisy = np.packbits(np.unpackbits(b[rng.permutation(150)[:75]], axis=1) ^ flips, axis=1)
    a = np.concatenate([noisy, rng.integers(0, 256, size=(75, 61), dtype=np.uint8)])
    a[10] = a[3]  # an exact tie for the mutual check
    fa, fb = Features(np.zeros((150, 2)), a, binary=True), Features(np.zeros((150, 2)), b, binary=True)
    got = match_features(fa, fb, ratio, mutual)
    assert {tuple(m) for m in got.tolist()} == _reference(a, b, ratio, mutual)
    if ratio == 0.75 and mutual:
        assert len(got) >= 70


@pytest.mark.parametrize("backend", ["numpy", "torch"])
@pytest.mark.parametrize("num_bytes", [32, 61])  # ORB's 256 bits, AKAZE's 488
def test_binary_backends_give_the_reference_matches(backend: str, num_bytes: int) -> None:
    """The int8 (torch) and float32 (numpy) products are both exact: each backend's matches equal counting
    differing bits, ties included, and its distances equal the bit count."""
    if backend == "torch":
        pytest.importorskip("torch")
    from synthleak.localize.matching import _match_binary, hamming

    rng = np.random.default_rng(num_bytes)
    b = rng.integers(0, 256, size=(90, num_bytes), dtype=np.uint8)
    flips = rng.random((45, num_bytes * 8)) < 0.04
    a = np.concatenate([np.packbits(np.unpackbits(b[:45], axis=1) ^ flips, axis=1),
                        rng.integers(0, 256, size=(45, num_bytes), dtype=np.uint8)])
    a[20], b[60] = a[2], b[2]  # exact ties on both sides
    bits = (np.unpackbits(a, axis=1)[:, None, :] != np.unpackbits(b, axis=1)[None]).sum(-1)
    assert np.array_equal(hamming(a, b, backend), bits.astype(np.float32))
    for ratio, mutual in [(0.75, True), (0.8, False), (0.0, False)]:
        got = _match_binary(a, b, ratio, mutual, backend)
        assert {tuple(m) for m in got.tolist()} == _reference(a, b, ratio, mutual)
    assert len(_match_binary(a, b, 0.75, True, backend)) >= 40
