"""Descriptor matching: the fast squared-distance matcher gives the textbook ratio/mutual matches."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from synthleak.localize import matching
from synthleak.localize.features import Features
from synthleak.localize.matching import match_features


def _reference(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool,
               both_ways: bool = False) -> set[tuple[int, int]]:
    """Lowe's test on true L2 distances between unit rows (float) or Hamming (uint8) distances with a full sort,
    the slow obvious way (``both_ways``: HLoc's ``NN-ratio``, the test from each side, then the mutual check)."""
    if a.dtype == np.uint8:
        bits_a, bits_b = np.unpackbits(a, axis=1), np.unpackbits(b, axis=1)
        dist = (bits_a[:, None, :] != bits_b[None]).sum(-1).astype(np.float64)
    else:
        a, b = (x.astype(np.float64) / np.sqrt((x.astype(np.float64) ** 2).sum(1, keepdims=True)) for x in (a, b))
        dist = np.sqrt(((a[:, None, :] - b[None]) ** 2).sum(-1))
    out = set()
    for i, row in enumerate(dist):
        order = np.argsort(row, kind="stable")
        j = int(order[0])
        if 0 < ratio < 1 and len(row) > 1 and not row[j] < ratio * row[order[1]]:
            continue
        if mutual and int(np.argmin(dist[:, j])) != i:
            continue
        column = np.sort(dist[:, j])
        if both_ways and mutual and 0 < ratio < 1 and len(column) > 1 and not column[0] < ratio * column[1]:
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


@pytest.mark.parametrize("binary", [False, True])
def test_ratio_both_ways_equals_reference(binary: bool) -> None:
    """HLoc's ``NN-ratio`` (the ratio test from both sides, then the mutual check): the reference's matches, and
    strictly fewer than the query-side test where map descriptors come in near-identical pairs."""
    rng = np.random.default_rng(5)
    if binary:
        b = rng.integers(0, 256, size=(150, 32), dtype=np.uint8)
        twins = np.packbits(np.unpackbits(b[:30], axis=1) ^ (rng.random((30, 256)) < 0.033), axis=1)
        a = np.concatenate([np.packbits(np.unpackbits(b[:90], axis=1) ^ (rng.random((90, 256)) < 0.03), axis=1),
                            twins])  # a query row near b[k] and a second query row (its twin) near it too
        fa, fb = Features(np.zeros((120, 2)), a, binary=True), Features(np.zeros((150, 2)), b, binary=True)
    else:
        b = rng.normal(size=(150, 32)).astype(np.float32)
        a = np.concatenate([b[:90] + 0.05 * rng.normal(size=(90, 32)),
                            b[:30] + 0.055 * rng.normal(size=(30, 32))]).astype(np.float32)
        fa, fb = Features(np.zeros((120, 2)), a), Features(np.zeros((150, 2)), b)
    one_way = {tuple(m) for m in match_features(fa, fb, 0.8, True).tolist()}
    both = {tuple(m) for m in match_features(fa, fb, 0.8, True, both_ways=True).tolist()}
    assert both == _reference(a, b, 0.8, True, both_ways=True)
    assert one_way == _reference(a, b, 0.8, True)
    assert both < one_way and len(one_way) - len(both) >= 10  # the twinned columns fail from the map's side


def test_sift_distances_are_exact_and_scale_free() -> None:
    """SIFT's integer descriptors: the unit-row scores do not depend on BLAS summation order (a reversed column
    order gives the same bytes), and the distances equal those of the rows normalised in float64 to rounding."""
    from synthleak.localize.matching import unit_scores

    rng = np.random.default_rng(2)
    a = rng.integers(0, 256, size=(300, 128)).astype(np.float32)
    b = rng.integers(0, 256, size=(200, 128)).astype(np.float32)
    score = unit_scores(a, b)
    again = unit_scores(a[:, ::-1].copy(), b[:, ::-1].copy())
    assert again.tobytes() == score.tobytes()
    unit_a, unit_b = (x / np.linalg.norm(x.astype(np.float64), axis=1, keepdims=True) for x in (a, b))
    np.testing.assert_allclose(2.0 + 2.0 * score, ((unit_a[:, None] - unit_b[None]) ** 2).sum(-1), atol=1e-6)
    half = unit_scores(a, 0.5 * b)  # scale-free: b/2 is the same direction
    np.testing.assert_array_equal(half, score)


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


@pytest.mark.parametrize("backend", ["numpy", "torch", "auto"])
@pytest.mark.parametrize("num_bytes", [32, 61])  # ORB's 256 bits, AKAZE's 488
def test_binary_backends_give_the_reference_matches(backend: str, num_bytes: int) -> None:
    """The int8 (torch) and float32 (numpy) products are both exact: each backend's matches (auto's too,
    whichever it picks) equal counting differing bits, ties included, and its distances equal the bit count."""
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


@pytest.fixture
def fresh_probe(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """auto measured afresh in this test (and again after it, so injected backends do not leak), no env var."""
    monkeypatch.delenv(matching.HAMMING_BACKEND_ENV, raising=False)
    matching.probe_timings.cache_clear()
    yield
    matching.probe_timings.cache_clear()


def _descriptor_pair(seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    b = rng.integers(0, 256, size=(80, 32), dtype=np.uint8)
    flips = rng.random((40, 256)) < 0.04
    a = np.concatenate([np.packbits(np.unpackbits(b[:40], axis=1) ^ flips, axis=1),
                        rng.integers(0, 256, size=(40, 32), dtype=np.uint8)])
    return a, b


def _counting(product: Callable[[np.ndarray, np.ndarray], np.ndarray], calls: list[int],
              sleep_s: float = 0.0) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    def wrapped(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        calls.append(1)
        if sleep_s:
            time.sleep(sleep_s)
        return product(a, b)

    return wrapped


def test_choose_backend_needs_a_clear_margin() -> None:
    assert matching.choose_backend({"numpy": 1.0, "torch": 0.5}) == "torch"
    assert matching.choose_backend({"numpy": 1.0, "torch": 1.0 / matching.TORCH_MARGIN}) == "torch"
    assert matching.choose_backend({"numpy": 1.0, "torch": 0.9}) == "numpy"  # faster, but within the noise
    assert matching.choose_backend({"numpy": 1.0, "torch": 30.0}) == "numpy"  # int8 without fast kernels
    assert matching.choose_backend({"numpy": 1.0}) == "numpy"  # no torch here
    with pytest.raises(ValueError, match="numpy"):
        matching.choose_backend({"torch": 1.0})


def test_auto_never_picks_a_backend_measured_slower_than_float32(fresh_probe: None) -> None:
    """Real measurements on this machine: auto is the probe's choice, and where that is torch, torch is not
    slower than float32 BLAS (10 % for noise) on a larger, matcher-sized product measured independently (the
    minimum over up to four rounds, so that another process's load is not taken for a slow backend)."""
    chosen = matching.auto_backend()
    timings = matching.probe_timings()
    assert chosen == matching.choose_backend(timings) and set(timings) == set(matching.backend_products())
    assert all(0 < seconds < 0.5 for seconds in timings.values()), timings
    if chosen == "torch":
        best = {"numpy": np.inf, "torch": np.inf}
        for _ in range(4):  # a loaded machine's noise goes away with more samples, a slow backend does not
            again = matching.measure_backends(shape=(1024, 1024, 32), repeats=10, budget_s=0.3)
            best = {name: min(best[name], again[name]) for name in best}
            if best["torch"] <= best["numpy"] * 1.1:
                break
        assert best["torch"] <= best["numpy"] * 1.1, (timings, best)


def test_probe_is_quick(fresh_probe: None) -> None:
    matching.backend_products()  # importing torch is not the probe's cost
    start = time.perf_counter()
    matching.probe_timings()
    assert time.perf_counter() - start < 0.5


def test_auto_falls_back_to_numpy_where_int8_is_slow(fresh_probe: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """A host whose int8 product is slow (here: the torch product made to sleep 50 ms a call, or float32 BLAS
    itself where torch is not installed): auto measures it, takes float32 BLAS, and no longer calls it. (A 10 ms
    sleep was within reach of the real float32 probe on a loaded 2-core host: 8 ms measured beside a study.)"""
    real = matching._torch_int_mm() or matching._float32_product
    calls: list[int] = []
    slow = _counting(real, calls, sleep_s=0.05)
    monkeypatch.setattr(matching, "_torch_int_mm", lambda: slow)
    assert matching.auto_backend() == "numpy"
    timings = matching.probe_timings()
    assert timings["torch"] >= 0.05 > timings["numpy"] * matching.TORCH_MARGIN, timings
    calls.clear()
    a, b = _descriptor_pair()
    got = matching._match_binary(a, b, 0.8, True)
    assert not calls and {tuple(m) for m in got.tolist()} == _reference(a, b, 0.8, True)
    assert matching.negated_dot(a, b).dtype == np.float32  # the BLAS product


def test_auto_takes_a_faster_backend(fresh_probe: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """The reverse: a "torch" product far faster than float32 BLAS (an exact int32 stand-in built on the real
    BLAS product, while the float32 backend is made to sleep 50 ms a call) is measured, chosen and used. The
    stand-in keeps the outcome independent of how fast this host's real int8 kernels are (on a slow one
    under load they take longer than the sleep)."""
    blas = matching._float32_product
    calls: list[int] = []
    stand_in = _counting(lambda a, b: blas(a, b).astype(np.int32), calls)
    monkeypatch.setattr(matching, "_torch_int_mm", lambda: stand_in)
    monkeypatch.setattr(matching, "_float32_product", _counting(blas, [], sleep_s=0.05))
    assert matching.auto_backend() == "torch"
    assert matching.probe_timings()["torch"] * matching.TORCH_MARGIN <= matching.probe_timings()["numpy"]
    calls.clear()
    a, b = _descriptor_pair()
    got = matching._match_binary(a, b, 0.8, True)
    assert calls and {tuple(m) for m in got.tolist()} == _reference(a, b, 0.8, True)


def test_auto_without_torch_is_numpy(fresh_probe: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(matching, "_torch_int_mm", lambda: None)
    assert matching.auto_backend() == "numpy" and set(matching.probe_timings()) == {"numpy"}
    a, b = _descriptor_pair()
    assert {tuple(m) for m in matching._match_binary(a, b, 0.8, True).tolist()} == _reference(a, b, 0.8, True)
    with pytest.raises(ImportError, match="torch"):
        matching.negated_dot(a, b, "torch")
    monkeypatch.setenv(matching.HAMMING_BACKEND_ENV, "torch")
    with pytest.raises(ImportError, match=matching.HAMMING_BACKEND_ENV):
        matching.negated_dot(a, b)


def test_env_var_overrides_auto(fresh_probe: None, monkeypatch: pytest.MonkeyPatch) -> None:
    """``SYNTHLEAK_HAMMING_BACKEND`` picks the backend without a probe; a bad value names the variable."""
    calls: list[int] = []
    monkeypatch.setattr(matching, "_torch_int_mm", lambda: _counting(lambda a, b: np.zeros((len(a), len(b))), calls))
    monkeypatch.setenv(matching.HAMMING_BACKEND_ENV, "numpy")
    assert matching.auto_backend() == "numpy" and matching.probe_timings.cache_info().currsize == 0
    a, b = _descriptor_pair()
    matching.negated_dot(a, b)
    assert not calls
    monkeypatch.setenv(matching.HAMMING_BACKEND_ENV, " Torch ")
    assert matching.auto_backend() == "torch"
    monkeypatch.setenv(matching.HAMMING_BACKEND_ENV, "gpu")
    with pytest.raises(ValueError, match=f"{matching.HAMMING_BACKEND_ENV}='gpu'.*auto, torch, numpy"):
        matching.auto_backend()
