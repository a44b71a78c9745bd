"""Placement metrics against exact ground truth: rotation (:func:`rotation_block`, then the symmetry-aware
:func:`synthleak.geometry.poses.rotation_error_deg`), centre distance, 3D IoU.

Object canonical frames have +z up and their origin at the bottom centre of the bounding box, which
spans ``[-x/2, x/2] x [-y/2, y/2] x [0, z]`` for extents ``(x, y, z)``; the box centre is ``(0, 0, z/2)``.
Poses may be similarities ``[s R | t]`` (the Sim(3) aligner); the scale is factored out of rotations and
applied to the box.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection

DEFAULT_THRESHOLDS: tuple[tuple[float, float], ...] = ((10.0, 0.25), (30.0, 0.5), (60.0, 2.0))


def rotation_block(matrix: np.ndarray, name: str) -> np.ndarray:
    """The 3x3 rotation of a rotation, a 4x4 pose or a similarity ``[s R | t]`` (the scale divided out);
    a ValueError naming ``name`` for a wrong shape, non-finite entries or a reflection."""
    arr = np.asarray(matrix, dtype=np.float64)
    if arr.shape not in ((3, 3), (4, 4)):
        raise ValueError(f"{name}: expected a 3x3 rotation or 4x4 pose, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: non-finite entries")
    rot = arr[:3, :3]
    det = np.linalg.det(rot)
    if det <= 0:
        raise ValueError(f"{name}: rotation block has determinant {det:.3g} <= 0")
    return rot / np.cbrt(det)


def _pose(matrix: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(R, t, s) of a 4x4 similarity pose."""
    arr = np.asarray(matrix, dtype=np.float64)
    if arr.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 pose, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: non-finite entries")
    det = np.linalg.det(arr[:3, :3])
    if det <= 0:
        raise ValueError(f"{name}: rotation block has determinant {det:.3g} <= 0")
    scale = float(np.cbrt(det))
    return arr[:3, :3] / scale, arr[:3, 3], scale


def _extents(extents: Sequence[float] | np.ndarray, name: str) -> np.ndarray:
    ext = np.asarray(extents, dtype=np.float64).reshape(-1)
    if ext.shape != (3,) or not np.all(np.isfinite(ext)) or np.any(ext <= 0):
        raise ValueError(f"{name}: expected three positive finite extents, got {extents!r}")
    return ext


def object_centre(world_from_object: np.ndarray, extents: Sequence[float] | np.ndarray) -> np.ndarray:
    """World position of the box centre ``(0, 0, z/2)`` of an object placed by a (similarity) pose."""
    rot, trans, scale = _pose(world_from_object, "world_from_object")
    ext = _extents(extents, "extents")
    return scale * rot @ np.array([0.0, 0.0, ext[2] / 2.0]) + trans


def translation_error_m(
    scene_from_object_est: np.ndarray,
    world_from_object_gt: np.ndarray,
    extents: Sequence[float] | np.ndarray,
    extents_est: Sequence[float] | np.ndarray | None = None,
) -> float:
    """Distance between the estimated and true bounding-box centres (metres).

    ``extents`` are the GT object's; ``extents_est`` (default: the same) the attacker object's, whose centre
    the estimate places.
    """
    est = object_centre(scene_from_object_est, extents if extents_est is None else extents_est)
    gt = object_centre(world_from_object_gt, extents)
    return float(np.linalg.norm(est - gt))


def box_halfspaces(pose: np.ndarray, extents: Sequence[float] | np.ndarray) -> np.ndarray:
    """(6, 4) halfspaces ``[a | b]`` (``a·x + b <= 0``) of the box of an object placed by ``pose``."""
    rot, trans, scale = _pose(pose, "pose")
    ext = _extents(extents, "extents") * scale
    lo = np.array([-ext[0] / 2, -ext[1] / 2, 0.0])
    hi = np.array([ext[0] / 2, ext[1] / 2, ext[2]])
    rows = []
    for axis in range(3):
        normal = rot[:, axis]
        # n·(x - t) <= hi  and  -n·(x - t) <= -lo
        rows.append(np.concatenate([normal, [-hi[axis] - normal @ trans]]))
        rows.append(np.concatenate([-normal, [lo[axis] + normal @ trans]]))
    return np.array(rows)


def box_volume(extents: Sequence[float] | np.ndarray, scale: float = 1.0) -> float:
    ext = _extents(extents, "extents")
    return float(np.prod(ext * scale))


def iou_3d(
    pose_a: np.ndarray,
    extents_a: Sequence[float] | np.ndarray,
    pose_b: np.ndarray,
    extents_b: Sequence[float] | np.ndarray,
) -> float:
    """Exact IoU of two oriented boxes (convex polytope intersection); 0 when disjoint or only touching."""
    halfspaces = np.vstack([box_halfspaces(pose_a, extents_a), box_halfspaces(pose_b, extents_b)])
    vol_a = box_volume(extents_a, _pose(pose_a, "pose_a")[2])
    vol_b = box_volume(extents_b, _pose(pose_b, "pose_b")[2])
    a, b = halfspaces[:, :3], halfspaces[:, 3]
    norms = np.linalg.norm(a, axis=1)
    # Chebyshev centre: maximise r subject to a_i x + r |a_i| <= -b_i
    res = linprog(
        c=[0.0, 0.0, 0.0, -1.0],
        A_ub=np.hstack([a, norms[:, None]]),
        b_ub=-b,
        bounds=[(None, None)] * 3 + [(0.0, None)],
        method="highs",
    )
    if not res.success or res.x[3] <= 1e-9 * max(vol_a, vol_b) ** (1 / 3):
        return 0.0
    inter = HalfspaceIntersection(halfspaces, res.x[:3])
    vol_i = float(ConvexHull(inter.intersections).volume)
    return float(vol_i / (vol_a + vol_b - vol_i))


def success_at(
    rot_err_deg: float,
    trans_err_m: float,
    thresholds: Sequence[tuple[float, float]] = DEFAULT_THRESHOLDS,
) -> list[bool]:
    """For each (degrees, metres) pair: rotation and translation errors both within it (NaN fails)."""
    rot = float(rot_err_deg)
    trans = float(trans_err_m)
    return [bool(rot <= dr and trans <= dt) for dr, dt in thresholds]


def success_rates(
    rot_err_deg: Sequence[float],
    trans_err_m: Sequence[float],
    thresholds: Sequence[tuple[float, float]] = DEFAULT_THRESHOLDS,
) -> list[float]:
    """Fraction of pairs succeeding at each threshold pair (NaN errors count as failures); NaN if empty."""
    rot = np.asarray(rot_err_deg, dtype=np.float64)
    trans = np.asarray(trans_err_m, dtype=np.float64)
    if rot.shape != trans.shape:
        raise ValueError(f"rot_err_deg / trans_err_m: shapes differ, {rot.shape} vs {trans.shape}")
    if rot.size == 0:
        return [math.nan for _ in thresholds]
    return [float(np.mean((rot <= dr) & (trans <= dt))) for dr, dt in thresholds]
