"""Score one placement against ground truth: the metric fields of a results row."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from synthleak.evaluate.metrics import iou_3d, rotation_block, translation_error_m
from synthleak.geometry.poses import rotation_error_deg


def score_placement(
    scene_from_object_est: np.ndarray | None,
    world_from_object_gt: np.ndarray | None,
    gt_extents: Sequence[float] | np.ndarray | None,
    est_extents: Sequence[float] | np.ndarray,
    symmetry: str = "none",
    object_from_local: np.ndarray | None = None,
) -> dict:
    """``rot_err_deg``, ``trans_err_m``, ``iou3d`` and ``scene_from_object_est`` (nested list) of one pair.

    ``scene_from_object_est`` is the aligner's output; when the attacker's local model is an SfM frame,
    pass its ``object_from_local`` (scoring-only GT registration) and the estimate is re-expressed as
    ``scene_from_local @ inv(object_from_local)``. Without GT presence (``world_from_object_gt`` None) or
    without an estimate the errors are NaN. ``est_extents`` are the attacker object's (it places its own
    box), ``gt_extents`` the scene object's; the rotation error uses the scene object's ``symmetry``.
    """
    nan = {"rot_err_deg": math.nan, "trans_err_m": math.nan, "iou3d": math.nan}
    if scene_from_object_est is None:
        return {**nan, "scene_from_object_est": None}
    est = np.asarray(scene_from_object_est, dtype=np.float64)
    if object_from_local is not None:
        est = est @ np.linalg.inv(np.asarray(object_from_local, dtype=np.float64))
    out = {**nan, "scene_from_object_est": est.tolist()}
    if world_from_object_gt is None:
        return out
    if gt_extents is None:
        raise ValueError("gt_extents: required when world_from_object_gt is given")
    gt = np.asarray(world_from_object_gt, dtype=np.float64)
    out["rot_err_deg"] = rotation_error_deg(rotation_block(est, "R_est"), rotation_block(gt, "R_gt"), symmetry)
    out["trans_err_m"] = translation_error_m(est, gt, gt_extents, extents_est=est_extents)
    out["iou3d"] = iou_3d(est, est_extents, gt, gt_extents)
    return out
