"""The attacker's local object model: poses of its own images relative to the photographed object.

Two sources:

* :func:`oracle_local_poses`: the exact ``cam_from_object`` stored with every attacker sequence (an
  attacker with a perfect local reconstruction, in the object's canonical frame).
* :func:`sfm_local_poses`: what a real attacker has, a pycolmap incremental SfM of its images, in an
  arbitrary SfM frame ("local"), brought to metric scale with the known object size (paper Sec. 3.2: "the
  scale of the local model can be (approximately) recovered using the known size of the object").

Metric scale: the attacker segments its own images (the instance mask of the target) and keeps the
triangulated points that most of their observations place inside the mask. After a statistical outlier
removal, their upright box (height along the up direction of the hand-held cameras, :func:`up_from_cameras`;
minimum-area rectangle of the footprint) has the diagonal ``d_sfm``, and the known object extents give the
scale ``||extents|| / d_sfm``. Only surfaces seen from the orbit are reconstructed (never the underside), so
this is approximate, like the paper's manual scaling: within 2.5 % for 11 of 13 study-small objects on 48-frame
orbits (the bicycle's thin tubes give a box 26 % too small, the sofa 4 %).

``object_from_local`` (a Sim(3) registration of the scaled SfM camera centres onto the GT camera centres,
LO-RANSAC then Umeyama on the inliers) is for SCORING only: an estimate ``scene_from_local`` from the attack
becomes a comparable ``scene_from_object = scene_from_local @ inv(object_from_local)``; the attack never sees
it. Registered views it leaves out are the ones SfM put in a wrong place (``stats["misregistered"]``).
:func:`cached_sfm_local_poses` keeps a model next to its COLMAP workspace and rebuilds it only when its inputs
change.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.attack.align import umeyama
from synthleak.attack.gravity import up_from_cameras
from synthleak.core.dataset import colmap_camera_model, load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, rotation_error_deg


def _load(sequence: Any) -> Any:
    return load_sequence(Path(sequence)) if isinstance(sequence, str | Path) else sequence


def oracle_local_poses(sequence: Any) -> dict[str, np.ndarray]:
    """``{frame name: cam_from_object}`` of an attacker sequence (a loaded Sequence or its folder)."""
    seq = _load(sequence)
    if getattr(seq, "frame", "object") != "object":
        raise ValueError(f"{seq.root}: objects.json frame is {seq.frame!r}, attacker sequences use 'object'")
    return {name: np.array(seq.cam_from_object[name], dtype=np.float64) for name in seq.frames}


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


def metric_scale_from_points(points: np.ndarray, object_extents: np.ndarray, k: int = 8,
                             up: np.ndarray | None = None) -> float:
    """``||extents|| / ||box extents||`` of the object's SfM points (NaN with fewer than 10 points).

    Stray points are dropped first (statistical outlier removal: mean distance to the ``k`` nearest
    neighbours above median + 3 x 1.4826 MAD). The box: with ``up`` (the SfM frame's up direction,
    :func:`up_from_cameras`), the height of the rest along ``up`` and the minimum-area rectangle of their
    horizontal footprint (an upright box, like the object's own axes); without it, their minimum-volume
    oriented bounding box, whose axes need not be the object's (a tapered stool gets a tilted, larger box).
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
        if up is None:
            _, box = trimesh.bounds.oriented_bounds(kept)
        else:
            up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
            basis = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]  # two horizontal unit vectors
            height = float(np.ptp(kept @ up))
            _, footprint = trimesh.bounds.oriented_bounds_2D(kept @ basis)
            box = np.array([*footprint, height])
    except Exception:  # degenerate (planar / collinear) point sets
        return float("nan")
    diag = float(np.linalg.norm(box))
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


def camera_groups(seq: Any, names: list[str]) -> dict[Camera, list[str]]:
    """``{camera: its frames}`` of ``names`` (each frame's own camera, in order of first use; frames in the
    given order): what SfM extracts with one COLMAP camera each."""
    groups: dict[Camera, list[str]] = {}
    for name in names:
        groups.setdefault(seq.camera_of(name), []).append(name)
    return groups


def sfm_local_poses(
    sequence: Any,
    object_extents: np.ndarray,
    workdir: str | Path,
    *,
    frames: list[str] | None = None,
    matcher: str = "sequential",
    max_features: int = 4096,
    peak_threshold: float = 0.004,
    num_threads: int = 1,
    seed: int = 0,
    min_num_matches: int = 15,
    init_min_num_inliers: int = 30,
    abs_pose_min_num_inliers: int = 15,
) -> SfmLocalModel:
    """pycolmap SfM (SIFT, exhaustive or sequential matching, incremental mapping, fixed intrinsics) of an
    attacker sequence, scaled to metres with ``object_extents`` (the attacker's knowledge of the size).

    Intrinsics: each frame's own camera (``Sequence.camera_of``), one COLMAP camera per distinct one
    (:func:`camera_groups`): ``PINHOLE``, or ``OPENCV`` / ``FULL_OPENCV`` for photos with a lens distortion
    (web photos, each its own device and size after the resize), all held fixed in bundle adjustment (an
    attacker that knows its photos' calibration). An all-pinhole sequence of one camera runs exactly the
    single-camera SfM it always did.

    ``matcher``: ``sequential`` (capture order: each image with its 10 successors and those 2^k further on),
    ``exhaustive`` or ``auto`` (= sequential). An attacker films or photographs its object in order, and
    exhaustive matching pairs opposite sides of symmetric furniture (a chest of drawers front and back): on
    24-frame orbits it registered blocks of 3-18 views in wrong places (study-small-pyrender, 7 of 13
    objects), sequential matching on 48-frame orbits none but one bicycle view. ``num_threads`` for
    extraction/matching (0 = all cores): the default 1 with the fixed ``seed`` (COLMAP PRNG, two-view RANSAC,
    single-threaded mapper) gives bit-identical results; more threads are faster but differ in the last
    digits. ``min_num_matches`` / ``init_min_num_inliers`` / ``abs_pose_min_num_inliers`` relax COLMAP's
    defaults (15 / 100 / 30), and ``peak_threshold`` (SIFT contrast, default 0.0067) is lowered, because
    those are tuned for large photos, not small renders of plain furniture. If SfM registers only part of
    the images, the rest are listed in ``unregistered`` (the attack leaves them out: they have no local
    pose); if nothing reconstructs, ``ok`` is False and the message says why.
    """
    import time

    import pycolmap

    started = time.perf_counter()
    seq = _load(sequence)
    extents = np.asarray(object_extents, dtype=np.float64).reshape(-1)
    if extents.shape != (3,) or not np.all(np.isfinite(extents)) or np.any(extents <= 0):
        raise ValueError(f"object_extents: expected three positive finite sizes, got {object_extents!r}")
    if seq.target_instance_id is None:
        raise ValueError(f"{seq.root}: objects.json target_instance_id is null: not an attacker sequence")
    names = list(seq.frames if frames is None else frames)
    unknown = [n for n in names if n not in seq.cam_from_object]
    if unknown:
        raise ValueError(f"frames: not in {seq.root}: {unknown[:5]}")
    workdir = Path(workdir)
    if workdir.exists():
        shutil.rmtree(workdir)
    (workdir / "sparse").mkdir(parents=True)
    database = workdir / "database.db"
    threads = num_threads if num_threads > 0 else (os.cpu_count() or 1)

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.max_num_features = max_features
    extraction.sift.peak_threshold = float(peak_threshold)
    for cam, group in camera_groups(seq, names).items():  # one COLMAP camera per distinct frame camera
        model, params = colmap_camera_model(cam)  # PINHOLE, or OPENCV / FULL_OPENCV with the photo's lens
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = model
        reader.camera_params = ",".join(repr(float(v)) for v in params)
        pycolmap.extract_features(database, seq.root / "images", image_names=group,
                                  camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                  extraction_options=extraction, device=pycolmap.Device.cpu)
    pycolmap.set_random_seed(int(seed) % (2**31))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = int(seed) % (2**31)
    kind = matcher if matcher != "auto" else "sequential"
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
                             [], names, False, message,
                             {"matcher": kind, "seconds": round(time.perf_counter() - started, 2)})

    if not recs:
        return failed("SfM failed: no reconstruction (too few matches or no initial pair)")
    rec = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
    raw = {rec.images[i].name: _pose4(rec.images[i].cam_from_world()) for i in rec.reg_image_ids()}
    registered = [n for n in names if n in raw]
    unregistered = [n for n in names if n not in raw]
    xyz, on_object = _object_points(rec, seq, int(seq.target_instance_id))
    scale = metric_scale_from_points(xyz[on_object], extents, up=up_from_cameras(raw))
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
    object_from_local, rmse, misregistered = _register_to_gt(cam_from_local, seq, seed)
    stats["misregistered"] = misregistered
    stats["seconds"] = round(time.perf_counter() - started, 2)
    message = f"SfM registered {len(registered)}/{len(names)} images"
    if unregistered:
        message += f" ({len(unregistered)} unregistered)"
    if len(recs) > 1:
        message += f"; {len(recs)} models, kept the largest"
    return SfmLocalModel(cam_from_local, points, on_object, float(scale), object_from_local, rmse, registered,
                         unregistered, len(registered) >= 2, message, stats)


def _register_to_gt(cam_from_local: dict[str, np.ndarray], seq, seed: int = 0
                    ) -> tuple[np.ndarray | None, float, list[str]]:
    """Scoring only: Sim(3) ``object_from_local`` of the local camera centres onto the GT object-frame centres
    (pycolmap LO-RANSAC, inlier error 5 % of the median GT camera distance, then Umeyama on the inliers), its
    RMSE over the inliers, and the registered frames it leaves out (SfM registered them in a wrong place)."""
    names = sorted(cam_from_local)
    if len(names) < 3:
        return None, float("nan"), []
    import pycolmap

    src = np.array([camera_centre(cam_from_local[n]) for n in names])
    dst = np.array([camera_centre(np.asarray(seq.cam_from_object[n])) for n in names])
    options = pycolmap.RANSACOptions()
    options.max_error = 0.05 * float(np.median(np.linalg.norm(dst, axis=1)))
    options.random_seed = int(seed) % (2**31)
    found = pycolmap.estimate_sim3d_robust(src, dst, options)
    keep = np.asarray(found["inlier_mask"], dtype=bool) if found else np.ones(len(names), dtype=bool)
    if keep.sum() < 3:
        keep = np.ones(len(names), dtype=bool)
    scale, rot, trans = umeyama(src[keep], dst[keep], with_scale=True)
    pose = np.eye(4)
    pose[:3, :3] = scale * rot
    pose[:3, 3] = trans
    err = np.sqrt(np.sum((src[keep] @ pose[:3, :3].T + trans - dst[keep]) ** 2, axis=1))
    return pose, float(np.sqrt(np.mean(err**2))), [n for n, k in zip(names, keep, strict=True) if not k]


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
        gt = np.asarray(seq.cam_from_object[name])
        r_est = pose[:3, :3] @ rot_ol.T  # cam_from_object rotation implied by the local pose
        rot_errs.append(rotation_error_deg(r_est, gt[:3, :3]))
        c_obj = sim[:3, :3] @ camera_centre(pose) + sim[:3, 3]
        centre_errs.append(np.linalg.norm(c_obj - camera_centre(gt)))
    return {"median_rot_deg": float(np.median(rot_errs)), "median_centre_m": float(np.median(centre_errs))}


SFM_CACHE_VERSION = 1
"""Bump when :func:`sfm_local_poses` changes what it computes: cached local models are then rebuilt."""


def _sequence_digest(seq, names: list[str]) -> str:
    """SHA-256 over the frames' image bytes, instance masks, camera and GT poses (what SfM and scoring read)."""
    import hashlib

    digest = hashlib.sha256()
    cam = seq.camera
    digest.update(repr((cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)).encode())
    if any(seq.camera_of(n) != cam for n in names):  # per-frame cameras (lens, resize); one camera: as before
        for name in names:
            digest.update(repr((name, *colmap_camera_model(seq.camera_of(name)))).encode())
    for name in names:
        digest.update(name.encode())
        digest.update(Path(seq.image_path(name)).read_bytes())
        digest.update(np.ascontiguousarray(seq.instance(name)).tobytes())
        digest.update(np.asarray(seq.cam_from_object[name], dtype=np.float64).tobytes())
    return digest.hexdigest()


def _model_to_json(model: SfmLocalModel) -> dict[str, Any]:
    return {
        "cam_from_local": {k: np.asarray(v).tolist() for k, v in sorted(model.cam_from_local.items())},
        "metric_scale": model.metric_scale,
        "object_from_local": None if model.object_from_local is None else model.object_from_local.tolist(),
        "registration_rmse_m": model.registration_rmse_m,
        "registered": model.registered, "unregistered": model.unregistered, "ok": model.ok,
        "message": model.message, "stats": model.stats,
    }


def _model_from_json(data: dict[str, Any], points: np.ndarray, mask: np.ndarray) -> SfmLocalModel:
    sim = data["object_from_local"]
    return SfmLocalModel({k: np.array(v, dtype=np.float64) for k, v in data["cam_from_local"].items()}, points,
                         mask, float(data["metric_scale"]), None if sim is None else np.array(sim, dtype=np.float64),
                         float(data["registration_rmse_m"]), list(data["registered"]), list(data["unregistered"]),
                         bool(data["ok"]), str(data["message"]), dict(data["stats"]))


def cached_sfm_local_poses(sequence: Any, object_extents: np.ndarray, workdir: str | Path, **options: Any
                           ) -> SfmLocalModel:
    """:func:`sfm_local_poses`, kept in ``workdir`` (``model.json`` + ``points.npz``) and rebuilt only when the
    sequence (images, masks, camera, poses), the extents or ``options`` change. ``stats`` gains the scoring
    figures ``scale_error`` (``object_from_local_scale - 1``), ``median_rot_deg`` / ``median_centre_m``
    (:func:`local_pose_errors`); ``stats["seconds"]`` is the wall time of the run that built it."""
    import json

    import pycolmap

    from synthleak.atomic_io import atomic_write_bytes, atomic_write_text
    from synthleak.cache import cache_key

    seq = _load(sequence)
    workdir = Path(workdir)
    names = list(options.get("frames") or seq.frames)
    key = cache_key("sfm", SFM_CACHE_VERSION, pycolmap.__version__, _sequence_digest(seq, names),
                    np.asarray(object_extents, dtype=np.float64).tolist(), {k: options[k] for k in sorted(options)})
    path, points_path = workdir / "model.json", workdir / "points.npz"
    if path.is_file() and points_path.is_file():
        try:
            data = json.loads(path.read_text())
            if data.get("key") == key:
                with np.load(points_path) as npz:
                    return _model_from_json(data["model"], npz["points"], npz["on_object"])
        except (OSError, ValueError, KeyError):
            pass  # unreadable or partial: rebuild
    model = sfm_local_poses(seq, object_extents, workdir / "colmap", **options)
    model.stats["scale_error"] = model.object_from_local_scale - 1.0
    model.stats.update(local_pose_errors(model, seq))
    import io

    buf = io.BytesIO()
    np.savez(buf, points=model.points_local, on_object=model.object_point_mask)
    atomic_write_bytes(points_path, buf.getvalue())
    atomic_write_text(path, json.dumps({"key": key, "model": _model_to_json(model)}, indent=1, allow_nan=True))
    return model


__all__ = [
    "SfmLocalModel",
    "cached_sfm_local_poses",
    "local_pose_errors",
    "metric_scale_from_points",
    "up_from_cameras",
    "oracle_local_poses",
    "scene_from_object_estimate",
    "sfm_local_poses",
]
