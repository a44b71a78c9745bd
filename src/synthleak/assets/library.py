"""The object library: model definitions (``object_library/*.toml``, props in ``object_library/props/*.toml``)
and their builds.

One TOML file per model (schema in ``object_library/README.md``)::

    id = "chair_ladderback"            # unique, [a-z0-9_]
    category = "chair"
    builder = "chair_ladderback"       # a registered builder (synthleak.assets.builders)
    symmetry = "none"                  # none | 2 | 4 | z  (2-/4-fold about +z, or continuous about z)
    support = "floor"                  # floor | wall | ceiling | surface
    role = "furniture"                 # optional: furniture (default) | prop (small clutter; props/*.toml)
    size = [0.46, 0.50, 0.92]          # full extents x, y, z in metres at default params
    scale_range = [0.9, 1.1]           # per-axis multiplicative scale range for variants
    colour_range = [0.08, 0.15, 0.15]  # optional: max |hue turns|, |saturation|, |value| shift
    description = "..."                # optional
    texture_size = 512                 # optional, 64..1024

    [params]
    seat_height = { default = 0.46, min = 0.42, max = 0.50 }
    n_slats = { default = 3, min = 2, max = 5, integer = true }

    [textures.frame]                   # one entry per material slot the builder draws
    kind = "wood"                      # synthleak.assets.textures.TEXTURE_KINDS
    colour = [0.55, 0.36, 0.20]
    colour2 = [0.3, 0.2, 0.1]          # optional; roughness, metallic, texel_scale (m per texture),
                                       # feature_scale, recolour (bool), emissive ([r, g, b]) optional

Each model is read by its builder (:data:`synthleak.assets.model.BUILDERS`: the parametric ones and
``imported``), its TOML checked by typed tables (:mod:`synthleak.schema`): a bad file raises ``ValueError``
naming the file and the key. Textures of a model are deterministic: material ``m`` of model ``id`` uses
``make_rng(0, "texture", id, m)``; they are cached, so building a model repeatedly is cheap.
"""

from __future__ import annotations

import difflib
import functools
import tomllib
from pathlib import Path

import numpy as np

from synthleak.assets import builders  # noqa: F401  (registers every builder)
from synthleak.assets.mesh import ObjectMesh, SupportSurface
from synthleak.assets.model import PROPS_DIR, ROLES, ObjectModel, get_builder, toml_error
from synthleak.errors import ConfigError, UnknownNameError
from synthleak.paths import object_library_dir


def build_model(
    model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
) -> tuple[ObjectMesh, list[SupportSurface]]:
    """Build ``model`` at ``params`` -> (mesh in the canonical frame, support surfaces), by its builder.

    ``textures`` optionally replaces material textures (variants pass recoloured ones)."""
    return get_builder(model.builder).build(model, params, textures)


# ----------------------------------------------------------------------------------------------- loading
def parse_model(path: Path) -> ObjectModel:
    """The model of one TOML file, read by the builder it names; errors name the file and the key."""
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from e
    name = data.get("builder")
    if name is None:
        raise toml_error(path, "builder", "missing")
    if not isinstance(name, str):
        raise toml_error(path, "builder", f"expected str, got {type(name).__name__}")
    return get_builder(name, f"{path}: builder").parse(path, data)


def load_library(directory: Path | None = None) -> dict[str, ObjectModel]:
    """All models of ``directory`` (default: :func:`synthleak.paths.object_library_dir`): ``*.toml``,
    ``props/*.toml`` and ``imported/*/*.toml``, sorted by id (ids unique over all of them).

    A bad file raises ``ValueError`` naming the file and the key."""
    d = Path(directory) if directory is not None else object_library_dir()
    if not d.is_dir():
        raise FileNotFoundError(f"object library folder {d} does not exist")
    models: dict[str, ObjectModel] = {}
    paths = sorted(d.glob("*.toml")) + sorted(d.glob(f"{PROPS_DIR}/*.toml")) + sorted(d.glob("imported/*/*.toml"))
    for path in paths:
        m = parse_model(path)
        if m.model_id in models:
            raise toml_error(path, "id", f"duplicate id {m.model_id!r} (also in {models[m.model_id].source})")
        models[m.model_id] = m
    return dict(sorted(models.items()))


def by_role(library: dict[str, ObjectModel], role: str) -> dict[str, ObjectModel]:
    """The models of ``library`` with ``role`` (``"furniture"`` or ``"prop"``), in the library's order."""
    if role not in ROLES:
        raise ValueError(f"role: {role!r} not in {ROLES}")
    return {k: m for k, m in library.items() if m.role == role}


@functools.lru_cache(maxsize=8)
def _default_library(directory: str) -> dict[str, ObjectModel]:
    return load_library(Path(directory))


def get_model(model_id: str, library: dict[str, ObjectModel] | None = None) -> ObjectModel:
    """One model of ``library`` (default: the default library, loaded once). Unknown id -> ``KeyError``
    listing close names."""
    lib = library if library is not None else _default_library(str(object_library_dir()))
    if model_id not in lib:
        close = difflib.get_close_matches(model_id, lib, n=5, cutoff=0.4)
        raise UnknownNameError(
            f"unknown model {model_id!r}; close: {close or 'none'} ({len(lib)} models in the library)"
        )
    return lib[model_id]
