"""The dataset contract of docs/DATASET.md, read in one place: sequence folders (:func:`load_sequence`), the stage
index ``stages/index.json`` (:func:`read_index`) and the file encodings (RGB: PNG uint8; depth: float32 ``.npy``;
instance ids: PNG uint16), which the renderer-side writers (:mod:`synthleak.render.dataset`) encode with
:func:`encode_png` / :func:`encode_npy`. Errors name the file and the field.

Frame names are the image file names (``000000.png``), as COLMAP's ``images.txt`` NAME and ``split.json``
use them; accessors also accept the bare stem (``000000``) or an integer index.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from synthleak.core.types import Camera, InstanceInfo
from synthleak.errors import SynthleakError
from synthleak.geometry.poses import check_pose, make_pose, matrix_from_quat_wxyz
from synthleak.portable import norm

BOP_DEPTH_SCALE = 0.25
"""BOP 16-bit depth PNGs hold depth_mm / BOP_DEPTH_SCALE: 0.25 mm steps up to 16.4 m (0.1 would stop at 6.5 m)."""

INDEX_NAME = "index.json"
RENDER_TWINS = "capture_render"
"""``<sequence>/capture_render/<frame>.png``: the renderer's own 8-bit frame of the first photo of each capture
profile in a photographed sequence, kept so a contact sheet and the report can put the render beside its photo."""
"""The stage index of a stages folder (``DATASET/stages/index.json``)."""


class DatasetError(SynthleakError, ValueError):
    """A malformed dataset file; the message names the file and the field."""


@dataclass(frozen=True)
class OpenCVCamera(Camera):
    """A :class:`Camera` with OpenCV radial-tangential (Brown-Conrady) distortion: COLMAP's ``OPENCV`` model
    (``fx fy cx cy k1 k2 p1 p2``), or ``FULL_OPENCV`` when ``k3`` is not 0. A camera-frame point (x, y, 1)
    is distorted in normalised coordinates, then ``u = fx x_d + cx`` (pixel-centre convention of
    :class:`Camera`, as COLMAP's)."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV's ``distCoeffs`` ``[k1, k2, p1, p2, k3]``."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3], dtype=np.float64)


def camera_dist_coeffs(camera: Camera) -> np.ndarray | None:
    """OpenCV ``[k1, k2, p1, p2, k3]`` of ``camera``; ``None`` for a pinhole camera (no distortion)."""
    return camera.dist_coeffs if isinstance(camera, OpenCVCamera) else None


def colmap_camera_model(camera: Camera) -> tuple[str, list[float]]:
    """COLMAP model name and params of ``camera``: ``PINHOLE`` (fx fy cx cy), ``OPENCV`` (+ k1 k2 p1 p2) or
    ``FULL_OPENCV`` (+ k1 k2 p1 p2 k3 k4 k5 k6, with k4 = k5 = k6 = 0) when k3 is not 0."""
    base = [float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)]
    if not isinstance(camera, OpenCVCamera):
        return "PINHOLE", base
    if camera.k3 == 0.0:
        return "OPENCV", base + [float(camera.k1), float(camera.k2), float(camera.p1), float(camera.p2)]
    return "FULL_OPENCV", base + [float(c) for c in camera.dist_coeffs] + [0.0, 0.0, 0.0]


def pycolmap_camera(camera: Camera) -> Any:
    """``camera`` as a ``pycolmap.Camera`` of :func:`colmap_camera_model`'s model and params."""
    import pycolmap

    model, params = colmap_camera_model(camera)
    return pycolmap.Camera(model=model, width=camera.width, height=camera.height, params=params)


def scaled_camera(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` for its image resized to ``width`` x ``height`` (corners to corners: ``fx, cx *= W' / W`` in the
    pixel-corner convention of :class:`Camera`; distortion, in normalised coordinates, unchanged)."""
    sx, sy = width / camera.width, height / camera.height
    return replace(camera, width=int(width), height=int(height), fx=camera.fx * sx, fy=camera.fy * sy,
                   cx=camera.cx * sx, cy=camera.cy * sy)


# ---------------------------------------------------------------------------------------------- encodings
def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an RGB (H, W, 3) or RGBA (H, W, 4) uint8 or a uint8 / uint16 (H, W) image (deterministic:
    OpenCV's libpng at compression level 3, no metadata chunks)."""
    array = np.ascontiguousarray(image)
    if array.ndim == 3:
        order = [2, 1, 0, 3] if array.shape[2] == 4 else slice(None, None, -1)
        array = np.ascontiguousarray(array[..., order])  # OpenCV writes BGR(A)
    ok, buf = cv2.imencode(".png", array, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError(f"cannot encode a {array.dtype} {array.shape} image as PNG")
    return buf.tobytes()


def encode_npy(array: np.ndarray) -> bytes:
    """``.npy`` bytes of ``array`` (no pickles)."""
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


def read_rgb(path: Path) -> np.ndarray:
    """An (H, W, 3) uint8 RGB image (alpha dropped, grey expanded); a DatasetError naming the file if unreadable."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DatasetError(f"{path}: missing or unreadable RGB image")
    return np.ascontiguousarray(image[..., ::-1])


def read_instance(path: Path) -> np.ndarray:
    """An (H, W) uint16 instance-id image; a DatasetError naming the file if missing or not 16-bit."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16:
        raise DatasetError(f"{path}: missing instance image or not 16-bit")
    return image


def read_depth(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """An (H, W) = ``shape`` float32 z-depth in metres (+inf: no hit); a DatasetError naming the file otherwise."""
    try:
        depth = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: unreadable depth ({exc})") from exc
    if depth.dtype != np.float32 or depth.shape != tuple(shape):
        raise DatasetError(f"{path}: depth must be float32 {tuple(shape)}, got {depth.dtype} {depth.shape}")
    return depth


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


# ------------------------------------------------------------------------------------------------ sequence
@dataclass
class Sequence:
    """One rendered sequence folder (see docs/DATASET.md)."""

    root: Path
    name: str
    kind: str
    camera: Camera
    frames: list[str]
    poses: dict[str, np.ndarray]
    """``{frame name: pose}`` as ``colmap/images.txt`` stores them, in the sequence's ``frame``: ``cam_from_world``
    in a scene sequence, ``cam_from_object`` (the target's canonical frame) in an attacker sequence. Read them
    under their name: :attr:`cam_from_world` / :attr:`cam_from_object`."""
    objects: list[InstanceInfo]
    frame: str = "world"
    target_instance_id: int | None = None
    split: dict[str, list[str]] = field(default_factory=dict)
    cameras: dict[str, Camera] = field(default_factory=dict)
    """``{frame name: camera}``: each frame's own camera (``colmap/images.txt`` CAMERA_ID), which differs from
    :attr:`camera` (camera 1) when the capture distorted or resized it (:meth:`camera_of`)."""

    def camera_of(self, frame: str | int) -> Camera:
        """The camera of ``frame`` (its distortion, if any, included: :class:`OpenCVCamera`)."""
        return self.cameras.get(self._key(frame), self.camera)

    @property
    def cam_from_world(self) -> dict[str, np.ndarray]:
        """``{frame name: cam_from_world}`` of a scene sequence; a DatasetError for an attacker sequence."""
        if self.frame != "world":
            raise DatasetError(f"{self.root / 'objects.json'}: frame is {self.frame!r}: an attacker sequence's "
                               "poses are cam_from_object (Sequence.cam_from_object), not cam_from_world")
        return self.poses

    @property
    def cam_from_object(self) -> dict[str, np.ndarray]:
        """``{frame name: cam_from_object}`` of an attacker sequence; a DatasetError for a scene sequence."""
        if self.frame != "object":
            raise DatasetError(f"{self.root / 'objects.json'}: frame is {self.frame!r}: a scene sequence's "
                               "poses are cam_from_world (Sequence.cam_from_world), not cam_from_object")
        return self.poses

    @property
    def map_frames(self) -> list[str]:
        """The frames that build the map (``split.json`` ``map``; every frame when there is no split)."""
        return list(self.split.get("map", self.frames))

    @property
    def query_frames(self) -> list[str]:
        """The held-out genuine queries (``split.json`` ``query``; none when there is no split)."""
        return list(self.split.get("query", []))

    def _key(self, frame: str | int) -> str:
        return f"{frame_stem(frame)}.png"

    def pose(self, frame: str | int) -> np.ndarray:
        """The stored pose of ``frame`` (``cam_from_world`` or ``cam_from_object``, see :attr:`poses`)."""
        return self.poses[self._key(frame)]

    def image_path(self, frame: str | int) -> Path:
        return frame_paths(self.root, frame)["rgb"]

    def depth_path(self, frame: str | int) -> Path:
        return frame_paths(self.root, frame)["depth"]

    def instance_path(self, frame: str | int) -> Path:
        return frame_paths(self.root, frame)["instance"]

    def rgb(self, frame: str | int) -> np.ndarray:
        return read_rgb(self.image_path(frame))

    def depth(self, frame: str | int) -> np.ndarray:
        camera = self.camera_of(frame)
        return read_depth(self.depth_path(frame), (camera.height, camera.width))

    def instance(self, frame: str | int) -> np.ndarray:
        return read_instance(self.instance_path(frame))

    def objects_by_id(self) -> dict[int, InstanceInfo]:
        return {o.instance_id: o for o in self.objects}


def read_json(path: Path) -> Any:
    """A dataset JSON file; a DatasetError naming the file when it is missing or malformed."""
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


COLMAP_MODELS = {"PINHOLE": 4, "OPENCV": 8, "FULL_OPENCV": 12}
"""The COLMAP camera models of a sequence's ``cameras.txt`` and their number of params."""


def _colmap_camera_line(path: Path, line: str) -> tuple[int, Camera]:
    tok = line.split()
    model = tok[1] if len(tok) > 1 else ""
    if model not in COLMAP_MODELS or len(tok) != 4 + COLMAP_MODELS[model]:
        raise DatasetError(f"{path}: camera line: expected 'ID PINHOLE W H fx fy cx cy' or 'ID OPENCV W H fx fy cx "
                           f"cy k1 k2 p1 p2' (or FULL_OPENCV with 8 coefficients), got {line!r}")
    try:
        camera_id, width, height = int(tok[0]), int(tok[2]), int(tok[3])
    except ValueError as exc:
        raise DatasetError(f"{path}: camera id/width/height are not integers: {tok[:4]}") from exc
    params = [float(v) for v in _floats(path, f"camera {camera_id} params", tok[4:])]
    if model == "PINHOLE":
        return camera_id, Camera(width, height, *params)
    if model == "FULL_OPENCV" and any(params[9:]):
        raise DatasetError(f"{path}: camera {camera_id}: FULL_OPENCV k4, k5, k6 must be 0 (rational distortion is "
                           f"not supported), got {params[9:]}")
    return camera_id, OpenCVCamera(width, height, *params[:9])


def read_colmap_cameras(path: Path) -> dict[int, Camera]:
    """``{CAMERA_ID: camera}`` of a COLMAP cameras.txt (``PINHOLE``, ``OPENCV`` or ``FULL_OPENCV``)."""
    cameras: dict[int, Camera] = {}
    for line in _data_lines(path):
        camera_id, camera = _colmap_camera_line(path, line)
        if camera_id in cameras:
            raise DatasetError(f"{path}: camera id {camera_id} appears twice")
        cameras[camera_id] = camera
    if not cameras:
        raise DatasetError(f"{path}: no camera")
    return cameras


def read_colmap_camera(path: Path) -> Camera:
    """The one camera of a single-camera COLMAP cameras.txt."""
    lines = _data_lines(path)
    if len(lines) != 1:
        raise DatasetError(f"{path}: expected exactly one camera, found {len(lines)}")
    return _colmap_camera_line(path, lines[0])[1]


def read_colmap_image_cameras(path: Path) -> dict[str, int]:
    """``{NAME: CAMERA_ID}`` of a COLMAP images.txt (checked by :func:`read_colmap_images`)."""
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    ids: dict[str, int] = {}
    for line in lines[0::2]:
        tok = line.split()
        if len(tok) == 10:
            try:
                ids[tok[9]] = int(tok[8])
            except ValueError as exc:
                raise DatasetError(f"{path}: image {tok[9]}: CAMERA_ID {tok[8]!r} is not an integer") from exc
    return ids


def read_colmap_images(path: Path) -> dict[str, np.ndarray]:
    """``{NAME: pose}`` (COLMAP's cam_from_world) from a COLMAP images.txt with empty POINTS2D lines."""
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
        poses[name] = make_pose(matrix_from_quat_wxyz(q / norm(q)), values[4:7])  # no BLAS: the same bits on any CPU
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
    camera_path = root / "colmap" / "cameras.txt"
    all_cameras = read_colmap_cameras(camera_path)
    poses = read_colmap_images(root / "colmap" / "images.txt")
    cameras: dict[str, Camera] = {}
    for name, camera_id in read_colmap_image_cameras(root / "colmap" / "images.txt").items():
        if camera_id not in all_cameras:
            raise DatasetError(f"{root / 'colmap' / 'images.txt'}: image {name}: CAMERA_ID {camera_id} is not in "
                               f"{camera_path}")
        cameras[name] = all_cameras[camera_id]
    camera = all_cameras[min(all_cameras)]
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
        cameras=cameras,
        frames=sorted(poses),
        poses=poses,
        objects=instances,
        frame=frame,
        target_instance_id=None if target is None else int(target),
        split=split,
    )


# --------------------------------------------------------------------------------------------- stage index
def read_index(stages_dir: Path) -> dict[str, Any]:
    """``stages_dir/index.json`` (the study plan `synthleak scenes` writes: rooms, attacker objects, which room
    holds which model), checked: a DatasetError naming the file and the field when it is missing or malformed."""
    path = Path(stages_dir) / INDEX_NAME
    if not path.is_file():
        raise DatasetError(f"{path}: stage index does not exist (run `synthleak scenes` or the study's render "
                           "stage first)")
    try:
        index = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(index, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(index).__name__}")
    for key in ("rooms", "attacker_objects"):
        if not isinstance(index.get(key), list):
            raise DatasetError(f"{path}: field {key!r} must be a list")
    for i, room in enumerate(index["rooms"]):
        for key in ("name", "stage"):
            if not isinstance(room, dict) or not isinstance(room.get(key), str):
                raise DatasetError(f"{path}: rooms[{i}].{key} must be a string")
    for i, obj in enumerate(index["attacker_objects"]):
        for key in ("id", "stage"):
            if not isinstance(obj, dict) or not isinstance(obj.get(key), str):
                raise DatasetError(f"{path}: attacker_objects[{i}].{key} must be a string")
    return index
