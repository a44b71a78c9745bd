"""Read a dataset sequence folder (``scenes/<room>/``): camera, GT poses, split, image paths.

A small private reader of the files described in docs/DATASET.md, so the localization service depends on
the file contract only. Errors name the file and the field.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from synthleak.geometry.poses import make_pose, matrix_from_quat_wxyz
from synthleak.render.base import Camera


class SequenceError(ValueError):
    """A sequence folder that cannot be read; the message names the file and the field."""


@dataclass
class SequenceFiles:
    """What mapping needs from one sequence folder."""

    root: Path
    camera: Camera
    cam_from_world: dict[str, np.ndarray]
    map_frames: list[str]
    query_frames: list[str]

    def image_path(self, frame: str) -> Path:
        return self.root / "images" / frame

    def instance_path(self, frame: str) -> Path:
        return self.root / "instance" / (Path(frame).stem + ".png")

    def rgb(self, frame: str) -> np.ndarray:
        return load_rgb(self.image_path(frame))

    def instance(self, frame: str) -> np.ndarray:
        path = self.instance_path(frame)
        if not path.is_file():
            raise SequenceError(f"{path}: instance mask missing")
        return np.asarray(Image.open(path)).astype(np.int64)


def load_rgb(path: Path) -> np.ndarray:
    """An (H, W, 3) uint8 image; raises naming the file if unreadable."""
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError) as exc:
        raise SequenceError(f"{path}: not a readable image ({exc})") from exc


def read_cameras_txt(path: Path) -> Camera:
    """The single PINHOLE camera of a COLMAP ``cameras.txt``."""
    if not path.is_file():
        raise SequenceError(f"{path}: missing")
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8 or parts[1] != "PINHOLE":
            raise SequenceError(f"{path}: expected 'ID PINHOLE W H fx fy cx cy', got {line!r}")
        try:
            w, h = int(parts[2]), int(parts[3])
            fx, fy, cx, cy = (float(x) for x in parts[4:8])
        except ValueError as exc:
            raise SequenceError(f"{path}: camera line {line!r}: {exc}") from exc
        return Camera(w, h, fx, fy, cx, cy)
    raise SequenceError(f"{path}: no camera line")


def read_images_txt(path: Path) -> dict[str, np.ndarray]:
    """``{image name: cam_from_world 4x4}`` from a COLMAP ``images.txt`` (POINTS2D lines may be empty)."""
    if not path.is_file():
        raise SequenceError(f"{path}: missing")
    poses: dict[str, np.ndarray] = {}
    lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
    for i in range(0, len(lines), 2):
        parts = lines[i].split()
        if not parts:
            continue
        if len(parts) != 10:
            raise SequenceError(f"{path}: line {i + 1}: expected 'ID QW QX QY QZ TX TY TZ CAM NAME'")
        try:
            values = np.array([float(x) for x in parts[1:8]])
        except ValueError as exc:
            raise SequenceError(f"{path}: line {i + 1}: pose values: {exc}") from exc
        poses[parts[9]] = make_pose(matrix_from_quat_wxyz(values[:4]), values[4:])
    return poses


def read_sequence(root: Path) -> SequenceFiles:
    """Camera, GT poses and split of a sequence folder."""
    root = Path(root)
    camera = read_cameras_txt(root / "colmap" / "cameras.txt")
    poses = read_images_txt(root / "colmap" / "images.txt")
    split_path = root / "split.json"
    if split_path.is_file():
        split = json.loads(split_path.read_text())
        for key in ("map", "query"):
            if not isinstance(split.get(key), list):
                raise SequenceError(f"{split_path}: field {key!r} must be a list of frame names")
            for name in split[key]:
                if name not in poses:
                    raise SequenceError(
                        f"{split_path}: {key} frame {name!r} has no pose in colmap/images.txt"
                    )
        map_frames, query_frames = list(split["map"]), list(split["query"])
    else:
        map_frames, query_frames = sorted(poses), []
    return SequenceFiles(root, camera, poses, map_frames, query_frames)
