"""Line-cloud maps: privacy-preserving localization from 2D keypoint <-> 3D line matches.

Speciale, Schönberger, Kang, Sinha, Pollefeys, "Privacy Preserving Image-Based Localization", CVPR 2019: each
map point ``X`` is replaced by a 3D line through it with a uniformly random direction ``d`` (the *anchor* is the
line's point nearest the world origin); the map stores the line, not where on it ``X`` was. A query keypoint
is a ray through the camera centre; it must meet its matched line, so the query pose is a generalized relative
pose between the central query camera and the "generalized camera" of the lines (Pless, CVPR 2003):
``x^T (R m + [t]_x R d) = 0`` with the line's Plücker moment ``m = anchor x d``
and ``cam_from_world = [R | t]``.

Solver: LO-RANSAC (seeded) over the minimal 6-line generalized relative pose solver ``p6L`` (Stewénius et al.,
"Solutions to minimal generalized relative pose problems", OMNIVIS 2005; PoseLib's ``gen_relpose_6pt``),
scored by the point-to-line reprojection error (pixels from the keypoint to the image of its 3D line) with a
cheirality check, locally optimized and finally refined by ``scipy.optimize.least_squares`` on that error.

On disk (``lines.npz`` of a map built with ``[localize] representation = "line-cloud"``): the Plücker coordinates
``directions`` (P, 3) and ``moments`` (P, 3) ``m = anchor x d`` on a 1e-9 grid (the anchor is ``d x m``), plus
``instance`` (P,) server-side labels and ``track_length`` (P,). The file holds no point of any line: the moment
is perpendicular to every point of its line, while an anchor lies within r of its map point X whenever
``|X . d| < r`` (a chance of r / |X|: 0.3 % of the points for r = 1 cm, 3 m from the origin).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from synthleak.core.types import Camera
from synthleak.localize.store import MapData, MapError, read_map_features, read_map_meta
from synthleak.seeding import derive_seed

LINES_FILE = "lines.npz"
GRID = 1e-9
"""Stored coordinates are rounded to multiples of this (metres; unitless for directions): portable bytes."""
LIFT_SEED_KEY = "line-cloud"
"""``derive_seed(LIFT_ROOT_SEED, LIFT_SEED_KEY, tier, inputs_sha256)`` seeds a map's lift."""
LIFT_ROOT_SEED = 0
SAMPLE_SIZE = 6
PRETEST_MATCHES = 48
"""Matches a minimal solution is first scored on (it is scored on all only if not clearly worse than the best)."""
LINE_ORIGIN_OFFSET_M = 1e3
"""The solver gets each line as a ray starting this far behind the anchor, so PoseLib's cheirality filter (a
ray's point must lie ahead of its origin) holds whichever side of the anchor the map point was (a line has no
front); the Plücker moment, all the constraint reads, does not change."""


def lift_seed(tier: str, inputs_sha256: str) -> int:
    """The lift's seed of a map: from the project's :func:`~synthleak.seeding.derive_seed`, keyed by the map's
    tier and inputs' content hash (the same inputs, the same lines)."""
    return derive_seed(LIFT_ROOT_SEED, LIFT_SEED_KEY, tier, inputs_sha256)


def _on_grid(a: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(a, np.float64) / GRID) * GRID


def lift_to_lines(points3d: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(directions, anchors)``: a uniformly random unit direction per point (``default_rng(seed)``, normalised
    Gaussian samples) and each line's point nearest the world origin, both on the :data:`GRID`."""
    points3d = np.asarray(points3d, np.float64).reshape(-1, 3)
    d = np.random.default_rng(int(seed)).normal(size=points3d.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    anchors = points3d - np.sum(points3d * d, axis=1, keepdims=True) * d
    return _on_grid(d), _on_grid(anchors)


@dataclass
class LineCloud:
    """A map's lines in memory: unit ``directions`` (P, 3), ``anchors`` (P, 3) (``d x m`` of the stored moments),
    ``instance`` (P,) labels."""

    directions: np.ndarray
    anchors: np.ndarray
    instance: np.ndarray

    def __len__(self) -> int:
        return len(self.directions)


@dataclass
class LineMapData(MapData):
    """A line-cloud map in memory: :class:`MapData` whose ``point_index`` indexes ``lines`` (``xyz`` is empty:
    the map holds no points)."""

    lines: LineCloud | None = None


def write_lines(path: Path, directions: np.ndarray, anchors: np.ndarray, instance: np.ndarray,
                track_length: np.ndarray) -> None:
    """Write ``lines.npz``: each line's direction and Plücker moment (never a point of it), see the module."""
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    moments = np.cross(np.asarray(anchors, np.float64).reshape(-1, 3), directions)
    np.savez(path, directions=_on_grid(directions), moments=_on_grid(moments),
             instance=np.asarray(instance, np.int64), track_length=np.asarray(track_length, np.int64))


def read_line_map(map_dir: Path) -> LineMapData:
    """Load a line-cloud map (``map.json``, ``features.npz``, ``lines.npz``), every array checked."""
    map_dir = Path(map_dir)
    meta, camera = read_map_meta(map_dir)
    names, features, point_index = read_map_features(map_dir, camera)
    path = map_dir / LINES_FILE
    if not path.is_file():
        raise MapError(f"{path}: missing (a line-cloud map keeps its lines there: rebuild the map)")
    with np.load(path) as data:
        try:
            d, m, inst = data["directions"], data["moments"], data["instance"]
        except KeyError as exc:
            raise MapError(f"{path}: field {exc.args[0]!r} missing") from None
    if d.shape != m.shape or d.ndim != 2 or d.shape[1] != 3 or len(inst) != len(d):
        raise MapError(f"{path}: fields 'directions' {d.shape}, 'moments' {m.shape} and 'instance' "
                       f"{inst.shape} must be (P, 3), (P, 3) and (P,)")
    if len(d) and np.abs(np.linalg.norm(d, axis=1) - 1.0).max() > 1e-6:
        raise MapError(f"{path}: field 'directions' holds vectors that are not unit length")
    if any(len(idx) and idx.max() >= len(d) for idx in point_index):
        raise MapError(f"{map_dir / 'features.npz'}: fields 'p3d_<i>' index past the {len(d)} lines")
    return LineMapData(meta, camera, names, features, point_index, np.zeros((0, 3)), inst,
                       lines=LineCloud(d, np.cross(d, m), inst))


# ---------------------------------------------------------------- geometry


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (a broadcast (3,) too): ``np.cross`` without its overhead."""
    a, b = np.broadcast_arrays(a, b)
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


class LineMatches:
    """2D keypoint <-> 3D line matches of one query, with what scoring and refinement reuse."""

    def __init__(self, keypoints: np.ndarray, directions: np.ndarray, anchors: np.ndarray, camera: Camera):
        self.keypoints = np.asarray(keypoints, np.float64).reshape(-1, 2)
        self.directions = np.asarray(directions, np.float64).reshape(-1, 3)
        self.anchors = np.asarray(anchors, np.float64).reshape(-1, 3)
        self.moments = _cross(self.anchors, self.directions)
        self.camera = camera
        n = len(self.keypoints)
        self.normalized = np.column_stack([(self.keypoints[:, 0] - camera.cx) / camera.fx,
                                           (self.keypoints[:, 1] - camera.cy) / camera.fy, np.ones(n)])
        self.bearings = self.normalized / np.linalg.norm(self.normalized, axis=1, keepdims=True)

    def __len__(self) -> int:
        return len(self.keypoints)

    def subset(self, index: np.ndarray) -> LineMatches:
        return LineMatches(self.keypoints[index], self.directions[index], self.anchors[index], self.camera)

    def _image_lines(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, t = pose[:3, :3], pose[:3, 3]
        d_c = self.directions @ r.T
        return self.moments @ r.T + _cross(t, d_c), d_c  # the camera-frame moment: x^T l = 0 on the image

    def residuals(self, pose: np.ndarray) -> np.ndarray:
        """Signed pixel distance from each keypoint to the image of its 3D line."""
        lines, _ = self._image_lines(pose)
        norm = np.hypot(lines[:, 0] / self.camera.fx, lines[:, 1] / self.camera.fy)
        return np.sum(lines * self.normalized, axis=1) / np.maximum(norm, 1e-300)

    def jacobian(self, pose: np.ndarray) -> np.ndarray:
        """(N, 6) d residual / d (w, dt) for the update ``R <- exp([w]_x) R, t <- t + dt``."""
        r, t = pose[:3, :3], pose[:3, 3]
        lines, d_c = self._image_lines(pose)
        rm = self.moments @ r.T
        scale = np.array([1.0 / self.camera.fx ** 2, 1.0 / self.camera.fy ** 2, 0.0])
        norm = np.maximum(np.hypot(lines[:, 0] / self.camera.fx, lines[:, 1] / self.camera.fy), 1e-300)
        dot = np.sum(lines * self.normalized, axis=1)
        g = self.normalized / norm[:, None] - (dot / norm ** 3)[:, None] * lines * scale  # d residual / d line
        # line' = line + w x Rm + t x (w x Rd) + dt x Rd, so g.line' - g.line = w.(Rm x g + Rd x (g x t)) + ...
        return np.concatenate([_cross(rm, g) + _cross(d_c, _cross(g, t)), _cross(d_c, g)], axis=1)

    def in_front(self, pose: np.ndarray, index: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Whether the point of each line (of ``index``) nearest its keypoint's ray lies in front of the camera."""
        r, t = pose[:3, :3], pose[:3, 3]
        d_c, p_c, b = self.directions[index] @ r.T, self.anchors[index] @ r.T + t, self.bearings[index]
        # closest points of the ray s*b and the line p_c + u*d_c: s = (bd * (d.p) - b.p) / (bd^2 - 1)
        bd, bp, dp = np.sum(b * d_c, 1), np.sum(b * p_c, 1), np.sum(d_c * p_c, 1)
        denom = bd * bd - 1.0
        return np.where(np.abs(denom) > 1e-12, (bd * dp - bp) / np.where(denom == 0, 1.0, denom), 1.0) > 0

    def inliers(self, pose: np.ndarray, max_error_px: float) -> np.ndarray:
        mask = np.abs(self.residuals(pose)) < max_error_px
        idx = np.nonzero(mask)[0]
        mask[idx] = self.in_front(pose, idx)
        return mask


def line_residuals_px(cam_from_world: np.ndarray, keypoints: np.ndarray, directions: np.ndarray,
                      anchors: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Signed pixel distance from each keypoint to the image of its 3D line, and whether the line's point
    nearest the keypoint's ray lies in front of the camera (cheirality)."""
    matches = LineMatches(keypoints, directions, anchors, camera)
    return matches.residuals(cam_from_world), matches.in_front(cam_from_world)


def _updated(pose: np.ndarray, x: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix() @ pose[:3, :3]
    out[:3, 3] = pose[:3, 3] + x[3:]
    return out


def refine_pose(cam_from_world: np.ndarray, matches: LineMatches, loss: str = "linear", f_scale: float = 1.0,
                max_nfev: int | None = None) -> np.ndarray:
    """``cam_from_world`` minimizing the point-to-line reprojection error (pixels) of ``matches``
    (``scipy.optimize.least_squares``, analytic Jacobian; ``loss``/``f_scale`` as there)."""
    sol = least_squares(lambda x: matches.residuals(_updated(cam_from_world, x)), np.zeros(6),
                        jac=lambda x: matches.jacobian(_updated(cam_from_world, x)), loss=loss, f_scale=f_scale,
                        max_nfev=max_nfev, method="trf" if loss != "linear" else "lm")
    return _updated(cam_from_world, sol.x)


def minimal_poses(bearings: np.ndarray, directions: np.ndarray, anchors: np.ndarray) -> list[np.ndarray]:
    """The ``cam_from_world`` poses (4x4) of the p6L solver on 6 (unit bearing, line) matches."""
    import poselib

    origins = anchors - LINE_ORIGIN_OFFSET_M * directions
    poses = []
    for s in poselib.gen_relpose_6pt(origins, directions, np.zeros_like(bearings), bearings):
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = s.R, s.t  # PoseLib: X_2 = R X_1 + t, here X_cam = R X_world + t
        poses.append(pose)
    return poses


LINE_NOISE_FLOOR_PX = 2.0
"""The point-to-line threshold never goes below this: the keypoints' own localization error."""


def equivalent_line_threshold(point_max_error_px: float, camera: Camera) -> float:
    """The point-to-line threshold (pixels) under which a keypoint falling anywhere in the image is a chance inlier
    as often as it is under the point server's ``point_max_error_px``: a disc of radius r (area pi r^2) against a
    band of half-width r' along an image line as long as the image diagonal d (area 2 r' d), so
    r' = pi r^2 / (2 d); never under :data:`LINE_NOISE_FLOOR_PX`. With 12 px at 480x360 that is 0.38 px, so the
    floor: 2 px. At the point server's own threshold a line cloud accepts queries of another room (measured:
    21-30 chance inliers on 8 wrong-room views, against 8-9 for points; ``tests/test_line_cloud.py``)."""
    diagonal = math.hypot(camera.width, camera.height)
    return max(LINE_NOISE_FLOOR_PX, math.pi * point_max_error_px ** 2 / (2.0 * diagonal))


@dataclass(frozen=True)
class LineRansacOptions:
    """LO-RANSAC settings. ``confidence`` and the trial bounds are lower than pycolmap's PnP defaults
    (0.99999, 100..10000): a p6L sample costs about 1 ms (P3P: microseconds)."""

    max_error_px: float = 12.0
    confidence: float = 0.9999
    min_trials: int = 20
    max_trials: int = 2000
    local_optimization: bool = True
    lo_max_matches: int = 200
    """LO refits a seeded subset of at most this many inliers (the final refinement uses all)."""


def estimate_pose_from_lines(keypoints: np.ndarray, directions: np.ndarray, anchors: np.ndarray,
                             camera: Camera, options: LineRansacOptions | None = None, seed: int = 0
                             ) -> dict | None:
    """Pose of a query from matches ``keypoints[i] <-> line (directions[i], anchors[i])``, or None.

    Returns what ``pycolmap.estimate_and_refine_absolute_pose`` returns for points: ``{"cam_from_world":
    pycolmap.Rigid3d, "inlier_mask": (N,) bool, "num_inliers": int}`` (+ ``num_trials``; inliers: point-to-line
    error under ``max_error_px`` and in front of the camera). ``seed`` seeds the sampling."""
    options = options or LineRansacOptions()
    matches = LineMatches(keypoints, directions, anchors, camera)
    n, thr = len(matches), float(options.max_error_px)
    if n < SAMPLE_SIZE:
        return None
    rng = np.random.default_rng(seed)
    probe = matches.subset(np.sort(rng.choice(n, min(n, PRETEST_MATCHES), replace=False)))
    best_pose, best_mask, best_count = None, np.zeros(n, bool), 0
    trials, needed = 0, options.max_trials
    while trials < max(needed, options.min_trials) and trials < options.max_trials:
        trials += 1
        sample = rng.choice(n, SAMPLE_SIZE, replace=False)
        for pose in minimal_poses(matches.bearings[sample], matches.directions[sample], matches.anchors[sample]):
            # pre-test on a fixed subset (most of p6L's up to 64 roots are far off): skip a clearly worse pose
            if best_count and (np.abs(probe.residuals(pose)) < thr).mean() < 0.5 * best_count / n:
                continue
            mask = matches.inliers(pose, thr)
            count = int(mask.sum())
            if count <= best_count:
                continue
            if options.local_optimization and count > SAMPLE_SIZE:  # LO-RANSAC (Chum et al., DAGM 2003)
                idx = np.nonzero(mask)[0]
                if len(idx) > options.lo_max_matches:
                    idx = np.sort(rng.choice(idx, options.lo_max_matches, replace=False))
                lo = refine_pose(pose, matches.subset(idx), max_nfev=10)
                lo_mask = matches.inliers(lo, thr)
                if lo_mask.sum() > count:
                    pose, mask, count = lo, lo_mask, int(lo_mask.sum())
            best_pose, best_mask, best_count = pose, mask, count
            w = count / n
            needed = int(np.ceil(np.log(1 - options.confidence) / np.log(max(1 - w ** SAMPLE_SIZE, 1e-12))))
    if best_pose is None or best_count < SAMPLE_SIZE:
        return None
    pose, mask = best_pose, best_mask
    for _ in range(2):  # refine on the inliers (robust to the ones a line cannot tell apart), re-select them
        refined = refine_pose(pose, matches.subset(np.nonzero(mask)[0]), loss="huber", f_scale=1.0)
        refined_mask = matches.inliers(refined, thr)
        if refined_mask.sum() < 0.9 * best_count:  # moved off the consensus: keep what we have
            break
        converged = np.array_equal(refined_mask, mask)
        pose, mask = refined, refined_mask
        if converged:
            break
    return {"cam_from_world": pycolmap.Rigid3d(pose[:3]), "inlier_mask": mask, "num_inliers": int(mask.sum()),
            "num_trials": trials}
