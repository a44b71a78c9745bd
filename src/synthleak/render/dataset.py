"""Sequence folders of docs/DATASET.md: atomic writers for frames and metadata, and ``load_sequence``.

Frame names are the image file names (``000000.png``), as COLMAP's ``images.txt`` NAME and ``split.json``
use them; accessors also accept the bare stem (``000000``) or an integer index.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from synthleak.atomic_io import TEMP_PREFIX, atomic_write_bytes, atomic_write_text
from synthleak.core.types import Camera, InstanceInfo
from synthleak.errors import SynthleakError
from synthleak.geometry.poses import (
    check_pose,
    invert,
    make_pose,
    matrix_from_quat_wxyz,
    quat_wxyz_from_matrix,
)
from synthleak.render.base import Frame

BOP_DEPTH_SCALE = 0.25
"""BOP 16-bit depth PNGs hold depth_mm / BOP_DEPTH_SCALE: 0.25 mm steps up to 16.4 m (0.1 would stop at 6.5 m)."""


class DatasetError(SynthleakError, ValueError):
    """A malformed dataset file; the message names the file and the field."""


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


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB uint8 (H, W, 3) or a uint8 / uint16 (H, W) image (deterministic)."""
    array = np.ascontiguousarray(image)
    if array.ndim == 3:
        array = np.ascontiguousarray(array[..., ::-1])  # OpenCV writes BGR
    ok, buf = cv2.imencode(".png", array, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError(f"cannot encode a {array.dtype} {array.shape} image as PNG")
    return buf.tobytes()


def encode_npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


# ------------------------------------------------------------------------------------------------- frames
def frame_name(index: int) -> str:
    return f"{index:06d}.png"


def frame_stem(frame: str | int) -> str:
    if isinstance(frame, int | np.integer):
        return f"{int(frame):06d}"
    return str(frame).removesuffix(".png").removesuffix(".npy")


def frame_paths(seq_dir: Path, frame: str | int) -> dict[str, Path]:
    stem = frame_stem(frame)
    seq_dir = Path(seq_dir)
    return {
        "rgb": seq_dir / "images" / f"{stem}.png",
        "depth": seq_dir / "depth" / f"{stem}.npy",
        "instance": seq_dir / "instance" / f"{stem}.png",
    }


def _png_whole(path: Path) -> bool:
    with open(path, "rb") as handle:
        head = handle.read(8)
        handle.seek(max(path.stat().st_size - 12, 0))
        tail = handle.read(12)
    return head == b"\x89PNG\r\n\x1a\n" and tail[4:8] == b"IEND"


def _npy_whole(path: Path) -> bool:
    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError):
        return False
    return array.dtype == np.float32


def frame_complete(seq_dir: Path, frame: str | int) -> bool:
    """All files of the frame exist and are whole (PNG up to its IEND chunk, npy as long as its header
    says). Our writers are atomic; the check also catches files truncated by other means."""
    paths = frame_paths(seq_dir, frame)
    if not all(p.is_file() for p in paths.values()):
        return False
    return _png_whole(paths["rgb"]) and _png_whole(paths["instance"]) and _npy_whole(paths["depth"])


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


def _colmap_cameras(camera: Camera) -> str:
    return (
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 1\n"
        f"1 PINHOLE {int(camera.width)} {int(camera.height)} "
        + " ".join(repr(float(x)) for x in (camera.fx, camera.fy, camera.cx, camera.cy))
        + "\n"
    )


def _colmap_images(names: list[str], poses: list[np.ndarray]) -> str:
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(names)}, mean observations per image: 0",
    ]
    for i, (name, pose) in enumerate(zip(names, poses, strict=True)):
        q = quat_wxyz_from_matrix(pose[:3, :3])
        t = pose[:3, 3]
        values = " ".join(repr(float(x)) for x in (*q, *t))
        lines += [f"{i + 1} {values} 1 {name}", ""]
    return "\n".join(lines) + "\n"


def check_existing_plan(seq_dir: Path, camera: Camera, frames: list[str], cam_from_world: list[np.ndarray]) -> None:
    """Refuse to resume into a folder whose COLMAP files describe other cameras or poses (another config)."""
    seq_dir = Path(seq_dir)
    for path, text in (
        (seq_dir / "colmap" / "cameras.txt", _colmap_cameras(camera)),
        (seq_dir / "colmap" / "images.txt", _colmap_images(frames, [np.asarray(p) for p in cam_from_world])),
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
    cam_from_world: list[np.ndarray],
    instances: list[InstanceInfo],
    frame: str = "world",
    target_instance_id: int | None = None,
    split: dict[str, list[str]] | None = None,
) -> None:
    """COLMAP text, BOP json, objects.json and (scenes) split.json. Poses must already be in ``frame``.

    For ``frame == "object"`` the caller passes ``cam_from_object`` poses and instances whose
    ``world_from_object`` is expressed in the target's canonical frame (see :func:`to_object_frame`).
    """
    seq_dir = Path(seq_dir)
    if frame not in ("world", "object"):
        raise ValueError(f"frame must be 'world' or 'object', got {frame!r}")
    poses = [check_pose(p, f"{seq_dir.name}/{n}: cam_from_world") for n, p in zip(frames, cam_from_world, strict=True)]
    atomic_write_text(seq_dir / "colmap" / "cameras.txt", _colmap_cameras(camera))
    atomic_write_text(seq_dir / "colmap" / "images.txt", _colmap_images(frames, poses))
    atomic_write_text(
        seq_dir / "colmap" / "points3D.txt",
        "# 3D point list with one line of data per point:\n# Number of points: 0\n",
    )
    cam_k = camera.K.ravel().tolist()
    scene_camera, scene_gt = {}, {}
    for name, pose in zip(frames, poses, strict=True):
        key = str(int(frame_stem(name)))
        scene_camera[key] = {
            "cam_K": cam_k,
            "cam_R_w2c": pose[:3, :3].ravel().tolist(),
            "cam_t_w2c": (pose[:3, 3] * 1000.0).tolist(),
            "depth_scale": BOP_DEPTH_SCALE,
        }
        entries = []
        for info in instances:
            cam_from_object = pose @ np.asarray(info.world_from_object, dtype=np.float64)
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
    """Re-express poses and instances in the target's canonical frame (attacker sequences)."""
    if target_id not in instances:
        raise ValueError(f"target_instance_id {target_id} is not an instance of the scene")
    world_from_target = np.asarray(instances[target_id].world_from_object, dtype=np.float64)
    target_from_world = invert(world_from_target)
    poses = [np.asarray(p) @ world_from_target for p in cam_from_world]
    moved = []
    for iid in sorted(instances):
        info = instances[iid]
        pose = np.eye(4) if iid == target_id else target_from_world @ np.asarray(info.world_from_object)
        moved.append(InstanceInfo(**{**info.__dict__, "world_from_object": pose}))
    return poses, moved


def make_split(frames: list[str], query_every: int) -> dict[str, list[str]]:
    """Every ``query_every``-th frame (indices n-1, 2n-1, ...) is a held-out query; the rest build the map.
    (A scene sequence with genuine close-ups adds ``closeup``: the query frames that are close-ups.)"""
    if query_every < 2:
        raise ValueError(f"render.query_every must be >= 2, got {query_every}")
    query = [f for i, f in enumerate(frames) if i % query_every == query_every - 1]
    return {"map": [f for f in frames if f not in set(query)], "query": query}


# ------------------------------------------------------------------------------------------------- reader
@dataclass
class Sequence:
    """One rendered sequence folder (see docs/DATASET.md)."""

    root: Path
    name: str
    kind: str
    camera: Camera
    frames: list[str]
    cam_from_world: dict[str, np.ndarray]
    objects: list[InstanceInfo]
    frame: str = "world"
    target_instance_id: int | None = None
    split: dict[str, list[str]] = field(default_factory=dict)

    def _key(self, frame: str | int) -> str:
        return f"{frame_stem(frame)}.png"

    def pose(self, frame: str | int) -> np.ndarray:
        return self.cam_from_world[self._key(frame)]

    def image_path(self, frame: str | int) -> Path:
        return frame_paths(self.root, frame)["rgb"]

    def rgb(self, frame: str | int) -> np.ndarray:
        path = self.image_path(frame)
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise DatasetError(f"{path}: missing or unreadable RGB image")
        return np.ascontiguousarray(image[..., ::-1])

    def depth(self, frame: str | int) -> np.ndarray:
        path = frame_paths(self.root, frame)["depth"]
        try:
            depth = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{path}: unreadable depth ({exc})") from exc
        if depth.dtype != np.float32 or depth.shape != (self.camera.height, self.camera.width):
            raise DatasetError(
                f"{path}: depth must be float32 {(self.camera.height, self.camera.width)}, "
                f"got {depth.dtype} {depth.shape}"
            )
        return depth

    def instance(self, frame: str | int) -> np.ndarray:
        path = frame_paths(self.root, frame)["instance"]
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.dtype != np.uint16:
            raise DatasetError(f"{path}: missing instance image or not 16-bit")
        return image

    def objects_by_id(self) -> dict[int, InstanceInfo]:
        return {o.instance_id: o for o in self.objects}


def read_json(path: Path) -> Any:
    """A sequence's JSON file; a DatasetError naming the file when it is missing or malformed."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file (render the sequence first)")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from exc


def _data_lines(path: Path) -> list[str]:
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    return [line for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]


def _floats(path: Path, field_name: str, tokens: list[str]) -> np.ndarray:
    try:
        values = np.array([float(t) for t in tokens])
    except ValueError as exc:
        raise DatasetError(f"{path}: {field_name}: not numbers: {tokens}") from exc
    if not np.all(np.isfinite(values)):
        raise DatasetError(f"{path}: {field_name}: non-finite value in {tokens}")
    return values


def read_colmap_camera(path: Path) -> Camera:
    lines = _data_lines(path)
    if len(lines) != 1:
        raise DatasetError(f"{path}: expected exactly one camera, found {len(lines)}")
    tok = lines[0].split()
    if len(tok) != 8 or tok[1] != "PINHOLE":
        raise DatasetError(f"{path}: camera 1: expected 'ID PINHOLE W H fx fy cx cy', got {lines[0]!r}")
    fx, fy, cx, cy = _floats(path, "camera params", tok[4:8])
    try:
        width, height = int(tok[2]), int(tok[3])
    except ValueError as exc:
        raise DatasetError(f"{path}: camera width/height are not integers: {tok[2:4]}") from exc
    return Camera(width, height, float(fx), float(fy), float(cx), float(cy))


def read_colmap_images(path: Path) -> dict[str, np.ndarray]:
    """``{NAME: cam_from_world}`` from a COLMAP images.txt with empty POINTS2D lines."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    poses: dict[str, np.ndarray] = {}
    for line in lines[0::2]:
        tok = line.split()
        if not tok:
            continue
        if len(tok) != 10:
            raise DatasetError(f"{path}: image line needs 10 fields, got {line!r}")
        name = tok[9]
        values = _floats(path, f"image {name} pose", tok[1:8])
        q = values[:4]
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise DatasetError(f"{path}: image {name}: quaternion is not unit length ({q})")
        poses[name] = make_pose(matrix_from_quat_wxyz(q / np.linalg.norm(q)), values[4:7])
    return poses


def _instance_from_dict(path: Path, i: int, d: dict[str, Any]) -> InstanceInfo:
    where = f"{path}: instances[{i}]"
    try:
        pose = np.asarray(d["world_from_object"], dtype=np.float64)
        extents = np.asarray(d["extents"], dtype=np.float64)
        info = InstanceInfo(
            instance_id=int(d["instance_id"]),
            name=str(d["name"]),
            model_id=str(d["model_id"]),
            category=str(d["category"]),
            symmetry=str(d["symmetry"]),
            role=str(d["role"]),
            world_from_object=pose,
            extents=extents,
            variant_params=dict(d.get("variant_params", {})),
            prim_path=str(d.get("prim_path", "")),
            support=str(d.get("support", "floor")),
        )
    except KeyError as exc:
        raise DatasetError(f"{where}: missing field {exc.args[0]!r}") from exc
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: bad value ({exc})") from exc
    try:
        check_pose(pose, f"{where}.world_from_object")
    except ValueError as exc:
        raise DatasetError(str(exc)) from exc
    if extents.shape != (3,) or not np.all(np.isfinite(extents)):
        raise DatasetError(f"{where}.extents: expected 3 finite numbers")
    return info


def load_sequence(path: Path) -> Sequence:
    """Read a sequence folder's metadata (images are read lazily by the accessors)."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: no such sequence folder")
    camera = read_colmap_camera(root / "colmap" / "cameras.txt")
    poses = read_colmap_images(root / "colmap" / "images.txt")
    objects_path = root / "objects.json"
    objects = read_json(objects_path)
    for key in ("instances", "frame", "target_instance_id"):
        if key not in objects:
            raise DatasetError(f"{objects_path}: missing field {key!r}")
    frame = objects["frame"]
    if frame not in ("world", "object"):
        raise DatasetError(f"{objects_path}: frame: expected 'world' or 'object', got {frame!r}")
    instances = [_instance_from_dict(objects_path, i, d) for i, d in enumerate(objects["instances"])]
    kind = "attacker" if frame == "object" else "scene"
    split: dict[str, list[str]] = {}
    split_path = root / "split.json"
    if split_path.is_file():
        raw = read_json(split_path)
        keys = ("map", "query", *(("closeup",) if "closeup" in raw else ()))
        for key in keys:
            if not isinstance(raw.get(key), list):
                raise DatasetError(f"{split_path}: field {key!r} must be a list of frame names")
            unknown = [f for f in raw[key] if f not in poses]
            if unknown:
                raise DatasetError(f"{split_path}: {key}: frames not in colmap/images.txt: {unknown[:5]}")
        not_queries = sorted(set(raw.get("closeup", [])) - set(raw["query"]))
        if not_queries:
            raise DatasetError(f"{split_path}: closeup: frames that are not queries: {not_queries[:5]}")
        split = {key: list(raw[key]) for key in keys}
    for name, pose in poses.items():
        if not np.all(np.isfinite(pose)):
            raise DatasetError(f"{root / 'colmap' / 'images.txt'}: image {name}: non-finite pose")
    target = objects["target_instance_id"]
    return Sequence(
        root=root,
        name=root.name,
        kind=kind,
        camera=camera,
        frames=sorted(poses),
        cam_from_world=poses,
        objects=instances,
        frame=frame,
        target_instance_id=None if target is None else int(target),
        split=split,
    )
