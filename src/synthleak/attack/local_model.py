"""The attacker's local object model: poses of its own images relative to the photographed object.

Two sources:

* :func:`oracle_local_poses`: the exact ``cam_from_object`` stored with every attacker sequence (an
  attacker with a perfect local reconstruction, in the object's canonical frame).
* :func:`sfm_local_poses`: what a real attacker has, a pycolmap incremental SfM of its images, in an
  arbitrary SfM frame ("local"), brought to metric scale with the known object size (paper Sec. 3.2: "the
  scale of the local model can be (approximately) recovered using the known size of the object").

Metric scale: the attacker segments its own images (the instance mask of the target) and keeps the
triangulated points that most of their observations place inside the mask. The diagonal ``d_sfm`` of their
minimum-volume oriented bounding box (after a statistical outlier removal) and the known object extents
give the scale ``||extents|| / d_sfm``. Only surfaces seen from the orbit are reconstructed (never the
underside), so this is approximate, like the paper's manual scaling (0.4 % off on a rendered 40-frame
sideboard orbit).

``object_from_local`` (a Sim(3) registration of the scaled SfM camera centres onto the GT camera centres,
Umeyama) is for SCORING only: an estimate ``scene_from_local`` from the attack becomes a comparable
``scene_from_object = scene_from_local @ inv(object_from_local)``; the attack never sees it.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.attack.align import umeyama
from synthleak.geometry.poses import camera_centre


def _load(sequence: Any) -> Any:
    if isinstance(sequence, str | Path):
        from synthleak.render.dataset import load_sequence

        return load_sequence(Path(sequence))
    return sequence


def oracle_local_poses(sequence: Any) -> dict[str, np.ndarray]:
    """``{frame name: cam_from_object}`` of an attacker sequence (a loaded Sequence or its folder)."""
    seq = _load(sequence)
    if getattr(seq, "frame", "object") != "object":
        raise ValueError(f"{seq.root}: objects.json frame is {seq.frame!r}, attacker sequences use 'object'")
    return {name: np.array(seq.cam_from_world[name], dtype=np.float64) for name in seq.frames}


@dataclass
class SfmLocalModel:
    """Result of :func:`sfm_local_poses`. Poses and points are in the metric-scaled SfM ("local") frame."""

    cam_from_local: dict[str, np.ndarray]
    points_local: np.ndarray
    object_point_mask: np.ndarray
    metric_scale: float
    """Metres per SfM unit applied to the reconstruction (from the known object size)."""
    object_from_local: np.ndarray | None
    """Sim(3) of the scaled local frame onto the object frame, from GT: scoring only."""
    registration_rmse_m: float
    registered: list[str]
    unregistered: list[str]
    ok: bool
    message: str
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def object_from_local_scale(self) -> float:
        """Residual scale error of the metric scaling (1.0 = perfect); NaN without a registration."""
        if self.object_from_local is None:
            return float("nan")
        return float(np.cbrt(np.linalg.det(self.object_from_local[:3, :3])))


def scene_from_object_estimate(scene_from_local: np.ndarray, object_from_local: np.ndarray) -> np.ndarray:
    """Scoring helper: the attack's ``scene_from_local`` re-expressed for the object frame (a similarity)."""
    local_from_object = np.linalg.inv(np.asarray(object_from_local, dtype=np.float64))
    return np.asarray(scene_from_local, dtype=np.float64) @ local_from_object


def metric_scale_from_points(points: np.ndarray, object_extents: np.ndarray, k: int = 8) -> float:
    """``||extents|| / ||OBB extents||`` of the object's SfM points (NaN with fewer than 10 points).

    Stray points are dropped first (statistical outlier removal: mean distance to the ``k`` nearest
    neighbours above median + 3 x 1.4826 MAD), then the minimum-volume oriented bounding box (trimesh) of
    the rest gives the reconstructed size.
    """
    import trimesh
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    ext = np.asarray(object_extents, dtype=np.float64).reshape(3)
    if points.shape[0] < max(10, k + 2):
        return float("nan")
    dist, _ = cKDTree(points).query(points, k + 1)
    mean_nn = dist[:, 1:].mean(axis=1)
    med = np.median(mean_nn)
    mad = 1.4826 * np.median(np.abs(mean_nn - med))
    kept = points[mean_nn <= med + 3.0 * mad]
    try:
        _, obb_extents = trimesh.bounds.oriented_bounds(kept)
    except Exception:  # degenerate (planar / collinear) point sets
        return float("nan")
    diag = float(np.linalg.norm(obb_extents))
    return float(np.linalg.norm(ext) / diag) if diag > 0 else float("nan")


def _pose4(rigid) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :] = np.asarray(rigid.matrix(), dtype=np.float64)
    return pose


def _object_points(rec, seq, target_id: int) -> tuple[np.ndarray, np.ndarray]:
    """All 3D points and a mask of those most of whose observations fall in the target's instance mask."""
    masks: dict[int, np.ndarray] = {}
    ids = sorted(rec.points3D)
    xyz = np.zeros((len(ids), 3))
    on_object = np.zeros(len(ids), dtype=bool)
    for k, pid in enumerate(ids):
        point = rec.points3D[pid]
        xyz[k] = point.xyz
        votes = total = 0
        for el in point.track.elements:
            image = rec.images[el.image_id]
            if el.image_id not in masks:
                masks[el.image_id] = seq.instance(image.name) == target_id
            mask = masks[el.image_id]
            u, v = np.floor(image.points2D[el.point2D_idx].xy).astype(int)
            if 0 <= v < mask.shape[0] and 0 <= u < mask.shape[1]:
                votes += int(mask[v, u])
                total += 1
        on_object[k] = total > 0 and votes * 2 > total
    return xyz, on_object


def sfm_local_poses(
    sequence: Any,
    object_extents: np.ndarray,
    workdir: str | Path,
    *,
    frames: list[str] | None = None,
    matcher: str = "auto",
    max_features: int = 4096,
    peak_threshold: float = 0.004,
    num_threads: int = 1,
    seed: int = 0,
    min_num_matches: int = 15,
    init_min_num_inliers: int = 30,
    abs_pose_min_num_inliers: int = 15,
) -> SfmLocalModel:
    """pycolmap SfM (SIFT, exhaustive or sequential matching, incremental mapping, fixed PINHOLE intrinsics)
    of an attacker sequence, scaled to metres with ``object_extents`` (the attacker's knowledge of the size).

    ``matcher``: ``exhaustive``, ``sequential`` (orbit order, overlap 10) or ``auto`` (exhaustive up to 60
    images). ``num_threads`` for extraction/matching (0 = all cores): the default 1 with the fixed ``seed``
    (COLMAP PRNG, two-view RANSAC, single-threaded mapper) gives bit-identical results; more threads are
    faster but differ in the last digits. ``min_num_matches`` / ``init_min_num_inliers`` /
    ``abs_pose_min_num_inliers`` relax COLMAP's defaults (15 / 100 / 30), and ``peak_threshold`` (SIFT
    contrast, default 0.0067) is lowered, because those are tuned for large photos, not small renders of
    plain furniture. If SfM registers only part of the images, the rest are
    listed in ``unregistered`` (the attack then sends only registered images: the others have no local
    pose); if nothing reconstructs, ``ok`` is False and the message says why.
    """
    import pycolmap

    seq = _load(sequence)
    extents = np.asarray(object_extents, dtype=np.float64).reshape(-1)
    if extents.shape != (3,) or not np.all(np.isfinite(extents)) or np.any(extents <= 0):
        raise ValueError(f"object_extents: expected three positive finite sizes, got {object_extents!r}")
    if seq.target_instance_id is None:
        raise ValueError(f"{seq.root}: objects.json target_instance_id is null: not an attacker sequence")
    names = list(seq.frames if frames is None else frames)
    unknown = [n for n in names if n not in seq.cam_from_world]
    if unknown:
        raise ValueError(f"frames: not in {seq.root}: {unknown[:5]}")
    workdir = Path(workdir)
    if workdir.exists():
        shutil.rmtree(workdir)
    (workdir / "sparse").mkdir(parents=True)
    database = workdir / "database.db"
    threads = num_threads if num_threads > 0 else (os.cpu_count() or 1)

    cam = seq.camera
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = ",".join(repr(float(v)) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = max_features
    extraction.sift.peak_threshold = float(peak_threshold)
    pycolmap.extract_features(database, seq.root / "images", image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    pycolmap.set_random_seed(int(seed) % (2**31))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(seed) % (2**31)
    kind = matcher if matcher != "auto" else ("exhaustive" if len(names) <= 60 else "sequential")
    if kind == "exhaustive":
        pycolmap.match_exhaustive(database, matching_options=matching, verification_options=verification,
                                  device=pycolmap.Device.cpu)
    elif kind == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = 10
        pairing.quadratic_overlap = True
        pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification, device=pycolmap.Device.cpu)
    else:
        raise ValueError(f"matcher: expected exhaustive | sequential | auto, got {matcher!r}")

    options = pycolmap.IncrementalPipelineOptions()
    options.ba_refine_focal_length = False
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    options.num_threads = 1
    options.min_num_matches = int(min_num_matches)
    options.mapper.init_min_num_inliers = int(init_min_num_inliers)
    options.mapper.abs_pose_min_num_inliers = int(abs_pose_min_num_inliers)
    options.random_seed = int(seed) % (2**31)
    options.mapper.random_seed = int(seed) % (2**31)
    options.mapper.num_threads = 1
    recs = pycolmap.incremental_mapping(database, seq.root / "images", workdir / "sparse", options)

    def failed(message: str) -> SfmLocalModel:
        return SfmLocalModel({}, np.zeros((0, 3)), np.zeros(0, dtype=bool), float("nan"), None, float("nan"),
                             [], names, False, message, {"matcher": kind})

    if not recs:
        return failed("SfM failed: no reconstruction (too few matches or no initial pair)")
    rec = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    raw = {rec.images[i].name: _pose4(rec.images[i].cam_from_world()) for i in rec.reg_image_ids()}
    registered = [n for n in names if n in raw]
    unregistered = [n for n in names if n not in raw]
    xyz, on_object = _object_points(rec, seq, int(seq.target_instance_id))
    scale = metric_scale_from_points(xyz[on_object], extents)
    stats = {"matcher": kind, "n_models": len(recs), "n_points": int(len(xyz)),
             "n_object_points": int(on_object.sum()), "n_registered": len(registered)}
    if not np.isfinite(scale):
        model = failed(f"SfM registered {len(registered)} images but only {int(on_object.sum())} points lie "
                       "on the object: cannot recover the metric scale")
        model.stats.update(stats)
        return model
    cam_from_local = {}
    for name in registered:
        pose = raw[name].copy()
        pose[:3, 3] *= scale
        cam_from_local[name] = pose
    points = xyz * scale
    object_from_local, rmse = _register_to_gt(cam_from_local, seq)
    message = f"SfM registered {len(registered)}/{len(names)} images"
    if unregistered:
        message += f" ({len(unregistered)} unregistered)"
    if len(recs) > 1:
        message += f"; {len(recs)} models, kept the largest"
    return SfmLocalModel(cam_from_local, points, on_object, float(scale), object_from_local, rmse, registered,
                         unregistered, len(registered) >= 2, message, stats)


def _register_to_gt(cam_from_local: dict[str, np.ndarray], seq) -> tuple[np.ndarray | None, float]:
    """Umeyama Sim(3) of local camera centres onto GT object-frame centres (scoring only) and its RMSE."""
    names = sorted(cam_from_local)
    if len(names) < 3:
        return None, float("nan")
    src = np.array([camera_centre(cam_from_local[n]) for n in names])
    dst = np.array([camera_centre(np.asarray(seq.cam_from_world[n])) for n in names])
    scale, rot, trans = umeyama(src, dst, with_scale=True)
    pose = np.eye(4)
    pose[:3, :3] = scale * rot
    pose[:3, 3] = trans
    rmse = float(np.sqrt(np.mean(np.sum((src @ pose[:3, :3].T + trans - dst) ** 2, axis=1))))
    return pose, rmse


def local_pose_errors(model: SfmLocalModel, sequence: Any) -> dict[str, float]:
    """Scoring: median rotation (deg) / centre (m) error of the SfM poses after ``object_from_local``."""
    seq = _load(sequence)
    if model.object_from_local is None:
        return {"median_rot_deg": float("nan"), "median_centre_m": float("nan")}
    sim = model.object_from_local
    scale = np.cbrt(np.linalg.det(sim[:3, :3]))
    rot_ol = sim[:3, :3] / scale
    rot_errs, centre_errs = [], []
    for name, pose in model.cam_from_local.items():
        gt = np.asarray(seq.cam_from_world[name])
        r_est = pose[:3, :3] @ rot_ol.T  # cam_from_object rotation implied by the local pose
        cos = (np.trace(r_est @ gt[:3, :3].T) - 1) / 2
        rot_errs.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        c_obj = sim[:3, :3] @ camera_centre(pose) + sim[:3, 3]
        centre_errs.append(np.linalg.norm(c_obj - camera_centre(gt)))
    return {"median_rot_deg": float(np.median(rot_errs)), "median_centre_m": float(np.median(centre_errs))}


__all__ = [
    "SfmLocalModel",
    "local_pose_errors",
    "metric_scale_from_points",
    "oracle_local_poses",
    "scene_from_object_estimate",
    "sfm_local_poses",
]
