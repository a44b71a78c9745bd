"""Variants of library models: recoloured, rescaled, reshaped copies (what an attacker photographs elsewhere).

``variant(model, seed, magnitude, kinds)`` draws, for each kind, one fixed direction ``u`` in [-1, 1] per
quantity from ``make_rng(seed, "variant", model_id, kind)`` (independent of the magnitude and of the other
kinds), then moves ``magnitude * u`` of the way from the model to the edge of the declared range:

- ``shape``: ``p = default + magnitude * u * (max - default if u > 0 else default - min)``, clipped to
  ``[min, max]``, rounded for integer parameters;
- ``scale``: per axis ``s = 1 + magnitude * u * (hi - 1 if u > 0 else 1 - lo)`` within ``scale_range``
  (``(lo, hi)``); models with symmetry ``z`` or ``4`` keep ``sx == sy``;
- ``colour``: ``(dh, ds, dv) = magnitude * u * colour_range`` (hue in turns, saturation and value deltas),
  applied with :func:`synthleak.assets.textures.hsv_shift` to every material with ``recolour`` (default true).

So magnitude 0 is exactly the model (same vertices, same texture bytes), magnitude 1 reaches the declared
ranges (values are clipped there for larger magnitudes), and a seed's variants lie on one line as the
magnitude grows. Scaling is about the canonical origin (bottom centre), so the frame convention holds.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from synthleak.assets.library import build_model, get_model
from synthleak.assets.materials import model_skus, with_materials
from synthleak.assets.mesh import VARIANT_KINDS, ObjectMesh, SupportSurface, TexturedPart
from synthleak.assets.model import ObjectModel, get_builder
from synthleak.assets.textures import hsv_shift
from synthleak.seeding import make_rng

__all__ = ["VARIANT_KINDS", "SupportSurface", "Variant", "variant", "variant_from_record"]


@dataclass
class Variant:
    """One concrete variant of ``model``; see the module docstring for how its parameters were drawn."""

    model: ObjectModel
    seed: int
    magnitude: float
    kinds: tuple[str, ...]
    shape_params: dict[str, float]
    scale: tuple[float, float, float]
    colour_shift: tuple[float, float, float]
    _cache: tuple[ObjectMesh, list[SupportSurface]] | None = field(default=None, repr=False, compare=False)

    def _built(self) -> tuple[ObjectMesh, list[SupportSurface]]:
        if self._cache is None:
            textures = None
            if any(self.colour_shift):
                textures = {
                    mat: hsv_shift(self.model.material_texture(mat), *self.colour_shift)
                    for mat, spec in self.model.textures.items()
                    if spec.recolour
                }
            mesh, surfaces = build_model(self.model, self.shape_params, textures)
            s = np.asarray(self.scale, np.float64)
            if np.any(s != 1.0):
                for p in mesh.parts:
                    p.vertices = p.vertices * s
                surfaces = [sf.scaled(self.scale) for sf in surfaces]
            self._cache = (mesh, surfaces)
        return self._cache

    def build(self) -> ObjectMesh:
        """The textured mesh (canonical frame: bottom centre at the origin, +z up, front +y), scaled and
        recoloured. Each call returns fresh arrays."""
        mesh, _ = self._built()
        return ObjectMesh(
            parts=[
                TexturedPart(
                    name=p.name,
                    vertices=p.vertices.copy(),
                    faces=p.faces.copy(),
                    uv=p.uv.copy(),
                    texture=p.texture.copy(),
                    roughness=p.roughness,
                    metallic=p.metallic,
                    emissive=p.emissive,
                )
                for p in mesh.parts
            ]
        )

    def support_surfaces(self) -> list[SupportSurface]:
        """Horizontal tops (object frame) on which small objects may stand; empty for chairs etc."""
        return list(self._built()[1])

    def extents(self) -> np.ndarray:
        """Full bounding-box sizes (x, y, z) of the built variant."""
        return self._built()[0].extents()

    def record(self) -> dict[str, Any]:
        """Every parameter used, JSON-serialisable; :func:`variant_from_record` rebuilds it. ``materials``
        (slot -> shared SKU id) is there only when the model uses catalogue SKUs."""
        skus = model_skus(self.model)
        return ({"materials": skus} if skus else {}) | {
            "model_id": self.model.model_id,
            "category": self.model.category,
            "seed": int(self.seed),
            "magnitude": float(self.magnitude),
            "kinds": list(self.kinds),
            "shape_params": {k: float(v) for k, v in sorted(self.shape_params.items())},
            "scale": [float(s) for s in self.scale],
            "colour_shift": [float(c) for c in self.colour_shift],
        }


def _toward(u: float, magnitude: float, centre: float, lo: float, hi: float) -> float:
    step = magnitude * u * ((hi - centre) if u > 0 else (centre - lo))
    return float(np.clip(centre + step, lo, hi))


def variant(model: ObjectModel, seed: int, magnitude: float, kinds: Sequence[str] = VARIANT_KINDS) -> Variant:
    """Draw a variant of ``model`` (see the module docstring). ``kinds`` is any subset of
    ``("colour", "scale", "shape")``."""
    kinds = tuple(kinds)
    bad = [k for k in kinds if k not in VARIANT_KINDS]
    if bad:
        raise ValueError(f"unknown variant kind(s) {bad}; known: {VARIANT_KINDS}")
    if not np.isfinite(magnitude) or magnitude < 0:
        raise ValueError(f"magnitude must be a finite number >= 0, got {magnitude}")
    m = float(magnitude)
    unsupported = [k for k in kinds if k not in get_builder(model.builder).variant_kinds]
    if unsupported:
        warnings.warn(
            f"model {model.model_id!r} ({model.builder} builder): {', '.join(unsupported)} variants are not "
            f"available; only {', '.join(k for k in kinds if k not in unsupported) or 'none'} vary",
            UserWarning,
            stacklevel=2,
        )
    shape = model.default_params()
    if "shape" in kinds:
        rng = make_rng(seed, "variant", model.model_id, "shape")
        for name in sorted(model.params):
            r = model.params[name]
            u = float(rng.uniform(-1.0, 1.0))
            shape[name] = r.clip(_toward(u, m, r.default, r.min, r.max))
    scale = (1.0, 1.0, 1.0)
    if "scale" in kinds:
        rng = make_rng(seed, "variant", model.model_id, "scale")
        lo, hi = model.scale_range
        s = [_toward(float(u), m, 1.0, lo, hi) for u in rng.uniform(-1.0, 1.0, 3)]
        if model.symmetry in ("z", "4"):
            s[1] = s[0]
        scale = (s[0], s[1], s[2])
    colour = (0.0, 0.0, 0.0)
    if "colour" in kinds:
        rng = make_rng(seed, "variant", model.model_id, "colour")
        u = rng.uniform(-1.0, 1.0, 3)
        colour = tuple(float(np.clip(m * ui * r, -r, r)) for ui, r in zip(u, model.colour_range, strict=True))
    return Variant(
        model=model,
        seed=int(seed),
        magnitude=m,
        kinds=kinds,
        shape_params=shape,
        scale=scale,
        colour_shift=colour,
    )  # type: ignore[arg-type]


def variant_from_record(record: dict[str, Any], library: dict[str, ObjectModel] | None = None) -> Variant:
    """Rebuild a :class:`Variant` from :meth:`Variant.record` (the stored parameters are used as they are)."""
    model = with_materials(get_model(record["model_id"], library), record.get("materials", {}))
    return Variant(
        model=model,
        seed=int(record["seed"]),
        magnitude=float(record["magnitude"]),
        kinds=tuple(record["kinds"]),
        shape_params={k: float(v) for k, v in record["shape_params"].items()},
        scale=tuple(float(s) for s in record["scale"]),  # type: ignore[arg-type]
        colour_shift=tuple(float(c) for c in record["colour_shift"]),
    )  # type: ignore[arg-type]
