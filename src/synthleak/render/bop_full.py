"""The whole BOP layout for a rendered sequence folder: a post-processing step after its frames are written.

``write_bop_extras(seq_dir, scene)`` adds, next to ``bop/scene_gt.json`` / ``bop/scene_camera.json``
(docs/DATASET.md; BOP format: bop_toolkit ``docs/bop_datasets_format.md``)::

    bop/scene_gt_info.json      per frame, in the order of scene_gt.json's entries: bbox_obj, bbox_visib,
                                px_count_all, px_count_valid, px_count_visib, visib_fract
    bop/mask/IMID_GTID.png      full (unoccluded) silhouette: pixel-centre rays against that object alone
    bop/mask_visib/IMID_GTID.png  visible part: the instance mask == obj_id
    bop/depth/IMID.png          uint16 depth, depth_mm = png * depth_scale (0 = no hit / out of range)
    bop/models/obj_%06d.ply     per instance (obj_id = instance id), millimetres, + models_info.json
    bop/scene_camera.json       rewritten with ``depth_scale``

Silhouettes are exact ray casts (the same pixel-centre convention as :mod:`synthleak.render.raycast`) using
scene_gt's ``cam_R_m2c`` / ``cam_t_m2c`` and each object's mesh in its own frame, so world and attacker
(object-frame) sequences are handled alike. As in bop_toolkit's ``calc_gt_info.py``, ``px_count_all`` and
``bbox_obj`` count the silhouette in a 3x enlarged image (truncated parts included; room-shell pieces are
counted inside the image only), boxes are ``[x, y, w, h]`` with ``w = x_max - x_min`` and are
``[-1, -1, -1, -1]`` when nothing is visible. Every file is written atomically (temp + rename).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from synthleak.atomic_io import atomic_write_bytes, atomic_write_text
from synthleak.core.dataset import DatasetError, camera_dist_coeffs, encode_png, load_sequence, read_json
from synthleak.core.types import Camera, RenderScene
from synthleak.geometry.poses import invert, make_pose, transform_points
from synthleak.portable import snap
from synthleak.render.dataset import atomic_write_json
from synthleak.render.distortion import lens_image_bounds, normalized_rays, project_camera_points

ENLARGE = 3
"""Silhouettes for ``px_count_all`` / ``bbox_obj`` are counted in an image ENLARGE times as wide and high."""
NEAR = 1e-6


# --------------------------------------------------------------------------------------------- meshes
class ObjectSilhouette:
    """One instance's triangles in its own (model) frame, with an embree BVH for silhouette rays.

    Rays go to embree's occlusion query directly (any hit, float32, coordinates shifted to the mesh's
    corner for precision): no per-call normalisation or float64 copies, which cost more than the casting."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self._shift = self.vertices.min(axis=0) if len(self.vertices) else np.zeros(3)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=(self.vertices - self._shift).astype(np.float32),
                     indices=self.faces.astype(np.int32))

    def hits(self, camera: Camera, cam_from_model: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bool per pixel (u[i], v[i]): does the ray through its centre (u + 0.5, v + 0.5) hit the mesh."""
        if len(u) == 0 or len(self.faces) == 0:
            return np.zeros(len(u), dtype=bool)
        pose = np.asarray(cam_from_model, dtype=np.float64)
        rot = pose[:3, :3]
        origin = (-rot.T @ pose[:3, 3] - self._shift).astype(np.float32)
        x64, y64 = normalized_rays(camera, u + 0.5, v + 0.5)  # a distorted camera's lens undone (NaN: no ray)
        ray = np.isfinite(x64) & np.isfinite(y64)
        x, y = np.where(ray, x64, 0.0).astype(np.float32), np.where(ray, y64, 0.0).astype(np.float32)
        axes = rot.astype(np.float32)  # rows: the camera's x, y, z axes in the model frame
        dirs = x[:, None] * axes[0] + y[:, None] * axes[1] + axes[2]
        origins = np.repeat(origin[None], len(dirs), axis=0)
        return (np.asarray(self._scene.run(origins, dirs, query="OCCLUDED")) >= 0) & ray


def instance_model_meshes(scene: RenderScene) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{instance_id: (vertices (N, 3) in the instance's own frame, metres; faces (M, 3))}``."""
    grouped: dict[int, tuple[list[np.ndarray], list[np.ndarray]]] = {}
    for mesh in scene.meshes:
        verts, faces = grouped.setdefault(int(mesh.instance_id), ([], []))
        offset = sum(len(v) for v in verts)
        verts.append(np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3) + offset)
    out = {}
    for iid, (verts, faces) in grouped.items():
        info = scene.instances.get(iid)
        object_from_world = invert(np.asarray(info.world_from_object)) if info is not None else np.eye(4)
        out[iid] = (transform_points(object_from_world, np.concatenate(verts)), np.concatenate(faces))
    return out


# ----------------------------------------------------------------------------------------- gt info
def _bbox(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def _region(camera: Camera, cam_from_model: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
            enlarge: bool) -> tuple:
    """``(u0, u1, v0, v1, z_far)``: the pixel box worth casting, columns ``u0 <= u < u1`` and rows
    ``v0 <= v < v1`` (the box of the mesh's projection, within the (enlarged) image; empty when ``u0 >= u1``
    or ``v0 >= v1``) and the largest camera z of the vertices (no ray meets the mesh beyond it).

    A mesh reaching behind the camera is clipped at ``z = NEAR`` first: each triangle's visible part is the
    hull of its vertices in front and the points where its edges cross the plane, so the box of those
    projected points (clamped: the crossings project very far out) bounds the silhouette. Without the
    clipping such a mesh would cast the whole enlarged image, nine times the frame, for a few pixels."""
    w, h = camera.width, camera.height
    lo_u, hi_u, lo_v, hi_v = (-w, 2 * w, -h, 2 * h) if enlarge else (0, w, 0, h)
    pts = transform_points(cam_from_model, vertices)
    if len(pts) == 0 or len(faces) == 0:
        return 0, 0, 0, 0, np.inf
    z_far = float(pts[:, 2].max())
    front = pts[:, 2] > NEAR
    if not front.any():
        return 0, 0, 0, 0, z_far
    used = pts[front]
    if not front.all():
        edges = np.asarray(faces, dtype=np.int64)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        edges = edges[front[edges[:, 0]] != front[edges[:, 1]]]
        a, b = pts[edges[:, 0]], pts[edges[:, 1]]
        s = (NEAR - a[:, 2]) / (b[:, 2] - a[:, 2])
        used = np.concatenate([used, a + s[:, None] * (b - a)])
    projected = project_camera_points(camera, used)
    if projected is None:  # a distorted camera sees the mesh beyond its lens model's range: bound what it can see
        projected = lens_image_bounds(camera, used)
    # a distorting lens bends the edges between the vertices: a margin of 2 % of the frame
    pad = 0 if camera_dist_coeffs(camera) is None else int(np.ceil(0.02 * max(w, h)))
    u = np.clip(projected[0], -4.0 * w, 5.0 * w)
    v = np.clip(projected[1], -4.0 * h, 5.0 * h)
    lo_u = max(lo_u, int(np.floor(u.min() - 0.5)) - 1 - pad)
    hi_u = min(hi_u, int(np.ceil(u.max() - 0.5)) + 2 + pad)
    lo_v = max(lo_v, int(np.floor(v.min() - 0.5)) - 1 - pad)
    hi_v = min(hi_v, int(np.ceil(v.max() - 0.5)) + 2 + pad)
    return lo_u, hi_u, lo_v, hi_v, z_far


def gt_info_for(
    camera: Camera,
    cam_from_model: np.ndarray,
    silhouette: ObjectSilhouette,
    visible: np.ndarray,
    depth_valid: np.ndarray,
    enlarge: bool = True,
    scene_miss: np.ndarray | None = None,
    depth: np.ndarray | None = None,
) -> tuple[dict[str, Any], np.ndarray]:
    """(scene_gt_info entry, full in-image mask) of one object in one frame.

    ``visible``: bool (H, W) instance mask of the object; ``depth_valid``: bool (H, W) non-zero BOP depth;
    ``scene_miss``: bool (H, W) pixels whose ray hits nothing in the whole scene (so not this object either);
    ``depth``: (H, W) z-depth of the visible surface (m): a ray that meets the object meets the visible
    surface first, so a pixel whose visible surface lies beyond the object's farthest vertex misses it.
    Only the pixels these do not decide are ray cast (mostly those of occluders in front of the object)."""
    h, w = camera.height, camera.width
    u0, u1, v0, v1, z_far = _region(camera, cam_from_model, silhouette.vertices, silhouette.faces, enlarge)
    full = visible.copy()
    out_x, out_y = np.zeros(0, np.int64), np.zeros(0, np.int64)
    if u0 < u1 and v0 < v1:
        a0, a1, b0, b1 = max(u0, 0), min(u1, w), max(v0, 0), min(v1, h)
        if a0 < a1 and b0 < b1:  # the region's part inside the image: cast only what the frame leaves open
            window = (slice(b0, b1), slice(a0, a1))
            known = visible[window].copy()
            if scene_miss is not None:
                known |= scene_miss[window]
            if depth is not None:
                known |= depth[window] > z_far * (1.0 + 1e-4) + 1e-4  # margin: z-buffer depth rounding
            ty, tx = np.nonzero(~known)
            tx, ty = tx + a0, ty + b0
            hit = silhouette.hits(camera, cam_from_model, tx, ty)
            full[ty[hit], tx[hit]] = True
        # the region's part outside the image (enlarged silhouettes of truncated objects): cast it all
        bands = [(u0, u1, v0, min(v1, 0)), (u0, u1, max(v0, h), v1),
                 (u0, min(u1, 0), b0, b1), (max(u0, w), u1, b0, b1)]
        xs, ys = [], []
        for c0, c1, r0, r1 in bands:
            if c0 < c1 and r0 < r1:
                gx, gy = np.meshgrid(np.arange(c0, c1), np.arange(r0, r1))
                xs.append(gx.ravel())
                ys.append(gy.ravel())
        if xs:
            bx, by = np.concatenate(xs), np.concatenate(ys)
            hit = silhouette.hits(camera, cam_from_model, bx, by)
            out_x, out_y = bx[hit], by[hit]
    in_y, in_x = np.nonzero(full)
    all_x, all_y = np.concatenate([in_x, out_x]), np.concatenate([in_y, out_y])
    px_all = int(len(all_x))
    px_visib = int(visible.sum())
    info = {
        "bbox_obj": _bbox(all_x, all_y) if px_visib > 0 else [-1, -1, -1, -1],
        "bbox_visib": _bbox(*np.nonzero(visible)[::-1]) if px_visib > 0 else [-1, -1, -1, -1],
        "px_count_all": px_all,
        "px_count_valid": int((full & depth_valid).sum()),
        "px_count_visib": px_visib,
        "visib_fract": float(px_visib / px_all) if px_all > 0 else 0.0,
    }
    return info, full


def depth_png(depth_m: np.ndarray, depth_scale: float, where: str = "depth", warn: bool = True) -> np.ndarray:
    """uint16 BOP depth (``depth_mm = png * depth_scale``); no hit and out-of-range depths (deeper than
    ``65535 * depth_scale`` mm: 6.55 m at 0.1) become 0, with a warning when ``warn``."""
    if not depth_scale > 0:
        raise ValueError(f"depth_scale must be > 0, got {depth_scale}")
    scaled = np.asarray(depth_m, dtype=np.float64) * 1000.0 / depth_scale
    finite = np.isfinite(scaled) & (scaled > 0)
    out = np.zeros(scaled.shape, dtype=np.uint16)
    values = np.round(scaled[finite])
    over = values > np.iinfo(np.uint16).max
    if over.any() and warn:
        warnings.warn(
            f"{where}: {int(over.sum())} pixels deeper than {65535 * depth_scale / 1000:.2f} m do not fit "
            f"16 bits at depth_scale {depth_scale}; stored as 0 (invalid). Use a larger depth_scale.",
            stacklevel=2,
        )
        values[over] = 0
    out[finite] = values.astype(np.uint16)
    return out


def _cam_from_model(path: Path, key: str, entry: dict[str, Any]) -> np.ndarray:
    try:
        rot = np.asarray(entry["cam_R_m2c"], dtype=np.float64).reshape(3, 3)
        t = np.asarray(entry["cam_t_m2c"], dtype=np.float64).reshape(3) / 1000.0
    except (KeyError, ValueError) as exc:
        raise DatasetError(f"{path}: frame {key}: bad cam_R_m2c / cam_t_m2c ({exc})") from exc
    return make_pose(rot, t)


def write_bop_extras(seq_dir: Path, scene: RenderScene, depth_scale: float = 0.1, models: bool = True) -> None:
    """Write scene_gt_info.json, mask/, mask_visib/, depth/ (and models/ when ``models``) under
    ``seq_dir/bop`` and set ``depth_scale`` in scene_camera.json. ``scene`` is the stage the sequence was
    rendered from (world frame, as :func:`synthleak.core.usd_read.read_render_scene` returns it)."""
    seq_dir = Path(seq_dir)
    seq = load_sequence(seq_dir)
    bop = seq_dir / "bop"
    gt_path, cam_path = bop / "scene_gt.json", bop / "scene_camera.json"
    scene_gt = read_json(gt_path)
    scene_camera = read_json(cam_path)
    meshes = instance_model_meshes(scene)
    silhouettes: dict[int, ObjectSilhouette] = {}
    roles = {iid: info.role for iid, info in scene.instances.items()}
    gt_info: dict[str, list[dict[str, Any]]] = {}
    too_deep = 0
    for key in sorted(scene_gt, key=int):
        im_id = int(key)
        camera = seq.camera_of(im_id)  # the frame's own (distorted / resized) camera
        depth = seq.depth(im_id)
        instance = seq.instance(im_id)
        png = depth_png(depth, depth_scale, warn=False)
        too_deep += int((np.isfinite(depth) & (png == 0)).sum())
        atomic_write_bytes(bop / "depth" / f"{im_id:06d}.png", encode_png(png))
        valid = png > 0
        miss = (instance == 0) & ~np.isfinite(depth)
        entries = []
        for gt_id, entry in enumerate(scene_gt[key]):
            obj_id = int(entry["obj_id"])
            if obj_id not in meshes:
                raise DatasetError(f"{gt_path}: frame {key}: obj_id {obj_id} has no mesh in {scene.source!r}")
            if obj_id not in silhouettes:
                silhouettes[obj_id] = ObjectSilhouette(*meshes[obj_id])
            visible = instance == obj_id
            info, full = gt_info_for(
                camera,
                _cam_from_model(gt_path, key, entry),
                silhouettes[obj_id],
                visible,
                valid,
                enlarge=roles.get(obj_id) != "shell",
                scene_miss=miss,
                depth=depth,
            )
            entries.append(info)
            name = f"{im_id:06d}_{gt_id:06d}.png"
            atomic_write_bytes(bop / "mask" / name, encode_png(full.astype(np.uint8) * 255))
            atomic_write_bytes(bop / "mask_visib" / name, encode_png(visible.astype(np.uint8) * 255))
        gt_info[key] = entries
    atomic_write_json(bop / "scene_gt_info.json", gt_info)
    if too_deep:
        warnings.warn(
            f"{seq_dir}: {too_deep} depth pixels deeper than {65535 * depth_scale / 1000:.2f} m do not fit 16 bits "
            f"at depth_scale {depth_scale}; stored as 0 (invalid) in bop/depth. Use a larger depth_scale.",
            stacklevel=2,
        )
    for entry in scene_camera.values():
        entry["depth_scale"] = float(depth_scale)
    atomic_write_json(cam_path, scene_camera)
    if models:
        ids = sorted({int(e["obj_id"]) for v in scene_gt.values() for e in v})
        write_bop_models(bop / "models", scene, ids)


# ------------------------------------------------------------------------------------------- models
def _symmetries(symmetry: str) -> dict[str, Any]:
    """BOP symmetry entries (model frame, mm) for a declared symmetry about the canonical +z axis."""
    if symmetry == "z":
        return {"symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]}
    folds = {"2": 2, "4": 4}.get(symmetry)
    if folds is None:
        return {}
    out = []
    for k in range(1, folds):
        a = 2.0 * np.pi * k / folds
        c, s = round(float(np.cos(a)), 15), round(float(np.sin(a)), 15)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) + 0.0  # +0.0: no negative zeros
        out.append(make_pose(rot, np.zeros(3)).ravel().tolist())
    return {"symmetries_discrete": out}


def diameter(points: np.ndarray) -> float:
    """Largest distance between any two points (over the convex hull's vertices)."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    try:
        hull = trimesh.convex.convex_hull(pts).vertices
    except Exception:  # noqa: BLE001 - flat or degenerate point sets: use all points
        hull = pts
    best = 0.0
    for start in range(0, len(hull), 1024):  # chunked: bounded memory for large hulls
        d = hull[start : start + 1024, None, :] - hull[None, :, :]
        best = max(best, float(np.sqrt((d**2).sum(-1)).max()))
    return best


def ply_text(vertices_mm: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> str:
    """ASCII PLY (x y z nx ny nz, triangles) as bop_toolkit's ``inout.load_ply`` reads it."""
    header = (
        "ply\nformat ascii 1.0\ncomment synthleak BOP model, millimetres\n"
        f"element vertex {len(vertices_mm)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    # on the printed grid first: a normal of -1e-17 on one CPU and +1e-17 on another prints -0.000000 / 0.000000
    vrows = snap(np.concatenate([vertices_mm, normals], axis=1), 1e-6)
    vlines = "\n".join(" ".join(f"{x:.6f}" for x in row) for row in vrows)
    flines = "\n".join(f"3 {a} {b} {c}" for a, b, c in np.asarray(faces, dtype=np.int64))
    return header + vlines + ("\n" if len(vrows) else "") + flines + ("\n" if len(faces) else "")


def write_bop_models(models_dir: Path, scene: RenderScene, obj_ids: list[int] | None = None) -> Path:
    """``models_dir/obj_%06d.ply`` (instance mesh in its own frame, millimetres, vertex normals) and
    ``models_info.json`` (diameter, min_*, size_*, symmetries from the declared symmetry). Returns
    the models_info.json path."""
    models_dir = Path(models_dir)
    meshes = instance_model_meshes(scene)
    ids = sorted(meshes) if obj_ids is None else [int(i) for i in obj_ids]
    info: dict[str, dict[str, Any]] = {}
    for iid in ids:
        if iid not in meshes:
            raise ValueError(f"write_bop_models: instance {iid} has no mesh in {scene.source!r}")
        verts, faces = meshes[iid]
        mm = verts * 1000.0
        normals = np.asarray(trimesh.Trimesh(mm, faces, process=False, validate=False).vertex_normals, dtype=np.float64)
        atomic_write_text(models_dir / f"obj_{iid:06d}.ply", ply_text(mm, faces, normals))
        lo, hi = mm.min(axis=0), mm.max(axis=0)
        entry: dict[str, Any] = {"diameter": diameter(mm)}
        for axis, name in enumerate("xyz"):
            entry[f"min_{name}"] = float(lo[axis])
            entry[f"size_{name}"] = float(hi[axis] - lo[axis])
        inst = scene.instances.get(iid)
        entry.update(_symmetries(inst.symmetry if inst is not None else "none"))
        info[str(iid)] = entry
    path = models_dir / "models_info.json"
    atomic_write_json(path, info)
    return path
