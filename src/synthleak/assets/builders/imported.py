"""The ``imported`` builder: models brought in by ``synthleak import``, their meshes and textures stored in the
library (``imported/<id>/``: layout and TOML in :mod:`synthleak.assets.import_store`).

Imported models have no shape parameters: colour and scale variants work, ``shape`` variants are not available.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from synthleak.assets.import_store import IMPORTED_BUILDER, read_ply, read_texture
from synthleak.assets.mesh import ObjectMesh, SupportSurface, TexturedPart
from synthleak.assets.model import ModelBuilder, ModelTable, ObjectModel, StoredPart, register_builder, toml_error
from synthleak.errors import ConfigError, UnknownNameError
from synthleak.schema import Rule, from_table, matches


def _parts(value: dict[str, StoredPart], where: str) -> None:
    if not value:
        raise ConfigError(f"{where}: expected one table per part")


@dataclass(frozen=True, kw_only=True)
class ImportedTable(ModelTable):
    """The TOML of an imported model (written by ``synthleak import``)."""

    RULES: ClassVar[dict[str, Rule]] = {**ModelTable.RULES, "category": matches(r".+"), "textures": _parts}

    scale_range: tuple[float, float] = (0.9, 1.1)
    imported: dict[str, Any] = field(default_factory=dict)
    """Provenance (informational): source file, sha256, up, front, units, scale."""
    textures: dict[str, StoredPart]


class ImportedBuilder(ModelBuilder):
    """Stored meshes: ``build`` reads each part's PLY and PNG (cached); no shape parameters."""

    name = IMPORTED_BUILDER
    variant_kinds: ClassVar[tuple[str, ...]] = ("colour", "scale")

    def parse(self, path: Path, data: dict[str, Any]) -> ObjectModel:
        t: ImportedTable = from_table(ImportedTable, data, f"{path}: ")
        for name, part in t.textures.items():
            for key, file in (("mesh", part.mesh), ("file", part.file)):
                if not (path.parent / file).is_file():
                    raise toml_error(path, f"textures.{name}.{key}", f"file {path.parent / file} does not exist")
        return ObjectModel(
            model_id=t.id,
            category=t.category,
            builder=IMPORTED_BUILDER,
            symmetry=t.symmetry,
            support=t.support,
            size=t.size,
            params={},
            scale_range=t.scale_range,
            textures=t.textures,
            source=str(path),
            colour_range=t.colour_range,
            description=t.description,
        )

    def build(
        self, model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
    ) -> tuple[ObjectMesh, list[SupportSurface]]:
        """The imported mesh (canonical frame, fresh arrays), no support surfaces; ``textures`` replaces part
        textures (colour variants). Any non-None ``params`` entry raises ``KeyError``."""
        given = {k: v for k, v in (params or {}).items() if v is not None}
        if given:
            raise UnknownNameError(
                f"model {model.model_id!r} is an imported mesh and has no shape parameters (got {sorted(given)})"
            )
        base = Path(model.source).parent
        parts = []
        for name, spec in model.textures.items():
            verts, faces, uv = read_ply(base / spec.mesh)
            tex = textures[name] if textures is not None and name in textures else self.texture(model, name)
            parts.append(
                TexturedPart(
                    name=name,
                    vertices=np.array(verts),
                    faces=np.array(faces),
                    uv=np.array(uv),
                    texture=np.array(tex),
                    roughness=float(spec.roughness),
                    metallic=float(spec.metallic),
                )
            )
        return ObjectMesh(parts), []

    def texture(self, model: ObjectModel, material: str) -> np.ndarray:
        """The stored (read-only) texture of one part."""
        if material not in model.textures:
            raise UnknownNameError(
                f"imported model {model.model_id!r} has no part {material!r}; it has {sorted(model.textures)}"
            )
        return read_texture(Path(model.source).parent / model.textures[material].file)


IMPORTED = register_builder(ImportedBuilder())


def parse_imported_model(path: Path) -> ObjectModel:
    """An imported model's TOML file -> :class:`ObjectModel`; errors name the file and the key."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    return IMPORTED.parse(path, data)
