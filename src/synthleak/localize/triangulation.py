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


def _dlt(projections: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    rows = np.concatenate([pixels[:, :1] * projections[:, 2] - projections[:, 0],
                           pixels[:, 1:] * projections[:, 2] - projections[:, 1]])
    _, _, vt = np.linalg.svd(rows)
    x = vt[-1]
    return x[:3] / x[3] if abs(x[3]) > 1e-12 else np.full(3, np.nan)


def triangulate_track(
    track: list[tuple[int, int]],
    keypoints: list[np.ndarray],
    projections: np.ndarray,
    centres: np.ndarray,
    max_error_px: float,
    min_angle_deg: float,
) -> TriangulatedPoint | None:
    """DLT, then drop observations over ``max_error_px`` (or behind a camera) and re-solve once."""
    track = list(track)
    for _ in range(2):
        imgs = np.array([i for i, _ in track])
        px = np.stack([keypoints[i][k] for i, k in track])
        xyz = _dlt(projections[imgs], px)
        if not np.all(np.isfinite(xyz)):
            return None
        proj = projections[imgs] @ np.append(xyz, 1.0)
        depth = proj[:, 2]
        err = np.linalg.norm(proj[:, :2] / np.where(depth > 1e-9, depth, np.nan)[:, None] - px, axis=1)
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
