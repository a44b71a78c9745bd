"""On-disk map format (``map_dir/``) shared by mapping and localization.

* ``map.json``: tier, inputs' content hash, config, camera, counts, format version, and ``retrieval``: the
  method and ``top_k`` of the localize config it was last built or reused with, and the ``bow`` index's
  parameters (:class:`synthleak.localize.retrieval.BowParams`);
* ``features.npz``: per map image ``kp_<i>`` (N, 2), ``desc_<i>``, ``p3d_<i>`` (N,) index into the
  points (-1: none), plus ``names`` and ``binary``;
* ``points.npz``: ``xyz`` (P, 3), ``instance`` (P,) majority GT instance id, ``error`` (px), ``track_length``,
  ``colmap_id`` (P,) the point's id in ``sfm/``;
* ``points_instance.json``: ``{colmap point3D id: instance id}`` (server-only labels for the defense);
* ``bow.npz``: bag-of-words retrieval index (vocabulary tree, idf, histograms);
* ``image_instances.json``: per map image, the GT instances it sees and their pixel counts
  (:mod:`synthleak.localize.visibility`);
* ``sfm/``: the COLMAP model (binary) with the GT poses.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthleak.core.types import Camera
from synthleak.errors import SynthleakError
from synthleak.localize.features import Features

FORMAT_VERSION = 2
"""2: vocabulary-tree ``bow.npz``, ``image_instances.json``, ``retrieval`` in ``map.json``."""


class MapError(SynthleakError, ValueError):
    """A map folder that cannot be used; names the file and the field."""


@dataclass
class MapData:
    """Everything the localizer needs, in memory."""

    meta: dict
    camera: Camera
    names: list[str]
    features: list[Features]
    point_index: list[np.ndarray]
    xyz: np.ndarray
    instance: np.ndarray


def camera_to_json(camera: Camera) -> dict:
    return {"width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
            "cx": camera.cx, "cy": camera.cy}


def read_map_meta(map_dir: Path) -> tuple[dict, Camera]:
    """``map.json`` and the map camera, checked (the arrays are not read)."""
    meta_path = Path(map_dir) / "map.json"
    if not meta_path.is_file():
        raise MapError(f"{meta_path}: missing (build the map with synthleak.localize.build_map)")
    meta = json.loads(meta_path.read_text())
    if meta.get("format_version") != FORMAT_VERSION:
        raise MapError(f"{meta_path}: field 'format_version' is {meta.get('format_version')}, "
                       f"expected {FORMAT_VERSION}: rebuild the map")
    try:
        c = meta["camera"]
        camera = Camera(int(c["width"]), int(c["height"]), float(c["fx"]), float(c["fy"]),
                        float(c["cx"]), float(c["cy"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise MapError(f"{meta_path}: field 'camera' is invalid ({exc})") from exc
    return meta, camera


def read_map_features(map_dir: Path, camera: Camera) -> tuple[list[str], list[Features], list[np.ndarray]]:
    """``features.npz`` of a map (any representation): image names, each image's features, and per keypoint the
    index of its 3D point or line (-1: none)."""
    with np.load(Path(map_dir) / "features.npz") as data:
        names = [str(n) for n in data["names"]]
        binary = bool(data["binary"])
        size = (camera.width, camera.height)
        features = [Features(data[f"kp_{i}"], data[f"desc_{i}"], binary, image_size=size)
                    for i in range(len(names))]
        point_index = [data[f"p3d_{i}"] for i in range(len(names))]
    return names, features, point_index


def read_map(map_dir: Path) -> MapData:
    """Load ``map.json``, ``features.npz`` and ``points.npz``."""
    map_dir = Path(map_dir)
    meta, camera = read_map_meta(map_dir)
    names, features, point_index = read_map_features(map_dir, camera)
    with np.load(map_dir / "points.npz") as data:
        xyz, instance = data["xyz"], data["instance"]
    return MapData(meta, camera, names, features, point_index, xyz, instance)
