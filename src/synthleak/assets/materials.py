"""The shared material catalogue: families of "SKUs", each SKU one exact texture.

In real homes the same printed laminate, veneer, upholstery fabric or hardware finish appears on many products
(a wooden lamp matched onto other wooden objects is the paper's own failure case). A :class:`Sku` is one such
material: its texture is generated from the SKU's id alone (``make_rng(0, "sku", sku_id)``) and mapped at the
SKU's physical scale (``texel_scale`` metres per texture), so two products using it show the same print.

A model's material slot may use a SKU of a family that fits the slot's texture kind (:data:`FAMILIES_BY_KIND`).
:func:`assign_materials` draws, per study seed and (model, slot), whether the slot uses a shared SKU
(probability ``material_sharing``) and which one; the draws do not depend on ``material_sharing`` itself, so
the slots shared at a lower sharing stay shared at a higher one. As in a furniture store, a few finishes are
far more common than the rest: families and SKUs are listed most popular first and drawn with weights
``1 / rank`` (the first laminate is on about 40 % of laminated slots). ``material_sharing = 0`` leaves every model as
the library defines it (same texture bytes). :func:`with_materials` applies an assignment to a model.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from synthleak.assets.model import MaterialSpec, ObjectModel
from synthleak.assets.textures import make_texture
from synthleak.seeding import make_rng

SKU_TEXTURE_SIZE = 512
UNIQUE = "unique"
"""The assignment value of a slot that keeps the model's own texture."""

Colour = tuple[float, float, float]


@dataclass(frozen=True)
class Sku:
    """One exact material sold on many products: texture kind, colours and physical print scale."""

    sku_id: str
    """``family/name``."""
    kind: str
    colour: Colour
    colour2: Colour | None = None
    feature_scale: float = 1.0
    texel_scale: float = 1.0
    roughness: float = 0.6
    metallic: float = 0.0

    @property
    def family(self) -> str:
        return self.sku_id.split("/", 1)[0]

    def texture(self) -> np.ndarray:
        """The SKU's texture (cached, read-only): the same bytes on every product."""
        return _sku_texture(self)

    def slot_spec(self, base: MaterialSpec) -> MaterialSpec:
        """A model's material slot (``[textures.<slot>]``) with this SKU's look; ``recolour`` and ``emissive``
        of ``base`` are kept."""
        return MaterialSpec(
            kind=self.kind,
            colour=self.colour,
            colour2=self.colour2,
            roughness=self.roughness,
            metallic=self.metallic,
            texel_scale=self.texel_scale,
            feature_scale=self.feature_scale,
            recolour=base.recolour,
            emissive=base.emissive,
            sku=self.sku_id,
        )


@functools.lru_cache(maxsize=128)
def _sku_texture(sku: Sku) -> np.ndarray:
    tex = make_texture(
        sku.kind,
        make_rng(0, "sku", sku.sku_id),
        sku.colour,
        SKU_TEXTURE_SIZE,
        colour2=sku.colour2,
        feature_scale=sku.feature_scale,
    )
    tex.flags.writeable = False
    return tex


def _family(name: str, kind: str, skus: dict[str, dict[str, Any]], **common: Any) -> tuple[Sku, ...]:
    return tuple(Sku(f"{name}/{sku}", kind, **{**common, **fields}) for sku, fields in skus.items())


FAMILIES: dict[str, tuple[Sku, ...]] = {
    "laminate": _family(  # printed wood-grain foils on particle board: the same print on many products
        "laminate", "wood", {
            "oak_natural": {"colour": (0.78, 0.62, 0.42), "colour2": (0.52, 0.36, 0.20)},
            "oak_white": {"colour": (0.88, 0.84, 0.76), "colour2": (0.66, 0.60, 0.50)},
            "birch": {"colour": (0.86, 0.76, 0.60), "colour2": (0.64, 0.52, 0.36)},
            "walnut": {"colour": (0.45, 0.30, 0.20), "colour2": (0.25, 0.15, 0.09)},
            "black_brown": {"colour": (0.22, 0.17, 0.14), "colour2": (0.10, 0.07, 0.05)},
            "ash_grey": {"colour": (0.62, 0.60, 0.56), "colour2": (0.40, 0.38, 0.35)},
        }, texel_scale=1.0, roughness=0.45),
    "solid_wood": _family(
        "solid_wood", "wood", {
            "pine": {"colour": (0.85, 0.68, 0.45), "colour2": (0.62, 0.40, 0.20), "feature_scale": 1.2},
            "beech": {"colour": (0.80, 0.62, 0.46), "colour2": (0.60, 0.42, 0.28)},
            "oak": {"colour": (0.70, 0.53, 0.34), "colour2": (0.45, 0.31, 0.17), "feature_scale": 0.8},
            "teak": {"colour": (0.58, 0.38, 0.22), "colour2": (0.36, 0.21, 0.10)},
            "rubberwood_stained": {"colour": (0.40, 0.26, 0.16), "colour2": (0.22, 0.13, 0.07)},
        }, texel_scale=0.8, roughness=0.55),
    "upholstery": _family(  # woven upholstery fabrics
        "upholstery", "fabric", {
            "grey": {"colour": (0.52, 0.52, 0.54)},
            "beige": {"colour": (0.78, 0.70, 0.58)},
            "dark_blue": {"colour": (0.16, 0.22, 0.38)},
            "green": {"colour": (0.30, 0.42, 0.30)},
            "anthracite": {"colour": (0.22, 0.22, 0.24)},
        }, texel_scale=0.5, roughness=0.9),
    "upholstery_print": _family(  # printed fabrics (cushions, seats, shades)
        "upholstery_print", "pattern", {
            "floral": {"colour": (0.85, 0.80, 0.70), "colour2": (0.55, 0.25, 0.30)},
            "leaves": {"colour": (0.80, 0.84, 0.78), "colour2": (0.20, 0.40, 0.25)},
            "geometric": {"colour": (0.90, 0.88, 0.84), "colour2": (0.15, 0.20, 0.35)},
            "dots": {"colour": (0.30, 0.35, 0.45), "colour2": (0.90, 0.85, 0.60)},
            "paisley": {"colour": (0.60, 0.20, 0.20), "colour2": (0.95, 0.80, 0.50)},
        }, texel_scale=0.6, roughness=0.85),
    "metal": _family(
        "metal", "metal", {
            "brushed_steel": {"colour": (0.66, 0.67, 0.69)},
            "black_powder": {"colour": (0.12, 0.12, 0.13)},
            "brass": {"colour": (0.76, 0.62, 0.34)},
            "chrome": {"colour": (0.80, 0.81, 0.83)},
        }, texel_scale=0.5, roughness=0.35, metallic=0.9),
    "plastic": _family(
        "plastic", "plastic", {
            "white": {"colour": (0.92, 0.92, 0.90)},
            "black": {"colour": (0.10, 0.10, 0.11)},
            "grey": {"colour": (0.55, 0.56, 0.58)},
            "red": {"colour": (0.75, 0.15, 0.12)},
        }, texel_scale=0.5, roughness=0.4),
    "ceramic": _family(
        "ceramic", "ceramic", {
            "white_glaze": {"colour": (0.92, 0.91, 0.88), "colour2": (0.30, 0.40, 0.60)},
            "stoneware": {"colour": (0.72, 0.64, 0.52), "colour2": (0.40, 0.28, 0.20)},
            "terracotta": {"colour": (0.72, 0.40, 0.26), "colour2": (0.45, 0.22, 0.12)},
            "blue_glaze": {"colour": (0.25, 0.38, 0.60), "colour2": (0.90, 0.88, 0.80)},
        }, texel_scale=0.3, roughness=0.3),
    "leather": _family(
        "leather", "leather", {
            "cognac": {"colour": (0.55, 0.32, 0.16)},
            "black": {"colour": (0.12, 0.11, 0.10)},
            "tan": {"colour": (0.70, 0.52, 0.34)},
        }, texel_scale=0.5, roughness=0.6),
    "print": _family(  # mass-produced art prints and posters
        "print", "print", {
            "abstract_warm": {"colour": (0.85, 0.55, 0.35)},
            "abstract_cool": {"colour": (0.35, 0.55, 0.80)},
            "botanical": {"colour": (0.45, 0.65, 0.40)},
            "monochrome": {"colour": (0.60, 0.60, 0.60)},
        }, texel_scale=1.0, roughness=0.5),
}
"""Family name -> its SKUs."""

FAMILIES_BY_KIND: dict[str, tuple[str, ...]] = {
    "wood": ("laminate", "solid_wood"),
    "fabric": ("upholstery",),
    "pattern": ("upholstery_print",),
    "metal": ("metal",),
    "plastic": ("plastic",),
    "ceramic": ("ceramic",),
    "leather": ("leather",),
    "print": ("print",),
}
"""Texture kind of a material slot -> the families whose SKUs may replace it (other kinds stay unique)."""

SKUS: dict[str, Sku] = {sku.sku_id: sku for skus in FAMILIES.values() for sku in skus}


def get_sku(sku_id: str) -> Sku:
    """The SKU called ``sku_id`` (``family/name``); raises naming the known families."""
    if sku_id not in SKUS:
        raise KeyError(f"unknown material SKU {sku_id!r} (families: {', '.join(FAMILIES)})")
    return SKUS[sku_id]


def assign_materials(model: ObjectModel, seed: int, sharing: float) -> dict[str, str]:
    """Slot -> SKU id (or :data:`UNIQUE`) of ``model`` in a study of ``seed``.

    Each slot whose kind fits a family draws ``u``, a family and a SKU from ``make_rng(seed, "materials",
    model_id, slot)``; it uses the SKU when ``u < sharing``. Emissive slots and imported models keep their
    own textures."""
    if not 0.0 <= sharing <= 1.0:
        raise ValueError(f"material_sharing must be in [0, 1], got {sharing}")
    out: dict[str, str] = {}
    for slot in sorted(model.textures):
        spec = model.textures[slot]
        families = FAMILIES_BY_KIND.get(spec.kind, ()) if isinstance(spec, MaterialSpec) else ()
        if not families or spec.emissive is not None:
            out[slot] = UNIQUE
            continue
        rng = make_rng(seed, "materials", model.model_id, slot)
        u = float(rng.random())
        family = FAMILIES[families[_popular(rng, len(families))]]
        sku = family[_popular(rng, len(family))]
        out[slot] = sku.sku_id if u < sharing else UNIQUE
    return out


def _popular(rng: np.random.Generator, n: int) -> int:
    """An index in ``range(n)`` drawn with weights ``1 / (index + 1)`` (the first is the most popular)."""
    weights = 1.0 / np.arange(1, n + 1)
    return int(rng.choice(n, p=weights / weights.sum()))


def with_materials(model: ObjectModel, assignment: Mapping[str, str]) -> ObjectModel:
    """``model`` whose slots use the assigned SKUs (slots set to :data:`UNIQUE` or absent keep theirs)."""
    shared = {slot: sku for slot, sku in assignment.items() if sku != UNIQUE}
    if not shared:
        return model
    unknown = sorted(set(shared) - set(model.textures))
    if unknown:
        raise KeyError(f"model {model.model_id!r} has no material slot(s) {unknown} (it has {sorted(model.textures)})")
    textures = dict(model.textures)
    for slot, sku_id in shared.items():
        textures[slot] = get_sku(sku_id).slot_spec(model.textures[slot])
    return dataclasses.replace(model, textures=textures)


def model_skus(model: ObjectModel) -> dict[str, str]:
    """Slot -> SKU id of the slots of ``model`` that use a shared SKU."""
    return {
        slot: spec.sku for slot, spec in sorted(model.textures.items()) if isinstance(spec, MaterialSpec) and spec.sku
    }
