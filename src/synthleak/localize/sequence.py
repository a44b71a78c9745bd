"""The view of a dataset sequence folder (``scenes/<room>/``) that mapping needs.

Reads through :func:`synthleak.render.dataset.load_sequence` (the owner of the file contract in
docs/DATASET.md); errors name the file and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from synthleak.core.types import Camera
from synthleak.errors import SynthleakError
from synthleak.render.dataset import DatasetError, load_sequence


class SequenceError(SynthleakError, ValueError):
    """A sequence folder that cannot be used; the message names the file and the field."""


@dataclass
class SequenceFiles:
    """Camera, GT poses, split and per-frame files of one sequence."""

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


def read_sequence(root: Path) -> SequenceFiles:
    """Camera, GT poses and split (no ``split.json``: every frame is a map frame, no queries)."""
    root = Path(root)
    try:
        seq = load_sequence(root)
    except DatasetError as exc:
        raise SequenceError(str(exc)) from exc
    map_frames = list(seq.split.get("map", seq.frames))
    query_frames = list(seq.split.get("query", []))
    return SequenceFiles(root, seq.camera, dict(seq.cam_from_world), map_frames, query_frames)
