"""Which GT instances each map image sees (from the sequence's instance masks), for the report's funnel.

A map stores ``image_instances.json``: ``{"min_fraction": f, "min_pixels": n, "images": {name: {instance id:
pixel count}}}`` with the instances covering at least ``min_fraction`` of an image's pixels (``min_pixels`` at
the map's resolution; 0.5 % is 864 px at 480x360, about a 30x30 px patch: enough for a handful of SIFT
keypoints). The localizer's result names the map images it matched (``retrieved``);
:func:`retrieved_sees` says whether one of them sees a given instance. Server-side ground truth: never sent to
a client.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

VISIBLE_MIN_FRACTION = 0.005
"""An instance is visible in an image when it covers at least this fraction of its pixels."""

FILE_NAME = "image_instances.json"


def visible_instances(mask: np.ndarray, min_fraction: float = VISIBLE_MIN_FRACTION) -> dict[int, int]:
    """``{instance id: pixel count}`` of the ids in an (H, W) instance mask covering >= ``min_fraction`` of it
    (0, the background, left out), sorted by id."""
    ids, counts = np.unique(np.asarray(mask), return_counts=True)
    min_pixels = min_pixels_for(mask.size, min_fraction)
    return {int(i): int(c) for i, c in zip(ids, counts, strict=True) if i != 0 and c >= min_pixels}


def min_pixels_for(num_pixels: int, min_fraction: float = VISIBLE_MIN_FRACTION) -> int:
    return max(1, int(np.ceil(min_fraction * num_pixels)))


def image_instances_json(names: Iterable[str], masks: Iterable[np.ndarray],
                         min_fraction: float = VISIBLE_MIN_FRACTION) -> dict:
    """The ``image_instances.json`` document for map images ``names`` and their instance masks."""
    images, num_pixels = {}, 0
    for name, mask in zip(names, masks, strict=True):
        num_pixels = int(np.asarray(mask).size)
        images[str(name)] = {str(k): v for k, v in visible_instances(mask, min_fraction).items()}
    return {"min_fraction": min_fraction, "min_pixels": min_pixels_for(num_pixels, min_fraction), "images": images}


def read_image_instances(map_dir: Path) -> dict[str, set[int]] | None:
    """``{map image name: visible instance ids}`` of a map, or None when the map has no such file (a remote
    server's map, or one built before the file existed)."""
    path = Path(map_dir) / FILE_NAME
    if not path.is_file():
        return None
    try:
        images = json.loads(path.read_text())["images"]
        return {str(name): {int(i) for i in ids} for name, ids in images.items()}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: field 'images' is invalid ({exc})") from exc


def retrieved_sees(retrieved: Iterable[str], instance_id: int, image_instances: Mapping[str, set[int]]) -> bool:
    """Whether one of the ``retrieved`` map images sees instance ``instance_id``.

    Raises naming the image when a retrieved name is not a map image (the log and the map disagree)."""
    for name in retrieved:
        try:
            if int(instance_id) in image_instances[name]:
                return True
        except KeyError:
            raise ValueError(f"retrieved map image {name!r} is not an image of this map") from None
    return False


def count_retrieving(records: Iterable[Mapping], instance_id: int,
                     image_instances: Mapping[str, set[int]] | None) -> int | None:
    """How many query records (query-log lines with ``retrieved``) retrieved a map image that sees
    ``instance_id``; None without the map's visibility or when the log names no retrieved images (a remote
    server answers with the pose only)."""
    records = list(records)
    if image_instances is None or any("retrieved" not in q for q in records):
        return None
    return sum(1 for q in records if retrieved_sees(q["retrieved"], instance_id, image_instances))
