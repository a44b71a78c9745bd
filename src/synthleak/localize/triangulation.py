"""Tracks from pairwise matches and their triangulation with known camera poses."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def fundamental_from_poses(
    k: np.ndarray, cam_a_from_world: np.ndarray, cam_b_from_world: np.ndarray
) -> np.ndarray:
    """F with ``x_b^T F x_a = 0`` for pixels of camera a and b (same intrinsics K)."""
    b_from_a = cam_b_from_world @ np.linalg.inv(cam_a_from_world)
    t = b_from_a[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    k_inv = np.linalg.inv(k)
    return k_inv.T @ tx @ b_from_a[:3, :3] @ k_inv


def epipolar_distance(f: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance in pixels (max of both images)."""
    ha = np.hstack([xa, np.ones((len(xa), 1))])
    hb = np.hstack([xb, np.ones((len(xb), 1))])
    lb = ha @ f.T  # lines in b
    la = hb @ f  # lines in a
    num = np.abs((hb * lb).sum(1))
    da = num / np.maximum(np.linalg.norm(la[:, :2], axis=1), 1e-12)
    db = num / np.maximum(np.linalg.norm(lb[:, :2], axis=1), 1e-12)
    return np.maximum(da, db)


def build_tracks(
    num_keypoints: list[int], matches: dict[tuple[int, int], np.ndarray]
) -> list[list[tuple[int, int]]]:
    """Union-find over ``(image, keypoint)`` nodes; each track keeps one keypoint per image (the first)."""
    offsets = np.concatenate([[0], np.cumsum(num_keypoints)]).astype(np.int64)
    parent = np.arange(offsets[-1])

    def find(x: int) -> int:
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for (i, j), m in sorted(matches.items()):
        for a, b in zip(offsets[i] + m[:, 0], offsets[j] + m[:, 1], strict=True):
            ra, rb = find(int(a)), find(int(b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    image_of = np.repeat(np.arange(len(num_keypoints)), num_keypoints)
    groups: dict[int, list[tuple[int, int]]] = {}
    for node in np.unique(np.concatenate([offsets[i] + m[:, 0] for (i, _), m in matches.items()] +
                                         [offsets[j] + m[:, 1] for (_, j), m in matches.items()] +
                                         [np.zeros(0, np.int64)])):
        img = int(image_of[node])
        groups.setdefault(find(int(node)), []).append((img, int(node - offsets[img])))
    tracks = []
    for root in sorted(groups):
        seen, track = set(), []
        for img, kp in sorted(groups[root]):
            if img not in seen:
                seen.add(img)
                track.append((img, kp))
        if len(track) >= 2:
            tracks.append(track)
    return tracks


@dataclass
class TriangulatedPoint:
    xyz: np.ndarray
    track: list[tuple[int, int]]
    error_px: float


def _bearings(pixels: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unit rays in the camera frame through ``pixels`` (COLMAP pixel convention), elementwise IEEE arithmetic
    only (no BLAS), so the same bits on every CPU."""
    x = (pixels[:, 0] - k[0, 2]) / k[0, 0]
    y = (pixels[:, 1] - k[1, 2]) / k[1, 1]
    norm = np.sqrt(x * x + y * y + 1.0)
    return np.stack([x / norm, y / norm, 1.0 / norm], axis=1)


def _in_cameras(cams_from_world: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame coordinates of world point ``xyz`` in each of the (N, 4, 4) poses (elementwise)."""
    r, t = cams_from_world[:, :3, :3], cams_from_world[:, :3, 3]
    return r[:, :, 0] * xyz[0] + r[:, :, 1] * xyz[1] + r[:, :, 2] * xyz[2] + t


def triangulate_track(
    track: list[tuple[int, int]],
    keypoints: list[np.ndarray],
    cams_from_world: np.ndarray,
    k: np.ndarray,
    centres: np.ndarray,
    max_error_px: float,
    min_angle_deg: float,
) -> TriangulatedPoint | None:
    """Multi-view triangulation from bearing vectors (pycolmap's ``triangulate_multi_view_point``: compiled
    Eigen, the same result on every CPU, where numpy's SVD goes through the host's LAPACK kernels), then drop
    observations over ``max_error_px`` (or behind a camera) and re-solve once."""
    import pycolmap

    track = list(track)
    for _ in range(2):
        imgs = np.array([i for i, _ in track])
        px = np.stack([keypoints[i][k_] for i, k_ in track])
        solved = pycolmap.triangulate_multi_view_point([cams_from_world[i][:3] for i in imgs], _bearings(px, k))
        if solved is None or not np.all(np.isfinite(solved)):
            return None
        xyz = np.asarray(solved, dtype=np.float64).reshape(3)
        cam = _in_cameras(cams_from_world[imgs], xyz)
        depth = cam[:, 2]
        safe = np.where(depth > 1e-9, depth, np.nan)
        du = k[0, 0] * cam[:, 0] / safe + k[0, 2] - px[:, 0]
        dv = k[1, 1] * cam[:, 1] / safe + k[1, 2] - px[:, 1]
        err = np.sqrt(du * du + dv * dv)
        good = (depth > 1e-9) & (err < max_error_px)
        if good.all():
            rays = xyz - centres[imgs]
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            cos = np.clip(rays @ rays.T, -1.0, 1.0)
            if np.degrees(np.arccos(cos.min())) < min_angle_deg:
                return None
            return TriangulatedPoint(xyz, track, float(err.mean()))
        track = [obs for obs, g in zip(track, good, strict=True) if g]
        if len(track) < 2:
            return None
    return None
