"""``synthleak export-maps``: what an outside localization pipeline needs to build a study's maps, and nothing
of the attacker's (the protocol: docs/service-protocol.md).

Per room, from the study's walk-through (``dataset/scenes/<room>/``), only the map frames (``split.json``
``map``): their images, their ground-truth z-depth (``depth=True``; it names no object, and the map built from
the posed images holds that geometry anyway), their COLMAP model with the ground-truth ``cam_from_world``
(``images.txt`` lines copied verbatim, ``cameras.txt`` with each camera a map frame uses, distortion
included), and a ``split.json`` of the map frames. Left out: the genuine query and close-up frames, every
attacker sequence (``attackers/``), the instance masks, ``objects.json`` and ``bop/`` (object labels and
poses), the stages and the study's maps, features and query logs. ``manifest.json`` (written last) names the
rooms (index order), the study's servers and the sha256 of every file.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

from synthleak.atomic_io import atomic_write_text
from synthleak.core.dataset import DatasetError, load_sequence, read_index
from synthleak.study.paths import StudyPaths

EXPORT_FORMAT = "synthleak-maps/1"
"""``manifest.json`` ``format`` of an export (docs/service-protocol.md)."""


def _colmap_lines(path: Path) -> list[str]:
    if not path.is_file():
        raise DatasetError(f"{path}: missing file")
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


def _map_colmap(colmap: Path, frames: list[str]) -> tuple[str, str]:
    """cameras.txt and images.txt of ``frames`` only, from a sequence's ``colmap/`` (lines kept verbatim:
    the poses are the dataset's bits)."""
    wanted = set(frames)
    image_lines: dict[str, str] = {}
    for line in _colmap_lines(colmap / "images.txt")[0::2]:
        tok = line.split()
        if len(tok) == 10 and tok[9] in wanted:
            image_lines[tok[9]] = line
    missing = [f for f in frames if f not in image_lines]
    if missing:
        raise DatasetError(f"{colmap / 'images.txt'}: map frames without a pose: {missing[:5]}")
    used = {line.split()[8] for line in image_lines.values()}
    camera_lines = [line for line in _colmap_lines(colmap / "cameras.txt") if line.strip() and line.split()[0] in used]
    if len(camera_lines) != len(used):
        raise DatasetError(f"{colmap / 'cameras.txt'}: CAMERA_IDs {sorted(used)} of the map frames not all defined")
    cameras = ("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
               f"# Number of cameras: {len(camera_lines)}\n" + "".join(line + "\n" for line in camera_lines))
    images = ("# Image list with two lines of data per image:\n"
              "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
              f"# Number of images: {len(frames)}, mean observations per image: 0\n"
              + "".join(f"{image_lines[f]}\n\n" for f in frames))
    return cameras, images


def _copy(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src`` where the file system allows, else a copy."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        dst.unlink()
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def export_maps(study_dir: Path, out_dir: Path, depth: bool = True) -> Path:
    """Write the mapping data of every room of the study ``study_dir`` to ``out_dir`` (layout: module
    docstring, docs/service-protocol.md); ``depth``: include the map frames' ground-truth depth. Returns the
    manifest's path. ``out_dir`` must not hold another export's files (a ValueError)."""
    paths = StudyPaths(Path(study_dir))
    out = Path(out_dir)
    stages = paths.scene_dataset / "stages"
    if not (stages / "index.json").is_file():
        raise FileNotFoundError(f"{stages / 'index.json'}: missing; is {study_dir} a study folder whose render "
                                f"stage ran (synthleak study CONFIG --out {study_dir})?")
    if out.exists() and any(out.iterdir()) and not (out / "manifest.json").is_file():
        raise ValueError(f"{out}: exists and is not an export (no manifest.json): give an empty or new folder")
    if (out / "rooms").is_dir():
        shutil.rmtree(out / "rooms")
    (out / "manifest.json").unlink(missing_ok=True)
    rooms: list[dict[str, Any]] = []
    for index, room in enumerate(read_index(stages)["rooms"]):
        name = room["name"]
        seq = load_sequence(paths.scene(name))
        frames = seq.map_frames
        if not frames:
            raise DatasetError(f"{seq.root / 'split.json'}: map: no map frames")
        folder = out / "rooms" / name
        for frame in frames:
            _copy(seq.image_path(frame), folder / "images" / frame)
            if depth:
                _copy(seq.depth_path(frame), folder / "depth" / seq.depth_path(frame).name)
        cameras, images = _map_colmap(seq.root / "colmap", frames)
        atomic_write_text(folder / "colmap" / "cameras.txt", cameras)
        atomic_write_text(folder / "colmap" / "images.txt", images)
        atomic_write_text(folder / "colmap" / "points3D.txt", "# 3D point list: empty (poses only)\n")
        atomic_write_text(folder / "split.json", json.dumps({"map": frames}, indent=1) + "\n")
        rooms.append({"name": name, "index": index, "path": f"rooms/{name}", "n_frames": len(frames),
                      "width": seq.camera.width, "height": seq.camera.height})
    servers = sorted(p.name for p in paths.maps.iterdir() if p.is_dir()) if paths.maps.is_dir() else []
    files = {p.relative_to(out).as_posix(): _sha256(p) for p in sorted(out.rglob("*")) if p.is_file()}
    manifest = {"format": EXPORT_FORMAT, "frame": "world", "pose": "cam_from_world", "depth": depth,
                "servers": servers, "rooms": rooms, "files": files}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    return out / "manifest.json"
