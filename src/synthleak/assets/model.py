"""What a library model is: :class:`ObjectModel`, its typed material slots, and the registry of the builders
that make its mesh.

Every model names a *builder* (``builder = ...`` in its TOML). A builder (:class:`ModelBuilder`, registered by
name in :data:`BUILDERS`) reads its models' TOML tables, builds their meshes and gives their material
textures: the parametric builders (:mod:`synthleak.assets.builders`, one per furniture design, drawing
procedural textures) and ``imported`` (:mod:`synthleak.assets.builders.imported`, meshes and textures stored
in the library). TOML tables are read with :func:`synthleak.schema.from_table`: the table classes below list
a rule per field; errors name the file and the key. The schema is in ``object_library/README.md``.
"""

from __future__ import annotations

import difflib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from synthleak.assets.mesh import VARIANT_KINDS, ObjectMesh, SupportSurface
from synthleak.assets.textures import TEXTURE_KINDS
from synthleak.errors import ConfigError
from synthleak.schema import Rule, anything, at_least, each, matches, one_of, optional, within

SYMMETRIES = ("none", "2", "4", "z")
SUPPORTS = ("floor", "wall", "ceiling", "surface")
ROLES = ("furniture", "prop")
"""``furniture``: the objects a study attacks and places as its scene objects; ``prop``: small clutter
(books, cushions, rugs, posters...) read from ``object_library/props/``."""
PROPS_DIR = "props"
TEXTURE_SEED = 0
"""Root seed of every model's textures (a model's look is fixed; variants recolour it)."""
MODEL_ID = r"[a-z0-9_]+"


@dataclass(frozen=True)
class ParamRange:
    """A shape parameter: its default and the range variants may use (inclusive); the TOML table
    ``{ default = .., min = .., max = .., integer = false }``."""

    default: float
    min: float
    max: float
    integer: bool = False

    def clip(self, value: float) -> float:
        v = float(np.clip(value, self.min, self.max))
        return float(round(v)) if self.integer else v


RGB = tuple[float, float, float]
_UNIT_RGB = optional(each(within(0.0, 1.0)))


@dataclass(frozen=True)
class MaterialSpec:
    """One material slot of a parametric model (``[textures.<slot>]``): a procedural texture and its shading,
    or a shared catalogue SKU's look (``sku``: set by :func:`synthleak.assets.materials.with_materials`)."""

    RULES: ClassVar[dict[str, Rule]] = {
        "kind": one_of(TEXTURE_KINDS),
        "colour": _UNIT_RGB,
        "colour2": _UNIT_RGB,
        "roughness": within(0.0, 1.0),
        "metallic": within(0.0, 1.0),
        "texel_scale": within(0.05, 10.0),
        "feature_scale": within(0.1, 10.0),
        "recolour": anything,
        "emissive": anything,
        "sku": anything,
    }

    kind: str
    """A texture kind of :data:`synthleak.assets.textures.TEXTURE_KINDS`."""
    colour: RGB
    colour2: RGB | None = None
    roughness: float = 0.6
    metallic: float = 0.0
    texel_scale: float = 1.0
    """Metres per texture repeat."""
    feature_scale: float = 1.0
    recolour: bool = True
    """Colour variants shift this slot's hue / saturation / value."""
    emissive: RGB | None = None
    sku: str | None = None
    """The shared catalogue SKU (``family/name``) whose texture the slot uses; never set in a TOML file."""


@dataclass(frozen=True)
class StoredPart:
    """One part of an imported model (``[textures.<part>]``): its PLY mesh and PNG texture beside the TOML."""

    RULES: ClassVar[dict[str, Rule]] = {
        "mesh": anything,
        "file": anything,
        "roughness": within(0.0, 1.0),
        "metallic": within(0.0, 1.0),
        "recolour": anything,
        "source_name": anything,
    }

    mesh: str
    file: str
    roughness: float = 0.6
    metallic: float = 0.0
    recolour: bool = True
    source_name: str = ""
    """The part's name in the imported file (informational)."""


@dataclass(frozen=True)
class ObjectModel:
    """One model of the library (a parsed TOML file): a piece of furniture or a prop (``role``)."""

    model_id: str
    category: str
    builder: str
    symmetry: str
    support: str
    size: tuple[float, float, float]
    params: dict[str, ParamRange] = field(hash=False)
    scale_range: tuple[float, float]
    textures: dict[str, MaterialSpec] | dict[str, StoredPart] = field(hash=False)
    """Material slot (parametric builders) or part (imported) -> its spec."""
    source: str
    colour_range: tuple[float, float, float] = (0.08, 0.15, 0.15)
    description: str = ""
    texture_size: int = 512
    role: str = "furniture"

    def default_params(self) -> dict[str, float]:
        return {k: float(v.default) for k, v in self.params.items()}

    def build(self, params: dict[str, float] | None = None) -> ObjectMesh:
        """The textured mesh at ``params`` (defaults for missing / None), canonical frame, unscaled."""
        return get_builder(self.builder).build(self, params)[0]

    def material_texture(self, material: str) -> np.ndarray:
        """The (cached, read-only) base texture of one material slot (its shared SKU's, if it uses one)."""
        return get_builder(self.builder).texture(self, material)


# ----------------------------------------------------------------------------------------------- builders
class ModelBuilder(ABC):
    """What makes the models that name it (``builder = "<name>"``): reads their TOML, builds, textures."""

    name: str
    variant_kinds: ClassVar[tuple[str, ...]] = VARIANT_KINDS
    """The variant kinds its models support (:mod:`synthleak.assets.variants` warns about the others)."""

    @abstractmethod
    def parse(self, path: Path, data: dict[str, Any]) -> ObjectModel:
        """The model of the TOML file ``path`` (its table ``data``); errors name the file and the key."""

    @abstractmethod
    def build(
        self, model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
    ) -> tuple[ObjectMesh, list[SupportSurface]]:
        """(mesh in the canonical frame, support surfaces) of ``model`` at ``params``; ``textures`` replaces
        material textures (variants pass recoloured ones)."""

    @abstractmethod
    def texture(self, model: ObjectModel, material: str) -> np.ndarray:
        """The (cached, read-only) base texture of one material slot of ``model``."""


BUILDERS: dict[str, ModelBuilder] = {}
"""Builder name -> builder; :mod:`synthleak.assets.builders` registers them all when imported."""


def register_builder(builder: ModelBuilder) -> ModelBuilder:
    """Add ``builder`` to :data:`BUILDERS` (a name registers once)."""
    if builder.name in BUILDERS:
        raise ValueError(f"builder {builder.name!r} registered twice")
    BUILDERS[builder.name] = builder
    return builder


def get_builder(name: str, where: str = "builder") -> ModelBuilder:
    """The builder called ``name``; an unknown name raises :class:`ConfigError` (``where``: the file and the
    key) listing close and known names."""
    if name not in BUILDERS:
        close = difflib.get_close_matches(name, BUILDERS, n=3)
        raise ConfigError(f"{where}: unknown builder {name!r} (close: {close}; known: {sorted(BUILDERS)})")
    return BUILDERS[name]


# ------------------------------------------------------------------------------------------- TOML tables
def _scale_range(value: tuple[float, float], where: str) -> None:
    if not 0 < value[0] <= 1.0 <= value[1]:
        raise ConfigError(f"{where}: need 0 < min <= 1 <= max, got {list(value)}")


def _colour_range(value: tuple[float, float, float], where: str) -> None:
    if min(value) < 0 or value[0] > 0.5 or max(value[1:]) > 1:
        raise ConfigError(f"{where}: need 0 <= hue <= 0.5 and 0 <= saturation, value <= 1, got {list(value)}")


@dataclass(frozen=True, kw_only=True)
class ModelTable:
    """The top-level keys of every model TOML; a builder's table class adds its own (``params``,
    ``textures``, ...)."""

    RULES: ClassVar[dict[str, Rule]] = {
        "id": matches(MODEL_ID),
        "category": anything,
        "builder": anything,
        "symmetry": one_of(SYMMETRIES),
        "support": one_of(SUPPORTS),
        "size": each(at_least(0.0, exclusive=True)),
        "scale_range": _scale_range,
        "colour_range": _colour_range,
        "description": anything,
    }

    id: str
    category: str
    builder: str
    symmetry: str
    support: str
    size: tuple[float, float, float]
    """Full extents x, y, z in metres (at default parameters)."""
    scale_range: tuple[float, float]
    """Per-axis multiplicative scale range of variants."""
    colour_range: tuple[float, float, float] = (0.08, 0.15, 0.15)
    """Max |hue turns|, |saturation|, |value| shift of colour variants."""
    description: str = ""


def toml_error(path: Path, key: str, message: str) -> ConfigError:
    """The error of a check beyond the table rules, in their format: ``<file>: <key>: <message>``."""
    return ConfigError(f"{path}: {key}: {message}")
