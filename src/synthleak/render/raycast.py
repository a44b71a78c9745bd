"""Exact ground truth by ray casting (embree via trimesh), independent of the photoreal renderer.

One ray per pixel centre ``(u + 0.5, v + 0.5)``; depth is the **z-depth** of the hit (distance to the image
plane), recomputed in float64 from the hit triangle's plane so it is not limited by embree's float32.
"""

from __future__ import annotations

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from synthleak.core.types import Camera, RenderMesh


def pixel_rays(camera: Camera, cam_from_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray origin (3,) and (H*W, 3) world directions with camera-frame z = 1, row-major over (v, u)."""
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    dirs_cam = np.stack(
        [(u.ravel() - camera.cx) / camera.fx, (v.ravel() - camera.cy) / camera.fy, np.ones(u.size)], axis=1
    )
    rot = np.asarray(cam_from_world, dtype=np.float64)[:3, :3]
    origin = -rot.T @ np.asarray(cam_from_world, dtype=np.float64)[:3, 3]
    return origin, dirs_cam @ rot  # (R^T d)^T = d^T R


class RaycastGT:
    """BVH over all meshes of a scene (built once); ``render`` gives z-depth and instance ids."""

    def __init__(self, meshes: list[RenderMesh]) -> None:
        if not meshes:
            raise ValueError("RaycastGT: the scene has no meshes")
        verts, faces, face_ids, offset = [], [], [], 0
        for mesh in meshes:
            v = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
            f = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
            if f.size and (f.min() < 0 or f.max() >= len(v)):
                raise ValueError(f"RaycastGT: mesh {mesh.name!r} has face indices outside its vertices")
            verts.append(v)
            faces.append(f + offset)
            face_ids.append(np.full(len(f), mesh.instance_id, dtype=np.uint16))
            offset += len(v)
        self.vertices = np.concatenate(verts)
        self.faces = np.concatenate(faces)
        self.face_instance = np.concatenate(face_ids)
        tri = self.vertices[self.faces]
        self._v0 = tri[:, 0]
        self._normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)
        self._intersector = RayMeshIntersector(mesh, scale_to_box=False)

    def render(self, camera: Camera, cam_from_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(depth float32 (H, W) z-depth, +inf no hit; instance uint16 (H, W), 0 background)."""
        origin, dirs = pixel_rays(camera, cam_from_world)
        origins = np.broadcast_to(origin, dirs.shape)
        tri = self._intersector.intersects_first(origins, dirs)
        hit = tri >= 0
        depth = np.full(len(dirs), np.inf)
        instance = np.zeros(len(dirs), dtype=np.uint16)
        idx = tri[hit]
        normal = self._normal[idx]
        # Ray o + t d with camera-frame z of d = 1: t is the z-depth. Exact float64 plane intersection.
        denom = np.einsum("ij,ij->i", normal, dirs[hit])
        num = np.einsum("ij,ij->i", normal, self._v0[idx] - origin)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num / denom
        bad = ~np.isfinite(t) | (t <= 0)
        if bad.any():  # degenerate triangle or grazing ray: fall back to embree's own hit point
            locs, ray_idx, _ = self._intersector.intersects_location(
                origins[hit][bad], dirs[hit][bad], multiple_hits=False
            )
            fallback = np.full(int(bad.sum()), np.inf)
            rot = np.asarray(cam_from_world)[:3, :3]
            fallback[ray_idx] = (locs - origin) @ rot[2]
            t[bad] = fallback
        depth[hit] = t
        instance[hit] = self.face_instance[idx]
        shape = (camera.height, camera.width)
        return depth.reshape(shape).astype(np.float32), instance.reshape(shape)

    def any_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(N,) bool: whether each ray hits any triangle."""
        return self._intersector.intersects_any(np.asarray(origins, float), np.asarray(directions, float))
