"""Renderer-side writers of the sequence folders of docs/DATASET.md: frames, COLMAP / BOP / objects.json metadata
and ``split.json``, each file atomically. The contract itself (file names, encodings, the reader
``load_sequence``) is :mod:`synthleak.core.dataset`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.atomic_io import TEMP_PREFIX, atomic_write_bytes, atomic_write_text
from synthleak.core.dataset import (
    BOP_DEPTH_SCALE,
    DatasetError,
    camera_dist_coeffs,
    colmap_camera_model,
    encode_npy,
    encode_png,
    frame_complete,
    frame_paths,
    frame_stem,
)
from synthleak.core.types import Camera, InstanceInfo
from synthleak.geometry.poses import check_pose, invert, quat_wxyz_from_matrix
from synthleak.portable import POSE_STEP, snap, snap_pose
from synthleak.render.base import Frame


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def atomic_write_json(path: Path, data: Any) -> None:
    """JSON with exact (repr) floats, sorted keys, trailing newline."""
    atomic_write_text(path, json.dumps(_plain(data), indent=1, sort_keys=True, allow_nan=False) + "\n")


def clean_temp_files(folder: Path) -> int:
    """Remove stray temporary files left by an interrupted writer under ``folder``; returns how many."""
    count = 0
    for tmp in Path(folder).rglob(TEMP_PREFIX + "*"):
        if tmp.is_file():
            tmp.unlink()
            count += 1
    return count


# ------------------------------------------------------------------------------------------------- frames
def write_frame(seq_dir: Path, frame: str | int, data: Frame) -> None:
    """Write depth, instance, then RGB of one frame, each atomically."""
    h, w = data.depth.shape
    if data.rgb.shape != (h, w, 3) or data.rgb.dtype != np.uint8:
        raise ValueError(f"frame {frame}: rgb must be uint8 ({h}, {w}, 3), got {data.rgb.dtype} {data.rgb.shape}")
    if data.instance.shape != (h, w):
        raise ValueError(f"frame {frame}: instance shape {data.instance.shape} != depth shape {(h, w)}")
    paths = frame_paths(seq_dir, frame)
    atomic_write_bytes(paths["depth"], encode_npy(data.depth.astype(np.float32)))
    atomic_write_bytes(paths["instance"], encode_png(data.instance.astype(np.uint16)))
    atomic_write_bytes(paths["rgb"], encode_png(data.rgb))


def write_bop_rgb(seq_dir: Path) -> int:
    """``bop/rgb/<frame>.png`` for every image of ``images/``: the scene folder ``bop/`` then holds its RGB frames
    where BOP tools (bop_toolkit) look for them. Each is a hard link to the image where the file system allows
    one (no extra space), else a copy (the same bytes); both are made under a temporary name and renamed into
    place. An existing link to the image (or, where links fail, a copy with its bytes) is kept. Returns how many
    were made."""
    seq_dir = Path(seq_dir)
    target_dir = seq_dir / "bop" / "rgb"
    made = 0
    for image in sorted((seq_dir / "images").glob("*.png")):
        target = target_dir / image.name
        if target.is_file() and os.path.samefile(image, target):
            continue
        target_dir.mkdir(parents=True, exist_ok=True)
        tmp = target_dir / f"{TEMP_PREFIX}{image.name}.{os.getpid()}"
        tmp.unlink(missing_ok=True)
        try:
            os.link(image, tmp)
        except OSError:  # no hard links here (another file system, FAT, some network mounts): a copy
            data = image.read_bytes()
            if target.is_file() and target.read_bytes() == data:
                continue
            atomic_write_bytes(target, data)
        else:
            os.replace(tmp, target)
        made += 1
    return made


# ------------------------------------------------------------------------------------------ capture records
CAPTURE_RECORDS = "capture.json"
"""A sequence photographed with a capture profile other than ``ideal``: frame name -> the capture record of
:func:`synthleak.render.capture.capture` (``profile``, ``effects``, chosen exposure, noise, ...)."""
PENDING_RECORDS = "capture-records"
"""Per-frame records (``<stem>.json``) written by the render workers, merged into :data:`CAPTURE_RECORDS` by
:func:`merge_capture_records` when the sequence's frames are rendered."""


def _finite(value: Any) -> Any:
    """``value`` with non-finite floats as strings (``"inf"``): JSON has no infinity."""
    if isinstance(value, float | np.floating) and not np.isfinite(value):
        return str(float(value))
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def write_capture_record(seq_dir: Path, frame: str | int, record: dict[str, Any]) -> None:
    """One frame's capture record, atomically, under :data:`PENDING_RECORDS` (before the frame's RGB: a complete
    frame always has its record)."""
    atomic_write_json(Path(seq_dir) / PENDING_RECORDS / f"{frame_stem(frame)}.json", _finite(record))


def read_capture_records(seq_dir: Path) -> dict[str, dict[str, Any]]:
    """Frame name -> capture record: :data:`CAPTURE_RECORDS` updated by any pending per-frame records; empty when
    the sequence has neither (every frame ``ideal``)."""
    seq_dir = Path(seq_dir)
    path = seq_dir / CAPTURE_RECORDS
    records: dict[str, dict[str, Any]] = {}
    if path.is_file():
        try:
            records = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{path}: not valid JSON: {exc}") from exc
    for pending in sorted((seq_dir / PENDING_RECORDS).glob("*.json")):
        try:
            records[f"{pending.stem}.png"] = json.loads(pending.read_text())
        except json.JSONDecodeError:  # only an atomic writer writes these; a damaged one is re-rendered
            continue
    return records


def merge_capture_records(seq_dir: Path) -> bool:
    """Fold the pending per-frame records into :data:`CAPTURE_RECORDS` (sorted by frame) and remove them; a
    rerun after an interruption merges again. Returns whether there was anything to merge."""
    pending_dir = Path(seq_dir) / PENDING_RECORDS
    pending = sorted(pending_dir.glob("*.json")) if pending_dir.is_dir() else []
    if not pending:
        return False
    atomic_write_json(Path(seq_dir) / CAPTURE_RECORDS, read_capture_records(seq_dir))
    for path in pending:
        path.unlink()
    clean_temp_files(pending_dir)
    pending_dir.rmdir()
    return True


def check_capture_plan(seq_dir: Path, frames: list[str], profiles: list[str]) -> None:
    """Refuse to resume into a folder whose complete frames were photographed with other capture profiles (a
    frame without a record is ``ideal``)."""
    seq_dir = Path(seq_dir)
    recorded_any = (seq_dir / CAPTURE_RECORDS).is_file() or (seq_dir / PENDING_RECORDS).is_dir()
    if not recorded_any and all(p == "ideal" for p in profiles):
        return
    records = read_capture_records(seq_dir)
    for frame, profile in zip(frames, profiles, strict=True):
        got = records.get(frame, {}).get("profile", "ideal")
        if got != profile and frame_complete(seq_dir, frame):
            raise DatasetError(
                f"{seq_dir / CAPTURE_RECORDS}: frame {frame} was photographed with capture profile {got!r}, the "
                f"config asks for {profile!r} (another config); delete {seq_dir} to re-render it"
            )


# ----------------------------------------------------------------------------------------------- metadata
def instance_to_dict(info: InstanceInfo, world_from_object: np.ndarray | None = None) -> dict[str, Any]:
    pose = info.world_from_object if world_from_object is None else world_from_object
    return {
        "instance_id": int(info.instance_id),
        "name": info.name,
        "model_id": info.model_id,
        "category": info.category,
        "symmetry": info.symmetry,
        "role": info.role,
        "world_from_object": np.asarray(pose, dtype=np.float64).tolist(),
        "extents": np.asarray(info.extents, dtype=np.float64).reshape(3).tolist(),
        "variant_params": _plain(info.variant_params),
        "prim_path": info.prim_path,
        "support": getattr(info, "support", "floor"),
    }


def camera_ids(cameras: list[Camera]) -> tuple[list[Camera], list[int]]:
    """The distinct cameras of a sequence's per-frame ``cameras`` (in order of first use) and each frame's
    COLMAP CAMERA_ID (1-based index into them)."""
    distinct: list[Camera] = []
    ids = []
    for camera in cameras:
        if camera not in distinct:
            distinct.append(camera)
        ids.append(distinct.index(camera) + 1)
    return distinct, ids


def _colmap_cameras(camera: Camera | list[Camera]) -> str:
    """cameras.txt of one camera or of the distinct per-frame cameras (``PINHOLE``, or ``OPENCV`` /
    ``FULL_OPENCV`` with the capture's lens distortion: :func:`synthleak.core.dataset.colmap_camera_model`)."""
    cameras = camera_ids(camera)[0] if isinstance(camera, list) else [camera]
    lines = []
    for i, cam in enumerate(cameras):
        model, params = colmap_camera_model(cam)
        lines.append(f"{i + 1} {model} {int(cam.width)} {int(cam.height)} " + " ".join(repr(float(x)) for x in params))
    return (
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: {len(cameras)}\n" + "".join(line + "\n" for line in lines)
    )


def _colmap_images(names: list[str], poses: list[np.ndarray], ids: list[int] | None = None) -> str:
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(names)}, mean observations per image: 0",
    ]
    for i, (name, pose) in enumerate(zip(names, poses, strict=True)):
        q = snap(quat_wxyz_from_matrix(pose[:3, :3]), POSE_STEP)
        t = snap(pose[:3, 3], POSE_STEP)
        values = " ".join(repr(float(x)) for x in (*q, *t))
        lines += [f"{i + 1} {values} {1 if ids is None else ids[i]} {name}", ""]
    return "\n".join(lines) + "\n"


def check_existing_plan(seq_dir: Path, camera: Camera, frames: list[str], poses: list[np.ndarray],
                        cameras: list[Camera] | None = None) -> None:
    """Refuse to resume into a folder whose COLMAP files describe other cameras or poses (another config).
    ``poses`` and ``cameras`` as :func:`write_sequence_metadata` takes them."""
    seq_dir = Path(seq_dir)
    cams = cameras or [camera] * len(frames)
    for path, text in (
        (seq_dir / "colmap" / "cameras.txt", _colmap_cameras(cams if cameras else camera)),
        (seq_dir / "colmap" / "images.txt", _colmap_images(frames, [np.asarray(p) for p in poses],
                                                           camera_ids(cams)[1])),
    ):
        if path.is_file() and path.read_text() != text:
            raise DatasetError(
                f"{path}: this sequence was rendered with other cameras or poses (another config or seed); "
                f"delete {seq_dir} to re-render it"
            )


def write_sequence_metadata(
    seq_dir: Path,
    *,
    camera: Camera,
    frames: list[str],
    poses: list[np.ndarray],
    instances: list[InstanceInfo],
    frame: str = "world",
    target_instance_id: int | None = None,
    split: dict[str, list[str]] | None = None,
    cameras: list[Camera] | None = None,
) -> None:
    """COLMAP text, BOP json, objects.json and (scenes) split.json. ``poses`` are in ``frame``: ``cam_from_world``
    for ``frame == "world"``; for ``frame == "object"`` (attacker sequences) ``cam_from_object`` poses and instances
    whose ``world_from_object`` is expressed in the target's canonical frame (see :func:`to_object_frame`).
    ``cameras``: each frame's camera when the capture distorts or resizes (default: ``camera`` for every frame):
    COLMAP gets one camera per distinct camera, BOP each frame's ``cam_K`` (and ``cam_dist``, OpenCV's
    ``[k1, k2, p1, p2, k3]``, for a distorted one).
    """
    seq_dir = Path(seq_dir)
    if frame not in ("world", "object"):
        raise ValueError(f"frame must be 'world' or 'object', got {frame!r}")
    pose_name = "cam_from_world" if frame == "world" else "cam_from_object"
    poses = [check_pose(p, f"{seq_dir.name}/{n}: {pose_name}") for n, p in zip(frames, poses, strict=True)]
    cams = cameras or [camera] * len(frames)
    if len(cams) != len(frames):
        raise ValueError(f"{seq_dir}: {len(cams)} cameras for {len(frames)} frames")
    atomic_write_text(seq_dir / "colmap" / "cameras.txt", _colmap_cameras(cams if cameras else camera))
    atomic_write_text(seq_dir / "colmap" / "images.txt", _colmap_images(frames, poses, camera_ids(cams)[1]))
    atomic_write_text(
        seq_dir / "colmap" / "points3D.txt",
        "# 3D point list with one line of data per point:\n# Number of points: 0\n",
    )
    scene_camera, scene_gt = {}, {}
    for name, pose, cam in zip(frames, poses, cams, strict=True):
        key = str(int(frame_stem(name)))
        scene_camera[key] = {
            "cam_K": cam.K.ravel().tolist(),
            "cam_R_w2c": pose[:3, :3].ravel().tolist(),
            "cam_t_w2c": (pose[:3, 3] * 1000.0).tolist(),
            "depth_scale": BOP_DEPTH_SCALE,
        }
        dist = camera_dist_coeffs(cam)
        if dist is not None:
            scene_camera[key]["cam_dist"] = dist.tolist()  # not a BOP field: OpenCV [k1, k2, p1, p2, k3]
        entries = []
        for info in instances:
            cam_from_object = snap_pose(pose @ np.asarray(info.world_from_object, dtype=np.float64))
            entries.append(
                {
                    "obj_id": int(info.instance_id),
                    "cam_R_m2c": cam_from_object[:3, :3].ravel().tolist(),
                    "cam_t_m2c": (cam_from_object[:3, 3] * 1000.0).tolist(),
                }
            )
        scene_gt[key] = entries
    atomic_write_json(seq_dir / "bop" / "scene_camera.json", scene_camera)
    atomic_write_json(seq_dir / "bop" / "scene_gt.json", scene_gt)
    atomic_write_json(
        seq_dir / "objects.json",
        {
            "instances": [instance_to_dict(i) for i in instances],
            "frame": frame,
            "target_instance_id": None if target_instance_id is None else int(target_instance_id),
        },
    )
    if split is not None:
        atomic_write_json(seq_dir / "split.json", {key: list(frames) for key, frames in split.items()})


def to_object_frame(
    cam_from_world: list[np.ndarray], instances: dict[int, InstanceInfo], target_id: int
) -> tuple[list[np.ndarray], list[InstanceInfo]]:
    """Re-express poses and instances in the target's canonical frame (attacker sequences): ``cam_from_world`` in,
    ``cam_from_object`` out (the target's ``world_from_object`` becomes the identity)."""
    if target_id not in instances:
        raise ValueError(f"target_instance_id {target_id} is not an instance of the scene")
    world_from_target = np.asarray(instances[target_id].world_from_object, dtype=np.float64)
    target_from_world = invert(world_from_target)
    poses = [snap_pose(np.asarray(p) @ world_from_target) for p in cam_from_world]
    moved = []
    for iid in sorted(instances):
        info = instances[iid]
        pose = np.eye(4) if iid == target_id else snap_pose(target_from_world @ np.asarray(info.world_from_object))
        moved.append(InstanceInfo(**{**info.__dict__, "world_from_object": pose}))
    return poses, moved


def make_split(frames: list[str], query_every: int) -> dict[str, list[str]]:
    """Every ``query_every``-th frame (indices n-1, 2n-1, ...) is a held-out query; the rest build the map.
    (A scene sequence with genuine close-ups adds ``closeup``: the query frames that are close-ups.)"""
    if query_every < 2:
        raise ValueError(f"render.query_every must be >= 2, got {query_every}")
    query = [f for i, f in enumerate(frames) if i % query_every == query_every - 1]
    return {"map": [f for f in frames if f not in set(query)], "query": query}
