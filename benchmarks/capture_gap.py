"""Which capture effect moves the tier ordering: an HPatches-style split (Balntas et al. 2017, CVPR) of
room-instance / attacker-variant image pairs by capture condition.

HPatches splits its pairs into a viewpoint and an illumination set; on real images learned features beat SIFT
on illumination and tie or lose on viewpoint. Our renders are noise-free, sharp, perfectly exposed and lit
alike, so this benchmark adds one capture effect at a time (:mod:`synthleak.render.capture`) to the attacker's
side of the same pairs and measures every tier on each condition.

Pairs (from a generated dataset: a finished study folder or its ``dataset/``, read through
:mod:`synthleak.core.dataset`): for each attacker object of ``stages/index.json`` that a room holds
(``present_in``), image **A** is a map frame of that room's walk-through that sees the instance (at least
``--min-coverage`` of its pixels), with the dataset's GT depth, instance ids and ``cam_from_world``; image
**B** is the attacker's variant, rendered here from its inventory-hall stage with the study's renderer at
the SAME object-relative pose, ``cam_from_hall = cam_from_object_A @ object_from_hall``
(``cam_from_object_A = cam_from_world_A @ scene_from_object``: the attack's premise, a look-alike seen as the
room's instance was). B keeps its linear radiance, so every condition photographs the same render. A pair is
kept only when B sees the variant over at least half of A's coverage (the hall's walls or other furniture can
block a room viewpoint); A is the dataset's frame as the study wrote it (photographed if its ``[render]
capture_map`` is not ``ideal``; the JSON records ``capture_map``). A's candidates are visited in a seeded order.

Verification (in the object frame, since B shows ANOTHER variant): B's keypoints are matched to A's with the
tier's own matcher (``matcher(B, A)``, as a query against a map image); A's keypoints are lifted with A's GT
depth and pose into the object frame. A match is *verified* when A's keypoint lies on the room instance, B's
on the variant, and A's lifted point, projected into B at B's GT pose (through B's lens when distorted),
falls within ``--tol-px`` (4) px of B's keypoint. The variant's scale and shape changes (``variant`` in
index.json, a few per cent at ci-tiny's magnitude 0.3) move surface points, so this ground truth is
approximate: a verified match is the same object-relative surface point up to that change; occlusion in B is
not tested (B's keypoint must be on the variant). *Localized*: pycolmap RANSAC PnP of B's matched keypoints
against A's lifted 3D points (every match with a finite A depth, background included, as a map image would
give), with the tier's PnP threshold and camera model (B's ``OPENCV`` camera after distortion), succeeds under
the tier's rule (at least ``min_inliers`` inliers, one vote per B keypoint) AND the pose is within 10 deg /
0.25 m (camera centre) of B's GT ``cam_from_object`` (the rule alone accepts wrong poses: a sideboard's nearly
planar front gave SIFT 52 inliers at 67 deg, the planar flip; the JSON keeps ``success`` and the errors).

Conditions (rows): ``viewpoint`` (A and B as rendered: variant, hall lights and background), ``light`` (B's
hall under a drawn lighting condition, :func:`synthleak.render.light_conditions.lit_scene` with capture kind
``attacker`` of the object's sequence: one condition per attacker object), then each effect ALONE on B:
:data:`EFFECT_GROUPS` (``sensor``: exposure + sensor noise/mosaic + ISP), then every other effect field of
:class:`~synthleak.render.capture.CaptureParams` on its own (so an effect added there is picked up by name),
then ``all:<profile>`` for :data:`ALL_PROFILES` and ``--profile`` (the whole drawn device). Per-effect
parameters start from ``devices.IDEAL`` and copy the named fields (and ``base_iso``) from the device drawn for the pair
(:func:`synthleak.render.devices.draw_device` of ``--profile``, seed ``derive_seed(seed, "capture-gap-device",
profile, pair)``), so all rows of a pair are slices of one device. Motion blur alone has no exposure stage: its
shutter is ``MotionBlur.shutter_s`` (1/30 s, what the phone's AE picks at 150 lux). Blur in pixels scales with
the image width (the phone lens's circle of confusion and the hand shake are physical angles), so at a study's
320 px both are sub-pixel (``max_coc_px``, ``motion_blur_px`` in the JSON's capture records). Geometric effects
(distortion, resize) ray cast B's depth and ids again for the photo's camera
(:func:`synthleak.render.distortion.raycast_camera`). A row whose fields are absent from ``CaptureParams``
(or whose module is missing) says ``not available``; one the profile leaves off says ``off in <profile>``.

Output: a markdown table (per tier: mean verified matches, localized share) on stdout, rich progress on stderr,
``--json OUT`` with every per-pair number. Deterministic: renders, devices and noise from ``derive_seed`` of the
dataset's seed; RANSAC seeded as the localizer's.

Measured (2026-12-03, at 6a5d062, ci-tiny study at 320x240 mitsuba, 24 pairs): docs/renderers.md, 'Which effect
moves the tier ordering'.

    python benchmarks/capture_gap.py STUDY_OR_DATASET [--pairs 10] [--tiers sift,orb,xfeat,xfeat-lighterglue]
        [--profile phone] [--max-keypoints 2048] [--tol-px 4] [--min-coverage 0.05] [--json OUT] [--no-progress]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.progress import Progress

from synthleak.config import StudyConfig, config_from_dict
from synthleak.core.dataset import (
    DatasetError,
    Sequence,
    load_sequence,
    pycolmap_camera,
    read_index,
    read_json,
)
from synthleak.core.types import Camera, RenderScene
from synthleak.errors import ConfigError
from synthleak.geometry.poses import camera_centre, invert, rotation_error_deg, transform_points
from synthleak.localize.features import Features
from synthleak.localize.localizer import RANSAC_SEED
from synthleak.localize.tiers import Tier, get_tier
from synthleak.render.capture import EFFECT_FIELDS, CaptureParams, capture, output_camera
from synthleak.render.devices import IDEAL, draw_device
from synthleak.seeding import derive_seed, make_rng

DEFAULT_TIERS = ("sift", "orb", "akaze", "xfeat", "xfeat-lighterglue", "aliked-lightglue")
EFFECT_GROUPS: dict[str, tuple[str, ...]] = {
    "sensor": ("exposure", "sensor", "color_matrix", "white_balance", "tone_curve"),
    "defocus": ("defocus",),
    "motion_blur": ("motion_blur",),
    "distortion": ("distortion",),
    "jpeg": ("jpeg",),
}
"""Named single effects: a row each, applied alone to B (fields of ``CaptureParams``)."""
ALL_PROFILES = ("phone", "web-photo")
"""Profiles applied as a whole (``all:<profile>``), each drawn per pair."""
MAX_ROT_DEG, MAX_TRANS_M = 10.0, 0.25
"""Localized: the tier's success AND a pose error within these."""


@dataclass(frozen=True)
class Condition:
    """One row: ``fields`` copied from the profile's drawn device (``"*"``: all of it), ``light``: B's hall
    under a drawn lighting condition, ``status``: why the row is empty (``""``: it runs)."""

    name: str
    fields: tuple[str, ...] = ()
    profile: str = ""
    light: bool = False
    status: str = ""


def conditions(profile: str) -> list[Condition]:
    """The rows, in order (see the module docstring)."""
    known = {f.name for f in dataclasses.fields(CaptureParams)}
    has_light = importlib.util.find_spec("synthleak.render.light_conditions") is not None
    rows = [Condition("viewpoint"), Condition("light", light=True, status="" if has_light else "not available")]
    for name, group in EFFECT_GROUPS.items():
        rows.append(Condition(name, group, profile, status="" if set(group) <= known else "not available"))
    grouped = {f for group in EFFECT_GROUPS.values() for f in group}
    rows += [Condition(f, (f,), profile) for f in EFFECT_FIELDS if f not in grouped]
    rows += [Condition(f"all:{p}", ("*",), p) for p in dict.fromkeys((*ALL_PROFILES, profile)) if p != "ideal"]
    return rows


def condition_params(cond: Condition, device: CaptureParams) -> CaptureParams:
    """``devices.IDEAL`` with ``cond.fields`` (and ``base_iso``) copied from ``device``."""
    if cond.fields == ("*",):
        return device
    if not cond.fields:
        return IDEAL
    return replace(IDEAL, name=f"{device.name}:{cond.name}", base_iso=device.base_iso,
                   **{f: getattr(device, f) for f in cond.fields})


# ------------------------------------------------------------------------------------------------ the dataset


def dataset_dir(path: Path) -> Path:
    """A study folder's ``dataset/`` or the dataset folder itself (an error naming what is missing)."""
    path = Path(path)
    for candidate in (path / "dataset", path):
        if (candidate / "stages" / "index.json").is_file():
            return candidate
    raise DatasetError(f"{path}: neither it nor {path / 'dataset'} holds stages/index.json (pass a study folder "
                       "or a dataset written by `synthleak generate`)")


def dataset_config(dataset: Path) -> StudyConfig:
    """The config the dataset was rendered with (``manifest.json`` ``config``)."""
    path = dataset / "manifest.json"
    if not path.is_file():
        raise DatasetError(f"{path}: missing (the dataset is unfinished: render it to the end first)")
    manifest = read_json(path)
    if not isinstance(manifest, dict) or not isinstance(manifest.get("config"), dict):
        raise DatasetError(f"{path}: field 'config' must be an object")
    return config_from_dict(manifest["config"], str(path))


@dataclass
class Pair:
    """A: the room's map frame; B: the variant rendered at A's object-relative pose (linear radiance kept)."""

    key: str
    obj: str
    room: str
    frame: str
    rgb_a: np.ndarray
    depth_a: np.ndarray
    instance_a: np.ndarray
    camera_a: Camera
    cam_from_object: np.ndarray
    """A's and B's GT pose in the object's canonical frame."""
    object_from_cam_a: np.ndarray
    room_id: int
    hall_id: int
    cam_from_hall: np.ndarray
    coverage_a: float
    coverage_b: float
    frames_b: dict[bool, Any] = field(default_factory=dict)
    """``{lit: Frame}``: B as rendered under the hall's lights (False) and a drawn condition (True)."""


@dataclass
class Hall:
    """An attacker stage prepared for rendering, under its own lights and (lazily) a drawn condition."""

    name: str
    scene: RenderScene
    target: int
    renderers: dict[bool, Any] = field(default_factory=dict)
    gt: Any = None


def _renderer(config: StudyConfig, hall: Hall, lit: bool, seed: int) -> Any:
    from synthleak.render.registry import get_renderer

    if lit not in hall.renderers:
        scene = hall.scene
        if lit:
            from synthleak.render.light_conditions import lit_scene

            scene = lit_scene(scene, "attacker", seed, hall.name)
        renderer = get_renderer(config.render)
        renderer.prepare(scene)
        hall.renderers[lit] = renderer
    return hall.renderers[lit]


def _hall_gt(hall: Hall) -> Any:
    from synthleak.render.raycast import RaycastGT

    if hall.gt is None:
        gt = getattr(hall.renderers.get(False), "_gt", None)
        hall.gt = gt if isinstance(gt, RaycastGT) else RaycastGT(hall.scene.meshes)
    return hall.gt


def render_camera(config: StudyConfig) -> Camera:
    rc = config.render
    return Camera.from_hfov(rc.width, rc.height, rc.hfov_deg)


def find_pairs(dataset: Path, config: StudyConfig, count: int, min_coverage: float, seed: int,
               light: bool, progress: Any = None) -> tuple[list[Pair], dict[str, Hall]]:
    """Up to ``count`` pairs, round-robin over the attacker objects present in a room (see the module docstring)."""
    from synthleak.render.lighting import with_default_light
    from synthleak.render.pipeline import load_stage

    index = read_index(dataset / "stages")
    camera = render_camera(config)
    todo: list[tuple[str, str, int, Sequence, list[str]]] = []
    for obj in index["attacker_objects"]:
        for room, room_id in sorted(obj.get("present_in", {}).items()):
            seq = load_sequence(dataset / "scenes" / room)
            frames = [f for f in seq.map_frames if np.mean(seq.instance(f) == int(room_id)) >= min_coverage]
            order = make_rng(seed, "capture-gap-pairs", obj["id"], room).permutation(len(frames))
            todo.append((obj["id"], room, int(room_id), seq, [frames[i] for i in order]))
    stages = {o["id"]: dataset / "stages" / o["stage"] for o in index["attacker_objects"]}
    halls: dict[str, Hall] = {}
    pairs: list[Pair] = []
    task = progress.add_task("pairs (render B)", total=count) if progress is not None else None
    while len(pairs) < count and any(c[4] for c in todo):
        for obj_id, room, room_id, seq, candidates in todo:
            if len(pairs) >= count:
                break
            while candidates:
                frame = candidates.pop(0)
                if obj_id not in halls:
                    scene = with_default_light(load_stage(stages[obj_id]))
                    if scene.target_instance_id is None:
                        raise DatasetError(f"{stages[obj_id]}: attacker stage has no target_instance_id")
                    halls[obj_id] = Hall(obj_id, scene, int(scene.target_instance_id))
                hall = halls[obj_id]
                scene_from_object = np.asarray(seq.objects_by_id()[room_id].world_from_object, dtype=np.float64)
                cam_from_object = seq.pose(frame) @ scene_from_object
                hall_from_object = np.asarray(hall.scene.instances[hall.target].world_from_object, dtype=np.float64)
                cam_from_hall = cam_from_object @ invert(hall_from_object)
                key = f"{obj_id}/{room}/{frame}"
                renderer = _renderer(config, hall, False, config.seed)
                frame_b = renderer.render(camera, cam_from_hall, derive_seed(seed, "capture-gap-render", key))
                instance_a = seq.instance(frame)
                cov_a = float(np.mean(instance_a == room_id))
                cov_b = float(np.mean(frame_b.instance == hall.target))
                if cov_b < 0.5 * cov_a:
                    continue
                frames_b = {False: frame_b}
                if light:
                    lit = _renderer(config, hall, True, config.seed)
                    frames_b[True] = lit.render(camera, cam_from_hall, derive_seed(seed, "capture-gap-render", key))
                pairs.append(Pair(key, obj_id, room, frame, seq.rgb(frame), seq.depth(frame), instance_a,
                                  seq.camera_of(frame), cam_from_object, invert(cam_from_object), room_id,
                                  hall.target, cam_from_hall, cov_a, cov_b, frames_b))
                if task is not None:
                    progress.advance(task)
                break
    return pairs, halls


# ------------------------------------------------------------------------------------------------ photographs


@dataclass
class PhotoB:
    """B under one condition: the photo, its camera and GT instance ids for that camera."""

    rgb: np.ndarray
    camera: Camera
    instance: np.ndarray
    record: dict[str, Any]


def photograph_b(pair: Pair, cond: Condition, hall: Hall, config: StudyConfig, profile: str, seed: int
                 ) -> PhotoB | str:
    """B under ``cond`` (or the reason it is empty: ``off in <profile>``)."""
    from synthleak.render.distortion import raycast_camera
    from synthleak.render.pipeline import linear_radiance

    frame = pair.frames_b[cond.light]
    camera = render_camera(config)
    name = cond.profile or profile
    device = draw_device(name, derive_seed(seed, "capture-gap-device", name, pair.key))
    params = condition_params(cond, device)
    if cond.fields and cond.fields != ("*",) and all(getattr(params, f) is None for f in cond.fields):
        return f"off in {name}"
    if params.is_ideal:
        return PhotoB(frame.rgb, camera, frame.instance, {"profile": "ideal", "effects": []})
    renderer = hall.renderers[cond.light]
    photo = capture(linear_radiance(frame, renderer), params, derive_seed(seed, "capture-gap-noise", pair.key,
                    cond.name), depth=frame.depth, camera=camera)
    out_camera = output_camera(camera, params)
    instance = frame.instance
    if out_camera != camera:
        _, instance = raycast_camera(_hall_gt(hall), out_camera, pair.cam_from_hall)
    return PhotoB(photo.rgb, out_camera, instance, photo.record)


# ------------------------------------------------------------------------------------------------ measuring


def lift(pair: Pair, keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A's keypoints in the object frame (N, 3), whether their depth is finite, whether they are on the
    room instance."""
    from synthleak.render.distortion import normalized_rays

    cam = pair.camera_a
    u = np.clip(np.floor(keypoints[:, 0]).astype(int), 0, cam.width - 1)
    v = np.clip(np.floor(keypoints[:, 1]).astype(int), 0, cam.height - 1)
    z = pair.depth_a[v, u].astype(np.float64)
    x, y = normalized_rays(cam, keypoints[:, 0], keypoints[:, 1])
    finite = np.isfinite(z) & np.isfinite(x) & np.isfinite(y)
    z = np.where(finite, z, 1.0)
    pts = transform_points(pair.object_from_cam_a, np.stack([x * z, y * z, z], axis=1))
    return pts, finite, pair.instance_a[v, u] == pair.room_id


def project(camera: Camera, cam_from_object: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates of object-frame points in ``camera``; NaN behind it or beyond its lens model."""
    from synthleak.core.dataset import camera_dist_coeffs
    from synthleak.render.distortion import project_camera_points, radial_fold_radius

    cam_pts = transform_points(cam_from_object, pts)
    out = np.full((len(pts), 2), np.nan)
    ok = cam_pts[:, 2] > 1e-6
    dist = camera_dist_coeffs(camera)
    if dist is not None:
        r2 = (cam_pts[:, 0] ** 2 + cam_pts[:, 1] ** 2) / np.maximum(cam_pts[:, 2], 1e-6) ** 2
        ok &= r2 < (0.95 * radial_fold_radius(float(dist[0]), float(dist[1]), float(dist[4]))) ** 2
    if ok.any():
        projected = project_camera_points(camera, cam_pts[ok])
        if projected is not None:
            out[ok] = np.stack(projected, axis=1)
    return out


def measure(pair: Pair, photo: PhotoB, feats_a: Features, pts: np.ndarray, finite: np.ndarray, on_a: np.ndarray,
            tier: Tier, extractor: Any, matcher: Any, tol_px: float) -> dict[str, Any]:
    """Verified matches and localization of one B photo against A (see the module docstring)."""
    import pycolmap

    feats_b = extractor(photo.rgb)
    if feats_b.image_size == (0, 0):
        feats_b = replace(feats_b, image_size=(photo.camera.width, photo.camera.height))
    out: dict[str, Any] = {"keypoints_b": len(feats_b), "matches": 0, "verified": 0, "inliers": 0,
                           "success": False, "localized": False, "rot_err_deg": None, "trans_err_m": None}
    if not len(feats_b) or not len(feats_a):
        return out
    m = np.asarray(matcher(feats_b, feats_a), dtype=np.int64).reshape(-1, 2)
    out["matches"] = len(m)
    if not len(m):
        return out
    kp_b = feats_b.keypoints[m[:, 0]]
    cam = photo.camera
    ub = np.clip(np.floor(kp_b[:, 0]).astype(int), 0, cam.width - 1)
    vb = np.clip(np.floor(kp_b[:, 1]).astype(int), 0, cam.height - 1)
    on_b = photo.instance[vb, ub] == pair.hall_id
    proj = project(cam, pair.cam_from_object, pts[m[:, 1]])
    err = np.linalg.norm(proj - kp_b, axis=1)
    verified = finite[m[:, 1]] & on_a[m[:, 1]] & on_b & (np.nan_to_num(err, nan=np.inf) <= tol_px)
    out["verified"] = int(verified.sum())
    use = finite[m[:, 1]]
    if use.sum() < max(tier.min_inliers, 4):
        return out
    pc_cam = pycolmap_camera(cam)
    options = pycolmap.AbsolutePoseEstimationOptions()
    options.ransac.max_error = float(tier.pnp_max_error_px)
    options.ransac.random_seed = RANSAC_SEED
    est = pycolmap.estimate_and_refine_absolute_pose(kp_b[use], pts[m[use, 1]], pc_cam, options)
    if est is None:
        return out
    inlier_b = m[use, 0][np.asarray(est["inlier_mask"], dtype=bool)]
    pose = np.eye(4)
    pose[:3] = est["cam_from_world"].matrix()
    rot = rotation_error_deg(pose, pair.cam_from_object)
    trans = float(np.linalg.norm(camera_centre(pose) - camera_centre(pair.cam_from_object)))
    out["inliers"] = int(len(np.unique(inlier_b)))
    out["success"] = out["inliers"] >= tier.min_inliers
    out["rot_err_deg"], out["trans_err_m"] = rot, trans
    out["localized"] = bool(out["success"] and rot < MAX_ROT_DEG and trans < MAX_TRANS_M)
    return out


def run(dataset: Path, tiers: list[str], pairs_wanted: int, profile: str, max_keypoints: int, tol_px: float,
        min_coverage: float, progress: bool = True) -> dict[str, Any]:
    """The whole benchmark; returns the JSON-serialisable result (``rows``: per condition and tier)."""
    from synthleak.progress import progress_display

    dataset = dataset_dir(dataset)
    config = dataset_config(dataset)
    seed = config.seed
    rows = conditions(profile)
    specs = [get_tier(t) for t in tiers]
    light = any(c.light and not c.status for c in rows)
    t0 = time.perf_counter()
    base = progress_display(progress)  # the project's columns, on stderr (stdout carries the table)
    with Progress(*base.columns, console=Console(stderr=True), disable=base.disable) as bar:
        pairs, halls = find_pairs(dataset, config, pairs_wanted, min_coverage, seed, light, bar)
        if not pairs:
            raise DatasetError(f"{dataset}: no pair found (no map frame sees a present attacker object over "
                               f"{min_coverage:.0%} of its pixels with the variant visible from there)")
        photos: dict[tuple[str, str], PhotoB | str] = {}
        task = bar.add_task("photographs (B)", total=len(pairs) * len(rows))
        for pair in pairs:
            for cond in rows:
                photos[pair.key, cond.name] = cond.status or photograph_b(pair, cond, halls[pair.obj], config,
                                                                          profile, seed)
                bar.advance(task)
        results: dict[str, dict[str, list[dict[str, Any]]]] = {c.name: {} for c in rows}
        for tier in specs:
            extractor, matcher = tier.make_extractor(max_keypoints), tier.make_matcher()
            task = bar.add_task(f"{tier.name}", total=len(pairs) * len(rows))
            for pair in pairs:
                feats_a = extractor(pair.rgb_a)
                if feats_a.image_size == (0, 0):
                    feats_a = replace(feats_a, image_size=(pair.camera_a.width, pair.camera_a.height))
                pts, finite, on_a = lift(pair, feats_a.keypoints)
                for cond in rows:
                    photo = photos[pair.key, cond.name]
                    if isinstance(photo, PhotoB):
                        r = measure(pair, photo, feats_a, pts, finite, on_a, tier, extractor, matcher, tol_px)
                        results[cond.name].setdefault(tier.name, []).append(
                            {"pair": pair.key, "capture_effects": photo.record.get("effects", []), **r})
                    bar.advance(task)
    table = []
    for cond in rows:
        statuses = {p for k, p in photos.items() if k[1] == cond.name and isinstance(p, str)}
        entry: dict[str, Any] = {"condition": cond.name, "fields": list(cond.fields), "profile": cond.profile,
                                 "status": cond.status or ("; ".join(sorted(statuses)) if statuses else "")}
        for tier in specs:
            per = results[cond.name].get(tier.name, [])
            entry[tier.name] = {
                "pairs": len(per),
                "mean_verified": float(np.mean([r["verified"] for r in per])) if per else None,
                "mean_matches": float(np.mean([r["matches"] for r in per])) if per else None,
                "localized_share": float(np.mean([r["localized"] for r in per])) if per else None,
                "per_pair": per,
            }
        table.append(entry)
    return {
        "dataset": str(dataset), "seed": seed, "profile": profile, "tiers": tiers, "tol_px": tol_px,
        "max_keypoints": max_keypoints, "resolution": [config.render.width, config.render.height],
        "renderer": config.render.renderer, "capture_map": config.render.capture_map,
        "pairs": [{"key": p.key, "coverage_a": p.coverage_a, "coverage_b": p.coverage_b,
                   "captures": {c.name: photos[p.key, c.name].record for c in rows
                                if isinstance(photos[p.key, c.name], PhotoB)}} for p in pairs],
        "seconds": round(time.perf_counter() - t0, 1), "rows": table,
    }


def markdown(result: dict[str, Any]) -> str:
    """The table: per tier mean verified matches and localized share (``n/a`` with the row's status)."""
    tiers = result["tiers"]
    head = "| condition | " + " | ".join(f"{t} verified | {t} loc" for t in tiers) + " |"
    lines = [head, "|---|" + "---:|---:|" * len(tiers)]
    for row in result["rows"]:
        cells = []
        for t in tiers:
            r = row[t]
            if r["mean_verified"] is None:
                cells += [row["status"] or "n/a", ""]
            else:
                cells += [f"{r['mean_verified']:.1f}", f"{r['localized_share']:.0%}"]
        name = row["condition"] + (f" ({row['status']})" if row["status"] and row[tiers[0]]["pairs"] else "")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path, help="a finished study folder or a generated dataset folder")
    parser.add_argument("--pairs", type=int, default=10)
    parser.add_argument("--tiers", default=",".join(DEFAULT_TIERS), help="comma-separated tier names")
    parser.add_argument("--profile", default="phone", help="device profile the single effects are drawn from")
    parser.add_argument("--max-keypoints", type=int, default=2048)
    parser.add_argument("--tol-px", type=float, default=4.0)
    parser.add_argument("--min-coverage", type=float, default=0.05, help="least share of A's pixels on the object")
    parser.add_argument("--json", type=Path, default=None, help="write the full result here")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.pairs < 1:
        parser.error(f"--pairs must be at least 1, got {args.pairs}")
    if not (args.tol_px > 0 and math.isfinite(args.tol_px)):
        parser.error(f"--tol-px must be a finite number > 0, got {args.tol_px}")
    tiers = [t.strip() for t in args.tiers.split(",") if t.strip()]
    for t in tiers:
        try:
            get_tier(t)
        except ValueError as exc:
            parser.error(f"--tiers: {exc}")
    try:
        draw_device(args.profile, 0)
    except ConfigError as exc:  # an unknown profile, naming the known ones
        parser.error(f"--profile: {exc}")
    result = run(args.dataset, tiers, args.pairs, args.profile, args.max_keypoints, args.tol_px,
                 args.min_coverage, progress=not args.no_progress)
    print(f"{len(result['pairs'])} pairs, {result['resolution'][0]}x{result['resolution'][1]} "
          f"{result['renderer']}, profile {result['profile']}, {result['seconds']} s")
    print(markdown(result))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1, default=_json_default) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
