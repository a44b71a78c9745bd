"""Paired-point maps: a line cloud whose every line passes through two map points.

Lee, Kim, Yun, Hong, "Paired-Point Lifting for Enhanced Privacy-Preserving Visual Localization", CVPR 2023
(PPL): instead of one random line per point (Speciale et al. CVPR 2019, :mod:`synthleak.localize.line_cloud`),
the triangulated points are split into random pairs and each pair is joined by the line through both. Both
points' descriptors map to that one line, so a query keypoint matched to either gives a 2D point <-> 3D line
match, solved as a line cloud is (:func:`~synthleak.localize.line_cloud.estimate_pose_from_lines`, unchanged).

Pairing (:func:`pair_points`, seeded from the map's content like :func:`~synthleak.localize.line_cloud.lift_seed`):
a random permutation, taken two by two. A pair closer than :data:`MIN_PAIR_DISTANCE_M` is re-drawn (a few seeded
rounds, each reshuffling the close pairs' points with as many points of other pairs): PPL hides which of a line's
two points sits where, which is worth little when the two are centimetres apart. Pairs still close after the
rounds are kept (a map whose points all lie within that distance has no other pairing). An odd point left over
gets a line of its own with a uniformly random direction (:func:`~synthleak.localize.line_cloud.lift_to_lines`).

On disk (``paired_lines.npz`` of a map built with ``[localize] representation = "paired-point"``), each line
once: ``directions`` (L, 3) and Plücker ``moments`` (L, 3) on the line cloud's 1e-9 grid; per *slot* (one slot
per triangulated point, what ``features.npz``'s ``p3d_<i>`` index): ``line`` (P,) the slot's line, ``instance``
(P,) its own server-side label, ``track_length`` (P,). No coordinate is stored per slot, and no point of any
line. The same inputs give the same bytes.

In memory (:func:`read_paired_point_map`) the map is a :class:`~synthleak.localize.line_cloud.LineMapData` whose
``lines`` and ``instance`` are per slot (each slot carries its line's direction and anchor and its own label), so
the localizer solves it as a line cloud and the defense's instance counts still tell a line's two points apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthleak.localize.line_cloud import (
    LIFT_ROOT_SEED,
    LineCloud,
    LineMapData,
    check_unit_directions,
    lift_to_lines,
    on_grid,
    read_line_fields,
)
from synthleak.localize.store import MapError, read_map_features, read_map_meta
from synthleak.seeding import derive_seed

PAIRED_LINES_FILE = "paired_lines.npz"
PAIR_SEED_KEY = "paired-point"
"""``derive_seed(LIFT_ROOT_SEED, PAIR_SEED_KEY, tier, inputs_sha256)`` seeds a map's pairing."""
MIN_PAIR_DISTANCE_M = 0.1
"""Pairs closer than this are re-drawn (see the module)."""
PAIR_ROUNDS = 16
"""Re-drawing rounds at most."""


def pair_seed(tier: str, inputs_sha256: str) -> int:
    """The pairing seed of a map: keyed by its tier and inputs' content hash (the same inputs, the same lines)."""
    return derive_seed(LIFT_ROOT_SEED, PAIR_SEED_KEY, tier, inputs_sha256)


def pair_points(points3d: np.ndarray, seed: int, min_distance: float = MIN_PAIR_DISTANCE_M,
                rounds: int = PAIR_ROUNDS) -> tuple[np.ndarray, int | None]:
    """``(pairs, single)``: (P // 2, 2) disjoint point indices, seeded (``default_rng(seed)``), pairs under
    ``min_distance`` re-drawn for up to ``rounds`` rounds; and the index of the point left over (odd P) or None."""
    points3d = np.asarray(points3d, np.float64).reshape(-1, 3)
    rng = np.random.default_rng(int(seed))
    perm = rng.permutation(len(points3d))
    single = int(perm[-1]) if len(perm) % 2 else None
    pairs = perm[: len(perm) - len(perm) % 2].reshape(-1, 2)
    for _ in range(rounds):
        close = np.linalg.norm(points3d[pairs[:, 0]] - points3d[pairs[:, 1]], axis=1) < min_distance
        if not close.any():
            break
        bad, good = np.nonzero(close)[0], np.nonzero(~close)[0]
        mix = np.concatenate([bad, rng.choice(good, min(len(good), len(bad)), replace=False)])
        pairs[mix] = rng.permutation(pairs[mix].ravel()).reshape(-1, 2)
    return pairs, single


@dataclass
class PairedLines:
    """Unique lines (``directions``, ``anchors``: (L, 3), on the grid) and each point's (slot's) ``line`` (P,)."""

    directions: np.ndarray
    anchors: np.ndarray
    line: np.ndarray

    def __len__(self) -> int:
        return len(self.directions)


def lift_pairs(points3d: np.ndarray, seed: int, min_distance: float = MIN_PAIR_DISTANCE_M) -> PairedLines:
    """PPL (Lee et al. CVPR 2023): the line through each pair of :func:`pair_points` (an odd point left over: a
    random line through it), as unit directions and each line's point nearest the world origin, on the grid."""
    points3d = np.asarray(points3d, np.float64).reshape(-1, 3)
    pairs, single = pair_points(points3d, seed, min_distance)
    a, b = points3d[pairs[:, 0]], points3d[pairs[:, 1]]
    d = b - a
    length = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(length == 0):  # coincident points: any line through them, seeded
        zero = length[:, 0] == 0
        d[zero] = np.random.default_rng(derive_seed(int(seed), "coincident")).normal(size=(int(zero.sum()), 3))
        length = np.linalg.norm(d, axis=1, keepdims=True)
    d /= length
    anchors = a - np.sum(a * d, axis=1, keepdims=True) * d
    line = np.empty(len(points3d), np.int64)
    line[pairs[:, 0]] = line[pairs[:, 1]] = np.arange(len(pairs))
    if single is not None:
        d1, a1 = lift_to_lines(points3d[[single]], derive_seed(int(seed), "single"))
        d, anchors = np.concatenate([d, d1]), np.concatenate([anchors, a1])
        line[single] = len(pairs)
    return PairedLines(on_grid(d), on_grid(anchors), line)


def write_paired_lines(path: Path, lines: PairedLines, instance: np.ndarray, track_length: np.ndarray) -> None:
    """Write ``paired_lines.npz`` (see the module): each line's direction and moment once, per slot its line,
    label and track length (deterministic bytes)."""
    d = np.asarray(lines.directions, np.float64).reshape(-1, 3)
    arrays = {"directions": on_grid(d), "moments": on_grid(np.cross(np.asarray(lines.anchors, np.float64), d)),
              "line": np.asarray(lines.line, np.int64), "instance": np.asarray(instance, np.int64),
              "track_length": np.asarray(track_length, np.int64)}
    np.savez(path, **arrays)  # as lines.npz: numpy writes fixed zip timestamps


def read_paired_point_map(map_dir: Path) -> LineMapData:
    """Load a paired-point map (``map.json``, ``features.npz``, ``paired_lines.npz``), every array checked; its
    ``lines`` and ``instance`` are per slot (``point_index`` indexes them), ``xyz`` is empty."""
    map_dir = Path(map_dir)
    meta, camera = read_map_meta(map_dir)
    names, features, point_index = read_map_features(map_dir, camera)
    path = map_dir / PAIRED_LINES_FILE
    d, m, line, inst = read_line_fields(path, ("directions", "moments", "line", "instance"), "a paired-point map")
    if d.shape != m.shape or d.ndim != 2 or d.shape[1] != 3 or line.ndim != 1 or inst.shape != line.shape:
        raise MapError(f"{path}: fields 'directions' {d.shape}, 'moments' {m.shape}, 'line' {line.shape} and "
                       f"'instance' {inst.shape} must be (L, 3), (L, 3), (P,) and (P,)")
    check_unit_directions(path, d)
    if len(line) and (line.min() < 0 or line.max() >= len(d)):
        raise MapError(f"{path}: field 'line' indexes past the {len(d)} lines")
    if len(d) and not np.isin(np.bincount(line, minlength=len(d)), (1, 2)).all():
        raise MapError(f"{path}: field 'line' must give every line one or two points")
    if any(len(idx) and idx.max() >= len(line) for idx in point_index):
        raise MapError(f"{map_dir / 'features.npz'}: fields 'p3d_<i>' index past the {len(line)} points")
    anchors = np.cross(d, m)
    return LineMapData(meta, camera, names, features, point_index, np.zeros((0, 3)), inst,
                       lines=LineCloud(d[line], anchors[line], inst))
