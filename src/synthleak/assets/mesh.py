"""Textured mesh types shared by the object library, the scene composer and the renderers.

Canonical object frame (the convention, written down once): origin at the bottom centre of the object's
footprint (the centre of its axis-aligned bounding box in x and y, its lowest point in z), +z up,
the front faces +y, units are metres. ``extents`` are the full bounding-box sizes along x, y, z.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

VARIANT_KINDS = ("colour", "scale", "shape")
"""What a variant of a model may change (``synthleak.assets.variants``)."""


@dataclass
class TexturedPart:
    """One triangle mesh with per-vertex UVs and its own RGB texture.

    ``vertices`` (N, 3) float64 in the owning object's frame; ``faces`` (M, 3) int64, counter-clockwise
    seen from outside; ``uv`` (N, 2) float64 in [0, 1] with v = 0 at the bottom row of ``texture``
    (OpenGL / USD convention); ``texture`` (H, W, 3) uint8, row 0 is the top of the image.
    ``roughness`` in [0, 1] and ``metallic`` in [0, 1] are hints for physically based renderers.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    roughness: float = 0.6
    metallic: float = 0.0
    emissive: tuple[float, float, float] | None = None


@dataclass
class ObjectMesh:
    """All parts of one object instance, in its canonical frame."""

    parts: list[TexturedPart] = field(default_factory=list)

    def bounds(self) -> np.ndarray:
        """(2, 3) min/max corners over all parts."""
        verts = np.concatenate([p.vertices for p in self.parts])
        return np.stack([verts.min(axis=0), verts.max(axis=0)])

    def extents(self) -> np.ndarray:
        """Full axis-aligned sizes along x, y, z."""
        lo, hi = self.bounds()
        return hi - lo


@dataclass(frozen=True)
class SupportSurface:
    """A horizontal top (object frame, metres) on which small objects may stand: height ``z`` and its
    axis-aligned footprint."""

    z: float
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def to_dict(self) -> dict[str, float]:
        return {
            "z": self.z,
            "x_min": self.x_min,
            "x_max": self.x_max,
            "y_min": self.y_min,
            "y_max": self.y_max,
        }

    def scaled(self, scale: Sequence[float]) -> SupportSurface:
        """The surface of the object scaled per axis about the canonical origin."""
        sx, sy, sz = (float(s) for s in scale)
        return SupportSurface(self.z * sz, self.x_min * sx, self.x_max * sx, self.y_min * sy, self.y_max * sy)
