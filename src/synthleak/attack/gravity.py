"""Which way is up, from the attacker's own data: in its local model (its hand-held, upright photos) and in the
scene (the placements the server's answers support best). The ``upright`` aligner needs both."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np


def up_from_cameras(cam_from_x: Mapping[str, np.ndarray] | np.ndarray) -> np.ndarray:
    """The up direction of frame x from hand-held, upright photos: the unit vector normal to every camera's
    image x axis (least squares: the smallest eigenvector of ``Σ x_i x_iᵀ``), signed along the image up (-y)
    axes. Needs cameras whose viewing directions differ in azimuth (an orbit)."""
    poses = np.asarray(list(cam_from_x.values()) if isinstance(cam_from_x, Mapping) else cam_from_x,
                       dtype=np.float64)
    x_axes, y_axes = poses[:, 0, :3], poses[:, 1, :3]
    _, vecs = np.linalg.eigh(x_axes.T @ x_axes)
    up = vecs[:, 0]
    return up if float(np.sum(-y_axes @ up)) >= 0 else -up


def scene_up_from_placements(placements: Iterable[tuple[int, np.ndarray]], min_inliers: int = 3
                             ) -> np.ndarray | None:
    """The scene's up direction from the attacker's placements in it: ``placements`` holds, per attacked object,
    Alg. 1's inlier count and its placement's image of the local up direction (``R_est @ local_up``). The mean
    direction of the placements with the most inliers (at least ``min_inliers``), or None when none has that
    many: a placement agreed on by several views stands the object the right way up, a lone answer need not.

    Estimating up from the answers' camera x axes instead (:func:`up_from_cameras` on the server poses) fails
    where most answers are wrong: 82-86° off for orb and akaze in one study-small room, against under 4° here.
    """
    kept = [(int(n), np.asarray(up, dtype=np.float64)) for n, up in placements if int(n) >= min_inliers]
    if not kept:
        return None
    most = max(n for n, _ in kept)
    total = np.sum([up / np.linalg.norm(up) for n, up in kept if n == most], axis=0)
    norm = float(np.linalg.norm(total))
    return total / norm if norm > 1e-9 else None


def local_ups(local_by_object: Mapping[str, Mapping[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """:func:`up_from_cameras` of each attacked object's local poses (objects with fewer than 2 left out)."""
    return {obj: up_from_cameras(poses) for obj, poses in local_by_object.items() if len(poses) >= 2}


def scene_ups(local_by_object: Mapping[str, Mapping[str, np.ndarray]], local_up: Mapping[str, np.ndarray],
              answers: Mapping[tuple[str, str], Mapping[str, Mapping[str, np.ndarray | None]]],
              delta_r_deg: float, delta_t_m: float, min_inliers: int = 3) -> dict[tuple[str, str], np.ndarray | None]:
    """:func:`scene_up_from_placements` of every server: ``answers`` maps (tier, room) to each attacked object's
    answers (frame -> the server's ``cam_from_scene``, None where not localized); each object is placed with
    Alg. 1 at (``delta_r_deg``, ``delta_t_m``) from its local poses ``local_by_object`` and votes with its local
    up direction ``local_up`` (:func:`local_ups`; objects without one do not vote)."""
    from synthleak.attack.run import run_attack

    out: dict[tuple[str, str], np.ndarray | None] = {}
    for server, by_object in answers.items():
        votes = []
        for obj, frames in sorted(by_object.items()):
            local = local_by_object.get(obj, {})
            if obj not in local_up:
                continue
            sent = {f: p for f, p in frames.items() if f in local and p is not None}
            alignment = run_attack(local, sent, "alg1", delta_r_deg, delta_t_m)
            if alignment.ok:
                votes.append((alignment.inliers.size, alignment.scene_from_object[:3, :3] @ local_up[obj]))
        out[server] = scene_up_from_placements(votes, min_inliers)
    return out
