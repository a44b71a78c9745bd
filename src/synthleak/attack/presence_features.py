"""What the attacker knows about one trial besides ε: features for the presence classifier.

Everything here comes from the attacker's side only: the poses the server returned (or its failures) and the
attacker's own local model, through the alignments the attack computed. Nothing reads the room's ground truth.
Per trial (one aligner at one threshold pair):

* ``second_eps``: support of the best single-image hypothesis (Alg. 1's inlier test) among the images
  outside the winning consensus, over N: a competing placement as strong as the winner means the server's
  poses disagree about where the object is;
* ``rot_spread`` / ``trans_spread``: median rotation / camera-centre residual of the inliers under the
  estimate, as a fraction of δr / δt (1 when there is no inlier): poses that agree tightly, or only just;
* ``disagree_rot_deg`` / ``disagree_trans_m``: the largest rotation angle / translation between this
  placement and the same aligner's placements at the other threshold pairs (180 degrees / :data:`FAR_M`
  when only one of the two has a placement): a placement that moves with the thresholds is fragile.

ε at each threshold pair is gathered from the trials' rows by :mod:`synthleak.attack.presence_classifier`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from synthleak.attack.align import Alignment, _angles_deg, _centres, _per_image_hypotheses, residuals

TRIAL_FEATURES = ("second_eps", "rot_spread", "trans_spread", "disagree_rot_deg", "disagree_trans_m")
"""Columns :func:`attack_features` adds to a results row."""

FAR_M = 10.0
"""Placement disagreement (metres) when only one of two threshold pairs gives a placement (and the cap)."""


def _stacks(local_poses: Mapping[str, np.ndarray], server_poses: Mapping[str, np.ndarray | None]
            ) -> tuple[np.ndarray, np.ndarray]:
    """The (local, server) pose stacks in the order :func:`synthleak.attack.run.run_attack` aligns them."""
    names = sorted(n for n in local_poses if server_poses.get(n) is not None)
    local = np.array([local_poses[n] for n in names], dtype=np.float64).reshape(-1, 4, 4)
    server = np.array([server_poses[n] for n in names], dtype=np.float64).reshape(-1, 4, 4)
    return local, server


def hypothesis_supports(local: np.ndarray, server: np.ndarray, delta_r_deg: float, delta_t_m: float
                        ) -> np.ndarray:
    """Inlier count of every single-image hypothesis under Alg. 1's test (strictly below both thresholds)."""
    if len(local) == 0:
        return np.zeros(0, dtype=np.int64)
    hyp_r, hyp_t = _per_image_hypotheses(local, server)
    local_c, server_c = _centres(local), _centres(server)
    out = np.zeros(len(local), dtype=np.int64)
    for i in range(len(local)):
        d_r = _angles_deg(local[:, :3, :3] @ hyp_r[i].T, server[:, :3, :3])
        d_t = np.linalg.norm(local_c @ hyp_r[i].T + hyp_t[i] - server_c, axis=1)
        out[i] = int(np.count_nonzero((d_r < delta_r_deg) & (d_t < delta_t_m)))
    return out


def trial_features(local_poses: Mapping[str, np.ndarray], server_poses: Mapping[str, np.ndarray | None],
                   alignment: Alignment, delta_r_deg: float, delta_t_m: float) -> dict[str, float]:
    """``second_eps``, ``rot_spread``, ``trans_spread`` of one trial: the inputs of ``run_attack`` and the
    alignment it returned."""
    local, server = _stacks(local_poses, server_poses)
    n_total = max(int(alignment.n_total), 1)
    supports = hypothesis_supports(local, server, delta_r_deg, delta_t_m)
    outside = np.setdiff1d(np.arange(len(local)), alignment.inliers)
    second = int(supports[outside].max()) if outside.size else 0
    rot_spread = trans_spread = 1.0
    if alignment.ok and alignment.inliers.size:
        d_r, d_t = residuals(local, server, alignment.scene_from_object)
        rot_spread = float(np.median(d_r[alignment.inliers]) / delta_r_deg)
        trans_spread = float(np.median(d_t[alignment.inliers]) / delta_t_m)
    return {"second_eps": second / n_total, "rot_spread": rot_spread, "trans_spread": trans_spread}


def _rotation(pose: np.ndarray) -> np.ndarray:
    return pose[:3, :3] / np.cbrt(np.linalg.det(pose[:3, :3]))


def placement_disagreement(alignments: Sequence[Alignment]) -> list[tuple[float, float]]:
    """Per alignment: the largest rotation angle (degrees) and translation (metres, capped at :data:`FAR_M`)
    to the other alignments' placements (0 with one alignment; 180 / FAR_M against a missing placement)."""
    out = []
    for k, a in enumerate(alignments):
        rot = trans = 0.0
        for j, b in enumerate(alignments):
            if j == k or (not a.ok and not b.ok):
                continue
            if a.ok != b.ok:
                rot, trans = 180.0, FAR_M
                continue
            pa, pb = a.scene_from_object, b.scene_from_object
            rot = max(rot, float(_angles_deg(_rotation(pa), _rotation(pb))))
            trans = max(trans, min(float(np.linalg.norm(pa[:3, 3] - pb[:3, 3])), FAR_M))
        out.append((rot, trans))
    return out


def attack_features(local_poses: Mapping[str, np.ndarray], server_poses: Mapping[str, np.ndarray | None],
                    alignments: Sequence[Alignment], thresholds: Sequence[tuple[float, float]]
                    ) -> list[dict[str, float]]:
    """:data:`TRIAL_FEATURES` of one aligner's trials at every threshold pair (``alignments[k]`` made at
    ``thresholds[k]`` from these ``run_attack`` inputs), in that order."""
    if len(alignments) != len(thresholds):
        raise ValueError(f"alignments / thresholds: {len(alignments)} vs {len(thresholds)}; one alignment per "
                         "threshold pair")
    disagree = placement_disagreement(alignments)
    return [trial_features(local_poses, server_poses, a, dr, dt) | {"disagree_rot_deg": rot, "disagree_trans_m": tr}
            for a, (dr, dt), (rot, tr) in zip(alignments, thresholds, disagree, strict=True)]
