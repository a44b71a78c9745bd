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
cheirality check (all roots of a sample pre-scored at once on a fixed subset), locally optimized and finally
refined by Levenberg-Marquardt on that error. A query is accepted at :func:`line_min_inliers`, the count at which
chance inliers accept it as rarely as the point server's ``min_inliers`` does.

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

import cv2
import numpy as np
import pycolmap

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


def on_grid(a: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(a, np.float64) / GRID) * GRID


def lift_to_lines(points3d: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(directions, anchors)``: a uniformly random unit direction per point (``default_rng(seed)``, normalised
    Gaussian samples) and each line's point nearest the world origin, both on the :data:`GRID`."""
    points3d = np.asarray(points3d, np.float64).reshape(-1, 3)
    d = np.random.default_rng(int(seed)).normal(size=points3d.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    anchors = points3d - np.sum(points3d * d, axis=1, keepdims=True) * d
    return on_grid(d), on_grid(anchors)


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
    np.savez(path, directions=on_grid(directions), moments=on_grid(moments),
             instance=np.asarray(instance, np.int64), track_length=np.asarray(track_length, np.int64))


def read_line_fields(path: Path, fields: tuple[str, ...], kind: str) -> list[np.ndarray]:
    """The arrays ``fields`` of a map's lines file ``path``; a :class:`MapError` naming the file (missing: ``kind``
    keeps its lines there) or the missing field."""
    if not path.is_file():
        raise MapError(f"{path}: missing ({kind} keeps its lines there: rebuild the map)")
    with np.load(path) as data:
        try:
            return [data[name] for name in fields]
        except KeyError as exc:
            raise MapError(f"{path}: field {exc.args[0]!r} missing") from None


def check_unit_directions(path: Path, directions: np.ndarray) -> None:
    """A :class:`MapError` naming ``path`` when a stored line direction is not unit length."""
    if len(directions) and np.abs(np.linalg.norm(directions, axis=1) - 1.0).max() > 1e-6:
        raise MapError(f"{path}: field 'directions' holds vectors that are not unit length")


def read_line_map(map_dir: Path) -> LineMapData:
    """Load a line-cloud map (``map.json``, ``features.npz``, ``lines.npz``), every array checked."""
    map_dir = Path(map_dir)
    meta, camera = read_map_meta(map_dir)
    names, features, point_index = read_map_features(map_dir, camera)
    path = map_dir / LINES_FILE
    d, m, inst = read_line_fields(path, ("directions", "moments", "instance"), "a line-cloud map")
    if d.shape != m.shape or d.ndim != 2 or d.shape[1] != 3 or len(inst) != len(d):
        raise MapError(f"{path}: fields 'directions' {d.shape}, 'moments' {m.shape} and 'instance' "
                       f"{inst.shape} must be (P, 3), (P, 3) and (P,)")
    check_unit_directions(path, d)
    if any(len(idx) and idx.max() >= len(d) for idx in point_index):
        raise MapError(f"{map_dir / 'features.npz'}: fields 'p3d_<i>' index past the {len(d)} lines")
    return LineMapData(meta, camera, names, features, point_index, np.zeros((0, 3)), inst,
                       lines=LineCloud(d, np.cross(d, m), inst))


# ---------------------------------------------------------------- geometry


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products along the last axis (broadcasting, e.g. a (3,) vector with an (N, 3) array): ``np.cross``
    without its overhead."""
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


class LineMatches:
    """2D keypoint <-> 3D line matches of one query, with what scoring and refinement reuse."""

    def __init__(self, keypoints: np.ndarray, directions: np.ndarray, anchors: np.ndarray, camera: Camera):
        self.keypoints = np.asarray(keypoints, np.float64).reshape(-1, 2)
        self.directions = np.asarray(directions, np.float64).reshape(-1, 3)
        self.anchors = np.asarray(anchors, np.float64).reshape(-1, 3)
        self.moments = _cross(self.anchors, self.directions)
        self.plucker = np.concatenate([self.moments, self.directions], axis=1)
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

    def _distances(self, lines: np.ndarray) -> np.ndarray:
        norm = np.hypot(lines[..., 0] / self.camera.fx, lines[..., 1] / self.camera.fy)
        return np.sum(lines * self.normalized, axis=-1) / np.maximum(norm, 1e-300)

    def residuals(self, pose: np.ndarray) -> np.ndarray:
        """Signed pixel distance from each keypoint to the image of its 3D line."""
        return self._distances(self._image_lines(pose)[0])

    def residuals_many(self, poses: np.ndarray) -> np.ndarray:
        """(K, N) :meth:`residuals` of K poses (K, 4, 4) at once: the camera-frame line of match i under pose k is
        ``[R_k | [t_k]_x R_k] (m_i, d_i)`` (the generalized essential matrix, Pless 2003), one matrix product."""
        r, t = poses[:, :3, :3], poses[:, :3, 3]
        e = _cross(t[:, None, :], r.transpose(0, 2, 1)).transpose(0, 2, 1)  # [t]_x R, column by column
        a = np.concatenate([r, e], axis=2).reshape(-1, 6)  # (3K, 6)
        lines = (self.plucker @ a.T).reshape(len(self), len(poses), 3).transpose(1, 0, 2)
        return self._distances(lines)

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
    out[:3, :3] = cv2.Rodrigues(np.asarray(x[:3], np.float64))[0] @ pose[:3, :3]  # cheaper than scipy's Rotation
    out[:3, 3] = pose[:3, 3] + x[3:]
    return out


def _cost(r: np.ndarray, huber: float | None) -> float:
    a = np.abs(r)
    if huber is None:
        return 0.5 * float(a @ a)
    return float(np.sum(np.where(a <= huber, 0.5 * a * a, huber * a - 0.5 * huber * huber)))


def refine_pose(cam_from_world: np.ndarray, matches: LineMatches, loss: str = "linear", f_scale: float = 1.0,
                max_nfev: int | None = None) -> np.ndarray:
    """``cam_from_world`` minimizing the point-to-line reprojection error (pixels) of ``matches``: Levenberg-
    Marquardt on the analytic Jacobian, ``loss`` ``"linear"`` or ``"huber"`` (iteratively reweighted, the kink at
    ``f_scale`` px), at most ``max_nfev`` steps (default 50). Six parameters: this loop costs about a quarter of
    what ``scipy.optimize.least_squares`` did per call (its overhead was most of it; cProfile on the benchmark)."""
    if loss not in ("linear", "huber"):
        raise ValueError(f"loss {loss!r}: 'linear' or 'huber'")
    huber = float(f_scale) if loss == "huber" else None
    pose, r = cam_from_world, matches.residuals(cam_from_world)
    cost, damping = _cost(r, huber), 1e-4
    for _ in range(max_nfev or 50):
        jac = matches.jacobian(pose)
        w = np.ones_like(r) if huber is None else np.minimum(1.0, huber / np.maximum(np.abs(r), 1e-300))
        jw = jac * w[:, None]
        hess, grad = jac.T @ jw, jw.T @ r
        while damping < 1e10:
            step = -np.linalg.solve(hess + damping * np.diag(np.diag(hess) + 1e-12), grad)
            cand = _updated(pose, step)
            r_cand = matches.residuals(cand)
            cost_cand = _cost(r_cand, huber)
            if cost_cand <= cost:
                pose, r, damping = cand, r_cand, max(damping / 10.0, 1e-12)
                break
            damping *= 10.0
        else:
            break  # no step lowers the cost: a minimum
        converged = cost - cost_cand <= 1e-10 * cost or np.abs(step).max() < 1e-12
        cost = cost_cand
        if converged:
            break
    return pose


def minimal_poses(bearings: np.ndarray, directions: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """The ``cam_from_world`` poses (K, 4, 4) of the p6L solver on 6 (unit bearing, line) matches."""
    import poselib

    origins = anchors - LINE_ORIGIN_OFFSET_M * directions
    sols = poselib.gen_relpose_6pt(origins, directions, np.zeros_like(bearings), bearings)
    poses = np.tile(np.eye(4), (len(sols), 1, 1))
    for pose, s in zip(poses, sols, strict=True):
        pose[:3, :3], pose[:3, 3] = s.R, s.t  # PoseLib: X_2 = R X_1 + t, here X_cam = R X_world + t
    return poses


LINE_NOISE_FLOOR_PX = 2.0
"""The point-to-line threshold never goes below this: the keypoints' own localization error."""


def equivalent_line_threshold(point_max_error_px: float, camera: Camera) -> float:
    """The point-to-line threshold (pixels) under which a keypoint falling anywhere in the image is a chance inlier
    as often as it is under the point server's ``point_max_error_px``: a disc of radius r (area pi r^2) against a
    band of half-width r' along an image line as long as the image diagonal d (area 2 r' d), so
    r' = pi r^2 / (2 d); never under :data:`LINE_NOISE_FLOOR_PX`. With 12 px at 480x360 that is 0.38 px, so the
    floor: 2 px, where a band is still several times the disc; :func:`line_min_inliers` makes up the rest."""
    diagonal = math.hypot(camera.width, camera.height)
    return max(LINE_NOISE_FLOOR_PX, math.pi * point_max_error_px ** 2 / (2.0 * diagonal))


# ---------------------------------------------------------------- the success rule

POINT_SAMPLE_SIZE = 3
"""P3P's minimal sample: a point hypothesis has these inliers for free."""
POINT_RANSAC_TRIALS = 10_000
"""``pycolmap.AbsolutePoseEstimationOptions().ransac.max_num_trials``: the point server's hypotheses on a query
without consensus (where a false accept happens)."""


def chance_inlier_probability(max_error_px: float, camera: Camera, lines: bool) -> float:
    """Chance that a keypoint falling uniformly in the image is an inlier of a wrong hypothesis: a disc of radius
    ``max_error_px`` around its predicted point (points), or a band of that half-width along its predicted image
    line, taken as long as the image diagonal (lines; an upper bound)."""
    area = float(camera.width * camera.height)
    if lines:
        return min(1.0, 2.0 * max_error_px * math.hypot(camera.width, camera.height) / area)
    return min(1.0, math.pi * max_error_px ** 2 / area)


def line_min_inliers(num_matches: int, point_min_inliers: int, point_max_error_px: float, line_max_error_px: float,
                     camera: Camera, point_trials: int = POINT_RANSAC_TRIALS, line_trials: int | None = None) -> int:
    """The fewest inliers a line server must find among ``num_matches`` to accept a query as often by chance as the
    point server does with ``point_min_inliers`` at ``point_max_error_px`` on the same number of matches.

    Chance model: on a query with no true pose, a hypothesis fitted to a minimal sample of s matches (P3P: 3,
    p6L: 6) has those s as inliers and each other match is a chance inlier with probability p
    (:func:`chance_inlier_probability`), so its inlier count is ``s + Binomial(n - s, p)``. A server trying T
    hypotheses (its RANSAC trial cap, where a query without consensus ends: ``point_trials``, ``line_trials``,
    default ``LineRansacOptions.max_trials``) accepts it by chance with probability ``1 - (1 - q)^T``,
    ``q = P(s + Binomial(n - s, p) >= k)``. Returned:
    the smallest k, at least ``point_min_inliers``, at which the line server's is at most the point server's
    (``num_matches + 1`` where none is: never accept). Compared as ``T log(1 - q)`` (exact where the probability
    is near 1), or as the union bound ``T q`` where both are tiny. At 320x240 and 150 matches, 12 px against
    2 px: 25 for the point server's 15."""
    from scipy.stats import binom

    n, k_point = int(num_matches), int(point_min_inliers)
    if n < k_point:
        return k_point
    line_trials = LineRansacOptions.max_trials if line_trials is None else int(line_trials)
    p_point = chance_inlier_probability(point_max_error_px, camera, lines=False)
    p_line = chance_inlier_probability(line_max_error_px, camera, lines=True)
    j_point, ks = k_point - POINT_SAMPLE_SIZE - 1, np.arange(k_point, n + 1)
    j_line = ks - SAMPLE_SIZE - 1  # P(s + B >= k) = P(B > k - s - 1)
    keep_point = point_trials * binom.logcdf(j_point, n - POINT_SAMPLE_SIZE, p_point)  # log P(no false accept)
    keep_line = line_trials * binom.logcdf(j_line, n - SAMPLE_SIZE, p_line)
    union_point = math.log(point_trials) + binom.logsf(j_point, n - POINT_SAMPLE_SIZE, p_point)
    union_line = math.log(line_trials) + binom.logsf(j_line, n - SAMPLE_SIZE, p_line)
    tiny = (keep_line > -1e-9) & (keep_point > -1e-9)
    ok = np.nonzero(np.where(tiny, union_line <= union_point, keep_line >= keep_point))[0]
    return int(ks[ok[0]]) if len(ok) else n + 1


# ---------------------------------------------------------------- the solver


@dataclass(frozen=True)
class LineRansacOptions:
    """LO-RANSAC settings. ``confidence`` (the textbook 0.99, Hartley & Zisserman 4.7.1) and the trial bounds are
    lower than pycolmap's PnP defaults (0.99999, 100..10000): a p6L sample costs about 1 ms (P3P: microseconds),
    and LO refits the first all-inlier sample to the whole consensus."""

    max_error_px: float = 12.0
    confidence: float = 0.99
    min_trials: int = 3
    max_trials: int = 2000
    local_optimization: bool = True
    lo_max_matches: int = 200
    """LO refits a seeded subset of at most this many inliers (the final refinement uses all)."""
    min_inliers: int = 0
    """The caller's success count (0: none). RANSAC stops once a model with as many inliers would have been found
    with ``confidence`` had it existed: a query the caller would reject needs no more trials."""


def _trials_needed(count: int, n: int, confidence: float) -> int:
    """Trials after which a sample of ``count`` inliers among ``n`` was drawn with ``confidence``."""
    w = min(count / n, 1.0)
    if w <= 0.0:
        return 2 ** 62
    miss = 1.0 - w ** SAMPLE_SIZE
    return 1 if miss <= 0.0 else int(np.ceil(np.log(1.0 - confidence) / np.log(max(miss, 1e-300))))


def estimate_pose_from_lines(keypoints: np.ndarray, directions: np.ndarray, anchors: np.ndarray,
                             camera: Camera, options: LineRansacOptions | None = None, seed: int = 0
                             ) -> dict | None:
    """Pose of a query from matches ``keypoints[i] <-> line (directions[i], anchors[i])``, or None.

    Returns what ``pycolmap.estimate_and_refine_absolute_pose`` returns for points: ``{"cam_from_world":
    pycolmap.Rigid3d, "inlier_mask": (N,) bool, "num_inliers": int}`` (+ ``num_trials``; inliers: point-to-line
    error under ``max_error_px`` and in front of the camera). ``seed`` seeds the sampling.

    Per sample, all p6L roots are pre-scored at once on a fixed subset of :data:`PRETEST_MATCHES` matches
    (:meth:`LineMatches.residuals_many`); only a root within half the best inlier share there is scored on all."""
    options = options or LineRansacOptions()
    matches = LineMatches(keypoints, directions, anchors, camera)
    n, thr = len(matches), float(options.max_error_px)
    if n < SAMPLE_SIZE:
        return None
    rng = np.random.default_rng(seed)
    probe = matches.subset(np.sort(rng.choice(n, min(n, PRETEST_MATCHES), replace=False)))
    best_pose, best_mask, best_count = None, np.zeros(n, bool), 0
    trials = 0
    needed = _trials_needed(options.min_inliers, n, options.confidence)
    while trials < max(needed, options.min_trials) and trials < options.max_trials:
        trials += 1
        sample = rng.choice(n, SAMPLE_SIZE, replace=False)
        poses = minimal_poses(matches.bearings[sample], matches.directions[sample], matches.anchors[sample])
        if not len(poses):
            continue
        probe_counts = (np.abs(probe.residuals_many(poses)) < thr).sum(axis=1)
        for k in np.argsort(-probe_counts, kind="stable"):
            if best_count and probe_counts[k] < 0.5 * best_count / n * len(probe):
                break  # this root and the ones after it are clearly worse than the best
            pose = poses[k]
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
            needed = _trials_needed(max(count, options.min_inliers), n, options.confidence)
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
