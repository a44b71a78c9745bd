"""Aligning the attacker's local poses with the server's poses (paper Alg. 1 and two variants).

Conventions and derivation
--------------------------
For attacker image *i* the attacker's local model gives ``cam_from_object`` = ``[R_i | t_i]`` and the
localization server returns ``cam_from_scene`` = ``[R̂_i | t̂_i]`` (both world-to-camera, like the paper).
A point ``x_o`` of the object seen by camera *i* satisfies ``x_c = R_i x_o + t_i`` and, if the server pose
is right, ``x_c = R̂_i x_s + t̂_i``. Eliminating ``x_c``::

    x_s = R̂_iᵀ (R_i x_o + t_i − t̂_i) = (R̂_iᵀ R_i) x_o + R̂_iᵀ (t_i − t̂_i)

so the hypothesis of Alg. 1, ``R_est = R̂_iᵀ R_i`` and ``t_est = R̂_iᵀ (t_i − t̂_i)``, is exactly
``scene_from_object = inv(cam_from_scene_i) @ cam_from_object_i``.

Inlier test for image *j* under ``[R_est | t_est]``: the predicted server pose is
``cam_from_object_j @ object_from_scene``, with rotation ``R_j R_estᵀ``; the rotation residual is
``angle(R_j R_estᵀ R̂_jᵀ)``. The camera centre of *j* is ``c_j = −R_jᵀ t_j`` in the object frame and
``ĉ_j = −R̂_jᵀ t̂_j`` in the scene; mapped to the scene, ``R_est c_j + t_est``. The translation residual
``||R̂_jᵀ t̂_j − R_est R_jᵀ t_j + t_est|| = ||(R_est c_j + t_est) − ĉ_j||`` is therefore a camera-centre
distance in metres. *j* is an inlier iff both residuals are strictly below ``δr`` / ``δt``.

Alg. 1 keeps the hypothesis with the most inliers (strict ``>``, so ties go to the first index) and
averages it over its inliers: the rotation is the chordal L2 mean of the inliers' ``R̂_jᵀ R_j``
(the sum projected to SO(3) by SVD), the translation the arithmetic mean of their ``t_est``
(``R̂_jᵀ (t_j − t̂_j)``), the paper's "averaging the relative poses of all inliers".

Inlier ratio ``eps = |inliers| / N`` with ``N = |P_o|``, the number of LOCAL poses sent to the server
(``n_total``), not the number the server localized. Images the server did not localize count in N but can
never be inliers: a server that refuses most images of an absent object then yields a small eps, which is
the signal the presence decision relies on. Dividing by the localized count instead would turn "2 of 2
localized images agree" into eps = 1 and make absent objects look present.

Variants: :func:`align_sim3` (unknown map scale, hypotheses from pairs of images) and :func:`align_robust`
(MSAC scoring + joint IRLS refinement), and :func:`align_pivot`, see their docstrings. Each is registered by
name (:func:`register_aligner`, :func:`get_aligner`); ``[attack] aligners`` in a config is checked against them.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from synthleak.geometry.poses import rotation_angles_deg
from synthleak.plugins import resolve
from synthleak.seeding import make_rng


@dataclass(frozen=True)
class Alignment:
    """Result of aligning local to server poses.

    ``scene_from_object`` is a 4x4 similarity ``[s R | t]`` (``scale`` = s, 1.0 for rigid aligners), or
    None when nothing was localized. ``inliers`` index the input pairs; ``hypothesis`` is the index
    (or the first index of the pair, Sim(3)) of the winning hypothesis, -1 when none.
    """

    scene_from_object: np.ndarray | None
    scale: float
    inliers: np.ndarray
    eps: float
    n_total: int
    n_localized: int
    hypothesis: int
    aligner: str = "alg1"
    extra: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.scene_from_object is not None


# --------------------------------------------------------------------------------------------- helpers


def _as_pose_stack(poses: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(poses, dtype=np.float64)
    if arr.ndim == 2 and arr.shape == (4, 4):
        arr = arr[None]
    if arr.size == 0:
        return np.zeros((0, 4, 4))
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"{name}: expected an (N, 4, 4) array of poses, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.unique(np.nonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name}: non-finite entries in poses {bad.tolist()}")
    rot = arr[:, :3, :3]
    ortho = np.abs(rot @ np.transpose(rot, (0, 2, 1)) - np.eye(3)).max(axis=(1, 2))
    dets = np.linalg.det(rot)
    bad = np.nonzero((ortho > 1e-4) | (np.abs(dets - 1.0) > 1e-4))[0]
    if bad.size:
        raise ValueError(f"{name}: rotation blocks of poses {bad.tolist()} are not proper rotations")
    return arr


def _validate(
    local: np.ndarray, server: np.ndarray, delta_r_deg: float, delta_t_m: float, n_total: int | None
) -> tuple[np.ndarray, np.ndarray, int]:
    local = _as_pose_stack(local, "local_cam_from_object")
    server = _as_pose_stack(server, "server_cam_from_scene")
    if local.shape[0] != server.shape[0]:
        raise ValueError(
            f"local_cam_from_object / server_cam_from_scene: {local.shape[0]} vs {server.shape[0]} poses; "
            "the i-th entries must be the same image"
        )
    for name, value in (("delta_r_deg", delta_r_deg), ("delta_t_m", delta_t_m)):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name}: must be a positive finite threshold, got {value}")
    n = local.shape[0]
    if n_total is None:
        n_total = n
    if int(n_total) != n_total or n_total < n:
        raise ValueError(f"n_total: must be an integer >= the number of localized pairs ({n}), got {n_total}")
    return local, server, int(n_total)


def project_to_so3(matrix: np.ndarray) -> np.ndarray:
    """Closest rotation (Frobenius norm) to a 3x3 matrix, via SVD with the determinant fixed to +1."""
    u, _, vt = np.linalg.svd(matrix)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def chordal_mean(rotations: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Chordal L2 mean of (N, 3, 3) rotations: the (weighted) sum projected to SO(3)."""
    w = np.ones(len(rotations)) if weights is None else np.asarray(weights, dtype=np.float64)
    return project_to_so3(np.einsum("n,nij->ij", w, rotations))


def _angles_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angles (degrees) of ``rot_a[n] rot_b[n]ᵀ`` for stacks, or one against a stack."""
    return rotation_angles_deg(np.einsum("...ik,...jk->...ij", rot_a, rot_b))


def _centres(cam_from_x: np.ndarray) -> np.ndarray:
    """Camera centres ``-Rᵀ t`` of an (N, 4, 4) stack."""
    return -np.einsum("nji,nj->ni", cam_from_x[:, :3, :3], cam_from_x[:, :3, 3])


def umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = True
) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ≈ s R src + t`` of (N, 3) point sets (Umeyama 1991): (s, R, t)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] < 3:
        raise ValueError(f"umeyama: expected two (N>=3, 3) arrays of one shape, got {src.shape}, {dst.shape}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, sing, vt = np.linalg.svd(cov)
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2] = -1.0
    rot = u @ np.diag(d) @ vt
    var_s = float((xs**2).sum() / len(src))
    scale = float((sing * d).sum() / var_s) if with_scale and var_s > 0 else 1.0
    return scale, rot, mu_d - scale * rot @ mu_s


def _per_image_hypotheses(local: np.ndarray, server: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R̂_iᵀ R_i`` and ``R̂_iᵀ (t_i − t̂_i)`` for every pair i: (N, 3, 3), (N, 3)."""
    r_hat_t = np.transpose(server[:, :3, :3], (0, 2, 1))
    rots = r_hat_t @ local[:, :3, :3]
    trans = np.einsum("nij,nj->ni", r_hat_t, local[:, :3, 3] - server[:, :3, 3])
    return rots, trans


def residuals(
    local: np.ndarray, server: np.ndarray, scene_from_object: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (degrees) and camera-centre (scene units) residuals of every pair under a similarity.

    ``scene_from_object = [s R | t]``: predicted server rotation ``R_j Rᵀ``, predicted centre
    ``s R c_j + t``. For s = 1 these are exactly Alg. 1's ``Δr`` and ``Δt``.
    """
    local = np.asarray(local, dtype=np.float64)
    server = np.asarray(server, dtype=np.float64)
    sr = scene_from_object[:3, :3]
    scale = float(np.cbrt(np.linalg.det(sr)))
    rot = sr / scale
    # angle(R_j R_estᵀ R̂_jᵀ) = angle((R_j R_estᵀ) vs R̂_j)
    d_r = _angles_deg(local[:, :3, :3] @ rot.T, server[:, :3, :3])
    pred = _centres(local) @ sr.T + scene_from_object[:3, 3]
    d_t = np.linalg.norm(pred - _centres(server), axis=1)
    return d_r, d_t


def _similarity(rot: np.ndarray, trans: np.ndarray, scale: float = 1.0) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = scale * rot
    pose[:3, 3] = trans
    return pose


def _empty(n_total: int, aligner: str) -> Alignment:
    return Alignment(None, 1.0, np.zeros(0, dtype=np.int64), 0.0, n_total, 0, -1, aligner)


# --------------------------------------------------------------------------------------------- Alg. 1


def align_alg1(
    local_cam_from_object: np.ndarray,
    server_cam_from_scene: np.ndarray,
    delta_r_deg: float,
    delta_t_m: float,
    *,
    n_total: int | None = None,
) -> Alignment:
    """Paper Alg. 1: best single-camera hypothesis, averaged over its inliers (see module docstring).

    ``n_total``: the number of local poses sent (the paper's N); None means only the given pairs were sent.
    """
    local, server, n_total = _validate(
        local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, n_total
    )
    n = local.shape[0]
    if n == 0:
        return _empty(n_total, "alg1")
    hyp_r, hyp_t = _per_image_hypotheses(local, server)
    local_rot = local[:, :3, :3]
    server_rot = server[:, :3, :3]
    server_c = _centres(server)
    local_c = _centres(local)
    best: np.ndarray = np.zeros(0, dtype=np.int64)
    best_i = -1
    for i in range(n):
        d_r = _angles_deg(local_rot @ hyp_r[i].T, server_rot)
        d_t = np.linalg.norm(local_c @ hyp_r[i].T + hyp_t[i] - server_c, axis=1)
        inl = np.nonzero((d_r < delta_r_deg) & (d_t < delta_t_m))[0]
        if inl.size > best.size:
            best, best_i = inl, i
    if best_i < 0:  # only with degenerate thresholds: no hypothesis explains even itself
        return Alignment(None, 1.0, best, 0.0, n_total, n, -1, "alg1")
    rot = chordal_mean(hyp_r[best])
    trans = hyp_t[best].mean(axis=0)
    return Alignment(_similarity(rot, trans), 1.0, best, best.size / n_total, n_total, n, best_i, "alg1")


# --------------------------------------------------------------------------------------------- Sim(3)


def _pair_list(n: int, max_pairs: int, seed: int) -> list[tuple[int, int]]:
    pairs = list(itertools.combinations(range(n), 2))
    if len(pairs) <= max_pairs:
        return pairs
    rng = make_rng(seed, "align_sim3", n)
    pick = np.sort(rng.choice(len(pairs), size=max_pairs, replace=False))
    return [pairs[k] for k in pick]


def align_sim3(
    local_cam_from_object: np.ndarray,
    server_cam_from_scene: np.ndarray,
    delta_r_deg: float,
    delta_t_m: float,
    *,
    n_total: int | None = None,
    max_pairs: int = 5000,
    min_baseline_frac: float = 0.05,
    seed: int = 0,
) -> Alignment:
    """Alg. 1 generalised to an unknown scale between local model and map: Sim(3) from pairs of images.

    For a pair (i, k): rotation = chordal mean of ``R̂_iᵀR_i`` and ``R̂_kᵀR_k``; scale
    ``s = ||ĉ_i − ĉ_k|| / ||c_i − c_k||`` (camera-centre baselines, server over local); translation
    ``t = mean(ĉ_{i,k} − s R c_{i,k})``. Pairs whose local baseline is below ``min_baseline_frac`` of the
    largest local baseline (or whose server baseline vanishes) are skipped. Inliers: rotation residual
    < ``δr`` and camera-centre distance ``||s R c_j + t − ĉ_j|| < δt`` (``δt`` in scene units). The best
    hypothesis (most inliers, first pair on ties) is refined on its inliers: chordal-mean rotation, then
    closed-form least-squares scale and translation of the camera centres given that rotation, then a
    final inlier re-count (eps uses the refined inliers; the refinement is kept only if it does not lose
    inliers). All pairs are tried when there are at most ``max_pairs``, otherwise a seeded sample.
    """
    local, server, n_total = _validate(
        local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, n_total
    )
    n = local.shape[0]
    if n == 0:
        return _empty(n_total, "sim3")
    hyp_r, _ = _per_image_hypotheses(local, server)
    local_c, server_c = _centres(local), _centres(server)
    if n == 1:  # one image: scale is unobservable, fall back to the rigid hypothesis
        single = align_alg1(local, server, delta_r_deg, delta_t_m, n_total=n_total)
        return Alignment(single.scene_from_object, 1.0, single.inliers, single.eps, n_total, 1, 0, "sim3",
                         {"scale_observable": False})
    span = np.linalg.norm(local_c.max(axis=0) - local_c.min(axis=0))
    min_base = max(min_baseline_frac * span, 1e-9)

    def count(pose: np.ndarray) -> np.ndarray:
        d_r, d_t = residuals(local, server, pose)
        return np.nonzero((d_r < delta_r_deg) & (d_t < delta_t_m))[0]

    pairs = np.array(_pair_list(n, max_pairs, seed), dtype=np.int64).reshape(-1, 2)
    base_local = np.linalg.norm(local_c[pairs[:, 0]] - local_c[pairs[:, 1]], axis=1)
    base_server = np.linalg.norm(server_c[pairs[:, 0]] - server_c[pairs[:, 1]], axis=1)
    pairs = pairs[(base_local >= min_base) & (base_server >= 1e-9)]
    best = np.zeros(0, dtype=np.int64)
    best_pose: np.ndarray | None = None
    best_pair = (-1, -1)
    best_count = 0
    cos_thr = np.cos(np.radians(delta_r_deg))
    for start in range(0, len(pairs), 1024):  # vectorised over chunks of pairs, in pair order
        chunk = pairs[start : start + 1024]
        i, k = chunk[:, 0], chunk[:, 1]
        scale = (np.linalg.norm(server_c[i] - server_c[k], axis=1)
                 / np.linalg.norm(local_c[i] - local_c[k], axis=1))
        u, _, vt = np.linalg.svd(hyp_r[i] + hyp_r[k])
        fix = np.ones((len(chunk), 3))
        fix[:, 2] = np.sign(np.linalg.det(u @ vt))
        rot = u @ (fix[:, :, None] * vt)
        trans = 0.5 * (server_c[i] + server_c[k]
                       - scale[:, None] * np.einsum("pab,pb->pa", rot, local_c[i] + local_c[k]))
        # angle(R_j R_pᵀ R̂_jᵀ) < δr  <=>  trace(R_pᵀ R̂_jᵀ R_j) > 1 + 2 cos δr
        cos = (np.einsum("pab,jab->pj", rot, hyp_r) - 1.0) / 2.0
        pred = scale[:, None, None] * np.einsum("pab,jb->pja", rot, local_c) + trans[:, None, :]
        dist = np.linalg.norm(pred - server_c[None], axis=2)
        counts = ((cos > cos_thr) & (dist < delta_t_m)).sum(axis=1)
        top = int(np.argmax(counts))  # first pair with the chunk's maximum
        if counts[top] > best_count:
            best_count = int(counts[top])
            best_pose = _similarity(rot[top], trans[top], float(scale[top]))
            best_pair = (int(chunk[top, 0]), int(chunk[top, 1]))
    if best_pose is None:
        return Alignment(None, 1.0, best, 0.0, n_total, n, -1, "sim3", {"scale_observable": False})
    best = count(best_pose)
    if best.size >= 2:
        refined = _refine_sim3(hyp_r[best], local_c[best], server_c[best])
        if refined is not None:
            inl = count(refined)
            if inl.size >= best.size:
                best, best_pose = inl, refined
    scale = float(np.cbrt(np.linalg.det(best_pose[:3, :3])))
    return Alignment(best_pose, scale, best, best.size / n_total, n_total, n, best_pair[0], "sim3",
                     {"pair": best_pair})


def _refine_sim3(rots: np.ndarray, local_c: np.ndarray, server_c: np.ndarray) -> np.ndarray | None:
    rot = chordal_mean(rots)
    lc = local_c - local_c.mean(axis=0)
    sc = server_c - server_c.mean(axis=0)
    denom = float((lc**2).sum())
    if denom < 1e-18:
        return None
    scale = float(np.einsum("ni,ni->", sc, lc @ rot.T)) / denom
    if not scale > 0:
        return None
    trans = server_c.mean(axis=0) - scale * rot @ local_c.mean(axis=0)
    return _similarity(rot, trans, scale)


# --------------------------------------------------------------------------------------------- robust


def align_robust(
    local_cam_from_object: np.ndarray,
    server_cam_from_scene: np.ndarray,
    delta_r_deg: float,
    delta_t_m: float,
    *,
    n_total: int | None = None,
    iterations: int = 20,
    cauchy_c: float = 0.5,
    cutoff: float = 2.0,
) -> Alignment:
    """Exhaustive single-image hypotheses scored MSAC-like, then a joint IRLS refinement of R and t.

    Residuals are normalised by the thresholds, ``r_j = max(Δr_j/δr, Δt_j/δt)`` (so ``r_j < 1`` is exactly
    Alg. 1's inlier test). Each hypothesis costs ``Σ_j min(r_j², 1)`` (truncated quadratic): among
    hypotheses with similar support the one that explains its inliers better wins, instead of whichever
    index comes first. The winner is refined by IRLS with Cauchy weights ``1/(1+(r_j/c)²)`` (zero beyond
    ``cutoff``) on the joint objective

        Σ_j w_j [ ||R − R̂_jᵀR_j||_F² / (2 σr²) + ||ĉ_j − R c_j − t||² / σt² ],

    whose minimiser in R is one Procrustes problem (``M = Σ w_j R̂_jᵀR_j /(2σr²) + Σ w_j ĉ'_j c'_jᵀ/σt²``,
    centred centres, R = proj_SO(3)(M)) and in t the weighted centre mean. ``σr``, ``σt`` are the per-axis
    noise levels re-estimated each iteration from the weighted residuals (a Gaussian likelihood weighting of
    the two kinds of evidence; floored at 1e-3 of the thresholds). Why it should beat Alg. 1: Alg. 1
    averages per-image hypotheses, each carrying the full rotation error of one server pose, whose lever
    arm (camera distance) turns small angle errors into large translation errors; here the spread of the
    inlier camera centres constrains the rotation too (noise averages over the baseline), rotation and
    translation are fitted consistently instead of averaging t_est made with different rotations, and
    near-threshold inliers are down-weighted rather than counted in full. eps is re-counted with Alg. 1's
    thresholds under the refined pose, so presence decisions stay comparable.
    """
    local, server, n_total = _validate(
        local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, n_total
    )
    n = local.shape[0]
    if n == 0:
        return _empty(n_total, "robust")
    hyp_r, hyp_t = _per_image_hypotheses(local, server)
    local_c, server_c = _centres(local), _centres(server)
    local_rot, server_rot = local[:, :3, :3], server[:, :3, :3]

    def norm_res(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
        d_r = _angles_deg(local_rot @ rot.T, server_rot)
        d_t = np.linalg.norm(local_c @ rot.T + trans - server_c, axis=1)
        return np.maximum(d_r / delta_r_deg, d_t / delta_t_m)

    costs = np.array([np.minimum(norm_res(hyp_r[i], hyp_t[i]) ** 2, 1.0).sum() for i in range(n)])
    best_i = int(np.argmin(costs))  # argmin returns the first index on ties
    rot, trans = hyp_r[best_i], hyp_t[best_i]
    floor_r, floor_t = 1e-3 * np.radians(delta_r_deg), 1e-3 * delta_t_m
    for _ in range(iterations):
        d_r, d_t = residuals(local, server, _similarity(rot, trans))
        r = np.maximum(d_r / delta_r_deg, d_t / delta_t_m)
        w = np.where(r < cutoff, 1.0 / (1.0 + (r / cauchy_c) ** 2), 0.0)
        if w.sum() <= 0:
            break
        # per-axis noise scales of the two residual kinds (weighted RMS / sqrt(3)), floored
        sigma_r = max(np.sqrt((w @ np.radians(d_r) ** 2) / (3.0 * w.sum())), floor_r)
        sigma_t = max(np.sqrt((w @ d_t**2) / (3.0 * w.sum())), floor_t)
        alpha, beta = 1.0 / (2.0 * sigma_r**2), 1.0 / sigma_t**2
        wc = w / w.sum()
        lc_mean = wc @ local_c
        sc_mean = wc @ server_c
        m = alpha * np.einsum("n,nij->ij", w, hyp_r) + beta * np.einsum(
            "n,ni,nj->ij", w, server_c - sc_mean, local_c - lc_mean
        )
        new_rot = project_to_so3(m)
        new_trans = sc_mean - new_rot @ lc_mean
        converged = np.abs(new_rot - rot).max() < 1e-12 and np.abs(new_trans - trans).max() < 1e-12
        rot, trans = new_rot, new_trans
        if converged:
            break
    inl = np.nonzero(norm_res(rot, trans) < 1.0)[0]
    if inl.size == 0:  # refinement drifted off everything: keep the raw hypothesis
        rot, trans = hyp_r[best_i], hyp_t[best_i]
        inl = np.nonzero(norm_res(rot, trans) < 1.0)[0]
    return Alignment(_similarity(rot, trans), 1.0, inl, inl.size / n_total, n_total, n, best_i, "robust",
                     {"cost": float(costs[best_i])})


# --------------------------------------------------------------------------------------------- pivot


def _so3_log(rotations: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rotations).as_rotvec()


def _so3_exp(rotvec: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rotvec).as_matrix()


def look_at_point(cam_from_x: np.ndarray) -> np.ndarray:
    """The point (frame x) nearest to every camera's optical axis in least squares: where an orbit looks.

    A small ridge towards the origin of x (1e-3 of the squared camera distance) keeps parallel axes defined.
    """
    centres = _centres(cam_from_x)
    axes = cam_from_x[:, 2, :3]  # optical axis (camera +z) in frame x: the third row of R
    proj = np.eye(3)[None] - np.einsum("ni,nj->nij", axes, axes)
    ridge = 1e-3 * float(np.mean(np.sum(centres**2, axis=1)) + 1e-12)
    return np.linalg.solve(proj.sum(axis=0) + ridge * np.eye(3), np.einsum("nij,nj->i", proj, centres))


def align_pivot(
    local_cam_from_object: np.ndarray,
    server_cam_from_scene: np.ndarray,
    delta_r_deg: float,
    delta_t_m: float,
    *,
    n_total: int | None = None,
    swing_ratio: float = 2.0,
    depth_ratio: float = 3.0,
    scale_r_deg: float = 10.0,
    scale_t_m: float = 0.25,
    iterations: int = 20,
) -> Alignment:
    """Alg. 1's consensus set, re-estimated trusting each server pose where PnP pins it down.

    The server's error for an attacker image (study-small-pyrender, 118 localized images) is mostly a *swing*
    of the camera around the object it sees: rotation error about the camera's x/y axes (median 2.4°) rather
    than about its optical axis (0.5°), camera centre off by 0.066 m across the viewing ray. The object's image,
    so the object's position seen from that camera, hardly moves: a per-image hypothesis puts the object's
    centre 0.009 m off across the ray and 0.028 m along it (PnP depth; the attacker's variant is a few % larger
    or smaller). The hard world (material sharing, distractors, clutter; 109 images near the truth over three
    tiers) gives the same picture: swing 2.3-2.6° against turn 0.5°, centre 0.05-0.08 m across the ray, object
    0.007-0.011 m across and 0.03 m along it (``benchmarks/server_pose_errors.py``). Alg. 1 averages rotations
    and translations isotropically with equal weights. Here:

    * consensus exactly as Alg. 1 (same hypotheses, thresholds, tie rule): ``inliers``, ``eps`` and so the
      presence decision are Alg. 1's; with one inlier the pose is Alg. 1's too;
    * rotation: minimise ``Σ w_j φ_jᵀ Λ φ_j`` over the inliers (Gauss-Newton on SO(3)), ``φ_j`` the rotation
      residual of image j in its camera frame, ``Λ = diag(1/k², 1/k², 1)``, ``k = swing_ratio``: a turn about
      the optical axis counts ``k`` times more than a swing. ``k = 2``, not the measured noise ratio 4.7:
      the turn errors are biased per pair (means -0.9° to +0.8°), and a camera at elevation e passes them to
      the yaw amplified by 1 / sin(e);
    * position: each image places the *pivot* ``p`` (where the attacker's orbit looks, from its local poses:
      :func:`look_at_point`) at ``R̂_jᵀ(R_j p + t_j − t̂_j)``, which a swing about the object does not move (its
      median error 0.026 m against 0.034 m for the object frame's origin); the weighted mean of those, with
      weight ``1/depth_ratio²`` along the camera's optical axis (3 = the measured ratio), gives ``q`` and
      ``t = q − R p``. Camera centres are never fitted: they carry the swing with the camera distance as lever
      arm, which is why ``robust``'s joint fit loses rotation accuracy to Alg. 1;
    * weights ``w_j = 1 / (1 + (Δr_j/scale_r)² + (Δp_j/scale_t)²)`` of image j's own hypothesis against the
      estimate (rotation angle, pivot distance), iterated: an inlier far off within loose thresholds (60°, 2 m)
      counts little. The scales are the paper's tightest success thresholds (10°, 0.25 m).
    """
    local, server, n_total = _validate(
        local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, n_total
    )
    for name, value in (("swing_ratio", swing_ratio), ("depth_ratio", depth_ratio), ("scale_r_deg", scale_r_deg),
                        ("scale_t_m", scale_t_m)):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name}: must be a positive finite number, got {value}")
    reference = align_alg1(local, server, delta_r_deg, delta_t_m, n_total=n_total)
    inl = reference.inliers
    if not reference.ok or inl.size < 2:
        return Alignment(reference.scene_from_object, 1.0, inl, reference.eps, n_total, reference.n_localized,
                         reference.hypothesis, "pivot")
    pivot = look_at_point(local[inl])
    rot, trans, w = _pivot_refine(local[inl], server[inl], reference.scene_from_object, pivot, swing_ratio=swing_ratio,
                                  depth_ratio=depth_ratio, scale_r_deg=scale_r_deg, scale_t_m=scale_t_m,
                                  iterations=iterations)
    return Alignment(_similarity(rot, trans), 1.0, inl, reference.eps, n_total, reference.n_localized,
                     reference.hypothesis, "pivot", {"pivot_object": pivot.tolist(), "weights": w.tolist()})


def _pivot_refine(loc: np.ndarray, srv: np.ndarray, start: np.ndarray, pivot: np.ndarray, *,
                  swing_ratio: float = 2.0, depth_ratio: float = 3.0, scale_r_deg: float = 10.0,
                  scale_t_m: float = 0.25, iterations: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`align_pivot`'s re-estimate over a consensus set (``loc``/``srv``: its pairs, >= 2) from the pose
    ``start``, placing ``pivot`` (:func:`look_at_point` of ``loc``); the defaults are ``align_pivot``'s. Returns
    rotation, translation and the final weights."""
    hyp_r, hyp_t = _per_image_hypotheses(loc, srv)
    placed = np.einsum("nij,j->ni", hyp_r, pivot) + hyp_t  # the pivot in the scene, per image
    srv_rot, loc_rot = srv[:, :3, :3], loc[:, :3, :3]
    lam_r = np.diag([1.0 / swing_ratio**2, 1.0 / swing_ratio**2, 1.0])
    lam_t = np.diag([1.0, 1.0, 1.0 / depth_ratio**2])
    info_r = np.einsum("nji,jk,nkl->nil", srv_rot, lam_r, srv_rot)  # R̂ᵀ Λ R̂: scene-frame information
    info_t = np.einsum("nji,jk,nkl->nil", srv_rot, lam_t, srv_rot)
    rot = start[:3, :3]
    q = rot @ pivot + start[:3, 3]
    w = np.ones(len(loc))
    for _ in range(iterations):
        for _ in range(10):  # Gauss-Newton: R <- exp(δ) R, φ_j(δ) ≈ φ_j + R̂_j δ
            phi = _so3_log(srv_rot @ rot @ np.transpose(loc_rot, (0, 2, 1)))
            hess = np.einsum("n,nij->ij", w, info_r)
            grad = np.einsum("n,nji,jk,nk->i", w, srv_rot, lam_r, phi)
            step = -np.linalg.solve(hess, grad)
            rot = _so3_exp(step) @ rot
            if np.linalg.norm(step) < 1e-12:
                break
        q = np.linalg.solve(np.einsum("n,nij->ij", w, info_t), np.einsum("n,nij,nj->i", w, info_t, placed))
        d_r = np.radians(_angles_deg(hyp_r, rot)) / np.radians(scale_r_deg)
        d_p = np.linalg.norm(placed - q, axis=1) / scale_t_m
        new_w = 1.0 / (1.0 + d_r**2 + d_p**2)
        if np.abs(new_w - w).max() < 1e-9:
            break
        w = new_w
    return project_to_so3(rot), q - rot @ pivot, w  # the translation from the unprojected R (pivot's bytes)


# --------------------------------------------------------------------------------------------- upright


def align_upright(
    local_cam_from_object: np.ndarray,
    server_cam_from_scene: np.ndarray,
    delta_r_deg: float,
    delta_t_m: float,
    *,
    n_total: int | None = None,
    local_up: np.ndarray | None = None,
    scene_up: np.ndarray | None = None,
    max_tilt_deg: float = 15.0,
) -> Alignment:
    """Alg. 1's single-image hypotheses, kept only where they stand the object upright, refined like ``pivot``.

    Why (per-image errors on study-small, 10°/0.25 m): where Alg. 1 fails on a present object with two or more
    localized images, the images mostly disagree (each its own consensus of one) and the first index wins the
    tie, yet one of them is often right (akaze and orb on the bicycle, orb on the step stool: 3-4° and 1-9 cm),
    while the wrong ones lay the object on its side or upside down (tilts of 30-180°). Furniture stands upright
    in both frames, so a hypothesis ``R`` must map the local model's up direction ``local_up`` onto the scene's
    ``scene_up`` (:mod:`synthleak.attack.gravity`: both from the attacker's own data). Here:

    * a hypothesis (and an inlier) counts only if its tilt ``angle(R local_up, scene_up) < max_tilt_deg``;
    * the upright hypothesis with most upright inliers wins, ties going to the smaller tilt (not the first
      index); ``eps`` = its inliers / N, so an object whose images the server turns over gets a small eps;
    * no upright hypothesis: nothing is placed (eps 0);
    * the winner is re-estimated over its inliers exactly as :func:`align_pivot` does.

    Without ``local_up`` or ``scene_up`` (an attacker with no estimate of the scene's up) it is ``pivot``.
    """
    local, server, n_total = _validate(
        local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, n_total
    )
    if not np.isfinite(max_tilt_deg) or max_tilt_deg <= 0:
        raise ValueError(f"max_tilt_deg: must be a positive finite number, got {max_tilt_deg}")
    if local_up is None or scene_up is None:
        fallback = align_pivot(local, server, delta_r_deg, delta_t_m, n_total=n_total)
        return Alignment(fallback.scene_from_object, 1.0, fallback.inliers, fallback.eps, n_total,
                         fallback.n_localized, fallback.hypothesis, "upright", {"gravity": False})
    ups = []
    for name, up in (("local_up", local_up), ("scene_up", scene_up)):
        up = np.asarray(up, dtype=np.float64).reshape(-1)
        if up.shape != (3,) or not np.all(np.isfinite(up)) or np.linalg.norm(up) < 1e-9:
            raise ValueError(f"{name}: expected a finite non-zero 3-vector, got {up}")
        ups.append(up / np.linalg.norm(up))
    n = local.shape[0]
    if n == 0:
        return _empty(n_total, "upright")
    hyp_r, hyp_t = _per_image_hypotheses(local, server)
    tilt = np.degrees(np.arccos(np.clip(np.einsum("nij,j->ni", hyp_r, ups[0]) @ ups[1], -1.0, 1.0)))
    upright = tilt < max_tilt_deg
    extra = {"gravity": True, "tilt_deg": tilt.tolist()}
    if not upright.any():
        return Alignment(None, 1.0, np.zeros(0, dtype=np.int64), 0.0, n_total, n, -1, "upright", extra)
    local_rot, server_rot = local[:, :3, :3], server[:, :3, :3]
    local_c, server_c = _centres(local), _centres(server)
    best, best_i, best_key = np.zeros(0, dtype=np.int64), -1, (-1, 0.0)
    for i in np.nonzero(upright)[0]:
        d_r = _angles_deg(local_rot @ hyp_r[i].T, server_rot)
        d_t = np.linalg.norm(local_c @ hyp_r[i].T + hyp_t[i] - server_c, axis=1)
        inl = np.nonzero((d_r < delta_r_deg) & (d_t < delta_t_m) & upright)[0]
        key = (inl.size, -float(tilt[i]))
        if key > best_key:
            best, best_i, best_key = inl, int(i), key
    start = _similarity(chordal_mean(hyp_r[best]), hyp_t[best].mean(axis=0))
    if best.size >= 2:
        rot, trans, _ = _pivot_refine(local[best], server[best], start, look_at_point(local[best]))
        start = _similarity(rot, trans)
    return Alignment(start, 1.0, best, best.size / n_total, n_total, n, best_i, "upright", extra)


Aligner = Callable[..., Alignment]
"""``aligner(local_cam_from_object, server_cam_from_scene, delta_r_deg, delta_t_m, *, n_total) -> Alignment``."""

ALIGNERS: dict[str, Aligner | str] = {}
"""Aligner registry: ``get_aligner(name)(local, server, delta_r_deg, delta_t_m, n_total=...)``."""


def register_aligner(name: str, aligner: Aligner | str) -> None:
    """Make ``name`` an aligner of ``[attack] aligners`` (a later registration of the name replaces the earlier
    one). ``aligner``: the function, or ``"package.module:function"`` imported on first use (an aligner in its own
    module, which may import this one's helpers)."""
    ALIGNERS[name] = aligner


def aligner_names() -> list[str]:
    """Registered aligner names, sorted."""
    return sorted(ALIGNERS)


def get_aligner(name: str) -> Aligner:
    """The aligner called ``name``; ValueError listing the known ones otherwise."""
    try:
        entry = ALIGNERS[name]
    except KeyError:
        raise ValueError(f"aligner: unknown name {name!r} (known: {', '.join(aligner_names())})") from None
    return resolve(entry)


register_aligner("alg1", align_alg1)
register_aligner("pivot", align_pivot)
register_aligner("robust", align_robust)
register_aligner("sim3", align_sim3)
register_aligner("upright", align_upright)
