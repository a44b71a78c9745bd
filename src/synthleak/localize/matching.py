"""Nearest-neighbour descriptor matching with Lowe's ratio test and an optional mutual check."""

from __future__ import annotations

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


def match_features(a: Features, b: Features, ratio: float, mutual: bool) -> np.ndarray:
    """(M, 2) int indices ``(i in a, j in b)``; ratio <= 0 or >= 1 disables the ratio test."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int64)
    if a.binary:
        return _match_binary(a.descriptors, b.descriptors, ratio, mutual)
    # Lowe's test on squared distances: d0 < r d1  <=>  d0^2 < r^2 d1^2 (no square roots).
    return nearest_neighbours(squared_l2(a.descriptors, b.descriptors), ratio * ratio, mutual)


def nearest_neighbours(dist: np.ndarray, ratio: float, mutual: bool) -> np.ndarray:
    """Matches from an (Na, Nb) float distance matrix (modified in place and restored): each row's nearest
    column (lowest index on ties) if ``best < ratio * second`` (when 0 < ratio < 1) and, with ``mutual``,
    the row is also that column's nearest row."""
    rows = np.arange(dist.shape[0])
    nn = np.argmin(dist, axis=1)
    keep = np.ones(len(rows), dtype=bool)
    if 0.0 < ratio < 1.0 and dist.shape[1] > 1:
        best = dist[rows, nn]
        dist[rows, nn] = np.inf  # the row minimum after removing the best is the second best
        second = dist.min(axis=1)
        dist[rows, nn] = best
        best, second = np.maximum(best, 0.0), np.maximum(second, 0.0)  # rounding below 0 counts as 0
        keep &= best < ratio * second
    if mutual:
        keep &= _is_column_argmin(dist, rows, nn)
    idx = np.nonzero(keep)[0]
    return np.stack([idx, nn[idx]], axis=1).astype(np.int64)


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


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Na, Nb) float32 Hamming distances of packed binary descriptors (uint8 rows), exact.

    Bits become +-1 floats, so one BLAS product gives ``bits - 2 * hamming`` (integers far below 2^24, exact
    in float32): twice as fast here as OpenCV's brute-force popcount (2048 x 2048 ORB: 18 -> 9 ms)."""
    sa = np.unpackbits(np.asarray(a, dtype=np.uint8), axis=1).astype(np.float32)
    sb = np.unpackbits(np.asarray(b, dtype=np.uint8), axis=1).astype(np.float32)
    sa, sb = sa * 2.0 - 1.0, sb * 2.0 - 1.0
    dist = sa @ sb.T
    dist *= -0.5
    dist += 0.5 * sa.shape[1]
    return dist


def _match_binary(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool) -> np.ndarray:
    """Hamming matching, same rules as the float matcher (Lowe's test on the distances themselves)."""
    return nearest_neighbours(hamming(a, b), ratio, mutual)
