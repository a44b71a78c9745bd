"""Build a localization map from a walk-through with known GT poses (HLoc "triangulation from poses").

Features on the map frames -> pairs from poses -> matching, filtered by the epipolar geometry of the
known poses -> tracks -> DLT triangulation with the GT poses -> COLMAP model + npz files (see
:mod:`synthleak.localize.store`). Each 3D point gets the majority GT instance id under its observations.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pycolmap

from synthleak.atomic_io import atomic_write_text
from synthleak.config import LocalizeConfig
from synthleak.core.dataset import DatasetError, Sequence, camera_dist_coeffs, load_sequence, pycolmap_camera
from synthleak.localize.deep import numerics_record
from synthleak.localize.features import Features
from synthleak.localize.pairs import pairs_from_poses
from synthleak.localize.representations import DEFAULT_REPRESENTATION
from synthleak.localize.retrieval import BowIndex, BowParams
from synthleak.localize.store import FORMAT_VERSION, camera_to_json
from synthleak.localize.tiers import DEFAULT_PROFILE, profile_tier, shared_matcher
from synthleak.localize.triangulation import (
    build_tracks,
    epipolar_distance,
    fundamental_from_poses,
    triangulate_track,
)
from synthleak.localize.visibility import FILE_NAME as IMAGE_INSTANCES_FILE
from synthleak.localize.visibility import VISIBLE_MIN_FRACTION, image_instances_json
from synthleak.progress import progress_bar

EPIPOLAR_MAX_PX = 4.0
TRIANGULATION_MAX_ERROR_PX = 4.0
TRIANGULATION_MIN_ANGLE_DEG = 1.0


def inputs_hash(seq: Sequence) -> str:
    """sha256 over the camera, poses, split and the map frames' images and instance masks."""
    digest = hashlib.sha256()
    files = [seq.root / "colmap" / "cameras.txt", seq.root / "colmap" / "images.txt", seq.root / "split.json"]
    for name in seq.map_frames:
        files += [seq.image_path(name), seq.instance_path(name)]
    for path in files:
        digest.update(str(path.relative_to(seq.root)).encode())
        digest.update(path.read_bytes() if path.is_file() else b"<missing>")
    return digest.hexdigest()


def bow_params(config: LocalizeConfig) -> BowParams:
    """The bag-of-words index a map is built with (every map has one, whatever ``config.retrieval``)."""
    return BowParams(branching=config.bow_branching, depth=config.bow_depth)


def _retrieval_meta(config: LocalizeConfig) -> dict:
    """``map.json``'s ``retrieval``: what a server of this map retrieves with (the config's method and top k)
    and the parameters of its ``bow.npz``."""
    return {"method": config.retrieval, "top_k": config.top_k, "bow": bow_params(config).to_json()}


def _map_settings(tier: str, config: LocalizeConfig, weights: dict) -> dict:
    settings = {"tier": tier, "max_keypoints": config.max_keypoints, "pairs_per_image": config.pairs_per_image,
                "bow": bow_params(config).to_json(), "visible_min_fraction": VISIBLE_MIN_FRACTION,
                "format_version": FORMAT_VERSION}
    if weights:  # learned tiers: new weights or a new definition (thresholds, budget), new map
        settings["weights_sha256"] = {k: v["sha256"] for k, v in weights.items()}
    if profile_tier(tier, config.profile).needs_torch:  # other torch numerics, other features: new map
        settings["torch_numerics"] = numerics_record()
    if config.profile != DEFAULT_PROFILE:  # strict maps keep the settings they had before profiles
        settings["profile"] = config.profile
    if weights or config.profile != DEFAULT_PROFILE:
        definition = profile_tier(tier, config.profile).definition()
        settings["tier_definition"] = json.loads(json.dumps(definition))  # as map.json reads back
    if config.representation != DEFAULT_REPRESENTATION:  # point maps keep the settings they had before
        settings["representation"] = config.representation
    return settings


def build_map(
    sequence_dir: Path,
    tier: str,
    out_dir: Path,
    config: LocalizeConfig | None = None,
    progress: bool = True,
    weights_dir: Path | None = None,
) -> Path:
    """Build (or reuse, if ``map.json`` matches the inputs' hash and settings) the map of a sequence.

    Returns ``out_dir``. ``weights_dir`` (learned tiers only) is searched for weight files before the installed
    weight packages; ``map.json`` records each weight file's sha256 (a map is rebuilt when they change). The map
    is matched with the tier as ``config.profile`` defines it; a profile other than ``strict`` is recorded in
    ``map.json``'s settings (``profile``, ``tier_definition``), so a map is rebuilt when it changes.
    """
    return build_maps(sequence_dir, tier, [(Path(out_dir), config or LocalizeConfig())], progress, weights_dir)[0]


def build_maps(
    sequence_dir: Path,
    tier: str,
    maps: list[tuple[Path, LocalizeConfig]],
    progress: bool = True,
    weights_dir: Path | None = None,
) -> list[Path]:
    """:func:`build_map` of each ``(out_dir, config)`` of one sequence and tier (the tier's servers: one per server
    profile and map representation), each map the same bytes as built alone, the work they share done once: the
    map frames' features (a profile sets only matching and PnP), each pair's descriptor scores (every profile's
    matching rule filters the same scores: :func:`~synthleak.localize.tiers.shared_matcher`), and the tracks and
    points of maps whose matching is the same (representations of one profile). Returns the out dirs."""
    sequence_dir = Path(sequence_dir)
    for _, config in maps:
        for key in ("profile", "representation"):
            if isinstance(getattr(config, key), list):
                raise ValueError(f"build_map: one {key} per map, got [localize] {key} = {getattr(config, key)!r}")
    seq = load_sequence(sequence_dir)
    if len(seq.map_frames) < 2:
        raise DatasetError(f"{sequence_dir / 'split.json'}: field 'map' needs at least 2 frames")
    digest = inputs_hash(seq)
    groups: dict[tuple[int, int], list[_MapJob]] = {}
    for out_dir, config in maps:
        job = _MapJob(Path(out_dir), config, profile_tier(tier, config.profile), weights_dir)
        if not job.reuse(digest):
            groups.setdefault((job.tier.keypoint_budget(config.max_keypoints), config.pairs_per_image), []).append(job)
    for jobs in groups.values():  # (one group in a study: its servers share the features and the pairs)
        _build_group(seq, sequence_dir, tier, digest, jobs, progress, weights_dir)
    return [Path(out_dir) for out_dir, _ in maps]


class _MapJob:
    """One map to build: where, with which config, the tier as its profile defines it, its recorded settings."""

    def __init__(self, out_dir: Path, config: LocalizeConfig, tier_spec, weights_dir: Path | None) -> None:
        self.out_dir, self.config, self.tier = out_dir, config, tier_spec
        self.weights = tier_spec.weights_record(weights_dir)
        self.settings = _map_settings(tier_spec.name, config, self.weights)

    def reuse(self, digest: str) -> bool:
        """True when ``map.json`` is of these inputs and settings (its query-time settings are updated)."""
        meta_path = self.out_dir / "map.json"
        if not meta_path.is_file():
            return False
        old = json.loads(meta_path.read_text())
        if old.get("inputs_sha256") != digest or old.get("settings") != self.settings:
            return False
        retrieval = _retrieval_meta(self.config)
        if old.get("retrieval") != retrieval:  # query-time settings: recorded, no rebuild
            atomic_write_text(meta_path, json.dumps(old | {"retrieval": retrieval}, indent=1))
        return True


def _build_group(seq: Sequence, sequence_dir: Path, tier: str, digest: str, jobs: list[_MapJob], progress: bool,
                 weights_dir: Path | None) -> None:
    """The maps of ``jobs`` (one keypoint budget and pair count): features and pair scores once for all."""
    config = jobs[0].config
    extractor = jobs[0].tier.make_extractor(config.max_keypoints, weights_dir)
    rules = list(dict.fromkeys(job.tier for job in jobs))  # distinct matching definitions
    matcher = shared_matcher(rules, weights_dir)
    names = list(seq.map_frames)
    poses = [seq.pose(n) for n in names]  # the map's world is the sequence's frame (cam_from_world of a scene)
    features: list[Features] = [extractor(seq.rgb(n)) for n in progress_bar(names, "features", progress)]

    k = seq.camera.K
    ideal = ideal_keypoints(seq, names, features)  # as the pinhole seq.camera sees them: lens undone, per frame
    matches: list[dict[tuple[int, int], np.ndarray]] = [{} for _ in rules]
    pairs = pairs_from_poses(poses, config.pairs_per_image)
    for i, j in progress_bar(pairs, "matching", progress):
        f = None
        for found, m in zip(matches, matcher(features[i], features[j]), strict=True):
            if len(m):
                f = fundamental_from_poses(k, poses[i], poses[j]) if f is None else f
                err = epipolar_distance(f, ideal[i][m[:, 0]], ideal[j][m[:, 1]])
                m = m[err < EPIPOLAR_MAX_PX]
            if len(m):
                found[(i, j)] = m

    masks = [seq.instance(n) for n in names]
    for rule, rule_matches in zip(rules, matches, strict=True):
        points, instance, point_index = _triangulate(seq, names, poses, features, ideal, masks, rule_matches,
                                                     progress)
        for job in jobs:
            if job.tier == rule:
                _write_map(job, seq, sequence_dir, tier, digest, names, poses, features, masks, points, instance,
                           point_index, len(pairs))


def _triangulate(seq: Sequence, names: list[str], poses: list[np.ndarray], features: list[Features],
                 ideal: list[np.ndarray], masks: list[np.ndarray], matches: dict[tuple[int, int], np.ndarray],
                 progress: bool) -> tuple[list, np.ndarray, list[np.ndarray]]:
    """Tracks of the pair ``matches``, their points (DLT with the GT poses), each point's GT instance and each
    image's keypoint -> point index."""
    k = seq.camera.K
    tracks = build_tracks([len(f) for f in features], matches) if matches else []
    cams_from_world = np.stack(poses)
    centres = np.stack([np.linalg.inv(p)[:3, 3] for p in poses])
    keypoints = [f.keypoints for f in features]
    points = [p for t in progress_bar(tracks, "triangulation", progress)
              if (p := triangulate_track(t, ideal, cams_from_world, k, centres, TRIANGULATION_MAX_ERROR_PX,
                                         TRIANGULATION_MIN_ANGLE_DEG)) is not None]
    instance = np.array([_vote(p.track, keypoints, masks) for p in points], dtype=np.int64)
    point_index = [np.full(len(f), -1, np.int64) for f in features]
    for pid, p in enumerate(points):
        for img, kp in p.track:
            point_index[img][kp] = pid
    return points, instance, point_index


def _write_map(job: _MapJob, seq: Sequence, sequence_dir: Path, tier: str, digest: str, names: list[str],
               poses: list[np.ndarray], features: list[Features], masks: list[np.ndarray], points: list,
               instance: np.ndarray, point_index: list[np.ndarray], num_pairs: int) -> None:
    """Write one map's files, ``map.json`` last (it marks a complete map)."""
    out_dir, config = job.out_dir, job.config
    if out_dir.exists():
        for name in ("sfm", "map.json", IMAGE_INSTANCES_FILE, "points.npz", "points_instance.json", "lines.npz",
                     "paired_lines.npz"):
            target = out_dir / name
            shutil.rmtree(target) if target.is_dir() else target.unlink(missing_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = config.representation in ("line-cloud", "paired-point")  # no points, no GT-posed COLMAP model
    colmap_ids = list(range(len(points))) if lines else _write_colmap(out_dir / "sfm", seq, names, poses, features,
                                                                      points)
    arrays = {"names": np.array(names), "binary": np.array(features[0].binary if features else False)}
    for i, f in enumerate(features):
        arrays |= {f"kp_{i}": f.keypoints, f"desc_{i}": f.descriptors, f"p3d_{i}": point_index[i]}
    np.savez(out_dir / "features.npz", **arrays)
    xyz = np.array([p.xyz for p in points]).reshape(-1, 3)
    if lines:  # Speciale et al. CVPR 2019: a random line through each point, the point never written
        from synthleak.localize.line_cloud import lift_seed, lift_to_lines, write_lines

        if config.representation == "paired-point":  # Lee et al. CVPR 2023: a line through each pair of points
            from synthleak.localize.paired_points import lift_pairs, pair_seed, write_paired_lines

            write_paired_lines(out_dir / "paired_lines.npz", lift_pairs(xyz, pair_seed(tier, digest)), instance,
                               np.array([len(p.track) for p in points]))
        else:
            write_lines(out_dir / "lines.npz", *lift_to_lines(xyz, lift_seed(tier, digest)), instance,
                        np.array([len(p.track) for p in points]))
    else:
        np.savez(out_dir / "points.npz", xyz=xyz, instance=instance, colmap_id=np.array(colmap_ids, np.int64),
                 error=np.array([p.error_px for p in points]),
                 track_length=np.array([len(p.track) for p in points]))
    (out_dir / "points_instance.json").write_text(
        json.dumps({str(c): int(i) for c, i in zip(colmap_ids, instance, strict=True)})
    )
    bow = bow_params(config)
    np.savez(out_dir / "bow.npz", **BowIndex.build(bow_features(features, point_index, bow), bow).to_arrays())
    (out_dir / IMAGE_INSTANCES_FILE).write_text(json.dumps(image_instances_json(names, masks), indent=0))
    meta = {
        "format_version": FORMAT_VERSION,
        "tier": tier,
        "sequence": str(sequence_dir),
        "inputs_sha256": digest,
        "settings": job.settings,
        "retrieval": _retrieval_meta(config),
        "keypoint_budget": job.tier.keypoint_budget(config.max_keypoints),
        "weights": job.weights,
        "camera": camera_to_json(seq.camera),
        "num_images": len(names),
        "num_pairs": num_pairs,
        "num_points": len(points),
        "mean_track_length": float(np.mean([len(p.track) for p in points])) if points else 0.0,
    }
    (out_dir / "map.json").write_text(json.dumps(meta, indent=1))  # written last: marks a complete map


def ideal_keypoints(seq: Sequence, names: list[str], features: list[Features]) -> list[np.ndarray]:
    """Each map frame's keypoints as the pinhole ``seq.camera`` would have seen them, for the epipolar filter and
    the triangulation (one K): a frame with its own camera (lens distortion, resize) goes through that camera's
    rays (:func:`synthleak.render.distortion.normalized_rays`, Newton undistortion; -1e9 where the lens has no
    ray). Frames of the pinhole ``seq.camera`` itself (all of an all-pinhole sequence) are returned as detected,
    bit for bit. The map stores the keypoints as detected, with each frame's own camera in ``sfm/``."""
    from synthleak.render.distortion import normalized_rays

    ref, out = seq.camera, []
    for name, f in zip(names, features, strict=True):
        cam = seq.camera_of(name)
        if cam == ref and camera_dist_coeffs(cam) is None:
            out.append(f.keypoints)
            continue
        x, y = normalized_rays(cam, f.keypoints[:, 0], f.keypoints[:, 1])
        px = np.stack([x * ref.fx + ref.cx, y * ref.fy + ref.cy], axis=1).reshape(-1, 2)
        px[~np.isfinite(px).all(axis=1)] = -1e9
        out.append(px)
    return out


def bow_features(features: list[Features], point_index: list[np.ndarray], params: BowParams) -> list[Features]:
    """What a map's bag of words indexes: each image's keypoints with a 3D point (``points_only``, unless no
    image has any), else all of them."""
    with_points = [f.subset(np.nonzero(idx >= 0)[0]) for f, idx in zip(features, point_index, strict=True)]
    return with_points if params.points_only and any(len(f) for f in with_points) else features


def _vote(obs: list[tuple[int, int]], keypoints: list[np.ndarray], masks: list[np.ndarray]) -> int:
    votes = Counter()
    for img, kp in obs:
        h, w = masks[img].shape
        x, y = keypoints[img][kp]
        votes[int(masks[img][min(max(int(y), 0), h - 1), min(max(int(x), 0), w - 1)])] += 1
    return min(votes.items(), key=lambda kv: (-kv[1], kv[0]))[0]


def _write_colmap(path: Path, seq: Sequence, names, poses, features, points) -> list[int]:
    rec = pycolmap.Reconstruction()
    camera_ids = {seq.camera: 1}  # camera 1: the sequence's; then one per other distinct frame camera (its lens)
    for name in names:
        camera_ids.setdefault(seq.camera_of(name), len(camera_ids) + 1)
    for cam, camera_id in camera_ids.items():
        camera = pycolmap_camera(cam)  # PINHOLE fx fy cx cy, or OPENCV / FULL_OPENCV
        camera.camera_id = camera_id
        rec.add_camera_with_trivial_rig(camera)
    for i, (name, pose, f) in enumerate(zip(names, poses, features, strict=True)):
        image = pycolmap.Image(name=name, keypoints=f.keypoints, camera_id=camera_ids[seq.camera_of(name)],
                               image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pose[:3]))
    ids = []
    for p in points:
        t = pycolmap.Track()
        for img, kp in p.track:
            t.add_element(img + 1, kp)
        ids.append(int(rec.add_point3D(p.xyz, t)))
    path.mkdir(parents=True, exist_ok=True)
    rec.write(str(path))
    return ids
