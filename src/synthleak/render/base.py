"""Renderer interface. Every backend consumes a world-space :class:`~synthleak.core.types.RenderScene` and
OpenCV cameras (:class:`~synthleak.core.types.Camera`) and returns a :class:`Frame`.

Frame conventions (all backends):
* pixel (u, v) covers [u, u+1) x [v, v+1); the ray through its centre passes (u + 0.5, v + 0.5);
* ``depth`` is float32 **z-depth** in metres (distance to the image plane along the optical axis),
  ``+inf`` where the ray hits nothing;
* ``instance`` is uint16: 0 = background, otherwise the stage's instance id (room shell pieces included);
* ``linear`` is the float linear radiance the backend encoded into ``rgb`` (mitsuba, Blender), for the
  photographic capture model (:mod:`synthleak.render.capture`); ``None`` where the backend has none (pyrender
  writes 8-bit gamma 2.2 directly: the pipeline linearises ``rgb`` by the backend's ``rgb_encoding``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from synthleak.core.types import Camera, RenderScene


@dataclass
class Frame:
    """One rendered view: RGB uint8 (H, W, 3), z-depth float32 (H, W), instance ids uint16 (H, W) and, where the
    backend has it, the linear radiance (H, W, 3) that ``rgb`` encodes."""

    rgb: np.ndarray
    depth: np.ndarray
    instance: np.ndarray
    linear: np.ndarray | None = None


class Renderer(Protocol):
    """A render backend. ``prepare`` is called once per scene, ``render`` once per frame.

    A backend whose frames carry no ``linear`` may say how its ``rgb`` is encoded with a class attribute
    ``rgb_encoding``: ``"srgb"`` (the default when absent) or ``"gamma2.2"`` (pyrender)."""

    name: str

    def prepare(self, scene: RenderScene) -> None: ...

    def render(self, camera: Camera, cam_from_world: np.ndarray, seed: int) -> Frame: ...
