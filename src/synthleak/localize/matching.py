"""Nearest-neighbour descriptor matching with Lowe's ratio test and an optional mutual check."""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from synthleak.localize.features import Features


def squared_l2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Na, Nb) float32 squared L2 distances from one BLAS product of augmented rows,
    ``[a, |a|^2, 1] . [-2 b, 1, |b|^2]``: no passes over the (Na, Nb) matrix besides the product itself.
    Tiny negative values (rounding, for equal descriptors) are left as they are: the matcher only compares."""
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    left = np.empty((len(a), a.shape[1] + 2), dtype=np.float32)
    left[:, :-2], left[:, -2], left[:, -1] = a, np.einsum("ij,ij->i", a, a), 1.0
    right = np.empty((len(b), b.shape[1] + 2), dtype=np.float32)
    right[:, :-2], right[:, -2], right[:, -1] = -2.0 * b, 1.0, np.einsum("ij,ij->i", b, b)
    return left @ right.T


def unit_scores(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Na, Nb) float32 ``-a.b / (|a| |b|)``: minus the cosine, so lower is nearer along rows and columns alike,
    and ``2 + 2 score`` is the squared L2 distance between the unit rows.

    The product runs in float32 BLAS, the scaling elementwise (by ``-1/|a|``, then by ``1/|b|``). For integer
    rows whose products sum below 2^24 (SIFT's uint8 descriptors: 128 x 255^2) every partial sum is exact, and
    IEEE elementwise products and square roots are correctly rounded, so the scores are the same bytes whatever
    kernel or summation order the CPU's BLAS picks (``docs/determinism.md``)."""
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)

    def inverse_norms(x: np.ndarray) -> np.ndarray:
        x64 = x.astype(np.float64)
        return (1.0 / np.sqrt(np.maximum(np.einsum("ij,ij->i", x64, x64), 1e-24))).astype(np.float32)

    score = a @ b.T
    score *= -inverse_norms(a)[:, None]
    score *= inverse_norms(b)[None, :]
    return score


def match_features(a: Features, b: Features, ratio: float, mutual: bool, *, both_ways: bool = False) -> np.ndarray:
    """(M, 2) int indices ``(i in a, j in b)``; ratio <= 0 or >= 1 disables the ratio test; ``both_ways``: a
    mutual match also passes the ratio test from ``b``'s side (HLoc's ``NN-ratio``). Float descriptors are
    compared as unit vectors (:func:`unit_scores`), binary ones by Hamming distance."""
    return pair_scores(a, b).matches(ratio, mutual, both_ways=both_ways)


@dataclass
class PairScores:
    """The descriptor scores of one image pair, computed once: every matching rule (ratio, mutual check) that
    servers of one tier apply is a cheap filter of the same matrix (:meth:`matches`)."""

    scores: np.ndarray | None
    """(Na, Nb) scores that rank as distances do, or None when either side has no features."""
    to_distance: Callable[[np.ndarray], np.ndarray] | None = None
    """Maps best and second scores to the distances the ratio test compares."""
    squared: bool = False
    """The distances are squared (the ratio test compares them with ``ratio**2``)."""

    def matches(self, ratio: float, mutual: bool, *, both_ways: bool = False) -> np.ndarray:
        """:func:`match_features`'s matches under this rule (the scores are left as they were)."""
        if self.scores is None:
            return np.zeros((0, 2), np.int64)
        return nearest_neighbours(self.scores, ratio * ratio if self.squared else ratio, mutual,
                                  to_distance=self.to_distance, both_ways=both_ways)


def pair_scores(a: Features, b: Features) -> PairScores:
    """The scores :func:`match_features` filters: unit-vector scores of float descriptors (Lowe's test on
    squared distances: ``d0 < r d1  <=>  d0^2 < r^2 d1^2``, no square roots), the +-1 product of binary ones
    (Lowe's test on the Hamming distances themselves, in float32)."""
    if len(a) == 0 or len(b) == 0:
        return PairScores(None)
    if a.binary:
        packed_bytes = np.asarray(a.descriptors).shape[1]
        return PairScores(negated_dot(a.descriptors, b.descriptors),
                          lambda score: _hamming_from_score(score, packed_bytes))
    return PairScores(unit_scores(a.descriptors, b.descriptors), lambda s: 2.0 + 2.0 * s.astype(np.float64),
                      squared=True)


def nearest_neighbours(dist: np.ndarray, ratio: float, mutual: bool,
                       to_distance: Callable[[np.ndarray], np.ndarray] | None = None,
                       both_ways: bool = False) -> np.ndarray:
    """Matches from an (Na, Nb) float or integer score matrix (modified in place and restored): each row's
    lowest column (lowest index on ties) if ``best < ratio * second`` (when 0 < ratio < 1) and, with
    ``mutual``, the row is also that column's lowest row; with ``mutual`` and ``both_ways``, also
    ``best < ratio * (the column's second best)`` (the ratio test from the columns' side, as HLoc's
    ``NN-ratio``: hloc/matchers/nearest_neighbor.py:51-58). Scores must rank as distances do; ``to_distance``
    maps the best and second scores to the distances the ratio test compares (default: the scores themselves)."""
    rows = np.arange(dist.shape[0])
    nn = np.argmin(dist, axis=1)
    keep = np.ones(len(rows), dtype=bool)
    ratio_on = 0.0 < ratio < 1.0
    high = np.inf if dist.dtype.kind == "f" else np.iinfo(dist.dtype).max
    if ratio_on and dist.shape[1] > 1:
        best = dist[rows, nn]
        # the row minimum after removing the best is the second best
        dist[rows, nn] = high
        second = dist.min(axis=1)
        dist[rows, nn] = best
        keep &= _passes_ratio(best, second, ratio, to_distance)
    if mutual:
        keep &= _is_column_argmin(dist, rows, nn)
    if mutual and both_ways and ratio_on and dist.shape[0] > 1:
        idx = np.nonzero(keep)[0]  # each kept row is its column's lowest row: the column's best
        cols = nn[idx]
        best = dist[idx, cols]
        dist[idx, cols] = high
        second = dist.min(axis=0)[cols]  # the column minimum after removing the best is the second best
        dist[idx, cols] = best
        keep[idx] &= _passes_ratio(best, second, ratio, to_distance)
    idx = np.nonzero(keep)[0]
    return np.stack([idx, nn[idx]], axis=1).astype(np.int64)


def _passes_ratio(best: np.ndarray, second: np.ndarray, ratio: float,
                  to_distance: Callable[[np.ndarray], np.ndarray] | None) -> np.ndarray:
    if to_distance is not None:
        best, second = to_distance(best), to_distance(second)
    best, second = np.maximum(best, 0.0), np.maximum(second, 0.0)  # rounding below 0 counts as 0
    return best < ratio * second


def _is_column_argmin(dist: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Bool per i: is ``rows[i]`` the first row attaining column ``cols[i]``'s minimum.

    ``np.argmin(dist, axis=0)`` walks a C-ordered matrix column-wise (31 ms for 2048 x 2048 float32); the
    column minima (a row-wise reduction, < 1 ms) and a tie-break among the candidate rows give the same
    answer, except where another row with a different nearest column ties exactly with the minimum."""
    candidate = dist[rows, cols] <= dist.min(axis=0)[cols]
    first = np.zeros(len(rows), dtype=bool)
    _, index = np.unique(cols[candidate], return_index=True)  # lowest candidate row per column
    first[np.nonzero(candidate)[0][index]] = True
    return first


HAMMING_BACKENDS = ("auto", "torch", "numpy")
"""How the binary matcher forms its +-1 product: ``torch`` (int8 x int8 -> int32, ``torch._int_mm``: 2-4x
faster than float32 BLAS on CPUs with VNNI, 20-50x slower on some without), ``numpy`` (float32 BLAS),
``auto`` (the one :func:`auto_backend` measures faster on this machine, or ``$SYNTHLEAK_HAMMING_BACKEND``).
Both products are exact integers, so every backend gives the same matches."""

HAMMING_BACKEND_ENV = "SYNTHLEAK_HAMMING_BACKEND"
"""Environment variable that overrides what ``auto`` means (``auto``, ``torch`` or ``numpy``; unset: auto)."""

TORCH_MARGIN = 1.25
"""``auto`` takes torch only if its probe time is at least this many times below float32 BLAS's."""

PROBE_SHAPE = (512, 256, 32)
"""Probe product: query rows, map rows, bytes per descriptor (ORB's 256 bits). Small enough that one int8
product on a host without fast int8 kernels (~0.14 s on an AVX2 EPYC: 0.28 s at 512 x 512) stays well under 0.5 s."""


def _signs(packed: np.ndarray) -> np.ndarray:
    """(N, bits) int8 +-1 rows of packed binary descriptors (uint8 rows)."""
    signs = np.unpackbits(np.asarray(packed, dtype=np.uint8), axis=1).astype(np.int8)
    signs *= 2
    signs -= 1
    return signs


@lru_cache(maxsize=1)
def _torch_int_mm() -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """``a @ b.T`` of int8 matrices as int32 through torch, or None where torch is not installed or its
    ``_int_mm`` does not run on CPU (older releases)."""
    try:
        import torch

        from synthleak.errors import SynthleakError
        from synthleak.localize.deep import portable_torch

        # pinned as the learned tiers pin it, so that running first here does not leave torch on other kernels;
        # where torch chose its kernels already, an int8 product is exact on any of them
        with contextlib.suppress(SynthleakError):
            torch = portable_torch()
        probe = torch.ones((2, 8), dtype=torch.int8)
        if int(torch._int_mm(probe, probe.T)[0, 0]) != 8:
            return None
    except (ImportError, AttributeError, RuntimeError, NotImplementedError):
        return None

    def int_mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return torch._int_mm(torch.from_numpy(a), torch.from_numpy(b).T).numpy()

    return int_mm


def _float32_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b.T`` of int8 matrices as float32 through BLAS (exact for |entries| <= 2^24)."""
    return a.astype(np.float32) @ b.astype(np.float32).T


def backend_products() -> dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """The concrete backends that run here (``numpy`` always, ``torch`` where its ``_int_mm`` runs on CPU),
    each as its int8 ``a @ b.T`` product."""
    products = {"numpy": _float32_product}
    int_mm = _torch_int_mm()
    if int_mm is not None:
        products["torch"] = int_mm
    return products


def measure_backends(shape: tuple[int, int, int] = PROBE_SHAPE, repeats: int = 10, budget_s: float = 0.1,
                     products: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] | None = None,
                     ) -> dict[str, float]:
    """Seconds per ``shape`` (query rows, map rows, bytes) +-1 product of each backend (default:
    :func:`backend_products`), the minimum of up to ``repeats`` interleaved runs after a tiny warm-up; a backend
    stops repeating once its runs add up to ``budget_s`` (one run of a slow one is enough to rule it out)."""
    if repeats < 1:
        raise ValueError(f"measure_backends: repeats must be at least 1, got {repeats}")
    products = backend_products() if products is None else products
    rows_a, rows_b, num_bytes = shape
    rng = np.random.default_rng(0)
    a = _signs(rng.integers(0, 256, (rows_a, num_bytes), dtype=np.uint8))
    b = _signs(rng.integers(0, 256, (rows_b, num_bytes), dtype=np.uint8))
    best = {name: np.inf for name in products}
    spent = dict.fromkeys(products, 0.0)
    for product in products.values():
        product(a[:8], b[:8])  # first-call costs (library loading, thread pools)
    for _ in range(repeats):
        for name, product in products.items():
            if spent[name] >= budget_s:
                continue
            start = time.perf_counter()
            product(a, b)
            elapsed = time.perf_counter() - start
            best[name], spent[name] = min(best[name], elapsed), spent[name] + elapsed
    return best


def choose_backend(timings: dict[str, float], margin: float = TORCH_MARGIN) -> str:
    """``torch`` if its measured seconds are at least ``margin`` times below ``numpy``'s, else ``numpy``
    (also where torch was not measured)."""
    if "numpy" not in timings:
        raise ValueError(f"choose_backend: no 'numpy' timing to compare with (got {sorted(timings)})")
    torch_s = timings.get("torch")
    return "torch" if torch_s is not None and torch_s * margin <= timings["numpy"] else "numpy"


@lru_cache(maxsize=1)
def probe_timings() -> dict[str, float]:
    """This process's :func:`measure_backends` (run at first use under the thread settings of that moment,
    then cached): what ``auto`` rests on."""
    return measure_backends()


def _backend_from_env() -> str:
    value = os.environ.get(HAMMING_BACKEND_ENV, "").strip().lower() or "auto"
    if value not in HAMMING_BACKENDS:
        raise ValueError(f"{HAMMING_BACKEND_ENV}={os.environ[HAMMING_BACKEND_ENV]!r}: expected one of "
                         f"{', '.join(HAMMING_BACKENDS)}")
    return value


def auto_backend() -> str:
    """The concrete backend ``auto`` stands for: ``$SYNTHLEAK_HAMMING_BACKEND`` if it names one, else
    :func:`choose_backend` of :func:`probe_timings` (measured once per process)."""
    override = _backend_from_env()
    return override if override != "auto" else choose_backend(probe_timings())


def negated_dot(a: np.ndarray, b: np.ndarray, backend: str = "auto") -> np.ndarray:
    """(Na, Nb) ``-(sa . sb)`` of the +-1 bit rows of packed binary descriptors ``a``, ``b`` (uint8 rows):
    ``hamming = (bits + score) / 2``, so the score ranks as the Hamming distance does. int32 (torch) or
    float32 (numpy); exact either way (|score| <= bits, far below 2^24)."""
    if backend not in HAMMING_BACKENDS:
        raise ValueError(f"negated_dot: unknown backend {backend!r} (known: {', '.join(HAMMING_BACKENDS)})")
    concrete = auto_backend() if backend == "auto" else backend
    sa, sb = _signs(a), _signs(b)
    np.negative(sb, out=sb)
    if concrete == "torch":
        int_mm = _torch_int_mm()
        if int_mm is None:
            source = f" (from {HAMMING_BACKEND_ENV})" if backend == "auto" else ""
            raise ImportError(f"negated_dot: backend 'torch'{source} needs torch whose _int_mm runs on CPU "
                              "(the [learned] extra)")
        if len(sa) and len(sb):
            return int_mm(sa, sb)
    return _float32_product(sa, sb)


def _hamming_from_score(score: np.ndarray, packed_bytes: int) -> np.ndarray:
    """float32 Hamming distances from :func:`negated_dot` scores of ``packed_bytes``-byte descriptors."""
    return ((8 * packed_bytes + score) // 2).astype(np.float32)


def hamming(a: np.ndarray, b: np.ndarray, backend: str = "auto") -> np.ndarray:
    """(Na, Nb) float32 Hamming distances of packed binary descriptors (uint8 rows), exact."""
    return _hamming_from_score(negated_dot(a, b, backend), np.asarray(a).shape[1])


def _match_binary(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool, backend: str = "auto", *,
                  both_ways: bool = False) -> np.ndarray:
    """Hamming matching, same rules as the float matcher (Lowe's test on the Hamming distances themselves,
    in float32; the nearest neighbours straight from the product's scores)."""
    packed_bytes = np.asarray(a).shape[1]
    return nearest_neighbours(negated_dot(a, b, backend), ratio, mutual,
                              to_distance=lambda score: _hamming_from_score(score, packed_bytes), both_ways=both_ways)
