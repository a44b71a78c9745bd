"""In-memory description of a scene: what the USD writer writes and the USD reader gives back.

``SceneSpec`` is what synthleak composes (rooms, attacker setups). ``RenderScene`` (core.types) is the
flattened, world-space form a renderer consumes; ``synthleak.core.usd_read.read_render_scene`` builds it
from any stage.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from synthleak.assets.mesh import ObjectMesh
from synthleak.core.types import Light


@dataclass
class PlacedObject:
    """One object instance placed in a scene.

    ``world_from_object`` maps the object's canonical frame into the scene (metres, +z up).
    ``role`` is ``"object"`` for furniture or ``"shell"`` for floor / walls / ceiling pieces, which get
    their own instance ids so a defense can count them.
    """

    instance_id: int
    name: str
    model_id: str
    category: str
    symmetry: str
    world_from_object: np.ndarray
    mesh: ObjectMesh
    variant_params: dict[str, Any] = field(default_factory=dict)
    role: str = "object"
    support: str = "floor"
    """floor | wall | ceiling | surface (stands on another object's top) | none."""
    extents: np.ndarray | None = None
    """Full canonical-frame bounding-box sizes (x, y, z); derived from the mesh when None."""

    def object_extents(self) -> np.ndarray:
        return self.mesh.extents() if self.extents is None else np.asarray(self.extents, dtype=np.float64)


@dataclass
class SceneSpec:
    """A room or an attacker setup. ``kind``: ``room`` or ``attacker``; ``target_instance_id`` names the
    photographed object of an attacker setup."""

    name: str
    kind: str
    objects: list[PlacedObject]
    lights: list[Light]
    room_size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seed: int = 0
    target_instance_id: int | None = None
    ambient: float = 0.0
    """Constant environment radiance (a weak fill light), 0 for none."""
    metadata: dict[str, Any] = field(default_factory=dict)
