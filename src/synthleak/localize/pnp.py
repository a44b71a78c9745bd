"""RANSAC PnP with refinement: a query's pose from its 2D-3D matches, by COLMAP (pycolmap) or poselib.

Both run LO-RANSAC over P3P with the same stopping rule, COLMAP's defaults as HLoc leaves them
(``hloc/localize_sfm.py`` sets only the threshold): stop once a model's inlier ratio makes a better one unlikely
at confidence 0.99999 (times 3), after at least 100 and at most 10,000 trials; then the pose is refined on its
inliers (robust least squares). The solvers differ in how each trial and the local optimisation are computed:
poselib's (Larsson, "PoseLib - Minimal Solvers for Camera Pose Estimation", 2020; P3P of Persson and Nordberg,
ECCV 2018) costs about half of COLMAP's on the same matches, which matters where most matches are chance (HLoc's
mutual-NN servers run every query to the trial cap), but its local optimisation finds fewer inliers than
COLMAP's on some queries near the acceptance bar, so it is not the default (``benchmarks/pnp.py`` measures cost,
inliers and moved acceptances of both on a study's own queries). Keypoints come undistorted, with the pinhole
camera (:func:`synthleak.localize.localizer.undistorted_keypoints`): a distorted camera model costs COLMAP twice
as much per trial for the same inliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synthleak.core.types import Camera

PNP_SOLVERS = ("colmap", "poselib")
"""Values of ``[localize] pnp_solver``."""

CONFIDENCE = 0.99999
MIN_TRIALS = 100
MAX_TRIALS = 10_000
TRIALS_MULTIPLIER = 3.0
"""COLMAP's RANSAC defaults (``pycolmap.RANSACOptions``), which HLoc keeps."""


@dataclass
class PoseEstimate:
    """A solver's answer: ``cam_from_world`` (3x4) and which matches are inliers."""

    cam_from_world: np.ndarray
    inlier_mask: np.ndarray


def estimate_pose(points2d: np.ndarray, points3d: np.ndarray, camera: Camera, max_error_px: float, seed: int,
                  solver: str = "colmap") -> PoseEstimate | None:
    """RANSAC PnP and refinement of the pinhole ``camera``'s keypoints ``points2d`` (N, 2) against ``points3d``
    (N, 3); None when no model has 3 inliers (COLMAP's failure; poselib's answer is held to the same bar)."""
    points2d = np.ascontiguousarray(points2d, dtype=np.float64)
    points3d = np.ascontiguousarray(points3d, dtype=np.float64)
    if solver == "poselib":
        return _poselib(points2d, points3d, camera, max_error_px, seed)
    if solver == "colmap":
        return _colmap(points2d, points3d, camera, max_error_px, seed)
    raise ValueError(f"unknown PnP solver {solver!r} (known: {', '.join(PNP_SOLVERS)})")


def _colmap(points2d: np.ndarray, points3d: np.ndarray, camera: Camera, max_error_px: float, seed: int
            ) -> PoseEstimate | None:
    import pycolmap

    from synthleak.core.dataset import pycolmap_camera

    options = pycolmap.AbsolutePoseEstimationOptions()
    options.ransac.max_error = float(max_error_px)
    options.ransac.random_seed = int(seed)
    options.ransac.confidence = CONFIDENCE
    options.ransac.min_num_trials, options.ransac.max_num_trials = MIN_TRIALS, MAX_TRIALS
    options.ransac.dyn_num_trials_multiplier = TRIALS_MULTIPLIER
    est = pycolmap.estimate_and_refine_absolute_pose(points2d, points3d, pycolmap_camera(camera), options)
    if est is None:
        return None
    return PoseEstimate(np.asarray(est["cam_from_world"].matrix()), np.asarray(est["inlier_mask"], dtype=bool))


def _poselib(points2d: np.ndarray, points3d: np.ndarray, camera: Camera, max_error_px: float, seed: int
             ) -> PoseEstimate | None:
    import poselib

    cam = {"model": "PINHOLE", "width": int(camera.width), "height": int(camera.height),
           "params": [float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)]}
    ransac = {"max_reproj_error": float(max_error_px), "seed": int(seed), "success_prob": CONFIDENCE,
              "min_iterations": MIN_TRIALS, "max_iterations": MAX_TRIALS, "dyn_num_trials_mult": TRIALS_MULTIPLIER}
    pose, info = poselib.estimate_absolute_pose(points2d, points3d, cam, ransac, {})
    inliers = np.asarray(info.get("inliers", []), dtype=bool)
    if len(points2d) < 3 or inliers.sum() < 3 or not np.isfinite(pose.Rt).all():
        return None
    return PoseEstimate(np.asarray(pose.Rt, dtype=np.float64), inliers)
