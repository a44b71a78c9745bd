"""Small textured box rooms rendered by an embree ray cast, written in the dataset sequence layout.

A stand-in for the mitsuba pipeline in tests and benchmarks: real images (procedural textures looked up
at the exact hit point), exact GT poses, z-depth and instance ids. Room shell pieces get ids 1..6,
boxes ("furniture") 100+. Deterministic for a given seed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image
from trimesh import Trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at, quat_wxyz_from_matrix
from synthleak.seeding import make_rng

PIXELS_PER_METRE = 160.0


@dataclass
class Quad:
    """A textured rectangle ``origin + s*u + t*v``, s in [0, size_u], t in [0, size_v]."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    size_u: float
    size_v: float
    instance_id: int
    texture: np.ndarray  # (H, W, 3) float32 in [0, 1]


def make_texture(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """Multi-scale colour noise with random blobs and bars: plenty of local features."""
    width, height = max(width, 8), max(height, 8)
    base = rng.uniform(0.2, 0.8, 3)
    tex = np.broadcast_to(base, (height, width, 3)).astype(np.float32).copy()
    for cells, amp in ((3, 0.25), (12, 0.15), (48, 0.08)):
        grid = rng.normal(0.0, amp, (cells, max(2, cells * width // height), 3)).astype(np.float32)
        tex += cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
    canvas = np.ascontiguousarray(tex)
    area = width * height
    for _ in range(int(area / 900)):
        colour = tuple(float(c) for c in rng.uniform(0.0, 1.0, 3))
        x, y = int(rng.integers(0, width)), int(rng.integers(0, height))
        size = int(rng.integers(3, 18))
        if rng.random() < 0.5:
            cv2.circle(canvas, (x, y), size, colour, -1, lineType=cv2.LINE_AA)
        else:
            x2, y2 = x + int(rng.integers(2, 30)), y + int(rng.integers(2, 30))
            cv2.rectangle(canvas, (x, y), (x2, y2), colour, -1, lineType=cv2.LINE_AA)
    return np.clip(canvas, 0.0, 1.0)


def _box_quads(
    rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, instance_id: int, inward: bool
) -> list[Quad]:
    """Six faces of an axis-aligned box; one texture per face."""
    quads = []
    size = hi - lo
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        for side in (0, 1):
            origin = lo.copy()
            origin[axis] = hi[axis] if side else lo[axis]
            u, v = np.eye(3)[a], np.eye(3)[b]
            tex = make_texture(rng, int(size[a] * PIXELS_PER_METRE), int(size[b] * PIXELS_PER_METRE))
            quads.append(Quad(origin, u, v, float(size[a]), float(size[b]), instance_id, tex))
    if inward:  # room shell: ids 1..6 (floor/ceiling/walls), in face order
        for i, quad in enumerate(quads):
            quad.instance_id = i + 1
    return quads


def make_room(seed: int, size: tuple[float, float, float] = (5.0, 4.0, 2.6), boxes: int = 4) -> list[Quad]:
    """A box room with ``boxes`` textured boxes (ids 100, 101, ...) along the walls."""
    rng = make_rng(seed, "testscene", "room")
    dims = np.array(size)
    quads = _box_quads(rng, np.zeros(3), dims, 0, inward=True)
    for k in range(boxes):
        angle = 2 * np.pi * (k + 0.5) / boxes
        extent = np.array([rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.1)])
        centre = dims[:2] / 2 + np.array([np.cos(angle), np.sin(angle)]) * (dims[:2] / 2 - 0.8)
        lo = np.array([*(centre - extent[:2] / 2), 0.0])
        quads += _box_quads(rng, lo, lo + extent, 100 + k, inward=False)
    return quads


class QuadScene:
    """Embree BVH over the quads; renders RGB, z-depth and instance ids."""

    def __init__(self, quads: list[Quad], light: tuple[float, float, float] = (0.3, 0.5, 0.8)) -> None:
        verts, faces = [], []
        for i, q in enumerate(quads):
            corners = [q.origin, q.origin + q.size_u * q.u, q.origin + q.size_u * q.u + q.size_v * q.v,
                       q.origin + q.size_v * q.v]
            verts += corners
            faces += [[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
        self.quads = quads
        self.light = np.asarray(light) / np.linalg.norm(light)
        mesh = Trimesh(np.array(verts), np.array(faces), process=False, validate=False)
        self._intersector = RayMeshIntersector(mesh, scale_to_box=False)

    def render(
        self, camera: Camera, cam_from_world: np.ndarray, supersample: int = 2
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rgb uint8, z-depth float32 (+inf no hit), instance uint16) at pixel centres."""
        rgb = np.zeros((camera.height, camera.width, 3), np.float64)
        offsets = (np.arange(supersample) + 0.5) / supersample
        for dy in offsets:
            for dx in offsets:
                colour, depth, inst = self._cast(camera, cam_from_world, dx, dy)
                rgb += colour
        rgb = np.round(255.0 * rgb / supersample**2).clip(0, 255).astype(np.uint8)
        _, depth, inst = self._cast(camera, cam_from_world, 0.5, 0.5)
        return rgb, depth.astype(np.float32), inst

    def _cast(self, camera: Camera, cam_from_world: np.ndarray, dx: float, dy: float):
        h, w = camera.height, camera.width
        u, v = np.meshgrid(np.arange(w) + dx, np.arange(h) + dy)
        d_cam = np.stack([(u.ravel() - camera.cx) / camera.fx, (v.ravel() - camera.cy) / camera.fy,
                          np.ones(u.size)], axis=1)
        rot = cam_from_world[:3, :3]
        origin = camera_centre(cam_from_world)
        dirs = d_cam @ rot
        tri, ray, loc = self._intersector.intersects_id(
            np.broadcast_to(origin, dirs.shape), dirs, multiple_hits=False, return_locations=True
        )
        colour = np.zeros((h * w, 3))
        depth = np.full(h * w, np.inf)
        inst = np.zeros(h * w, np.uint16)
        quad_ids = tri // 2
        for qi in np.unique(quad_ids):
            q = self.quads[qi]
            sel = quad_ids == qi
            rays, pts = ray[sel], loc[sel]
            rel = pts - q.origin
            th, tw = q.texture.shape[:2]
            s = np.clip(rel @ q.u * PIXELS_PER_METRE - 0.5, 0, tw - 1)
            t = np.clip(rel @ q.v * PIXELS_PER_METRE - 0.5, 0, th - 1)
            tex = _bilinear(q.texture, s, t)
            normal = np.cross(q.u, q.v)
            shade = 0.55 + 0.45 * abs(float(normal @ self.light))
            colour[rays] = tex * shade
            depth[rays] = (pts - origin) @ rot[2]
            inst[rays] = q.instance_id
        return colour.reshape(h, w, 3), depth.reshape(h, w), inst.reshape(h, w)


def _bilinear(texture: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup at float texel coordinates (already clipped to the texture)."""
    th, tw = texture.shape[:2]
    s0 = np.minimum(np.floor(s).astype(np.int64), tw - 2)
    t0 = np.minimum(np.floor(t).astype(np.int64), th - 2)
    fs, ft = (s - s0)[:, None], (t - t0)[:, None]
    top = texture[t0, s0] * (1 - fs) + texture[t0, s0 + 1] * fs
    bottom = texture[t0 + 1, s0] * (1 - fs) + texture[t0 + 1, s0 + 1] * fs
    return top * (1 - ft) + bottom * ft


def walkthrough_poses(
    frames: int, room: tuple[float, float, float] = (5.0, 4.0, 2.6), radius: float = 0.7
) -> list[np.ndarray]:
    """Cameras on a circle around the room centre looking across the room, sweeping slowly."""
    centre = np.array([room[0] / 2, room[1] / 2])
    poses = []
    for i in range(frames):
        theta = 2 * np.pi * i / frames
        eye = np.array([*(centre + radius * np.array([np.cos(theta), np.sin(theta)])), 1.4])
        yaw = theta + np.pi + 0.35 * np.sin(3 * theta)
        target = np.array([*(eye[:2] + np.array([np.cos(yaw), np.sin(yaw)])), 1.4 - 0.35])
        poses.append(look_at(eye, target))
    return poses


def write_sequence(
    out_dir: Path,
    quads: list[Quad],
    camera: Camera,
    poses: list[np.ndarray],
    query_every: int = 5,
    name: str = "room_000",
) -> Path:
    """Render ``poses`` and write a sequence folder (images, depth, instance, colmap, split, objects)."""
    scene = QuadScene(quads)
    for sub in ("images", "depth", "instance", "colmap"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    names, lines = [], []
    for i, pose in enumerate(poses):
        rgb, depth, inst = scene.render(camera, pose)
        stem = f"{i:06d}"
        Image.fromarray(rgb).save(out_dir / "images" / f"{stem}.png")
        np.save(out_dir / "depth" / f"{stem}.npy", depth)
        Image.fromarray(inst).save(out_dir / "instance" / f"{stem}.png")
        q = quat_wxyz_from_matrix(pose[:3, :3])
        t = pose[:3, 3]
        lines.append(f"{i + 1} {' '.join(f'{x:.17g}' for x in (*q, *t))} 1 {stem}.png\n\n")
        names.append(f"{stem}.png")
    (out_dir / "colmap" / "cameras.txt").write_text(
        f"1 PINHOLE {camera.width} {camera.height} "
        + " ".join(repr(float(x)) for x in (camera.fx, camera.fy, camera.cx, camera.cy)) + "\n"
    )
    (out_dir / "colmap" / "images.txt").write_text("".join(lines))
    (out_dir / "colmap" / "points3D.txt").write_text("")
    query = [n for i, n in enumerate(names) if query_every and i % query_every == query_every // 2]
    split = {"map": [n for n in names if n not in query], "query": query}
    (out_dir / "split.json").write_text(json.dumps(split, indent=1))
    objects = {"instances": [_instance_json(i, [q for q in quads if q.instance_id == i])
                             for i in sorted({q.instance_id for q in quads})],
               "frame": "world", "target_instance_id": None}
    (out_dir / "objects.json").write_text(json.dumps(objects, indent=1))
    return out_dir


def _instance_json(instance_id: int, quads: list[Quad]) -> dict:
    """An objects.json entry (docs/DATASET.md) for a box or a room shell piece."""
    corners = np.array([c for q in quads for c in (q.origin, q.origin + q.size_u * q.u + q.size_v * q.v)])
    lo, hi = corners.min(0), corners.max(0)
    pose = np.eye(4)
    pose[:3, 3] = (lo + hi) / 2
    shell = instance_id < 100
    return {"instance_id": instance_id, "name": f"{'shell' if shell else 'box'}_{instance_id}",
            "model_id": "shell" if shell else "textured_box", "category": "shell" if shell else "box",
            "symmetry": "none", "role": "shell" if shell else "scene", "world_from_object": pose.tolist(),
            "extents": (hi - lo).tolist(), "variant_params": {}}


def render_image(
    quads: list[Quad], camera: Camera, cam_from_world: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One RGB image and its instance mask (for ad-hoc queries)."""
    rgb, _, inst = QuadScene(quads).render(camera, cam_from_world)
    return rgb, inst
