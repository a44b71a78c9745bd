"""Shared data types: the pinhole :class:`Camera`, :class:`Light`, and the flattened world-space scene a
renderer consumes (:class:`RenderScene` of :class:`RenderMesh` and :class:`InstanceInfo`).

Camera convention: pixel (u, v) covers [u, u+1) x [v, v+1); the ray through its centre passes (u + 0.5, v + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics (COLMAP ``PINHOLE``), pixel-centre convention above."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the standard symbol
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> Camera:
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, width / 2.0, height / 2.0)


@dataclass
class Light:
    """A light source. ``kind``: ``sphere`` (point-like, ``radius``), ``rect`` (area light facing -z of its
    frame, ``size``), or ``distant`` (direction = -z of its frame). ``world_from_light`` places it;
    ``intensity`` is radiant intensity (W/sr) for sphere lights and radiance for rect lights, ``color`` RGB."""

    name: str
    kind: str
    world_from_light: np.ndarray
    intensity: float
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    radius: float = 0.05
    size: tuple[float, float] = (0.5, 0.5)


@dataclass
class RenderMesh:
    """One textured triangle mesh in world coordinates (metres, +z up) with its instance id."""

    name: str
    instance_id: int
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    texture: np.ndarray | None
    """(H, W, 3) uint8, row 0 at the top; None: use ``base_color``."""
    base_color: tuple[float, float, float] = (0.7, 0.7, 0.7)
    roughness: float = 0.6
    metallic: float = 0.0
    emissive: tuple[float, float, float] | None = None

    def checked_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (N, 3) float64, faces (M, 3) int64)``; a clear error for an empty or broken mesh."""
        verts = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if len(verts) == 0 or len(faces) == 0:
            raise ValueError(f"mesh {self.name!r} (instance {self.instance_id}) is empty")
        if faces.min() < 0 or faces.max() >= len(verts):
            raise ValueError(f"mesh {self.name!r}: face indices outside its {len(verts)} vertices")
        return verts, faces


@dataclass
class InstanceInfo:
    """What ground truth needs to know about one instance."""

    instance_id: int
    name: str
    model_id: str
    category: str
    symmetry: str
    role: str
    world_from_object: np.ndarray
    extents: np.ndarray
    variant_params: dict = field(default_factory=dict)
    prim_path: str = ""
    support: str = "floor"
    """floor | wall | ceiling | surface | none (as ``PlacedObject.support``); orbits depend on it."""


@dataclass
class RenderScene:
    """Everything a renderer needs, flattened to world space."""

    meshes: list[RenderMesh]
    lights: list[Light]
    instances: dict[int, InstanceInfo]
    ambient: float = 0.0
    source: str = ""
    kind: str = "room"
    target_instance_id: int | None = None
