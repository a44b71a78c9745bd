"""Two-view verification of a query's matches: per (query, map image) pair, an essential matrix.

A server may keep, of the 2D-2D matches between the query and each retrieved map image, only the inliers of an
essential matrix estimated on that pair (pycolmap ``estimate_essential_matrix``: the 5-point solver of Nistér,
"An efficient solution to the five-point relative pose problem", PAMI 2004, in LO-RANSAC), and only from pairs
with at least ``min_inliers`` of them (COLMAP's two-view geometry asks for 15). What survives is what PnP or the
line solver sees. The check needs only both images' keypoints and intrinsics, which every map representation
keeps; it needs no 3D point and no map image pose. Its use here: a query of another place has no pair that
passes, so a line-cloud server rejects it without running its p6L RANSAC to the trial cap
(``docs/map-representations.md``, "Cost").
"""

from __future__ import annotations

import numpy as np
import pycolmap

from synthleak.core.dataset import pycolmap_camera
from synthleak.core.types import Camera

ESSENTIAL_MIN_MATCHES = 5
"""The 5-point solver's minimal sample: a pair with fewer matches cannot be verified."""


def essential_inliers(query_keypoints: np.ndarray, map_keypoints: np.ndarray, query_camera: pycolmap.Camera,
                      map_camera: pycolmap.Camera, max_error_px: float, seed: int = 0,
                      min_inliers: int = 0) -> np.ndarray:
    """(M,) bool: which matches ``query_keypoints[i] <-> map_keypoints[i]`` are inliers of the essential matrix
    LO-RANSAC finds (all False when it finds none), with COLMAP's two-view verification settings
    (``pycolmap.TwoViewGeometryOptions().ransac``: confidence 0.999, 100 to 10,000 trials, an inlier share of at
    least 25 % assumed) except ``max_error_px``, the threshold in pixels, and the seed.

    ``min_inliers``: the fewest inliers the caller accepts. The assumed inlier share is then at least
    ``min_inliers / M``, which caps the trials (COLMAP's ``min_inlier_ratio``) at what finds such a model with
    the same 0.999 confidence: at 15 of 20 matches that is 77 trials instead of 10,000, what a pair of 20 chance
    matches cost before."""
    n = len(query_keypoints)
    if n < ESSENTIAL_MIN_MATCHES:
        return np.zeros(n, bool)
    options = pycolmap.TwoViewGeometryOptions().ransac  # COLMAP's two-view RANSAC: 100-10000 trials, 0.999
    options.max_error = float(max_error_px)
    options.random_seed = int(seed)
    options.min_inlier_ratio = max(options.min_inlier_ratio, min(1.0, min_inliers / n))
    est = pycolmap.estimate_essential_matrix(np.asarray(query_keypoints, np.float64),
                                             np.asarray(map_keypoints, np.float64), query_camera, map_camera,
                                             options)
    if est is None:
        return np.zeros(n, bool)
    return np.asarray(est["inlier_mask"], dtype=bool)


def verified_matches(query_keypoints: np.ndarray, pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                     query_camera: Camera, map_camera: Camera, max_error_px: float, min_inliers: int,
                     seed: int = 0) -> list[np.ndarray]:
    """Per pair ``(matches (M, 2) query keypoint / map keypoint, map keypoints (K, 2), map points (K,))``, the
    ``(query keypoint, map point)`` matches (M', 2) that are essential-matrix inliers of a pair with at least
    ``min_inliers`` of them (an empty array for any other pair)."""
    qcam, mcam = pycolmap_camera(query_camera), pycolmap_camera(map_camera)
    out = []
    for matches, map_keypoints, map_points in pairs:
        keep = np.zeros(len(matches), bool)
        if len(matches) >= max(min_inliers, ESSENTIAL_MIN_MATCHES):
            keep = essential_inliers(query_keypoints[matches[:, 0]], map_keypoints[matches[:, 1]], qcam, mcam,
                                     max_error_px, seed, min_inliers)
            if keep.sum() < min_inliers:
                keep[:] = False
        out.append(np.stack([matches[keep, 0], map_points[matches[keep, 1]]], axis=1).astype(np.int64))
    return out
