"""The query feature file: one image's :class:`~synthleak.localize.features.Features` as ``.npz`` (exact arrays).

Arrays: ``keypoints``, ``descriptors``, ``binary`` (0-d bool), ``image_size`` (``(width, height)``, int64) and,
when the extractor scores its keypoints, ``scores``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from synthleak.atomic_io import atomic_write_bytes
from synthleak.localize.features import Features


def save_features(path: Path, features: Features, image_size: tuple[int, int]) -> None:
    """One image's features as ``.npz`` (exact arrays), written atomically."""
    buffer = io.BytesIO()
    arrays = {"keypoints": features.keypoints, "descriptors": features.descriptors,
              "binary": np.array(features.binary), "image_size": np.array(image_size, np.int64)}
    if features.scores is not None:
        arrays["scores"] = features.scores
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def load_features(path: Path) -> tuple[Features, tuple[int, int]]:
    """``(Features, (width, height))`` of :func:`save_features`."""
    with np.load(path) as z:
        scores = z["scores"] if "scores" in z.files else None
        size = tuple(int(v) for v in z["image_size"])
        return Features(z["keypoints"], z["descriptors"], bool(z["binary"]), scores, size), size
