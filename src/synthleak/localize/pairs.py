"""Image pairs for mapping chosen from known poses (HLoc ``pairs_from_poses`` style)."""

from __future__ import annotations

import numpy as np

from synthleak.geometry.poses import camera_centre


def pairs_from_poses(
    cams_from_world: list[np.ndarray], pairs_per_image: int, max_angle_deg: float = 45.0
) -> list[tuple[int, int]]:
    """For each camera, its ``pairs_per_image`` nearest cameras (centre distance) whose optical axes differ
    by less than ``max_angle_deg``; returns sorted unique ``(i, j)`` with ``i < j``."""
    n = len(cams_from_world)
    if n < 2 or pairs_per_image <= 0:
        return []
    centres = np.stack([camera_centre(p) for p in cams_from_world])
    axes = np.stack([p[2, :3] for p in cams_from_world])  # optical axis in world = third row of R
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    dist[cos < np.cos(np.radians(max_angle_deg))] = np.inf
    np.fill_diagonal(dist, np.inf)
    pairs = set()
    for i in range(n):
        order = np.argsort(dist[i], kind="stable")[:pairs_per_image]
        pairs.update((min(i, int(j)), max(i, int(j))) for j in order if np.isfinite(dist[i, j]))
    return sorted(pairs)
